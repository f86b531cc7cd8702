"""`avatarkit head export / info`: meshes that load back, posing options, one-line errors."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from avatarkit.cli.main import main
from avatarkit.head import HeadParams, load_template


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def head():
    return load_template()


@pytest.mark.parametrize("ext", [".ply", ".obj", ".glb"])
def test_export_template_loads_back(tmp_path, capsys, head, ext):
    out = tmp_path / f"head{ext}"
    code, stdout, _ = run(capsys, "head", "export", "-o", out)
    assert code == 0 and "wrote" in stdout
    mesh = trimesh.load(out, force="mesh", process=False)
    assert len(mesh.faces) == head.num_faces
    assert mesh.is_watertight
    if ext == ".ply":
        np.testing.assert_allclose(mesh.vertices, head.v_template, atol=1e-6)
        colors = mesh.visual.vertex_colors[:, :3]
        assert (colors[head.regions["left_iris"]] != colors[head.regions["scalp"][:1]]).any()


def test_export_with_expression_and_jaw(tmp_path, capsys, head):
    out = tmp_path / "smile.ply"
    code, _, _ = run(capsys, "head", "export", "--expr", "smile=1", "--expr", "blink_left=1", "--jaw", "0.2",
                     "-o", out, "-q")
    assert code == 0
    e = np.zeros((1, head.num_expr))
    e[0, head.expression_names.index("smile")] = 1
    e[0, head.expression_names.index("blink_left")] = 1
    expect, _ = head.forward(HeadParams(expr=e, jaw=[[0.2, 0, 0]]))
    np.testing.assert_allclose(trimesh.load(out, process=False).vertices, expect[0], atol=1e-6)


def test_export_posed_by_clip_frame(tmp_path, capsys, head):
    motion = pytest.importorskip("avatarkit.motion")
    clip = motion.make_clip("nod", frames=10, expr_dims=0)
    path = tmp_path / "nod.npz"
    motion.save_clip(path, clip)
    out = tmp_path / "nod5.ply"
    assert run(capsys, "head", "export", "--clip", path, "--frame", 5, "-o", out, "-q")[0] == 0
    expect, _ = head.forward(HeadParams.from_clip(clip, frames=[5]))
    np.testing.assert_allclose(trimesh.load(out, process=False).vertices, expect[0], atol=1e-5)
    code, _, err = run(capsys, "head", "export", "--clip", path, "--frame", 99, "-o", tmp_path / "x.ply")
    assert code == 2 and "outside the clip's 10 frames" in err and not (tmp_path / "x.ply").exists()
    # a FLAME-tracked clip (100 expression coefficients) on the template: one warning line
    expr = np.zeros((10, 100), np.float32)
    expr[:, 50] = 0.5
    flame_clip = motion.make_clip("nod", frames=10, expr_dims=100).replace(expr=expr)
    flame_path = tmp_path / "talk.npz"
    motion.save_clip(flame_path, flame_clip)
    code, _, err = run(capsys, "head", "export", "--clip", flame_path, "--frame", 4, "-o", tmp_path / "t.ply")
    lines = err.strip().splitlines()
    assert code == 0 and len(lines) == 1 and lines[0].startswith("warning: expr has 100 coefficients")


@pytest.mark.parametrize("args,message", [
    (["-o", "{tmp}/head.xyz"], "unknown mesh format"),
    (["--expr", "grin=1", "-o", "{tmp}/a.ply"], "unknown expression"),
    (["--expr", "smile", "-o", "{tmp}/a.ply"], "NAME=VALUE"),
    (["--frame", "3", "-o", "{tmp}/a.ply"], "--frame needs --clip"),
    (["-o", "{tmp}/missing/a.ply"], "does not exist"),
])
def test_export_errors_are_one_line_and_write_nothing(tmp_path, capsys, args, message):
    args = [a.format(tmp=tmp_path) for a in args]
    code, _, err = run(capsys, "head", "export", *args)
    assert code == 2 and err.startswith("error: ") and message in err
    assert len(err.strip().splitlines()) == 1
    assert not any(tmp_path.rglob("*.ply")) and not any(tmp_path.rglob("*.xyz"))


def test_info(capsys, head):
    code, out, _ = run(capsys, "head", "info", "--json")
    assert code == 0
    d = json.loads(out)
    assert d["vertices"] == head.num_vertices and d["joints"] == ["root", "neck", "jaw", "left_eye", "right_eye"]
    assert d["regions"]["scalp"] == len(head.regions["scalp"])
    code, out, _ = run(capsys, "head", "info")
    assert code == 0 and "template head" in out and "scalp" in out
