"""3DGS PLY read/write: round trips, plyfile as the peer reader/writer, bad input, fuzzing.

Every test here runs twice, with the numpy reference decoder and with the Taichi kernel, and
the kernel variant fails unless the kernel actually ran (see `decoder` and `kernel_ran`);
tests whose files the kernel can never take (`NUMPY_ONLY`) run once."""
from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement

from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians import ply as ply_module
from avatarkit.gaussians.io import load_gaussians, register_format, save_gaussians
from avatarkit.gaussians.ply import OPACITY_EPS, read_ply, write_ply
from avatarkit.gaussians.ply_header import parse_header, read_ply_header
from avatarkit.gaussians.ply_table import VertexTable, read_ply_arrays
from avatarkit.gaussians.sh import SH_C0
from helpers import random_gaussians

SH_REST = {0: 0, 1: 9, 2: 24, 3: 45}


#: calls of the kernel decoder in this process (the spy below counts them)
KERNEL_CALLS = []


@pytest.fixture(scope="module", params=["numpy", "kernel"], autouse=True)
def decoder(request):
    """The decoder `read_ply`'s default ("auto") picks in this module's tests: the files here
    are small, so left alone it would always pick numpy. Module-scoped for hypothesis. The
    kernel decoder is wrapped by a spy that counts its calls."""
    real = ply_module._decode_with_kernel

    def spy(*args, **kwargs):
        KERNEL_CALLS.append(1)
        return real(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ply_module, "_kernel_pays", lambda *args: request.param == "kernel")
        mp.setattr(ply_module, "_decode_with_kernel", spy)
        yield request.param


@pytest.fixture(autouse=True)
def kernel_ran(request, decoder):
    """A [kernel] variant must run the kernel at least once; tests whose files it can never
    take run with numpy only (`NUMPY_ONLY`)."""
    before = len(KERNEL_CALLS)
    yield
    if decoder == "kernel":
        assert len(KERNEL_CALLS) > before, f"{request.node.name} never ran the kernel decoder"


#: for tests whose files the kernel never reads (text or big-endian rows, doubles, rgb colour,
#: files refused before the rows are decoded): one variant, not a second copy of the first
NUMPY_ONLY = pytest.mark.parametrize("decoder", ["numpy"], indirect=True)


def inria_names(degree: int) -> list[str]:
    """The INRIA property order, spelled out independently of the code under test."""
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(SH_REST[degree])]
    return names + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def inria_record(gs: GaussianSet) -> np.ndarray:
    """A structured array in the INRIA layout built the way 3DGS's save_ply does it."""
    n, k = len(gs), gs.sh.shape[1]
    f_rest = gs.sh[:, 1:].transpose(0, 2, 1).reshape(n, -1)  # (N, 3*(K-1)) channel-major
    o = np.clip(gs.opacities.astype(np.float64), OPACITY_EPS, 1 - OPACITY_EPS)
    cols = [gs.means, np.zeros((n, 3)), gs.sh[:, 0], f_rest, np.log(o / (1 - o))[:, None],
            np.log(gs.scales.astype(np.float64)), gs.quats]
    values = np.concatenate(cols, axis=1).astype(np.float32)
    rec = np.empty(n, [(name, "f4") for name in inria_names(gs.sh_degree)])
    for i, name in enumerate(rec.dtype.names):
        rec[name] = values[:, i]
    return rec


def write_with_plyfile(path, rec: np.ndarray, *, text=False, byte_order="<", before=(), after=()):
    elements = [*before, PlyElement.describe(rec, "vertex"), *after]
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))
    return path


def assert_same(a: GaussianSet, b: GaussianSet, *, exact_sh=True):
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.quats, b.quats)
    # scales pass through log (float64) -> float32 -> exp: a float32 rounding in log space
    np.testing.assert_allclose(a.scales, b.scales, rtol=2e-6)
    np.testing.assert_allclose(a.opacities, b.opacities, atol=2e-7)
    if exact_sh:
        np.testing.assert_array_equal(a.sh, b.sh)
    assert set(a.extras) == set(b.extras)
    for key in a.extras:
        np.testing.assert_array_equal(a.extras[key], b.extras[key])


