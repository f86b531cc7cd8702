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
