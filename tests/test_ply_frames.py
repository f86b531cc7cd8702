"""PLY axes: ours (y-up) or the 3DGS/COLMAP y-down frame splat viewers assume, for writing and
reading, in `write_ply`/`read_ply`, the bake's PLY sequence and `convert`."""
from __future__ import annotations

import json

import numpy as np
import pytest

from avatarkit.cli.main import main
from avatarkit.convert import ConvertOptions, convert
from avatarkit.errors import FormatError, InputError
from avatarkit.export.ply_sequence import PlySequenceWriter, read_sidecar
from avatarkit.gaussians.ply import FLIP_SH_SIGNS, PLY_FRAMES, flip_y_down, read_ply, write_ply
from avatarkit.gaussians.ply_table import read_ply_arrays
from avatarkit.gaussians.sh import eval_sh, sh_rotation
from avatarkit.rotations import quat_to_matrix
from helpers import random_gaussians
from test_usd_stage import synthetic_bake

FLIP = np.diag([1.0, -1.0, -1.0])  # 180 degrees about X: ours <-> y-down


def _covariances(gs) -> np.ndarray:
    r = np.stack([quat_to_matrix(q) for q in gs.quats.astype(np.float64)])
    s = gs.scales.astype(np.float64)
    return np.einsum("nij,nj,nkj->nik", r, s * s, r)


