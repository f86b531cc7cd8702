"""`avatarkit view`: the codes (round-trip bounds), the page's data layout, --max-size, the
readers of every kind of bake, and bad input. The browser itself: test_web_player_browser.py."""
from __future__ import annotations

import json

import numpy as np
import pytest

from avatarkit.cli.main import main
from avatarkit.errors import InputError, OutputError
from avatarkit.export import quantize as qz
from avatarkit.export.ply_sequence import PlySequenceWriter
from avatarkit.export.splat_frames import open_splat_frames
from avatarkit.export.web_player import (PlayerOptions, decode_player, delta_bytes, delta_planes,
                                         delta_quat_words, encode_frames, kabsch_rotation, pack_parts,
                                         parse_size, read_player, undelta_bytes, undelta_planes,
                                         undelta_quat_words, write_player)
from avatarkit.gaussians.ply import write_ply
from avatarkit.gaussians.sh import SH_C0
from helpers import random_gaussians, random_quats, random_rotation
from test_usd_stage import synthetic_bake, write_bake
from avatarkit.export.usd_stage import UsdWriteOptions


# --- codes ---------------------------------------------------------------------------------------
def test_positions_round_trip_within_half_a_step():
    rng = np.random.default_rng(0)
    lo, hi = qz.position_box([-0.2, -0.3, 0.1], [0.25, 0.1, 0.1])  # z flat: widened
    x = rng.uniform(lo, hi, size=(5000, 3))
    x[:, 2] = 0.1
    back = qz.decode_positions(qz.encode_positions(x, lo, hi), lo, hi)
    bound = (hi - lo) / 131070 + 1e-7  # half a 16-bit step + float32 rounding of ~0.3 m
    assert (np.abs(back - x) <= bound).all()
    assert np.abs(back - x).max(0)[0] > 0.5 * bound[0]  # the bound is tight, not vacuous


def test_quaternions_round_trip_within_a_quarter_degree():
    rng = np.random.default_rng(1)
    q = random_quats(20000, rng)
    words = qz.encode_quats(q)
    assert words.dtype == np.uint32
    assert set(np.unique(words >> 30)) == {0, 1, 2, 3}  # every "largest component" case
    back = qz.decode_quats(words)
    assert np.allclose(np.linalg.norm(back, axis=1), 1, atol=1e-6)
    err = qz.quat_angle_deg(back, q)
    # half a 10-bit step (6.9e-4) on each small component, the largest one rebuilt from them:
    # angle ~ 2 |dq| <= 2 * 2 * 6.9e-4 rad = 0.16 degrees, plus float32 noise in arccos near 1;
    # measured 0.21 over 20k random rotations
    assert err.max() < 0.25
    np.testing.assert_array_equal(qz.encode_quats(-q), words)  # q and -q: one rotation, one code


def test_log_scales_and_unit_codes_round_trip():
    rng = np.random.default_rng(2)
    s = np.exp(rng.uniform(np.log(1e-4), np.log(0.05), size=(3000, 3)))
    lo, hi = float(np.log(s).min()), float(np.log(s).max())
    back = qz.decode_log_scales(qz.encode_log_scales(s, lo, hi), lo, hi)
    assert (np.abs(back / s - 1) <= np.exp((hi - lo) / 510) - 1 + 1e-6).all()
    v = rng.uniform(0, 1.7, 1000)
    assert np.abs(qz.decode_unit(qz.encode_unit(v, 1.7), 1.7) - v).max() <= 0.5 / 255 * 1.7 + 1e-6


def test_position_deltas_round_trip_exactly_with_wrap_around():
    rng = np.random.default_rng(3)
    q = rng.integers(0, 65536, size=(7, 40, 3)).astype(np.uint16)
    q[3] = 65535
    q[4] = 0  # a jump that wraps
    planes = delta_planes(q)
    assert planes.shape == (7, 2, 120) and planes.dtype == np.uint8
    np.testing.assert_array_equal(undelta_planes(planes, 40), q)


def test_rotation_and_scale_deltas_round_trip_exactly():
    rng = np.random.default_rng(5)
    words = qz.encode_quats(random_quats(6 * 50, rng)).reshape(6, 50)
    words[2:4] = words[1]  # still frames
    planes = delta_quat_words(words)
    assert planes.shape == (6, 4, 50) and planes.dtype == np.uint8
    assert not planes[2:4].any()  # no change, all zero: what zlib packs away
    np.testing.assert_array_equal(undelta_quat_words(planes), words)
    codes = rng.integers(0, 256, size=(6, 50, 3)).astype(np.uint8)
    np.testing.assert_array_equal(undelta_bytes(delta_bytes(codes)), codes)


def test_kabsch_finds_the_rotation():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(200, 3))
    r = random_rotation(rng)
    b = a @ r.T + [0.3, -1, 2]
    np.testing.assert_allclose(kabsch_rotation(a, b), r, atol=1e-9)


