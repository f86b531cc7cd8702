"""Avatar bundle: the sample avatar, the folder format, save/load round trips, and every way a
folder can be broken (each a FormatError that names the file)."""
from __future__ import annotations

import functools
import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from avatarkit.avatar import (AVATAR_FORMAT, BALD_FILE, CAGE_FILE, HAIR_FILE, MANIFEST, PREVIEW_FILE,
                              RIG_FILE, Avatar, HeadModelChangedWarning, HeadRef, RigRebuiltWarning,
                              check_avatar_target, inspect_avatar, load_avatar, load_rest_splats,
                              read_manifest)
from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.gaussians.ply import read_ply, write_ply

N_BALD, N_HAIR = 2000, 1500


@functools.cache
def small_avatar() -> Avatar:
    """One small sample avatar per test process (shared by the avatar, bake and CLI tests)."""
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    return make_sample_avatar(n_hair=N_HAIR, n_bald=N_BALD, cage_vertices=300, seed=3)


_SAVED: dict[str, Path] = {}


def saved_avatar(tmp_path_factory) -> Path:
    """The small avatar saved once per process (tests copy it before breaking it)."""
    if "path" not in _SAVED or not _SAVED["path"].is_dir():
        _SAVED["path"] = small_avatar().save(tmp_path_factory.mktemp("avatar") / "sample")
    return _SAVED["path"]


@pytest.fixture(scope="module")
def avatar():
    return small_avatar()


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return saved_avatar(tmp_path_factory)


@pytest.fixture
def copy(folder, tmp_path):
    """A fresh copy of the saved avatar folder to break."""
    return Path(shutil.copytree(folder, tmp_path / "copy"))


# --- the sample avatar -------------------------------------------------------------------------

def test_sample_avatar_counts_and_binding(avatar):
    head = avatar.head_model
    assert len(avatar.bald) == N_BALD
    assert len(avatar.hair) == N_HAIR  # the generator's surplus is cut to the exact count
    ids = avatar.bald.extras["binding"]
    assert ids.dtype == np.int32 and ids.min() >= 0 and ids.max() < head.num_faces
    assert avatar.rig.deformer.weights_t.shape == (avatar.cage.n_vertices, 2 * N_HAIR)
    assert avatar.rig.model.num_vertices == avatar.cage.n_vertices


def test_bald_discs_lie_flat_on_their_triangles(avatar):
    from avatarkit.rig.frames import triangle_frames
    from avatarkit.rotations import quat_to_matrix

    v = avatar.rest_head_vertices.astype(np.float64)
    f = avatar.head_model.faces[avatar.bald.extras["binding"]]
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # on the plane of the host triangle, and inside it (barycentric coordinates >= 0)
    d = np.einsum("ij,ij->i", avatar.bald.means - tri[:, 0], normal)
    assert np.abs(d).max() < 1e-6
    import trimesh
    bary = trimesh.triangles.points_to_barycentric(tri, avatar.bald.means.astype(np.float64))
    assert bary.min() > -1e-4
    # thin axis (index 1) along the normal, the two others in the plane
    r = quat_to_matrix(avatar.bald.quats.astype(np.float64))
    assert np.abs(np.einsum("ij,ij->i", r[:, :, 1], normal)).min() > 0.9999
    s = avatar.bald.scales
    assert (s[:, 1] < 0.2 * s[:, [0, 2]].min(axis=1)).all()
    _, rot, _ = triangle_frames(v, f)
    assert np.allclose(np.abs(np.einsum("nij,nij->n", rot, r)), 3, atol=1e-4)  # the triangle frame