# --- round trips ------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_exact(tmp_path, degree):
    # with a uchar extra the rows are not whole 4-byte words: the kernel leaves those to numpy
    for extras in (("binding", "part", "feat", "weight"), ("binding", "feat", "weight")):
        gs = random_gaussians(300, degree, seed=degree, extras=extras)
        path = tmp_path / "g.ply"
        write_ply(path, gs)
        back = read_ply(path)
        assert back.sh_degree == degree
        assert_same(back, gs)
        for key, value in gs.extras.items():
            assert back.extras[key].dtype == value.dtype and back.extras[key].shape == value.shape


def test_round_trip_many_blocks_and_unaligned_data(tmp_path):
    # > one gather block (~2 MB of rows) with a partial last block; a header comment of odd
    # length puts the float data at an unaligned file offset
    gs = random_gaussians(20_011, 3, seed=5, extras=("binding",))
    path = tmp_path / "big.ply"
    write_ply(path, gs)
    data = path.read_bytes()
    odd = data.replace(b"element vertex", b"comment x\nelement vertex", 1)
    assert (len(odd) - len(data)) % 4 != 0
    (tmp_path / "odd.ply").write_bytes(odd)
    for p in (path, tmp_path / "odd.ply"):
        assert_same(read_ply(p), gs)


def test_round_trip_empty_and_single(tmp_path):
    for n in (0, 1):
        gs = random_gaussians(n, 1, seed=3, extras=("binding", "feat"))
        write_ply(tmp_path / "g.ply", gs)
        back = read_ply(tmp_path / "g.ply")
        assert len(back) == n and back.sh_degree == 1
        assert_same(back, gs)


def test_opacity_zero_and_one_stay_finite(tmp_path):
    gs = random_gaussians(4, 0).replace(opacities=np.array([0.0, 1.0, 0.5, 1e-9]))
    write_ply(tmp_path / "o.ply", gs)
    raw = read_ply_arrays(tmp_path / "o.ply")["opacity"]
    assert np.isfinite(raw).all()
    back = read_ply(tmp_path / "o.ply").opacities
    np.testing.assert_allclose(back, [OPACITY_EPS, 1 - OPACITY_EPS, 0.5, OPACITY_EPS], atol=1e-7)


@NUMPY_ONLY
def test_write_is_atomic_and_checks_extras(tmp_path):
    gs = random_gaussians(5, 0)
    target = tmp_path / "out.ply"
    bad_extras = [
        {"big": np.full(5, 2**40, np.int64)},          # does not fit int32
        {"cube": np.zeros((5, 2, 2), np.float32)},     # PLY columns are (N,) or (N, m)
        {"text": np.array(["a"] * 5)},                 # not a PLY type
        {"opacity": np.zeros(5, np.float32)},          # clashes with a core property
        {"scale": np.zeros((5, 3), np.float32)},       # would write scale_0..2 twice
    ]
    for extras in bad_extras:
        with pytest.raises(InputError):
            write_ply(target, gs.replace(extras=extras))
        assert not target.exists()
        assert list(tmp_path.iterdir()) == []  # no temporary file left behind
    with pytest.raises(OutputError):
        write_ply(tmp_path / "no" / "such" / "dir.ply", gs)


@NUMPY_ONLY
def test_int64_and_bool_extras_are_narrowed(tmp_path):
    gs = random_gaussians(6, 0, extras={"binding": np.arange(6, dtype=np.int64),
                                        "mask": np.array([1, 0, 1, 0, 0, 1], bool)})
    write_ply(tmp_path / "e.ply", gs)
    props = {p.name: p.dtype for p in read_ply_header(tmp_path / "e.ply").element("vertex").properties}
    assert props["binding"] == "i4" and props["mask"] == "u1"
    back = read_ply(tmp_path / "e.ply")
    np.testing.assert_array_equal(back.extras["binding"], np.arange(6))
    np.testing.assert_array_equal(back.extras["mask"], [1, 0, 1, 0, 0, 1])


