"""The animated bake stage: layout, values per frame, value clips, half, Points, usdz, failures."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import trimesh
from pxr import Gf, Kind, Usd, UsdGeom, UsdVol

from avatarkit.baked import BakeFrame, BakeStatic, SplatFrame
from avatarkit.errors import InputError, OutputError
from avatarkit.export.usd_stage import (CAGE_PATH, FACE_PATH, HAIR_PATH, HEAD_PATH, ROOT_PATH, UsdStageWriter,
                                        UsdWriteOptions, face_normals, inspect_usd, validate_stage,
                                        vertex_normals)
from avatarkit.gaussians.usd import save_usd
from avatarkit.gaussians.usd_read import read_splat_prim
from avatarkit.inspect import inspect_file
from helpers import random_gaussians

FPS = 24.0
#: a quarter turn about +X, w x y z
QUARTER_X = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0], np.float32)


def _turn_y(angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation about +Y as (matrix (3, 3), quaternion (4,) wxyz)."""
    c, s = np.cos(angle), np.sin(angle)
    return (np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            np.array([np.cos(angle / 2), 0, np.sin(angle / 2), 0]))


def synthetic_bake(n_frames: int = 10, n_face: int = 60, n_hair: int = 90, face_degree: int = 3,
                   hair_degree: int = 1, seed: int = 0) -> tuple[BakeStatic, list[BakeFrame]]:
    """A small bake: an icosphere head turning about Y, splats riding it, hair scales breathing,
    a box cage swaying. The first face splat starts as a quarter turn about X."""
    from avatarkit.rotations import quat_multiply

    head = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    cage = trimesh.creation.box((0.3, 0.35, 0.3))
    face = random_gaussians(n_face, sh_degree=face_degree, seed=seed, extras=("binding",))
    quats = face.quats.copy()
    quats[0] = QUARTER_X
    face = face.replace(quats=quats)
    hair = random_gaussians(n_hair, sh_degree=hair_degree, seed=seed + 1)
    static = BakeStatic(fps=FPS, n_frames=n_frames, head_faces=head.faces.astype(np.int32), face=face, hair=hair,
                        cage_faces=cage.faces.astype(np.int32),
                        provenance={"tool": "test", "clip": {"name": "turn", "frames": n_frames},
                                    "ids": [1, 2, 3], "tags": ["a", "b"], "note": None})
    frames = []
    for i in range(n_frames):
        r, q = _turn_y(0.1 * i)
        moved = []
        for gs, grow in ((face, 1.0), (hair, 1.0 + 0.05 * i)):
            qq = quat_multiply(q[None], gs.quats.astype(np.float64))
            moved.append(SplatFrame(means=(gs.means @ r.T + [0, 0.01 * i, 0]).astype(np.float32),
                                    quats=(qq / np.linalg.norm(qq, axis=1, keepdims=True)).astype(np.float32),
                                    scales=(gs.scales * grow).astype(np.float32)))
        frames.append(BakeFrame(index=i, time=i / FPS,
                                head_vertices=(head.vertices @ r.T).astype(np.float32),
                                face=moved[0], hair=moved[1],
                                cage_vertices=(cage.vertices + [0.01 * np.sin(i), 0, 0]).astype(np.float32)))
    return static, frames


def write_bake(path, static, frames, options=None):
    with UsdStageWriter(path, options) as writer:
        writer.begin(static)
        for f in frames:
            writer.write(f)
    return writer


def _points(stage, path, t):
    return np.asarray(stage.GetPrimAtPath(path).GetAttribute("points").Get(t), np.float32)


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture(scope="module")
def bake():
    return synthetic_bake()