def test_bald_colours_follow_the_face(avatar):
    from avatarkit.synthetic.sample_avatar import IRIS, PUPIL, SCLERA, make_bald

    head = avatar.head_model
    bald = make_bald(head, avatar.rest_head_vertices, 20000, seed=1)  # enough for statistics
    rgb = bald.colors
    faces = head.faces[bald.extras["binding"]]
    in_region = lambda name: head.region_mask(name)[faces].sum(axis=1) >= 2  # noqa: E731
    skin = in_region("scalp")
    lips = in_region("lips") & ~in_region("mouth_interior")
    assert skin.sum() > 50 and lips.sum() > 5
    redness = lambda c: c[:, 0] - c[:, 1:].mean(axis=1)  # noqa: E731
    assert redness(rgb[lips]).mean() > redness(rgb[skin]).mean() + 0.1
    eyes = in_region("eyes")
    assert eyes.sum() > 5
    eye_cols = rgb[eyes]
    near = lambda c: np.abs(eye_cols - np.asarray(c)).max(axis=1) < 0.08  # noqa: E731
    assert (near(SCLERA) | near(IRIS) | near(PUPIL)).all()
    assert near(SCLERA).any()
    # brows: darker skin above the eyes
    brows = (rgb.mean(axis=1) < 0.35) & ~eyes & ~in_region("mouth_interior")
    eye_y = head.rest_joints()[0][3, 1]
    assert brows.sum() > 20 and (bald.means[brows, 1] > eye_y).all()


def test_hair_is_outside_the_head(avatar):
    d, _ = avatar.rig.model.sdf.query(avatar.hair.means)
    assert (d > 0).mean() > 0.999


def test_make_bald_is_deterministic(avatar):
    from avatarkit.synthetic.sample_avatar import make_bald

    a = make_bald(avatar.head_model, avatar.rest_head_vertices, 300, seed=5)
    b = make_bald(avatar.head_model, avatar.rest_head_vertices, 300, seed=5)
    c = make_bald(avatar.head_model, avatar.rest_head_vertices, 300, seed=6)
    assert np.array_equal(a.means, b.means) and np.array_equal(a.sh, b.sh)
    assert not np.array_equal(a.means, c.means)
    with pytest.raises(InputError):
        make_bald(avatar.head_model, avatar.rest_head_vertices, 0)


def test_assemble_binds_and_rigs_the_parts(avatar):
    """Parts from elsewhere (e.g. reconstruction): unbound bald Gaussians get their nearest face."""
    a = Avatar.assemble(avatar.head_model, avatar.bald.replace(extras={}), avatar.hair, cage=avatar.cage,
                        name="made", provenance={"source_image": "me.jpg"})
    # sampled inside their triangles, so the nearest face is the one they came from (edges aside)
    assert (a.bald.extras["binding"] == avatar.bald.extras["binding"]).mean() > 0.95
    assert np.array_equal(a.rig.deformer.weights_t, avatar.rig.deformer.weights_t)
    assert np.array_equal(a.rig.model.roots, avatar.rig.model.roots)
    assert a.provenance["source_image"] == "me.jpg" and a.provenance["tool"] == "avatarkit"
    assert a.name == "made" and a.head_ref.kind == "template"


# --- save / load --------------------------------------------------------------------------------

def test_folder_layout_and_manifest(folder, avatar):
    from avatarkit.schemas import validate

    names = {p.name for p in folder.iterdir()}
    assert names == {MANIFEST, BALD_FILE, HAIR_FILE, CAGE_FILE, RIG_FILE, PREVIEW_FILE}
    m = json.loads((folder / MANIFEST).read_text())
    validate(m, "avatar")
    assert m["format"] == AVATAR_FORMAT and m["version"] == 1
    assert m["head_model"]["kind"] == "template"
    assert m["head_model"]["vertices"] == avatar.head_model.num_vertices
    assert m["parts"]["bald"]["count"] == N_BALD and m["parts"]["hair"]["count"] == N_HAIR
    assert m["provenance"]["tool"] == "avatarkit" and "make_sample_avatar" in m["provenance"]["generator"]
    assert len(m["identity"]["shape"]) == avatar.head_model.num_shape
    # bald.ply opens as a plain 3DGS file with the binding extra, in the INRIA order
    from plyfile import PlyData
    ply = PlyData.read(str(folder / BALD_FILE))
    names = [p.name for p in ply["vertex"].properties]
    assert names[:3] == ["x", "y", "z"] and names[-1] == "binding"
    assert np.array_equal(np.asarray(ply["vertex"]["binding"]), avatar.bald.extras["binding"])
    # files get the usual permissions, not the temp folder's private ones
    mask = os.umask(0)
    os.umask(mask)
    assert (folder.stat().st_mode & 0o777) == (0o777 & ~mask)


