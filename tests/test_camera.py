"""Camera: constructors, conventions, JSON round trip (bench format), validation."""
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from avatarkit.errors import FormatError, InputError
from avatarkit.gaussians import GaussianSet
from avatarkit.render import Camera, frame_camera, framing, turntable_cameras

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"  # the standard scene generator


def _is_rotation(r):
    return np.allclose(r @ r.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(r), 1.0)


def test_from_fov_intrinsics():
    cam = Camera.from_fov(60.0, 640, 480)
    assert cam.fy == pytest.approx(240 / math.tan(math.radians(30)))
    assert cam.fx == cam.fy
    assert (cam.cx, cam.cy) == (320, 240)
    # the top and bottom image edges are 30 degrees off the axis
    uv, _ = cam.project([[0.0, -math.tan(math.radians(30)), 1.0]])
    assert uv[0, 1] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(cam.camera_center, 0, atol=1e-12)


def test_look_at_target_on_principal_point_and_up_is_up():
    rng = np.random.default_rng(1)
    for _ in range(20):
        eye, target = rng.normal(size=3) * 2, rng.normal(size=3) * 0.3
        cam = Camera.look_at(eye, target, fov_deg=40, width=200, height=100)
        assert _is_rotation(cam.rotation)
        np.testing.assert_allclose(cam.camera_center, eye, atol=1e-12)
        uv, z = cam.project([target])
        np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-9)
        assert z[0] == pytest.approx(np.linalg.norm(target - eye))
        # a point above the target (world +Y) is higher in the image (smaller v)
        uv_up, _ = cam.project([target + [0, 0.01, 0]])
        assert uv_up[0, 1] < cam.cy


def test_orbit_front_view_looks_down_minus_z():
    cam = Camera.orbit((0, 0, 0), 0, 0, 2.0, 30, 64, 64)
    np.testing.assert_allclose(cam.camera_center, [0, 0, 2.0], atol=1e-12)
    np.testing.assert_allclose(cam.rotation[2], [0, 0, -1], atol=1e-12)   # camera z = -Z world
    np.testing.assert_allclose(cam.rotation[0], [1, 0, 0], atol=1e-12)    # image right = +X
    np.testing.assert_allclose(cam.rotation[1], [0, -1, 0], atol=1e-12)   # image down = -Y
    uv, _ = cam.project([[0.1, 0, 0], [0, 0.1, 0]])
    assert uv[0, 0] > cam.cx and uv[1, 1] < cam.cy


def test_orbit_azimuth_elevation_and_poles():
    target = np.array([0.1, 1.6, -0.2])
    cam = Camera.orbit(target, 90, 0, 1.5)
    np.testing.assert_allclose(cam.camera_center, target + [1.5, 0, 0], atol=1e-12)
    cam = Camera.orbit(target, 0, 30, 2.0)
    np.testing.assert_allclose(cam.camera_center - target,
                               [0, 2 * math.sin(math.radians(30)), 2 * math.cos(math.radians(30))],
                               atol=1e-12)
    for el in (90, -90):
        cam = Camera.orbit(target, 37, el, 1.0)
        assert _is_rotation(cam.rotation)
        uv, z = cam.project([target])
        np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-9)
        assert z[0] == pytest.approx(1.0)


def test_json_round_trip_and_bench_format(tmp_path):
    sys.path.insert(0, str(BENCH))
    try:
        from make_scene import make_scene
    finally:
        sys.path.remove(str(BENCH))
    *_, bench = make_scene(10, 96, 64)
    path = tmp_path / "bench.camera.json"
    path.write_text(json.dumps(bench))
    cam = Camera.from_json(path)
    assert (cam.width, cam.height, cam.cx, cam.cy) == (96, 64, 48, 32)
    np.testing.assert_array_equal(cam.world_to_camera, np.eye(4))

    cam = Camera.orbit((0.1, 0.2, 0.3), 33, -12, 0.8, 25, 320, 240)
    out = tmp_path / "cam.json"
    cam.to_json(out)
    d = json.loads(out.read_text())
    assert d["convention"] == "opencv" and set(bench) == set(d)
    back = Camera.from_json(out)
    for k in ("fx", "fy", "cx", "cy", "width", "height"):
        assert getattr(back, k) == getattr(cam, k)
    np.testing.assert_array_equal(back.world_to_camera, cam.world_to_camera)


def test_opengl_convention_is_converted():
    cam = Camera.orbit((0, 0, 0), 20, 10, 3.0)
    d = cam.to_dict()
    d["world_to_camera"] = (np.diag([1.0, -1, -1, 1]) @ cam.world_to_camera).tolist()
    d["convention"] = "opengl"
    np.testing.assert_allclose(Camera.from_dict(d).world_to_camera, cam.world_to_camera, atol=1e-12)