@pytest.mark.parametrize("ext", [".usda", ".usdc", ".usd"])
def test_chunked_stage_layout_values_and_validation(tmp_path, bake, ext):
    static, frames = bake
    path = tmp_path / f"clip{ext}"
    with UsdStageWriter(path, UsdWriteOptions(chunk_frames=4)) as writer:
        writer.begin(static)
        for f in frames:
            writer.write(f)
    # what the user gets: the stage and its clips folder, nothing temporary
    assert _listing(tmp_path) == [f"clip{ext}", "clip_clips"]
    # + the marker that lets a later bake replace the folder (and nothing else of that name)
    assert _listing(tmp_path / "clip_clips") == [".avatarkit-clips", "chunk_00000.usdc", "chunk_00001.usdc",
                                                 "chunk_00002.usdc", "manifest.usda"]
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, len(frames) - 1)
    root = stage.GetDefaultPrim()
    assert root.GetPath() == ROOT_PATH and root.IsA(UsdGeom.Xform)
    assert Usd.ModelAPI(root).GetKind() == Kind.Tokens.component
    prims = {p: stage.GetPrimAtPath(p) for p in (HEAD_PATH, FACE_PATH, HAIR_PATH, CAGE_PATH)}
    assert prims[HEAD_PATH].IsA(UsdGeom.Mesh) and prims[CAGE_PATH].IsA(UsdGeom.Mesh)
    assert prims[FACE_PATH].IsA(UsdVol.ParticleField3DGaussianSplat)
    assert prims[HAIR_PATH].IsA(UsdVol.ParticleField3DGaussianSplat)
    assert UsdGeom.Imageable(prims[CAGE_PATH]).GetPurposeAttr().Get() == UsdGeom.Tokens.guide
    head = UsdGeom.Mesh(prims[HEAD_PATH])
    assert head.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert np.array_equal(np.asarray(head.GetFaceVertexIndicesAttr().Get()), static.head_faces.reshape(-1))
    assert head.GetDisplayColorPrimvar().GetInterpolation() == UsdGeom.Tokens.constant
    # time samples: one per frame on every animated attribute, none on the static ones
    for p in (FACE_PATH, HAIR_PATH):
        for name in ("positions", "orientations", "scales", "extent"):
            assert prims[p].GetAttribute(name).GetNumTimeSamples() == len(frames), (p, name)
        for name in ("opacities", "radiance:sphericalHarmonicsCoefficients"):
            attr = prims[p].GetAttribute(name)
            assert attr.GetNumTimeSamples() == 0 and attr.HasValue()
    for p in (HEAD_PATH, CAGE_PATH):
        for name in ("points", "extent"):
            assert prims[p].GetAttribute(name).GetTimeSamples() == [float(i) for i in range(len(frames))]
    # values at frame k are the frame written, bit for bit; extents contain the points
    for f in frames:
        for p, part, rest in ((FACE_PATH, f.face, static.face), (HAIR_PATH, f.hair, static.hair)):
            gs = read_splat_prim(prims[p], f.index)
            np.testing.assert_array_equal(gs.means, part.means)
            np.testing.assert_array_equal(gs.quats, part.quats)
            np.testing.assert_array_equal(gs.scales, part.scales)
            np.testing.assert_array_equal(gs.opacities, rest.opacities)
            np.testing.assert_array_equal(gs.sh, rest.sh)
            lo, hi = np.asarray(prims[p].GetAttribute("extent").Get(f.index))
            assert (part.means >= lo).all() and (part.means <= hi).all()
            np.testing.assert_array_equal(lo, part.means.min(axis=0))
        for p, pts in ((HEAD_PATH, f.head_vertices), (CAGE_PATH, f.cage_vertices)):
            np.testing.assert_array_equal(_points(stage, p, f.index), pts)
            lo, hi = np.asarray(prims[p].GetAttribute("extent").Get(f.index))
            assert (pts >= lo).all() and (pts <= hi).all()
    data = stage.GetRootLayer().customLayerData["avatarkit"]
    assert data["frames"] == len(frames) and data["value_clips"] == 3
    prov = data["provenance"]
    assert prov["tool"] == "test" and prov["clip"] == {"name": "turn", "frames": len(frames)}
    assert list(prov["ids"]) == [1, 2, 3] and list(prov["tags"]) == ["a", "b"]
    assert "note" not in prov  # None is left out, not stored as the text "null"
    assert validate_stage(path) == []


def test_motion_interpolates_across_chunk_boundaries(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "clip.usdc"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=4))
    stage = Usd.Stage.Open(str(path))
    for t in (3.5, 7.25):  # chunk 0 | 1 and 1 | 2
        a, b = int(t), int(t) + 1
        w = t - a
        want = (1 - w) * frames[a].cage_vertices + w * frames[b].cage_vertices
        np.testing.assert_allclose(_points(stage, CAGE_PATH, t), want, atol=1e-7)
        pos = np.asarray(stage.GetPrimAtPath(FACE_PATH).GetAttribute("positions").Get(t))
        np.testing.assert_allclose(pos, (1 - w) * frames[a].face.means + w * frames[b].face.means, atol=1e-6)