@pytest.mark.parametrize("text, n", [("50MB", 50_000_000), ("800 kb", 800_000), ("20MiB", 20 << 20),
                                     ("1.5g", 1_500_000_000), ("12345", 12345)])
def test_parse_size(text, n):
    assert parse_size(text) == n


@pytest.mark.parametrize("text", ["", "ten", "5 parsecs", "0", "-3MB"])
def test_parse_size_rejects(text):
    with pytest.raises(InputError):
        parse_size(text)


# --- the page's data: a synthetic bake through USD (value clips) and a PLY sequence ----------------
@pytest.fixture(scope="module")
def bake(tmp_path_factory):
    """The stage tests' synthetic bake (face turning rigidly about Y, hair scales growing 5% a
    frame), as a chunked USD stage and as a PLY sequence."""
    folder = tmp_path_factory.mktemp("bake")
    static, frames = synthetic_bake(n_frames=6, n_face=80, n_hair=120)
    write_bake(folder / "clip.usdc", static, frames, UsdWriteOptions(chunk_frames=2))
    assert (folder / "clip_clips").is_dir()
    with PlySequenceWriter(folder / "ply") as w:
        w.begin(static)
        for f in frames:
            w.write(f)
    return folder, static, frames


def test_usd_stage_and_ply_sequence_read_back_the_same_frames(bake):
    folder, static, frames = bake
    usd = open_splat_frames(folder / "clip.usdc")
    ply = open_splat_frames(folder / "ply")
    for src in (usd, ply):
        assert (src.n_frames, src.fps, sorted(src.rest)) == (6, 24.0, ["face", "hair"])
        assert src.sh_degree == 3
    for i, (a, b) in enumerate(zip(usd.frames(), ply.frames())):
        for part in ("face", "hair"):
            want = getattr(frames[i], part)
            for got in (a[part], b[part]):
                np.testing.assert_allclose(got[0], want.means, atol=1e-6)
                np.testing.assert_allclose(np.abs((got[1] * want.quats).sum(1)), 1, atol=1e-5)
                np.testing.assert_allclose(got[2], want.scales, rtol=1e-5)
    assert i == 5


def test_page_decodes_to_the_bake_within_the_code_bounds(bake, tmp_path):
    folder, static, frames = bake
    result = write_player(folder / "clip.usdc", tmp_path / "p.html")
    assert result.frames == 6 and result.splats == 200 and result.sh_degree_dropped == 3
    # the face turns rigidly: rotations and scales stored once; hair scales grow: per frame
    assert result.animated == {"face": 0, "hair": 120}
    header, raw = read_player(tmp_path / "p.html")
    assert header["fps"] == 24.0 and header["n_frames"] == 6 and header["sh_degree_source"] == 3
    decoded = decode_player(header, raw)
    src = open_splat_frames(folder / "clip.usdc")
    parts, color_scale = encode_frames(src)
    order = {p.name: p.order for p in parts}
    for spec in header["parts"]:
        name = spec["name"]
        d, o = decoded[name], order[name]
        lo, hi = np.asarray(spec["box"][0]), np.asarray(spec["box"][1])
        gs = getattr(static, name)
        rgb = np.maximum(0, gs.sh[o, 0] * SH_C0 + 0.5)
        assert np.abs(d["colors"] - rgb).max() <= 0.5 / 255 * color_scale + 1e-6
        assert np.abs(d["opacities"] - gs.opacities[o]).max() <= 0.5 / 255 + 1e-6
        for f in range(6):
            want = getattr(frames[f], name)
            assert (np.abs(d["means"][f] - want.means[o]) <= (hi - lo) / 131070 + 1e-6).all()
            # shared rotations: within the 0.5 degree tolerance plus the code's 0.25
            assert qz.quat_angle_deg(d["quats"][f], want.quats[o]).max() < 0.5 + 0.25
            span = spec["log_scale"][1] - spec["log_scale"][0]
            assert (np.abs(np.log(d["scales"][f] / want.scales[o])) <= span / 510 + 0.01 + 1e-5).all()


def test_layout_arrays_have_their_documented_shapes(bake):
    folder, _, _ = bake
    parts, _ = encode_frames(open_splat_frames(folder / "clip.usdc"))
    raw, specs = pack_parts(parts)
    for spec in specs:
        n, k, a = spec["count"], spec["animated"], spec["arrays"]
        assert a["colors"]["shape"] == [n, 4] and a["rot_static"]["shape"] == [n]
        assert a["scale_static"]["shape"] == [n, 3] and a["rot_frames"]["shape"] == [6, 4, k]
        assert a["scale_frames"]["shape"] == [6, k, 3] and a["part_rot"]["shape"] == [6, 4]
        assert a["positions"]["shape"] == [6, 2, 3 * n] and a["positions"]["dtype"] == "uint8"
        for s in a.values():
            assert s["offset"] % 4 == 0 and s["offset"] + s["length"] * np.dtype(s["dtype"]).itemsize <= len(raw)


