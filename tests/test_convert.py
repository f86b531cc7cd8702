"""`convert` / `avatarkit convert`: PLY <-> USD <-> SPZ round trips, sequences, NVIDIA parity, bad input."""
from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from avatarkit.cli.main import main
from avatarkit.convert import ConvertOptions, convert, resolve_inputs
from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.gaussians.ply import read_ply, write_ply
from avatarkit.gaussians.spz import read_spz
from avatarkit.gaussians.usd import validate_stage
from avatarkit.gaussians.usd_read import load_usd
from helpers import random_gaussians

FIELDS = ("means", "quats", "scales", "opacities", "sh")


@pytest.fixture
def ply(tmp_path):
    path = tmp_path / "in.ply"
    write_ply(path, random_gaussians(400, sh_degree=3, seed=1))
    return path


def test_ply_usd_ply_round_trip(tmp_path, ply):
    src = read_ply(ply)
    for ext in (".usdc", ".usda", ".usdz"):
        mid, out = tmp_path / f"mid{ext}", tmp_path / f"out{ext}.ply"
        r = convert(ply, mid)
        assert (r.count, r.sh_degree, r.frames) == (400, 3, 1) and r.bytes == mid.stat().st_size
        usd = load_usd(mid)
        for f in FIELDS:  # bit for bit: USD holds the same float32 values
            np.testing.assert_array_equal(getattr(usd, f), getattr(src, f), err_msg=f)
        convert(mid, out)
        back = read_ply(out)
        for f in ("means", "quats", "sh"):
            np.testing.assert_array_equal(getattr(back, f), getattr(src, f), err_msg=f)
        # PLY stores log scale and logit opacity: one float32 rounding each way
        np.testing.assert_allclose(back.scales, src.scales, rtol=1e-6)
        np.testing.assert_allclose(back.opacities, src.opacities, rtol=1e-5, atol=1e-7)
        assert validate_stage(mid) == []


def test_half_usd_round_trip(tmp_path, ply):
    convert(ply, tmp_path / "h.usdc", ConvertOptions(half=True))
    back, src = load_usd(tmp_path / "h.usdc"), read_ply(ply)
    np.testing.assert_allclose(back.means, src.means, rtol=2.0 ** -11, atol=2.0 ** -24)
    np.testing.assert_allclose(back.sh, src.sh, rtol=2.0 ** -11, atol=2.0 ** -24)


def test_ply_spz_ply_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    gs = random_gaussians(500, sh_degree=2, seed=2)
    gs = gs.replace(sh=np.clip(gs.sh, -0.95, 0.95), opacities=rng.uniform(0.01, 0.99, 500).astype(np.float32))
    write_ply(tmp_path / "a.ply", gs)
    convert(tmp_path / "a.ply", tmp_path / "a.spz")
    convert(tmp_path / "a.spz", tmp_path / "b.ply")
    src, back = read_ply(tmp_path / "a.ply"), read_ply(tmp_path / "b.ply")
    assert np.abs(back.means - src.means).max() <= 2.0 ** -13 + 1e-6
    assert np.abs(np.log(back.scales / src.scales)).max() <= 1 / 32 + 1e-5
    assert np.abs(back.opacities - src.opacities).max() <= 0.5 / 255 + 1e-5
    assert np.abs(back.sh[:, 0] - src.sh[:, 0]).max() <= 0.5 / (0.15 * 255) + 1e-5
    assert np.abs(back.sh[:, 1:4] - src.sh[:, 1:4]).max() <= 4.5 / 128 + 1e-6
    assert np.abs(back.sh[:, 4:] - src.sh[:, 4:]).max() <= 8.5 / 128 + 1e-6
    assert np.abs((back.quats * src.quats).sum(1)).min() > np.cos(np.radians(0.5) / 2)


