"""bake(): per-frame head, bald and hair results of the sample avatar driven by short clips."""
from __future__ import annotations

import tracemalloc
import warnings

import numpy as np
import pytest

from avatarkit.bake import BakeConfig, bake, check_clip, prepare_clip, run_bake
from avatarkit.bake_writers import PreviewWriter
from avatarkit.rig.binding_kernel import binding_to_world
from avatarkit.errors import InputError
from avatarkit.head.model import HeadParams
from avatarkit.motion import ExprDimsWarning, MotionClip, make_clip
from avatarkit.sim.config import SimConfig
from test_avatar import small_avatar

FAST = SimConfig(substeps=2, iterations=6)  # enough to exercise the solver, cheap


@pytest.fixture(scope="module")
def avatar():
    return small_avatar()


@pytest.fixture(scope="module")
def shake():
    return make_clip("shake", frames=8, fps=25, expr_dims=0)


@pytest.fixture(scope="module")
def baked(avatar, shake):
    static, frames = bake(avatar, shake, BakeConfig(sim=FAST, preroll=0.2))
    return static, list(frames)


def _turn(n: int, degrees: float = 40.0, axis=(0.0, 1.0, 0.0), fps: float = 25.0) -> MotionClip:
    """The head turning about the root joint (global rotation only)."""
    angle = np.radians(degrees) * np.linspace(0, 1, n)[:, None]
    clip = MotionClip.rest(n, fps)
    return clip.replace(rotation=angle * np.asarray(axis, np.float32), name="turn")


def test_static_data_and_frame_stream(avatar, shake, baked):
    static, frames = baked
    assert static.n_frames == len(frames) == shake.n_frames and static.fps == shake.fps
    assert static.face is avatar.bald and static.hair is avatar.hair
    assert np.array_equal(static.head_faces, avatar.head_model.faces)
    assert np.array_equal(static.cage_faces, avatar.cage.faces)
    assert static.provenance["source_frames"] == [0, shake.n_frames]
    assert static.provenance["settings"]["sim"]["substeps"] == 2
    for k, f in enumerate(frames):
        assert f.index == k and f.time == pytest.approx(k / shake.fps)
        assert f.head_vertices.shape == (avatar.head_model.num_vertices, 3)
        assert f.cage_vertices.shape == (avatar.cage.n_vertices, 3)
        for part, n in (("face", len(avatar.bald)), ("hair", len(avatar.hair))):
            s = getattr(f, part)
            assert s.means.shape == (n, 3) and s.quats.shape == (n, 4) and s.scales.shape == (n, 3)
            for a in (s.means, s.quats, s.scales):
                assert a.dtype == np.float32 and np.isfinite(a).all()
            np.testing.assert_allclose(np.linalg.norm(s.quats, axis=1), 1, atol=1e-5)
            assert (s.scales > 0).all()
        assert f.gaussians(static, "face").extras["binding"] is avatar.bald.extras["binding"]


def test_head_vertices_are_the_models_forward(avatar, shake, baked):
    _, frames = baked
    params = HeadParams.from_clip(shake)
    params.shape = avatar.shape
    want, _ = avatar.head_model.forward(params)
    got = np.stack([f.head_vertices for f in frames])
    assert np.array_equal(got, want)


def test_bald_gaussians_ride_their_triangles(avatar, baked):
    """Each frame's bald Gaussians equal the reference TriangleBinding.to_world."""
    _, frames = baked
    for f in frames[::3]:
        ref = avatar.binding.to_world(f.head_vertices)
        np.testing.assert_allclose(f.face.means, ref.means, atol=2e-7)
        np.testing.assert_allclose(f.face.scales, ref.scales, rtol=2e-6)
        np.testing.assert_allclose(f.face.quats, ref.quats, atol=2e-6)


def test_fast_binding_matches_reference_on_random_meshes(avatar):
    """The fused kernel against the numpy reference on wildly deformed heads."""
    rng = np.random.default_rng(0)
    for _ in range(3):
        v = avatar.rest_head_vertices + rng.normal(0, 0.003, avatar.rest_head_vertices.shape).astype(np.float32)
        ref = avatar.binding.to_world(v)
        m, q, s = binding_to_world(avatar.binding, v)
        np.testing.assert_allclose(m, ref.means, atol=2e-7)
        np.testing.assert_allclose(s, ref.scales, rtol=2e-6)
        np.testing.assert_allclose(q, ref.quats, atol=2e-6)


def test_collapsed_triangle_is_reported(avatar):
    v = avatar.rest_head_vertices.copy()
    face = int(avatar.bald.extras["binding"][0])
    a, b, c = avatar.head_model.faces[face]
    v[b] = v[a]
    with pytest.raises(InputError, match=f"triangle {face} collapsed"):
        binding_to_world(avatar.binding, v)


