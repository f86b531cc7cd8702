"""`avatarkit motion ...`: exit codes, outputs, messages."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.cli.main import COMMANDS, main
from avatarkit.motion import KINDS, load_clip, make_clip, save_clip


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_registered_and_kinds_agree():
    from avatarkit.cli import motion_cmd

    assert COMMANDS["motion"] == "avatarkit.cli.motion_cmd:motion"
    assert motion_cmd._KINDS == KINDS


def test_make_writes_the_clip(tmp_path, capsys):
    code, out, err = run(capsys, "motion", "make", "nod", "-o", str(tmp_path / "nod.npz"))
    assert code == 0, err
    assert "50 frames at 25 fps" in out
    got, ref = load_clip(tmp_path / "nod.npz"), make_clip("nod")
    np.testing.assert_array_equal(got.rotation, ref.rotation)
    assert got.fps == 25.0 and got.name == "nod"


def test_make_options_and_json(tmp_path, capsys):
    out_path = tmp_path / "s.json"
    code, _, err = run(capsys, "motion", "make", "shake", "--frames", "40", "--fps", "30",
                       "--amplitude", "20", "--expr-dims", "10", "-q", "-o", str(out_path))
    assert code == 0, err
    c = load_clip(out_path)
    assert c.n_frames == 40 and c.fps == 30.0 and c.expr_dims == 10
    assert np.rad2deg(np.abs(c.rotation[:, 1]).max()) <= 20 * (1 + 1e-5)


def test_inspect(tmp_path, capsys):
    run(capsys, "motion", "make", "whip", "-q", "-o", str(tmp_path / "w.npz"))
    code, out, _ = run(capsys, "motion", "inspect", str(tmp_path / "w.npz"))
    assert code == 0
    assert "75 at 25 fps (3.000 s)" in out
    line = next(l for l in out.splitlines() if l.strip().startswith("rotation"))
    assert "-60.00..60.00" in line and line.rstrip().endswith("60.00 deg")


def test_bad_input_exits_2_with_one_line(tmp_path, capsys):
    code, out, err = run(capsys, "motion", "inspect", str(tmp_path / "missing.npz"))
    assert code == 2 and out == ""
    assert err.strip() == f"error: {tmp_path / 'missing.npz'}: no such file or folder"
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    code, _, err = run(capsys, "motion", "inspect", str(tmp_path / "bad.npz"))
    assert code == 2 and "bad.npz: not a readable .npz" in err and "Traceback" not in err


def test_make_bad_arguments(tmp_path, capsys):
    code, _, err = run(capsys, "motion", "make", "nod", "-o", str(tmp_path / "nod.txt"))
    assert code == 2 and "cannot write a motion clip as '.txt'" in err
    code, _, _ = run(capsys, "motion", "make", "dance", "-o", str(tmp_path / "d.npz"))
    assert code == 2
    code, _, _ = run(capsys, "motion", "make", "nod", "--frames", "1", "-o", str(tmp_path / "n.npz"))
    assert code == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_convert_and_resample(tmp_path, capsys):
    folder = tmp_path / "flame_param"
    folder.mkdir()
    clip = make_clip("talk", frames=12, expr_dims=5)
    for i in range(12):
        np.savez(folder / f"{i:05d}.npz", rotation=clip.rotation[[i]], translation=clip.translation[[i]],
                 neck_pose=clip.neck[[i]], jaw_pose=clip.jaw[[i]], eyes_pose=clip.eyes[[i]],
                 expr=clip.expr[[i]], shape=np.zeros(3))
    code, out, err = run(capsys, "motion", "convert", str(folder), "--fps", "30", "--start", "2",
                         "-o", str(tmp_path / "c.json"))
    assert code == 0, err
    c = load_clip(tmp_path / "c.json")
    assert c.n_frames == 10 and c.fps == 30.0
    np.testing.assert_array_equal(c.jaw, clip.jaw[2:])
    code, out, err = run(capsys, "motion", "resample", str(tmp_path / "c.json"), "--to-fps", "60",
                         "-o", str(tmp_path / "r.npz"))
    assert code == 0, err
    assert load_clip(tmp_path / "r.npz").n_frames == 19


def test_inspector_for_avatarkit_inspect(tmp_path, monkeypatch):
    inspect_mod = pytest.importorskip("avatarkit.inspect")
    from avatarkit.motion.inspector import is_motion_clip

    # a private copy of the registry, so this test leaves the global one as it was
    monkeypatch.setattr(inspect_mod, "_inspectors", list(inspect_mod._inspectors))
    inspect_mod.register_inspector(is_motion_clip, "avatarkit.motion.inspector:inspect_clip")
    clip = make_clip("turn", expr_dims=4)
    save_clip(tmp_path / "t.npz", clip)
    save_clip(tmp_path / "t.json", clip)
    for path in (tmp_path / "t.npz", tmp_path / "t.json"):
        s = inspect_mod.inspect_file(path)
        assert s.kind == "motion clip" and s.get("frames") == 75 and s.get("fps") == 25.0
        assert s.get("rotation (deg)") == "x 0.00..0.00, y -40.00..40.00, z 0.00..0.00; peak 40.00"
        assert s.to_dict()["duration_s"] == 3.0
    (tmp_path / "other.json").write_text('{"format": "something else"}')
    np.savez(tmp_path / "model.npz", v_template=np.zeros((3, 3)))
    assert not is_motion_clip(tmp_path / "other.json") and not is_motion_clip(tmp_path / "model.npz")
    assert not is_motion_clip(tmp_path / "missing.npz")
