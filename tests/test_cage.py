"""Cage construction, its guarantees, the inside/depth test, and cage files."""
import numpy as np
import pytest
import trimesh

from avatarkit.cage import (Cage, build_cage, cage_points, check_cage, clipped_depth, load_cage,
                            save_cage, winding_numbers_reference)
from avatarkit.cage.inside import point_triangle_distance
from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.gaussians import GaussianSet
from avatarkit.synthetic import make_hair


def sphere_cage(subdivisions=2, radius=1.0):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Cage(m.vertices, m.faces)


# --- the Cage type and its checks -------------------------------------------------------------

def test_cage_validates_its_arrays():
    c = sphere_cage(1)
    assert c.vertices.dtype == np.float32 and c.faces.dtype == np.int32
    assert len(c.edges()) == 3 * len(c.faces) // 2
    assert c.volume() > 0
    with pytest.raises(InputError, match="shape"):
        Cage(np.zeros((10, 2)), c.faces)
    with pytest.raises(InputError, match="outside"):
        Cage(c.vertices, c.faces + 1000)
    with pytest.raises(InputError, match="non-finite"):
        Cage(np.full_like(c.vertices, np.nan), c.faces)


def test_check_accepts_a_good_cage():
    check = check_cage(sphere_cage())
    assert check.ok, check.problems
    assert check.watertight and check.oriented and check.outward and check.manifold
    assert check.components == 1 and check.degenerate_faces == 0 and check.min_angle_deg > 40


def test_check_reports_inward_faces():
    c = sphere_cage()
    check = check_cage(Cage(c.vertices, c.faces[:, ::-1]))
    assert not check.outward and any("inward" in p for p in check.problems)


def test_check_reports_a_hole():
    c = sphere_cage()
    check = check_cage(Cage(c.vertices, c.faces[1:]))
    assert not check.watertight and not check.ok


def test_check_reports_a_flipped_face():
    c = sphere_cage()
    faces = c.faces.copy()
    faces[3] = faces[3, ::-1]
    check = check_cage(Cage(c.vertices, faces))
    assert check.watertight and not check.oriented


def test_check_reports_a_non_manifold_vertex():
    # an icosahedron and its mirror image through one of its vertices, sharing only that vertex:
    # every edge still has two faces, but the shared vertex has two separate fans. The mirror's
    # copy of vertex 0 is dropped, so non-manifoldness is the only thing wrong with this cage.
    a = trimesh.creation.icosphere(subdivisions=0)
    n = len(a.vertices)
    v = np.concatenate([a.vertices, 2 * a.vertices[0] - a.vertices[1:]])
    mirror = np.concatenate([[0], np.arange(n, 2 * n - 1)])  # the mirror's vertex 0 is vertex 0 itself
    f = np.concatenate([a.faces, mirror[a.faces[:, ::-1]]])
    check = check_cage(Cage(v, f))
    assert check.watertight and check.oriented and check.outward and not check.manifold
    assert check.unused_vertices == 0 and check.degenerate_faces == 0
    assert len(check.problems) == 1 and "not manifold" in check.problems[0], check.problems


def test_check_reports_an_unused_vertex():
    c = sphere_cage(1)
    check = check_cage(Cage(np.concatenate([c.vertices, [[0.0, 0.0, 0.0]]]), c.faces))
    assert check.manifold and check.unused_vertices == 1 and check.components == 1
    assert check.problems == ["1 vertices are not used by any face"]


def test_check_reports_degenerate_faces():
    c = sphere_cage(1)
    v = c.vertices.copy()
    a, b, d = c.faces[0]
    v[d] = (v[a] + v[b]) / 2  # flatten one triangle onto its edge
    check = check_cage(Cage(v, c.faces))
    assert check.degenerate_faces >= 1 and not check.ok


def test_check_points_inside_with_margin():
    c = sphere_cage(3)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    deep = d * rng.uniform(0, 0.8, (2000, 1))
    assert check_cage(c, deep, margin=0.1).ok
    shallow = np.concatenate([deep, [[0.97, 0, 0]]])
    check = check_cage(c, shallow, margin=0.1)
    assert check.points_shallow == 1 and check.points_outside == 0 and not check.ok
    outside = np.concatenate([deep, [[1.5, 0, 0], [0, 0, -3]]])
    check = check_cage(c, outside, margin=0.1)
    assert check.points_outside == 2 and check.min_depth < 0


def test_shallow_points_at_the_margin():
    # a cube of half-size 1: a point on the +x axis at depth d is exactly d from the nearest face,
    # so points 1 % either side of the margin test the threshold itself (not "much shallower")
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    cage = Cage(box.vertices, box.faces)
    for margin in (0.1, 0.3):
        for depth, shallow in ((0.99 * margin, 1), (1.01 * margin, 0)):
            check = check_cage(cage, [[1.0 - depth, 0.0, 0.0], [0.0, 0.0, 0.0]], margin=margin)
            assert check.points_shallow == shallow and check.points_outside == 0, (margin, depth)
            assert check.ok is (not shallow) and check.min_depth == pytest.approx(depth, rel=1e-9)


