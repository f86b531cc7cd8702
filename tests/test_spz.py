"""SPZ: hand-built files decoded per Niantic's spec, round trips within the quantisation, bad files."""
from __future__ import annotations

import gzip
import math
import struct

import numpy as np
import pytest

from avatarkit.errors import FormatError, InputError
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.spz import encode_streams, read_spz, spz_bytes, write_spz
from helpers import random_quats

MAGIC = 0x5053474E


def header(version, n, degree, fbits=12, flags=0):
    return struct.pack("<IIIBBBB", MAGIC, version, n, degree, fbits, flags, 0)


def i24(v: int) -> bytes:
    return int(v).to_bytes(3, "little", signed=True)


def spz_in_range(n=2000, degree=3, seed=0) -> GaussianSet:
    """Random splats inside SPZ's encodable ranges."""
    rng = np.random.default_rng(seed)
    sh = rng.uniform(-0.95, 0.95, size=(n, (degree + 1) ** 2, 3))
    sh[:, 0] = rng.uniform(-3.2, 3.2, size=(n, 3))
    return GaussianSet(rng.uniform(-50, 50, (n, 3)), random_quats(n, rng), np.exp(rng.uniform(-9, 4, (n, 3))),
                       rng.uniform(0.01, 0.99, n), sh)


