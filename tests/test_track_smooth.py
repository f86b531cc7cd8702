"""The tracker's zero-lag smoother: banded solve against the dense reference, exact on straight
lines, no lag on a step, gaps filled."""
import numpy as np
import pytest

from avatarkit.track.smooth import step_lag, whittaker, whittaker_reference


@pytest.mark.parametrize("T", [3, 4, 5, 17, 120])
def test_banded_solve_matches_dense_reference(T):
    rng = np.random.default_rng(T)
    x = rng.normal(size=(T, 4))
    w = rng.uniform(0, 1, T)
    w[rng.uniform(size=T) < 0.2] = 0.0
    w[0] = 1.0
    for lam in (0.5, 4.0, 100.0):
        np.testing.assert_allclose(whittaker(x, w, lam), whittaker_reference(x, w, lam), atol=1e-9)


def test_straight_lines_are_kept_exactly():
    t = np.arange(60, dtype=np.float64)
    x = np.stack([0.3 * t - 2.0, -0.01 * t], axis=1)
    np.testing.assert_allclose(whittaker(x, lam=50.0), x, atol=1e-8)


@pytest.mark.parametrize("lam", [1.0, 4.0, 40.0])
def test_no_lag_on_a_step(lam):
    assert abs(step_lag(lam)) < 1e-6


def test_a_causal_filter_would_lag():
    """The figure step_lag reports is real: an exponential moving average lags by frames."""
    x = (np.arange(200) >= 100).astype(float)
    ema = np.zeros_like(x)
    for i in range(1, 200):
        ema[i] = 0.7 * ema[i - 1] + 0.3 * x[i]
    crossing = np.argmax(ema >= 0.5)
    assert crossing - 99.5 > 1.0


def test_gaps_with_zero_weight_are_interpolated():
    t = np.arange(80, dtype=np.float64)
    x = np.sin(t / 12.0)
    w = np.ones(80)
    w[30:36] = 0.0
    noisy = x.copy()
    noisy[30:36] = 99.0           # what a frame without a face holds: ignored
    z = whittaker(noisy, w, lam=2.0)
    assert np.abs(z[30:36] - x[30:36]).max() < 0.02


def test_noise_is_reduced_and_slow_motion_kept():
    rng = np.random.default_rng(0)
    t = np.arange(300, dtype=np.float64)
    signal = 0.3 * np.sin(2 * np.pi * t / 60.0)         # a 2 s head turn at 30 fps
    noisy = signal + rng.normal(0, 0.02, len(t))
    z = whittaker(noisy, lam=4.0)
    assert np.std(z - signal) < 0.5 * np.std(noisy - signal)
    # the smoother passes a 60-frame period with < 1 % amplitude loss
    clean = whittaker(signal, lam=4.0)
    assert np.abs(clean[30:-30] - signal[30:-30]).max() < 0.01 * 0.3


def test_all_zero_weights_refused():
    with pytest.raises(ValueError):
        whittaker(np.zeros(10), np.zeros(10))


def test_refinement_changes_without_smoothing_are_the_linear_interpolation():
    from avatarkit.track.tracker import smoothed_changes

    rng = np.random.default_rng(3)
    done = np.array([2, 5, 6, 11, 17])
    changes = rng.normal(size=(5, 9))
    rows = np.arange(20)
    want = np.stack([np.interp(rows, done, changes[:, j]) for j in range(9)], 1)   # held at the ends
    np.testing.assert_allclose(smoothed_changes(done, changes, rows, 0.0), want)


def test_smoothed_refinement_changes_recover_a_bias_under_noise_better_than_interpolation():
    """The refinement's change on a frame is a slowly moving bias plus per-frame noise: the
    smoother over the refined rows (every 3rd) comes closer to the bias than interpolating them."""
    from avatarkit.track.tracker import smoothed_changes

    rng = np.random.default_rng(0)
    T = 150
    rows = np.arange(T)
    bias = np.stack([0.02 + 0.01 * np.sin(2 * np.pi * rows / T), np.full(T, -0.01)], 1)      # (T, 2)
    done = rows[::3]
    noisy = bias[done] + rng.normal(scale=0.01, size=(len(done), 2))
    linear = smoothed_changes(done, noisy, rows, 0.0)
    smooth = smoothed_changes(done, noisy, rows, 1000.0)
    inside = rows <= done[-1]
    err_lin = np.sqrt(np.mean((linear - bias)[inside] ** 2))
    err_smooth = np.sqrt(np.mean((smooth - bias)[inside] ** 2))
    assert err_smooth < 0.5 * err_lin
    # past the last refined row the change is held, as interpolation holds it
    np.testing.assert_allclose(smooth[~inside], np.repeat(smooth[inside][-1:], (~inside).sum(), 0))


def test_smoothed_refinement_keeps_a_constant_change_and_composes_rotations():
    from avatarkit.rotations import axis_angle_to_matrix, matrix_to_axis_angle
    from avatarkit.track.tracker import apply_refinement

    T = 12
    raw = {"rotation": np.tile([0.1, -0.2, 0.05], (T, 1)), "translation": np.zeros((T, 3)), "jaw": np.zeros((T, 3))}
    found = np.ones(T, bool)
    found[4] = False
    dr, dt, dj = np.array([0.0, 0.03, 0.0]), np.array([0.0, 0.0, 0.01]), np.array([0.02, 0.0, 0.0])
    refined = {r: (dr, dt, dj) for r in range(0, T, 3)}
    apply_refinement(raw, refined, found, smoothing=100.0)
    want = matrix_to_axis_angle(axis_angle_to_matrix(dr) @ axis_angle_to_matrix(np.array([0.1, -0.2, 0.05])))
    for t in np.flatnonzero(found):
        np.testing.assert_allclose(raw["rotation"][t], np.asarray(want, np.float64).reshape(3), atol=1e-6)
        np.testing.assert_allclose(raw["translation"][t], dt, atol=1e-9)
        np.testing.assert_allclose(raw["jaw"][t], dj, atol=1e-9)
    np.testing.assert_allclose(raw["jaw"][4], 0.0)      # no face: left to the clip's smoother


def test_a_named_refinement_setting_brings_its_own_spacing():
    from avatarkit.track.photometric import Settings
    from avatarkit.track.tracker import REFINE_EVERY, REFINE_SETTINGS, TrackOptions, refine_spacing

    assert refine_spacing(TrackOptions(refine="photometric")) == 1
    assert refine_spacing(TrackOptions(refine="photometric-fast")) == REFINE_EVERY["photometric-fast"] > 1
    assert refine_spacing(TrackOptions(refine="photometric-fast", refine_every=2)) == 2
    assert refine_spacing(TrackOptions(refine="photometric", refine_every=3)) == 3
    for name in REFINE_SETTINGS:       # every setting is `photometric.Settings` fields (track_video builds one)
        Settings(**REFINE_SETTINGS[name])