def test_sh_degree_option_drops_bands(tmp_path, ply):
    r = convert(ply, tmp_path / "d1.usda", ConvertOptions(sh_degree=1))
    assert r.sh_degree == 1
    back, src = load_usd(tmp_path / "d1.usda"), read_ply(ply)
    np.testing.assert_array_equal(back.sh, src.sh[:, :4])
    assert convert(tmp_path / "d1.usda", tmp_path / "d3.ply", ConvertOptions(sh_degree=3)).sh_degree == 1


def test_matches_nvidia_converter(tmp_path, ply):
    nv = pytest.importorskip("usd_convert_gsplat",
                             reason="NVIDIA's usd-convert-gsplat (test-only peer) is not installed")
    nv.write_gaussian_splat_usd(nv.read_ply(str(ply)), str(tmp_path / "nv.usda"), source_file=str(ply),
                                prim_name="Splats")
    convert(ply, tmp_path / "ours.usda")
    a, b = Usd.Stage.Open(str(tmp_path / "nv.usda")), Usd.Stage.Open(str(tmp_path / "ours.usda"))
    for get in (UsdGeom.GetStageUpAxis, UsdGeom.GetStageMetersPerUnit):
        assert get(a) == get(b)
    pa, pb = a.GetPrimAtPath("/Splats"), b.GetPrimAtPath("/Splats")
    names = {x.GetName() for x in pa.GetAuthoredAttributes()}
    assert names == {x.GetName() for x in pb.GetAuthoredAttributes()}
    assert "radiance:sphericalHarmonicsCoefficients" in names and "primvars:displayColor" in names
    for name in sorted(names):
        x, y = pa.GetAttribute(name), pb.GetAttribute(name)
        assert x.GetTypeName() == y.GetTypeName(), name
        for key in ("elementSize", "interpolation"):
            assert x.GetMetadata(key) == y.GetMetadata(key), (name, key)
        # NVIDIA computes in float64 Python: allow one float32 rounding
        np.testing.assert_allclose(np.asarray(y.Get(), float), np.asarray(x.Get(), float),
                                   rtol=2e-7, atol=1e-7, err_msg=name)


def _sequence(folder, n_frames=11, n=60):
    base = random_gaussians(n, sh_degree=1, seed=3)
    folder.mkdir()
    frames = []
    for i in range(n_frames):
        f = base.replace(means=base.means + np.float32(0.01 * i))
        write_ply(folder / f"frame_{i}.ply", f)  # frame_10 sorts after frame_9 only naturally
        frames.append(f)
    return frames


def test_folder_of_plys_becomes_one_time_sampled_stage(tmp_path):
    frames = _sequence(tmp_path / "seq")
    (tmp_path / "seq" / "notes.txt").write_text("ignored")
    out = tmp_path / "seq.usdc"
    done = []
    r = convert(tmp_path / "seq", out, ConvertOptions(fps=30), progress=lambda i, n: done.append((i, n)))
    assert (r.frames, r.count) == (11, 60) and done[-1] == (11, 11)
    stage = Usd.Stage.Open(str(out))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (0, 10, 30)
    prim = stage.GetPrimAtPath("/Splats")
    assert prim.GetAttribute("positions").GetNumTimeSamples() == 11
    assert prim.GetAttribute("opacities").GetNumTimeSamples() == 0  # unchanged: written once
    for i in (0, 2, 9, 10):
        np.testing.assert_array_equal(load_usd(out, time=i).means, frames[i].means)
    assert validate_stage(stage) == []


def test_long_sequences_read_with_the_kernel_give_the_same_stage(tmp_path, monkeypatch):
    import avatarkit.gaussians.ply as ply

    _sequence(tmp_path / "seq", n_frames=4)
    convert(tmp_path / "seq", tmp_path / "numpy.usda")
    calls = []
    real = ply._decode_with_kernel
    monkeypatch.setattr(ply, "_decode_with_kernel", lambda *a: calls.append(1) or real(*a))
    monkeypatch.setattr(ply, "sequence_decoder", lambda paths: "kernel")  # as for GBs of frames
    convert(tmp_path / "seq", tmp_path / "kernel.usda")
    assert len(calls) == 4
    assert (tmp_path / "kernel.usda").read_text() == (tmp_path / "numpy.usda").read_text()