def test_clipped_depth_matches_brute_force():
    v, f = (lambda m: (m.vertices, m.faces))(trimesh.creation.icosphere(subdivisions=2))
    v = v * (1 + 0.3 * np.sin(3 * v[:, :1]))        # non-convex
    pts = np.random.default_rng(1).uniform(-1.4, 1.4, (400, 3))
    tri = v[f]
    brute = np.array([point_triangle_distance(np.repeat(p[None], len(f), 0), tri).min() for p in pts])
    sign = np.where(winding_numbers_reference(pts, v, f) > 0.5, 1.0, -1.0)
    for radius in (0.05, 0.3, 5.0):
        got = clipped_depth(pts, v, f, radius)
        np.testing.assert_allclose(got, sign * np.minimum(brute, radius), atol=1e-9)


# --- building cages around hair ---------------------------------------------------------------

@pytest.fixture(scope="module", params=["long_straight", "bob", "ponytail", "curly"])
def hair_and_cage(request):
    hair = make_hair(request.param, n=4000, seed=2)
    return hair, build_cage(hair)


def test_built_cages_meet_every_guarantee(hair_and_cage):
    hair, cage = hair_and_cage
    assert 100 <= cage.n_vertices <= 500
    margin = cage.info["margin"]
    assert margin > 0
    check = check_cage(cage, cage_points(hair), margin)  # centres and all six axis ends
    assert check.ok, check.problems
    assert check.watertight and check.manifold and check.outward and check.degenerate_faces == 0
    assert check.min_depth >= margin
    assert check.min_angle_deg > 5  # an even triangulation for the XPBD solver
    edges = cage.edges()
    length = np.linalg.norm(cage.vertices[edges[:, 0]] - cage.vertices[edges[:, 1]], axis=1)
    assert length.max() < 4 * np.median(length)


def test_cage_is_coarse_but_close(hair_and_cage):
    hair, cage = hair_and_cage
    lo, hi = hair.bounds()
    diag = np.linalg.norm(hi - lo)
    c_lo, c_hi = cage.vertices.min(0), cage.vertices.max(0)
    # encloses the hair, without a huge gap (the cage is not a bounding blob)
    assert (c_lo < lo).all() and (c_hi > hi).all()
    assert ((lo - c_lo) < 0.15 * diag).all() and ((c_hi - hi) < 0.15 * diag).all()


def test_target_vertex_count_and_margin_are_honoured():
    hair = make_hair("bob", n=2000, seed=0)
    small = build_cage(hair, target_vertices=150, margin=0.008)
    assert small.n_vertices <= 150
    assert check_cage(small, cage_points(hair), 0.008).ok


def test_build_cage_rejects_bad_input():
    hair = make_hair("short", n=100)
    with pytest.raises(InputError, match="empty"):
        build_cage(GaussianSet.empty())
    with pytest.raises(InputError, match="target_vertices"):
        build_cage(hair, target_vertices=5)
    with pytest.raises(InputError, match="margin"):
        build_cage(hair, margin=-1.0)
    with pytest.raises(InputError, match="voxel_size"):
        build_cage(hair, voxel_size=0.0)


def test_fallback_ladder_then_clear_error(monkeypatch):
    import avatarkit.cage.build as build

    hair = make_hair("short", n=150)
    real = build.check_cage
    calls = []

    def failing_first(cage, points=None, margin=0.0):
        calls.append(cage.n_vertices)
        check = real(cage, points, margin)
        if len(calls) == 1:
            check.problems.append("simulated failure")
        return check

    monkeypatch.setattr(build, "check_cage", failing_first)
    cage = build_cage(hair, target_vertices=40)
    assert cage.info["attempt"] == 2 and len(calls) == 2

    def always_failing(cage, points=None, margin=0.0):
        check = real(cage)  # topology only: cheap
        check.problems.append("simulated failure")
        return check

    monkeypatch.setattr(build, "check_cage", always_failing)
    with pytest.raises(InputError, match="could not build a valid cage around 150 Gaussians.*attempt 6"):
        build_cage(hair, target_vertices=40)


def test_single_gaussian_gets_a_cage():
    g = GaussianSet.from_colors([[0.0, 0.0, 0.0]], [[1, 0, 0, 0]], [[0.01, 0.002, 0.002]], [1.0],
                                [[0.5, 0.5, 0.5]])
    cage = build_cage(g, target_vertices=60)
    assert check_cage(cage, cage_points(g), cage.info["margin"]).ok


# --- files ------------------------------------------------------------------------------------

@pytest.mark.parametrize("ext", [".ply", ".obj", ".off"])
def test_cage_file_round_trip_keeps_order(tmp_path, ext):
    c = sphere_cage(2)
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(c.vertices))              # an order trimesh would not produce
    inv = np.argsort(perm)
    c = Cage(c.vertices[perm], inv[c.faces])
    path = tmp_path / f"cage{ext}"
    save_cage(path, c)
    back = load_cage(path)
    np.testing.assert_array_equal(back.faces, c.faces)
    np.testing.assert_allclose(back.vertices, c.vertices, atol=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temp file left


def test_cage_file_errors(tmp_path):
    c = sphere_cage(1)
    with pytest.raises(OutputError, match="format"):
        save_cage(tmp_path / "cage.stl", c)
    with pytest.raises(OutputError):
        save_cage(tmp_path / "missing" / "cage.ply", c)
    with pytest.raises(InputError, match="not found"):
        load_cage(tmp_path / "nope.ply")
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    with pytest.raises(FormatError, match="bad.ply"):
        load_cage(bad)
    pts = tmp_path / "points.ply"
    trimesh.PointCloud(np.random.default_rng(0).random((10, 3))).export(pts)
    with pytest.raises(FormatError, match="triangle"):
        load_cage(pts)