def test_round_trip(folder, avatar, tmp_path):
    loaded = load_avatar(folder)
    # bit-exact where the PLY stores our floats as they are
    assert np.array_equal(loaded.bald.means, avatar.bald.means)
    assert np.array_equal(loaded.bald.quats, avatar.bald.quats)
    assert np.array_equal(loaded.bald.sh, avatar.bald.sh)
    assert np.array_equal(loaded.bald.extras["binding"], avatar.bald.extras["binding"])
    assert np.array_equal(loaded.hair.means, avatar.hair.means)
    assert np.array_equal(loaded.hair.extras["strand"], avatar.hair.extras["strand"])
    # PLY stores log-scales and logit opacities: equal to float32 rounding
    np.testing.assert_allclose(loaded.bald.scales, avatar.bald.scales, rtol=1e-6)
    np.testing.assert_allclose(loaded.hair.opacities, avatar.hair.opacities, rtol=1e-6, atol=1e-7)
    assert np.array_equal(loaded.cage.vertices, avatar.cage.vertices)
    assert np.array_equal(loaded.cage.faces, avatar.cage.faces)
    assert np.array_equal(loaded.shape, avatar.shape)
    assert loaded.head_ref == avatar.head_ref and loaded.name == avatar.name
    # the rig comes back: every simulation table and the SDF exactly; the MVC weights are
    # recomputed from hair.ply, whose log-scales move the axis ends by float32 rounding
    np.testing.assert_allclose(loaded.rig.deformer.weights_t, avatar.rig.deformer.weights_t, atol=1e-6)
    for name, value in vars(avatar.rig.model).items():
        other = getattr(loaded.rig.model, name)
        if name == "sdf":
            assert np.array_equal(other.values_grad, value.values_grad)
            assert np.array_equal(other.origin, value.origin) and other.spacing == value.spacing
        elif isinstance(value, np.ndarray):
            assert np.array_equal(other, value), name
        else:
            assert other == value, name
    # triangle-local values recomputed on load agree with the in-memory ones
    np.testing.assert_allclose(loaded.binding.local.means, avatar.binding.local.means, atol=1e-5)
    assert loaded.preview is not None and loaded.preview.shape == (512, 512, 3)
    assert loaded.path == folder
    # saving a loaded avatar and loading again changes nothing
    again = load_avatar(loaded.save(tmp_path / "again"))
    for part in ("bald", "hair"):
        a, b = getattr(loaded, part), getattr(again, part)
        for field in ("means", "quats", "scales", "opacities", "sh"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), (part, field)
    assert np.array_equal(again.rig.deformer.weights_t, loaded.rig.deformer.weights_t)  # deterministic
    assert json.loads((tmp_path / "again" / MANIFEST).read_text())["provenance"]["created"] == \
        json.loads((folder / MANIFEST).read_text())["provenance"]["created"]


def test_resave_replaces_an_avatar_folder_atomically(avatar, copy, monkeypatch):
    before = sorted(p.name for p in copy.iterdir())
    monkeypatch.setattr(type(avatar.rig), "save", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        avatar.save(copy)
    assert sorted(p.name for p in copy.iterdir()) == before  # the old folder is intact
    assert [p.name for p in copy.parent.iterdir() if p.name.startswith(".")] == []  # no temp left
    monkeypatch.undo()
    avatar.save(copy, preview=False)  # the in-memory avatar has no image: none is written
    assert PREVIEW_FILE not in {p.name for p in copy.iterdir()}
    assert load_avatar(copy).preview is None


def test_save_refuses_what_is_not_an_avatar_folder(avatar, tmp_path):
    other = tmp_path / "stuff"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="not an avatar folder"):
        avatar.save(other)
    assert (other / "notes.txt").read_text() == "mine"
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="not a folder"):
        avatar.save(tmp_path / "file")
    with pytest.raises(OutputError, match="does not exist"):
        check_avatar_target(tmp_path / "missing" / "avatar")


