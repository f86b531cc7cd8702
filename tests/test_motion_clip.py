"""MotionClip: validation, slice, resample (slerp / linear), expression dimensions."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avatarkit.errors import InputError
from avatarkit.motion import ExprDimsWarning, MotionClip


def random_clip(n=20, fps=25.0, expr_dims=10, seed=0) -> MotionClip:
    rng = np.random.default_rng(seed)
    r = lambda w, s=0.3: rng.normal(scale=s, size=(n, w))  # noqa: E731
    return MotionClip(fps, r(3), r(3, 0.01), r(3, 0.05), r(3, 0.1), r(6, 0.1), r(expr_dims, 1.0),
                      rng.normal(size=50), name="random")


def test_basic_properties():
    c = random_clip(20, 25.0)
    assert c.n_frames == len(c) == 20
    assert c.duration == pytest.approx(0.8)
    np.testing.assert_allclose(c.times, np.arange(20) / 25)
    assert c.expr_dims == 10 and c.shape.shape == (50,)
    assert c.pose.shape == (20, 15)
    np.testing.assert_array_equal(c.pose[:, 6:9], c.jaw)
    assert all(getattr(c, k).dtype == np.float32 for k in ("rotation", "eyes", "expr", "shape"))


def test_rest_clip_is_zero():
    c = MotionClip.rest(5, 30.0, expr_dims=7, shape_dims=3)
    assert c.n_frames == 5 and c.fps == 30.0 and c.expr.shape == (5, 7) and c.shape.shape == (3,)
    assert not np.any(c.pose) and not np.any(c.expr)


@pytest.mark.parametrize("change, match", [
    ({"jaw": np.zeros((19, 3))}, "'jaw' has 19 frames but the clip has 20"),
    ({"eyes": np.zeros((20, 3))}, r"'eyes' must have shape \(T, 6\), got \(20, 3\)"),
    ({"expr": np.zeros(20)}, r"'expr' must have shape \(T, E\)"),
    ({"neck": np.full((20, 3), np.nan)}, "'neck' has a non-finite value at frame 0"),
    ({"fps": 0}, "fps must be a positive number"),
    ({"fps": float("inf")}, "fps must be a positive number"),
    ({"shape": np.zeros((2, 2))}, r"'shape' must have shape \(S,\)"),
    ({"rotation": np.zeros((0, 3)), "translation": np.zeros((0, 3))}, "at least one frame"),
    ({"rotation": "abc"}, "not a numeric array"),
])
def test_validation_errors(change, match):
    with pytest.raises(InputError, match=match):
        random_clip().replace(**change)


def test_nan_in_a_later_frame_names_the_frame():
    c = random_clip()
    expr = c.expr.copy()
    expr[7, 3] = np.inf
    with pytest.raises(InputError, match="'expr' has a non-finite value at frame 7"):
        c.replace(expr=expr)


def test_slice():
    c = random_clip(20)
    s = c.slice(5, 12)
    assert s.n_frames == 7 and s.fps == c.fps and s.name == c.name
    np.testing.assert_array_equal(s.expr, c.expr[5:12])
    np.testing.assert_array_equal(s.shape, c.shape)
    np.testing.assert_array_equal(c.slice(-3).jaw, c.jaw[-3:])
    with pytest.raises(InputError, match="empty"):
        c.slice(15, 10)


def test_resample_to_same_rate_is_identity():
    c = random_clip(30)
    r = c.resample(c.fps)
    assert r.n_frames == c.n_frames
    for key in ("rotation", "neck", "jaw", "eyes", "translation", "expr"):
        np.testing.assert_allclose(getattr(r, key), getattr(c, key), atol=1e-6)


def test_resample_keeps_first_and_last_time():
    c = random_clip(26, fps=25.0)  # 1.0 s from first to last frame
    up = c.resample(60.0)
    assert up.n_frames == 61 and up.fps == 60.0
    np.testing.assert_allclose(up.translation[[0, -1]], c.translation[[0, -1]], atol=1e-7)
    down = c.resample(10.0)
    assert down.n_frames == 11
    np.testing.assert_allclose(down.expr[::2], c.expr[::5], atol=1e-6)  # shared sample times


def test_resample_interpolates_translation_linearly():
    n = 11
    c = MotionClip.rest(n, 10.0, expr_dims=2).replace(
        translation=np.outer(np.arange(n) ** 2, [1.0, 0, 0]) * 1e-3,
        expr=np.stack([np.arange(n), -np.arange(n)], 1).astype(float))
    r = c.resample(20.0)
    t = np.arange(r.n_frames) / 20.0 * 10.0  # old frame units
    lo = np.floor(t)
    expect = (lo ** 2 + (t - lo) * ((lo + 1) ** 2 - lo ** 2)) * 1e-3
    np.testing.assert_allclose(r.translation[:, 0], expect, atol=1e-7)
    np.testing.assert_allclose(r.expr[:, 0], t, atol=1e-6)


def test_resample_slerps_rotations():
    # constant angular velocity about a tilted axis: slerp reproduces the exact in-between poses
    axis = np.array([0.3, 0.8, -0.52])
    axis /= np.linalg.norm(axis)
    angles = np.linspace(0, 1.2, 7)
    c = MotionClip.rest(7, 6.0).replace(rotation=np.outer(angles, axis), neck=np.outer(angles[::-1], axis))
    r = c.resample(24.0)
    fine = np.linspace(0, 1.2, r.n_frames)
    np.testing.assert_allclose(r.rotation, np.outer(fine, axis), atol=1e-6)
    np.testing.assert_allclose(r.neck, np.outer(fine[::-1], axis), atol=1e-6)


def test_resample_takes_the_short_way_round():
    # 170 deg -> -170 deg about y is a 20 deg step through 180, not a 340 deg swing through 0
    c = MotionClip.rest(2, 1.0).replace(rotation=np.deg2rad([[0, 170, 0], [0, -170, 0]]))
    mid = c.resample(2.0).rotation[1]
    assert Rotation.from_rotvec(mid).magnitude() == pytest.approx(np.pi, abs=1e-6)


def test_with_expr_dims_truncates_and_pads_with_warnings():
    c = random_clip(expr_dims=10)
    assert c.with_expr_dims(10) is c
    with pytest.warns(ExprDimsWarning, match="dropped the last 6"):
        t = c.with_expr_dims(4)
    np.testing.assert_array_equal(t.expr, c.expr[:, :4])
    with pytest.warns(ExprDimsWarning, match="padded with zeros"):
        p = c.with_expr_dims(16)
    np.testing.assert_array_equal(p.expr[:, :10], c.expr)
    assert not np.any(p.expr[:, 10:])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c.with_expr_dims(10)
    with pytest.raises(InputError):
        c.with_expr_dims(-1)
