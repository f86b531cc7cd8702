"""USD splat prims: writer layout (OpenUSD schema + NVIDIA conventions), reader, round trips, animation."""
from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdVol, Vt

from avatarkit.errors import FormatError, InputError
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.sh import SH_C0, SH_COUNTS
from avatarkit.gaussians.usd import UsdWriteOptions, create_stage, open_output_stage, save_usd, validate_stage
from avatarkit.gaussians.usd_prims import SplatPrimWriter
from avatarkit.gaussians.usd_read import find_splat_prims, load_usd, read_splat_prim
from helpers import random_gaussians

FIELDS = ("means", "quats", "scales", "opacities", "sh")


def assert_same(a: GaussianSet, b: GaussianSet):
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


@pytest.mark.parametrize("ext", [".usda", ".usdc", ".usd", ".usdz"])
@pytest.mark.parametrize("degree", [0, 3])
def test_float_round_trip_is_bit_exact(tmp_path, ext, degree):
    gs = random_gaussians(300, sh_degree=degree, seed=degree)
    path = tmp_path / f"s{ext}"
    save_usd(path, gs)
    back = load_usd(path)
    assert_same(gs, back)
    assert validate_stage(path) == []
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporaries left


def test_half_round_trip_within_half_precision(tmp_path):
    gs = random_gaussians(500, sh_degree=2, seed=3)
    path = tmp_path / "h.usdc"
    save_usd(path, gs, UsdWriteOptions(half=True))
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/Splats")
    for name in ("positionsh", "orientationsh", "scalesh", "opacitiesh",
                 "radiance:sphericalHarmonicsCoefficientsh"):
        assert prim.GetAttribute(name).HasAuthoredValue(), name
    for name in ("positions", "orientations", "scales", "opacities"):
        assert not prim.GetAttribute(name).HasAuthoredValue(), name
    back = load_usd(path)
    rel = 2.0 ** -11  # half has an 11-bit significand: relative rounding error <= 2^-11
    for f in ("means", "scales", "opacities", "sh"):
        a, b = getattr(gs, f), getattr(back, f)
        np.testing.assert_allclose(b, a, rtol=rel, atol=2.0 ** -24, err_msg=f)
    # quats are renormalised after rounding: compare as rotations
    dots = np.abs((gs.quats * back.quats).sum(axis=1))
    assert dots.min() > 1 - 1e-6
    assert validate_stage(path) == []


def test_half_rejects_values_beyond_half_range(tmp_path):
    gs = random_gaussians(10, seed=1)
    gs = gs.replace(means=gs.means + np.float32(1e5))
    path = tmp_path / "h.usda"
    path.write_text("old")
    with pytest.raises(InputError, match="half"):
        save_usd(path, gs, UsdWriteOptions(half=True))
    assert path.read_text() == "old"  # the old file is untouched
    assert len(list(tmp_path.iterdir())) == 1


def test_layout_matches_schema_and_nvidia_conventions(tmp_path):
    gs = random_gaussians(50, sh_degree=2, seed=4)
    path = tmp_path / "s.usda"
    save_usd(path, gs, UsdWriteOptions(prim_path="/World/Splats"))
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    assert stage.GetPrimAtPath("/World").GetTypeName() == "Xform"
    prim = stage.GetPrimAtPath("/World/Splats")
    assert prim.IsA(UsdVol.ParticleField3DGaussianSplat)
    q = prim.GetAttribute("orientations").Get()
    assert isinstance(q[0], Gf.Quatf)
    np.testing.assert_array_equal([q[i].GetReal() for i in range(3)], gs.quats[:3, 0])
    np.testing.assert_array_equal(np.array([q[0].GetImaginary()[i] for i in range(3)]), gs.quats[0, 1:])
    np.testing.assert_array_equal(np.asarray(prim.GetAttribute("scales").Get()), gs.scales)  # linear
    np.testing.assert_array_equal(np.asarray(prim.GetAttribute("opacities").Get()), gs.opacities)
    sh_attr = prim.GetAttribute("radiance:sphericalHarmonicsCoefficients")
    k = SH_COUNTS[2]
    assert sh_attr.GetMetadata("elementSize") == k
    assert sh_attr.GetMetadata("interpolation") == "vertex"
    assert prim.GetAttribute("radiance:sphericalHarmonicsDegree").Get() == 2
    # per particle, coefficient-major: particle 1's DC is entry k
    np.testing.assert_array_equal(np.asarray(sh_attr.Get())[k], gs.sh[1, 0])
    color = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    assert color.GetInterpolation() == "vertex"
    np.testing.assert_allclose(np.asarray(color.Get()), np.clip(0.5 + SH_C0 * gs.sh[:, 0], 0, 1), atol=1e-7)
    extent = np.asarray(prim.GetAttribute("extent").Get())
    np.testing.assert_array_equal(extent, [gs.means.min(0), gs.means.max(0)])
    # USD's text form writes the real part first: the file's first quaternion is w, x, y, z
    import re
    first = re.search(r"quatf\[\] orientations = \[\(([^)]*)\)", path.read_text()).group(1)
    np.testing.assert_allclose([float(v) for v in first.split(",")], gs.quats[0], rtol=1e-6)
    assert validate_stage(stage) == []