def test_stage_reads_its_animated_attributes_through_the_clip_manifest(tmp_path, bake):
    """The stage names `<name>_clips/manifest.usda` as its value-clip manifest, and USD takes
    the list of clip-animated attributes from that file (without one it would scan every clip
    layer itself): an attribute struck from the manifest stops reading the clips."""
    from pxr import Sdf

    static, frames = bake
    path = tmp_path / "clip.usdc"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=4))
    manifest_file = tmp_path / "clip_clips" / "manifest.usda"
    stage = Usd.Stage.Open(str(path))
    clips = Usd.ClipsAPI(stage.GetPrimAtPath(ROOT_PATH))
    asset = clips.GetClipManifestAssetPath()
    assert asset.path == "./clip_clips/manifest.usda"
    assert os.path.samefile(asset.resolvedPath, manifest_file)
    assert [a.path for a in clips.GetClipAssetPaths()] == [f"./clip_clips/chunk_{k:05d}.usdc" for k in range(3)]
    for k in range(3):  # each chunk opened on its own still plays at the bake's rate
        chunk = Sdf.Layer.FindOrOpen(str(tmp_path / "clip_clips" / f"chunk_{k:05d}.usdc"))
        assert chunk.HasTimeCodesPerSecond() and chunk.timeCodesPerSecond == FPS
    manifest = Sdf.Layer.FindOrOpen(str(manifest_file))
    for p in (FACE_PATH, HAIR_PATH):
        for name in ("positions", "orientations", "scales", "extent"):
            assert manifest.GetAttributeAtPath(f"{p}.{name}"), (p, name)
        assert not manifest.GetAttributeAtPath(f"{p}.opacities")  # static: in the root layer
    for p in (HEAD_PATH, CAGE_PATH):
        assert manifest.GetAttributeAtPath(f"{p}.points")
    hair = np.asarray(stage.GetPrimAtPath(HAIR_PATH).GetAttribute("positions").Get(5))
    np.testing.assert_array_equal(hair, frames[5].hair.means)
    del stage

    # strike the hair's positions from the manifest: a fresh stage no longer finds them in the
    # clips, while everything the manifest still lists reads as before
    spec = Sdf.Layer.FindOrOpen(str(manifest_file)).GetPrimAtPath(HAIR_PATH)
    spec.RemoveProperty(spec.properties["positions"])
    manifest.Save()
    stage = Usd.Stage.Open(str(path))
    attr = stage.GetPrimAtPath(HAIR_PATH).GetAttribute("positions")
    assert attr.GetNumTimeSamples() == 0
    got = attr.Get(5)
    assert got is None or not np.array_equal(np.asarray(got), frames[5].hair.means)
    np.testing.assert_array_equal(np.asarray(stage.GetPrimAtPath(FACE_PATH).GetAttribute("positions").Get(5)),
                                  frames[5].face.means)


