"""Hairstyle transfer: hair relative to the scalp, re-seated on heads of other sizes and shapes,
pushed outside the head, cleaned of the source's skin, re-rigged; the CLI and the hair grid."""
from __future__ import annotations

import copy
import dataclasses
import functools
import warnings

import numpy as np
import pytest

from avatarkit.avatar import Avatar, _rest_vertices, load_avatar
from avatarkit.hair_rig import HairRig
from avatarkit.cage.inside import clipped_depth, surface_distance
from avatarkit.cage.mesh import check_cage
from avatarkit.cage.points import cage_points
from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.hairstyle import (MARGIN, ScalpHair, SkinCleanup, hair_grid, parse_views, reseat_hair,
                                 scalp_faces, skin_in_hair, transfer_hair)
from avatarkit.rotations import quat_to_matrix
from test_avatar import small_avatar

CAGE = 150  # vertices of the rebuilt cages: small keeps the weights cheap


@pytest.fixture(scope="module")
def source():
    return small_avatar()


@functools.cache
def target_avatar(scale: float, width: float, seed: int) -> Avatar:
    """The template head with other identity coefficients (`scale`: 1 + 0.03 scale in size;
    `head_width` in standard deviations), its own bald discs and a little hair so it is a
    complete avatar (its rig's SDF is coarse, to keep the fixture cheap)."""
    from avatarkit.cage.build import build_cage
    from avatarkit.head.sdf_grid import HeadSDF
    from avatarkit.synthetic.sample_avatar import make_bald

    src = small_avatar()
    head = src.head_model
    shape = np.zeros(head.num_shape, np.float32)
    shape[head.shape_names.index("scale")] = scale
    shape[head.shape_names.index("head_width")] = width
    rest = _rest_vertices(head, shape)
    bald = make_bald(head, rest, 1500, seed)
    hair = src.hair.subset(np.arange(0, len(src.hair), 20)).transform(scale=1 + 0.03 * scale)
    cage = build_cage(hair, target_vertices=60)
    rig = HairRig.build(head, rest, hair, cage, sdf=HeadSDF.build(rest, head.faces, spacing=0.005))
    return Avatar(head, bald, hair, cage, rig, shape, name=f"target_{scale:+g}_{width:+g}")


@pytest.fixture(scope="module")
def big():
    return target_avatar(4.0, 1.5, 11)     # ~12% larger, wider


@pytest.fixture(scope="module")
def small():
    return target_avatar(-4.0, -1.0, 12)   # ~12% smaller, narrower


@pytest.fixture(scope="module")
def on_big(source, big):
    return transfer_hair(source, big, cage_vertices=CAGE)


@pytest.fixture(scope="module")
def on_small(source, small):
    return transfer_hair(source, small, cage_vertices=CAGE)


def _hairless(avatar: Avatar) -> Avatar:
    """The avatar with its hair removed: a hairless avatar (a bald person: no cage, no rig)."""
    return Avatar(avatar.head_model, avatar.bald, GaussianSet.empty(), None, None, avatar.shape,
                  name=f"{avatar.name}_bald")


def _clearance(points: np.ndarray, avatar: Avatar) -> np.ndarray:
    """(N,) signed distance of points outside the avatar's rest head (negative inside), exact
    within 2 cm: winding numbers, independent of the pseudo-normal test the assembly uses."""
    return -clipped_depth(points, avatar.rest_head_vertices, avatar.head_model.faces, 0.02)


def _spread(points: np.ndarray) -> float:
    """RMS distance of points (N, 3) from their centroid."""
    p = np.asarray(points, np.float64)
    return float(np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).mean()))


def _head_size(avatar: Avatar) -> float:
    return _spread(avatar.rest_head_vertices)


# --- hair relative to the scalp --------------------------------------------------------------------

@pytest.mark.parametrize("neighbours", [1, 8])
def test_scalp_relative_hair_round_trips_on_its_own_head(source, neighbours):
    head = source.head_model
    rest = source.rest_head_vertices
    rel = ScalpHair.bind(source.hair, head, rest, cage=source.cage, neighbours=neighbours)
    assert np.isin(rel.binding.face_ids, scalp_faces(head)).all()
    assert np.isin(rel.point_faces, scalp_faces(head)).all()
    assert rel.n_hair == len(source.hair) and rel.n_cage == source.cage.n_vertices
    np.testing.assert_allclose(rel.point_weights.sum(axis=1), 1.0, atol=1e-12)
    hair, cage = rel.to_world(rest)
    np.testing.assert_allclose(hair.means, source.hair.means, atol=1e-6)
    np.testing.assert_allclose(hair.scales, source.hair.scales, rtol=1e-5)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", hair.quats, source.hair.quats)), 1.0, atol=1e-5)
    np.testing.assert_allclose(hair.sh, source.hair.sh, atol=1e-5)
    np.testing.assert_allclose(cage, source.cage.vertices, atol=1e-6)
    assert "binding" not in hair.extras
    np.testing.assert_array_equal(hair.extras["strand"], source.hair.extras["strand"])


