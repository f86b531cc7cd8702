"""Data safety (issue 19): a command never deletes or replaces what it did not create; bad input
and hostile sizes are one-line exit-2 errors checked before allocation; signals leave nothing
partial; temporary entries a killed run left are swept by the next run; workers die with their
driver; Ctrl-C is never swallowed."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from avatarkit.cli.main import main
from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.motion import make_clip, save_clip
from faults import entries, temp_leftovers
from test_avatar import saved_avatar

FAST = ["--substeps", "1", "--iterations", "2", "--preroll", "0"]
EXE = str(Path(sys.executable).with_name("avatarkit"))


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str, *names) -> str:
    """The whole of stderr is one `error: ...` line that names each of `names`."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for n in names:
        assert str(n) in lines[0], (n, err)
    return lines[0]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return saved_avatar(tmp_path_factory)


@pytest.fixture(scope="module")
def clip6(tmp_path_factory):
    path = tmp_path_factory.mktemp("clips") / "talk.npz"
    save_clip(path, make_clip("shake", frames=6, fps=25))
    return path


# --- 1. never delete what the command did not create --------------------------------------------

def test_a_user_folder_at_the_clips_name_is_refused_and_kept(folder, clip6, tmp_path, capsys):
    user = tmp_path / "talk_clips"
    user.mkdir()
    (user / "thesis.txt").write_text("thesis")
    code, _, err = run(capsys, "bake", folder, clip6, "-o", tmp_path / "talk.usdc", "--chunk-frames", 2, *FAST)
    assert code == 2
    one_error_line(err, user, "not made by avatarkit")
    assert (user / "thesis.txt").read_text() == "thesis"
    assert entries(tmp_path) == ["talk_clips", "talk_clips/thesis.txt"]


def test_a_plain_file_or_link_at_the_clips_name_is_refused_and_kept(folder, clip6, tmp_path, capsys):
    (tmp_path / "a_clips").write_text("notes")
    code, _, err = run(capsys, "bake", folder, clip6, "-o", tmp_path / "a.usdc", "--chunk-frames", 2, *FAST)
    assert code == 2
    one_error_line(err, tmp_path / "a_clips")
    assert (tmp_path / "a_clips").read_text() == "notes"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "b_clips").symlink_to(elsewhere)
    code, _, err = run(capsys, "bake", folder, clip6, "-o", tmp_path / "b.usdc", "--chunk-frames", 2, *FAST)
    assert code == 2 and "link" in one_error_line(err, tmp_path / "b_clips")
    assert (tmp_path / "b_clips").is_symlink() and elsewhere.is_dir()
    assert not temp_leftovers(tmp_path)


def test_the_input_clip_folder_is_never_destroyed(folder, tmp_path, capsys):
    """`bake av shot_clips -o shot.usdc`: the per-frame npz folder being read is the clips name."""
    from avatarkit.motion.io import NPZ_KEYS

    clip = make_clip("nod", frames=6, fps=25)
    shot = tmp_path / "shot_clips"
    shot.mkdir()
    for i in range(clip.n_frames):
        np.savez(shot / f"{i:05d}.npz", **{k: getattr(clip, c)[i:i + 1] for c, k in NPZ_KEYS.items()})
    before = {p.name: p.read_bytes() for p in shot.iterdir()}
    code, _, err = run(capsys, "bake", folder, shot, "-o", tmp_path / "shot.usdc", "--chunk-frames", 2, *FAST)
    assert code == 2
    one_error_line(err, shot)
    assert {p.name: p.read_bytes() for p in shot.iterdir()} == before


