"""The walls behind the synthetic turning videos (`synthetic.walls`): what each is, and that a
render put on a wall image is the render over that colour where the wall is uniform."""
import numpy as np
import pytest

from avatarkit.synthetic.walls import WALLS, over_wall, wall_image


def test_each_wall_is_a_deterministic_image_of_its_kind():
    for kind in WALLS:
        w = wall_image(kind, 64)
        assert w.shape == (64, 64, 3) and w.dtype == np.float32
        assert 0.0 <= w.min() and w.max() <= 1.0
        np.testing.assert_array_equal(w, wall_image(kind, 64))
    assert (wall_image("white", 8) == 1.0).all()
    assert np.ptp(wall_image("dark", 8)) == 0 and wall_image("dark", 8).mean() < 0.3
    teal = wall_image("colour", 8)[0, 0]
    assert teal[1] > 0.5 and teal[0] < 0.1                      # saturated, not grey
    clutter = wall_image("clutter", 96)
    colours = np.unique(np.round(clutter.reshape(-1, 3), 1), axis=0)
    assert len(colours) >= 8                                     # many colours, not a plain wall
    with pytest.raises(ValueError, match="unknown wall"):
        wall_image("brick", 8)


def test_a_splat_video_on_a_uniform_wall_image_is_the_video_on_that_colour():
    """`head_video.avatar_video` with an image background renders over black and adds the wall
    under the coverage: on a uniform image this is the colour background to within a level, and
    on the clutter wall the pixels the head leaves uncovered are the wall's."""
    from avatarkit.export.images import to_uint8
    from avatarkit.synthetic.head_video import avatar_video, head_video_camera
    from avatarkit.synthetic.sample_avatar import make_sample_avatar
    from avatarkit.synthetic.turning_video import turning_clip

    avatar = make_sample_avatar(n_hair=300, n_bald=1500, style="short", cage_vertices=60)
    clip = turning_clip(2)
    camera = head_video_camera(48, distance=0.5)
    on_colour = [f.rgb for f in avatar_video(avatar, clip, camera, (0.22, 0.22, 0.22))]
    on_image = [f.rgb for f in avatar_video(avatar, clip, camera, wall_image("dark", 48))]
    for a, b in zip(on_colour, on_image):
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1
    clutter = wall_image("clutter", 48)
    frame = next(iter(avatar_video(avatar, clip, camera, clutter))).rgb
    np.testing.assert_array_equal(frame[:4, :4], to_uint8(clutter[:4, :4]))   # the corner: no head there


def test_the_mesh_subject_on_a_wall_is_its_render_over_that_colour():
    """`over_wall` of the mesh subject's render over black (its colour premultiplied by its
    supersampled coverage) is its render over the colour, the outline's mixed pixels included."""
    from avatarkit.render.camera import Camera
    from avatarkit.synthetic.mesh_head import MeshHead

    subject = MeshHead.make()
    lo, hi = subject.bounds()
    camera = Camera.orbit((lo + hi) / 2, 30.0, 0.0, 0.6, 35.0, 40, 40)
    rgb0, alpha = subject.render(camera, background=(0.0, 0.0, 0.0))
    teal = wall_image("colour", 40)
    expect, _ = subject.render(camera, background=tuple(float(c) for c in teal[0, 0]))
    assert 0.0 < alpha.mean() < 1.0 and ((alpha > 0) & (alpha < 1)).any()
    np.testing.assert_allclose(over_wall(rgb0, alpha, teal), expect, atol=1e-5)
