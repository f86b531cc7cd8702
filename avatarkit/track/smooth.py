"""Zero-lag temporal smoothing of tracked parameters: a weighted Whittaker smoother.

For a channel x (T, D) with per-frame weights w (T,) (a frame's confidence; 0 for a frame
where no face was found) the smoothed z minimises

    sum_t w_t |z_t - x_t|^2  +  lam * sum_t |z_{t-1} - 2 z_t + z_{t+1}|^2,

i.e. (W + lam D^T D) z = W x with D the second-difference operator: a banded, symmetric
positive-definite system (bandwidth 2) solved in O(T). The smoother is symmetric in time, so
it has no lag (a filter that runs forward only, e.g. a One-Euro filter, trails fast motion);
it keeps straight lines (constant velocity) exactly; and frames with weight 0 are filled by the
curve through their neighbours (a natural cubic-spline-like interpolation), which is how
frames without a face are interpolated.

`lam` is in frames^4: the smoother's cut-off period is about 2 pi lam^(1/4) frames
(lam = 4 keeps motions faster than ~9 frames, at 30 fps 0.3 s, almost untouched).

`whittaker` is the fast banded solve; `whittaker_reference` builds the dense matrix (tests).
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solveh_banded

#: added to every weight so a run of weight-0 frames at a clip's end stays well posed
_EPS = 1e-9


def _as_2d(x: np.ndarray) -> tuple[np.ndarray, bool]:
    x = np.asarray(x, np.float64)
    return (x[:, None], True) if x.ndim == 1 else (x, False)


def whittaker(x: np.ndarray, weights: np.ndarray | None = None, lam: float = 4.0) -> np.ndarray:
    """Smooth x (T,) or (T, D) along axis 0 with weights (T,) >= 0 (default 1). Returns float64
    of x's shape. T < 3 or lam == 0 returns x where weights > 0 (nothing to smooth)."""
    x2, flat = _as_2d(x)
    T = len(x2)
    w = np.ones(T) if weights is None else np.clip(np.asarray(weights, np.float64).reshape(T), 0, None)
    if w.max(initial=0.0) <= 0:
        raise ValueError("whittaker: every weight is zero")
    if T < 3 or lam <= 0:
        out = x2.copy()
        return out[:, 0] if flat else out
    # D^T D of the (T-2, T) second difference, in upper banded form (rows: diagonals +2, +1, 0)
    ab = np.zeros((3, T))
    ab[0, 2:] = lam
    ab[1, 1:T - 1] += -2.0 * lam
    ab[1, 2:] += -2.0 * lam
    ab[2, :T - 2] += lam
    ab[2, 1:T - 1] += 4.0 * lam
    ab[2, 2:] += lam
    ab[2] += w + _EPS
    z = solveh_banded(ab, w[:, None] * x2, lower=False, check_finite=False)
    return z[:, 0] if flat else z


def whittaker_reference(x: np.ndarray, weights: np.ndarray | None = None, lam: float = 4.0) -> np.ndarray:
    """The same smoother by a dense solve: (diag(w) + lam D^T D) z = diag(w) x."""
    x2, flat = _as_2d(x)
    T = len(x2)
    w = np.ones(T) if weights is None else np.asarray(weights, np.float64).reshape(T)
    if T < 3 or lam <= 0:
        return x2[:, 0].copy() if flat else x2.copy()
    D = np.zeros((T - 2, T))
    for i in range(T - 2):
        D[i, i:i + 3] = (1.0, -2.0, 1.0)
    A = np.diag(w + _EPS) + lam * D.T @ D
    z = np.linalg.solve(A, w[:, None] * x2)
    return z[:, 0] if flat else z


def step_lag(lam: float, frames: int = 200) -> float:
    """Lag, in frames, of the smoother on a unit step: where the smoothed step crosses 0.5,
    minus where the input steps. 0 for a symmetric smoother (a check, and a figure for docs)."""
    x = (np.arange(frames) >= frames // 2).astype(np.float64)
    z = whittaker(x, lam=lam)
    i = int(np.argmax(z >= 0.5))
    # linear interpolation of the crossing between samples i-1 and i
    crossing = i - 1 + (0.5 - z[i - 1]) / (z[i] - z[i - 1])
    return float(crossing - (frames // 2 - 0.5))