@pytest.mark.parametrize("neighbours", [1, 8])
def test_scalp_relative_hair_follows_a_similarity_of_the_head(source, neighbours):
    """On a head rotated, scaled and moved as a whole, the hair (and its view-dependent colour)
    moves exactly as `GaussianSet.transform` moves it (analytic)."""
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    s, t = 1.3, np.array([0.05, -0.02, 0.1])
    rest = source.rest_head_vertices.astype(np.float64)
    moved = s * rest @ rot.T + t
    hair = source.hair.with_sh_degree(2)
    rng = np.random.default_rng(1)
    hair = hair.replace(sh=np.concatenate([hair.sh[:, :1], rng.normal(0, 0.2, (len(hair), 8, 3))], axis=1))
    rel = ScalpHair.bind(hair, source.head_model, rest, cage=source.cage, neighbours=neighbours)
    got, cage = rel.to_world(moved)
    want = hair.transform(rot, t, s)
    np.testing.assert_allclose(got.means, want.means, atol=2e-6)
    np.testing.assert_allclose(got.scales, want.scales, rtol=1e-5)
    np.testing.assert_allclose(quat_to_matrix(got.quats), quat_to_matrix(want.quats), atol=1e-5)
    np.testing.assert_allclose(got.sh, want.sh, atol=1e-4)
    np.testing.assert_allclose(cage, source.cage.vertices.astype(np.float64) * s @ rot.T + t, atol=2e-6)


def test_blended_positions_tear_less_than_single_triangles(source, big):
    """Neighbouring hair Gaussians stay neighbours on a head of another shape; blending over
    several scalp triangles keeps their spacing better than one triangle each."""
    from scipy.spatial import cKDTree

    src = source.hair.means.astype(np.float64)
    _, nb = cKDTree(src).query(src, k=6)
    scale = float(np.cbrt(abs(_volume(big)) / abs(_volume(source))))

    def worst(neighbours):
        rel = ScalpHair.bind(source.hair, source.head_model, source.rest_head_vertices, neighbours=neighbours)
        p = rel.points_to_world(big.rest_head_vertices)
        d0 = src[nb[:, 1:]] - src[:, None]
        d1 = p[nb[:, 1:]] - p[:, None]
        return np.percentile(np.linalg.norm(d1 - scale * d0, axis=2), 99)

    one, eight = worst(1), worst(8)
    assert eight < 0.5 * one
    assert eight < 0.002  # metres, for neighbours ~8 mm apart


def _volume(avatar) -> float:
    from avatarkit.cage.mesh import signed_volume

    return signed_volume(avatar.rest_head_vertices.astype(np.float64), avatar.head_model.faces)


# --- the transfer ------------------------------------------------------------------------------

def test_transfer_onto_the_same_avatar_reproduces_its_hair(source):
    seated = reseat_hair(source, source)
    assert seated.report.dropped_skin == 0 and seated.report.pushed == 0
    assert len(seated.hair) == len(source.hair)
    np.testing.assert_allclose(seated.hair.means, source.hair.means, atol=1e-5)
    np.testing.assert_allclose(seated.carried_cage.vertices, source.cage.vertices, atol=1e-5)

    # the full transfer with the carried cage rebuilds the same rig: same roots
    result = transfer_hair(source, source, cage="carry")
    assert result.provenance["transfer"]["cage"] == "carried"
    np.testing.assert_allclose(result.hair.means, source.hair.means, atol=1e-5)
    np.testing.assert_array_equal(result.rig.model.roots, source.rig.model.roots)
    assert result.rig.method == source.rig.method


