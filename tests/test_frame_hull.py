"""The frames' silhouettes bound the avatar (`track.frame_hull`) on cases whose answer is known."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet, rgb_to_dc
from avatarkit.render.camera import Camera
from helpers import plane_grid
from avatarkit.track.frame_hull import carve, wall_image, wall_votes

SIZE = 96


def _plane(xs, ys, z=0.0, opacity=0.99) -> GaussianSet:
    return plane_grid(xs, ys, z, 0.5, opacity)


def _camera():
    return Camera.look_at((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)


def _view(g, cam):
    return SimpleNamespace(gaussians=g, camera=cam)


def _columns(g, cam):
    px, _ = cam.project(g.means)
    return np.asarray(px)[:, 0]


def _left_person(cut=SIZE // 2):
    person = np.zeros((SIZE, SIZE), bool)
    person[:, :cut] = True
    return person


def test_gaussians_every_frame_shows_over_the_wall_are_cleared_those_inside_kept():
    """A plane seen head on; every frame's person covers the image's left half. The Gaussians
    whose footprint lies on the right half (the wall) are cleared, those on the left kept, and
    the ones on the person's outline (within the margin and a footprint) are left alone."""
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    g = _plane(xs, ys)
    cam = _camera()
    wall = wall_image(_left_person(), margin=1)
    assert wall[:, :SIZE // 2 + 1].sum() == 0 and wall[:, SIZE // 2 + 1:].all()
    out = carve([_view(g, cam)] * 4, [wall] * 4)
    col = _columns(g, cam)
    assert out.cleared[col > SIZE / 2 + 4].all()
    assert not out.cleared[col < SIZE / 2 - 2].any()
    assert out.info["frames"] == 4 and out.info["total"] == int(out.cleared.sum())


def test_one_frame_that_disagrees_clears_nothing():
    """Three frames show the whole image as the person and one the right half as wall: under
    the quorum (half of the frames a Gaussian shows in) nothing is cleared; a frame without a
    segmentation (None) does not vote."""
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    g = _plane(xs, ys)
    cam = _camera()
    everyone = wall_image(np.ones((SIZE, SIZE), bool))
    half = wall_image(_left_person())
    views = [_view(g, cam)] * 4
    assert not carve(views, [everyone, everyone, everyone, half]).cleared.any()
    # the same wall in two frames of three that vote: cleared
    out = carve(views, [half, half, everyone, None])
    assert out.info["frames"] == 3 and out.cleared[_columns(g, cam) > SIZE / 2 + 4].all()
    # seen in fewer than min_frames frames: kept
    assert not carve(views[:2], [half, half], min_frames=3).cleared.any()


def test_the_next_round_clears_what_the_first_exposed():
    """Two planes, the back one hidden by the front one: the first round clears the front
    plane's Gaussians over the wall (the back ones do not show), the second the back ones it
    exposed there; the back plane's Gaussians on the person stay."""
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.005)
    front = _plane(xs, ys, 0.0)
    back = _plane(xs[np.abs(xs) < 0.08], ys[np.abs(ys) < 0.08], -0.02)   # inside the front's outline
    g = GaussianSet.concat([front, back])
    cam = _camera()
    wall = wall_image(_left_person())
    n = len(front)
    col = _columns(g, cam)
    one = carve([_view(g, cam)] * 3, [wall] * 3, rounds=1)
    assert one.cleared[:n][col[:n] > SIZE / 2 + 4].all()
    assert not one.cleared[n:].any()
    two = carve([_view(g, cam)] * 3, [wall] * 3, rounds=2)
    assert two.cleared[n:][col[n:] > SIZE / 2 + 4].all()
    assert not two.cleared[:n][col[:n] < SIZE / 2 - 2].any()
    # a back Gaussian by the cut shows only the sliver past the front's edge, on the wall: it
    # may go; well inside, none does
    assert not two.cleared[n:][col[n:] < SIZE / 2 - 8].any()
    assert two.info["cleared"][0] == one.info["total"]


def test_allowed_limits_what_may_be_cleared():
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    g = _plane(xs, ys)
    cam = _camera()
    wall = wall_image(_left_person())
    allowed = np.arange(len(g)) % 2 == 0
    out = carve([_view(g, cam)] * 3, [wall] * 3, allowed=allowed)
    assert out.cleared.any() and not out.cleared[~allowed].any()