@pytest.mark.parametrize("changes, words", [
    (dict(width=0), "width"), (dict(height=-3), "height"), (dict(width=12.5), "width"),
    (dict(fx=float("nan")), "fx"), (dict(fy=0.0), "focal"), (dict(cx=float("inf")), "cx"),
    (dict(world_to_camera=np.diag([1.0, 1, -1, 1])), "rotation"),
    (dict(world_to_camera=np.diag([2.0, 1, 1, 1])), "rotation"),
    (dict(world_to_camera=np.eye(3)), "4x4"),
    (dict(world_to_camera=np.full((4, 4), np.nan)), "non-finite"),
])
def test_bad_camera_values(changes, words):
    args = dict(fx=100.0, fy=100.0, cx=32.0, cy=32.0, width=64, height=64, world_to_camera=np.eye(4))
    args.update(changes)
    with pytest.raises(InputError, match=words):
        Camera(**args)


def test_bad_constructor_arguments():
    with pytest.raises(InputError, match="same point"):
        Camera.look_at((1, 2, 3), (1, 2, 3))
    with pytest.raises(InputError, match="parallel"):
        Camera.look_at((0, 2, 0), (0, 0, 0), up=(0, 1, 0))
    with pytest.raises(InputError, match="field of view"):
        Camera.from_fov(180, 10, 10)
    with pytest.raises(InputError, match="distance"):
        Camera.orbit((0, 0, 0), 0, 0, -1.0)
    with pytest.raises(InputError, match="finite"):
        Camera.orbit((0, float("nan"), 0), 0, 0, 1.0)


def test_bad_json_files(tmp_path):
    with pytest.raises(InputError, match="not found") as e:
        Camera.from_json(tmp_path / "missing.json")
    assert "missing.json" in str(e.value)
    p = tmp_path / "garbage.json"
    p.write_text("{ nope")
    with pytest.raises(FormatError, match="garbage.json: not valid JSON"):
        Camera.from_json(p)
    p.write_text("[1, 2]")
    with pytest.raises(FormatError, match="JSON object"):
        Camera.from_json(p)
    good = Camera.from_fov(30, 8, 8).to_dict()
    for key, value, words in [("convention", "blender", "convention"), ("width", -8, "width"),
                              ("world_to_camera", [[1, 0], [0, 1]], "4x4"), ("fx", "abc", "fx")]:
        d = dict(good, **{key: value})
        p.write_text(json.dumps(d))
        with pytest.raises(InputError, match=words) as e:
            Camera.from_json(p)
        assert str(e.value).startswith(str(p))
    del good["fx"]
    p.write_text(json.dumps(good))
    with pytest.raises(FormatError, match="missing fx"):
        Camera.from_json(p)


def test_with_size_keeps_the_view():
    cam = Camera.orbit((0, 0, 0), 10, 5, 2.0, 30, 200, 100)
    small = cam.with_size(100, 50)
    pts = np.random.default_rng(0).normal(size=(10, 3)) * 0.2
    np.testing.assert_allclose(small.project(pts)[0], cam.project(pts)[0] / 2, atol=1e-9)


def test_frame_camera_sees_every_point_and_turntable():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(50, 3)) * [0.1, 0.15, 0.1] + [0, 1.6, 0]
    gs = GaussianSet.from_colors(pts, np.tile([1.0, 0, 0, 0], (50, 1)), np.full((50, 3), 0.01),
                                 np.full(50, 0.5), np.full((50, 3), 0.5))
    for az in (0, 45, 180, 300):
        cam = frame_camera(gs, az, 20, width=160, height=90)
        uv, z = cam.project(pts)
        assert (z > 0).all()
        assert (uv >= 0).all() and (uv[:, 0] <= 160).all() and (uv[:, 1] <= 90).all()
    target, dist = framing(gs)
    cams = turntable_cameras(8, gs, elevation_deg=0)
    assert len(cams) == 8
    centers = np.array([c.camera_center for c in cams])
    np.testing.assert_allclose(np.linalg.norm(centers - target, axis=1), dist)
    np.testing.assert_allclose(centers[0], target + [0, 0, dist], atol=1e-9)
    np.testing.assert_allclose(centers[2], target + [dist, 0, 0], atol=1e-9)
    with pytest.raises(InputError, match="positive"):
        turntable_cameras(0, gs)
    with pytest.raises(InputError, match="empty"):
        frame_camera(GaussianSet.empty())