@pytest.mark.parametrize("which", ["big", "small"])
def test_transfer_onto_another_head(request, source, which):
    target = request.getfixturevalue(which)
    result = request.getfixturevalue(f"on_{which}")
    head = target.head_model
    rest = target.rest_head_vertices
    assert result.head_model is head
    np.testing.assert_array_equal(result.shape, target.shape)
    assert result.bald is target.bald
    scale = result.provenance["transfer"]["head_scale"]
    assert (scale > 1.05) if which == "big" else (scale < 0.95)

    # no hair Gaussian inside the target head, none closer than half the margin
    assert _clearance(result.hair.means, target).min() >= 0.499 * MARGIN

    # roots on its scalp: the simulation roots attach to scalp faces, and every strand's first
    # Gaussian sits just outside the target's scalp
    scalp = scalp_faces(head)
    model = result.rig.model
    assert len(model.roots) >= 3 and np.isin(model.root_faces, scalp).all()
    strand = result.hair.extras["strand"]
    first = np.r_[True, strand[1:] != strand[:-1]]
    to_scalp = surface_distance(result.hair.means[first], rest, head.faces[scalp], 0.05)
    assert np.median(to_scalp) < 0.004 and to_scalp.max() < 0.01

    # hair volume relative to head size is preserved
    rel_src = _spread(source.hair.means) / _head_size(source)
    rel_dst = _spread(result.hair.means) / _head_size(target)
    assert rel_dst == pytest.approx(rel_src, rel=0.05)
    size = _head_size(target) / _head_size(source)
    carried = result.provenance["transfer"]["carried_cage_volume"]
    assert carried / source.cage.volume() == pytest.approx(size ** 3, rel=0.1)
    # the fresh cage (its size depends on the builder's fallbacks, not a volume measure) holds
    # every hair centre and axis end
    assert check_cage(result.cage, cage_points(result.hair)).ok

    # nothing lost, provenance names both sources
    assert len(result.hair) == len(source.hair)
    t = result.provenance["transfer"]
    assert t["hair_from"]["name"] == source.name and t["head_from"]["name"] == target.name
    assert t["hair"] == len(result.hair) and t["margin_m"] == MARGIN


def test_assembly_pushes_hair_out_to_the_margin(source, big):
    """With a margin wider than the hair's clearance, the hair that is too close moves out to
    it, the rest stays where the re-seat put it."""
    margin = 0.008
    rel = ScalpHair.bind(source.hair, source.head_model, source.rest_head_vertices)
    before = rel.points_to_world(big.rest_head_vertices)
    was = _clearance(before, big)
    seated = reseat_hair(source, big, margin=margin)
    now = _clearance(seated.hair.means, big)
    assert now.min() >= 0.499 * margin
    moved = np.linalg.norm(seated.hair.means - before, axis=1) > 1e-7
    assert moved.sum() == seated.report.pushed > 0
    np.testing.assert_array_equal(moved, was < margin / 2)
    # moved out to the margin (a little less where the surface curves inward near them)
    assert np.median(now[moved]) == pytest.approx(margin, abs=1e-5)
    assert now[moved].max() <= margin + 1e-5


def test_transferred_avatar_bakes_and_round_trips(on_big, tmp_path):
    from avatarkit.bake import BakeConfig, bake
    from avatarkit.motion import make_clip
    from avatarkit.sim.config import SimConfig

    clip = make_clip("shake", frames=4, fps=25, expr_dims=0)
    static, frames = bake(on_big, clip, BakeConfig(sim=SimConfig(substeps=2, iterations=6), preroll=0.1))
    n = 0
    for frame in frames:
        for part in (frame.face, frame.hair):
            for a in (part.means, part.quats, part.scales):
                assert np.isfinite(a).all()
        assert np.isfinite(frame.cage_vertices).all()
        n += 1
    assert n == 4

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a loaded rig must match: no RigRebuiltWarning
        back = load_avatar(on_big.save(tmp_path / "out", preview=False))
    assert back.counts() == on_big.counts()
    assert back.provenance["transfer"] == on_big.provenance["transfer"]
    np.testing.assert_array_equal(back.shape, on_big.shape)


# --- skin clean-up ---------------------------------------------------------------------------------

def _hair_with_skin(source: Avatar, n: int = 50) -> tuple[GaussianSet, np.ndarray]:
    """The source's hair plus `n` of its bald Gaussians from around the hairline (forehead and
    where scalp meets face), as a lifter's residual skin; returns (hair, is_probe (N,))."""
    head = source.head_model
    f = head.faces[source.bald.extras["binding"]]
    forehead = head.region_mask("forehead")[f].any(axis=1)
    border = head.region_mask("scalp")[f].any(axis=1) & head.region_mask("face")[f].any(axis=1)
    idx = np.flatnonzero(forehead | border)
    idx = idx[np.linspace(0, len(idx) - 1, n).astype(int)]
    probes = source.bald.subset(idx).replace(extras={"strand": np.full(n, -1, np.int32)})
    strands = source.hair.extras["strand"].astype(np.int32)
    hair = GaussianSet.concat([source.hair.replace(extras={"strand": strands}), probes])
    return hair, np.r_[np.zeros(len(source.hair), bool), np.ones(n, bool)]


