"""The subject's jaw corrective: the head model carrying it (zero at rest, still far from the mouth,
a FLAME model's own posedirs kept), the tracker's landmark models seeing it, the avatar folder
keeping it, the video build's fit recovering a known one from projected landmarks, and the fit's
guard keeping only the slopes the frames support."""
from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from avatarkit.errors import FormatError
from avatarkit.face.fit import LandmarkModel, LandmarkTargets
from avatarkit.head.jaw_corrective import (JawCorrective, apply_jaw_corrective, jaw_features, load_npz,
                                           opening_feature, save_npz)
from avatarkit.head.model import HeadParams, load_template
from avatarkit.track.jaw_corrective import fit_corrective, landmark_slopes, slope_threshold, supported_slopes
from avatarkit.track.solve import FrameProblem, _rodrigues
from avatarkit.track.tracker import model_embedding


@functools.cache
def _template():
    return load_template()


def _mouth_field(model, drop: float = 0.04) -> JawCorrective:
    """A smooth known corrective: the jaw-carried vertices near the lips drop `drop` metres
    per unit of opening, fading with distance from the lips' centre over 1.2 cm (the chin and
    jaw line stay: they tell the fit how far the jaw opened)."""
    v = model.v_template.astype(np.float64)
    centre = v[model.regions["lips"]].mean(0)
    d = np.linalg.norm(v - centre, axis=1)
    idx = np.flatnonzero((d < 0.02) & (model.weights[:, 2] > 0.5))
    fall = np.exp(-(d[idx] / 0.012) ** 2)
    field = np.zeros((len(idx), 3))
    field[:, 1] = -drop * fall
    return JawCorrective.from_opening(idx, field)


def _pose(model, jaw, rotation=None):
    T = len(jaw)
    return model.forward(HeadParams(jaw=np.asarray(jaw, np.float32),
                                    rotation=None if rotation is None else np.asarray(rotation, np.float32),
                                    expr=np.zeros((T, model.num_expr), np.float32)))[0]


def test_opening_feature_is_the_x_sine():
    jaw = np.array([[0.2, 0.0, 0.0], [0.0, 0.3, 0.0], [0.1, 0.05, -0.04], [0.0, 0.0, 0.0]])
    s = opening_feature(jaw)
    theta = np.linalg.norm(jaw, axis=1)
    axis_x = np.where(theta > 0, jaw[:, 0] / np.maximum(theta, 1e-12), 0.0)
    np.testing.assert_allclose(s, np.sin(theta) * axis_x, atol=1e-12)
    assert jaw_features(jaw).shape == (4, 9) and not jaw_features(jaw[3:]).any()


def test_zero_at_rest_and_still_far_from_the_mouth():
    model = _template()
    corr = _mouth_field(model)
    moved = apply_jaw_corrective(model, corr)
    assert model.posedirs is None and model.jaw_corrective is None      # the template is untouched
    jaw = np.array([[0.0, 0, 0], [0.25, 0, 0], [0.15, 0.05, 0.0]])
    a, b = _pose(model, jaw), _pose(moved, jaw)
    np.testing.assert_array_equal(a[0], b[0])                          # nothing at jaw 0
    still = np.setdiff1d(np.arange(model.num_vertices), corr.vertex_index)
    np.testing.assert_allclose(a[1:, still], b[1:, still], atol=1e-6)  # nothing off the field
    # on the field: the known drop, turned by the jaw (skinning after the corrective)
    s = opening_feature(jaw[1:2])[0]
    assert np.abs(b[1, corr.vertex_index] - a[1, corr.vertex_index]).max() > 0.5 * 0.04 * s
    assert np.all((b[1, corr.vertex_index, 1] - a[1, corr.vertex_index, 1]) <= 1e-6)  # down, never up


def test_flame_layout_keeps_its_own_posedirs():
    model = apply_jaw_corrective(_template(), None)     # a copy
    rng = np.random.default_rng(0)
    own = (rng.normal(size=(36, model.num_vertices * 3)) * 1e-4).astype(np.float32)
    model.posedirs = own.copy()
    corr = _mouth_field(model)
    a = apply_jaw_corrective(model, corr)
    expect = own.copy()
    expect[9:18] += corr.dense(model.num_vertices)
    np.testing.assert_allclose(a.posedirs, expect, atol=1e-7)
    # a second corrective replaces the first; None takes it off again
    b = apply_jaw_corrective(a, JawCorrective.from_opening(corr.vertex_index, 2 * corr.opening_field))
    expect2 = own.copy()
    expect2[9:18] += 2 * corr.dense(model.num_vertices)
    np.testing.assert_allclose(b.posedirs, expect2, atol=1e-7)
    np.testing.assert_allclose(apply_jaw_corrective(b, None).posedirs, own, atol=1e-7)
    assert apply_jaw_corrective(apply_jaw_corrective(_template(), corr), None).posedirs is None