def test_a_frame_votes_by_the_share_of_its_blending_weight_on_the_wall():
    """One Gaussian straddling the wall's edge: with its centre on the edge about half its
    weight is on the wall, so it votes outside at share 0.4 and not at 0.6."""
    cam = _camera()
    g = _plane(np.array([0.0]), np.array([0.0]))
    col = _columns(g, cam)[0]
    person = np.zeros((SIZE, SIZE), bool)
    person[:, :int(round(col))] = True
    wall = wall_image(person, margin=0)
    shows, outside = wall_votes(g, cam, wall, share=0.4)
    assert shows[0] and outside[0]
    shows, outside = wall_votes(g, cam, wall, share=0.6)
    assert shows[0] and not outside[0]


def test_one_wall_image_per_view():
    g = _plane(np.array([0.0]), np.array([0.0]))
    with pytest.raises(ValueError):
        carve([_view(g, _camera())] * 2, [None])


def test_the_stage_clears_on_both_avatars_only_when_asked(monkeypatch):
    """`frame_colours._carve`: off (carve False, or None with CARVE off) nothing is asked of the
    frames; on, the Gaussians `carve_frames` clears get opacity 0 on the avatar the views pose
    and on the one the stage returns (bald first, then hair), the others keep theirs."""
    from avatarkit.track import frame_colours as fc
    from avatarkit.track import frame_hull

    def avatar():
        return SimpleNamespace(bald=_plane(np.arange(3) * 0.01, np.array([0.0])),
                               hair=_plane(np.arange(2) * 0.01, np.array([0.0]), opacity=0.7), binding="stale")

    cleared = np.array([False, True, False, True, False])
    asked = []

    def fake(views, allowed=None, **kw):
        asked.append(views)
        return frame_hull.Carved(cleared & (True if allowed is None else allowed), {"total": 2})

    monkeypatch.setattr(frame_hull, "carve_frames", fake)
    saved, built = avatar(), avatar()
    assert fc._carve(saved, built, ["v"], False) is None
    monkeypatch.setattr(frame_hull, "CARVE", False)
    assert fc._carve(saved, built, ["v"], None) is None and not asked
    monkeypatch.setattr(frame_hull, "CARVE", True)
    monkeypatch.setattr(frame_hull, "BALD", True)
    out = fc._carve(saved, built, ["v"], None)
    assert asked == [["v"]] and out.info["total"] == 2
    for a in (saved, built):
        np.testing.assert_array_equal(a.bald.opacities, np.float32([0.99, 0.0, 0.99]))
        np.testing.assert_array_equal(a.hair.opacities, np.float32([0.0, 0.7]))
        assert "binding" not in a.__dict__       # posing rebinds: the cleared discs are not drawn


def test_the_stage_clears_only_the_hair_by_default(monkeypatch):
    """With `frame_hull.BALD` off (the default) the stage lets the vote clear hair only: the bald
    head is one layer of discs, and a cleared outline disc is a hole a side view looks through."""
    from avatarkit.track import frame_colours as fc
    from avatarkit.track import frame_hull

    got = []

    def fake(views, allowed=None, **kw):
        got.append(allowed)
        return frame_hull.Carved(np.ones(5, bool) & (True if allowed is None else allowed), {})

    monkeypatch.setattr(frame_hull, "carve_frames", fake)
    monkeypatch.setattr(frame_hull, "CARVE", True)
    assert frame_hull.BALD is False
    saved = SimpleNamespace(bald=_plane(np.arange(3) * 0.01, np.array([0.0])),
                            hair=_plane(np.arange(2) * 0.01, np.array([0.0]), opacity=0.7))
    fc._carve(saved, saved, ["v"], None)
    np.testing.assert_array_equal(got[0], [False, False, False, True, True])
    np.testing.assert_array_equal(saved.bald.opacities, np.float32([0.99, 0.99, 0.99]))
    np.testing.assert_array_equal(saved.hair.opacities, np.float32([0.0, 0.0]))


def _sphere(n=400, radius=0.05):
    """(n, 3) points on a sphere at the origin (a Fibonacci lattice) and discs on them facing out."""
    from avatarkit.rotations import matrix_to_quat

    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    normal = np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)
    # a frame whose third axis is the normal (the disc's thin axis)
    a = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(normal, a)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    rot = np.stack([u, np.cross(normal, u), normal], 2)
    q = matrix_to_quat(rot)
    return radius * normal, normal, q