# --- our files, read by plyfile -------------------------------------------------------------
@NUMPY_ONLY
@pytest.mark.parametrize("degree", [0, 3])
def test_plyfile_reads_our_files(tmp_path, degree):
    gs = random_gaussians(200, degree, seed=11, extras=("binding", "feat"))
    path = tmp_path / "g.ply"
    write_ply(path, gs)
    ply = PlyData.read(str(path))
    assert [e.name for e in ply.elements] == ["vertex"]
    assert not ply.text and ply.byte_order == "<"
    v = ply["vertex"].data
    extra_names = ["binding", "feat_0", "feat_1", "feat_2", "feat_3"]
    assert list(v.dtype.names) == inria_names(degree) + extra_names
    assert all(v.dtype[name] == np.dtype("<f4") for name in inria_names(degree))
    assert v.dtype["binding"] == np.dtype("<i4")

    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], 1), gs.means)
    np.testing.assert_array_equal(np.stack([v[f"rot_{i}"] for i in range(4)], 1), gs.quats)
    np.testing.assert_array_equal(np.stack([v["nx"], v["ny"], v["nz"]], 1), 0)
    np.testing.assert_allclose(np.exp(np.stack([v[f"scale_{i}"] for i in range(3)], 1)),
                               gs.scales, rtol=2e-6)
    np.testing.assert_allclose(1 / (1 + np.exp(-v["opacity"].astype(np.float64))),
                               gs.opacities, atol=2e-7)
    np.testing.assert_array_equal(np.stack([v[f"f_dc_{i}"] for i in range(3)], 1), gs.sh[:, 0])
    k = gs.sh.shape[1]
    for c in range(3):  # channel-major: f_rest index = c*(K-1) + (j-1)
        for j in range(1, k):
            np.testing.assert_array_equal(v[f"f_rest_{c * (k - 1) + j - 1}"], gs.sh[:, j, c])
    np.testing.assert_array_equal(v["binding"], gs.extras["binding"])
    np.testing.assert_array_equal(np.stack([v[f"feat_{i}"] for i in range(4)], 1), gs.extras["feat"])


@NUMPY_ONLY
def test_read_ply_arrays_matches_plyfile(tmp_path):
    gs = random_gaussians(50, 2, extras=("part",))
    write_ply(tmp_path / "g.ply", gs)
    v = PlyData.read(str(tmp_path / "g.ply"))["vertex"].data
    arrays = read_ply_arrays(tmp_path / "g.ply")
    assert list(arrays) == list(v.dtype.names)
    for name in v.dtype.names:
        assert arrays[name].dtype == v.dtype[name]
        np.testing.assert_array_equal(arrays[name], v[name])


# --- files written by plyfile -----------------------------------------------------------------
@pytest.mark.parametrize("text,byte_order", [(False, "<"), (True, "=")])
@pytest.mark.parametrize("degree", [0, 3])
def test_reads_plyfile_inria_layout(tmp_path, text, byte_order, degree):
    _inria_layout_case(tmp_path, text, byte_order, degree)


@NUMPY_ONLY  # the kernel reads little-endian rows only
@pytest.mark.parametrize("degree", [0, 3])
def test_reads_plyfile_inria_layout_big_endian(tmp_path, degree):
    _inria_layout_case(tmp_path, False, ">", degree)


def _inria_layout_case(tmp_path, text, byte_order, degree):
    gs = random_gaussians(120, degree, seed=degree + 7)
    path = write_with_plyfile(tmp_path / "p.ply", inria_record(gs), text=text, byte_order=byte_order)
    header = read_ply_header(path)
    assert header.format == {"<": "binary_little_endian", ">": "binary_big_endian",
                             "=": "ascii"}[byte_order]
    assert_same(read_ply(path), gs)


