"""`avatarkit bake` and `avatarkit avatar`: end to end into a temp folder, and bad input -> exit 2."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from avatarkit.cli.main import COMMANDS, main
from avatarkit.motion import make_clip, save_clip
from test_avatar import saved_avatar

FAST = ["--substeps", "2", "--iterations", "6", "--preroll", "0.2"]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return saved_avatar(tmp_path_factory)


@pytest.fixture(scope="module")
def clip_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("clips") / "shake.npz"
    save_clip(path, make_clip("shake", frames=5, fps=25))
    return path


def test_registered_and_literals_agree():
    from avatarkit.cli import avatar_cmd, bake_cmd
    from avatarkit.gaussians.ply import PLY_FRAMES
    from avatarkit.sim.config import COLLISION_MODES
    from avatarkit.synthetic.hair import HAIR_STYLES

    assert COMMANDS["bake"] == "avatarkit.cli.bake_cmd:bake_cmd"
    assert COMMANDS["avatar"] == "avatarkit.cli.avatar_cmd:avatar"
    assert set(bake_cmd._COLLISION) == set(COLLISION_MODES)
    assert bake_cmd._PLY_FRAMES == PLY_FRAMES
    assert set(avatar_cmd._STYLES) == set(HAIR_STYLES)


def test_bake_end_to_end(folder, clip_file, tmp_path, capsys):
    from plyfile import PlyData
    from pxr import Usd, UsdVol

    from avatarkit.avatar import load_avatar
    from avatarkit.bake import BakeConfig, bake
    from avatarkit.export.video import read_video_frames
    from avatarkit.gaussians.usd import validate_stage
    from avatarkit.motion import load_clip
    from avatarkit.sim.config import SimConfig

    usd, plys, gif = tmp_path / "out.usda", tmp_path / "plys", tmp_path / "prev.gif"
    code, out, err = run(capsys, "bake", folder, clip_file, "-o", usd, "--ply-dir", plys, "--preview", gif,
                         "--preview-size", 48, "--chunk-frames", 2, *FAST)
    assert code == 0, err
    assert "baked 5 frames" in out and "frames/s" in out and "USD stage" in out
    assert " MB" in out or " kB" in out

    # the same bake in memory
    config = BakeConfig(sim=SimConfig(substeps=2, iterations=6), preroll=0.2)
    static, frames = bake(load_avatar(folder), load_clip(clip_file), config)
    frames = list(frames)

    stage = Usd.Stage.Open(str(usd))
    assert validate_stage(stage) == []
    assert stage.GetTimeCodesPerSecond() == 25 and stage.GetEndTimeCode() == 4
    face = UsdVol.ParticleField3DGaussianSplat(stage.GetPrimAtPath("/Avatar/Face"))
    hair = stage.GetPrimAtPath("/Avatar/Hair")
    assert face and hair.GetTypeName() == "ParticleField3DGaussianSplat"
    positions = face.GetPrim().GetAttribute("positions")
    assert len(positions.GetTimeSamples()) == 5
    for k in (0, 3):
        got = np.asarray(positions.Get(k))
        assert np.array_equal(got, frames[k].face.means)
        hair_pos = np.asarray(hair.GetAttribute("positions").Get(k))
        assert np.array_equal(hair_pos, frames[k].hair.means)
        head = np.asarray(stage.GetPrimAtPath("/Avatar/Head").GetAttribute("points").Get(k))
        assert np.array_equal(head, frames[k].head_vertices)

    seq = json.loads((plys / "sequence.json").read_text())
    assert seq["frame_count"] == 5 and seq["fps"] == 25
    ply = PlyData.read(str(plys / "frame_00003.ply"))["vertex"]
    n_face = len(frames[3].face.means)
    xyz = np.stack([ply["x"], ply["y"], ply["z"]], axis=1)
    assert np.array_equal(xyz[:n_face], frames[3].face.means)
    assert np.array_equal(xyz[n_face:], frames[3].hair.means)

    assert len(read_video_frames(gif)) == 5


def test_bake_ply_only_with_a_frame_range_and_static_hair(folder, clip_file, tmp_path, capsys):
    plys = tmp_path / "seq"
    code, out, err = run(capsys, "bake", folder, clip_file, "--ply-dir", plys, "--split", "--frames", "1:3",
                         "--static-hair", "-q", "--ply-frame", "ydown")
    assert code == 0, err
    assert out == "" and err == ""
    names = sorted(p.name for p in plys.iterdir())
    assert names == ["face_00000.ply", "face_00001.ply", "hair_00000.ply", "hair_00001.ply", "sequence.json"]
    assert json.loads((plys / "sequence.json").read_text())["ply_frame"] == "ydown"


def test_avatar_info_and_inspect(folder, capsys):
    code, out, err = run(capsys, "avatar", "info", folder, "--check")
    assert code == 0, err
    assert "avatar folder" in out and "bald Gaussians" in out and "ok" in out
    code, out, err = run(capsys, "inspect", folder, "--json")
    assert code == 0, err
    assert json.loads(out)["kind"] == "avatar folder"


def _one_line_error(code, err, *words):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for w in words:
        assert w in lines[0], lines[0]


def test_bad_outputs_fail_before_any_work(folder, clip_file, tmp_path, capsys):
    code, _, err = run(capsys, "bake", tmp_path / "no_avatar", clip_file, "-o", tmp_path / "nowhere" / "x.usdc")
    _one_line_error(code, err, "nowhere", "does not exist")  # the output is checked first
    code, _, err = run(capsys, "bake", folder, clip_file, "-o", tmp_path / "x.abc")
    _one_line_error(code, err, "x.abc", "extension")
    code, _, err = run(capsys, "bake", folder, clip_file, "--preview", tmp_path / "x.avi")
    _one_line_error(code, err, "x.avi")
    (tmp_path / "file").write_text("x")
    code, _, err = run(capsys, "bake", folder, clip_file, "--ply-dir", tmp_path / "file")
    _one_line_error(code, err, "not a folder")
    code, _, err = run(capsys, "bake", folder, clip_file)
    _one_line_error(code, err, "nothing to write")
    code, _, err = run(capsys, "bake", folder, clip_file, "-o", tmp_path / "x.usdc", "--split")
    _one_line_error(code, err, "--split")
    code, _, err = run(capsys, "bake", folder, clip_file, "-o", tmp_path / "x.usdc", "--ply-frame", "ydown")
    _one_line_error(code, err, "--ply-frame")
    code, _, err = run(capsys, "bake", folder, clip_file, "-o", tmp_path / "x.usdc", "--frames", "a:b")
    _one_line_error(code, err, "a:b")
    code, _, err = run(capsys, "bake", folder, clip_file, "-o", tmp_path / "x.usdc", "--gravity", "0,1")
    _one_line_error(code, err, "--gravity")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_bad_avatar_and_clip_inputs(folder, clip_file, tmp_path, capsys):
    out = tmp_path / "x.usdc"
    code, _, err = run(capsys, "bake", tmp_path / "missing", clip_file, "-o", out)
    _one_line_error(code, err, "missing", "not found")
    broken = Path(shutil.copytree(folder, tmp_path / "broken"))
    data = (broken / "bald.ply").read_bytes()
    (broken / "bald.ply").write_bytes(data[:len(data) // 3])
    code, _, err = run(capsys, "bake", broken, clip_file, "-o", out)
    _one_line_error(code, err, "bald.ply")
    # a clip for another head model: SMPL-X-like eyes (3 numbers per frame)
    other = tmp_path / "other.npz"
    z = dict(np.load(clip_file))
    z["eyes_pose"] = z["eyes_pose"][:, :3]
    np.savez(other, **z)
    code, _, err = run(capsys, "bake", folder, other, "-o", out)
    _one_line_error(code, err, "other.npz", "eyes_pose")
    # a clip in millimetres
    mm = tmp_path / "mm.npz"
    z = dict(np.load(clip_file))
    z["translation"] = z["translation"] + 250.0
    np.savez(mm, **z)
    code, _, err = run(capsys, "bake", folder, mm, "-o", out)
    _one_line_error(code, err, "mm.npz", "millimetres")
    code, _, err = run(capsys, "bake", folder, clip_file, "-o", out, "--frames", "10:20")
    _one_line_error(code, err, "shake.npz", "empty")
    assert not out.exists()


def test_interrupted_bake_leaves_nothing(folder, clip_file, tmp_path, capsys, monkeypatch):
    from avatarkit.export.ply_sequence import PlySequenceWriter

    real = PlySequenceWriter.write

    def write(self, frame):
        if frame.index == 2:
            raise KeyboardInterrupt
        real(self, frame)

    monkeypatch.setattr(PlySequenceWriter, "write", write)
    usd, plys, gif = tmp_path / "out.usdc", tmp_path / "plys", tmp_path / "prev.gif"
    code, _, err = run(capsys, "bake", folder, clip_file, "-o", usd, "--ply-dir", plys, "--preview", gif,
                       "--preview-size", 32, *FAST)
    assert code == 130 and "interrupted" in err
    assert list(tmp_path.iterdir()) == []  # no stage, no clip layers, no frames, no video, no temp


def test_warnings_are_one_line_each(folder, tmp_path, capsys):
    clip = make_clip("talk", frames=10, fps=25, expr_dims=40, seed=1)  # talk moves expressions
    expr = clip.expr.copy()
    expr[:, 30] = 0.3  # beyond the template's 9 coefficients
    path = tmp_path / "talk.npz"
    save_clip(path, clip.replace(expr=expr))
    code, out, err = run(capsys, "bake", folder, path, "--ply-dir", tmp_path / "p", "--static-hair")
    assert code == 0, err
    warns = [line for line in err.splitlines() if line.startswith("warning:")]
    assert len(warns) == 1 and "expression coefficients" in warns[0]


@pytest.mark.slow
def test_sample_command_and_full_bake(tmp_path, capsys):
    """The real thing at a moderate size: `avatar sample`, then a usdz + half + orbit mp4 bake."""
    av = tmp_path / "sample"
    code, out, err = run(capsys, "avatar", "sample", "-o", av, "--n-hair", 8000, "--n-bald", 8000,
                         "--hair-style", "bob")
    assert code == 0, err
    assert "wrote" in out and (av / "avatar.json").is_file()
    clip = tmp_path / "whip.npz"
    assert run(capsys, "motion", "make", "whip", "--frames", 30, "-o", clip)[0] == 0
    usdz, mp4 = tmp_path / "whip.usdz", tmp_path / "whip.mp4"
    code, out, err = run(capsys, "bake", av, clip, "-o", usdz, "--half", "--preview", mp4, "--orbit",
                         "--preview-size", 96, "--chunk-frames", 8)
    assert code == 0, err
    from pxr import Usd

    from avatarkit.gaussians.usd import validate_stage
    stage = Usd.Stage.Open(str(usdz))
    assert validate_stage(stage) == []
    assert len(stage.GetPrimAtPath("/Avatar/Hair").GetAttribute("positionsh").GetTimeSamples()) == 30
    code, out, err = run(capsys, "bake", av, clip, "-o", tmp_path / "pts.usdc", "--usd-points",
                         "--frames", ":6", "--collision", "vertex")
    assert code == 0, err
    stage = Usd.Stage.Open(str(tmp_path / "pts.usdc"))
    assert stage.GetPrimAtPath("/Avatar/Hair").GetTypeName() == "Points"



def test_rigid_hair_avatars_bake_static_by_default(folder, clip_file, tmp_path):
    """An avatar built with short (rigid) hair bakes without dynamics unless asked; the stage's
    provenance records what was decided."""
    from pxr import Usd

    from avatarkit.avatar import load_avatar

    avatar = load_avatar(folder)
    avatar.provenance["hair_mode"] = "rigid"
    rigid = tmp_path / "rigid"
    avatar.save(rigid, preview=False)
    assert load_avatar(rigid).hair_mode == "rigid"
    for source, args, want in ((rigid, [], True), (rigid, ["--dynamic-hair"], False),
                               (folder, [], False), (folder, ["--static-hair"], True)):
        out = tmp_path / f"o{source.name}{len(args)}{want}.usda"
        assert main(["bake", str(source), str(clip_file), "-o", str(out), "-q", *FAST, *args]) == 0
        stage = Usd.Stage.Open(str(out))  # held: the layer dies with the stage
        data = stage.GetRootLayer().customLayerData["avatarkit"]
        assert data["provenance"]["settings"]["sim"]["static"] is want