def _kabsch(a: np.ndarray, b: np.ndarray):
    """The rigid (R, t) taking points a (N, 3) to b in the least-squares sense."""
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1, 1, d]) @ u.T
    return r, cb - r @ ca


def test_rigid_head_turn_moves_bald_gaussians_rigidly(avatar):
    from avatarkit.rotations import matrix_to_quat, quat_multiply

    clip = _turn(4, 50.0)
    static, frames = bake(avatar, clip, BakeConfig(sim=SimConfig(static=True)))
    frames = list(frames)
    rest, last = frames[0].face, frames[-1].face
    r, t = _kabsch(rest.means.astype(np.float64), last.means.astype(np.float64))
    moved = rest.means @ r.T + t
    assert np.abs(moved - last.means).max() < 2e-6
    angle = np.degrees(np.arccos((np.trace(r) - 1) / 2))
    assert angle == pytest.approx(50.0, abs=1e-3)
    q = quat_multiply(matrix_to_quat(r)[None], rest.quats.astype(np.float64))
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", q, last.quats)), 1, atol=1e-5)
    np.testing.assert_allclose(last.scales, rest.scales, rtol=1e-5)
    # in static mode the whole cage (and so the hair) turns with the head joint
    rc, tc = _kabsch(frames[0].cage_vertices.astype(np.float64), frames[-1].cage_vertices.astype(np.float64))
    assert np.abs(frames[0].cage_vertices @ rc.T + tc - frames[-1].cage_vertices).max() < 1e-5
    np.testing.assert_allclose(rc, r, atol=1e-5)
    assert np.abs(frames[0].hair.means @ r.T + t - frames[-1].hair.means).max() < 1e-4


def test_hair_roots_follow_the_scalp(avatar, baked):
    _, frames = baked
    model = avatar.rig.model
    for f in frames:
        want = model.root_targets(f.head_vertices)
        np.testing.assert_allclose(f.cage_vertices[model.roots], want, atol=1e-6)
    moved = np.abs(frames[-1].cage_vertices - frames[0].cage_vertices).max()
    assert moved > 1e-3  # the shake moves the cage


def test_frames_are_produced_lazily_and_memory_stays_bounded(avatar):
    clip = make_clip("nod", frames=96, fps=25, expr_dims=0)
    static, frames = bake(avatar, clip, BakeConfig(sim=FAST, preroll=0.0))
    assert frames.produced == 0 and len(frames) == 96
    first = next(frames)
    assert first.index == 0 and frames.produced == 1
    next(frames)  # compile and warm up before measuring

    def peak(n: int) -> int:
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        for _ in range(n):
            next(frames)
        used = tracemalloc.get_traced_memory()[1] - base
        tracemalloc.stop()
        return used

    # both windows start new chunks of frames (HAIR_BATCH = 16: posed, simulated and deformed
    # together) at least twice (Taichi's per-call caches settle after the first few): the short
    # one frames 2..37, the long one 38..93
    short, long = peak(36), peak(56)
    frame_bytes = sum(a.nbytes for a in (first.head_vertices, first.cage_vertices, first.face.means,
                                         first.face.quats, first.face.scales, first.hair.means,
                                         first.hair.quats, first.hair.scales))
    assert long < 1.1 * short + 2 * frame_bytes, (short, long, frame_bytes)
    assert frames.produced == 94


@pytest.mark.parametrize("batch", [3, 16])
def test_batched_hair_equals_the_single_frame_reference(avatar, shake, baked, batch):
    """hair_batch > 1 (frames deformed several per product) gives the frames of the simple
    path (one product per frame), up to float32 rounding of the product; the rest is equal."""
    _, batched = baked if batch == 16 else (None, list(bake(avatar, shake, BakeConfig(
        sim=FAST, preroll=0.2, hair_batch=batch))[1]))
    _, single = bake(avatar, shake, BakeConfig(sim=FAST, preroll=0.2, hair_batch=1))
    single = list(single)
    assert BakeConfig().hair_batch == 16 and len(batched) == len(single) == shake.n_frames
    for b, s in zip(batched, single):
        assert b.index == s.index
        assert np.array_equal(b.head_vertices, s.head_vertices)
        assert np.array_equal(b.cage_vertices, s.cage_vertices)
        assert np.array_equal(b.face.means, s.face.means)
        np.testing.assert_allclose(b.hair.means, s.hair.means, atol=2e-7)
        np.testing.assert_allclose(b.hair.quats, s.hair.quats, atol=2e-5)
        # 1e-4: the product in another order moves an axis length by up to 4e-5 relative
        np.testing.assert_allclose(b.hair.scales, s.hair.scales, rtol=1e-4)
    # and the single-frame path is CageDeformer.deform_arrays of the frame's cage, the centres
    # then pushed out of the posed head (by a few millimetres at most, issue 18)
    d = avatar.rig.deformer
    for s in single[::3]:
        means, quats, scales = d.deform_arrays(s.cage_vertices)
        assert np.array_equal(s.hair.quats, quats) and np.array_equal(s.hair.scales, scales)
        assert np.abs(s.hair.means - means).max() < 0.005


