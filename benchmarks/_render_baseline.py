"""The previous compositor (sessions 4-5), kept as the same-process baseline of
`benchmarks/render.py`: the renderer's first three stages, then this packing, a gather of the
records into list order, and the compositor that walked each row's analytic span with a
forward-differenced Gaussian (two `exp` per row, scalar pixel updates). Benchmark-only: nothing
in the library or the tests uses it.

`render_previous(gaussians, camera)` -> (rgb, alpha, depth), the same images as `render` to
float32 rounding (checked by the benchmark).
"""
import numpy as np

from avatarkit._taichi import ensure_taichi
from avatarkit.render.pipeline import bin_gaussians, project_gaussians, sh_colors

ti = ensure_taichi()

f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
f32_2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
f32_3 = ti.types.ndarray(dtype=ti.f32, ndim=3)
i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)

TILE = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4

SPAN_EPS = 1e-3  # pixels of slack on every analytic span bound (float rounding)
# A task composites one band of BAND rows of a 16x16 tile, its pixels' state in local arrays.
# 8 rows: compiling 256-pixel local arrays took ~1 s longer (cold cache) for ~3% less run time.
BAND = 8
NBAND = TILE // BAND
PACK = 16  # floats per packed splat: 64 bytes, about one cache line


@ti.kernel
def pack_splats(means2d: f32_2, conics: f32_2, opacities: f32_1, colors: f32_2, depths: f32_1,
                radii: i32_1, packed: f32_2):
    """Everything the compositor reads about a splat, in one cache line, with the per-splat
    constants of the span bounds precomputed: (mx, my, a, b, c, opacity, qmax, det, 1/a,
    y half-extent, exp(-a), depth, r, g, b, span slack)."""
    for g in range(means2d.shape[0]):
        if radii[g] > 0:
            ca = conics[g, 0]
            cb = conics[g, 1]
            cc = conics[g, 2]
            op = opacities[g]
            # alpha >= 1/255  <=>  q = a dx^2 + 2 b dx dy + c dy^2 <= qmax = 2 ln(255 opacity);
            # the small relative slack keeps float rounding of the bounds on the safe side
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
            packed[g, 12] = colors[g, 0]
            packed[g, 13] = colors[g, 1]
            packed[g, 14] = colors[g, 2]
            # float rounding of a span end is ~1e-7 of the span's coordinates: a pixel's slack
            # is SPAN_EPS plus a margin for the widest span of this splat
            packed[g, 15] = SPAN_EPS + 1e-5 * ti.sqrt(ti.max(qmax, 0.0) * (ca + cc) / det) * 3.0


@ti.kernel
def gather_pairs(ids: i32_1, packed: f32_2, pairs: f32_2):
    """pairs[k] = packed[ids[k]]: the compositor then streams through memory in list order
    instead of jumping to a random splat per list entry (~20% of its time at 100k)."""
    for k in range(ids.shape[0]):
        g = ids[k]
        for j in ti.static(range(PACK)):
            pairs[k, j] = packed[g, j]