def test_recede_moves_the_outline_discs_inward_and_leaves_the_front():
    """A sphere of discs seen head on by four frames whose person is a disc a little smaller
    than the sphere's outline: the discs on the rim (their footprint over the wall) move inward
    along their normal, a step a round; the discs facing the camera (inside the person) stay;
    no disc is cleared (opacities kept), and the rendered outline comes inside the person."""
    from avatarkit.render import render
    from avatarkit.track.frame_hull import recede

    centres, normal, q = _sphere()
    cam = _camera()
    n = len(centres)

    def sphere_set(offsets):
        return GaussianSet(centres + offsets, q, np.tile([0.008, 0.008, 0.0008], (n, 1)), np.full(n, 0.99),
                           rgb_to_dc(np.full((n, 3), 0.5, np.float32)))

    full = render(sphere_set(np.zeros((n, 3))), cam, np.ones(3)).alpha > 0.5
    ys, xs = np.nonzero(full)
    cy, cx = ys.mean(), xs.mean()
    radius_px = np.sqrt(full.sum() / np.pi)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    person = (yy - cy) ** 2 + (xx - cx) ** 2 <= (radius_px - 3) ** 2
    wall = wall_image(person, margin=1)
    poses = []

    def pose(offsets):
        poses.append(offsets.copy())
        return [_view(sphere_set(offsets), cam)] * 4

    out = recede(pose, [wall] * 4, -normal, np.ones(n, bool), step=0.004, rounds=3)
    assert out.moved.any() and out.info["total"] == int(out.moved.sum())
    depth = np.linalg.norm(out.offsets, axis=1)
    # moved along the inward normal only, whole steps, at most `rounds` of them
    np.testing.assert_allclose(out.offsets[out.moved], -normal[out.moved] * depth[out.moved, None], atol=1e-12)
    steps = depth / 0.004
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    assert np.round(steps).max() <= 3 and not depth[~out.moved].any()
    # the discs that face the camera (the middle of the view) stay, the rim's move
    facing = normal[:, 2]
    assert not out.moved[facing > 0.8].any()
    assert out.moved[(np.abs(facing) < 0.2)].mean() > 0.5
    # each round posed the moves so far
    assert len(poses) == len(out.info["moved"]) >= 2 and not poses[0].any() and all(p.any() for p in poses[1:])
    after = render(sphere_set(out.offsets), cam, np.ones(3)).alpha > 0.5
    assert (after & ~person).sum() < (full & ~person).sum() / 2
    # only the movable move
    keep = np.abs(facing) < 0.2
    frozen = recede(pose, [wall] * 4, -normal, ~keep, step=0.004, rounds=3)
    assert not frozen.moved[keep].any()


def test_inward_normals_point_into_the_mesh_whatever_its_winding():
    """A tetrahedron's face normals, wound outward or inward, come back pointing at its inside."""
    from avatarkit.track.frame_hull import inward_normals

    v = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    f = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    for faces in (f, f[:, ::-1]):
        n = inward_normals(v, faces, np.arange(4))
        centres = v[faces].mean(axis=1)
        assert (np.einsum("fk,fk->f", n, -centres) > 0).all()
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)