def test_landmark_models_see_the_corrective():
    """The tracker's reduced problem and the torch landmark model pose the corrected mouth as
    the head model's own forward pass does."""
    model = apply_jaw_corrective(_template(), _mouth_field(_template()))
    emb = model_embedding(model).with_offset(None)     # its offsets do not ride emb.points' jaw
    lm = LandmarkModel(model, emb)
    problem = FrameProblem.from_landmark_model(lm, np.zeros(model.num_shape), 0)
    jaw = np.array([0.22, 0.03, -0.02])
    verts = _pose(model, jaw[None])[0].astype(np.float64)
    truth = emb.points(verts, model.faces)
    np.testing.assert_allclose(problem.points(np.zeros((1, 0)), jaw[None])[0], truth, atol=2e-6)
    np.testing.assert_allclose(lm.points_numpy(None, None, jaw), truth, atol=2e-6)
    plain = LandmarkModel(_template(), emb)
    assert plain.jaw_pose is None and np.abs(plain.points_numpy(None, None, jaw) - truth).max() > 1e-3


def _frames(model, emb, n: int, seed: int, focal: float = 600.0, size=(480, 480)):
    """Targets of `model`'s landmarks seen at n poses and jaw openings (0..0.3 rad)."""
    rng = np.random.default_rng(seed)
    lm = LandmarkModel(model, emb)
    problem = FrameProblem.from_landmark_model(lm, np.zeros(model.num_shape), 0)
    out = []
    for i in range(n):
        jaw = np.array([0.3 * (i % 10) / 9, rng.normal(0, 0.01), 0.0])
        rot = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.35, 0.35), rng.uniform(-0.05, 0.05)])
        trans = np.array([rng.normal(0, 0.01), rng.normal(0, 0.01), -0.5])
        pts = problem.points(np.zeros((1, 0)), jaw[None])[0]
        cam = pts @ _rodrigues(rot[None])[0].T + trans
        cam[:, 1:] *= -1.0
        xy = np.stack([focal * cam[:, 0] / cam[:, 2] + size[0] / 2, focal * cam[:, 1] / cam[:, 2] + size[1] / 2], 1)
        z = focal * cam[:, 2] / cam[:, 2].mean()
        out.append(LandmarkTargets(xy, z, np.ones(len(xy)), np.zeros((len(xy), 2)), 60.0, size))
    return out, focal


def _mouth_motion(model, corrective, emb, rows_of=None, jaw: float = 0.25) -> np.ndarray:
    """(K, 3) what the corrective adds to the landmarks at an opening of `jaw` radians."""
    with_c = apply_jaw_corrective(model, corrective) if corrective is not None else model
    a = LandmarkModel(with_c, emb).points_numpy(None, None, np.array([jaw, 0.0, 0.0]))
    b = LandmarkModel(model, emb).points_numpy(None, None, np.array([jaw, 0.0, 0.0]))
    return a - b


def test_fit_recovers_a_known_corrective():
    model = _template()
    truth = _mouth_field(model)
    emb = model_embedding(model)
    targets, focal = _frames(apply_jaw_corrective(model, truth), emb, 40, seed=1)
    fit = fit_corrective(model, np.zeros(model.num_shape), emb, targets, focal)
    assert fit.corrective is not None
    want = _mouth_motion(model, truth, emb)
    got = _mouth_motion(model, fit.corrective, emb)
    moving = np.linalg.norm(want, axis=1) > 1e-3                      # the landmarks the truth moves
    assert moving.sum() >= 5
    err = np.linalg.norm(got - want, axis=1)
    # the lower lip's landmarks move as the truth moves them (~6-10 mm) to within 25 %
    assert err[moving].max() < 0.25 * np.linalg.norm(want, axis=1).max()
    assert err.mean() < 1e-3
    rounds = fit.figures["rounds"]
    assert rounds[-1]["mouth_rms_px"] < 0.5 * rounds[0]["mouth_rms_px"]


def test_fit_learns_nothing_from_a_mouth_the_model_has():
    model = _template()
    emb = model_embedding(model)
    targets, focal = _frames(model, emb, 30, seed=2)
    fit = fit_corrective(model, np.zeros(model.num_shape), emb, targets, focal, rounds=1)
    assert fit.corrective is not None and fit.corrective.max_displacement(0.3) < 5e-4
    few = fit_corrective(model, np.zeros(model.num_shape), emb, targets[:5], focal)
    assert few.corrective is None and "fewer" in few.figures["skipped"]