def test_avatar_checks_its_parts(avatar):
    bad = avatar.bald.replace(extras={})
    with pytest.raises(InputError, match="binding"):
        Avatar(avatar.head_model, bad, avatar.hair, avatar.cage, avatar.rig)
    ids = avatar.bald.extras["binding"].copy()
    ids[7] = avatar.head_model.num_faces
    with pytest.raises(InputError, match="Gaussian 7 is bound to face"):
        Avatar(avatar.head_model, avatar.bald.replace(extras={"binding": ids}), avatar.hair,
               avatar.cage, avatar.rig)
    with pytest.raises(InputError, match="rig is for"):
        Avatar(avatar.head_model, avatar.bald, avatar.hair.subset(np.arange(10)), avatar.cage, avatar.rig)
    with pytest.raises(InputError, match="coefficients"):
        Avatar(avatar.head_model, avatar.bald, avatar.hair, avatar.cage, avatar.rig,
               shape=np.ones(avatar.head_model.num_shape + 3))


# --- broken folders ---------------------------------------------------------------------------------

def _edit_manifest(folder: Path, fn) -> None:
    m = json.loads((folder / MANIFEST).read_text())
    fn(m)
    (folder / MANIFEST).write_text(json.dumps(m))


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _rewrite_bald(folder: Path, fn) -> None:
    gs = read_ply(folder / BALD_FILE)
    write_ply(folder / BALD_FILE, fn(gs))


def _bind_out_of_range(gs):
    ids = gs.extras["binding"].copy()
    ids[3] = 10 ** 7
    return gs.replace(extras={"binding": ids})


BROKEN = {
    "no manifest": (lambda f: (f / MANIFEST).unlink(), "", "no avatar.json"),
    "manifest not JSON": (lambda f: (f / MANIFEST).write_text("{nope"), MANIFEST, "not valid JSON"),
    "manifest schema": (lambda f: _edit_manifest(f, lambda m: m["parts"].pop("hair")), MANIFEST,
                        "avatar schema"),
    "newer version": (lambda f: _edit_manifest(f, lambda m: m.update(version=2)), MANIFEST, "newer"),
    "bald missing": (lambda f: (f / BALD_FILE).unlink(), BALD_FILE, "missing"),
    "bald corrupt": (lambda f: _truncate(f / BALD_FILE), BALD_FILE, ""),
    "bald not a ply": (lambda f: (f / BALD_FILE).write_bytes(b"hello"), BALD_FILE, ""),
    "binding missing": (lambda f: _rewrite_bald(f, lambda g: g.replace(extras={})), BALD_FILE, "binding"),
    "binding out of range": (lambda f: _rewrite_bald(f, _bind_out_of_range), BALD_FILE,
                             "bound to face 10000000"),
    "bald count": (lambda f: _edit_manifest(f, lambda m: m["parts"]["bald"].update(count=5)), BALD_FILE,
                   "avatar.json says 5"),
    "hair corrupt": (lambda f: _truncate(f / HAIR_FILE), HAIR_FILE, ""),
    "hair count": (lambda f: _rewrite_bald_hair(f), HAIR_FILE, "avatar.json says"),
    "cage missing": (lambda f: (f / CAGE_FILE).unlink(), CAGE_FILE, "missing"),
    "cage garbage": (lambda f: (f / CAGE_FILE).write_bytes(b"ply\nformat ascii 1.0\nend_header\n"),
                     CAGE_FILE, ""),
    "cage count": (lambda f: _edit_manifest(f, lambda m: m["parts"]["cage"].update(vertices=3)), CAGE_FILE,
                   "avatar.json says 3"),
    "rig garbage": (lambda f: (f / RIG_FILE).write_bytes(b"PK\x03\x04garbage"), RIG_FILE, "npz"),
    "rig missing": (lambda f: (f / RIG_FILE).unlink(), RIG_FILE, "missing"),
    "rig of another avatar": (lambda f: _edit_manifest(
        f, lambda m: m["parts"]["rig"].update(inputs_sha256="0" * 64)), RIG_FILE, "another avatar"),
    "head model counts": (lambda f: _edit_manifest(f, lambda m: m["head_model"].update(vertices=5023)),
                          MANIFEST, "5023 vertices"),
    "flame file missing": (lambda f: _edit_manifest(f, lambda m: m.update(head_model={
        "kind": "flame", "path": "/no/such/flame2023.pkl", "sha256": "a" * 64, "vertices": 5023,
        "faces": 9976})), MANIFEST, "not there"),
    "shape too long": (lambda f: _edit_manifest(f, lambda m: m["identity"].update(shape=[0.1] * 400)),
                       MANIFEST, "400 coefficients"),
    "preview missing": (lambda f: (f / PREVIEW_FILE).unlink(), PREVIEW_FILE, "missing"),
    "preview corrupt": (lambda f: (f / PREVIEW_FILE).write_bytes(b"not a png"), PREVIEW_FILE, "image"),
}


