"""Our stages in the USD tools studios run: an OpenUSD older than the splat schema (26.3), and
NVIDIA's validator (`usd-validation-nvidia`, a test-only peer installed by `make`)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

from avatarkit.export.usd_stage import CAGE_PATH, FACE_PATH, HAIR_PATH, HEAD_PATH, ROOT_PATH, UsdWriteOptions
from peer_scripts.usd_read_times import flat
from peers import SCRIPTS, python_peer, run_peer
from test_usd_stage import synthetic_bake, write_bake

#: the newest usd-core without `UsdVol.ParticleField3DGaussianSplat` (what most DCCs ship today)
OLD_USD = "usd-core==25.11"
#: integer and fractional times, inside chunks and across the chunk boundaries at 4 and 8
TIMES = [0.0, 1.5, 3.0, 3.5, 4.0, 4.5, 7.25, 8.0, 9.0]
VARIANTS = {"float": {}, "half": {"half": True}, "usd_points": {"usd_points": True}}


def _animated(stage: Usd.Stage) -> dict[str, list[str]]:
    """Every attribute with time samples, per prim under /Avatar (as usd-core 26 reads it)."""
    return {str(p.GetPath()): sorted(a.GetName() for a in p.GetAttributes() if a.GetNumTimeSamples())
            for p in stage.GetPrimAtPath(ROOT_PATH).GetChildren()}


def test_chunked_root_layer_declares_every_animated_attribute(tmp_path):
    """The root layer of a chunked stage names each attribute the clips animate, with its type
    and no value (a value there would hide the clips' samples)."""
    static, frames = synthetic_bake()
    path = tmp_path / "clip.usdc"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=4))
    stage = Usd.Stage.Open(str(path))
    layer = stage.GetRootLayer()
    animated = _animated(stage)
    assert set(animated[FACE_PATH]) >= {"positions", "orientations", "scales", "extent"}
    assert set(animated[HEAD_PATH]) >= {"points", "extent", "primvars:normals"}
    for prim_path, names in animated.items():
        prim = stage.GetPrimAtPath(prim_path)
        for name in names:
            spec = layer.GetAttributeAtPath(f"{prim_path}.{name}")
            assert spec is not None, f"{prim_path}.{name} is not declared in the root layer"
            assert spec.typeName == prim.GetAttribute(name).GetTypeName()
            assert not spec.HasDefaultValue() and not layer.ListTimeSamplesForPath(spec.path)


@pytest.mark.slow
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_older_usd_reads_chunked_stages(tmp_path, variant):
    """usd-core 25.11 (no splat schema: Face and Hair are untyped there) opens a chunked bake and
    reads every animated attribute through the clips at integer and fractional times, as 26.x
    does; flattening keeps every sample."""
    python = python_peer("usd-core-25.11", [OLD_USD])
    static, frames = synthetic_bake()
    path = tmp_path / "clip.usdc"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=4, **VARIANTS[variant]))
    stage = Usd.Stage.Open(str(path))
    animated = _animated(stage)
    assert set(animated) == {HEAD_PATH, FACE_PATH, HAIR_PATH, CAGE_PATH}
    request = tmp_path / "request.json"
    request.write_text(json.dumps({"attributes": animated, "times": TIMES}))
    out, flattened = tmp_path / "old.json", tmp_path / "flat.usda"
    run = run_peer([python, SCRIPTS / "usd_read_times.py", path, request, out, flattened])
    assert run.returncode == 0, run.stderr
    old = json.loads(out.read_text())
    assert tuple(old["version"]) < (0, 26, 3) and not old["has_splat_schema"]
    assert old["errors"] == []
    for prim_path, names in animated.items():
        assert set(names) <= set(old["listed"][prim_path]), prim_path
        for name in names:
            attr = stage.GetPrimAtPath(prim_path).GetAttribute(name)
            for t in TIMES:
                got = old["values"][prim_path][name][repr(t)]
                assert got is not None, f"{prim_path}.{name} at {t}"
                np.testing.assert_allclose(got, flat(attr.Get(t)), rtol=0, atol=1e-6,
                                           err_msg=f"{prim_path}.{name} at {t}")
    # what the older USD flattened (a plain layer now: no clips) holds every frame's sample
    flat_stage = Usd.Stage.Open(str(flattened))
    for prim_path, names in animated.items():
        for name in names:
            attr = flat_stage.GetPrimAtPath(prim_path).GetAttribute(name)
            assert attr.GetTimeSamples() == [float(f.index) for f in frames], f"{prim_path}.{name}"
            want = stage.GetPrimAtPath(prim_path).GetAttribute(name)
            for f in (frames[0], frames[5], frames[-1]):
                np.testing.assert_array_equal(flat(attr.Get(f.index)), flat(want.Get(f.index)))


