"""`avatarkit bake-batch --engine ray` on a local Ray instance started here (2 CPUs, no
dashboard, no usage statistics): outputs identical to single `avatarkit bake` runs, a broken job
fails alone, a dead worker is retried, re-runs skip."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
ray = pytest.importorskip("ray")

from avatarkit.batch import run_batch  # noqa: E402
from test_avatar import saved_avatar  # noqa: E402
from test_batch import (_SAVED, FRAMES, JOBS, USD_ONLY, assert_same_as_single_bake, batch_cli,  # noqa: E402
                        fake_batch, fake_execute, make_inputs, no_partials, single_bakes)



@pytest.fixture(scope="module")
def local_ray():
    import logging

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    _SAVED["path"] = saved_avatar(tmp_path_factory)
    return make_inputs(tmp_path_factory.mktemp("batch_inputs"))


@pytest.mark.slow  # 25-40 s: six single bakes, Ray's workers importing avatarkit and Taichi
def test_ray_batch_equals_single_bakes_and_reruns_skip(local_ray, inputs, tmp_path, capsys):
    out = tmp_path / "out"
    code, stdout, err = batch_cli(capsys, "bake-batch", inputs / "batch.json", "-o", out, "--engine", "ray")
    assert code == 0, err
    assert ray.is_initialized()  # the engine used the test's instance and left it running
    report = json.loads((out / "batch_report.json").read_text())
    assert report["engine"] == "ray" and report["workers"] == 2
    assert report["counts"] == {"done": 6, "skipped": 0, "failed": 0, "cancelled": 0}
    ref = single_bakes(inputs, tmp_path / "single")
    for name in JOBS:
        assert_same_as_single_bake(out, ref, name)
    assert no_partials(out) == []
    loads: dict = {}
    for job in report["jobs"]:
        assert job["frames"] == FRAMES
        key = (job["worker"], job["name"].split("/")[0])
        loads[key] = loads.get(key, 0) + bool(job["avatar_loaded"])
    assert all(n == 1 for n in loads.values()), loads  # each Ray worker loads each avatar once

    code, stdout, err = batch_cli(capsys, "bake-batch", inputs / "batch.json", "-o", out, "--engine", "ray")
    assert code == 0 and json.loads((out / "batch_report.json").read_text())["counts"]["skipped"] == 6


@pytest.mark.slow
def test_ray_broken_job_fails_alone(local_ray, inputs, tmp_path, capsys):
    import shutil

    broken = Path(shutil.copytree(inputs / "avatars" / "a", tmp_path / "broken"))
    (broken / "rig.npz").write_bytes(b"truncated")
    doc = {"defaults": USD_ONLY,
           "jobs": [{"avatar": [str(broken), str(inputs / "avatars" / "b")], "clip": str(inputs / "clips" / "nod.npz")}]}
    (tmp_path / "b.json").write_text(json.dumps(doc))
    code, stdout, err = batch_cli(capsys, "bake-batch", tmp_path / "b.json", "-o", tmp_path / "out", "--engine", "ray")
    assert code == 3
    jobs = {j["name"]: j for j in json.loads((tmp_path / "out" / "batch_report.json").read_text())["jobs"]}
    assert jobs["b/nod"]["status"] == "done"
    assert jobs["broken/nod"]["status"] == "failed" and "rig.npz" in jobs["broken/nod"]["error"]
    assert jobs["broken/nod"]["attempts"] == 1


def test_ray_dead_worker_is_retried(local_ray, tmp_path):
    """The fast Ray representative (~8 s, most of it Ray's start): fake jobs, real engine."""
    import test_batch

    # Ray's workers cannot import this test folder: send the fake job function by value
    ray.cloudpickle.register_pickle_by_value(test_batch)
    batch = fake_batch(tmp_path, ["ok", "die-once", "die-always"])
    report = run_batch(batch, tmp_path / "out", engine="ray", retries=1, execute_fn=fake_execute)
    jobs = {j.name: j for j in report.jobs}
    assert jobs["av/ok"].status == "done" and jobs["av/ok"].attempts == 1
    assert jobs["av/die-once"].status == "done" and jobs["av/die-once"].attempts == 2
    assert jobs["av/die-always"].status == "failed" and jobs["av/die-always"].attempts == 2
    assert "WorkerCrashedError" in jobs["av/die-always"].error