def _rewrite_bald_hair(folder: Path) -> None:
    gs = read_ply(folder / HAIR_FILE)
    write_ply(folder / HAIR_FILE, gs.subset(np.arange(len(gs) - 1)))


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_folder_names_the_file(copy, case):
    breaker, filename, message = BROKEN[case]
    breaker(copy)
    with pytest.raises(FormatError) as info:
        load_avatar(copy)
    err = info.value
    assert err.path is not None
    assert Path(err.path) == (copy / filename if filename else copy), str(err)
    assert message in str(err)


def test_missing_folder_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_avatar(tmp_path / "nope")


def test_changed_hair_rebuilds_the_rig_with_a_warning(copy, avatar):
    gs = read_ply(copy / HAIR_FILE)
    write_ply(copy / HAIR_FILE, gs.replace(means=gs.means + np.float32(0.0005)))
    with pytest.warns(RigRebuiltWarning, match="recomputing"):
        loaded = load_avatar(copy)
    w_new, w_old = loaded.rig.deformer.weights_t, avatar.rig.deformer.weights_t
    assert w_new.shape == w_old.shape and not np.array_equal(w_new, w_old)
    # same head: the stored SDF is kept
    assert np.array_equal(loaded.rig.model.sdf.values_grad, avatar.rig.model.sdf.values_grad)
    # the rebuilt weights reproduce the moved points (MVC linear precision)
    x = (loaded.cage.vertices.T @ w_new).T
    from avatarkit.cage.points import deformation_points
    np.testing.assert_allclose(x, deformation_points(loaded.hair), atol=2e-5)


def test_changed_template_geometry_warns(copy):
    _edit_manifest(copy, lambda m: m["head_model"].update(sha256="b" * 64))
    with pytest.warns(HeadModelChangedWarning):
        load_avatar(copy)


def test_flame_reference_checks_the_hash(tmp_path):
    model = tmp_path / "flame.pkl"
    model.write_bytes(b"not really flame")
    ref = HeadRef.for_file(model)
    assert ref.kind == "flame" and len(ref.sha256) == 64 and Path(ref.path).is_absolute()
    model.write_bytes(b"changed")
    with pytest.raises(FormatError, match="changed since"):
        ref.load()
    with pytest.raises(InputError):
        HeadRef("flame")
    with pytest.raises(InputError):
        HeadRef.for_file(tmp_path / "missing.pkl")


# --- inspection -------------------------------------------------------------------------------------

def test_inspect_avatar_folder(folder):
    from avatarkit.inspect import inspect_file

    s = inspect_file(folder)
    assert s.kind == "avatar folder"
    d = s.to_dict()
    assert d["bald_gaussians"] == N_BALD and d["hair_gaussians"] == N_HAIR
    assert {f["name"] for f in d["files"]} >= {BALD_FILE, HAIR_FILE, RIG_FILE}
    assert "template" in d["head_model"]
    assert inspect_avatar(folder).to_text().startswith("avatar folder:")
    assert read_manifest(folder)["name"] == d["name"]


# --- rig file formats -------------------------------------------------------------------------------