# --- NVIDIA's validator ---------------------------------------------------------------------
#: bake variants written as single-file stages (chunk_frames 0), and one chunked
STAGES = {"default": {}, "half": {"half": True}, "usd_points": {"usd_points": True},
          "no_head_normals": {"head_normals": False}}


def _nvidia_validate(asset: Path, *extra: str) -> dict:
    """`nvidia_usd_validate ASSET` with its default rules -> its JSON report."""
    exe = shutil.which("nvidia_usd_validate", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("NVIDIA's usd-validation-nvidia (test-only peer; `make install` adds it) is not installed")
    report = asset.parent / f"{asset.name}.nvidia.json"
    run = subprocess.run([exe, str(asset), "--json-output", str(report), *extra],
                         capture_output=True, text=True, timeout=600)
    assert report.is_file(), run.stdout + run.stderr
    return json.loads(report.read_text())


def _problems(report: dict) -> list[str]:
    """Every failure and error of a report (warnings are advice, not failed checks)."""
    return [f"{rule['rule']['name']}: {issue['message']} at {issue.get('at', {}).get('path')}"
            for rule in report["rules"] for issue in rule["issues"]
            if issue["severity"] not in ("WARNING", "INFO")]


@pytest.fixture(scope="module")
def baked_stages(tmp_path_factory):
    """The small sample avatar (FLAME-layout template head with eyeballs, a real cage) baked
    with a nod into each STAGES variant as one file, plus a chunked stage and a convert file."""
    from avatarkit.bake import BakeConfig, run_bake
    from avatarkit.bake_writers import make_writer
    from avatarkit.convert import convert
    from avatarkit.motion import make_clip
    from avatarkit.sim.config import SimConfig
    from test_avatar import small_avatar

    root = tmp_path_factory.mktemp("nvidia")
    single, chunked = root / "single", root / "chunked"
    single.mkdir()
    chunked.mkdir()
    writers = [make_writer("usd", single / f"{name}.usdc", {"chunk_frames": 0, **opts})
               for name, opts in STAGES.items()]
    writers.append(make_writer("usd", chunked / "nod.usdc", {"chunk_frames": 3}))
    writers.append(make_writer("ply", root / "ply"))
    config = BakeConfig(sim=SimConfig(substeps=2, iterations=6), preroll=0.2)
    run_bake(small_avatar(), make_clip("nod", frames=7, fps=24), config, writers)
    convert(root / "ply" / "frame_00003.ply", single / "convert.usdc")
    return single, chunked


@pytest.mark.slow
def test_nvidia_validator_passes_single_file_stages(baked_stages):
    """0 failures and 0 errors from `nvidia_usd_validate`'s default rules on every single-file
    stage (it validates the folder's files one by one). Out of scope: its warnings (e.g.
    IndexedPrimvarChecker suggests indexing repeated splat colours, which would only add an
    index per splat) and GaussianSplatSchemaChecker, which NVIDIA registers disabled and which
    reads attributes at the default time only, so it fails on any animated splat prim (see the
    next test)."""
    single, _ = baked_stages
    names = sorted(p.name for p in single.glob("*.usdc"))
    assert names == sorted([f"{n}.usdc" for n in STAGES] + ["convert.usdc"])
    report = _nvidia_validate(single)
    assert _problems(report) == [], report  # its status says FAIL for warnings alone


@pytest.mark.slow
def test_nvidia_validator_on_chunked_stages_and_the_splat_schema_checker(baked_stages):
    """The chunked stage passes too. The splat-schema requirement (VG.035, off by default)
    passes on a one-shot convert file; on an animated prim it cannot run (it takes
    len() of the default-time positions, which an animated prim does not author: USD's
    animation model keeps them in time samples), so it is out of scope for bakes."""
    single, chunked = baked_stages
    report = _nvidia_validate(chunked / "nod.usdc")
    assert _problems(report) == [], report
    report = _nvidia_validate(single / "convert.usdc", "--requirement", "com.nvidia.usd.VG.035")
    assert _problems(report) == [] and report["status"] == "PASS", report