def test_a_bakes_own_clips_folder_is_replaced(folder, clip6, tmp_path, capsys):
    from avatarkit.export.usd_stage import CLIPS_MARKER

    out = tmp_path / "t.usdc"
    assert run(capsys, "bake", folder, clip6, "-o", out, "--chunk-frames", 2, "-q", *FAST)[0] == 0
    clips = tmp_path / "t_clips"
    assert (clips / CLIPS_MARKER).is_file() and len(list(clips.glob("chunk_*.usdc"))) == 3
    code, _, err = run(capsys, "bake", folder, clip6, "-o", out, "--chunk-frames", 3, "-q", *FAST)
    assert code == 0, err
    assert sorted(p.name for p in clips.glob("chunk_*.usdc")) == ["chunk_00000.usdc", "chunk_00001.usdc"]
    # ... but not once something else was put in it
    (clips / "notes.txt").write_text("mine")
    code, _, err = run(capsys, "bake", folder, clip6, "-o", out, "--chunk-frames", 2, *FAST)
    assert code == 2 and "notes.txt" in one_error_line(err, clips)
    assert (clips / "notes.txt").read_text() == "mine"


def test_transfer_hair_output_equal_to_an_input_is_refused(folder, tmp_path, capsys):
    import shutil

    a = Path(shutil.copytree(folder, tmp_path / "a"))
    before = sorted((p.name, p.stat().st_size) for p in a.iterdir())
    for flag in ("--hair", "--onto"):
        other = folder if flag == "--hair" else a
        argv = ["transfer-hair", "--hair", a if flag == "--hair" else folder, "--onto", a if flag == "--onto" else folder,
                "-o", a]
        code, _, err = run(capsys, *argv)
        assert code == 2 and flag in one_error_line(err, a), other
    assert sorted((p.name, p.stat().st_size) for p in a.iterdir()) == before


def test_a_link_in_a_batch_output_folder_cannot_send_outputs_outside(folder, clip6, tmp_path, capsys):
    from avatarkit.batch import load_batch, run_batch

    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    (out / "sample").symlink_to(outside)  # the job's outputs go under <avatar name>/
    doc = {"defaults": {"sim": {"substeps": 1, "iterations": 2}, "preroll": 0},
           "jobs": [{"avatar": str(folder), "clip": str(clip6), "name": "sample/{clip}"}]}
    (tmp_path / "b.json").write_text(json.dumps(doc))
    report = run_batch(load_batch(tmp_path / "b.json"), out, engine="inline")
    assert report.count("failed") == 1
    assert "symbolic link" in report.failed[0].error
    assert list(outside.iterdir()) == []


# --- 5. temporary entries: swept after a kill, removed on SIGTERM ------------------------------

def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temporaries_of_dead_processes_are_swept(tmp_path):
    from avatarkit import fileio

    host = fileio._HOST
    dead = _dead_pid()
    stale_dir = tmp_path / f".out.usdc.partial-{host}-{dead}-abc"
    stale_dir.mkdir()
    (stale_dir / "big").write_bytes(b"x" * 100)
    stale_file = tmp_path / f".out.ply.partial-{host}-{dead}-xyz.ply"
    stale_file.write_bytes(b"x")
    live = tmp_path / f".out.ply.partial-{host}-{os.getpid()}-live.ply"   # a writer running now
    live.write_bytes(b"x")
    other_host = tmp_path / f".out.ply.partial-000000-{dead}-q.ply"      # another machine's
    other_host.write_bytes(b"x")
    user = tmp_path / ".out.ply.partial-notes"                           # not our pattern
    user.write_bytes(b"x")
    aside = tmp_path / f".kept.old-{host}-{dead}-k"                      # killed between renames
    aside.mkdir()
    removed = fileio.sweep_stale(tmp_path)
    assert sorted(p.name for p in removed) == sorted([stale_dir.name, stale_file.name])
    assert live.exists() and other_host.exists() and user.exists()
    assert (tmp_path / "kept").is_dir() and not aside.exists()  # the old output is put back


def test_a_writer_sweeps_before_it_writes(tmp_path):
    from avatarkit import fileio
    from avatarkit.gaussians.ply import write_ply
    from helpers import random_gaussians

    stale = tmp_path / f".x.ply.partial-{fileio._HOST}-{_dead_pid()}-abc.ply"
    stale.write_bytes(b"half a file")
    write_ply(tmp_path / "x.ply", random_gaussians(10))
    assert entries(tmp_path) == ["x.ply"]


