"""Taichi CPU kernels of `labels3d`: per-Gaussian blending weights accumulated per pixel label.

Imported lazily (after `ensure_taichi()`). The compositing is the renderer's
(`avatarkit/render/_kernels.py`, `rasterize`) step for step: the same packed per-splat
constants, the same analytic row/span bounds of the alpha >= 1/255 ellipse, the same
forward-differenced Gaussian along a span, the same 0.99 clamp and T < 1e-4 termination; so a
pixel's weights sum to the renderer's alpha there to float32 rounding. Instead of a colour,
each splat's weight alpha T goes to `weights[splat, label[pixel]]`.
"""

import os

from avatarkit._taichi import ensure_taichi

os.environ.setdefault("TI_ENABLE_PYBUF", "0")  # see avatarkit/render/_kernels.py
ti = ensure_taichi()

f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
f32_2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
f64_2 = ti.types.ndarray(dtype=ti.f64, ndim=2)
i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
i32_2 = ti.types.ndarray(dtype=ti.i32, ndim=2)

TILE = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
SPAN_EPS = 1e-3
BAND = 8
NBAND = TILE // BAND
PACK = 16


@ti.kernel
def pack_splats(means2d: f32_2, conics: f32_2, opacities: f32_1, depths: f32_1, radii: i32_1,
                packed: f32_2):
    """(mx, my, a, b, c, opacity, qmax, det, 1/a, y half-extent, exp(-a), depth, span slack)
    per visible splat, computed exactly as the renderer's `pack_splats` does."""
    for g in range(means2d.shape[0]):
        if radii[g] > 0:
            ca = conics[g, 0]
            cb = conics[g, 1]
            cc = conics[g, 2]
            op = opacities[g]
            qmax = 2.0 * ti.log(op / ALPHA_MIN) * 1.0001 + 1e-5
            det = ca * cc - cb * cb
            packed[g, 0] = means2d[g, 0]
            packed[g, 1] = means2d[g, 1]
            packed[g, 2] = ca
            packed[g, 3] = cb
            packed[g, 4] = cc
            packed[g, 5] = op
            packed[g, 6] = qmax
            packed[g, 7] = det
            packed[g, 8] = 1.0 / ca
            packed[g, 9] = ti.sqrt(ti.max(qmax, 0.0) * ca / det) + SPAN_EPS
            packed[g, 10] = ti.exp(-ca)
            packed[g, 11] = depths[g]
            packed[g, 12] = SPAN_EPS + 1e-5 * ti.sqrt(ti.max(qmax, 0.0) * (ca + cc) / det) * 3.0


@ti.kernel
def accumulate(offsets: i32_1, ids: i32_1, packed: f32_2, labels: i32_2, weights: f64_2,
               out_t: f32_2, out_depth: f32_2):
    """Front-to-back compositing that adds each splat's alpha T to weights[splat, label].

    One task per band of 8 rows of a 16x16 tile, as in the renderer. Consecutive pixels of one
    splat with the same label are summed locally and added with one atomic per run, so a
    region of constant label costs one atomic per splat and band, not one per pixel.
    `weights` (N, L) float64 must start at zero; out_t / out_depth are the transmittance and
    expected depth images, as the renderer computes them.
    """
    height = out_t.shape[0]
    width = out_t.shape[1]
    tiles_x = (width + TILE - 1) // TILE
    ti.loop_config(block_dim=1)
    for tb in range((offsets.shape[0] - 1) * NBAND):
        t = tb // NBAND
        x0 = (t % tiles_x) * TILE
        y0 = (t // tiles_x) * TILE + (tb % NBAND) * BAND
        x1 = ti.min(x0 + TILE, width)
        y1 = ti.min(y0 + BAND, height)
        fx0 = ti.cast(x0, ti.f32)
        fx1 = ti.cast(x1 - 1, ti.f32)
        fy0 = ti.cast(y0, ti.f32)
        fy1 = ti.cast(y1 - 1, ti.f32)
        st_t = ti.Vector([1.0] * (BAND * TILE), ti.f32)
        st_d = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        remaining = (x1 - x0) * ti.max(y1 - y0, 0)
        row_left = ti.Vector([0] * BAND, ti.i32)
        for r in range(y1 - y0):
            row_left[r] = x1 - x0
        for k in range(offsets[t], offsets[t + 1]):
            if remaining == 0:
                break
            g = ids[k]
            mx = packed[g, 0]
            my = packed[g, 1]
            ca = packed[g, 2]
            cb = packed[g, 3]
            cc = packed[g, 4]
            op = packed[g, 5]
            qmax = packed[g, 6]
            det = packed[g, 7]
            inv_a = packed[g, 8]
            ext_y = packed[g, 9]
            step2 = packed[g, 10]
            z = packed[g, 11]
            eps = packed[g, 12]
            run_label = -1
            run_acc = ti.cast(0.0, ti.f64)
            ya = ti.max(ti.ceil(my - ext_y - 0.5), fy0)
            yb = ti.min(ti.floor(my + ext_y - 0.5), fy1)
            for iy in range(ti.cast(ya, ti.i32), ti.cast(yb, ti.i32) + 1):
                dy = my - (ti.cast(iy, ti.f32) + 0.5)
                disc = ca * qmax - dy * dy * det
                if disc >= 0 and row_left[iy - y0] > 0:
                    half = ti.sqrt(disc) * inv_a
                    cxr = mx + cb * dy * inv_a
                    xa = ti.max(ti.ceil(cxr - half - 0.5 - eps), fx0)
                    xb = ti.min(ti.floor(cxr + half - 0.5 + eps), fx1)
                    dx = mx - (xa + 0.5)
                    gval = op * ti.exp(-0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy)
                    ratio = ti.exp(ca * dx - 0.5 * ca + cb * dy)
                    base = (iy - y0) * TILE - x0
                    for ix in range(ti.cast(xa, ti.i32), ti.cast(xb, ti.i32) + 1):
                        p = base + ix
                        tr = st_t[p]
                        if tr > 0:
                            alpha = ti.min(ALPHA_MAX, gval)
                            if alpha >= ALPHA_MIN:
                                test_t = tr * (1.0 - alpha)
                                if test_t < T_MIN:
                                    st_t[p] = -tr
                                    remaining -= 1
                                    row_left[iy - y0] -= 1
                                else:
                                    w = alpha * tr
                                    lab = labels[iy, ix]
                                    if lab != run_label:
                                        if run_label >= 0:
                                            ti.atomic_add(weights[g, run_label], run_acc)
                                        run_label = lab
                                        run_acc = 0.0
                                    run_acc += ti.cast(w, ti.f64)
                                    st_d[p] += z * w
                                    st_t[p] = test_t
                        gval *= ratio
                        ratio *= step2
            if run_label >= 0:
                ti.atomic_add(weights[g, run_label], run_acc)
        for iy in range(y0, y1):
            for ix in range(x0, x1):
                p = (iy - y0) * TILE + ix - x0
                tr = ti.abs(st_t[p])
                out_t[iy, ix] = tr
                acc = 1.0 - tr
                d = 0.0
                if acc > 0:
                    d = st_d[p] / acc
                out_depth[iy, ix] = d