def _ar1(rng, shape, rho: float, std: float) -> np.ndarray:
    """(T, ...) a stationary AR(1) series along the first axis: errors correlated in time, as
    the face mesh's readings of neighbouring frames are."""
    e = rng.normal(0.0, std * np.sqrt(1 - rho ** 2), shape)
    e[0] = rng.normal(0.0, std, shape[1:])
    for t in range(1, shape[0]):
        e[t] += rho * e[t - 1]
    return e


def _slope_data(slope_m: float, seed: int, T: int = 128, K: int = 120):
    """K landmarks' residuals (T, K, 3) = slope_m x the opening along -y + errors correlated in
    time (1 mm, AR(1) 0.9: the shared clips' residuals stay correlated over ~12 frames), seen
    from the front; the opening a smooth series (AR(1) 0.95, 0.03 rms) like a talking jaw's."""
    rng = np.random.default_rng(seed)
    s = 0.04 + _ar1(rng, (T,), 0.95, 0.03)
    res = _ar1(rng, (T, K, 3), 0.9, 1e-3)
    res[:, :, 1] -= slope_m * s[:, None]
    res[:, :, 2] = 0.0
    planes = np.broadcast_to(np.diag([1.0, 1.0, 0.0]), (T, 3, 3)).copy()
    jaw = np.stack([np.arcsin(s), np.zeros(T), np.zeros(T)], 1)
    return res, planes, s, jaw, np.zeros(K)


def test_slope_guard_drops_slopes_fitted_to_correlated_errors():
    res, planes, s, jaw, jw = _slope_data(0.0, seed=3)
    blocks = np.arange(len(s)) // 16
    plain, _, _ = supported_slopes(res, planes, s, jaw, jw)
    tested, stat, threshold = supported_slopes(res, planes, s, jaw, jw, blocks=blocks)
    # untested, errors that drift with the opening read as slopes of several mm at 0.3 rad ...
    assert np.percentile(np.linalg.norm(plain, axis=1), 90) * 0.3 > 1e-3
    # ... the test keeps about its level's share of them (0.99: ~1 %; a few % allowed)
    assert np.isfinite(threshold) and (stat > threshold).mean() <= 0.05
    assert np.abs(tested[stat <= threshold]).max() == 0.0


