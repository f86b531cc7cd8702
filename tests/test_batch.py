"""`avatarkit bake-batch` on the local process pool: outputs identical to single `avatarkit bake`
runs, re-runs skip what is up to date, a broken job fails alone, transient failures and dead
workers are retried, Ctrl-C leaves nothing half-written."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from avatarkit.batch import BatchInterrupted, JobResult, load_batch, run_batch
from avatarkit.batch.worker import failure
from avatarkit.cli.main import main
from avatarkit.errors import InputError
from test_avatar import saved_avatar

CLIPS = ("nod", "shake", "talk")
FRAMES = 3
FAST_CLI = ["--substeps", "2", "--iterations", "6", "--preroll", "0.2"]
BATCH = {
    "format": "avatarkit.batch", "version": 1,
    "defaults": {"outputs": {"usd": "{name}.usdc", "ply": "{name}_ply", "preview": "{name}.gif"},
                 "preview": {"size": 32}, "sim": {"substeps": 2, "iterations": 6}, "preroll": 0.2},
    "jobs": [{"avatar": ["avatars/a", "avatars/b"], "clips": "clips"}],
}
JOBS = [f"{a}/{c}" for a in "ab" for c in CLIPS]
#: the same bake settings, USD output only (for the tests about failures)
USD_ONLY = {"sim": {"substeps": 2, "iterations": 6}, "preroll": 0.2}


# --- shared inputs (also used by test_batch_ray) ----------------------------------------------

def make_inputs(root: Path) -> Path:
    """root/avatars/a: the small test avatar; root/avatars/b: another one (every other bald
    Gaussian of a, tinted); root/clips/{nod,shake,talk}.npz of FRAMES frames; root/batch.json."""
    from avatarkit.avatar import Avatar, load_avatar
    from avatarkit.motion import make_clip, save_clip

    src = saved_avatar_path()
    shutil.copytree(src, root / "avatars" / "a")
    a = load_avatar(src)
    bald = a.bald.subset(np.arange(0, len(a.bald), 2))
    bald = bald.replace(sh=bald.sh * np.float32(0.8))
    b = Avatar(a.head_model, bald, a.hair, a.cage, a.rig, a.shape, a.head_ref, "b", a.sh_frame, a.provenance)
    b.save(root / "avatars" / "b", preview=False)
    (root / "clips").mkdir()
    for kind in CLIPS:
        save_clip(root / "clips" / f"{kind}.npz", make_clip(kind, frames=FRAMES, fps=25))
    (root / "batch.json").write_text(json.dumps(BATCH))
    return root


_SAVED: dict = {}


def saved_avatar_path() -> Path:
    return _SAVED["path"]


def single_bakes(inputs: Path, ref: Path) -> Path:
    """Each job of BATCH as its own `avatarkit bake` run, into ref/<avatar>/<clip>..."""
    for name in JOBS:
        avatar, clip = name.split("/")
        (ref / avatar).mkdir(parents=True, exist_ok=True)
        stem = ref / avatar / clip
        code = main(["bake", str(inputs / "avatars" / avatar), str(inputs / "clips" / f"{clip}.npz"),
                     "-o", f"{stem}.usdc", "--ply-dir", f"{stem}_ply", "--preview", f"{stem}.gif",
                     "--preview-size", "32", "-q", *FAST_CLI])
        assert code == 0
    return ref


def assert_same_values(a: np.ndarray, b: np.ndarray, what) -> None:
    """Equal, floats up to rounding: batch workers run with fewer threads (AVATARKIT_THREADS),
    and the hair's float32 products round differently with another thread split or another
    CPU's BLAS kernel; 40 XPBD substeps a frame carry that along (seen on AMD EPYC: up to
    5e-6 in unit quaternions, 1 ulp in extents). 2e-5 is 0.02 mm on positions."""
    assert a.shape == b.shape, what
    if a.dtype.kind == "f":
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=2e-5, err_msg=str(what))
    else:
        assert np.array_equal(a, b), what


def assert_same_usd(a: Path, b: Path) -> None:
    """Every attribute of every prim: same time samples, same values."""
    from pxr import Usd

    sa, sb = Usd.Stage.Open(str(a)), Usd.Stage.Open(str(b))
    prims_a = [p.GetPath() for p in sa.Traverse()]
    assert prims_a == [p.GetPath() for p in sb.Traverse()] and len(prims_a) >= 5
    assert (sa.GetStartTimeCode(), sa.GetEndTimeCode(), sa.GetTimeCodesPerSecond()) == \
        (sb.GetStartTimeCode(), sb.GetEndTimeCode(), sb.GetTimeCodesPerSecond())
    n_sampled = 0
    for path in prims_a:
        pa, pb = sa.GetPrimAtPath(path), sb.GetPrimAtPath(path)
        names = sorted(x.GetName() for x in pa.GetAttributes())
        assert names == sorted(x.GetName() for x in pb.GetAttributes()), path
        for name in names:
            xa, xb = pa.GetAttribute(name), pb.GetAttribute(name)
            times = xa.GetTimeSamples()
            assert times == xb.GetTimeSamples(), (path, name)
            n_sampled += bool(times)
            for t in times or [Usd.TimeCode.Default()]:
                va, vb = xa.Get(t), xb.Get(t)
                if hasattr(va, "__len__") and not isinstance(va, str):
                    assert_same_values(np.asarray(va), np.asarray(vb), (path, name, t))
                else:
                    assert va == vb, (path, name, t)
    assert n_sampled >= 8  # the moving attributes were compared, not just the static ones


def assert_same_as_single_bake(out: Path, ref: Path, name: str) -> None:
    from avatarkit.export.video import read_video_frames

    assert_same_usd(out / f"{name}.usdc", ref / f"{name}.usdc")
    plys = sorted((ref / f"{name}_ply").glob("*.ply"))
    assert len(plys) == FRAMES
    from avatarkit.gaussians.ply import read_ply

    for p in plys:
        got, want = read_ply(out / f"{name}_ply" / p.name), read_ply(p)
        for field in ("means", "quats", "scales", "opacities", "sh"):
            assert_same_values(getattr(got, field), getattr(want, field), (p, field))
    got, want = read_video_frames(out / f"{name}.gif"), read_video_frames(ref / f"{name}.gif")
    assert len(got) == FRAMES
    for x, y in zip(got, want):
        # a last-bit difference in a splat can move a pixel across a palette boundary
        differ = np.any(x != y, axis=-1)
        assert differ.mean() < 0.002 and np.abs(x.astype(int) - y).max() <= 24


def no_partials(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".partial" in p.name]


def batch_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# --- fixtures ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    _SAVED["path"] = saved_avatar(tmp_path_factory)
    return make_inputs(tmp_path_factory.mktemp("batch_inputs"))


@pytest.fixture(scope="module")
def reference(inputs, tmp_path_factory):
    return single_bakes(inputs, tmp_path_factory.mktemp("single"))


@pytest.fixture(scope="module")
def local_run(inputs, tmp_path_factory):
    """The batch run once on 2 local workers: (exit code, stdout, stderr, outdir, report)."""
    out = tmp_path_factory.mktemp("batch_out")
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()) as stdout, contextlib.redirect_stderr(err):
        code = main(["bake-batch", str(inputs / "batch.json"), "-o", str(out), "--workers", "2"])
    report = json.loads((out / "batch_report.json").read_text())
    return code, stdout.getvalue(), err.getvalue(), out, report


# --- the local engine ---------------------------------------------------------------------------

def test_local_batch_equals_single_bakes(local_run, reference):
    code, stdout, err, out, report = local_run
    assert code == 0, err
    assert report["counts"] == {"done": 6, "skipped": 0, "failed": 0, "cancelled": 0}
    for name in JOBS:
        assert_same_as_single_bake(out, reference, name)
    assert no_partials(out) == []


def test_report_summary_records_and_avatar_cache(local_run):
    code, stdout, err, out, report = local_run
    assert "done" in stdout and "skipped" in stdout and "failed" in stdout and "batch_report.json" in stdout
    assert [j["name"] for j in report["jobs"]] == JOBS
    assert report["engine"] == "local" and report["workers"] == 2
    for job in report["jobs"]:
        assert job["status"] == "done" and job["attempts"] == 1 and job["frames"] == FRAMES
        for o in job["outputs"]:
            assert o["status"] == "written"
            target = out / o["path"]
            rec = json.loads((target.parent / (target.name + ".job.json")).read_text())
            assert rec["job"] == job["name"] and rec["kind"] == o["kind"]
            assert sum(f["bytes"] for f in rec["files"]) == o["bytes"] > 0
            assert len(rec["files"]) == (FRAMES + 1 if o["kind"] == "ply" else 1)
    # each worker process read each avatar from disk at most once
    loads: dict = {}
    for job in report["jobs"]:
        key = (job["worker"], job["name"].split("/")[0])
        loads[key] = loads.get(key, 0) + bool(job["avatar_loaded"])
    assert all(n == 1 for n in loads.values()), loads
    assert len({j["worker"] for j in report["jobs"]}) <= 2


def test_rerun_skips_everything_and_redoes_only_a_deleted_output(local_run, reference, inputs, capsys):
    code, _, _, out, _ = local_run
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file() and p.name != "batch_report.json"}
    code, stdout, err = batch_cli(capsys, "bake-batch", inputs / "batch.json", "-o", out, "--workers", "2")
    assert code == 0, err
    report = json.loads((out / "batch_report.json").read_text())
    assert report["counts"]["skipped"] == 6 and report["counts"]["done"] == 0
    assert all("worker" not in j for j in report["jobs"])  # nothing was sent to a worker
    assert report["bytes"]["total"] == sum(p.stat().st_size for p in stamps if not p.name.endswith(".job.json"))
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps

    # one output gone: only that job runs, and only that output is written again
    shutil.rmtree(out / "b" / "shake_ply")
    code, stdout, err = batch_cli(capsys, "bake-batch", inputs / "batch.json", "-o", out, "--workers", "2")
    assert code == 0, err
    report = json.loads((out / "batch_report.json").read_text())
    assert report["counts"] == {"done": 1, "skipped": 5, "failed": 0, "cancelled": 0}
    job = next(j for j in report["jobs"] if j["status"] == "done")
    assert job["name"] == "b/shake"
    assert {o["kind"]: o["status"] for o in job["outputs"]} == {"usd": "skipped", "ply": "written",
                                                               "preview": "skipped"}
    assert (out / "b" / "shake.usdc").stat().st_mtime_ns == stamps[out / "b" / "shake.usdc"]
    assert_same_as_single_bake(out, reference, "b/shake")


def test_changed_inputs_or_settings_redo_their_jobs(local_run, inputs, tmp_path):
    _, _, _, out, _ = local_run
    work = Path(shutil.copytree(out, tmp_path / "out"))
    batch_dir = Path(shutil.copytree(inputs, tmp_path / "in", ignore=shutil.ignore_patterns("avatars")))
    (batch_dir / "avatars").symlink_to(inputs / "avatars")
    from avatarkit.motion import make_clip, save_clip

    save_clip(batch_dir / "clips" / "talk.npz", make_clip("talk", frames=FRAMES, fps=25, seed=7))
    report = run_batch(load_batch(batch_dir / "batch.json"), work, engine="inline")
    assert {j.name for j in report.jobs if j.status == "done"} == {"a/talk", "b/talk"}
    assert report.count("skipped") == 4

    doc = dict(BATCH, jobs=[{"avatar": "avatars/a", "clips": "clips"},
                            {"avatar": "avatars/b", "clips": "clips", "sim": {"substeps": 3}}])
    (batch_dir / "batch.json").write_text(json.dumps(doc))
    report = run_batch(load_batch(batch_dir / "batch.json"), work, engine="inline")
    done = [j for j in report.jobs if j.status == "done"]
    assert [j.name for j in done] == ["b/nod", "b/shake", "b/talk"] and report.count("skipped") == 3
    assert sum(j.avatar_loaded for j in done) <= 1  # this process keeps the avatar it loaded


def test_broken_jobs_fail_alone(inputs, tmp_path, capsys):
    broken = Path(shutil.copytree(inputs / "avatars" / "a", tmp_path / "broken"))
    (broken / "avatar.json").write_text("{ this is not json")
    (tmp_path / "bad_clip.npz").write_bytes(b"not a zip file")
    doc = {"defaults": USD_ONLY,
           "jobs": [{"avatar": [str(broken), str(inputs / "avatars" / "a")], "clip": str(inputs / "clips" / "nod.npz")},
                    {"avatar": str(inputs / "avatars" / "b"), "clip": str(tmp_path / "bad_clip.npz")},
                    {"avatar": str(tmp_path / "missing"), "clip": str(inputs / "clips" / "nod.npz")}]}
    path = tmp_path / "batch.json"
    path.write_text(json.dumps(doc))
    out = tmp_path / "out"
    code, stdout, err = batch_cli(capsys, "bake-batch", path, "-o", out, "--workers", "2")
    assert code == 3  # some jobs failed: neither a bug (1) nor a bad batch file (2)
    report = json.loads((out / "batch_report.json").read_text())
    status = {j["name"]: j for j in report["jobs"]}
    assert status["a/nod"]["status"] == "done" and (out / "a" / "nod.usdc").is_file()
    for name, words in (("broken/nod", ["avatar.json", "not valid JSON"]), ("b/bad_clip", ["bad_clip.npz"]),
                        ("missing/nod", ["missing", "not found"])):
        job = status[name]
        assert job["status"] == "failed", job
        assert job.get("attempts", 0) <= 1  # bad input is never retried
        for w in words:
            assert w in job["error"], job["error"]
        assert f"failed: {name}: " in stdout and f"failed: {name}" in err
        assert not (out / name).with_suffix(".usdc").exists()
    assert no_partials(out) == []


def test_rigid_hair_avatars_bake_static_unless_the_batch_says(inputs, tmp_path):
    """As with `avatarkit bake`: an avatar built with rigid hair bakes static by default."""
    from pxr import Usd

    from avatarkit.avatar import load_avatar

    rigid = load_avatar(inputs / "avatars" / "a")
    rigid.provenance["hair_mode"] = "rigid"
    rigid.save(tmp_path / "rigid", preview=False)
    nod = str(inputs / "clips" / "nod.npz")
    doc = {"defaults": USD_ONLY,
           "jobs": [{"avatar": [str(tmp_path / "rigid"), str(inputs / "avatars" / "a")], "clip": nod},
                    {"name": "{avatar}_dynamic", "avatar": str(tmp_path / "rigid"), "clip": nod,
                     "sim": {"static": False}}]}
    (tmp_path / "batch.json").write_text(json.dumps(doc))
    report = run_batch(load_batch(tmp_path / "batch.json"), tmp_path / "out", engine="inline")
    assert all(j.status == "done" for j in report.jobs), report.jobs
    for name, want in (("rigid/nod", True), ("a/nod", False), ("rigid_dynamic", False)):
        stage = Usd.Stage.Open(str(tmp_path / "out" / f"{name}.usdc"))
        settings = stage.GetRootLayer().customLayerData["avatarkit"]["provenance"]["settings"]
        assert settings["sim"]["static"] is want, name


def test_bad_batch_file_exits_2(tmp_path, capsys):
    path = tmp_path / "b.json"
    path.write_text(json.dumps({"jobs": [{"avatar": "a", "clip": "c.npz", "sim": {"substeps": 0}}]}))
    code, out, err = batch_cli(capsys, "bake-batch", path, "-o", tmp_path / "out")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: ") and "substeps" in lines[0]
    assert not (tmp_path / "out").exists()  # nothing made for a batch that never started
    code, out, err = batch_cli(capsys, "bake-batch", tmp_path / "none.json", "-o", tmp_path / "out")
    assert code == 2 and "not found" in err
    path.write_text(json.dumps({"jobs": [{"avatar": "a", "clip": "c.npz"}]}))
    code, out, err = batch_cli(capsys, "bake-batch", path, "-o", tmp_path / "out", "--address", "auto")
    assert code == 2 and "--address applies to --engine ray" in err


def test_ray_engine_without_ray_says_how_to_install(tmp_path, monkeypatch, capsys):
    path = tmp_path / "b.json"
    (tmp_path / "a").mkdir()
    (tmp_path / "c.npz").write_bytes(b"x")
    path.write_text(json.dumps({"jobs": [{"avatar": "a", "clip": "c.npz"}]}))
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    code, out, err = batch_cli(capsys, "bake-batch", path, "-o", tmp_path / "out", "--engine", "ray")
    assert code == 2 and "avatarkit[ray]" in err


# --- failures, retries, interruption (fake jobs: no baking) -------------------------------------

def fake_execute(task):
    """Stands in for worker.execute. The clip's name says what to do: ok, oserror-once,
    oserror-always, badinput, bug, die-once, die-always. Counts its calls per job in outdir/calls/."""
    calls = Path(task.outdir) / "calls"
    calls.mkdir(exist_ok=True)
    marker = calls / task.job.clip.stem
    with open(marker, "a") as fh:
        fh.write("x")
    n = marker.stat().st_size
    how = task.job.clip.stem.split("_")[0]
    if how == "die-always" or (how == "die-once" and n == 1):
        time.sleep(0.2)  # let the neighbour start, so the pool breaks with both in it
        os._exit(3)
    result = None
    if how == "oserror-always" or (how == "oserror-once" and n == 1):
        result = failure(task, OSError(5, "Input/output error (a flaky share)"), 0.0)
    elif how == "badinput":
        result = failure(task, InputError("no such thing", task.job.clip), 0.0)
    elif how == "bug":
        result = failure(task, ValueError("a bug, not a flaky share"), 0.0)
    if result is not None:
        result.attempts = task.attempt  # as worker.execute does
        return result
    time.sleep(0.1)
    return JobResult(task.job.name, "done", attempts=task.attempt, worker=f"pid {os.getpid()}")


def fake_batch(tmp_path: Path, clips: list[str]):
    (tmp_path / "av").mkdir(exist_ok=True)
    (tmp_path / "av" / "avatar.json").write_text("{}")
    for c in clips:
        (tmp_path / f"{c}.npz").write_bytes(b"x")
    doc = {"jobs": [{"avatar": "av", "clip": [f"{c}.npz" for c in clips]}]}
    (tmp_path / "b.json").write_text(json.dumps(doc))
    return load_batch(tmp_path / "b.json")


def test_transient_failures_are_retried_bad_input_is_not(tmp_path, monkeypatch):
    from avatarkit.batch import runner

    monkeypatch.setattr(runner, "BACKOFF", 0.01)
    batch = fake_batch(tmp_path, ["ok", "oserror-once", "badinput"])
    events = []
    report = run_batch(batch, tmp_path / "out", engine="inline", retries=2, execute_fn=fake_execute,
                       on_event=events.append)
    jobs = {j.name: j for j in report.jobs}
    assert jobs["av/ok"].status == "done" and jobs["av/ok"].attempts == 1
    assert jobs["av/oserror-once"].status == "done" and jobs["av/oserror-once"].attempts == 2
    assert jobs["av/badinput"].status == "failed" and jobs["av/badinput"].attempts == 1
    assert "no such thing" in jobs["av/badinput"].error
    retries = [e for e in events if e.kind == "retry"]
    assert [e.job for e in retries] == ["av/oserror-once"] and "flaky share" in retries[0].message
    assert not report.ok and report.counts["failed"] == 1

    # no retries left: the transient failure is final
    (tmp_path / "again").mkdir()
    report = run_batch(fake_batch(tmp_path / "again", ["oserror-once"]), tmp_path / "out2", engine="inline",
                       retries=0, execute_fn=fake_execute)
    assert report.jobs[0].status == "failed" and report.jobs[0].transient and "flaky" in report.jobs[0].error


def test_retries_counts_the_attempts_after_the_first(tmp_path, monkeypatch):
    """`retries=1`: a job that fails transiently once is retried once and succeeds; one that
    always fails is tried exactly twice; a bug (not an OSError) is final at once."""
    from avatarkit.batch import runner

    monkeypatch.setattr(runner, "BACKOFF", 0.01)
    batch = fake_batch(tmp_path, ["oserror-once", "oserror-always", "bug"])
    events = []
    report = run_batch(batch, tmp_path / "out", engine="inline", retries=1, execute_fn=fake_execute,
                       on_event=events.append)
    jobs = {j.name: j for j in report.jobs}
    assert jobs["av/oserror-once"].status == "done" and jobs["av/oserror-once"].attempts == 2
    always = jobs["av/oserror-always"]
    assert always.status == "failed" and always.transient and always.attempts == 2
    bug = jobs["av/bug"]
    assert bug.status == "failed" and not bug.transient and bug.attempts == 1
    assert bug.error_type == "ValueError" and "a bug" in bug.error
    calls = tmp_path / "out" / "calls"
    assert (calls / "oserror-once").read_text() == "xx" and (calls / "oserror-always").read_text() == "xx"
    assert sorted(e.job for e in events if e.kind == "retry") == ["av/oserror-always", "av/oserror-once"]


def test_dead_workers_are_retried_and_the_culprit_found(tmp_path):
    batch = fake_batch(tmp_path, ["ok_1", "die-once", "ok_2", "die-always", "ok_3"])
    report = run_batch(batch, tmp_path / "out", engine="local", workers=2, retries=1, execute_fn=fake_execute)
    jobs = {j.name: j for j in report.jobs}
    for name in ("av/ok_1", "av/ok_2", "av/ok_3"):
        assert jobs[name].status == "done", jobs[name]
        assert jobs[name].attempts == 1  # a neighbour's crash is not charged to them
    assert jobs["av/die-once"].status == "done"
    culprit = jobs["av/die-always"]
    assert culprit.status == "failed" and "worker process died" in culprit.error
    assert culprit.attempts == 2 and culprit.error_type == "WorkerLost"
    calls = (tmp_path / "out" / "calls" / "die-always").stat().st_size
    assert 2 <= calls <= 3  # charged twice when alone, maybe once more beside a neighbour


def test_ctrl_c_stops_cleanly(inputs, tmp_path):
    """Interrupted after the first finished job: the rest are stopped or never started, and
    nothing is left half-written; the report is saved and says so."""
    from avatarkit.motion import make_clip, save_clip

    clips = tmp_path / "clips"
    clips.mkdir()
    for kind in ("nod", "shake", "talk", "turn"):
        save_clip(clips / f"{kind}.npz", make_clip(kind, frames=15, fps=25))
    doc = {"defaults": USD_ONLY, "jobs": [{"avatar": str(inputs / "avatars" / "a"), "clips": str(clips)}]}
    (tmp_path / "b.json").write_text(json.dumps(doc))
    out = tmp_path / "out"

    def stop(event):
        if event.kind == "done":
            raise KeyboardInterrupt

    with pytest.raises(BatchInterrupted) as e:
        run_batch(load_batch(tmp_path / "b.json"), out, workers=2, on_event=stop)
    report = e.value.report
    assert report.interrupted and report.path == out / "batch_report.json"
    assert json.loads(report.path.read_text())["interrupted"] is True
    assert report.count("done") >= 1 and report.count("cancelled") >= 1
    assert report.count("done") + report.count("cancelled") == 4
    assert no_partials(out) == []
    for job in report.jobs:
        usd = out / f"{job.name}.usdc"
        if job.status == "done":
            assert usd.is_file() and (out / f"{job.name}.usdc.job.json").is_file()
        else:
            assert not usd.exists() and not (out / f"{job.name}.usdc.job.json").exists()
    # the next run finishes the rest
    report = run_batch(load_batch(tmp_path / "b.json"), out, engine="inline")
    assert report.ok and report.count("skipped") >= 1


@pytest.mark.slow
def test_ctrl_c_in_a_terminal(inputs, tmp_path):
    """SIGINT to the whole process group, as a terminal's Ctrl-C: exit code 130, no partials."""
    from avatarkit.motion import make_clip, save_clip

    clips = tmp_path / "clips"
    clips.mkdir()
    # enough work that the batch is still running when the first job's file appears, also on a
    # fast host (six 60-frame clips finished before the signal there)
    for i in range(12):
        save_clip(clips / f"c{i}.npz", make_clip("shake", frames=150, fps=25, amplitude=10 + i))
    doc = {"defaults": USD_ONLY, "jobs": [{"avatar": str(inputs / "avatars" / "a"), "clips": str(clips)}]}
    (tmp_path / "b.json").write_text(json.dumps(doc))
    out = tmp_path / "out"
    exe = Path(sys.executable).with_name("avatarkit")
    proc = subprocess.Popen([str(exe), "bake-batch", str(tmp_path / "b.json"), "-o", str(out), "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(out.rglob("*.job.json")):
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr and "cancelled" in stderr
    assert json.loads((out / "batch_report.json").read_text())["interrupted"] is True
    assert no_partials(out) == []