def test_the_stage_recedes_on_both_avatars_only_when_asked(monkeypatch):
    """`frame_colours._recede`: off (RECEDE off, or the hull did not run) nothing moves; on,
    `recede`'s offsets move the bald discs of the avatar the views pose (its cached binding
    dropped, so posing sees them) and of the one the stage returns; the hair stays."""
    from avatarkit.track import frame_colours as fc
    from avatarkit.track import frame_hull

    v = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    f = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])

    def avatar():
        bald = _plane(np.arange(3) * 0.01, np.array([0.0]))
        bald = bald.replace(extras={"binding": np.array([0, 1, 3], np.int32)})
        a = SimpleNamespace(bald=bald, hair=_plane(np.arange(2) * 0.01, np.array([0.0]), opacity=0.7),
                            rest_head_vertices=v, head_model=SimpleNamespace(faces=f))
        a.binding = "stale"
        return a

    offsets = np.array([[0.0, 0, 0], [0.001, 0.002, 0], [0, 0, -0.003]])
    got = {}

    def fake(pose, walls, normals, movable, **kw):
        got.update(walls=walls, normals=normals, movable=movable, posed=pose(offsets))
        return frame_hull.Receded(offsets, np.array([False, True, True]), {"total": 2})

    monkeypatch.setattr(frame_hull, "recede", fake)
    carved = frame_hull.Carved(np.zeros(5, bool), {}, walls=["w"])
    saved, built = avatar(), avatar()
    before = saved.bald.means.copy()
    monkeypatch.setattr(frame_hull, "RECEDE", False)
    assert fc._recede(saved, built, carved, lambda: "views") is None and not got
    monkeypatch.setattr(frame_hull, "RECEDE", True)
    assert fc._recede(saved, built, None, lambda: "views") is None and not got
    seen = []
    out = fc._recede(saved, built, carved, lambda: seen.append(saved.bald.means.copy()) or "views")
    assert out.info["total"] == 2 and got["walls"] == ["w"] and got["posed"] == "views"
    np.testing.assert_allclose(seen[0], before + offsets, atol=1e-7)
    np.testing.assert_allclose(got["normals"], frame_hull.inward_normals(v, f, [0, 1, 3]))
    for a in (saved, built):
        np.testing.assert_allclose(a.bald.means, before + offsets, atol=1e-7)
        assert "binding" not in a.__dict__
        np.testing.assert_array_equal(a.hair.means, avatar().hair.means)


def test_the_other_gaussians_recede_from_their_own_walls():
    """`recede(other=, other_walls=)`: the sphere's frames show it whole as the person, so no
    disc moves by `walls`; the discs marked other vote with a smaller person (their wall, as
    the neck's is the clothes too) and only the rim's of them move."""
    from avatarkit.track.frame_hull import recede

    centres, normal, q = _sphere()
    cam = _camera()
    n = len(centres)

    def pose(offsets):
        g = GaussianSet(centres + offsets, q, np.tile([0.008, 0.008, 0.0008], (n, 1)), np.full(n, 0.99),
                        rgb_to_dc(np.full((n, 3), 0.5, np.float32)))
        return [_view(g, cam)] * 3

    everyone = wall_image(np.ones((SIZE, SIZE), bool))
    yy, xx = np.mgrid[:SIZE, :SIZE]
    small = wall_image((yy - SIZE / 2) ** 2 + (xx - SIZE / 2) ** 2 <= 8 ** 2)
    assert not recede(pose, [everyone] * 3, -normal, np.ones(n, bool)).moved.any()
    left = centres[:, 0] < 0
    out = recede(pose, [everyone] * 3, -normal, np.ones(n, bool), other_walls=[small] * 3, other=left)
    assert out.moved.any() and not out.moved[~left].any()
    rim = np.abs(normal[:, 2]) < 0.3
    assert out.moved[left & rim].mean() > 0.5


def test_the_necks_wall_is_all_but_skin_and_hair():
    """`neck_walls`: background and body (clothes) are wall, skin and hair (dilated by the
    margin) are not; a frame without labels gives None."""
    from avatarkit.recon.segment import BACKGROUND, BODY, HAIR, SKIN
    from avatarkit.track.frame_hull import neck_walls

    lab = np.full((8, 12), BACKGROUND, np.uint8)
    lab[:, 3:6] = SKIN
    lab[:2, 6:9] = HAIR
    lab[4:, 6:] = BODY
    wall, none = neck_walls([lab, None], margin=0)
    assert none is None
    np.testing.assert_array_equal(wall, ~np.isin(lab, (SKIN, HAIR)))
    grown = neck_walls([lab], margin=1)[0]
    assert not grown[:, 2:7].any() and grown[4:, 8:].all() and grown[:, 0].all()