def test_z_up_turns_data_and_reads_back(tmp_path):
    gs = random_gaussians(200, sh_degree=3, seed=5)
    path = tmp_path / "z.usdc"
    save_usd(path, gs, UsdWriteOptions(up_axis="Z"))
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    raw = read_splat_prim(stage.GetPrimAtPath("/Splats"))
    x, y, z = gs.means.T
    np.testing.assert_array_equal(raw.means, np.stack([x, -z, y], 1))  # +90 degrees about X
    # a splat's up axis (its local +Y turned by q) becomes +Z on the stage
    from avatarkit.rotations import quat_to_matrix
    np.testing.assert_allclose(quat_to_matrix(raw.quats) @ [0, 0, 1],
                               (quat_to_matrix(gs.quats) @ [0, 0, 1])[:, [0, 2, 1]] * [1, -1, 1], atol=1e-6)
    back = load_usd(path)
    np.testing.assert_array_equal(back.means, gs.means)
    np.testing.assert_allclose(back.quats * np.sign((back.quats * gs.quats).sum(1, keepdims=True)),
                               gs.quats, atol=1e-6)
    np.testing.assert_allclose(back.sh, gs.sh, atol=1e-5)
    assert validate_stage(stage) == []


def _hand_stage(tmp_path, name="hand.usda", **attrs):
    stage = create_stage()
    prim = UsdVol.ParticleField3DGaussianSplat.Define(stage, "/P")
    stage.SetDefaultPrim(prim.GetPrim())
    for attr, value in attrs.items():
        prim.GetPrim().GetAttribute(attr.replace("__", ":")).Set(value)
    path = tmp_path / name
    stage.GetRootLayer().Export(str(path))
    return path


def test_reader_applies_schema_defaults(tmp_path):
    pts = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]], np.float32)
    path = _hand_stage(tmp_path, positions=Vt.Vec3fArray.FromNumpy(pts),
                       orientations=Vt.QuatfArray.FromNumpy(np.array([[0, 0, 0, 1]], np.float32)),  # too short
                       opacities=Vt.FloatArray([0.25, 0.5, 0.75, 1.0]))  # too long
    gs = load_usd(path)
    np.testing.assert_array_equal(gs.means, pts)
    np.testing.assert_array_equal(gs.quats, np.tile([1, 0, 0, 0], (3, 1)))  # ignored -> identity
    np.testing.assert_array_equal(gs.scales, np.ones((3, 3)))  # unit scale
    np.testing.assert_array_equal(gs.opacities, [0.25, 0.5, 0.75])  # truncated
    # no SH authored (degree falls back to 3 but coefficients are missing) -> grey 0.5
    assert gs.sh_degree == 0
    np.testing.assert_allclose(gs.colors, 0.5)


def test_reader_takes_half_and_keeps_bands_up_to_3(tmp_path):
    n, k = 4, 25  # SH degree 4: 25 coefficients per particle
    rng = np.random.default_rng(0)
    coeffs = rng.normal(size=(n * k, 3)).astype(np.float16)
    path = _hand_stage(tmp_path, positionsh=Vt.Vec3hArray.FromNumpy(np.ones((n, 3), np.float16)),
                       radiance__sphericalHarmonicsDegree=4,
                       radiance__sphericalHarmonicsCoefficientsh=Vt.Vec3hArray.FromNumpy(coeffs))
    gs = load_usd(path)
    assert gs.sh_degree == 3
    np.testing.assert_array_equal(gs.sh, coeffs.astype(np.float32).reshape(n, k, 3)[:, :16])


def test_float_attribute_preferred_over_half(tmp_path):
    path = _hand_stage(tmp_path, positions=Vt.Vec3fArray.FromNumpy(np.full((2, 3), 0.1, np.float32)),
                       positionsh=Vt.Vec3hArray.FromNumpy(np.full((2, 3), 7, np.float16)))
    np.testing.assert_array_equal(load_usd(path).means, np.full((2, 3), 0.1, np.float32))