def _wait_for(predicate, timeout=120.0, proc=None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        if proc is not None and proc.poll() is not None:
            return False
        time.sleep(0.05)
    return False


def _bake_cmd(folder, clip, out: Path):
    return [EXE, "bake", str(folder), str(clip), "-o", str(out / "t.usdc"), "--ply-dir", str(out / "t_ply"),
            "--preview", str(out / "t.gif"), "--preview-size", "32", "--chunk-frames", "5",
            "--substeps", "2", "--iterations", "4", "--preroll", "0"]


@pytest.fixture(scope="module")
def long_clip(tmp_path_factory):
    path = tmp_path_factory.mktemp("long") / "long.npz"
    save_clip(path, make_clip("shake", frames=400, fps=25))
    return path


def _started(out: Path) -> bool:
    """The bake is writing: its frames folder has frames in it."""
    return any(out.glob("t_ply/.frames.partial-*/frame_*.ply"))


def test_sigterm_during_a_bake_leaves_nothing(folder, long_clip, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen(_bake_cmd(folder, long_clip, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    assert _wait_for(lambda: _started(out), proc=proc), proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "terminated"
    assert entries(out) == []


@pytest.mark.slow
def test_sigkill_then_rerun_leaves_no_stale_temporaries(folder, long_clip, clip6, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen(_bake_cmd(folder, long_clip, out), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    assert _wait_for(lambda: _started(out), proc=proc)
    proc.kill()
    proc.wait()
    assert temp_leftovers(out)  # what a killed process cannot clean: now the next run's job
    assert not (out / "t.usdc").exists() and not (out / "t.gif").exists()
    r = subprocess.run(_bake_cmd(folder, clip6, out), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert temp_leftovers(out) == []
    assert sorted(p.name for p in (out / "t_ply").iterdir()) == \
        [f"frame_{i:05d}.ply" for i in range(6)] + ["sequence.json"]


# --- 3. Ctrl-C during Taichi's kernel decoration ---------------------------------------------------

def test_an_interrupt_during_kernel_decoration_propagates(monkeypatch):
    """Taichi's `_inside_class` reads the caller's source under a bare `except:`; ours lets a
    KeyboardInterrupt through."""
    from avatarkit._taichi import ensure_taichi

    ti = ensure_taichi()
    kernel_impl = ti.lang.kernel_impl

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(kernel_impl.inspect, "getframeinfo", interrupted)
    with pytest.raises(KeyboardInterrupt):
        @ti.kernel
        def k():
            pass


_IMPORT_KERNELS = """
import sys, time
from avatarkit._taichi import ensure_taichi
print("ready", flush=True)
ensure_taichi()
import avatarkit.sim._kernels, avatarkit.render._kernels, avatarkit.cage._kernels
import avatarkit.recon._label_kernels, avatarkit.gaussians._ply_kernels
time.sleep(2.0)
print("survived", flush=True)
"""


@pytest.mark.slow
def test_sigint_during_import_is_never_swallowed():
    """SIGINT at spread-out moments while Taichi starts and kernels are decorated: every run ends
    interrupted (a swallowed one would sleep on and print "survived")."""
    env = {**os.environ, "TI_SKIP_VERSION_CHECK": "ON", "ENABLE_TAICHI_HEADER_PRINT": "0"}
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-c", _IMPORT_KERNELS.replace("time.sleep(2.0)", "")], env=env, check=True,
                   capture_output=True)
    span = time.monotonic() - t0
    for i in range(10):
        proc = subprocess.Popen([sys.executable, "-c", _IMPORT_KERNELS], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(span * i / 10)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert "survived" not in out, (i, err[-2000:])
        assert proc.returncode != 0


# --- 6. batch workers die with their driver ---------------------------------------------------------

def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_pool_workers_die_with_a_killed_driver(folder, long_clip, tmp_path):
    clips = tmp_path / "clips"
    clips.mkdir()
    for i in range(3):
        (clips / f"c{i}.npz").write_bytes(long_clip.read_bytes())
    doc = {"defaults": {"sim": {"substeps": 2, "iterations": 4}, "preroll": 0,
                        "outputs": {"ply": "{name}_ply"}},
           "jobs": [{"avatar": str(folder), "clips": str(clips)}]}
    (tmp_path / "b.json").write_text(json.dumps(doc))
    out = tmp_path / "out"
    driver = subprocess.Popen([EXE, "bake-batch", str(tmp_path / "b.json"), "-o", str(out), "--workers", "2"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert _wait_for(lambda: any(out.rglob("frame_*.ply")), proc=driver)
        workers = _children(driver.pid)
        assert workers
        driver.kill()
        driver.wait()
        assert _wait_for(lambda: not any(_alive(w) for w in workers), timeout=20), \
            [w for w in workers if _alive(w)]
    finally:
        for w in _children(driver.pid):
            os.kill(w, signal.SIGKILL)
    # the workers cleaned up as they died (SIGTERM interrupts a job like Ctrl-C): no frames left
    assert not list(out.rglob("*.partial-*/frame_*.ply"))


# --- 4 / 9. bad input and hostile sizes: one line, exit 2, before allocation ------------------------

def _npz_with_header(path: Path, key_shapes: dict) -> None:
    """An npz whose members' .npy headers claim `key_shapes` but hold only a few bytes."""
    with zipfile.ZipFile(path, "w") as z:
        for key, shape in key_shapes.items():
            header = ("{'descr': '<f4', 'fortran_order': False, 'shape': %r, }" % (shape,)).ljust(118) + "\n"
            body = 4 * min(int(np.prod(shape)), 1024)  # all of a small array, 4 kB of a huge one
            z.writestr(key + ".npy", b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode()
                       + b"\x00" * body)


def test_an_npz_header_claiming_a_huge_array_is_refused_unallocated(tmp_path, capsys):
    import tracemalloc

    path = tmp_path / "huge.npz"
    keys = {k: (4, 3) for k in ("rotation", "translation", "neck_pose", "jaw_pose")}
    keys.update(eyes_pose=(4, 6), expr=(int(1e11), 3))
    _npz_with_header(path, keys)
    tracemalloc.start()
    code, _, err = run(capsys, "inspect", path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert code == 2 and "expr" in one_error_line(err, path)
    assert peak < 50e6


def test_a_zip_bomb_npz_is_refused_before_it_is_inflated(tmp_path, monkeypatch):
    import tracemalloc

    from avatarkit import fileio
    from avatarkit.motion import load_clip

    path = tmp_path / "bomb.npz"
    clip = make_clip("nod", frames=4, fps=25)
    from avatarkit.motion.io import NPZ_KEYS
    arrays = {k: getattr(clip, c) for c, k in NPZ_KEYS.items()}
    arrays["padding"] = np.zeros(64 << 20, np.uint8)  # 64 MB of zeros: ~64 kB compressed
    np.savez_compressed(path, **arrays)
    assert path.stat().st_size < 1 << 20
    monkeypatch.setattr(fileio, "MAX_NPZ_BYTES", 16 << 20)
    tracemalloc.start()
    with pytest.raises(FormatError, match="once decompressed; the limit is 16 MiB") as info:
        load_clip(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert str(path) in str(info.value) and peak < 8 << 20


def test_a_zero_frame_clip_is_one_line(tmp_path, capsys, folder):
    from avatarkit.motion.io import NPZ_KEYS

    path = tmp_path / "empty.npz"
    widths = {"rotation": 3, "translation": 3, "neck_pose": 3, "jaw_pose": 3, "eyes_pose": 6, "expr": 10}
    np.savez(path, **{k: np.zeros((0, widths[k]), np.float32) for k in NPZ_KEYS.values()})
    for argv in (["inspect", path], ["bake", folder, path, "-o", tmp_path / "o.usdc"],
                 ["motion", "resample", path, "--to-fps", 30, "-o", tmp_path / "r.npz"]):
        code, _, err = run(capsys, *argv)
        assert code == 2, argv
        one_error_line(err, path)


def test_deeply_nested_json_is_one_line(tmp_path, capsys, folder):
    import shutil

    deep = "[" * 100_000 + "]" * 100_000
    clip = tmp_path / "clip.json"
    clip.write_text('{"format": "avatarkit.motion", "version": 1, "frames": ' + deep + "}")
    batch = tmp_path / "b.json"
    batch.write_text('{"jobs": ' + deep + "}")
    av = Path(shutil.copytree(folder, tmp_path / "av"))
    (av / "avatar.json").write_text('{"x": ' + deep + "}")
    cam = tmp_path / "c.camera.json"
    cam.write_text(deep)
    for argv, name in ((["inspect", clip], clip), (["bake-batch", batch, "-o", tmp_path / "o"], batch),
                       (["inspect", av], av / "avatar.json"),
                       (["render", folder, "-o", tmp_path / "x.png", "--camera", cam], cam)):
        code, _, err = run(capsys, *argv)
        assert code == 2, (argv, err)
        assert "nested" in one_error_line(err, name)


@pytest.mark.parametrize("fps", [1e300, 1e-300, float("nan"), float("inf")])
def test_extreme_frame_rates_are_refused(fps, tmp_path, capsys, folder):
    clip = make_clip("nod", frames=4, fps=25)
    path = tmp_path / "c.npz"
    from avatarkit.motion.io import NPZ_KEYS
    np.savez(path, fps=np.float64(fps), **{k: getattr(clip, c) for c, k in NPZ_KEYS.items()})
    code, _, err = run(capsys, "bake", folder, path, "-o", tmp_path / "o.usdc", *FAST)
    assert code == 2
    one_error_line(err, path)
    ok = tmp_path / "ok.npz"
    save_clip(ok, clip)
    code, _, err = run(capsys, "bake", folder, ok, "-o", tmp_path / "o.usdc", "--fps", repr(fps), *FAST)
    assert code == 2 and "fps" in err and "Traceback" not in err
    assert not (tmp_path / "o.usdc").exists()


def test_preroll_and_render_sizes_are_bounded(tmp_path, capsys, folder, clip6):
    code, _, err = run(capsys, "bake", folder, clip6, "-o", tmp_path / "o.usdc", "--preroll", "1e9")
    assert code == 2 and "preroll" in one_error_line(err)
    t0 = time.perf_counter()
    code, _, err = run(capsys, "render", folder, "-o", tmp_path / "x.png", "--width", 100000, "--height", 100000)
    assert code == 2 and "too large" in one_error_line(err)
    code, _, err = run(capsys, "render", folder, "-o", tmp_path / "x.png", "--width", 8000, "--height", 8000,
                       "--contact-sheet", 64)
    assert code == 2 and "contact sheet" in one_error_line(err)
    assert time.perf_counter() - t0 < 30  # refused up front, not after rendering
    assert entries(tmp_path) == []


# --- 7 / 8. inspect SPZ, convert --time nan ------------------------------------------------------

def test_inspect_summarises_spz(tmp_path, capsys):
    from avatarkit.gaussians.spz import write_spz
    from helpers import random_gaussians

    path = tmp_path / "x.spz"
    write_spz(path, random_gaussians(50, sh_degree=1))
    code, out, err = run(capsys, "inspect", path, "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["kind"] == "SPZ splats"
    text = json.dumps(doc)
    assert '"gaussians": 50' in text.lower() and "SPZ version 3" in text


def test_convert_time_nan_is_refused(tmp_path, capsys):
    from avatarkit.convert import ConvertOptions
    from avatarkit.gaussians.ply import write_ply
    from helpers import random_gaussians

    src = tmp_path / "a.ply"
    write_ply(src, random_gaussians(20))
    code, _, err = run(capsys, "convert", src, "-o", tmp_path / "b.ply", "--time", "nan")
    assert code == 2 and "--time" in err and not (tmp_path / "b.ply").exists()
    with pytest.raises(InputError, match="time code"):
        ConvertOptions(time=float("nan")).check()


# --- 10. one line, naming the file ----------------------------------------------------------------

def test_warnings_before_an_error_are_not_printed(folder, tmp_path, capsys):
    clip = make_clip("talk", frames=6, fps=25, expr_dims=40, seed=1)
    expr = clip.expr.copy()
    expr[:, 30] = 0.3  # beyond the template's coefficients: a warning while the clip is prepared
    path = tmp_path / "talk.npz"
    save_clip(path, clip.replace(expr=expr))
    (tmp_path / "o_clips").mkdir()
    code, _, err = run(capsys, "bake", folder, path, "-o", tmp_path / "o.usdc", "--chunk-frames", 2, *FAST)
    assert code == 2
    one_error_line(err, tmp_path / "o_clips")


def test_an_empty_splat_file_in_render_names_it(tmp_path, capsys):
    from avatarkit.gaussians import GaussianSet
    from avatarkit.gaussians.ply import write_ply

    path = tmp_path / "empty.ply"
    write_ply(path, GaussianSet.empty() if hasattr(GaussianSet, "empty") else
              GaussianSet(np.zeros((0, 3)), np.zeros((0, 4)) + [1, 0, 0, 0], np.ones((0, 3)), np.zeros(0),
                          np.zeros((0, 1, 3))))
    code, _, err = run(capsys, "render", path, "-o", tmp_path / "x.png")
    assert code == 2
    one_error_line(err, path)


def test_a_bald_hair_source_names_its_folder(folder, tmp_path, capsys):
    from avatarkit.avatar import load_avatar

    a = load_avatar(folder)
    bald = type(a)(a.head_model, a.bald, a.hair.subset(np.zeros(0, int)), None, None, a.shape, a.head_ref,
                   "bald", a.sh_frame, a.provenance)
    bald.save(tmp_path / "bald", preview=False)
    code, _, err = run(capsys, "transfer-hair", "--hair", tmp_path / "bald", "--onto", folder,
                       "-o", tmp_path / "out")
    assert code == 2
    one_error_line(err, tmp_path / "bald")


def test_usd_warnings_are_held_not_printed_before_the_error(tmp_path, capfd):
    """OpenUSD prints `Warning: ... Could not open asset` lines straight to stderr; they become
    held warnings, so a failing command still prints one line."""
    path = tmp_path / "r.usda"
    path.write_text('#usda 1.0\ndef Xform "A" (\n    references = @missing.usda@\n)\n{\n}\n')
    code, _, err = run(capfd, "render", path, "-o", tmp_path / "r.png")  # fd 2 too: USD writes there
    assert code == 2
    one_error_line(err, path)


@pytest.mark.slow
def test_sigterm_during_a_build_leaves_nothing(tmp_path):
    portrait = Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg"
    out = tmp_path / "av"
    proc = subprocess.Popen([EXE, "build", str(portrait), "-o", str(out), "--n-bald", "2000", "--n-hair", "2000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # the staging folder appears when the avatar is saved, the build's last second or less on a
    # fast host: the signal goes at once (a 1 s wait let the build finish first there)
    assert _wait_for(lambda: any(tmp_path.glob(".av.build-*")), timeout=300, proc=proc), proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert entries(tmp_path) == []


@pytest.mark.slow
@pytest.mark.skipif(not __import__("faults").real_enospc_available(), reason="no user namespaces for a tmpfs")
@pytest.mark.parametrize("command", [
    "{exe} motion make talk --frames 20000 --expr-dims 100 -o clip.npz",
    "{exe} motion make talk --frames 20000 --expr-dims 100 -o clip.json",
    "{exe} avatar sample -o av --n-hair 2000 --n-bald 2000 --no-preview -q",
])
def test_a_real_full_disk_is_one_line_and_leaves_nothing(command, tmp_path):
    """A real ENOSPC: the command runs on a 64 kB tmpfs (in a user namespace)."""
    from faults import run_on_full_disk

    disk = tmp_path / "disk"
    disk.mkdir()
    r = run_on_full_disk(command.format(exe=EXE) + "; echo rc=$?; ls -A", disk, 64)
    out = r.stdout.strip().splitlines()
    assert "rc=2" in out, (r.stdout, r.stderr)
    assert out[-1] == "rc=2", out  # `ls -A` printed nothing after it: no output, no temporary
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "No space left on device" in lines[0], r.stderr