@NUMPY_ONLY
def test_reads_doubles_shuffled_order_without_normals(tmp_path):
    gs = random_gaussians(80, 2, seed=4)
    rec = inria_record(gs)
    names = [n for n in rec.dtype.names if n not in ("nx", "ny", "nz")]
    order = np.random.default_rng(0).permutation(names)
    shuffled = np.empty(len(rec), [(n, "f8") for n in order])
    for n in order:
        shuffled[n] = rec[n]
    path = write_with_plyfile(tmp_path / "s.ply", shuffled)
    assert_same(read_ply(path), gs)  # float32 -> float64 -> float32 is exact


@NUMPY_ONLY
def test_reads_extras_with_their_dtypes(tmp_path):
    gs = random_gaussians(40, 1, seed=9)
    rec = inria_record(gs)
    rng = np.random.default_rng(1)
    binding = rng.integers(0, 5000, len(gs)).astype(np.int32)
    label = rng.integers(0, 255, len(gs)).astype(np.uint8)
    uv = rng.normal(size=(len(gs), 2))
    extra = np.empty(len(gs), rec.dtype.descr + [("binding_0", "<i4"), ("label", "u1"),
                                                 ("uv_0", "<f8"), ("uv_1", "<f8"),
                                                 ("odd_3", "<i2"), ("mixed_0", "<f4"),
                                                 ("mixed_1", "<i4")])
    for n in rec.dtype.names:
        extra[n] = rec[n]
    extra["binding_0"], extra["label"], extra["uv_0"], extra["uv_1"] = binding, label, uv[:, 0], uv[:, 1]
    extra["odd_3"], extra["mixed_0"], extra["mixed_1"] = 7, 1.5, 3
    for text in (False, True):
        back = read_ply(write_with_plyfile(tmp_path / f"e{text}.ply", extra, text=text))
        assert list(back.extras) == ["binding", "label", "uv", "odd_3", "mixed_0", "mixed_1"]
        np.testing.assert_array_equal(back.extras["binding"], binding)
        assert back.extras["binding"].dtype == np.int32 and back.extras["binding"].shape == (40,)
        np.testing.assert_array_equal(back.extras["label"], label)
        assert back.extras["label"].dtype == np.uint8
        np.testing.assert_array_equal(back.extras["uv"], uv)
        assert back.extras["uv"].dtype == np.float64
        assert back.extras["odd_3"].dtype == np.int16 and (back.extras["odd_3"] == 7).all()
        assert back.extras["mixed_1"].dtype == np.int32
        assert_same(back.replace(extras={}), gs)


@NUMPY_ONLY
def test_reads_rgb_uchar_colours(tmp_path):
    gs = random_gaussians(30, 0, seed=2)
    rec = inria_record(gs)
    rgb = np.random.default_rng(3).integers(0, 256, (len(gs), 3)).astype(np.uint8)
    names = [n for n in rec.dtype.names if not n.startswith(("f_dc", "nx", "ny", "nz"))]
    out = np.empty(len(gs), [(n, "f4") for n in names] + [(c, "u1") for c in ("red", "green", "blue")])
    for n in names:
        out[n] = rec[n]
    out["red"], out["green"], out["blue"] = rgb.T
    back = read_ply(write_with_plyfile(tmp_path / "rgb.ply", out))
    np.testing.assert_allclose(back.colors, rgb / 255.0, atol=1e-6)
    np.testing.assert_allclose(back.sh[:, 0], (rgb / 255.0 - 0.5) / SH_C0, atol=1e-5)
    assert back.extras == {}