def test_the_stage_recedes_the_regions_asked_and_the_neck_from_the_clothes(monkeypatch):
    """`frame_colours._recede` hands `recede` the discs of `RECEDE_REGIONS` as movable (None:
    all), and with `CLOTHES_NECK` the neck's discs as `other` with walls made of the frames'
    labels (`neck_walls`: the clothes are wall for them); without labels, no other walls."""
    from avatarkit.recon.segment import BODY, SKIN
    from avatarkit.track import frame_colours as fc
    from avatarkit.track import frame_hull

    v = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    f = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    neck = np.array([False, True, False, True])          # vertices: faces 1 (0, 3, 1) and 3 (1, 3, 2) hold two

    def avatar():
        bald = _plane(np.arange(3) * 0.01, np.array([0.0])).replace(extras={"binding": np.array([0, 1, 3], np.int32)})
        model = SimpleNamespace(faces=f, regions={"neck": np.flatnonzero(neck)}, region_mask=lambda name: neck)
        return SimpleNamespace(bald=bald, hair=_plane(np.arange(2) * 0.01, np.array([0.0])),
                               rest_head_vertices=v, head_model=model)

    got = {}

    def fake(pose, walls, normals, movable, other_walls=None, other=None, **kw):
        got.update(movable=movable, other=other, other_walls=other_walls)
        return frame_hull.Receded(np.zeros((3, 3)), np.zeros(3, bool), {})

    lab = np.full((4, 4), BODY, np.uint8)
    lab[:, :2] = SKIN
    monkeypatch.setattr(frame_hull, "recede", fake)
    monkeypatch.setattr(frame_hull, "RECEDE", True)
    monkeypatch.setattr(frame_hull, "RECEDE_REGIONS", None)
    monkeypatch.setattr(frame_hull, "CLOTHES_NECK", False)
    carved = frame_hull.Carved(np.zeros(5, bool), {}, walls=["w"], labels=[lab])
    fc._recede(avatar(), avatar(), carved, lambda: None)
    np.testing.assert_array_equal(got["movable"], [True, True, True])
    assert got["other"] is None and got["other_walls"] is None
    monkeypatch.setattr(frame_hull, "RECEDE_REGIONS", ("neck",))
    monkeypatch.setattr(frame_hull, "CLOTHES_NECK", True)
    fc._recede(avatar(), avatar(), carved, lambda: None)
    np.testing.assert_array_equal(got["movable"], [False, True, True])
    np.testing.assert_array_equal(got["other"], [False, True, True])
    np.testing.assert_array_equal(got["other_walls"][0], frame_hull.neck_walls([lab])[0])
    assert got["other_walls"][0][:, 3].all() and not got["other_walls"][0][:, 0].any()
    fc._recede(avatar(), avatar(), frame_hull.Carved(np.zeros(5, bool), {}, walls=["w"]), lambda: None)
    assert got["other"] is None and got["other_walls"] is None