def test_part_rotation_follows_the_turn(bake):
    folder, _, _ = bake
    parts, _ = encode_frames(open_splat_frames(folder / "clip.usdc"))
    face = next(p for p in parts if p.name == "face")
    for i in range(6):  # synthetic_bake turns by 0.1 rad a frame about +Y
        want = np.array([np.cos(0.05 * i), 0, np.sin(0.05 * i), 0])
        assert abs(abs(float(face.part_rot[i] @ want)) - 1) < 1e-6


def test_max_size_subsamples_and_says_what_it_dropped(bake, tmp_path):
    folder, _, _ = bake
    full = write_player(folder / "ply", tmp_path / "full.html")
    data = (tmp_path / "full.html").read_text().split('type="application/octet-stream">')[1].split("</script>")[0]
    fixed = full.bytes - len(data)  # the page without its data
    cap = fixed + (full.bytes - fixed) // 2
    capped = write_player(folder / "ply", tmp_path / "capped.html", PlayerOptions(max_bytes=cap))
    assert capped.bytes <= cap == (tmp_path / "capped.html").stat().st_size + (cap - capped.bytes)
    assert 0 < sum(capped.dropped.values()) < 200
    assert capped.splats + sum(capped.dropped.values()) == 200
    header, raw = read_player(tmp_path / "capped.html")
    assert {p["name"]: p["count"] for p in header["parts"]} == \
        {n: c - capped.dropped[n] for n, c in (("face", 80), ("hair", 120))}
    decode_player(header, raw)  # still a consistent layout
    with pytest.raises(InputError, match="below what the page needs"):
        write_player(folder / "ply", tmp_path / "tiny.html", PlayerOptions(max_bytes=1000))
    assert not (tmp_path / "tiny.html").exists()


def test_single_files_and_avatar_folders(tmp_path):
    gs = random_gaussians(50, sh_degree=1, seed=5)
    write_ply(tmp_path / "one.ply", gs)
    r = write_player(tmp_path / "one.ply", tmp_path / "one.html", PlayerOptions(background=(1, 1, 1)))
    assert (r.frames, r.splats, r.kind, r.sh_degree_dropped) == (1, 50, "splat file", 1)
    header, raw = read_player(tmp_path / "one.html")
    assert header["background"] == [1.0, 1.0, 1.0]
    d = decode_player(header, raw)["splats"]
    assert d["means"].shape == (1, 50, 3)


# --- bad input: exit 2, one line --------------------------------------------------------------------
def _bad(capsys, args):
    code = main(["view", "-q", *args])  # -q: no progress bar label on stderr
    err = capsys.readouterr().err.strip()
    return code, err


@pytest.mark.parametrize("case", ["missing", "text_file", "bad_ply", "bad_ext", "bad_size", "no_folder",
                                  "empty_folder", "too_small", "bad_usd"])
def test_bad_input_exits_2_with_one_line(case, tmp_path, capsys):
    gs = random_gaussians(20, seed=6)
    write_ply(tmp_path / "ok.ply", gs)
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\nend_header\n")
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.usdc").write_bytes(b"not a crate file")
    args = {"missing": [str(tmp_path / "nope.usdc"), "-o", str(tmp_path / "o.html")],
            "text_file": [str(tmp_path / "notes.txt"), "-o", str(tmp_path / "o.html")],
            "bad_ply": [str(tmp_path / "bad.ply"), "-o", str(tmp_path / "o.html")],
            "bad_ext": [str(tmp_path / "ok.ply"), "-o", str(tmp_path / "o.png")],
            "bad_size": [str(tmp_path / "ok.ply"), "-o", str(tmp_path / "o.html"), "--max-size", "lots"],
            "no_folder": [str(tmp_path / "ok.ply"), "-o", str(tmp_path / "nowhere" / "o.html")],
            "empty_folder": [str(tmp_path / "empty"), "-o", str(tmp_path / "o.html")],
            "too_small": [str(tmp_path / "ok.ply"), "-o", str(tmp_path / "o.html"), "--max-size", "2KB"],
            "bad_usd": [str(tmp_path / "bad.usdc"), "-o", str(tmp_path / "o.html")]}[case]
    code, err = _bad(capsys, args)
    assert code == 2, err
    assert err.startswith("error: ") and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "o.html").exists()
    if case == "bad_usd":
        assert "bad.usdc" in err and "not a readable USD file" in err


def test_cli_writes_a_page_and_reports(tmp_path, capsys):
    write_ply(tmp_path / "ok.ply", random_gaussians(30, sh_degree=2, seed=7))
    assert main(["view", str(tmp_path / "ok.ply"), "-o", str(tmp_path / "ok.html"), "--background", "white"]) == 0
    out = capsys.readouterr()
    assert "wrote" in out.out and "30 splats" in out.out
    assert "SH degree 0" in out.err and "degree 2" in out.err
    assert (tmp_path / "ok.html").read_text().startswith("<!DOCTYPE html>")