def test_rig_file_holds_no_dense_weights(folder, avatar):
    from avatarkit.hair_rig import RIG_FORMAT

    with np.load(folder / RIG_FILE) as z:
        assert str(z["format"]) == RIG_FORMAT == "avatarkit.rig/2"
        assert "deform_weights_t" not in z.files
        shapes = {k: z[k].shape for k in z.files}
        besides_sdf = sum(z[k].nbytes for k in z.files if k != "sdf_values")
    # nothing per hair Gaussian is left: the model's tables are per cage vertex or head face
    hair_sized = {len(avatar.hair) * m for m in (1, 2, 7)}
    assert not [k for k, shape in shapes.items() if hair_sized & set(shape)], shapes
    assert besides_sdf < 1e6


def _as_format_1(folder: Path, weights_t: np.ndarray) -> None:
    """Rewrite a folder's rig.npz the way avatarkit wrote rig format 1 (dense weights stored)."""
    with np.load(folder / RIG_FILE) as z:
        data = {k: z[k] for k in z.files}
    data["format"] = np.array("avatarkit.rig/1")
    data["deform_weights_t"] = weights_t
    with open(folder / RIG_FILE, "wb") as fh:
        np.savez(fh, **data)


def test_rig_format_1_with_dense_weights_is_still_read(copy, folder):
    fresh = load_avatar(folder)
    # marked weights: a format-1 file's weights are used as stored, not recomputed
    marked = fresh.rig.deformer.weights_t.copy()
    marked[:, 0] = marked[::-1, 0]
    _as_format_1(copy, marked)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RigRebuiltWarning)  # the inputs hash of format 1 still matches
        old = load_avatar(copy)
    assert np.array_equal(old.rig.deformer.weights_t, marked)
    # same file without its weights: a FormatError naming it
    with np.load(copy / RIG_FILE) as z:
        data = {k: z[k] for k in z.files if k != "deform_weights_t"}
    with open(copy / RIG_FILE, "wb") as fh:
        np.savez(fh, **data)
    with pytest.raises(FormatError, match="deform_weights_t") as info:
        load_avatar(copy)
    assert Path(info.value.path) == copy / RIG_FILE


def test_loaded_weights_wait_until_the_hair_moves(folder):
    loaded = load_avatar(folder)
    assert not loaded.rig.deformer.weights_ready  # loading, inspecting, rendering at rest: no MVC
    loaded.rest_gaussians()
    assert not loaded.rig.deformer.weights_ready
    loaded.hair_driver().hair_arrays(loaded.cage.vertices)
    assert loaded.rig.deformer.weights_ready


def test_recomputed_weights_bake_like_stored_ones(copy, folder):
    """Format 2 (weights recomputed on load) and format 1 (weights stored) give the same hair."""
    from avatarkit.bake import BakeConfig, bake
    from avatarkit.motion import make_clip
    from avatarkit.sim.config import SimConfig

    new = load_avatar(folder)
    _as_format_1(copy, new.rig.deformer.weights_t)
    old = load_avatar(copy)
    clip = make_clip("shake", frames=4, fps=25, expr_dims=0)
    cfg = BakeConfig(sim=SimConfig(substeps=2, iterations=4), preroll=0.0)
    for a, b in zip(bake(new, clip, cfg)[1], bake(old, clip, cfg)[1]):
        for x, y in zip((a.hair.means, a.hair.quats, a.hair.scales), (b.hair.means, b.hair.quats, b.hair.scales)):
            assert np.array_equal(x, y)


# --- hairless avatars (a bald person) ------------------------------------------------------------

@functools.cache
def hairless_avatar() -> Avatar:
    """The small sample avatar without its hair: no cage, no rig (shared with the bake tests)."""
    from avatarkit.gaussians.gaussian_set import GaussianSet

    av = small_avatar()
    return Avatar(av.head_model, av.bald, GaussianSet.empty(), None, None, av.shape, name="bald_sample")


