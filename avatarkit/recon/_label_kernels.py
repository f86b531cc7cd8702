"""Taichi CPU kernels of `labels3d`: per-Gaussian blending weights accumulated per pixel label.

Imported lazily (after `ensure_taichi()`). The compositing is the renderer's
(`avatarkit/render/_kernels.py`, `rasterize`) step for step, built from the same functions:
the same packed records (the renderer's `pack_splats`), the same rows and 8-pixel blocks that
a splat's extents reach, the same per-pixel alpha (`lane_alpha`), 0.99 clamp and T < 1e-4
termination; so the transmittance and depth images are the renderer's bit for bit, and a
pixel's weights sum to its alpha to float32 rounding. Instead of a colour, each splat's weight
alpha T goes to `weights[splat, label[pixel]]`.
"""

import os

from avatarkit._taichi import ensure_taichi

os.environ.setdefault("TI_ENABLE_PYBUF", "0")  # see avatarkit/render/_kernels.py
ti = ensure_taichi()

from avatarkit.render._kernels import (ALPHA_MIN, BAND, LANES, NBAND, T_MIN, TILE,  # noqa: E402
                                       band_rect, lane_alpha)

f32_2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
f64_2 = ti.types.ndarray(dtype=ti.f64, ndim=2)
i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
i32_2 = ti.types.ndarray(dtype=ti.i32, ndim=2)


@ti.kernel
def accumulate(offsets: i32_1, ids: i32_1, packed: f32_2, labels: i32_2, weights: f64_2,
               out_t: f32_2, out_depth: f32_2):
    """Front-to-back compositing that adds each splat's alpha T to weights[splat, label].

    One task per band of a 16x16 tile, as in the renderer; row g of `packed` is the renderer's
    record of splat g. Consecutive drawn pixels of one splat with the same label are summed
    locally and added with one atomic per run, so a region of constant label costs one atomic
    per splat and band, not one per pixel. `weights` (N, L) float64 must start at zero;
    out_t / out_depth are the transmittance and expected depth images, as the renderer
    computes them.
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
        st_t = ti.Vector([1.0] * (BAND * TILE), ti.f32)
        st_d = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        cols = (x1 - x0 + LANES - 1) // LANES * LANES  # whole blocks, as the renderer
        remaining = cols * ti.max(y1 - y0, 0)
        row_left = ti.Vector([0] * BAND, ti.i32)
        for r in range(y1 - y0):
            row_left[r] = cols
        for k in range(offsets[t], offsets[t + 1]):
            if remaining == 0:
                break
            g = ids[k]
            mx = packed[g, 0]
            my = packed[g, 1]
            ha = packed[g, 2]
            nb = packed[g, 3]
            hc = packed[g, 4]
            op = packed[g, 5]
            z = packed[g, 8]
            run_label = -1
            run_acc = ti.cast(0.0, ti.f64)
            ra, rb, b0, b1 = band_rect(mx, my, packed[g, 6], packed[g, 7], x0, y0, x1, y1)
            for r in range(ra, rb + 1):
                if row_left[r] > 0:
                    dy = my - (ti.cast(y0 + r, ti.f32) + 0.5)
                    bdy = nb * dy
                    cdy = hc * dy * dy
                    ended = 0
                    for blk in ti.static(range(TILE // LANES)):
                        if b0 <= blk and blk <= b1:
                            dx0 = mx - (ti.cast(x0 + blk * LANES, ti.f32) + 0.5)
                            lanes = x1 - x0 - blk * LANES
                            row = ((r & (BAND - 1)) << 4) | (blk << 3)
                            wv = ti.Vector([0.0] * LANES, ti.f32)
                            for lane in ti.static(range(LANES)):
                                p = row | lane
                                alpha = lane_alpha(op, ha, bdy, cdy, dx0 - lane)
                                tr = st_t[p]
                                draw = (alpha >= ALPHA_MIN) & (tr > 0)
                                a = alpha if draw else 0.0
                                test_t = tr * (1.0 - a)
                                end = draw & (test_t < T_MIN)
                                w = 0.0 if end else a * tr
                                st_d[p] += z * w
                                st_t[p] = -tr if end else test_t
                                ended += ti.cast(end, ti.i32)
                                wv[lane] = w
                            # a run-time loop: unrolled, the label runs' branches took
                            # seconds more to compile (cold cache) for no measurable gain
                            for lane in range(ti.min(LANES, lanes)):  # not past the edge
                                if wv[lane] > 0:
                                    lab = labels[y0 + r, x0 + blk * LANES + lane]
                                    if lab != run_label:
                                        if run_label >= 0:
                                            ti.atomic_add(weights[g, run_label], run_acc)
                                        run_label = lab
                                        run_acc = 0.0
                                    run_acc += ti.cast(wv[lane], ti.f64)
                    remaining -= ended
                    row_left[r] -= ended
            if run_label >= 0:
                ti.atomic_add(weights[g, run_label], run_acc)
        for iy in range(y0, y1):
            for ix in range(x0, x1):
                p = ((iy - y0) << 4) | (ix - x0)
                tr = ti.abs(st_t[p])
                out_t[iy, ix] = tr
                acc = 1.0 - tr
                d = 0.0
                if acc > 0:
                    d = st_d[p] / acc
                out_depth[iy, ix] = d