def test_normalises_quaternions_zero_becomes_identity(tmp_path):
    gs = random_gaussians(5, 0)
    rec = inria_record(gs)
    q = np.array([[2, 0, 0, 0], [0, 0, 0, 0], [1, 1, 1, 1], [0, -3, 0, 4], [1e-30, 0, 0, 0]], np.float32)
    for i in range(4):
        rec[f"rot_{i}"] = q[:, i]
    back = read_ply(write_with_plyfile(tmp_path / "q.ply", rec))
    expect = [[1, 0, 0, 0], [1, 0, 0, 0], [0.5, 0.5, 0.5, 0.5], [0, -0.6, 0, 0.8], [1, 0, 0, 0]]
    np.testing.assert_allclose(back.quats, expect, atol=1e-7)


def test_skips_other_elements(tmp_path):
    gs = random_gaussians(25, 1, seed=8)
    rec = inria_record(gs)
    faces = np.empty(7, [("vertex_indices", "O")])
    faces["vertex_indices"] = [np.array([0, 1, 2], np.int32)] * 7
    cams = np.zeros(3, [("fx", "f8"), ("id", "u1")])
    for text in (False, True):
        for before, after in [((), (faces,)), ((cams,), (faces,)), ((cams, faces), ()),
                              ((faces,), (cams,))]:
            els = [PlyElement.describe(e, "face" if e.dtype.names[0] == "vertex_indices" else "camera")
                   for e in (*before, *after)]
            path = write_with_plyfile(tmp_path / "m.ply", rec, text=text,
                                      before=els[:len(before)], after=els[len(before):])
            assert_same(read_ply(path), gs)


def test_variable_lists_before_vertex_are_a_clear_error(tmp_path):
    gs = random_gaussians(5, 0)
    faces = np.empty(2, [("vertex_indices", "O")])
    faces["vertex_indices"] = [np.array([0, 1, 2], np.int32), np.array([0, 1, 2, 3], np.int32)]
    path = write_with_plyfile(tmp_path / "v.ply", inria_record(gs),
                              before=[PlyElement.describe(faces, "face")])
    with pytest.raises(FormatError, match="varies in length"):
        read_ply(path)
    # the same element after the vertex element is never read, and ASCII skips it by lines
    assert_same(read_ply(write_with_plyfile(tmp_path / "w.ply", inria_record(gs),
                                            after=[PlyElement.describe(faces, "face")])), gs)
    assert_same(read_ply(write_with_plyfile(tmp_path / "t.ply", inria_record(gs), text=True,
                                            before=[PlyElement.describe(faces, "face")])), gs)


# --- bad input --------------------------------------------------------------------------------
HEADER = ("ply\nformat binary_little_endian 1.0\nelement vertex {n}\n"
          + "".join(f"property float {p}\n" for p in inria_names(0)) + "end_header\n")


def good_bytes(n=3, degree=0, seed=0) -> bytes:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "g.ply"
        write_ply(path, random_gaussians(n, degree, seed=seed, extras=("binding",)))
        return path.read_bytes()


def expect_format_error(tmp_path, data: bytes, match: str, name="bad.ply"):
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(FormatError, match=match) as info:
        read_ply(path)
    assert str(info.value).startswith(str(path) + ": ")
    return info.value


@NUMPY_ONLY
def test_empty_and_non_ply(tmp_path):
    expect_format_error(tmp_path, b"", "empty file")
    expect_format_error(tmp_path, b"\x89PNG\r\n\x1a\n" + bytes(100), "not a PLY file")
    expect_format_error(tmp_path, b"solid cube\nfacet normal 0 0 1\n", "not a PLY file")
    expect_format_error(tmp_path, b"ply\nformat binary_little_endian 1.0\n", "no 'end_header'")


@NUMPY_ONLY
def test_truncated_data(tmp_path):
    data = good_bytes(10, 2)
    for cut in (1, 7, 250):
        expect_format_error(tmp_path, data[:-cut], "truncated")


@NUMPY_ONLY
def test_absurd_and_negative_counts(tmp_path):
    for n, match in [(10**12, "truncated"), (2**64 + 5, "truncated"), (-1, "negative count"),
                     ("12abc", "not an integer")]:
        data = HEADER.format(n=n).encode() + bytes(1000)
        expect_format_error(tmp_path, data, match)
    ascii_header = HEADER.replace("binary_little_endian", "ascii").format(n=10**12)
    expect_format_error(tmp_path, ascii_header.encode() + b"0 " * 500, "truncated")


