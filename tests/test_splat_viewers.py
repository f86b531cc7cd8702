"""Our PLY and SPZ files in the splat tools studios run, each a test-only peer installed on first
use into `.peers/` (see `peers.py`): PlayCanvas `splat-transform` and `@spz-loader/core`
(Niantic's spz library built to wasm) from npm, NVIDIA's `usd-convert-gsplat`, and gsply
(PyPI, in its own venv: it pulls numba). All slow: they need node or a second environment.

Axes: a PLY file says nothing about its axes; 3DGS trainers write the COLMAP/OpenCV frame
(y down, "RDF") and viewers assume it, while SPZ is RUB (y up) by its specification, which is
ours. So `--ply-frame ydown` PLY and our SPZ hold the same avatar for every reader that follows
Niantic's convention (RDF PLY <-> RUB SPZ: y and z negated).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from avatarkit.convert import ConvertOptions, convert
from avatarkit.gaussians.ply import flip_y_down, read_ply, write_ply
from avatarkit.gaussians.ply_table import read_ply_arrays
from avatarkit.gaussians.spz import DEFAULT_VERSION, SUPPORTED_VERSIONS, read_spz, write_spz
from peers import SCRIPTS, npm_peer, python_peer, run_peer

pytestmark = pytest.mark.slow

#: splat-transform 2.x reads and writes SPZ by the specification (RUB <-> its PLY frame, RDF);
#: 3.x (from 3.4 at least, checked on 3.4.2, 3.6.1, 3.7.0) takes SPZ bytes as they are
SPLAT_TRANSFORM_SPEC = "@playcanvas/splat-transform@2.7.1"
SPLAT_TRANSFORM_NEW = "@playcanvas/splat-transform@3.7.0"
SPZ_LOADER = "@spz-loader/core@0.3.1"
GSPLY = "gsply==0.4.6"


@pytest.fixture(scope="module")
def avatar_files(tmp_path_factory):
    """The small sample avatar at rest as our PLY, y-down PLY and SPZ (via `convert`)."""
    from test_avatar import small_avatar

    root = tmp_path_factory.mktemp("viewers")
    gs = small_avatar().rest_gaussians()
    files = {"gs": gs, "yup": root / "avatar.ply", "ydown": root / "avatar_ydown.ply", "spz": root / "avatar.spz"}
    write_ply(files["yup"], gs)
    convert(files["yup"], files["ydown"], ConvertOptions(ply_frame="ydown", input_ply_frame="yup"))
    convert(files["yup"], files["spz"])
    return files


def _columns(path) -> dict[str, np.ndarray]:
    """A PLY's position, rotation, log-scale, logit-opacity and colour columns as on disk."""
    raw = read_ply_arrays(path)
    rest = sorted((k for k in raw if k.startswith("f_rest_")), key=lambda k: int(k[7:]))
    return {"pos": np.stack([raw[c] for c in "xyz"], 1), "rot": np.stack([raw[f"rot_{i}"] for i in range(4)], 1),
            "scale": np.stack([raw[f"scale_{i}"] for i in range(3)], 1), "opacity": raw["opacity"],
            "dc": np.stack([raw[f"f_dc_{i}"] for i in range(3)], 1),
            "rest": np.stack([raw[c] for c in rest], 1) if rest else np.zeros((len(raw["x"]), 0))}


def _same_splats(a: dict, b: dict, quantised: bool, opacity_atol: float | None = None,
                 rot_dot: float = 0.9999) -> None:
    """Two column sets agree: to float rounding, or within SPZ's quantisation (spz.py notes).
    opacity_atol: for decodes of one SPZ that clamp opacity differently (ours and Niantic's
    keep alpha byte 255 at 254/255, splat-transform takes it as 1). rot_dot: the least |q . q'|
    when quantised (SPZ v2's 8-bit x, y, z with w derived are coarse where w is small)."""
    tol = {"pos": 2.0 ** -13 + 1e-6, "scale": 1 / 32 + 1e-5, "dc": 0.5 / (0.15 * 255) + 1e-5,
           "rest": 8 / 128 + 1e-5} if quantised else {"pos": 1e-6, "scale": 1e-5, "dc": 1e-6, "rest": 1e-6}
    for key, atol in tol.items():
        np.testing.assert_allclose(a[key], b[key], rtol=0, atol=atol, err_msg=key)
    qa = a["rot"] / np.linalg.norm(a["rot"], axis=1, keepdims=True)
    qb = b["rot"] / np.linalg.norm(b["rot"], axis=1, keepdims=True)
    assert np.abs((qa * qb).sum(1)).min() > (rot_dot if quantised else 1 - 1e-6)  # q and -q agree
    sig = lambda x: 1 / (1 + np.exp(-x.astype(np.float64)))  # noqa: E731
    if opacity_atol is None:
        opacity_atol = 1 / 255 + 1e-6 if quantised else 1e-6
    np.testing.assert_allclose(sig(a["opacity"]), sig(b["opacity"]), rtol=0, atol=opacity_atol)


