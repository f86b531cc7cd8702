"""Procedural clips: finite, start and end at rest, smooth, amplitude respected, deterministic."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.motion import KINDS, make_clip
from avatarkit.motion.procedural import DEFAULT_AMPLITUDE, DEFAULT_SECONDS

CHANNELS = ("rotation", "translation", "neck", "jaw", "eyes", "expr")
#: (channel, column) that carries each kind's amplitude
MAIN = {"nod": ("rotation", 0), "shake": ("rotation", 1), "tilt": ("rotation", 2),
        "turn": ("rotation", 1), "talk": ("jaw", 0), "idle": ("rotation", 1), "whip": ("rotation", 1)}


@pytest.mark.parametrize("kind", KINDS)
def test_finite_and_at_rest_at_both_ends(kind):
    c = make_clip(kind)
    assert c.n_frames == round(DEFAULT_SECONDS[kind] * 25) and c.fps == 25.0 and c.name == kind
    for key in CHANNELS:
        a = getattr(c, key)
        assert np.isfinite(a).all()
        assert not np.any(a[0]) and not np.any(a[-1]), f"{kind}: {key} not at rest at an end"
    assert c.expr_dims == 100 and len(c.shape) == 0


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("amplitude", [None, 7.0, 33.0])
def test_amplitude_is_the_peak_angle(kind, amplitude):
    c = make_clip(kind, fps=50, amplitude=amplitude)
    want = DEFAULT_AMPLITUDE[kind] if amplitude is None else amplitude
    key, col = MAIN[kind]
    peak = np.rad2deg(np.abs(getattr(c, key)[:, col]).max())
    assert peak <= want * (1 + 1e-5)
    assert peak >= want * 0.97  # sampled at 50 fps the crest may fall between frames
    # no other head joint turns further than the main motion (eyes may: idle's gaze drifts 2x)
    assert np.rad2deg(np.abs(c.pose[:, :9]).max()) <= want * (1 + 1e-5)
    assert np.rad2deg(np.abs(c.eyes).max()) <= 2 * want * (1 + 1e-5)


@pytest.mark.parametrize("kind", ["nod", "shake", "tilt", "turn", "talk", "idle"])
def test_eases_in_and_out(kind):
    c = make_clip(kind, frames=400, fps=100)
    for key in ("rotation", "jaw"):
        a = getattr(c, key).astype(np.float64)
        v = np.diff(a, axis=0) * c.fps
        peak = np.abs(v).max()
        if peak == 0:
            continue
        # velocity near both ends is a small fraction of the peak (no jump start, no dead stop)
        assert np.abs(v[:2]).max() < 0.05 * peak and np.abs(v[-2:]).max() < 0.05 * peak


def test_whip_is_fast_with_sudden_stops():
    c = make_clip("whip", fps=200)  # 3 s
    yaw = np.rad2deg(c.rotation[:, 1].astype(np.float64))
    speed = np.abs(np.diff(yaw)) * c.fps
    assert speed.max() > 300  # deg/s: 60 deg in 0.3 s ending at full speed is 400 deg/s
    # a sudden stop: near full speed, and still two frames (10 ms) later
    stops = np.flatnonzero((speed[:-2] > 250) & (speed[2:] < 1e-6))
    assert len(stops) >= 3
    assert yaw.max() == pytest.approx(60, abs=1e-4) and yaw.min() == pytest.approx(-60, abs=1e-4)


def test_talk_moves_jaw_and_expressions():
    c = make_clip("talk", expr_dims=10)
    assert np.rad2deg(c.jaw[:, 0]).max() == pytest.approx(12, rel=0.03)
    assert (c.jaw[:, 0] >= 0).all()  # the mouth opens, never closes past rest
    assert (np.abs(c.expr[:, :5]) > 1e-3).any(0).all() and not np.any(c.expr[:, 5:])
    assert make_clip("talk", expr_dims=0).expr.shape == (100, 0)


def test_deterministic_and_seeded():
    for kind in KINDS:
        a, b = make_clip(kind), make_clip(kind)
        for key in CHANNELS:
            np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    assert not np.array_equal(make_clip("talk", seed=1).jaw, make_clip("talk").jaw)
    assert not np.array_equal(make_clip("idle", seed=1).rotation, make_clip("idle").rotation)


def test_frames_and_fps_options():
    c = make_clip("nod", frames=31, fps=30)
    assert c.n_frames == 31 and c.duration == pytest.approx(31 / 30)
    assert make_clip("shake", frames=2).n_frames == 2


@pytest.mark.parametrize("kwargs, match", [
    ({"kind": "dance"}, "unknown motion kind 'dance'"),
    ({"kind": "nod", "frames": 1}, "frames must be an integer >= 2"),
    ({"kind": "nod", "frames": 2.5}, "frames must be an integer >= 2"),
    ({"kind": "nod", "amplitude": 200}, "between 0 and 180"),
    ({"kind": "nod", "amplitude": float("nan")}, "between 0 and 180"),
    ({"kind": "nod", "fps": 0}, "fps must be a positive number"),
    ({"kind": "nod", "expr_dims": -1}, "expr_dims"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(InputError, match=match):
        make_clip(**kwargs)


@pytest.mark.parametrize("kind", ["nod", "shake", "tilt", "turn", "talk", "idle", "whip"])
@pytest.mark.parametrize("frames", [2, 3])
def test_very_short_clips_are_finite(kind, frames):
    clip = make_clip(kind, frames=frames)
    for name in ("rotation", "translation", "neck", "jaw", "eyes", "expr"):
        assert np.isfinite(getattr(clip, name)).all(), (kind, frames, name)