def test_short_bake_is_one_self_contained_file(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "short.usdc"
    writer = UsdStageWriter(path, UsdWriteOptions(chunk_frames=len(frames)))
    writer.begin(static)
    for f in frames:
        writer.write(f)
    result = writer.close()
    assert _listing(tmp_path) == ["short.usdc"]
    assert result.clips_dir is None and result.frames == len(frames)
    assert (result.first_frame, result.last_frame) == (0, len(frames) - 1)
    assert result.bytes == path.stat().st_size
    stage = Usd.Stage.Open(str(path))
    assert not Usd.ClipsAPI(stage.GetPrimAtPath(ROOT_PATH)).GetClipAssetPaths()
    face = stage.GetPrimAtPath(FACE_PATH)
    assert face.GetAttribute("positions").GetNumTimeSamples() == len(frames)
    np.testing.assert_array_equal(read_splat_prim(face, 7).means, frames[7].face.means)
    assert validate_stage(stage) == []


def test_result_reports_clip_files(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "c.usdc"
    writer = UsdStageWriter(path, UsdWriteOptions(chunk_frames=5))
    writer.begin(static)
    for f in frames:
        writer.write(f)
    result = writer.close()
    assert result.clips_dir == tmp_path / "c_clips"
    assert result.bytes == path.stat().st_size + sum(p.stat().st_size for p in result.clips_dir.iterdir())


def test_quaternion_order_survives(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "q.usda"
    write_bake(path, static, frames[:1], UsdWriteOptions(chunk_frames=0))
    stage = Usd.Stage.Open(str(path))
    q = stage.GetPrimAtPath(FACE_PATH).GetAttribute("orientations").Get(0)[0]
    assert isinstance(q, Gf.Quatf)
    assert q.GetReal() == pytest.approx(np.cos(np.pi / 4))
    assert tuple(q.GetImaginary()) == pytest.approx((np.sin(np.pi / 4), 0, 0))
    np.testing.assert_allclose(read_splat_prim(stage.GetPrimAtPath(FACE_PATH), 0).quats[0], QUARTER_X, atol=1e-7)
    text = path.read_text()
    assert "(0.70710677, 0.70710677, 0, 0)" in text  # USD text: real part first


def test_half_precision(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "half.usdc"
    write_bake(path, static, frames, UsdWriteOptions(half=True, chunk_frames=4))
    stage = Usd.Stage.Open(str(path))
    face = stage.GetPrimAtPath(FACE_PATH)
    for name in ("positions", "orientations", "scales", "opacities", "radiance:sphericalHarmonicsCoefficients"):
        assert not face.GetAttribute(name).HasValue()
    assert face.GetAttribute("positionsh").GetNumTimeSamples() == len(frames)
    assert face.GetAttribute("orientationsh").GetTypeName() == "quath[]"
    rel = 2.0 ** -11
    for f in (frames[0], frames[5], frames[-1]):
        gs = read_splat_prim(face, f.index)
        np.testing.assert_allclose(gs.means, f.face.means, rtol=rel, atol=1e-7)
        np.testing.assert_allclose(gs.quats, f.face.quats, rtol=rel, atol=rel)
        np.testing.assert_allclose(gs.scales, f.face.scales, rtol=rel)
        np.testing.assert_allclose(gs.sh, static.face.sh, rtol=rel, atol=1e-7)
        np.testing.assert_array_equal(_points(stage, HEAD_PATH, f.index), f.head_vertices)  # meshes stay float
    assert validate_stage(stage) == []


def test_usdz_packages_clips_and_opens_with_all_samples(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "clip.usdz"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=3))
    assert _listing(tmp_path) == ["clip.usdz"]
    stage = Usd.Stage.Open(str(path))
    assert stage.GetEndTimeCode() == len(frames) - 1
    hair = stage.GetPrimAtPath(HAIR_PATH)
    assert hair.GetAttribute("scales").GetNumTimeSamples() == len(frames)
    for f in frames:
        np.testing.assert_array_equal(read_splat_prim(hair, f.index).scales, f.hair.scales)
        np.testing.assert_array_equal(_points(stage, HEAD_PATH, f.index), f.head_vertices)
    assert validate_stage(path) == []


@pytest.mark.parametrize("half", [False, True])
def test_usd_points_variant(tmp_path, bake, half):
    static, frames = bake
    path = tmp_path / "points.usdc"
    write_bake(path, static, frames, UsdWriteOptions(usd_points=True, half=half, chunk_frames=4))
    stage = Usd.Stage.Open(str(path))
    rel = 2.0 ** -11 if half else 0
    for p, part, rest in ((FACE_PATH, "face", static.face), (HAIR_PATH, "hair", static.hair)):
        prim = stage.GetPrimAtPath(p)
        assert prim.IsA(UsdGeom.Points) and not prim.IsA(UsdVol.ParticleField3DGaussianSplat)
        points = UsdGeom.Points(prim)
        pv = UsdGeom.PrimvarsAPI(prim)
        assert prim.GetAttribute("orientations").GetTypeName() == ("quath[]" if half else "quatf[]")
        assert points.GetWidthsInterpolation() == UsdGeom.Tokens.vertex
        scales_pv = pv.GetPrimvar("scales")
        assert scales_pv.GetInterpolation() == UsdGeom.Tokens.vertex
        sh = pv.GetPrimvar("radiance:sphericalHarmonicsCoefficients")
        assert sh.GetElementSize() == rest.sh.shape[1] and sh.GetInterpolation() == UsdGeom.Tokens.vertex
        assert pv.GetPrimvar("radiance:sphericalHarmonicsDegree").Get() == rest.sh_degree
        np.testing.assert_allclose(np.asarray(sh.Get()).reshape(rest.sh.shape), rest.sh, rtol=rel, atol=1e-7)
        np.testing.assert_array_equal(np.asarray(pv.GetPrimvar("displayOpacity").Get()), rest.opacities)
        np.testing.assert_allclose(np.asarray(pv.GetPrimvar("displayColor").Get()), rest.colors, atol=1e-7)
        for f in (frames[0], frames[6]):
            moving = getattr(f, part)
            pts = np.asarray(points.GetPointsAttr().Get(f.index))
            np.testing.assert_array_equal(pts, moving.means)
            xyzw = np.asarray(prim.GetAttribute("orientations").Get(f.index))
            np.testing.assert_allclose(xyzw[:, [3, 0, 1, 2]], moving.quats, rtol=rel, atol=rel)
            np.testing.assert_allclose(np.asarray(scales_pv.Get(f.index)), moving.scales, rtol=rel)
            widths = np.asarray(points.GetWidthsAttr().Get(f.index))
            np.testing.assert_allclose(widths, 2 * moving.scales.max(axis=1), rtol=1e-6)
            lo, hi = np.asarray(points.GetExtentAttr().Get(f.index))
            assert (pts - widths[:, None] / 2 >= lo - 1e-7).all() and (pts + widths[:, None] / 2 <= hi + 1e-7).all()
            np.testing.assert_allclose([lo, hi], np.asarray(points.ComputeExtent(pts, widths)), atol=1e-7)
    assert prim.GetAttribute("orientations").GetNumTimeSamples() == len(frames)
    assert validate_stage(stage) == []


@pytest.mark.parametrize("chunk_frames", [0, 4])
def test_head_and_cage_normals(tmp_path, bake, chunk_frames):
    """By default the head has smooth normals and the cage flat ones, time-sampled, with
    subdivision off: every mesh has normals or a subdivision scheme, never both."""
    static, frames = bake
    path = tmp_path / "n.usdc"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=chunk_frames))
    stage = Usd.Stage.Open(str(path))
    head = UsdGeom.Mesh(stage.GetPrimAtPath(HEAD_PATH))
    cage = UsdGeom.Mesh(stage.GetPrimAtPath(CAGE_PATH))
    assert head.GetSubdivisionSchemeAttr().Get() == cage.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    pv = UsdGeom.PrimvarsAPI(head).GetPrimvar("normals")
    assert pv.GetInterpolation() == UsdGeom.Tokens.faceVarying and pv.IsIndexed()
    assert not head.GetNormalsAttr().HasAuthoredValue()  # one set of normals only
    np.testing.assert_array_equal(np.asarray(pv.GetIndices()), static.head_faces.reshape(-1))
    assert pv.GetAttr().GetTimeSamples() == [float(f.index) for f in frames]
    assert cage.GetNormalsInterpolation() == UsdGeom.Tokens.uniform
    assert cage.GetNormalsAttr().GetTimeSamples() == [float(f.index) for f in frames]
    for f in (frames[0], frames[5], frames[-1]):
        v = f.head_vertices
        n = np.asarray(pv.Get(f.index))  # one value per vertex
        np.testing.assert_allclose(n, vertex_normals(v, static.head_faces), atol=1e-7)
        corners = np.asarray(pv.ComputeFlattened(f.index))  # what a renderer sees per face corner
        np.testing.assert_array_equal(corners, n[static.head_faces.reshape(-1)])
        # an icosphere about the origin: normals point outwards, close to the radial direction
        radial = v / np.linalg.norm(v, axis=1, keepdims=True)
        assert (np.einsum("ij,ij->i", n, radial) > 0.98).all()
        # the cage box: each face normal is an axis, pointing away from the box centre
        c = f.cage_vertices
        fn = np.asarray(cage.GetNormalsAttr().Get(f.index))
        assert fn.shape == (len(static.cage_faces), 3)
        np.testing.assert_allclose(np.abs(fn).max(axis=1), 1, atol=1e-6)
        out = c[static.cage_faces].mean(axis=1) - c.mean(axis=0)
        assert (np.einsum("ij,ij->i", fn, out) > 0).all()
    assert validate_stage(stage) == []


def test_head_without_normals_is_a_subdivision_surface(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "s.usdc"
    write_bake(path, static, frames, UsdWriteOptions(head_normals=False, chunk_frames=0))
    stage = Usd.Stage.Open(str(path))
    head = UsdGeom.Mesh(stage.GetPrimAtPath(HEAD_PATH))
    assert head.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.loop
    assert not UsdGeom.PrimvarsAPI(head).HasPrimvar("normals") and not head.GetNormalsAttr().HasAuthoredValue()
    assert validate_stage(stage) == []


def test_face_normals_match_a_plain_loop():
    mesh = trimesh.creation.capsule(height=0.2, radius=0.1, count=[8, 8])
    v, f = mesh.vertices, mesh.faces
    want = np.array([np.cross(v[b] - v[a], v[c] - v[a]) for a, b, c in f])
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(face_normals(v, f), want, atol=1e-6)
    np.testing.assert_allclose(face_normals(v, f), mesh.face_normals, atol=1e-6)  # trimesh agrees
    # a degenerate face has no normal
    assert (face_normals(np.vstack([v, [[9, 9, 9]]]), np.vstack([f, [[len(v)] * 3]]))[-1] == 0).all()


def test_vertex_normals_match_a_plain_loop():
    mesh = trimesh.creation.capsule(height=0.2, radius=0.1, count=[8, 8])
    v, f = mesh.vertices, mesh.faces
    want = np.zeros_like(v)
    for a, b, c in f:  # the obvious reference: add each face's area-weighted normal to its corners
        fn = np.cross(v[b] - v[a], v[c] - v[a])
        for i in (a, b, c):
            want[i] += fn
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(vertex_normals(v, f), want, atol=1e-6)
    # a vertex no face uses has no normal
    assert (vertex_normals(np.vstack([v, [[9, 9, 9]]]), f)[-1] == 0).all()


def test_abort_on_exception_leaves_nothing_and_keeps_the_old_stage(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "clip.usdc"
    write_bake(path, static, frames[:6], UsdWriteOptions(chunk_frames=4))
    before = {p.name: p.read_bytes() for p in [path, *sorted((tmp_path / "clip_clips").iterdir())]}
    with pytest.raises(KeyboardInterrupt):
        with UsdStageWriter(path, UsdWriteOptions(chunk_frames=2)) as writer:
            writer.begin(static)
            for f in frames:
                writer.write(f)
                if f.index == 6:
                    raise KeyboardInterrupt
    assert _listing(tmp_path) == ["clip.usdc", "clip_clips"]
    after = {p.name: p.read_bytes() for p in [path, *sorted((tmp_path / "clip_clips").iterdir())]}
    assert after == before
    # and into an empty folder: nothing at all
    empty = tmp_path / "empty"
    empty.mkdir()
    writer = UsdStageWriter(empty / "x.usdz", UsdWriteOptions(chunk_frames=2))
    writer.begin(static)
    for f in frames[:5]:
        writer.write(f)
    writer.abort()
    assert _listing(empty) == []


def test_rewrite_replaces_the_clip_folder(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "clip.usdc"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=2))
    assert len(list((tmp_path / "clip_clips").glob("chunk_*"))) == 5
    later = [BakeFrame(f.index, f.time, f.head_vertices + np.float32(1), f.face, f.hair, f.cage_vertices)
             for f in frames[:6]]
    write_bake(path, static, later, UsdWriteOptions(chunk_frames=4))
    assert _listing(tmp_path) == ["clip.usdc", "clip_clips"]
    assert len(list((tmp_path / "clip_clips").glob("chunk_*"))) == 2
    stage = Usd.Stage.Open(str(path))
    assert stage.GetEndTimeCode() == 5
    np.testing.assert_array_equal(_points(stage, HEAD_PATH, 5), later[5].head_vertices)


def test_frames_may_start_later_and_skip(tmp_path, bake):
    static, frames = bake
    picked = [frames[i] for i in (2, 3, 5, 8, 9)]
    path = tmp_path / "part.usda"
    write_bake(path, static, picked, UsdWriteOptions(chunk_frames=2))
    stage = Usd.Stage.Open(str(path))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (2, 9)
    attr = stage.GetPrimAtPath(HAIR_PATH).GetAttribute("positions")
    assert attr.GetTimeSamples() == [2.0, 3.0, 5.0, 8.0, 9.0]
    for f in picked:
        np.testing.assert_array_equal(np.asarray(attr.Get(f.index)), f.hair.means)


def test_output_errors(tmp_path, bake):
    static, frames = bake
    with pytest.raises(OutputError, match="unknown USD extension"):
        UsdStageWriter(tmp_path / "x.abc")
    with pytest.raises(OutputError, match="does not exist"):
        UsdStageWriter(tmp_path / "missing" / "x.usdc").begin(static)
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    with pytest.raises(OutputError):
        UsdStageWriter(blocker / "x.usdc").begin(static)
    (tmp_path / "dir.usdc").mkdir()
    with pytest.raises(OutputError, match="is a folder"):
        UsdStageWriter(tmp_path / "dir.usdc").begin(static)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root may write anywhere")
def test_unwritable_folder(tmp_path, bake):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="not writable"):
            UsdStageWriter(locked / "x.usdc").begin(bake[0])
    finally:
        locked.chmod(0o700)


def test_unwritable_folder_as_any_user(tmp_path, bake, monkeypatch):
    """The same case for root (as CI runs), who may write anywhere: the folder refuses the
    writer's temporary folder (injected EACCES), and nothing is left."""
    import errno
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(tempfile, "mkdtemp", refuse)
    with pytest.raises(OutputError, match="not writable") as e:
        UsdStageWriter(tmp_path / "x.usdc").begin(bake[0])
    assert str(tmp_path) in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_bad_frames_are_input_errors_and_leave_nothing(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "bad.usdc"
    short = BakeFrame(3, 3 / FPS, frames[3].head_vertices, frames[3].face,
                      SplatFrame(frames[3].hair.means[:-1], frames[3].hair.quats[:-1], frames[3].hair.scales[:-1]),
                      frames[3].cage_vertices)
    nan = frames[3].face.means.copy()
    nan[4, 1] = np.nan
    cases = [
        (short, "frame 3: hair has 89 Gaussians but the bake.s static data has 90"),
        (BakeFrame(3, 0.0, frames[3].head_vertices, SplatFrame(nan, frames[3].face.quats, frames[3].face.scales),
                   frames[3].hair, frames[3].cage_vertices), "frame 3: face: means has a non-finite value"),
        (BakeFrame(3, 0.0, frames[3].head_vertices[:5], frames[3].face, frames[3].hair, frames[3].cage_vertices),
         "head_vertices has 5 vertices"),
        (frames[1], "increasing index order; 1 follows 2"),
    ]
    for bad, message in cases:
        with pytest.raises(InputError, match=message):
            with UsdStageWriter(path, UsdWriteOptions(chunk_frames=2)) as writer:
                writer.begin(static)
                for f in frames[:3]:
                    writer.write(f)
                writer.write(bad)
        assert _listing(tmp_path) == []
    with pytest.raises(InputError, match="no frames"):
        with UsdStageWriter(path) as writer:
            writer.begin(static)
    assert _listing(tmp_path) == []
    with pytest.raises(InputError, match="begin"):
        UsdStageWriter(path).write(frames[0])
    with pytest.raises(InputError, match="chunk_frames"):
        UsdStageWriter(path, UsdWriteOptions(chunk_frames=-1))
    with pytest.raises(InputError, match="fps"):
        UsdStageWriter(path).begin(BakeStatic(0.0, 1, static.head_faces, static.face, static.hair, static.cage_faces))
    assert _listing(tmp_path) == []


@pytest.mark.parametrize("up_axis", ["Y", "Z"])
def test_split_splat_writer_equals_write(up_axis):
    """write_static + write_samples author exactly what write(gs, time) does, Z-up turn included."""
    from avatarkit.gaussians.usd import create_stage
    from avatarkit.gaussians.usd_prims import SplatPrimWriter

    gs = [random_gaussians(40, sh_degree=2, seed=s) for s in (3, 4)]
    gs[1] = gs[0].replace(means=gs[1].means, quats=gs[1].quats, scales=gs[1].scales)
    stage = create_stage(up_axis=up_axis)
    whole, split = SplatPrimWriter(stage, "/A/Whole"), SplatPrimWriter(stage, "/A/Split")
    split.write_static(gs[0])
    for t, g in enumerate(gs):
        whole.write(g, time=t)
        split.write_samples(t, g.means, g.quats, g.scales)
    a, b = stage.GetPrimAtPath("/A/Whole"), stage.GetPrimAtPath("/A/Split")
    for name in ("positions", "orientations", "scales", "extent", "opacities",
                 "radiance:sphericalHarmonicsCoefficients", "radiance:sphericalHarmonicsDegree",
                 "primvars:displayColor"):
        assert a.GetAttribute(name).GetTimeSamples() == b.GetAttribute(name).GetTimeSamples(), name
        for t in (Usd.TimeCode.Default(), 0, 1):
            va, vb = a.GetAttribute(name).Get(t), b.GetAttribute(name).Get(t)
            assert (va is None and vb is None) or np.array_equal(np.asarray(va), np.asarray(vb)), (name, t)
    with pytest.raises(InputError, match="first write"):
        split.write_static(gs[0])
    with pytest.raises(InputError, match="write_samples"):
        split.write(gs[0], time=2)
    with pytest.raises(InputError, match="39 Gaussians but the prim has 40"):
        split.write_samples(2, gs[0].means[1:], gs[0].quats[1:], gs[0].scales[1:])
    with pytest.raises(InputError, match="scales must be > 0"):
        split.write_samples(2, gs[0].means, gs[0].quats, -gs[0].scales)
    with pytest.raises(InputError, match=r"quats must have shape \(N, 4\)"):
        split.write_samples(2, gs[0].means, gs[0].quats[:, :3], gs[0].scales)


def test_inspect_bake_stage_and_convert_file(tmp_path, bake):
    static, frames = bake
    path = tmp_path / "clip.usda"
    write_bake(path, static, frames, UsdWriteOptions(chunk_frames=4))
    summary = inspect_file(path)
    assert summary.kind == "USD stage"
    assert summary.get("frames") == len(frames) and summary.get("fps") == FPS
    assert summary.get("frame range") == [0, len(frames) - 1]
    assert summary.get("splats") == len(static.face) + len(static.hair)
    assert summary.get("value clips")["layers"] == 3
    rows = {r["name"]: r for r in summary.get("prims")}
    assert rows[FACE_PATH]["type"] == "ParticleField3DGaussianSplat" and rows[FACE_PATH]["splats"] == len(static.face)
    assert rows[FACE_PATH]["sh_degree"] == 3 and rows[HAIR_PATH]["sh_degree"] == 1
    assert rows[HEAD_PATH]["time_samples"] == len(frames) and rows[CAGE_PATH]["purpose"] == "guide"
    assert "provenance" in json.loads(summary.get("custom layer data"))["avatarkit"]
    json.dumps(summary.to_dict())
    assert "ParticleField3DGaussianSplat" in summary.to_text()
    # a one-shot file from `convert`
    one = tmp_path / "one.usdz"
    save_usd(one, static.hair)
    summary = inspect_usd(one)
    assert summary.get("frames") == "static (no time samples)"
    assert summary.get("splats") == len(static.hair) and summary.get("format").startswith("USDZ")
    # Points variant counts its splats too
    pts = tmp_path / "p.usdc"
    write_bake(pts, static, frames[:2], UsdWriteOptions(usd_points=True))
    assert inspect_file(pts).get("splats") == len(static.face) + len(static.hair)


def test_inspect_cli(tmp_path, bake):
    from avatarkit.cli.main import main

    static, frames = bake
    path = tmp_path / "clip.usdc"
    write_bake(path, static, frames[:3])
    assert main(["inspect", str(path)]) == 0
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\ndef Xform \"A\" {\n")
    assert main(["inspect", str(bad)]) == 2