def test_slope_guard_keeps_a_slope_the_frames_show():
    # 9 mm at the opening's rms, 27 mm at 0.3 rad (the grey clip's: ~25 mm), over errors of 1 mm
    # correlated over ~10 frames (8 blocks of 16 frames: the test has little power; at a third of
    # this slope it keeps about half the landmarks)
    res, planes, s, jaw, jw = _slope_data(0.3, seed=5)
    plain, _, _ = supported_slopes(res, planes, s, jaw, jw)
    tested, stat, threshold = supported_slopes(res, planes, s, jaw, jw, blocks=np.arange(len(s)) // 16)
    kept = stat > threshold
    assert kept.mean() >= 0.9
    # a kept slope is the plain fit's (the ridge's shrinkage included), downward
    np.testing.assert_array_equal(tested[kept], plain[kept])
    assert (tested[kept, 1] < -0.1).all()
    assert np.abs(tested[~kept]).max(initial=0.0) == 0.0


def test_slope_statistic_matches_refitting_without_each_block():
    """The fast path (each block's sums taken off the whole's normal equations) against the slow
    obvious one: the slopes refitted on the frames outside each block."""
    from avatarkit.track.jaw_corrective import slope_statistic

    res, planes, s, jaw, jw = _slope_data(0.1, seed=6, T=70, K=4)
    blocks = np.arange(len(s)) // 16                                       # 5 blocks, the last short
    slopes, stat, threshold = supported_slopes(res, planes, s, jaw, jw, blocks=blocks, level=0.0)
    plain = landmark_slopes(res, planes, s, jaw, jw)
    held = np.stack([landmark_slopes(res[blocks != b], planes[blocks != b], s[blocks != b], jaw[blocks != b], jw)
                     for b in range(5)])                                 # (B, K, 3)
    np.testing.assert_allclose(slopes, plain, rtol=1e-9, atol=1e-12)     # level 0: all kept
    want = [slope_statistic(plain[k], held[:, k]) for k in range(4)]
    np.testing.assert_allclose(stat, want, rtol=1e-6)


def test_slope_threshold_is_the_f_test():
    from scipy.stats import f

    assert slope_threshold(4) == np.inf
    assert slope_threshold(8, 0.99) == pytest.approx(3 * 7 / 5 * f.ppf(0.99, 3, 5))
    assert slope_threshold(8) > slope_threshold(16) > 3 * f.ppf(0.99, 3, 10 ** 6) * 0.99


def test_npz_round_trip_and_broken_file(tmp_path):
    corr = _mouth_field(_template())
    save_npz(corr, tmp_path / "c.npz")
    back = load_npz(tmp_path / "c.npz")
    np.testing.assert_array_equal(back.vertex_index, corr.vertex_index)
    np.testing.assert_array_equal(back.dirs, corr.dirs)
    np.savez(tmp_path / "bad.npz", vertex_index=corr.vertex_index, dirs=corr.dirs[:, :3], meta=np.array(
        json.dumps({"format": "avatarkit.jaw_corrective/1"})))
    with pytest.raises(FormatError, match="shape"):
        load_npz(tmp_path / "bad.npz")


def test_avatar_keeps_its_corrective(tmp_path):
    from avatarkit.avatar import (JAW_CORRECTIVE_FILE, MANIFEST, Avatar, inspect_avatar, load_avatar,
                                  load_avatar_head)
    from tests.test_avatar import hairless_avatar

    shared = hairless_avatar()                          # cached: not to be changed
    corr = _mouth_field(shared.head_model)
    bare = Avatar(apply_jaw_corrective(shared.head_model, corr), shared.bald, shared.hair, None, None,
                  shared.shape, name="bald_sample")
    out = bare.save(tmp_path / "a", preview=False)
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["head_model"]["jaw_corrective"]["file"] == JAW_CORRECTIVE_FILE
    loaded = load_avatar(out)
    np.testing.assert_array_equal(loaded.head_model.posedirs, bare.head_model.posedirs)
    assert "jaw corrective" in dict(inspect_avatar(out).rows)
    head, _, _, _ = load_avatar_head(out)
    np.testing.assert_array_equal(head.jaw_corrective.dirs, corr.dirs)
    jaw = np.array([[0.2, 0.0, 0.0]])
    np.testing.assert_array_equal(_pose(loaded.head_model, jaw), _pose(bare.head_model, jaw))
    np.testing.assert_array_equal(loaded.rest_head_vertices, bare.rest_head_vertices)
    # a re-save keeps it; a changed file is refused; an old folder (none) loads without one
    loaded.save(tmp_path / "b", preview=False)
    assert load_avatar(tmp_path / "b").head_model.jaw_corrective is not None
    (out / JAW_CORRECTIVE_FILE).write_bytes((out / JAW_CORRECTIVE_FILE).read_bytes() + b"x")
    with pytest.raises(FormatError, match="SHA-256"):
        load_avatar(out)
    plain = hairless_avatar().save(tmp_path / "c", preview=False)
    assert "jaw_corrective" not in json.loads((plain / MANIFEST).read_text())["head_model"]
    assert load_avatar(plain).head_model.jaw_corrective is None


@pytest.mark.slow
def test_a_talking_template_learns_no_corrective(tmp_path, monkeypatch):
    """Known answer: the template rendered talking (the jaw 0..0.25 rad at ~1.3 Hz, a gentle turn)
    opens its mouth as the model does, so what the face mesh's reading teaches is zero. Without
    the guard the fit learned 21 mm at 0.3 rad from it; with it 4.3 mm (session 12)."""
    import avatarkit.track.jaw_corrective as jc
    from avatarkit.export.video import write_video
    from avatarkit.motion.clip import MotionClip
    from avatarkit.recon.pipeline import BuildOptions
    from avatarkit.synthetic.head_video import HeadVideo, head_video_camera
    from avatarkit.synthetic.shading import LIGHT
    from avatarkit.track.video_build import build_tracking

    T = 96
    t = np.arange(T) / 24.0
    jaw = np.zeros((T, 3))
    jaw[:, 0] = 0.125 * (1 - np.cos(2 * np.pi * 1.3 * t)) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.31 * t))
    rot = np.stack([0.06 * np.sin(2 * np.pi * 0.23 * t), 0.25 * np.sin(2 * np.pi * 0.17 * t), np.zeros(T)], 1)
    clip = MotionClip(fps=24, rotation=rot, translation=np.zeros((T, 3)), neck=np.zeros((T, 3)),
                      jaw=jaw, eyes=np.zeros((T, 6)), expr=np.zeros((T, 9)))
    hv = HeadVideo(clip, head_video_camera(256, distance=0.45), n_gaussians=20000, light=LIGHT, mouth=True)
    path = tmp_path / "talking.mp4"
    write_video(path, [f.rgb for f in hv.frames()], fps=24)
    result = build_tracking(path, BuildOptions())
    guarded = jc.fit_jaw_corrective(result)
    monkeypatch.setattr(jc, "SLOPE_BLOCK", None)
    plain = jc.fit_jaw_corrective(result)
    assert plain.corrective.max_displacement(0.3) > 0.01                # what the guard is for
    assert guarded.corrective is None or guarded.corrective.max_displacement(0.3) < 0.005