@pytest.mark.parametrize("target_skin", ["same", "darker"])
def test_source_skin_in_the_hair_is_dropped(source, big, target_skin):
    hair, probe = _hair_with_skin(source)
    rel = ScalpHair.bind(hair, source.head_model, source.rest_head_vertices)
    seated, _ = rel.to_world(big.rest_head_vertices)
    bald = big.bald if target_skin == "same" else big.bald.with_colors(big.bald.colors * 0.45)
    faces = source.head_model.faces
    is_skin, cand = skin_in_hair(hair, seated.means, source.bald, (source.rest_head_vertices, faces),
                                 bald, (big.rest_head_vertices, faces))
    assert cand[probe].all()                       # skin is always near a head surface
    assert is_skin[probe].mean() >= 0.9            # brows (dark, like hair) may stay
    assert is_skin[~probe].mean() <= 0.005


def test_reseat_drops_skin_and_reports_it(source, big):
    hair, probe = _hair_with_skin(source)
    dirty = copy.copy(source)
    dirty.hair = hair
    seated = reseat_hair(dirty, big)
    assert seated.report.source_hair == len(hair)
    assert seated.report.dropped_skin >= 0.9 * probe.sum()
    assert (seated.hair.extras["strand"] == -1).sum() <= 0.1 * probe.sum()
    assert len(seated.hair) == len(hair) - seated.report.dropped_skin
    kept = reseat_hair(dirty, big, cleanup=False)
    assert len(kept.hair) == len(hair) and kept.report.dropped_skin == 0


def test_skin_cleanup_settings_are_checked():
    for bad in (dict(band=0), dict(band=float("nan")), dict(k=0), dict(k=1.5), dict(colour_weight=-1)):
        with pytest.raises(InputError):
            SkinCleanup(**bad)


# --- incompatible inputs ---------------------------------------------------------------------------

def _with_head(avatar: Avatar, head) -> Avatar:
    return Avatar(head, avatar.bald, avatar.hair, avatar.cage, avatar.rig, avatar.shape, name="other")


def test_heads_of_different_topology_are_refused(source):
    head = source.head_model
    rolled = dataclasses.replace(head, faces=np.roll(head.faces, 1, axis=0))
    with pytest.raises(InputError, match="different head model topology.*face 0 differs"):
        reseat_hair(source, _with_head(source, rolled))
    fewer = dataclasses.replace(head, faces=head.faces[:-10])
    with pytest.raises(InputError, match=f"different head model topology.*{head.num_faces - 10}"):
        transfer_hair(_with_head(source, fewer), source)


def test_source_without_hair_is_refused(source, big):
    with pytest.raises(InputError, match="has no hair Gaussians"):
        transfer_hair(_hairless(source), big)


def test_hair_onto_a_hairless_target(source, big, on_big, tmp_path):
    """Putting hair on a bald head: the hair lands where it lands on the same head with hair (the
    target's own hair plays no part), with a fresh cage and rig; the result saves and loads."""
    bald_big = _hairless(big)
    result = transfer_hair(source, bald_big, cage_vertices=CAGE)
    assert result.has_hair and result.cage is not None and result.rig is not None
    assert len(result.hair) == len(on_big.hair)
    np.testing.assert_allclose(result.hair.means, on_big.hair.means, atol=1e-5)
    assert np.array_equal(result.bald.means, big.bald.means)
    loaded = load_avatar(result.save(tmp_path / "haired", preview=False))
    assert len(loaded.hair) == len(result.hair) and loaded.cage.n_vertices == result.cage.n_vertices


def test_head_without_scalp_is_refused(source):
    head = source.head_model
    no_scalp = dataclasses.replace(head, regions={k: v for k, v in head.regions.items() if k != "scalp"})
    other = _with_head(source, no_scalp)
    with pytest.raises(InputError, match="no 'scalp' region"):
        reseat_hair(other, other)


def test_bad_arguments_are_refused(source):
    with pytest.raises(InputError, match="margin"):
        reseat_hair(source, source, margin=-0.001)
    with pytest.raises(InputError, match="must be an Avatar"):
        reseat_hair(source.hair, source)
    with pytest.raises(InputError, match="cage must be one of"):
        transfer_hair(source, source, cage="keep")
    with pytest.raises(InputError, match="neighbours"):
        ScalpHair.bind(source.hair, source.head_model, source.rest_head_vertices, neighbours=0)


# --- the hair library view -------------------------------------------------------------------------