def test_frame_range_equals_the_same_frames_of_the_full_bake(avatar, shake, baked):
    _, full = baked
    static, part = bake(avatar, shake, BakeConfig(frames=(3, 6), sim=FAST, preroll=0.2))
    part = list(part)
    assert static.n_frames == 3 and [f.index for f in part] == [0, 1, 2]
    assert static.provenance["source_frames"] == [3, 6]
    for k, f in enumerate(part):
        g = full[3 + k]
        assert np.array_equal(f.head_vertices, g.head_vertices)
        assert np.array_equal(f.cage_vertices, g.cage_vertices)  # simulated from frame 0 too
        # the hair of a ranged bake is deformed in smaller products: equal to float32 rounding
        np.testing.assert_allclose(f.hair.means, g.hair.means, atol=2e-7)
    _, tail = bake(avatar, shake, BakeConfig(frames=(-2, None), sim=FAST))
    assert len(tail) == 2


def test_fps_resamples_the_clip(avatar, shake):
    static, frames = bake(avatar, shake, BakeConfig(fps=50, sim=SimConfig(static=True)))
    assert static.fps == 50 and static.n_frames == 2 * (shake.n_frames - 1) + 1
    frames = list(frames)
    assert frames[-1].time == pytest.approx((shake.n_frames - 1) / shake.fps)
    _, orig = bake(avatar, shake, BakeConfig(sim=SimConfig(static=True)))
    orig = list(orig)
    np.testing.assert_allclose(frames[4].head_vertices, orig[2].head_vertices, atol=1e-6)


