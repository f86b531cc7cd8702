"""`avatarkit build`: a small build through the CLI, and bad input -> exit 2, one line naming the
file, and no avatar folder (nor temp folder) left behind."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from avatarkit.cli.main import main

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg"


def _run(args, capsys):
    code = main(list(map(str, args)))
    out, err = capsys.readouterr()
    return code, out, err


def _assert_nothing_left(parent: Path, keep=()):
    left = sorted(p.name for p in parent.iterdir() if p.name not in keep)
    assert left == [], left


def test_help_lists_the_options(capsys):
    code, out, _ = _run(["build", "--help"], capsys)
    assert code == 0
    for opt in ("--hair-mask", "--head-splats", "--bald-splats", "--head-model", "--flame-params",
                "--face-index", "--preview / --no-preview", "-q"):
        assert opt in out


def test_small_build_through_the_cli(tmp_path, capsys):
    out_dir = tmp_path / "avatar"
    code, _, err = _run(["build", SAMPLE, "-o", out_dir, "--n-bald", 3000, "--n-hair", 2000,
                         "--hair-mode", "cage", "--no-preview"], capsys)
    assert code == 0, err
    # one progress line per stage on stderr, with its seconds
    for stage in ("analyse", "segment", "fit", "lift", "assemble", "hair_rig"):
        assert stage in err
    assert "wrote" in err and "s\n" in err
    manifest = json.loads((out_dir / "avatar.json").read_text())
    # the built-in lifter's 3000 and its extra discs (the eyes', the holes'), plus the Gaussians on the head pixels
    # they left uncovered
    cover = manifest["provenance"]["build"]["coverage"]
    extra = manifest["provenance"]["build"]["lift"]["bald_extra"]
    assert manifest["parts"]["bald"]["count"] == 3000 + extra + cover["bald_added"]
    assert manifest["provenance"]["hair_mode"] == "cage"
    assert manifest["provenance"]["source_image"].endswith("portrait.jpg")
    assert not (out_dir / "preview.png").exists()
    _assert_nothing_left(tmp_path, keep=("avatar",))
    # quiet: nothing on stderr
    code, _, err = _run(["build", SAMPLE, "-o", out_dir, "--n-bald", 3000, "--n-hair", 1000,
                         "--no-preview", "-q"], capsys)
    assert code == 0 and err == ""


def test_bald_portrait_builds_a_hairless_avatar(tmp_path, capsys):
    """No hair in the portrait (here: an empty --hair-mask): exit 0, a warning, no hair files."""
    import cv2

    from avatarkit.recon.image_io import read_image

    mask = tmp_path / "no_hair.png"
    cv2.imwrite(str(mask), np.zeros(read_image(SAMPLE).shape[:2], np.uint8))
    out_dir = tmp_path / "avatar"
    code, _, err = _run(["build", SAMPLE, "-o", out_dir, "--hair-mask", mask, "--n-bald", 2000,
                         "--n-hair", 1500, "--no-preview"], capsys)
    assert code == 0, err
    assert "warning: no hair found: building a bald avatar" in err
    assert "no hair (a bald avatar)" in err
    manifest = json.loads((out_dir / "avatar.json").read_text())
    assert set(manifest["parts"]) == {"bald"}
    assert sorted(p.name for p in out_dir.iterdir()) == ["avatar.json", "bald.ply"]


def _bad(capsys, tmp_path, args, *expect):
    out_dir = tmp_path / "out"
    code, _, err = _run(["build", *args, "-o", out_dir], capsys)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert lines[-1].startswith("error: "), err
    assert "Traceback" not in err
    for e in expect:
        assert e in lines[-1], lines[-1]
    assert not out_dir.exists()
    return lines[-1]


def test_unreadable_and_missing_portraits(tmp_path, capsys):
    fake = tmp_path / "photo.jpg"
    fake.write_text("this is not a picture")
    _bad(capsys, tmp_path, [fake], str(fake))
    _bad(capsys, tmp_path, [tmp_path / "missing.jpg"], "missing.jpg")
    _assert_nothing_left(tmp_path, keep=("photo.jpg",))


def test_no_face_several_faces_and_a_small_face(tmp_path, capsys):
    from avatarkit.recon.image_io import read_image, write_image

    blank = tmp_path / "blank.png"
    write_image(blank, np.full((256, 256, 3), 128, np.uint8))
    _bad(capsys, tmp_path, [blank], "no face found", str(blank))
    image = read_image(SAMPLE)
    two = tmp_path / "two.jpg"
    write_image(two, np.concatenate([image, image], axis=1))
    line = _bad(capsys, tmp_path, [two], "found 2 faces", "--face-index")
    assert "[0]" in line and "[1]" in line
    import cv2

    small = tmp_path / "small.png"
    write_image(small, cv2.resize(image, (160, 160), interpolation=cv2.INTER_AREA))
    _bad(capsys, tmp_path, [small], "face is too small", str(small))
    _assert_nothing_left(tmp_path, keep=("blank.png", "two.jpg", "small.png"))


def test_bad_imports_and_options(tmp_path, capsys):
    ply = tmp_path / "head.ply"
    ply.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 500\nproperty float x\n"
                    b"property float y\nend_header\n\x00\x00")
    other = tmp_path / "bald.ply"
    other.write_bytes(ply.read_bytes())
    _bad(capsys, tmp_path, [SAMPLE, "--head-splats", ply, "--bald-splats", other], str(ply))
    _bad(capsys, tmp_path, [SAMPLE, "--head-splats", ply], "--bald-splats")
    _bad(capsys, tmp_path, [SAMPLE, "--flame-params", tmp_path / "nope.npz"], "nope.npz")
    junk = tmp_path / "track.npz"
    junk.write_bytes(b"junk")
    _bad(capsys, tmp_path, [SAMPLE, "--flame-params", junk], str(junk))
    mask = tmp_path / "mask.png"
    mask.write_text("not a png")
    _bad(capsys, tmp_path, [SAMPLE, "--hair-mask", mask], str(mask))
    _bad(capsys, tmp_path, [SAMPLE, "--face-index", 3], "face index 3 is out of range")
    _assert_nothing_left(tmp_path, keep=("head.ply", "bald.ply", "track.npz", "mask.png"))


def test_refuses_to_replace_a_folder_that_is_not_an_avatar(tmp_path, capsys):
    target = tmp_path / "precious"
    target.mkdir()
    (target / "thesis.tex").write_text("do not delete")
    code, _, err = _run(["build", SAMPLE, "-o", target], capsys)
    assert code == 2 and "not an avatar folder" in err
    assert (target / "thesis.tex").read_text() == "do not delete"
