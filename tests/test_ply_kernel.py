"""`read_ply`'s Taichi kernel against its numpy reference: same bits, same errors, same fallbacks.

(tests/test_ply.py also runs all of its tests through both decoders.)
"""
from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from avatarkit.errors import FormatError
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians import ply as ply_module
from avatarkit.gaussians.ply_header import read_ply_header
from avatarkit.gaussians.ply import read_ply

REST = {0: 0, 1: 9, 2: 24, 3: 45}
FIELDS = ("means", "quats", "scales", "opacities", "sh")


def raw_record(n: int, degree: int, seed: int = 0, *, normals=True, extras=()) -> np.ndarray:
    """INRIA-layout rows with raw values the way files hold them, rough edges included: unnormalised,
    zero and huge quaternions, extreme log scales and logits, subnormal and signed-zero SH
    coefficients (copied, never computed with)."""
    rng = np.random.default_rng(seed)
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals else [])
    names += ["f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(REST[degree])]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    dtype = [(name, "<f4") for name in names] + list(extras)
    rec = np.zeros(n, dtype)
    for name in names:
        rec[name] = rng.normal(size=n)
    for name in ("scale_0", "scale_1", "scale_2"):
        rec[name] = rng.uniform(-9, -1, n)
    q = rng.normal(size=(n, 4)) * rng.choice([1.0, 1e-3, 1e3], size=(n, 1))
    q[::7] /= np.linalg.norm(q[::7], axis=1, keepdims=True)  # already unit
    q[1::11] = 0.0                                           # zero -> identity
    q[3::17] = [3e18, -1e18, 2e18, 5e17]                     # squares overflow float32
    for i, name in enumerate(("rot_0", "rot_1", "rot_2", "rot_3")):
        rec[name] = q[:, i]
    if n > 8:
        rec["scale_0"][4] = 88.0     # exp ~1.65e38: still a float32
        rec["scale_1"][5] = -87.0    # exp ~1.6e-38: float32's smallest normals
        rec["opacity"][6] = 90.0     # sigmoid -> exactly 1
        rec["opacity"][7] = -750.0   # sigmoid -> 0
        rec["f_dc_0"][8] = -0.0
        rec["f_dc_1"][8] = 1e-42     # subnormal colour
    for name, dt in extras:
        rec[name] = rng.integers(0, 1000, n).astype(dt)
    return rec


def write(path, rec, *, byte_order="<", comment=""):
    data = PlyData([PlyElement.describe(rec, "vertex")], byte_order=byte_order)
    if comment:
        data.comments = [comment]
    data.write(str(path))
    return path


@pytest.fixture
def kernel_calls(monkeypatch):
    """Counts calls of the kernel path, so a test knows it took it."""
    calls = []
    real = ply_module._decode_with_kernel

    def spy(*args, **kwargs):
        result = real(*args, **kwargs)
        calls.append(result is not None)
        return result

    monkeypatch.setattr(ply_module, "_decode_with_kernel", spy)
    return calls


def assert_same_bits(a: GaussianSet, b: GaussianSet):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, name
        assert y.flags.c_contiguous and y.flags.writeable, name
        np.testing.assert_array_equal(x.view(np.uint32), y.view(np.uint32), err_msg=name)
    assert set(a.extras) == set(b.extras)
    for key in a.extras:
        assert a.extras[key].dtype == b.extras[key].dtype
        np.testing.assert_array_equal(a.extras[key], b.extras[key])


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("layout", ["inria", "no-normals", "extras", "odd-offset"])
def test_kernel_gives_the_reference_bits(tmp_path, kernel_calls, degree, layout):
    extras = [("binding_0", "<i4"), ("feat_0", "<f4"), ("feat_1", "<f4")] if layout == "extras" else ()
    rec = raw_record(3001, degree, seed=degree, normals=layout != "no-normals", extras=extras)
    path = write(tmp_path / "g.ply", rec)
    if layout == "odd-offset":  # a comment that puts the rows at an offset not a multiple of 4
        for length in range(1, 5):
            write(path, rec, comment="x" * length)
            if read_ply_header(path).data_offset % 4:
                break
        assert read_ply_header(path).data_offset % 4
    ref = read_ply(path, decoder="numpy")
    fast = read_ply(path, decoder="kernel")
    assert kernel_calls == [True]
    assert_same_bits(ref, fast)
    # the constructor's checks pass on the kernel's output and change nothing it made
    assert_same_bits(fast, GaussianSet(*(getattr(fast, f) for f in FIELDS), dict(fast.extras)))
    np.testing.assert_array_equal(fast.quats[1], [1, 0, 0, 0])


@pytest.mark.parametrize("name,value", [("scale_1", -103.0), ("opacity", -100.0), ("rot_2", 1e-40)])
def test_subnormal_arithmetic_is_left_to_the_reference(tmp_path, kernel_calls, name, value):
    # exp(-103) and sigmoid(-100) are float32 subnormals, and a subnormal quaternion component
    # counts: the kernel (flush-to-zero) flags the row and numpy decodes the file
    rec = raw_record(300, 1, seed=3)
    row = 23  # a zero quaternion in raw_record: (0, 0, 1e-40, 0) must become (0, 0, 1, 0)
    rec[name][row] = value
    path = write(tmp_path / "s.ply", rec)
    ref = read_ply(path, decoder="numpy")
    assert_same_bits(ref, read_ply(path, decoder="kernel"))
    assert kernel_calls == [False]
    if name == "rot_2":
        np.testing.assert_array_equal(ref.quats[row], [0, 0, 1, 0])
    else:
        kept = ref.scales[row, 1] if name == "scale_1" else ref.opacities[row]
        assert 0 < kept < np.finfo(np.float32).tiny


def test_taichi_leaves_numpy_arithmetic_alone():
    from avatarkit._taichi import ensure_taichi

    ensure_taichi()  # ti.init switches on flush-to-zero in this thread; we switch it off again
    assert np.float32(1e-42) * np.float32(1) > 0
    assert np.exp(np.float64(-103)).astype(np.float32) > 0


def test_kernel_threads_agree_with_one_pass_on_many_rows(tmp_path, kernel_calls):
    # enough rows that the parallel loop splits across threads and blocks
    rec = raw_record(200_003, 3, seed=9)
    path = write(tmp_path / "big.ply", rec)
    assert_same_bits(read_ply(path, decoder="numpy"), read_ply(path, decoder="kernel"))
    assert kernel_calls == [True]


@pytest.mark.parametrize("name,value", [
    ("x", np.nan), ("f_dc_2", np.inf), ("f_rest_44", -np.inf), ("f_rest_0", np.nan),
    ("opacity", np.nan), ("scale_1", np.inf), ("scale_2", 200.0), ("scale_0", -200.0),
    ("rot_3", np.nan), ("rot_0", np.inf)])
def test_bad_rows_read_as_the_reference_reports_them(tmp_path, kernel_calls, name, value):
    rec = raw_record(500, 3, seed=2)
    rec[name][321] = value
    rec[name][400] = value
    path = write(tmp_path / "bad.ply", rec)
    with pytest.raises(FormatError) as ref:
        read_ply(path, decoder="numpy")
    with pytest.raises(FormatError) as fast:
        read_ply(path, decoder="kernel")
    assert kernel_calls == [False]  # the kernel flagged a row and handed over
    assert str(fast.value) == str(ref.value)
    assert "321" in str(fast.value)


def test_nan_normals_are_ignored_by_both(tmp_path, kernel_calls):
    rec = raw_record(300, 1, seed=4)
    rec["ny"][10] = np.nan  # inside the span the kernel checks, but not a value we use
    path = write(tmp_path / "n.ply", rec)
    assert_same_bits(read_ply(path, decoder="numpy"), read_ply(path, decoder="kernel"))
    assert kernel_calls == [False]  # flagged, then the reference found nothing wrong


@pytest.mark.parametrize("variant", ["big-endian", "double", "rot-shuffled", "rgb", "uchar-extra"])
def test_layouts_the_kernel_cannot_take_fall_back(tmp_path, kernel_calls, variant):
    rec = raw_record(400, 2, seed=7)
    byte_order = "<"
    if variant == "big-endian":
        byte_order = ">"
    elif variant == "double":
        rec = rec.astype([(n, "<f8") for n in rec.dtype.names])
    elif variant == "rot-shuffled":
        names = list(rec.dtype.names)
        names[-4:] = ["rot_1", "rot_0", "rot_2", "rot_3"]
        rec = rec[names]
        rec = np.array(rec.tolist(), [(n, "<f4") for n in names])
    elif variant == "rgb":
        names = [n for n in rec.dtype.names if not n.startswith("f_dc")]
        out = np.zeros(len(rec), [(n, "<f4") for n in names] + [(c, "u1") for c in ("red", "green", "blue")])
        for n in names:
            out[n] = rec[n]
        out["red"] = 200
        rec = out
    else:
        out = np.zeros(len(rec), rec.dtype.descr + [("part", "u1")])
        for n in rec.dtype.names:
            out[n] = rec[n]
        rec = out
    path = write(tmp_path / "v.ply", rec, byte_order=byte_order)
    assert_same_bits(read_ply(path, decoder="numpy"), read_ply(path, decoder="kernel"))
    assert kernel_calls == []


class FakeTable:
    def __init__(self, rows: int, row_bytes: int):
        self.rows = rows
        self.raw = np.broadcast_to(np.zeros(1, np.uint8), (rows, row_bytes))

    def __len__(self):
        return self.rows


def test_auto_takes_the_kernel_only_when_it_pays(monkeypatch):
    import avatarkit._taichi as taichi_mod

    monkeypatch.setattr(ply_module, "_loaded_layouts", set())
    layout = ("inria", 16)
    pays = ply_module._kernel_pays
    monkeypatch.setattr(taichi_mod, "taichi_running", lambda: False)
    assert pays(FakeTable(100, 248), "kernel", layout)               # asked for
    assert not pays(FakeTable(1_000_000, 248), "auto", layout)       # 248 MB: start-up not paid
    assert pays(FakeTable(6_000_000, 248), "auto", layout)           # 1.5 GB: paid
    monkeypatch.setattr(taichi_mod, "taichi_running", lambda: True)
    assert not pays(FakeTable(1_000_000, 248), "auto", layout)       # the kernel load is not paid
    assert pays(FakeTable(2_000_000, 248), "auto", layout)
    ply_module._loaded_layouts.add(layout)
    assert pays(FakeTable(20_000, 248), "auto", layout)              # loaded: nothing unpaid
    assert not pays(FakeTable(1000, 248), "auto", layout)            # too few rows for a launch
    assert not pays(FakeTable(20_000, 248), "auto", ("other", 16))


def test_auto_uses_the_kernel_once_loaded(tmp_path, kernel_calls, monkeypatch):
    monkeypatch.setattr(ply_module, "_loaded_layouts", set())
    path = write(tmp_path / "g.ply", raw_record(ply_module.KERNEL_MIN_ROWS, 0, seed=1))
    read_ply(path)  # auto, kernel not loaded: numpy
    assert kernel_calls == []
    read_ply(path, decoder="kernel")
    read_ply(path)  # auto, now loaded
    assert kernel_calls == [True, True]


def test_unknown_decoder_is_a_value_error(tmp_path):
    with pytest.raises(ValueError, match="decoder"):
        read_ply(tmp_path / "x.ply", decoder="fast")


def test_sequence_decoder_weighs_all_the_files(tmp_path, monkeypatch):
    paths = [write(tmp_path / f"f{i}.ply", raw_record(50, 0, seed=i)) for i in range(3)]
    assert ply_module.sequence_decoder(paths) == "auto"  # a few KB pay nothing
    total = sum(p.stat().st_size for p in paths)
    # at a saving that just pays Taichi's start and the load over these bytes, take the kernel
    unpaid = ply_module.TAICHI_START_S + ply_module.KERNEL_LOAD_S
    import avatarkit._taichi as taichi_mod

    monkeypatch.setattr(taichi_mod, "taichi_running", lambda: False)
    monkeypatch.setattr(ply_module, "KERNEL_SAVES_S_PER_BYTE", unpaid / total * (1 + 1e-9))
    assert ply_module.sequence_decoder(paths) == "kernel"
    assert ply_module.sequence_decoder(paths[:2]) == "auto"