def test_clip_checks(avatar, shake):
    with pytest.raises(InputError, match="millimetres"):
        check_clip(shake.replace(translation=shake.translation + np.float32(120.0)))
    with pytest.raises(InputError, match="degrees"):
        check_clip(shake.replace(rotation=shake.rotation + np.float32(30.0)))
    with pytest.raises(InputError, match="empty"):
        bake(avatar, shake, BakeConfig(frames=(20, 30)))
    n = avatar.head_model.num_expr
    wide = shake.replace(expr=np.zeros((shake.n_frames, n + 50), np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clip, _, _ = prepare_clip(wide, avatar.head_model, BakeConfig())  # zeros only: quiet
    assert clip.expr_dims == n
    expr = np.zeros((shake.n_frames, n + 50), np.float32)
    expr[:, n + 3] = 0.5
    with pytest.warns(ExprDimsWarning):
        clip, _, _ = prepare_clip(shake.replace(expr=expr), avatar.head_model, BakeConfig())
    assert clip.expr_dims == n


def test_config_checks():
    assert BakeConfig.parse_frames("3:9") == (3, 9)
    assert BakeConfig.parse_frames("5:") == (5, None)
    assert BakeConfig.parse_frames(":4") == (0, 4)
    assert BakeConfig.parse_frames("7") == (7, 8)
    for bad in ("a:b", "1:2:3", ""):
        with pytest.raises(InputError):
            BakeConfig.parse_frames(bad)
    with pytest.raises(InputError):
        BakeConfig(fps=0)
    with pytest.raises(InputError):
        BakeConfig(preroll=-1)
    with pytest.raises(InputError):
        BakeConfig(sim="fast")
    for bad in (0, -3, 2.5, True, "8"):
        with pytest.raises(InputError, match="hair_batch"):
            BakeConfig(hair_batch=bad)


class _Recorder:
    def __init__(self, fail_at=None, exc=RuntimeError):
        self.calls, self.fail_at, self.exc = [], fail_at, exc

    def begin(self, static):
        self.calls.append("begin")

    def write(self, frame):
        if frame.index == self.fail_at:
            raise self.exc("stop")
        self.calls.append(frame.index)

    def close(self):
        self.calls.append("close")
        return "done"

    def abort(self):
        self.calls.append("abort")


def test_run_bake_feeds_every_writer_once(avatar, shake):
    a, b = _Recorder(), _Recorder()
    seen = []
    summary = run_bake(avatar, shake, BakeConfig(sim=FAST, preroll=0), [a, b],
                       progress=lambda done, total: seen.append((done, total)))
    n = shake.n_frames
    assert a.calls == b.calls == ["begin", *range(n), "close"]
    assert summary.frames == n and summary.results == ["done", "done"]
    assert seen[-1] == (n, n) and len(seen) == n
    assert summary.fps > 0 and {"head", "bald", "simulate", "hair"} <= set(summary.timings)


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_run_bake_aborts_every_writer_on_failure(avatar, shake, exc):
    a, b = _Recorder(), _Recorder(fail_at=2, exc=exc)
    with pytest.raises(exc):
        run_bake(avatar, shake, BakeConfig(sim=FAST, preroll=0), [a, b])
    assert a.calls[-1] == "abort" and b.calls[-1] == "abort" and "close" not in a.calls


def test_a_signal_during_one_writers_abort_still_aborts_the_others(avatar, shake):
    """A batch worker may get a second signal (its driver's SIGTERM) while the first one's
    cleanup runs: every other writer is still aborted, and the error that stopped the bake is
    the one raised."""
    class _InterruptedAbort(_Recorder):
        def abort(self):
            self.calls.append("abort")
            raise KeyboardInterrupt

    a, b, c = _InterruptedAbort(), _Recorder(), _Recorder(fail_at=2, exc=RuntimeError)
    with pytest.raises(RuntimeError):
        run_bake(avatar, shake, BakeConfig(sim=FAST, preroll=0), [a, b, c])
    assert a.calls[-1] == b.calls[-1] == c.calls[-1] == "abort"


def test_preview_writer(avatar, shake, tmp_path):
    from avatarkit.export.video import read_video_frames

    out = tmp_path / "preview.gif"
    run_bake(avatar, shake, BakeConfig(frames=(0, 3), sim=SimConfig(static=True)),
             [PreviewWriter(out, size=64, orbit=True)])
    frames = read_video_frames(out)
    assert len(frames) == 3 and frames[0].shape == (64, 64, 3)
    # the head is in the picture: the centre is not background
    assert (frames[0][24:40, 24:40] < 250).any()
    broken = tmp_path / "broken.mp4"
    with pytest.raises(RuntimeError):
        run_bake(avatar, shake, BakeConfig(sim=SimConfig(static=True)),
                 [PreviewWriter(broken, size=32), _Recorder(fail_at=1)])
    assert not broken.exists() and [p.name for p in tmp_path.iterdir()] == ["preview.gif"]


# --- a hairless avatar -------------------------------------------------------------------------

def test_hairless_avatar_bakes_its_head_only(baked, shake, tmp_path):
    """No simulation; the bald Gaussians move exactly as on the same avatar with hair; the USD
    stage has no Hair or Cage prim and validates; the PLY frames hold the face only."""
    import json

    from pxr import Usd

    from avatarkit.bake_writers import make_writer
    from avatarkit.export.usd_stage import CAGE_PATH, FACE_PATH, HAIR_PATH, HEAD_PATH, validate_stage
    from avatarkit.gaussians.ply import read_ply
    from test_avatar import hairless_avatar

    bare = hairless_avatar()
    static, frames = bake(bare, shake, BakeConfig(sim=FAST, preroll=0.2, hair_batch=3))
    frames = list(frames)
    assert len(static.hair) == 0 and static.cage_faces.shape == (0, 3)
    assert len(frames) == len(baked[1]) == shake.n_frames
    for got, want in zip(frames, baked[1]):
        assert got.index == want.index and len(got.hair.means) == 0 and got.cage_vertices.shape == (0, 3)
        np.testing.assert_allclose(got.head_vertices, want.head_vertices, atol=1e-6)
        np.testing.assert_allclose(got.face.means, want.face.means, atol=1e-6)

    usd, ply, split, video = (tmp_path / "bald.usda", tmp_path / "frames", tmp_path / "split",
                              tmp_path / "bald.gif")
    writers = [make_writer("usd", usd, {"chunk_frames": 3}), make_writer("ply", ply),
               make_writer("ply", split, {"split": True}), PreviewWriter(video, size=32)]
    summary = run_bake(bare, shake, BakeConfig(sim=FAST), writers)
    assert summary.frames == shake.n_frames and summary.timings["simulate"] == 0.0
    stage = Usd.Stage.Open(str(usd))
    assert stage.GetPrimAtPath(HEAD_PATH) and stage.GetPrimAtPath(FACE_PATH)
    assert not stage.GetPrimAtPath(HAIR_PATH) and not stage.GetPrimAtPath(CAGE_PATH)
    assert validate_stage(stage) == []
    merged = read_ply(ply / "frame_00003.ply")
    assert len(merged) == len(bare.bald) and not merged.extras["part"].any()
    np.testing.assert_allclose(merged.means, frames[3].face.means, atol=1e-6)
    assert json.loads((ply / "sequence.json").read_text())["parts"].keys() == {"face"}
    assert sorted(p.name for p in split.glob("*.ply"))[0] == "face_00000.ply"
    assert not list(split.glob("hair_*")) and video.stat().st_size > 0