def test_hand_built_v2_file(tmp_path):
    positions = [(1.0, -0.5, 0.25), (-3.0, 2.0, 1 / 4096)]
    alphas = [255, 128]
    colors = [(128, 255, 0), (10, 20, 30)]
    scales = [(160, 96, 0), (255, 1, 200)]
    rots = [(204, 127, 128), (0, 255, 191)]
    sh = [list(range(100, 109)), list(range(200, 209))]  # degree 1: 3 coefficients x 3 channels
    body = b"".join(i24(round(c * 4096)) for p in positions for c in p)
    body += bytes(alphas) + bytes(sum(colors, ())) + bytes(sum(scales, ())) + bytes(sum(rots, ()))
    body += bytes(sum(sh, []))
    path = tmp_path / "hand.spz"
    path.write_bytes(gzip.compress(header(2, 2, 1) + body))

    gs = read_spz(path)
    assert len(gs) == 2 and gs.sh_degree == 1
    np.testing.assert_array_equal(gs.means, np.array(positions, np.float32))
    np.testing.assert_allclose(gs.opacities, [254 / 255, 128 / 255], atol=1e-7)  # clamped like Niantic
    np.testing.assert_allclose(gs.sh[:, 0], (np.array(colors) / 255 - 0.5) / 0.15, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(gs.scales, np.exp(np.array(scales) / 16 - 10), rtol=1e-6)
    for i, r in enumerate(rots):
        xyz = np.array(r) / 127.5 - 1
        w = math.sqrt(max(0.0, 1 - xyz @ xyz))
        q = np.array([w, *xyz])
        np.testing.assert_allclose(gs.quats[i], q / np.linalg.norm(q), atol=1e-6)
    expect_sh = (np.array(sh, float).reshape(2, 3, 3) - 128) / 128  # [point][coefficient][channel]
    np.testing.assert_allclose(gs.sh[:, 1:], expect_sh, atol=1e-7)


def pack_smallest_three(xyzw):
    """Scalar transcription of the spec: largest index (2 bits), then 3 x (sign, 9-bit magnitude)."""
    q = np.asarray(xyzw, float) / np.linalg.norm(xyzw)
    largest = int(np.argmax(np.abs(q)))
    if q[largest] < 0:
        q = -q
    comp = largest
    for i in range(4):
        if i != largest:
            comp = (comp << 10) | (int(q[i] < 0) << 9) | int(511 * abs(q[i]) / math.sqrt(0.5) + 0.5)
    return struct.pack("<I", comp), q


@pytest.mark.parametrize("xyzw", [(0, 0, 0, 1), (1, 0, 0, 0), (0.1, -0.2, 0.3, -0.9), (-0.7, 0.1, 0.69, 0.05),
                                  (0.5, 0.5, -0.5, 0.5)])
def test_hand_built_v3_rotations(tmp_path, xyzw):
    packed, q = pack_smallest_three(xyzw)
    body = i24(0) * 3 + bytes([200]) + bytes([128, 128, 128]) + bytes([160, 160, 160]) + packed
    path = tmp_path / "r.spz"
    path.write_bytes(gzip.compress(header(3, 1, 0) + body))
    got = read_spz(path).quats[0]  # w x y z
    want = np.array([q[3], q[0], q[1], q[2]])
    assert abs(abs(got @ want) - 1) < 2e-6
    np.testing.assert_allclose(got * np.sign(got @ want), want, atol=1.5e-3)


def test_encoder_bytes_follow_the_spec():
    gs = GaussianSet(means=[[1.0, -0.5, 2.0 ** -12]], quats=[[1, 0, 0, 0]], scales=[[1.0, np.exp(-4), np.exp(-10)]],
                     opacities=[0.5], sh=np.array([[[0.0, 1 / 0.15 * (127.5 / 255), -1]]]))
    pos, alpha, color, scale, rot, sh = encode_streams(gs, version=3)
    assert pos == i24(4096) + i24(-2048) + i24(1)
    assert alpha == bytes([128])              # round(0.5 * 255) = 127.5 -> 128 (half away from zero)
    assert scale == bytes([160, 96, 0])
    assert color[0] == 128 and color[1] == 255  # 0 -> 127.5 -> 128; 127.5/255/0.15 -> 255
    assert rot == struct.pack("<I", 3 << 30)   # identity: w largest, others zero
    assert sh == b""
    _, _, _, _, rot2, _ = encode_streams(gs, version=2)
    assert rot2 == bytes([128, 128, 128])


@pytest.mark.parametrize("version", [2, 3])
def test_round_trip_within_quantisation(tmp_path, version):
    gs = spz_in_range(3000, degree=3, seed=version)
    path = tmp_path / "r.spz"
    write_spz(path, gs, version=version)
    back = read_spz(path)
    assert back.sh_degree == 3
    assert np.abs(back.means - gs.means).max() <= 2.0 ** -13 + 1e-5
    assert np.abs(np.log(back.scales / gs.scales)).max() <= 1 / 32 + 1e-5
    assert np.abs(back.opacities - gs.opacities).max() <= 0.5 / 255 + 1e-6
    assert np.abs(back.sh[:, 0] - gs.sh[:, 0]).max() <= 0.5 / (0.15 * 255) + 1e-5
    assert np.abs(back.sh[:, 1:4] - gs.sh[:, 1:4]).max() <= 4.5 / 128 + 1e-6   # 5-bit band 1
    assert np.abs(back.sh[:, 4:] - gs.sh[:, 4:]).max() <= 8.5 / 128 + 1e-6     # 4-bit bands 2, 3
    angle = np.degrees(2 * np.arccos(np.clip(np.abs((back.quats * gs.quats).sum(1)), 0, 1)))
    assert angle.max() < (0.5 if version == 3 else 20)  # v2's derived w is coarse near w = 0
    if version == 2:
        assert np.median(angle) < 1.0


def test_v4_round_trip_matches_v3(tmp_path):
    pytest.importorskip("zstandard", reason="SPZ v4 streams are zstd-compressed")
    gs = spz_in_range(500, degree=2, seed=9)
    write_spz(tmp_path / "a.spz", gs, version=4)
    write_spz(tmp_path / "b.spz", gs, version=3)
    data = (tmp_path / "a.spz").read_bytes()
    assert struct.unpack_from("<II", data) == (MAGIC, 4)
    a, b = read_spz(tmp_path / "a.spz"), read_spz(tmp_path / "b.spz")
    for f in ("means", "quats", "scales", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    # a table entry that disagrees with the header is caught
    toc = struct.unpack_from("<I", data, 16)[0]
    bad = bytearray(data)
    struct.pack_into("<Q", bad, toc + 8, 17)
    (tmp_path / "bad.spz").write_bytes(bytes(bad))
    with pytest.raises(FormatError, match="bad.spz"):
        read_spz(tmp_path / "bad.spz")


def test_degree_4_keeps_bands_up_to_3(tmp_path):
    n = 3
    body = i24(0) * 3 * n + bytes([100] * n) + bytes([128] * 3 * n) + bytes([160] * 3 * n)
    body += struct.pack("<I", 3 << 30) * n
    rest = np.arange(n * 24 * 3) % 256
    body += bytes(rest.astype(np.uint8))
    path = tmp_path / "d4.spz"
    path.write_bytes(gzip.compress(header(3, n, 4) + body))
    gs = read_spz(path)
    assert gs.sh_degree == 3
    np.testing.assert_allclose(gs.sh[:, 1:], (rest.reshape(n, 24, 3)[:, :15] - 128) / 128)


def test_peer_reader_reads_our_files(tmp_path):
    nv = pytest.importorskip("usd_convert_gsplat", reason="NVIDIA's usd-convert-gsplat is a test-only peer")
    gs = spz_in_range(300, degree=2, seed=11)
    for version in (2, 3):
        path = tmp_path / f"v{version}.spz"
        write_spz(path, gs, version=version)
        ours, theirs = read_spz(path), nv.read_spz(str(path))
        np.testing.assert_array_equal(theirs.positions, ours.means)
        np.testing.assert_allclose(np.exp(theirs.scales), ours.scales, rtol=1e-6)
        np.testing.assert_allclose(1 / (1 + np.exp(-theirs.opacities)), ours.opacities, atol=1e-6)
        np.testing.assert_allclose(theirs.f_dc, ours.sh[:, 0], atol=1e-6)
        np.testing.assert_allclose(theirs.f_rest.reshape(len(gs), -1, 3), ours.sh[:, 1:], atol=1e-7)
        np.testing.assert_allclose(np.abs((theirs.rotations * ours.quats).sum(1)), 1, atol=1e-6)


def _good_file(tmp_path) -> bytes:
    return spz_bytes(spz_in_range(50, degree=1))


@pytest.mark.parametrize("case", ["not_gzip", "bad_magic", "truncated_gzip", "short_payload", "huge_count",
                                  "version", "degree", "empty_header", "zero_points", "garbage_gzip"])
def test_corrupt_files_are_format_errors(tmp_path, case):
    good = _good_file(tmp_path)
    raw = gzip.decompress(good)
    data = {
        "not_gzip": b"hello world, not an spz file",
        "bad_magic": gzip.compress(b"XXXX" + raw[4:]),
        "truncated_gzip": good[: len(good) // 2],
        "short_payload": gzip.compress(raw[:-10]),
        "huge_count": gzip.compress(header(3, 2**31, 3) + raw[16:]),
        "version": gzip.compress(header(7, 50, 1) + raw[16:]),
        "degree": gzip.compress(header(3, 50, 9) + raw[16:]),
        "empty_header": gzip.compress(raw[:10]),
        "zero_points": gzip.compress(header(3, 0, 0)),
        "garbage_gzip": b"\x1f\x8b" + bytes(range(200)),
    }[case]
    path = tmp_path / "bad.spz"
    path.write_bytes(data)
    with pytest.raises(FormatError, match="bad.spz"):
        read_spz(path)


@pytest.mark.parametrize("version", [2, 3, 4])
def test_a_header_count_that_disagrees_with_the_data_is_refused(tmp_path, version):
    """Counts one below and one above the real one, and one no file of this size could hold: each
    refused with its own reason (a count too low would otherwise read shifted attributes)."""
    if version == 4:
        pytest.importorskip("zstandard", reason="SPZ v4 streams are zstd-compressed")
    good = spz_bytes(spz_in_range(50, degree=1), version=version)
    path = tmp_path / "count.spz"
    path.write_bytes(good)
    assert len(read_spz(path)) == 50
    reasons = {49: "count is wrong" if version < 4 else "a stream holds",
               51: "truncated" if version < 4 else "a stream holds", 2**30: "claims"}
    for n, reason in reasons.items():
        if version < 4:
            raw = bytearray(gzip.decompress(good))
            struct.pack_into("<I", raw, 8, n)
            data = gzip.compress(bytes(raw))
        else:
            data = bytearray(good)
            struct.pack_into("<I", data, 8, n)
        path.write_bytes(bytes(data))
        with pytest.raises(FormatError, match=reason):
            read_spz(path)
    if version < 4:  # the same surplus is fine where the flags announce extension records
        raw = bytearray(gzip.decompress(good))
        struct.pack_into("<I", raw, 8, 49)
        raw[14] |= 0x2
        path.write_bytes(gzip.compress(bytes(raw)))
        assert len(read_spz(path)) == 49


def test_write_errors_leave_nothing(tmp_path):
    gs = spz_in_range(10)
    far = gs.replace(means=gs.means + np.float32(5000))  # beyond 24-bit fixed point at 12 bits
    with pytest.raises(InputError, match="position range"):
        write_spz(tmp_path / "far.spz", far)
    with pytest.raises(InputError, match="version"):
        write_spz(tmp_path / "v.spz", gs, version=5)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="file not found"):
        read_spz(tmp_path / "missing.spz")