def test_prim_selection_and_errors(tmp_path):
    a, b = random_gaussians(5, seed=1), random_gaussians(7, seed=2)
    path = tmp_path / "two.usda"
    with open_output_stage(path) as stage:
        SplatPrimWriter(stage, "/World/A").write(a)
        SplatPrimWriter(stage, "/World/B").write(b)
    with pytest.raises(InputError, match="/World/A, /World/B"):
        load_usd(path)
    assert len(load_usd(path, prim_path="/World/B")) == 7
    with pytest.raises(InputError, match="no ParticleField3DGaussianSplat prim at /World/C"):
        load_usd(path, prim_path="/World/C")

    mesh_only = tmp_path / "mesh.usda"
    stage = create_stage()
    UsdGeom.Mesh.Define(stage, "/M")
    stage.GetRootLayer().Export(str(mesh_only))
    with pytest.raises(FormatError, match="mesh.usda: has no ParticleField3DGaussianSplat prim"):
        load_usd(mesh_only)

    junk = tmp_path / "junk.usdc"
    junk.write_bytes(b"PXR-USDC" + bytes(40))
    with pytest.raises(FormatError, match="junk.usdc"):
        load_usd(junk)
    with pytest.raises(InputError, match="file not found"):
        load_usd(tmp_path / "missing.usd")


def test_reader_applies_world_transform_and_units(tmp_path):
    gs = random_gaussians(40, sh_degree=1, seed=6)
    stage = create_stage(meters_per_unit=0.01)  # centimetres
    xf = UsdGeom.Xform.Define(stage, "/World")
    xf.AddTranslateOp().Set(Gf.Vec3d(10, 20, 30))
    xf.AddRotateYOp().Set(90.0)
    xf.AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
    SplatPrimWriter(stage, "/World/S").write(gs)
    path = tmp_path / "xf.usda"
    stage.GetRootLayer().Export(str(path))

    ry = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float)  # +90 degrees about Y
    expect = gs.transform(rotation=ry, translation=0.01 * np.array([10, 20, 30]), scale=0.02)
    back = load_usd(path)
    np.testing.assert_allclose(back.means, expect.means, atol=1e-6)
    np.testing.assert_allclose(back.scales, expect.scales, rtol=1e-5)
    np.testing.assert_allclose(np.abs((back.quats * expect.quats).sum(1)), 1, atol=1e-6)
    np.testing.assert_allclose(back.sh, expect.sh, atol=1e-5)
    local = load_usd(path, world=False)
    np.testing.assert_array_equal(local.means, gs.means)

    xf.AddScaleOp(opSuffix="squash").Set(Gf.Vec3f(1, 0.5, 1))
    stage.GetRootLayer().Export(str(path))
    with pytest.raises(InputError, match="non-uniform scale"):
        load_usd(path)


def test_animated_writer_static_once_and_promotion(tmp_path):
    base = random_gaussians(100, sh_degree=1, seed=7)
    frames = []
    for i in range(5):
        f = base.replace(means=base.means + np.float32(0.01 * i))
        if i >= 3:  # opacities change from frame 3 on
            f = f.replace(opacities=base.opacities * np.float32(0.5))
        frames.append(f)
    path = tmp_path / "anim.usdc"
    with open_output_stage(path, fps=30, start=0, end=4) as stage:
        w = SplatPrimWriter(stage, "/Splats")
        for i, f in enumerate(frames):
            w.write(f, time=i)
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetEndTimeCode() == 4
    prim = stage.GetPrimAtPath("/Splats")
    assert prim.GetAttribute("positions").GetNumTimeSamples() == 5
    assert prim.GetAttribute("extent").GetNumTimeSamples() == 5
    assert prim.GetAttribute("radiance:sphericalHarmonicsCoefficients").GetNumTimeSamples() == 0
    assert prim.GetAttribute("opacities").GetNumTimeSamples() == 4  # promoted: frames 0, 2, 3, 4
    for i, f in enumerate(frames):
        assert_same(load_usd(path, time=i), f)
    assert validate_stage(stage) == []


def test_animated_writer_rejects_count_or_degree_change():
    stage = create_stage()
    w = SplatPrimWriter(stage, "/S")
    w.write(random_gaussians(10, seed=1), time=0)
    with pytest.raises(InputError, match="10"):
        w.write(random_gaussians(11, seed=1), time=1)
    with pytest.raises(InputError, match="SH degree"):
        w.write(random_gaussians(10, sh_degree=1, seed=1), time=1)
    one = SplatPrimWriter(stage, "/T")
    one.write(random_gaussians(3))
    with pytest.raises(InputError, match="only write"):
        one.write(random_gaussians(3), time=0)


def test_find_splat_prims_skips_inactive():
    stage = create_stage()
    SplatPrimWriter(stage, "/A").write(random_gaussians(2))
    SplatPrimWriter(stage, "/B").write(random_gaussians(2))
    stage.GetPrimAtPath("/B").SetActive(False)
    assert [str(p.GetPath()) for p in find_splat_prims(stage)] == ["/A"]


def test_bad_prim_path_and_extension(tmp_path):
    with pytest.raises(InputError, match="prim path"):
        SplatPrimWriter(create_stage(), "Splats")
    from avatarkit.errors import OutputError
    with pytest.raises(OutputError, match="unknown USD extension"):
        save_usd(tmp_path / "x.abc", random_gaussians(2))
