"""The face mesh and iris models run on two inputs at once (`landmarks.BATCH`: a region with its
mirror image, the two eyes): the same answers, bit for bit, as one run per input (the
reference, `BATCH = False`)."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.face import landmarks, models

needs_models = pytest.mark.skipif(not models.models_available(), reason="face models not installed")


@needs_models
def test_batched_runs_give_the_one_by_one_answers(monkeypatch):
    from avatarkit.face import detect_faces, face_landmarks
    from avatarkit.recon.fit import synthetic_head_view
    from avatarkit.recon.image_io import read_image

    images = [read_image("samples/portrait.jpg"),
              synthetic_head_view(rotation=np.array([0.1, 0.5, 0.05]), size=512, n_gaussians=20000, seed=1).image]
    assert landmarks.BATCH is True
    for image in images:
        face = max(detect_faces(image), key=lambda f: f.score)
        for kw in ({"mirror": False}, {"mirror": True}, {"mirror": True, "augment": True}):
            got = {}
            for batch in (True, False):
                monkeypatch.setattr(landmarks, "BATCH", batch)
                got[batch] = face_landmarks(image, face, **kw)
            a, b = got[True], got[False]
            for name in ("points", "iris", "eye_contours"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=f"{name} {kw}")
            assert a.presence == b.presence and a.roi == b.roi and a.eye_rois == b.eye_rois


@needs_models
def test_model_outputs_are_not_overwritten_by_the_next_run():
    """`Model.run` hands out LiteRT's `get_tensor` arrays without copying them again: they are
    the caller's (a later run leaves them alone)."""
    rng = np.random.default_rng(0)
    model = models.get_model("landmarks")
    first = model.run(rng.random(model.input_shape, dtype=np.float32))
    kept = [o.copy() for o in first]
    second = model.run(rng.random(model.input_shape, dtype=np.float32))
    for a, b, c in zip(first, kept, second):
        np.testing.assert_array_equal(a, b)
    assert any(not np.array_equal(b, c) for b, c in zip(kept, second))