def test_the_hull_keeps_the_labels_only_when_the_neck_needs_them(monkeypatch):
    """`_carve` asks `carve_frames` for the segmentation's labels only with RECEDE and
    CLOTHES_NECK both on; `carve_frames(labels=True)` takes its walls from those labels' person
    (non-background) and keeps them."""
    from avatarkit.recon.segment import BACKGROUND, BODY, SKIN
    from avatarkit.track import frame_colours as fc
    from avatarkit.track import frame_hull

    asked = []

    def fake(views, allowed=None, labels=False):
        asked.append(labels)
        return frame_hull.Carved(np.zeros(5, bool), {})

    monkeypatch.setattr(frame_hull, "carve_frames", fake)
    monkeypatch.setattr(frame_hull, "CARVE", True)
    saved = SimpleNamespace(bald=_plane(np.arange(3) * 0.01, np.array([0.0])),
                            hair=_plane(np.arange(2) * 0.01, np.array([0.0])))
    for recede_on, neck, want in ((False, True, False), (True, False, False), (True, True, True)):
        monkeypatch.setattr(frame_hull, "RECEDE", recede_on)
        monkeypatch.setattr(frame_hull, "CLOTHES_NECK", neck)
        fc._carve(saved, saved, ["v"], None)
        assert asked[-1] is want
    monkeypatch.undo()

    lab = np.full((SIZE, SIZE), BACKGROUND, np.uint8)
    lab[:, :SIZE // 2] = SKIN
    lab[SIZE // 2:, :SIZE // 2] = BODY
    monkeypatch.setattr(frame_hull, "person_labels", lambda images: [lab, None])
    monkeypatch.setattr(frame_hull, "person_masks", lambda images: pytest.fail("segmented twice"))
    g = _plane(np.arange(-0.1, 0.1 + 1e-9, 0.01), np.arange(-0.1, 0.1 + 1e-9, 0.01))
    views = [SimpleNamespace(gaussians=g, camera=_camera(), image=None)] * 2
    out = frame_hull.carve_frames(views, labels=True, min_frames=1)
    assert out.labels[0] is lab and out.labels[1] is None and out.walls[1] is None
    np.testing.assert_array_equal(out.walls[0], wall_image(lab != BACKGROUND))


def test_recede_reads_its_step_and_rounds_when_called(monkeypatch):
    """`recede` without step / rounds takes the module's `STEP` and `RECEDE_ROUNDS` as they are
    when it runs (a setting changed after import is used)."""
    from avatarkit.track import frame_hull

    centres, normal, q = _sphere()
    n = len(centres)
    cam = _camera()
    wall = wall_image(np.zeros((SIZE, SIZE), bool))        # all wall: every shown disc votes out

    def pose(offsets):
        g = GaussianSet(centres + offsets, q, np.tile([0.008, 0.008, 0.0008], (n, 1)), np.full(n, 0.99),
                        rgb_to_dc(np.full((n, 3), 0.5, np.float32)))
        return [_view(g, cam)] * 3

    monkeypatch.setattr(frame_hull, "STEP", 0.0005)
    monkeypatch.setattr(frame_hull, "RECEDE_ROUNDS", 2)
    out = frame_hull.recede(pose, [wall] * 3, -normal, np.ones(n, bool))
    assert len(out.info["moved"]) == 2
    np.testing.assert_allclose(out.info["deepest"], 0.001)


def test_one_pass_for_both_walls_tallies_as_two():
    """`_tally_pair` (one 4-label compositing pass per frame, what `recede` runs for the neck's
    other wall) counts the same votes as `_tally` once per wall, frames without one wall or the
    other included; shares near the votes' edge (several) so that a weight off by its
    summation's rounding would show."""
    from avatarkit.track.frame_hull import _tally, _tally_pair

    centres, normal, q = _sphere(n=900)
    cam = _camera()
    n = len(centres)
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    views, walls, others = [], [], []
    for k in range(5):
        t = np.array([0.004 * (k - 2), 0.002 * k, 0.0])
        g = GaussianSet(centres + t, q, np.tile([0.008, 0.008, 0.0008], (n, 1)), rng.uniform(0.3, 0.99, n),
                        rgb_to_dc(np.full((n, 3), 0.5, np.float32)))
        views.append(_view(g, cam))
        cx, cy = SIZE / 2 + rng.normal(0, 3, 2)
        walls.append(None if k == 1 else wall_image((yy - cy) ** 2 + (xx - cx) ** 2 <= (14 + k) ** 2))
        others.append(None if k == 3 else wall_image(((yy - cy) ** 2 + (xx - cx) ** 2 <= 11 ** 2) & (yy < cy + 4)))
    for share in (0.1, 0.3, 0.5, 0.7):
        seen, out, seen2, out2 = _tally_pair(views, walls, others, share)
        a, b = _tally(views, walls, None, share)
        c, d = _tally(views, others, None, share)
        assert out.any() and out2.any() and (out != out2).any()
        for x, y in ((seen, a), (out, b), (seen2, c), (out2, d)):
            np.testing.assert_array_equal(x, y)


def test_frames_segmented_on_threads_as_one_after_another():
    """`_each_segmented` on two threads gives each frame the labels the plain loop gives (each
    segmentation seeds its own thread's OpenCV RNG), in the frames' order, None where no face
    is found: the sample portrait, it mirrored, and a blank frame."""
    from pathlib import Path

    from avatarkit.recon.image_io import read_image
    from avatarkit.recon.segment import segment_portrait
    from avatarkit.track.frame_hull import _each_segmented

    image = read_image(Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg")
    images = [image, np.ascontiguousarray(image[:, ::-1]), np.full_like(image, 200)]

    def labels(im, analysis):
        return segment_portrait(im, analysis).labels

    serial = _each_segmented(images, labels, threads=1)
    threaded = _each_segmented(images, labels, threads=2)
    assert serial[2] is None and threaded[2] is None
    for a, b in zip(serial[:2], threaded[:2]):
        assert a is not None and (a == 2).any()
        np.testing.assert_array_equal(a, b)
    assert (serial[0] != serial[1]).any()
