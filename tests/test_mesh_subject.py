"""The mesh-made synthetic subject (`synthetic.mesh_head`) and its rasteriser
(`synthetic.mesh_raster`): the batched z-buffer against the per-triangle loop, known-answer
coverage and depth, and the subject's renders."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.render.camera import Camera
from avatarkit.synthetic.mesh_raster import downsample, rasterise, rasterise_reference


def _camera(size: int, distance: float = 1.0) -> Camera:
    return Camera.orbit((0.0, 0.0, 0.0), 20.0, 10.0, distance, 40.0, size, size)


def _icosphere(subdivisions: int = 1, radius: float = 0.2, centre=(0.0, 0.0, 0.0)):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices) + np.asarray(centre), np.asarray(s.faces)


def test_batched_rasteriser_matches_the_triangle_loop():
    # two overlapping spheres: occlusion between meshes and within one
    va, fa = _icosphere(1, 0.2, (0.0, 0.0, 0.0))
    vb, fb = _icosphere(1, 0.12, (0.1, 0.05, 0.15))
    v = np.concatenate([va, vb])
    f = np.concatenate([fa, fb + len(va)])
    attrs = np.concatenate([v, np.repeat([[0.0], [1.0]], [len(va), len(vb)], axis=0)], axis=1)
    cam = _camera(32)
    fast, slow = rasterise(v, f, attrs, cam), rasterise_reference(v, f, attrs, cam)
    np.testing.assert_array_equal(fast.covered, slow.covered)
    assert fast.covered.sum() > 200 and (fast.attributes[..., 3] > 0.5).sum() > 80   # both spheres show (240, 127)
    np.testing.assert_allclose(fast.depth[fast.covered], slow.depth[slow.covered], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.attributes, slow.attributes, rtol=0, atol=1e-12)


def test_rasterised_depth_and_coverage_are_those_of_the_surface():
    # a square facing the camera at known depth: coverage = its projected area, depth exact,
    # interpolated world point = the ray's hit (perspective-correct interpolation)
    cam = Camera.orbit((0.0, 0.0, 0.0), 0.0, 0.0, 1.0, 40.0, 64, 64)
    v = np.array([[-0.1, -0.1, 0.0], [0.1, -0.1, 0.0], [0.1, 0.1, 0.0], [-0.1, 0.1, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    r = rasterise(v, f, v, cam)
    side = 0.2 * cam.fx / 1.0
    assert abs(r.covered.sum() - side ** 2) < 4 * side
    np.testing.assert_allclose(r.depth[r.covered], 1.0, atol=1e-9)
    px, _ = cam.project(r.attributes[r.covered])
    ys, xs = np.nonzero(r.covered)
    np.testing.assert_allclose(px, np.stack([xs + 0.5, ys + 0.5], axis=1), atol=1e-6)
    # tilted: perspective-correct interpolation still lands each pixel's point on its own ray
    tilt = v.copy()
    tilt[:, 2] = np.array([0.1, -0.1, -0.1, 0.1])
    r = rasterise(tilt, f, tilt, cam)
    px, _ = cam.project(r.attributes[r.covered])
    ys, xs = np.nonzero(r.covered)
    np.testing.assert_allclose(px, np.stack([xs + 0.5, ys + 0.5], axis=1), atol=1e-6)


def test_nothing_in_front_of_the_camera_draws_nothing():
    cam = _camera(16)
    v, f = _icosphere(0, 0.1, (0.0, 0.0, 3.0))   # behind the camera (which sits ~1 m out)
    r = rasterise(v, f, np.ones((len(v), 1)), cam)
    assert not r.covered.any() and np.isinf(r.depth).all()
    assert downsample(np.arange(16.0).reshape(4, 4), 2).tolist() == [[2.5, 4.5], [10.5, 12.5]]


@pytest.fixture(scope="module")
def subject():
    from avatarkit.synthetic.mesh_head import MeshHead

    return MeshHead.make()


def test_the_mesh_subject_shows_face_hair_and_eyes_where_they_belong(subject):
    from avatarkit.render.views import frame_camera

    front = frame_camera(subject.bounds(), 0.0, 0.0, width=64, height=64)
    rgb, alpha = subject.render(front)
    assert 0.1 < (alpha > 0.5).mean() < 0.5
    head = rgb[alpha > 0.99]
    # skin dominates the front; the hair cap is darker and on top; the eyes' whites are there
    skin = np.abs(head - np.array([0.86, 0.66, 0.54]) * 0.9).max(axis=1) < 0.15
    assert skin.mean() > 0.3
    rows = np.nonzero((alpha > 0.5).any(axis=1))[0]
    top = rgb[rows[0]:rows[0] + 6][alpha[rows[0]:rows[0] + 6] > 0.99]
    assert top.mean() < 0.4, top.mean()
    back = frame_camera(subject.bounds(), 180.0, 0.0, width=64, height=64)
    rgb_b, alpha_b = subject.render(back)
    upper = rgb_b[:32][alpha_b[:32] > 0.99]
    assert upper.mean() < 0.4       # the back of the head: hair
    # the subject at rest and posed by a zero clip frame are the same picture
    from avatarkit.synthetic.turning_video import turning_clip

    clip = turning_clip(8)
    np.testing.assert_allclose(subject.posed(clip, 0), subject.rest, atol=1e-6)