def test_hair_grid_shows_each_hairstyle_on_one_head(source, big):
    grid = hair_grid(big, [source], views=["front", "profile"], size=64, include_own=True, labels=False)
    pad = 4
    assert grid.image.shape == (2 * 64 + 3 * pad, 2 * 64 + 3 * pad, 3) and grid.image.dtype == np.uint8
    assert grid.rows == ["own hair", source.name] and grid.views == ["front", "profile"]
    assert grid.reports[0] is None and grid.reports[1].hair == len(source.hair)
    cell = lambda r, c: grid.image[pad + r * (64 + pad):][:64, pad + c * (64 + pad):][:, :64].astype(int)
    # the target's own hair (a sparse subset) and the source's long hair differ, in both views
    for c in range(2):
        assert np.abs(cell(0, c) - cell(1, c)).mean() > 2
    assert (cell(1, 0) < 250).any()  # something was drawn


def test_parse_views():
    assert parse_views("front, three-quarter") == ["front", "three-quarter"]
    assert parse_views(["back"]) == ["back"]
    with pytest.raises(InputError, match="unknown view 'side'"):
        parse_views("front,side")
    with pytest.raises(InputError, match="no views"):
        parse_views(" , ")


# --- CLI -------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def folders(source, small, tmp_path_factory):
    root = tmp_path_factory.mktemp("transfer_cli")
    return (source.save(root / "hair_src", preview=False), small.save(root / "head_dst", preview=False))


def test_cli_transfer_hair(folders, tmp_path, capsys):
    from avatarkit.cli.main import main
    from avatarkit.export.images import read_png

    src, dst = folders
    out, png = tmp_path / "result", tmp_path / "result.png"
    code = main(["transfer-hair", "--hair", str(src), "--onto", str(dst), "-o", str(out), "--preview",
                 str(png), "--cage-vertices", "100"])
    assert code == 0, capsys.readouterr().err
    assert "hair Gaussians" in capsys.readouterr().out
    result = load_avatar(out)
    assert len(result.hair) > 0 and result.name == "target_-4_-1_sample_long_straight_hair"
    assert result.provenance["transfer"]["hair_from"]["path"] == str(src)
    assert read_png(png).shape[:2] == (512, 512)


def test_cli_transfer_hair_bad_input_writes_nothing(folders, tmp_path, capsys):
    from avatarkit.cli.main import main

    src, dst = folders
    out = tmp_path / "result"
    missing = str(tmp_path / "missing")
    assert main(["transfer-hair", "--hair", missing, "--onto", str(dst), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "missing" in err and "Traceback" not in err
    assert main(["transfer-hair", "--hair", str(src), "--onto", str(dst), "-o", str(out),
                 "--preview", str(tmp_path / "no_dir" / "p.png")]) == 2
    assert "no_dir" in capsys.readouterr().err
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "keep.txt").write_text("x")
    assert main(["transfer-hair", "--hair", str(src), "--onto", str(dst), "-o", str(tmp_path / "busy")]) == 2
    assert not out.exists() and (tmp_path / "busy" / "keep.txt").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["busy"]  # no temp folders left


def test_cli_hair_grid(folders, tmp_path, capsys):
    from avatarkit.cli.main import main
    from avatarkit.export.images import read_png

    src, dst = folders
    png = tmp_path / "grid.png"
    code = main(["hair-grid", "--head", str(dst), "--hair", str(src), str(src), "-o", str(png),
                 "--views", "front,three-quarter,back", "--size", "48", "-q"])
    assert code == 0, capsys.readouterr().err
    assert read_png(png).shape[:2] == (2 * 48 + 3 * 4, 3 * 48 + 4 * 4)
    assert main(["hair-grid", "--head", str(dst), "--hair", str(src), "-o", str(png), "--views", "left"]) == 2
    assert "unknown view 'left'" in capsys.readouterr().err
    assert main(["hair-grid", "--head", str(dst), "--hair", str(src), "-o", str(tmp_path / "g.jpg")]) == 2
    assert ".png" in capsys.readouterr().err


def test_cli_commands_registered_and_defaults_agree():
    from click.testing import CliRunner

    from avatarkit.cli import hair_cmd
    from avatarkit.cli.main import COMMANDS, cli

    assert COMMANDS["transfer-hair"] == "avatarkit.cli.hair_cmd:transfer_hair_cmd"
    assert COMMANDS["hair-grid"] == "avatarkit.cli.hair_cmd:hair_grid_cmd"
    margin = {p.name: p.default for p in hair_cmd.transfer_hair_cmd.params}["margin"]
    assert margin == MARGIN
    for name in ("transfer-hair", "hair-grid"):
        r = CliRunner().invoke(cli, [name, "--help"])
        assert r.exit_code == 0 and "Examples" in r.output