@NUMPY_ONLY
def test_header_problems(tmp_path):
    good = HEADER.format(n=1)
    cases = [
        (good.replace("property float x\n", "property float128 x\n"), "unknown property type"),
        (good.replace("property float x\n", "property list uchar int x\n"), "'x' is a list"),
        (good.replace("property float x\n", "property list float int x\n"), "not an integer type"),
        (good.replace("property float x\n", "property int x\n"), "'x' has integer type"),
        (good.replace("format binary_little_endian 1.0", "format binary_middle_endian 1.0"),
         "bad format"),
        (good.replace("format binary_little_endian 1.0\n", ""), "no 'format' line"),
        (good.replace("element vertex 1\n", "element vertex 1\nwibble\n"), "unknown keyword"),
        (good.replace("element vertex 1", "element point 1"), "no 'vertex' element"),
        (good.replace("property float y\n", "property float x\n"), "declared twice"),
        ("ply\nformat ascii 1.0\ncomment caf\u00e9\nend_header\n", "non-ASCII"),
        ("ply\nformat ascii 1.0\n" + "comment " + "x" * 70000 + "\nend_header\n", "64 KiB"),
    ]
    for header, match in cases:
        expect_format_error(tmp_path, header.encode("utf-8") + bytes(100), match)


@NUMPY_ONLY
@pytest.mark.parametrize("missing,match", [
    (("x",), "position property x"),
    (("rot_0", "rot_3"), "rotation properties rot_0 rot_3"),
    (("scale_1",), "scale property scale_1"),
    (("opacity",), "opacity property opacity"),
    (("f_dc_0",), "no colour"),
    (("f_rest_4",), "8 f_rest"),
])
def test_missing_properties(tmp_path, missing, match):
    rec = inria_record(random_gaussians(4, 1))
    keep = [n for n in rec.dtype.names if n not in missing]
    cut = np.empty(len(rec), [(n, "f4") for n in keep])
    for n in keep:
        cut[n] = rec[n]
    path = write_with_plyfile(tmp_path / "m.ply", cut)
    with pytest.raises(FormatError, match=match) as info:
        read_ply(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("name,value", [("y", np.nan), ("rot_2", np.inf), ("scale_0", np.nan),
                                        ("opacity", -np.inf), ("f_dc_1", np.nan),
                                        ("f_rest_3", np.inf), ("binding_f", np.nan)])
def test_non_finite_values_name_property_and_row(tmp_path, name, value):
    gs = random_gaussians(6, 1)
    rec = inria_record(gs)
    out = np.empty(len(rec), rec.dtype.descr + [("binding_f", "<f4")])
    for n in rec.dtype.names:
        out[n] = rec[n]
    out["binding_f"] = 1.0
    out[name][4] = value
    for text in (False, True):
        path = write_with_plyfile(tmp_path / f"nan{text}.ply", out, text=text)
        with pytest.raises(FormatError, match=rf"property '{name}' .* at vertex 4"):
            read_ply(path)


def test_double_overflowing_float32_and_huge_log_scale(tmp_path):
    rec = inria_record(random_gaussians(3, 0))
    doubled = np.empty(len(rec), [(n, "f8") for n in rec.dtype.names])
    for n in rec.dtype.names:
        doubled[n] = rec[n]
    doubled["z"][1] = 1e300
    with pytest.raises(FormatError, match="property 'z'.*vertex 1"):
        read_ply(write_with_plyfile(tmp_path / "d.ply", doubled))
    rec["scale_2"][2] = 200.0  # exp(200) is inf in float32
    with pytest.raises(FormatError, match="vertex 2"):
        read_ply(write_with_plyfile(tmp_path / "s.ply", rec))


@NUMPY_ONLY
def test_bad_ascii_values(tmp_path):
    good = HEADER.replace("binary_little_endian", "ascii").format(n=2)
    row = " ".join(["0.5"] * 17)
    expect_format_error(tmp_path, (good + row + "\n" + row + " 1\n").encode(), "bad ASCII")
    expect_format_error(tmp_path, (good + row + "\n" + row.replace("0.5", "abc", 1) + "\n").encode(),
                        "bad ASCII")
    expect_format_error(tmp_path, (good + row + "\n").encode(), "truncated")


@NUMPY_ONLY
def test_missing_file_and_folder_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_ply(tmp_path / "nope.ply")
    with pytest.raises(InputError, match="folder"):
        read_ply(tmp_path)


# --- fuzzing -------------------------------------------------------------------------------
GOOD_BINARY = good_bytes(4, 1, seed=1)
GOOD_ASCII = HEADER.replace("binary_little_endian", "ascii").format(n=2).encode() + \
    (" ".join(["0.25"] * 17) + "\n").encode() * 2
HEADER_EDITS = [b"-1", b"99999999999999", b"0", b"1", b"list uchar int", b"double", b"uchar",
                b"ascii", b"binary_big_endian", b"\n", b"end_header\n", b"element face 3\n",
                b"property float x\n", b"", b"nan", b"\xff", b"vertex"]


def _read_or_format_error(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.ply"
        path.write_bytes(data)
        try:
            gs = read_ply(path)
        except FormatError as e:
            assert str(path) in str(e)
        else:
            assert isinstance(gs, GaussianSet)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from([GOOD_BINARY, GOOD_ASCII]), st.data())
def test_fuzz_only_format_errors(base, data):
    # "rows": bytes changed after the header only, so the rows reach a decoder (the [kernel]
    # variant must run the kernel: with "mutate" alone ~9 % of binary cases got past the
    # header, and one run in three or four drew none)
    kind = data.draw(st.sampled_from(["truncate", "mutate", "header", "rows"]))
    buf = bytearray(base)
    if kind == "truncate":
        del buf[data.draw(st.integers(0, len(buf))):]
    elif kind in ("mutate", "rows"):
        first = base.index(b"end_header\n") + len(b"end_header\n") if kind == "rows" else 0
        for _ in range(data.draw(st.integers(1, 8))):
            buf[data.draw(st.integers(min(first, len(buf) - 1), len(buf) - 1))] = data.draw(st.integers(0, 255))
    else:
        end = base.index(b"end_header")
        tokens = [m.span() for m in re.finditer(rb"\S+", base[:end])]
        start, stop = tokens[data.draw(st.integers(0, len(tokens) - 1))]
        buf[start:stop] = data.draw(st.sampled_from(HEADER_EDITS))
    _read_or_format_error(bytes(buf))


# --- fast path vs reference ------------------------------------------------------------------
PLY_NAMES = {"f4": "float", "f8": "double", "i4": "int", "u4": "uint", "u1": "uchar", "i2": "short"}


@NUMPY_ONLY
def test_gather_matches_reference_columns():
    rng = np.random.default_rng(0)
    for byte_order in "<>":
        for types in (["f4"] * 6, ["f4", "i4", "u4", "f4", "f4", "i4"], ["f8", "u1", "f4", "i2", "f4", "f8"]):
            dtype = np.dtype([(f"p{i}", byte_order + t) for i, t in enumerate(types)])
            rec = np.zeros(10_000, dtype)
            for name in dtype.names:
                rec[name] = rng.integers(0, 100, len(rec))
            props = parse_header(
                ("ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                 + "".join(f"property {PLY_NAMES[t]} p{i}\n" for i, t in enumerate(types))
                 + "end_header\n").encode(), "x").elements[0].properties
            table = VertexTable(rec.view(np.uint8).reshape(len(rec), -1), props, byte_order)
            groups = [["p0", "p3", "p4"], ["p4", "p0"], ["p1"], ["p5", "p2"]]
            groups = [g for g in groups if len({table.dtypes[c] for c in g}) == 1]
            for g, got in zip(groups, table.gather(groups)):
                want = np.stack([rec[c] for c in g], 1)
                assert got.flags.c_contiguous and got.dtype.isnative
                np.testing.assert_array_equal(got, want)


# --- dispatch (avatarkit.gaussians.io) ------------------------------------------------------
def test_load_save_dispatch(tmp_path):
    gs = random_gaussians(10, 1, extras=("binding",))
    save_gaussians(tmp_path / "a.PLY", gs)
    assert_same(load_gaussians(tmp_path / "a.PLY"), gs)
    with pytest.raises(InputError, match=r"\.ply"):
        load_gaussians(tmp_path / "a.xyz")
    with pytest.raises(OutputError, match=r"\.ply"):
        save_gaussians(tmp_path / "a.xyz", gs)


def test_register_format(tmp_path, monkeypatch):
    from avatarkit.gaussians import io

    monkeypatch.setattr(io, "_loaders", dict(io._loaders))
    monkeypatch.setattr(io, "_savers", dict(io._savers))
    saved = {}
    register_format("npzsplat", loader="avatarkit.gaussians.ply:read_ply",
                    saver=lambda path, g, **kw: saved.update(path=path, n=len(g), **kw))
    save_gaussians(tmp_path / "x.npzsplat", gs := random_gaussians(3), flag=1)
    assert saved == {"path": tmp_path / "x.npzsplat", "n": 3, "flag": 1}
    write_ply(tmp_path / "y.npzsplat", gs)  # the string loader resolves to read_ply
    assert_same(load_gaussians(tmp_path / "y.npzsplat"), gs)
    assert ".npzsplat" in io.loadable_extensions()


def test_crlf_line_endings(tmp_path):
    gs = random_gaussians(6, 1, seed=12)
    binary = tmp_path / "b.ply"
    write_ply(binary, gs)
    data = binary.read_bytes()
    end = data.index(b"end_header\n")
    (tmp_path / "b_crlf.ply").write_bytes(data[:end].replace(b"\n", b"\r\n") + b"end_header\r\n"
                                          + data[end + len(b"end_header\n"):])
    assert_same(read_ply(tmp_path / "b_crlf.ply"), gs)
    text = write_with_plyfile(tmp_path / "t.ply", inria_record(gs), text=True).read_bytes()
    (tmp_path / "t_crlf.ply").write_bytes(text.replace(b"\n", b"\r\n"))
    assert_same(read_ply(tmp_path / "t_crlf.ply"), gs)


def test_results_never_view_the_file(tmp_path):
    # mixed value sizes take the reference path (both variants), whole words the variant's
    # decoder; a 1-row view would be "contiguous" already
    for extras in (("part", "weight"), ("weight",)):
        gs = random_gaussians(1, 1, extras=extras)
        write_ply(tmp_path / "one.ply", gs)
        back = read_ply(tmp_path / "one.ply")
        for a in (back.means, back.quats, back.scales, back.opacities, back.sh, *back.extras.values()):
            assert a.flags.writeable
        os.replace(tmp_path / "one.ply", tmp_path / "moved.ply")
        (tmp_path / "moved.ply").write_bytes(b"")  # truncating the file must not affect the set
        back.means[0] += 1
        np.testing.assert_array_equal(back.means, gs.means + 1)


@NUMPY_ONLY
def test_a_huge_f_rest_index_is_a_format_error(decoder, tmp_path):
    """A damaged header naming f_rest_99999999999 (the fuzz tests' find) is refused with the
    indices named, not a MemoryError while describing them."""
    names = inria_names(0) + ["f_rest_0", "f_rest_99999999999"]
    rec = np.zeros(3, [(name, "f4") for name in names])
    path = write_with_plyfile(tmp_path / "huge.ply", rec)
    with pytest.raises(FormatError, match=r"2 f_rest_\* properties \(indices 0,99999999999\)"):
        read_ply(path, decoder=decoder)