def test_hairless_avatar_has_no_cage_or_rig(avatar):
    from avatarkit.gaussians.gaussian_set import GaussianSet

    bare = hairless_avatar()
    assert not bare.has_hair and bare.hair_mode == "none"
    assert bare.counts()["hair"] == 0 and bare.counts()["cage_vertices"] == 0
    with pytest.raises(InputError, match="no hair"):
        bare.hair_driver()
    # a cage or rig without hair, or hair without them, is refused
    with pytest.raises(InputError, match="no cage and no rig"):
        Avatar(avatar.head_model, avatar.bald, GaussianSet.empty(), avatar.cage, avatar.rig)
    with pytest.raises(InputError, match="needs its cage and its rig"):
        Avatar(avatar.head_model, avatar.bald, avatar.hair, None, None)
    # assemble of an empty hair builds no cage
    built = Avatar.assemble(avatar.head_model, avatar.bald, GaussianSet.empty())
    assert built.cage is None and built.rig is None
    # the rest splats are the bald head's, and a preview renders
    rest = bare.rest_gaussians()
    assert len(rest) == len(avatar.bald) and not rest.extras["part"].any()
    image = bare.render_preview(size=48)
    assert image.shape == (48, 48, 3) and (image < 250).any()


def test_hairless_avatar_round_trip(tmp_path):
    bare = hairless_avatar()
    out = bare.save(tmp_path / "bald", preview=False)
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, BALD_FILE]
    manifest = read_manifest(out)
    assert set(manifest["parts"]) == {"bald"}
    loaded = load_avatar(out)
    assert not loaded.has_hair and loaded.cage is None and loaded.rig is None
    np.testing.assert_allclose(loaded.bald.means, bare.bald.means, atol=1e-6)
    summary = dict(inspect_avatar(out).rows)
    assert summary["hair Gaussians"] == 0 and "hairless" in summary["cage"]
    # re-saving the loaded avatar gives the same parts; a cage listed without hair is refused
    loaded.save(out, preview=False)
    _edit_manifest(out, lambda m: m["parts"].update(cage={"file": CAGE_FILE, "vertices": 4, "faces": 4}))
    with pytest.raises(FormatError, match="avatar schema"):
        load_avatar(out)


# --- rest splats without the rig (previews) ------------------------------------------------------

def test_load_rest_splats_is_the_loaded_avatars_rest_set(folder, tmp_path):
    fast = load_rest_splats(folder)
    full = load_avatar(folder).rest_gaussians()
    for name in ("means", "quats", "scales", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(full, name))
    assert list(fast.extras) == ["part"]
    np.testing.assert_array_equal(fast.extras["part"], full.extras["part"])
    assert (fast.extras["part"] == 1).sum() == N_HAIR
    bare = hairless_avatar().save(tmp_path / "bald", preview=False)
    assert len(load_rest_splats(bare)) == N_BALD and not load_rest_splats(bare).extras["part"].any()


def test_load_rest_splats_names_the_broken_file(copy):
    (copy / HAIR_FILE).unlink()
    with pytest.raises(FormatError, match="file missing") as info:
        load_rest_splats(copy)
    assert str(copy / HAIR_FILE) in str(info.value)
    write_ply(copy / HAIR_FILE, small_avatar().hair.subset(np.arange(10)))
    with pytest.raises(FormatError, match=f"has 10 Gaussians but avatar.json says {N_HAIR}"):
        load_rest_splats(copy)
    with pytest.raises(FormatError, match="no avatar.json"):
        load_rest_splats(copy.parent)


def test_cli_renders_an_avatar_folder(folder, tmp_path, capsys):
    from avatarkit.cli.main import main
    from avatarkit.export.images import read_png, to_uint8
    from avatarkit.render import frame_camera, render

    out = tmp_path / "a.png"
    assert main(["render", str(folder), "-o", str(out), "--width", "48", "--height", "40", "-q"]) == 0
    rest = load_avatar(folder).rest_gaussians()
    expected = to_uint8(render(rest, frame_camera(rest, width=48, height=40)).rgb)
    np.testing.assert_array_equal(read_png(out), expected)
    assert main(["render", str(tmp_path), "-o", str(tmp_path / "b.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {tmp_path}") and "no avatar.json" in err and "Traceback" not in err
    assert not (tmp_path / "b.png").exists()