def test_sequence_count_mismatch_is_clear_and_leaves_nothing(tmp_path):
    _sequence(tmp_path / "seq", n_frames=3)
    write_ply(tmp_path / "seq" / "frame_2.ply", random_gaussians(59, sh_degree=1))
    with pytest.raises(InputError, match=r"frame_2\.ply.*59 Gaussians.*60"):
        convert(tmp_path / "seq", tmp_path / "seq.usdc")
    assert not list(tmp_path.glob("*seq*.usdc*")) and not list(tmp_path.glob(".*"))


def test_natural_order(tmp_path):
    (tmp_path / "d").mkdir()
    for name in ("f10.ply", "f2.ply", "f1.ply", "F3.ply"):
        (tmp_path / "d" / name).write_bytes(b"")
    assert [p.name for p in resolve_inputs(tmp_path / "d")] == ["f1.ply", "f2.ply", "F3.ply", "f10.ply"]


def test_bad_inputs(tmp_path, ply):
    # a PLY without rotations and scales is not a splat file
    no_rot = tmp_path / "points.ply"
    no_rot.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                       b"property float z\nproperty float opacity\nend_header\n0 0 0 1\n")
    with pytest.raises(FormatError, match="points.ply"):
        convert(no_rot, tmp_path / "p.usdc")
    with pytest.raises(InputError, match="unknown input format '.obj'"):
        (tmp_path / "m.obj").write_text("v 0 0 0\n")
        convert(tmp_path / "m.obj", tmp_path / "m.usdc")
    with pytest.raises(OutputError, match="unknown output format '.abc'"):
        convert(ply, tmp_path / "x.abc")
    stage = Usd.Stage.CreateNew(str(tmp_path / "empty.usda"))
    UsdGeom.Xform.Define(stage, "/W")
    stage.Save()
    with pytest.raises(FormatError, match="no ParticleField3DGaussianSplat"):
        convert(tmp_path / "empty.usda", tmp_path / "e.ply")
    (tmp_path / "bad.spz").write_bytes(b"\x1f\x8b" + bytes(100))
    with pytest.raises(FormatError, match="bad.spz"):
        convert(tmp_path / "bad.spz", tmp_path / "s.ply")
    with pytest.raises(InputError, match="up-axis"):
        convert(ply, tmp_path / "z.ply", ConvertOptions(up_axis="Z"))
    with pytest.raises(InputError, match="fps"):
        convert(ply, tmp_path / "f.usdc", ConvertOptions(fps=0))
    outputs = {"p.usdc", "m.usdc", "x.abc", "e.ply", "s.ply", "z.ply", "f.usdc"}
    assert not outputs & {p.name for p in tmp_path.iterdir()}
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]


def test_cli(tmp_path, ply, capsys):
    out = tmp_path / "o.usdz"
    assert main(["convert", str(ply), "-o", str(out), "--up-axis", "Z", "--prim-path", "/World/Head"]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f"wrote {out}: 400 Gaussians") and "SH degree 3" in line and " s" in line
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and stage.GetPrimAtPath("/World/Head")
    assert main(["convert", str(out), "-o", str(tmp_path / "o.spz"), "-q", "--sh-degree", "1"]) == 0
    assert capsys.readouterr().out == ""
    assert read_spz(tmp_path / "o.spz").sh_degree == 1
    assert main(["convert", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "n.usdc")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "nope.ply" in err and "Traceback" not in err


def test_register_adds_formats_to_io(tmp_path):
    from avatarkit.gaussians import io, spz, usd
    usd.register()
    spz.register()
    gs = random_gaussians(20, sh_degree=1, seed=5)
    for name in ("a.usdz", "a.spz"):
        io.save_gaussians(tmp_path / name, gs)
        assert len(io.load_gaussians(tmp_path / name)) == 20
    np.testing.assert_array_equal(io.load_gaussians(tmp_path / "a.usdz").means, gs.means)