def _splat_transform(folder, source, target):
    exe = folder / "node_modules" / ".bin" / "splat-transform"
    run = run_peer([exe, source, target], timeout=300)
    assert run.returncode == 0 and target.is_file(), run.stdout + run.stderr
    return _columns(target)


def _ours(gs) -> dict:
    """What our writer puts in a PLY for `gs`, as columns."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        write_ply(Path(d) / "x.ply", gs)
        return _columns(Path(d) / "x.ply")


def test_splat_transform_opens_y_down_ply_and_spz_identical(avatar_files, tmp_path):
    """splat-transform (2.x: SPZ as its specification says) turns our SPZ and our y-down PLY into
    the same splats, up to SPZ's quantisation; our y-up PLY comes out turned 180 degrees about
    X against the SPZ (the finding: y and z negated)."""
    folder = npm_peer("splat-transform-2.7.1", [SPLAT_TRANSFORM_SPEC])
    from_ply = _splat_transform(folder, avatar_files["ydown"], tmp_path / "from_ply.ply")
    from_spz = _splat_transform(folder, avatar_files["spz"], tmp_path / "from_spz.ply")
    from_yup = _splat_transform(folder, avatar_files["yup"], tmp_path / "from_yup.ply")
    gs = avatar_files["gs"]
    _same_splats(from_ply, _ours(flip_y_down(gs)), quantised=False)  # the PLY is read as it is
    _same_splats(from_spz, _ours(flip_y_down(read_spz(avatar_files["spz"]))), quantised=False,
                 opacity_atol=1 / 255 + 1e-6)
    _same_splats(from_ply, from_spz, quantised=True)
    np.testing.assert_allclose(from_yup["pos"][:, 1:], -from_spz["pos"][:, 1:], atol=2.0 ** -13 + 1e-6)


def test_splat_transform_3_reads_spz_without_converting_axes(avatar_files, tmp_path):
    """splat-transform 3.x departs from the SPZ specification: it reads (and writes) SPZ bytes
    in its PLY frame, unconverted. So there a y-down PLY and a RUB SPZ of the same avatar open
    turned 180 degrees about X against each other; we keep SPZ to its specification (and to
    Niantic's library, the next test) and say so in the docs."""
    folder = npm_peer("splat-transform-3.7.0", [SPLAT_TRANSFORM_NEW])
    from_spz = _splat_transform(folder, avatar_files["spz"], tmp_path / "from_spz.ply")
    from_ply = _splat_transform(folder, avatar_files["ydown"], tmp_path / "from_ply.ply")
    _same_splats(from_spz, _ours(read_spz(avatar_files["spz"])), quantised=False, opacity_atol=1 / 255 + 1e-6)
    _same_splats(from_ply, _ours(flip_y_down(avatar_files["gs"])), quantised=False)


def _spz_loader(folder, path, coord=None):
    args = ["node", SCRIPTS / "spz_loader.mjs", folder / "node_modules", path] + ([coord] if coord else [])
    return run_peer(args, timeout=120)


@pytest.mark.parametrize("version", [2, 3])
def test_niantic_reader_in_the_ply_frame_equals_our_y_down_ply(avatar_files, tmp_path, version):
    """Niantic's library (via @spz-loader/core) unpacks our SPZ into the PLY frame (RDF) as the
    y-down PLY we write, to SPZ's quantisation; unpacked as stored (RUB) it is ours."""
    folder = npm_peer("spz-loader-0.3.1", [SPZ_LOADER])
    path = tmp_path / f"v{version}.spz"
    write_spz(path, avatar_files["gs"], version=version)
    for coord, gs in (("RDF", flip_y_down(avatar_files["gs"])), (None, avatar_files["gs"])):
        run = _spz_loader(folder, path, coord)
        assert run.returncode == 0, run.stderr
        c = json.loads(run.stdout)
        n = len(gs)
        assert c["numPoints"] == n and c["shDegree"] == gs.sh_degree
        xyzw = np.array(c["rotations"]).reshape(n, 4)
        k = gs.sh.shape[1]
        # activated by the loader (alpha byte 255 becomes 1.0 in float32): undone here
        alpha = np.clip(np.array(c["alphas"], np.float64), 1e-9, 1 - 1e-9)
        theirs = {"pos": np.array(c["positions"]).reshape(n, 3), "rot": xyzw[:, [3, 0, 1, 2]],
                  "scale": np.log(np.array(c["scales"])).reshape(n, 3), "opacity": np.log(alpha / (1 - alpha)),
                  "dc": np.array(c["colors"]).reshape(n, 3) - 0.5,
                  "rest": np.array(c["sh"]).reshape(n, k - 1, 3).transpose(0, 2, 1).reshape(n, -1)}
        _same_splats(theirs, _ours(gs), quantised=True, rot_dot=0.99 if version == 2 else 0.9999)


def test_default_spz_version_is_the_newest_both_peers_read(tmp_path):
    """NVIDIA's converter and @spz-loader/core read SPZ 2 and 3 and fail on 4 (the finding:
    "Not a gzipped file" and "divide by zero"); our default is the newest both read, and 4
    stays behind --spz-version."""
    nv = pytest.importorskip("usd_convert_gsplat", reason="NVIDIA's usd-convert-gsplat is a test-only peer")
    folder = npm_peer("spz-loader-0.3.1", [SPZ_LOADER])
    from helpers import random_gaussians

    gs = random_gaussians(64, sh_degree=2, seed=5)
    read_by = {"nvidia": set(), "spz-loader": set()}
    for version in SUPPORTED_VERSIONS:
        path = tmp_path / f"v{version}.spz"
        write_spz(path, gs, version=version)
        try:
            theirs = nv.read_spz(str(path))
            np.testing.assert_array_equal(theirs.positions, read_spz(path).means)
            read_by["nvidia"].add(version)
        except Exception as e:  # what the peer says about a version it cannot read
            assert version == 4 and "gzip" in str(e).lower(), e
        run = _spz_loader(folder, path)
        if run.returncode == 0:
            assert json.loads(run.stdout)["numPoints"] == len(gs)
            read_by["spz-loader"].add(version)
        else:
            assert version == 4 and "divide by zero" in run.stderr, run.stderr
    assert read_by == {"nvidia": {2, 3}, "spz-loader": {2, 3}}
    assert DEFAULT_VERSION == max(read_by["nvidia"] & read_by["spz-loader"])


def test_gsply_reads_merged_and_split_frames(tmp_path):
    """gsply maps PLY rows as float32 arrays: it reads our merged frames (`part` is float32) and
    split frames in both frames exactly; a uchar `part` (what merged frames had) breaks every
    row after the first."""
    from avatarkit.export.ply_sequence import PlySequenceWriter
    from test_usd_stage import synthetic_bake

    python = python_peer("gsply-0.4.6", [GSPLY])
    static, frames = synthetic_bake(n_frames=2)
    paths = []
    for split in (False, True):
        for ply_frame in ("yup", "ydown"):
            folder = tmp_path / f"{'split' if split else 'merged'}_{ply_frame}"
            with PlySequenceWriter(folder, split=split, ply_frame=ply_frame) as writer:
                writer.begin(static)
                for f in frames:
                    writer.write(f)
            paths += sorted(folder.glob("*.ply"))
    merged = read_ply(tmp_path / "merged_yup" / "frame_00001.ply")
    old = tmp_path / "uchar_part.ply"
    write_ply(old, merged.replace(extras={"part": merged.extras["part"].astype(np.uint8)}))
    out = tmp_path / "gsply.npz"
    run = run_peer([python, SCRIPTS / "gsply_read.py", out, *paths, old], timeout=600)
    assert run.returncode == 0, run.stderr
    got = np.load(out)
    for i, path in enumerate(paths):
        assert f"{i}_error" not in got, (path, got.get(f"{i}_error"))
        ours = _columns(path)
        theirs = {"pos": got[f"{i}_means"], "rot": got[f"{i}_quats"], "scale": got[f"{i}_scales"],
                  "opacity": got[f"{i}_opacities"], "dc": got[f"{i}_sh0"],
                  "rest": got[f"{i}_shN"].transpose(0, 2, 1).reshape(len(ours["pos"]), -1)}
        for key in ours:
            np.testing.assert_array_equal(theirs[key], ours[key], err_msg=f"{path.name}: {key}")
    i = len(paths)
    assert f"{i}_error" in got or not np.array_equal(got[f"{i}_means"], _columns(old)["pos"])