def test_sh_signs_are_the_rotation_and_niantics_table():
    """FLIP_SH_SIGNS is our SH rotation of 180 degrees about X (a diagonal of +-1), and the sign
    table Niantic's spz library uses between RDF (PLY) and RUB (SPZ): its `flipSh` with
    x = +1, y = -1, z = -1 (src/cc/splat-types.h, coordinateConverter)."""
    mats = sh_rotation(FLIP, 3)
    diag = np.concatenate([[1.0]] + [np.diag(m) for m in mats])
    for m in mats:
        np.testing.assert_allclose(m, np.diag(np.diag(m)), atol=1e-9)
    np.testing.assert_allclose(diag, FLIP_SH_SIGNS, atol=1e-9)
    x, y, z = 1, -1, -1
    niantic = [y, z, x, x * y, y * z, 1, x * z, 1, y, x * y * z, y, z, x, z, x]
    assert FLIP_SH_SIGNS[1:].tolist() == niantic


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_flip_is_exact_its_own_inverse_and_a_rotation(degree):
    gs = random_gaussians(300, sh_degree=degree, seed=degree, extras=("binding",))
    flipped = flip_y_down(gs)
    np.testing.assert_array_equal(flipped.means, gs.means * [1, -1, -1])
    back = flip_y_down(flipped)
    for name in ("means", "quats", "scales", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(back, name), getattr(gs, name))
    assert flipped.extras.keys() == gs.extras.keys()
    # the same Gaussians as GaussianSet.transform by 180 degrees about X (which rotates SH by
    # least squares): covariances, and colours seen from any direction
    turned = gs.transform(rotation=FLIP)
    np.testing.assert_allclose(flipped.means, turned.means, atol=1e-7)
    np.testing.assert_allclose(_covariances(flipped), _covariances(turned), atol=1e-9)
    np.testing.assert_allclose(flipped.sh, turned.sh, atol=1e-6)
    dirs = np.random.default_rng(1).normal(size=(len(gs), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    np.testing.assert_allclose(eval_sh(flipped.sh, dirs @ FLIP.T), eval_sh(gs.sh, dirs), atol=1e-6)


@pytest.mark.parametrize("decoder", ["numpy", "kernel"])
def test_write_and_read_y_down(tmp_path, decoder):
    gs = random_gaussians(500, sh_degree=3, seed=4)
    path = tmp_path / "down.ply"
    write_ply(path, gs, frame="ydown")
    raw = read_ply_arrays(path)
    np.testing.assert_array_equal(np.stack([raw["x"], raw["y"], raw["z"]], 1), gs.means * [1, -1, -1])
    np.testing.assert_array_equal(np.stack([raw[f"rot_{i}"] for i in range(4)], 1), gs.quats * [1, 1, -1, -1])
    # f_rest is channel-major on disk: coefficient j (1..15) of channel c is f_rest_{c*15 + j-1}
    np.testing.assert_array_equal(raw["f_rest_0"], -gs.sh[:, 1, 0])  # band 1, -y: flips
    np.testing.assert_array_equal(raw["f_rest_2"], gs.sh[:, 3, 0])   # band 1, -x: stays
    np.testing.assert_array_equal(raw["f_dc_1"], gs.sh[:, 0, 1])
    # read in its frame: ours again, bit for bit; read as ours: turned over
    back = read_ply(path, frame="ydown", decoder=decoder)
    for name in ("means", "quats", "sh"):
        np.testing.assert_array_equal(getattr(back, name), getattr(gs, name))
    np.testing.assert_array_equal(read_ply(path, decoder=decoder).means, gs.means * [1, -1, -1])


def test_bad_frame_names(tmp_path):
    gs = random_gaussians(3)
    with pytest.raises(InputError, match="PLY frame must be one of yup, ydown"):
        write_ply(tmp_path / "a.ply", gs, frame="zup")
    assert not (tmp_path / "a.ply").exists()
    write_ply(tmp_path / "a.ply", gs)
    with pytest.raises(InputError, match="got 'RDF'"):
        read_ply(tmp_path / "a.ply", frame="RDF")
    with pytest.raises(InputError):
        PlySequenceWriter(tmp_path / "seq", ply_frame="down")
    assert PLY_FRAMES == ("yup", "ydown")


@pytest.mark.parametrize("split", [False, True])
def test_bake_sequence_in_y_down(tmp_path, split):
    static, frames = synthetic_bake(n_frames=3)
    folders = {}
    for frame in PLY_FRAMES:
        folders[frame] = tmp_path / frame
        with PlySequenceWriter(folders[frame], split=split, ply_frame=frame) as writer:
            writer.begin(static)
            for f in frames:
                writer.write(f)
    doc = read_sidecar(folders["ydown"])
    assert doc["ply_frame"] == "ydown" and read_sidecar(folders["yup"])["ply_frame"] == "yup"
    for name in doc["files"]["face"] if split else doc["files"]:
        up, down = read_ply(folders["yup"] / name), read_ply(folders["ydown"] / name, frame="ydown")
        for field in ("means", "quats", "sh"):
            np.testing.assert_array_equal(getattr(down, field), getattr(up, field))
        np.testing.assert_array_equal(read_ply_arrays(folders["ydown"] / name)["y"], -up.means[:, 1])


def test_sidecar_frame_is_checked(tmp_path):
    static, frames = synthetic_bake(n_frames=1)
    folder = tmp_path / "seq"
    with PlySequenceWriter(folder) as writer:
        writer.begin(static)
        writer.write(frames[0])
    doc = json.loads((folder / "sequence.json").read_text())
    doc["ply_frame"] = "sideways"
    (folder / "sequence.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="'ply_frame' is 'sideways'"):
        read_sidecar(folder)
    del doc["ply_frame"]  # sidecars written before the option: ours
    (folder / "sequence.json").write_text(json.dumps(doc))
    assert "ply_frame" not in read_sidecar(folder)


def test_convert_between_frames(tmp_path):
    gs = random_gaussians(200, sh_degree=2, seed=7)
    ours, down = tmp_path / "ours.ply", tmp_path / "down.ply"
    write_ply(ours, gs)
    write_ply(down, gs, frame="ydown")
    # ours -> y-down PLY: what write_ply(frame="ydown") writes, byte for byte
    convert(ours, tmp_path / "c.ply", ConvertOptions(ply_frame="ydown", input_ply_frame="yup"))
    assert (tmp_path / "c.ply").read_bytes() == down.read_bytes()
    # a y-down PLY read in its frame gives the same SPZ (RUB, whatever the PLY frame) and USD
    convert(ours, tmp_path / "a.spz")
    convert(down, tmp_path / "b.spz", ConvertOptions(ply_frame="ydown"))
    assert (tmp_path / "a.spz").read_bytes() == (tmp_path / "b.spz").read_bytes()
    from avatarkit.gaussians.usd_read import load_usd

    convert(down, tmp_path / "b.usda", ConvertOptions(ply_frame="ydown"))
    for name in ("means", "quats", "sh"):
        np.testing.assert_array_equal(getattr(load_usd(tmp_path / "b.usda"), name), getattr(gs, name))
    # y-down both ways is the identity
    convert(down, tmp_path / "d.ply", ConvertOptions(ply_frame="ydown"))
    assert (tmp_path / "d.ply").read_bytes() == down.read_bytes()


def test_convert_frame_options_need_ply(tmp_path, capsys):
    gs = random_gaussians(20, seed=2)
    write_ply(tmp_path / "a.ply", gs)
    convert(tmp_path / "a.ply", tmp_path / "a.spz")
    with pytest.raises(InputError, match="--ply-frame applies to PLY input or output"):
        convert(tmp_path / "a.spz", tmp_path / "b.usdc", ConvertOptions(ply_frame="ydown"))
    with pytest.raises(InputError, match="--input-ply-frame applies to PLY input"):
        convert(tmp_path / "a.spz", tmp_path / "b.ply", ConvertOptions(input_ply_frame="ydown"))
    with pytest.raises(InputError, match="PLY frame must be one of"):
        convert(tmp_path / "a.ply", tmp_path / "b.ply", ConvertOptions(ply_frame="up"))
    assert not (tmp_path / "b.usdc").exists() and not (tmp_path / "b.ply").exists()
    assert main(["convert", str(tmp_path / "a.ply"), "-o", str(tmp_path / "c.ply"), "--ply-frame", "ydown",
                 "--input-ply-frame", "yup", "-q"]) == 0
    np.testing.assert_array_equal(read_ply(tmp_path / "c.ply", frame="ydown").means, gs.means)
    assert main(["convert", str(tmp_path / "a.spz"), "-o", str(tmp_path / "d.usdc"), "--ply-frame", "ydown"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "--ply-frame" in err and "Traceback" not in err


def test_literals_agree():
    from avatarkit.cli import bake_cmd, convert_cmd

    assert bake_cmd._PLY_FRAMES == convert_cmd._PLY_FRAMES == PLY_FRAMES