@ti.kernel
def rasterize_previous(offsets: i32_1, pairs: f32_2, bg_r: ti.f32, bg_g: ti.f32,
              bg_b: ti.f32, out_rgb: f32_3, out_t: f32_2, out_depth: f32_2):
    """Front-to-back alpha compositing. One task per band of 8 rows of a 16x16 tile (tasks
    spread over the cores) walks the tile's depth-sorted list, its pixels' state in local arrays.

    Per splat only the rows, and in each row only the span, where alpha >= 1/255 are visited:
    the ellipse q <= qmax gives both bounds analytically. Along a span the Gaussian is stepped
    by forward differences (exp of a quadratic: two multiplies per pixel instead of an exp);
    the alpha test, clamping and termination are the INRIA ones. A pixel that terminates keeps
    its transmittance stored negated; rows whose pixels have all terminated are skipped, and the
    band stops when all its pixels have. (INRIA also skips power > 0, which a positive-definite
    conic never gives; the forward-differenced Gaussian needs no such test.)
    """
    height = out_rgb.shape[0]
    width = out_rgb.shape[1]
    tiles_x = (width + TILE - 1) // TILE
    ti.loop_config(block_dim=1)  # bands cost very different amounts: hand them out one by one
    for tb in range((offsets.shape[0] - 1) * NBAND):
        t = tb // NBAND
        x0 = (t % tiles_x) * TILE
        y0 = (t // tiles_x) * TILE + (tb % NBAND) * BAND
        x1 = ti.min(x0 + TILE, width)
        y1 = ti.min(y0 + BAND, height)  # y1 <= y0 for a band below the image: nothing to do
        fx0 = ti.cast(x0, ti.f32)
        fx1 = ti.cast(x1 - 1, ti.f32)
        fy0 = ti.cast(y0, ti.f32)
        fy1 = ti.cast(y1 - 1, ti.f32)
        st_t = ti.Vector([1.0] * (BAND * TILE), ti.f32)
        st_r = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        st_g = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        st_b = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        st_d = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        remaining = (x1 - x0) * ti.max(y1 - y0, 0)
        row_left = ti.Vector([0] * BAND, ti.i32)  # unfinished pixels per row of the band
        for r in range(y1 - y0):
            row_left[r] = x1 - x0
        for k in range(offsets[t], offsets[t + 1]):
            if remaining == 0:
                break
            mx = pairs[k, 0]
            my = pairs[k, 1]
            ca = pairs[k, 2]
            cb = pairs[k, 3]
            cc = pairs[k, 4]
            op = pairs[k, 5]
            qmax = pairs[k, 6]
            det = pairs[k, 7]
            inv_a = pairs[k, 8]
            ext_y = pairs[k, 9]
            step2 = pairs[k, 10]
            z = pairs[k, 11]
            cr = pairs[k, 12]
            cg = pairs[k, 13]
            cbl = pairs[k, 14]
            eps = pairs[k, 15]
            # rows whose pixel centre iy + 0.5 lies within the ellipse's vertical extent
            ya = ti.max(ti.ceil(my - ext_y - 0.5), fy0)
            yb = ti.min(ti.floor(my + ext_y - 0.5), fy1)
            for iy in range(ti.cast(ya, ti.i32), ti.cast(yb, ti.i32) + 1):
                dy = my - (ti.cast(iy, ti.f32) + 0.5)
                disc = ca * qmax - dy * dy * det
                if disc >= 0 and row_left[iy - y0] > 0:
                    # q(dx) <= qmax for dx in cxr - mx -+ half  (d = mean - pixel centre)
                    half = ti.sqrt(disc) * inv_a
                    cxr = mx + cb * dy * inv_a
                    xa = ti.max(ti.ceil(cxr - half - 0.5 - eps), fx0)
                    xb = ti.min(ti.floor(cxr + half - 0.5 + eps), fx1)
                    # gval = opacity exp(power) at the span start; power's step to the next
                    # pixel is a dx - a/2 + b dy, which itself changes by -a per pixel
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
                                    st_r[p] += cr * w
                                    st_g[p] += cg * w
                                    st_b[p] += cbl * w
                                    st_d[p] += z * w
                                    st_t[p] = test_t
                        gval *= ratio
                        ratio *= step2
        for iy in range(y0, y1):
            for ix in range(x0, x1):
                p = (iy - y0) * TILE + ix - x0
                tr = ti.abs(st_t[p])
                out_t[iy, ix] = tr
                out_rgb[iy, ix, 0] = st_r[p] + tr * bg_r
                out_rgb[iy, ix, 1] = st_g[p] + tr * bg_g
                out_rgb[iy, ix, 2] = st_b[p] + tr * bg_b
                acc = 1.0 - tr
                d = 0.0
                if acc > 0:
                    d = st_d[p] / acc
                out_depth[iy, ix] = d


def render_previous(gaussians, camera):
    """(rgb (H, W, 3), alpha (H, W), depth (H, W)) float32 on a black background."""
    proj = project_gaussians(gaussians, camera)
    colors = sh_colors(gaussians, camera)
    bins = bin_gaussians(proj, camera, gaussians.opacities)
    h, w = camera.height, camera.width
    rgb = np.zeros((h, w, 3), np.float32)
    trans = np.ones((h, w), np.float32)
    depth = np.zeros((h, w), np.float32)
    if len(bins.gaussian_ids):
        packed = np.empty((len(proj.radii), PACK), np.float32)
        pack_splats(proj.means2d, proj.conics, np.ascontiguousarray(gaussians.opacities, np.float32),
                    colors, proj.depths, proj.radii, packed)
        pairs = np.empty((len(bins.gaussian_ids), PACK), np.float32)
        gather_pairs(bins.gaussian_ids, packed, pairs)
        rasterize_previous(bins.tile_offsets, pairs, 0.0, 0.0, 0.0, rgb, trans, depth)
    return rgb, 1.0 - trans, depth
