"""`make bench` in a fresh clone: every benchmark script runs at tiny sizes (`--quick`) from a copy
of the repository's files with nothing beside it (no ../shared), and the scene generator in
benchmarks/ is the standard scene the peers were timed on."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p.name for p in (ROOT / "benchmarks").glob("*.py")
                 if not p.name.startswith("_") and p.name != "make_scene.py")
SHARED_SCENE = ROOT.parent / "shared" / "bench" / "make_scene.py"


def _import_bench(name: str):
    """A module of benchmarks/ (run as scripts there, they import each other by bare name)."""
    import importlib

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def _import_make_scene():
    return _import_bench("make_scene")


def test_scene_is_the_standard_definition(tmp_path):
    """Seed 0, a 60 degree frustum, depth 2..4, identity OpenCV camera; when the project's bench
    notes are beside this checkout, byte-identical files to theirs."""
    make_scene = _import_make_scene()
    means, scales, quats, opacity, rgb, cam = make_scene.make_scene(2000, 640, 480)
    assert means[:, 2].min() >= 2.0 and means[:, 2].max() <= 4.0
    half = np.tan(np.radians(30.0))
    assert np.all(np.abs(means[:, :2]) <= means[:, 2:] * half + 1e-6)
    assert (np.abs(means[:, :2]) / means[:, 2:]).max() > 0.95 * half  # reaches the frustum's sides
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1, atol=1e-6)
    assert opacity.min() >= 0.3 and np.median(scales) == pytest.approx(0.01, rel=0.1)
    assert cam["convention"] == "opencv" and cam["world_to_camera"] == np.eye(4).tolist()
    assert cam["fy"] == pytest.approx(0.5 * 640 / half) and (cam["cx"], cam["cy"]) == (320, 240)
    again = make_scene.make_scene(2000, 640, 480)
    np.testing.assert_array_equal(again[0], means)

    if not SHARED_SCENE.is_file():
        pytest.skip("the project's bench notes are not beside this checkout")
    ours = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "make_scene.py"), "500",
                           str(tmp_path / "a.ply")], check=True)
    peer = subprocess.run([sys.executable, str(SHARED_SCENE), "500", str(tmp_path / "b.ply")], check=True)
    assert ours.returncode == peer.returncode == 0
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    assert json.loads((tmp_path / "a.camera.json").read_text()) == json.loads(
        (tmp_path / "b.camera.json").read_text())


@pytest.fixture(scope="module")
def clone(tmp_path_factory):
    """The files a clone has (tracked and not ignored), copied with nothing beside them."""
    try:
        files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                               cwd=ROOT, check=True, capture_output=True).stdout.split(b"\0")
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    dest = tmp_path_factory.mktemp("fresh") / "avatarkit"
    for name in filter(None, files):
        src = ROOT / os.fsdecode(name)
        if src.is_file():
            (dest / os.fsdecode(name)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / os.fsdecode(name))
    assert not (dest.parent / "shared").exists()
    return dest


def test_make_bench_runs_every_script():
    """The Makefile's list is every script here, so the test below covers what `make bench` runs."""
    if shutil.which("make") is None:
        pytest.skip("no make")
    out = subprocess.run(["make", "-s", "--eval", "print-bench: ; @echo $(BENCH_SCRIPTS)", "print-bench"],
                         cwd=ROOT, check=True, capture_output=True, text=True).stdout.split()
    assert out == [f"benchmarks/{name}" for name in SCRIPTS]


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS)
def test_benchmark_runs_in_a_fresh_clone(clone, script):
    env = dict(os.environ, PYTHONPATH=str(clone), AVATARKIT_THREADS="2")
    r = subprocess.run([sys.executable, f"benchmarks/{script}", "--quick"], cwd=clone, env=env,
                       capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert r.stdout.strip(), "a benchmark prints its figures"


def test_a_switch_set_from_the_benchmarks_command_line_reaches_the_library(monkeypatch):
    """`--set module.NAME=value` (benchmarks/_switches.py): the value is a Python literal or else
    the bare text; the module is found under avatarkit; a switch that is not there, not
    UPPERCASE, or a text without "=" is refused by name; once set, the library reads it when
    called (docs/development.md, "Module switches")."""
    import avatarkit.recon.multiview as mv

    sw = _import_bench("_switches")
    module, name, value = sw.parse_switch("recon.multiview.RELABEL_CONNECTED=None")
    assert module is mv and name == "RELABEL_CONNECTED" and value is None
    assert sw.parse_switch("avatarkit.recon.multiview.RELABEL_REACH=0.2")[2] == 0.2
    assert sw.parse_switch("recon.hair_outline.VETO=direction")[2] == "direction"
    assert sw.parse_switch("recon.hair_outline.VETO='band'")[2] == "band"
    for bad, what in (("recon.multiview.NO_SUCH=1", "has no NO_SUCH"), ("recon.nowhere.X=1", "no module"),
                      ("recon.multiview.view_samples=1", "not a module switch"), ("recon.multiview.SCALP_FILL", "expected")):
        with pytest.raises(ValueError, match=what):
            sw.parse_switch(bad)
    monkeypatch.setattr(mv, "SCALP_FILL", True)                   # restored after the test
    views = mv.VideoViews(np.zeros(10), [], {})
    assert views.fills_scalp()
    assert sw.apply_switches(["recon.multiview.SCALP_FILL=False"]) == ["avatarkit.recon.multiview.SCALP_FILL = False"]
    assert not views.fills_scalp()
