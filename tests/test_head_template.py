"""The built-in procedural template head: a valid closed mesh of human size that poses like FLAME."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from avatarkit.head import HeadModel, HeadParams, load_template
from avatarkit.head.meshcheck import self_intersections, triangle_quality
from avatarkit.head.template import EXPRESSION_NAMES, EYE_RADIUS, SHAPE_NAMES
from avatarkit.rotations import axis_angle_to_matrix


@pytest.fixture(scope="module")
def head() -> HeadModel:
    return load_template()


@pytest.fixture(scope="module")
def parts(head):
    """(head surface vertex mask, left eyeball mask, right eyeball mask)."""
    left, right = head.region_mask("left_eye"), head.region_mask("right_eye")
    return ~(left | right), left, right


def expr(head, **named) -> np.ndarray:
    e = np.zeros((1, head.num_expr), np.float32)
    for k, v in named.items():
        e[0, head.expression_names.index(k)] = v
    return e


def test_mesh_is_closed_manifold_outward_and_genus_zero(head):
    mesh = head.to_trimesh()
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward normals: positive signed volume
    components = mesh.split(only_watertight=False)
    assert len(components) == 3  # head + neck surface and two eyeballs
    for c in components:
        assert c.is_watertight and c.volume > 0 and c.euler_number == 2
    skin, left, right = (int(m.sum()) for m in (~(head.region_mask("eyes")), head.region_mask("left_eye"),
                                                head.region_mask("right_eye")))
    assert 3000 <= skin <= 8000 and left == right > 100


def test_no_self_intersection_at_rest_and_the_check_can_fail(head):
    assert len(self_intersections(head.v_template, head.faces)) == 0
    pushed = head.v_template.copy()
    pushed[head.regions["left_eye"]] += [0.0, 0.0, 0.008]  # eyeball through the eyelids
    assert len(self_intersections(pushed, head.faces)) > 0


def test_triangle_quality(head):
    q = triangle_quality(head.v_template, head.faces)
    assert q.min() > 3.0 and np.percentile(q, 1) > 15.0


def test_human_head_proportions_in_metres(head, parts):
    skin = head.v_template[parts[0]]
    lo, hi = skin.min(0), skin.max(0)
    eyes = head.rest_joints()[0, 3:5]
    above_ears = skin[skin[:, 1] > eyes[:, 1].mean() + 0.03]
    breadth = np.ptp(above_ears[:, 0])
    length = np.ptp(above_ears[:, 2])  # glabella/forehead to the back of the head
    front = skin[(np.abs(skin[:, 0]) < 0.03) & (skin[:, 2] > eyes[0, 2])]  # chin is ahead of the eyes
    chin = front[:, 1].min()
    assert 0.14 <= breadth <= 0.17, breadth
    assert 0.17 <= length <= 0.21, length
    assert 0.21 <= hi[1] - chin <= 0.25, hi[1] - chin
    assert hi[0] - lo[0] < 0.2 and hi[2] - lo[2] < 0.25
    volume = head.to_trimesh().volume
    assert 0.0035 < volume < 0.0065, volume  # litres of a head plus a short neck
    # face toward +Z: the nose tip is the frontmost point, on the mid-plane, below the eyes
    nose = skin[np.argmax(skin[:, 2])]
    assert abs(nose[0]) < 0.005 and nose[1] < eyes[0, 1] and nose[2] > eyes[0, 2] + 0.02
    # +Y up: the crown is above the eyes, the neck below
    assert hi[1] > eyes[0, 1] + 0.1 and lo[1] < eyes[0, 1] - 0.15


def test_joints(head, parts):
    J = head.rest_joints()[0]
    _, left, right = parts
    np.testing.assert_allclose(J[3], head.v_template[left].mean(0), atol=1e-6)
    np.testing.assert_allclose(J[4], head.v_template[right].mean(0), atol=1e-6)
    assert J[3, 0] > 0 > J[4, 0]  # joint 3 is the left eye, on the subject's left (+X)
    np.testing.assert_allclose(J[1], 0, atol=1e-6)  # the origin is the neck joint
    assert J[0, 1] < J[1, 1] - 0.08  # root at the neck base
    assert abs(J[2, 0]) < 1e-6 and J[2, 1] < J[3, 1] - 0.015 and J[1, 2] < J[2, 2] < J[3, 2]  # jaw: below/behind eyes


def test_weights_sum_to_one_and_are_smooth(head, parts):
    W = head.weights
    assert W.min() >= 0
    np.testing.assert_allclose(W.sum(1), 1, atol=1e-6)
    _, left, right = parts
    assert np.all(W[left, 3] == 1) and np.all(W[right, 4] == 1)
    neck = head.region_mask("neck")
    blend = (W[:, 0] > 0.2) & (W[:, 0] < 0.8)
    assert (blend & neck).sum() > 20  # the neck blends from root to head, not a step
    # smooth: along every edge of the skin, weights change by less than a step function would
    e = head.to_trimesh().edges_unique
    jump = np.abs(W[e[:, 0]] - W[e[:, 1]]).max(1)
    skin_edge = ~(left | right)[e[:, 0]]
    lips_edge = head.region_mask("mouth_interior")[e].any(1)  # the lip crease switches on purpose
    assert np.percentile(jump[skin_edge & ~lips_edge], 99.5) < 0.5


def test_root_rotation_rotates_every_vertex_rigidly(head):
    aa = np.array([0.2, 0.7, -0.3])
    v, _ = head.forward(HeadParams(rotation=aa, translation=[0.01, 0.02, 0.03]))
    R = axis_angle_to_matrix(aa)
    j0 = head.rest_joints()[0, 0]
    np.testing.assert_allclose(v[0], (head.v_template - j0) @ R.T + j0 + [0.01, 0.02, 0.03], atol=2e-6)


def test_jaw_moves_only_jaw_weighted_vertices(head):
    v, A = head.forward(HeadParams(jaw=[[0.3, 0.0, 0.0]]))
    moved = np.linalg.norm(v[0] - head.v_template, axis=1)
    w = head.weights[:, 2]
    assert moved[w == 0].max() < 1e-7
    assert moved[w > 0.99].min() > 1e-3
    full = w == 1
    rigid = head.v_template[full] @ A[0, 2, :3, :3].T + A[0, 2, :3, 3]
    np.testing.assert_allclose(v[0][full], rigid, atol=1e-6)
    # the chin goes down (the jaw opens) by about its distance to the jaw joint times the angle
    t = head.v_template
    ahead = np.flatnonzero((np.abs(t[:, 0]) < 0.01) & (t[:, 2] > head.rest_joints()[0, 3, 2]))
    chin = ahead[np.argmin(t[ahead, 1])]
    drop = t[chin, 1] - v[0, chin, 1]
    assert 0.2 * 0.3 * 0.08 < drop < 0.3 * 0.12


def test_lips_part_across_the_crease(head):
    W = head.weights[:, 2]
    mouth = head.regions["mouth_interior"]
    assert len(mouth) > 10
    upper = mouth[W[mouth] < 0.5]
    lower = mouth[W[mouth] >= 0.5]
    assert len(upper) and len(lower)
    assert head.v_template[upper, 1].mean() > head.v_template[lower, 1].mean()


@pytest.mark.parametrize("side,joint", [("left_eye", 3), ("right_eye", 4)])
def test_eye_rotation_turns_the_eyeball(head, side, joint):
    aa = np.array([0.1, 0.35, 0.0])
    eyes = np.zeros((1, 6))
    eyes[0, (joint - 3) * 3:(joint - 3) * 3 + 3] = aa
    v, _ = head.forward(HeadParams(eyes=eyes))
    idx = head.regions[side]
    c = head.rest_joints()[0, joint]
    r = np.linalg.norm(v[0, idx] - c, axis=1)
    np.testing.assert_allclose(r, EYE_RADIUS, atol=1e-6)  # still a sphere about the same centre
    rest = head.v_template[idx]
    pupil = idx[np.argmax(rest[:, 2] - c[2])]
    np.testing.assert_allclose(head.v_template[pupil] - c, [0, 0, EYE_RADIUS], atol=1e-6)
    direction = (v[0, pupil] - c) / EYE_RADIUS
    np.testing.assert_allclose(direction, axis_angle_to_matrix(aa) @ [0, 0, 1], atol=1e-6)
    others = np.setdiff1d(np.arange(head.num_vertices), idx)
    assert np.abs(v[0, others] - head.v_template[others]).max() < 1e-7


def _segment_hits(head, vertices, p0, p1) -> bool:
    from avatarkit.head.meshcheck import _segments_hit_triangles

    skin_faces = head.faces[~head.region_mask("eyes")[head.faces].any(1)]
    t = vertices[skin_faces].astype(np.float64)
    n = len(t)
    return bool(_segments_hit_triangles(np.tile(p0, (n, 1)), np.tile(p1, (n, 1)), t[:, 0], t[:, 1], t[:, 2]).any())


@pytest.mark.parametrize("name,joint", [("blink_left", 3), ("blink_right", 4)])
def test_blink_closes_the_lid_without_touching_the_eyeball(head, name, joint):
    c = head.rest_joints()[0, joint].astype(np.float64)
    pupil = c + [0, 0, EYE_RADIUS]
    look = (pupil + [0, 0, 0.05], pupil + [0, 0, 0.0005])
    assert not _segment_hits(head, head.v_template, *look)  # open: the pupil is visible
    skin = ~head.region_mask("eyes")
    for amount in (0.5, 1.0):
        v, _ = head.forward(HeadParams(expr=expr(head, **{name: amount})))
        d = np.linalg.norm(v[0, skin] - c, axis=1)
        assert d.min() > EYE_RADIUS + 2e-4
    assert _segment_hits(head, v[0], *look)  # closed: the lid covers it
    other = 4 if joint == 3 else 3
    co = head.rest_joints()[0, other].astype(np.float64) + [0, 0, EYE_RADIUS]
    assert not _segment_hits(head, v[0], co + [0, 0, 0.05], co + [0, 0, 0.0005])


def test_expressions_and_shapes_are_sized_and_named(head):
    assert head.expression_names == EXPRESSION_NAMES and head.shape_names == SHAPE_NAMES
    for required in ("brow_raise", "smile", "blink_left", "blink_right", "mouth_stretch"):
        assert required in head.expression_names
    for required in ("head_width", "head_depth", "head_height", "jaw_width"):
        assert required in head.shape_names
    for k in range(head.num_expr):
        mag = np.linalg.norm(head.exprdirs[:, :, k], axis=1).max()
        assert 0.002 < mag < 0.02, (head.expression_names[k], mag)
    for k in range(head.num_shape):
        mag = np.linalg.norm(head.shapedirs[:, :, k], axis=1).max()
        assert 0.002 < mag < 0.02, (head.shape_names[k], mag)
    # one unit of head_width widens the head by a few millimetres (about one std of adults)
    def width(s):
        v, _ = head.forward(HeadParams(shape=s))
        return np.ptp(v[0, :, 0])
    s = np.zeros(head.num_shape)
    s[head.shape_names.index("head_width")] = 1
    assert 0.003 < width(s) - width(-s) < 0.02


def test_shapes_and_expressions_keep_the_eyes_clear(head):
    rng = np.random.default_rng(7)
    skin = ~head.region_mask("eyes")
    J = head.rest_joints()
    for trial in range(3):
        shape = rng.uniform(-2.5, 2.5, head.num_shape)
        e = rng.uniform(0, 1, (1, head.num_expr))
        params = HeadParams(shape=shape, expr=e)
        v, _ = head.forward(params)
        J = head.rest_joints(params)[0]
        for joint in (3, 4):
            d = np.linalg.norm(v[0, skin] - J[joint], axis=1)
            assert d.min() > EYE_RADIUS * (1 + 0.03 * shape[-1]) * 0.99
    assert len(self_intersections(v[0], head.faces)) == 0


def test_regions(head):
    v = head.v_template
    for name in ("scalp", "face", "eyes", "left_eye", "right_eye", "mouth_interior", "neck", "lips", "forehead"):
        assert len(head.regions[name]) > 0, name
    scalp, face, neck = (head.region_mask(n) for n in ("scalp", "face", "neck"))
    assert not (scalp & face).any() and not (scalp & neck).any() and not (face & neck).any()
    J = head.rest_joints()[0]
    eye_y, eye_z = J[3:5, 1].mean(), J[3:5, 2].mean()
    skin = ~head.region_mask("eyes")
    top = np.argmax(np.where(skin, v[:, 1], -np.inf))
    assert scalp[top]
    mid = skin & (np.abs(v[:, 1] - (eye_y + 0.03)) < 0.01) & (np.abs(v[:, 0]) < 0.02)
    back = np.flatnonzero(mid)[np.argmin(v[mid, 2])]
    assert scalp[back]
    # the scalp covers the top and back: most skin above the brows and behind the ears is scalp
    upper_back = skin & (v[:, 1] > eye_y + 0.04) & (v[:, 2] < eye_z - 0.1)
    assert scalp[upper_back].mean() > 0.95
    # ...and none of the face below the brows
    assert not (scalp & (v[:, 2] > eye_z) & (v[:, 1] < eye_y + 0.03)).any()
    assert (v[neck, 1] < eye_y - 0.07).all()
    nose = np.argmax(np.where(skin, v[:, 2], -np.inf))
    assert face[nose]
    np.testing.assert_array_equal(head.regions["eyes"], np.union1d(head.regions["left_eye"], head.regions["right_eye"]))
    assert set(head.region_faces("scalp", "all")) <= set(head.region_faces("scalp", "majority"))


def test_template_is_cached_deterministic_and_copied(head):
    a = load_template()
    a.v_template[:] = 0
    b = load_template()
    np.testing.assert_array_equal(b.v_template, head.v_template)
    np.testing.assert_array_equal(b.faces, head.faces)
    assert HeadModel.template().num_vertices == head.num_vertices


@pytest.mark.slow
def test_generation_is_deterministic(head):
    from avatarkit.head.model import build_template

    again = build_template()
    np.testing.assert_array_equal(again.faces, head.faces)
    np.testing.assert_array_equal(again.v_template, head.v_template)


def test_trimesh_round_trip_through_ply(head, tmp_path):
    from avatarkit.head.mesh_export import write_mesh

    v, _ = head.forward(HeadParams(jaw=[[0.25, 0, 0]]))
    path = tmp_path / "head.ply"
    write_mesh(head, path, v[0])
    back = trimesh.load(path, process=False)
    np.testing.assert_allclose(back.vertices, v[0], atol=1e-6)
    np.testing.assert_array_equal(back.faces, head.faces)


# --- the shipped surface ----------------------------------------------------------------------

def test_shipped_surface_is_current_and_equals_the_generated_one():
    """The shipped file must come from today's generating code (else every process silently pays
    ~2.5 s), and loading it must give what generating gives."""
    from avatarkit.head import template

    shipped = template.shipped_head_surface()
    assert shipped is not None, ("avatarkit/head/data/template_surface.npz is stale or missing: "
                                 "run scripts/make_template_surface.py")
    v, f = template.generate_head_surface()
    np.testing.assert_array_equal(shipped[1], f)
    np.testing.assert_allclose(shipped[0], v, rtol=0, atol=1e-9)


def test_surface_made_by_other_code_is_generated_instead(monkeypatch, tmp_path):
    from avatarkit.head import template

    generated = (np.zeros((3, 3)), np.array([[0, 1, 2]]))
    monkeypatch.setattr(template, "generate_head_surface", lambda: generated)
    monkeypatch.setattr(template, "surface_sources_sha256", lambda: "other code")
    assert template.shipped_head_surface() is None
    assert template._head_surface() is generated
    monkeypatch.setattr(template, "SURFACE_FILE", tmp_path / "missing.npz")
    assert template.shipped_head_surface() is None
    (tmp_path / "bad.npz").write_bytes(b"not an npz")
    monkeypatch.setattr(template, "SURFACE_FILE", tmp_path / "bad.npz")
    assert template.shipped_head_surface() is None
