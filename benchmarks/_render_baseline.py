"""Session 6's renderer (the main branch before issue 17's session 7 work), kept as the
same-process baseline of `benchmarks/render.py`: its kernels copied unchanged, and
`render_main` running its four stages as `pipeline.render` did (projection, SH, the numpy
depth argsort with the per-splat sort, count and scatter kernels, the serial `first_sight`
pass, packing, compositing). Benchmark-only: nothing in the library or the tests uses it.

`render_main(gaussians, camera)` -> (rgb, alpha, depth), the same images as `render`
(bit for bit: checked by the benchmark).
"""
import numpy as np

from avatarkit._taichi import ensure_taichi
from avatarkit.render.pipeline import depth_order, tile_grid, tile_q_limits

ti = ensure_taichi()

f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
f32_2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
f32_3 = ti.types.ndarray(dtype=ti.f32, ndim=3)
f64_2 = ti.types.ndarray(dtype=ti.f64, ndim=2)
i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
i32_2 = ti.types.ndarray(dtype=ti.i32, ndim=2)

TILE = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
DILATION = 0.3

# SH constants (3DGS `eval_sh`), repeated here because kernels cannot read Python tuples at
# run time; tests compare this kernel with `avatarkit.gaussians.sh` and a direct formula.
C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2_0, C2_1, C2_2, C2_3, C2_4 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                                -1.0925484305920792, 0.5462742152960396)
C3_0, C3_1, C3_2, C3_3, C3_4, C3_5, C3_6 = (-0.5900435899266435, 2.890611442640554,
                                            -0.4570457994644658, 0.3731763325901154,
                                            -0.4570457994644658, 1.445305721320277,
                                            -0.5900435899266435)


@ti.kernel
def project(means: f32_2, quats: f32_2, scales: f32_2, opacities: f32_1, viewmat: f64_2,
            fx: ti.f64, fy: ti.f64, cx: ti.f64, cy: ti.f64, width: ti.i32, height: ti.i32,
            near: ti.f64, means2d: f32_2, depths: f32_1, conics: f32_2, radii: i32_1,
            rects: i32_2):
    """EWA projection of every Gaussian (float64 inside, float32 out); radius 0 = culled.

    rects[i] = (tile x0, tile y0, tile x1, tile y1), half-open, clamped to the tile grid.
    """
    tiles_x = (width + TILE - 1) // TILE
    tiles_y = (height + TILE - 1) // TILE
    tan_x = 0.5 * width / fx
    tan_y = 0.5 * height / fy
    lim_xp = (width - cx) / fx + 0.3 * tan_x
    lim_xn = cx / fx + 0.3 * tan_x
    lim_yp = (height - cy) / fy + 0.3 * tan_y
    lim_yn = cy / fy + 0.3 * tan_y
    for i in range(means.shape[0]):
        radii[i] = 0
        rects[i, 0] = 0
        rects[i, 1] = 0
        rects[i, 2] = 0
        rects[i, 3] = 0
        px = ti.cast(means[i, 0], ti.f64)
        py = ti.cast(means[i, 1], ti.f64)
        pz = ti.cast(means[i, 2], ti.f64)
        x = viewmat[0, 0] * px + viewmat[0, 1] * py + viewmat[0, 2] * pz + viewmat[0, 3]
        y = viewmat[1, 0] * px + viewmat[1, 1] * py + viewmat[1, 2] * pz + viewmat[1, 3]
        z = viewmat[2, 0] * px + viewmat[2, 1] * py + viewmat[2, 2] * pz + viewmat[2, 3]
        depths[i] = ti.cast(z, ti.f32)
        if z > near and opacities[i] >= ALPHA_MIN:
            # world covariance R S S^T R^T from the unit quaternion (w, x, y, z)
            qw = ti.cast(quats[i, 0], ti.f64)
            qx = ti.cast(quats[i, 1], ti.f64)
            qy = ti.cast(quats[i, 2], ti.f64)
            qz = ti.cast(quats[i, 3], ti.f64)
            qn = ti.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw / qn, qx / qn, qy / qn, qz / qn
            rot = ti.Matrix([
                [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)],
                [2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)],
                [2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)]],
                ti.f64)
            s = ti.Matrix([[ti.cast(scales[i, 0], ti.f64), 0.0, 0.0],
                           [0.0, ti.cast(scales[i, 1], ti.f64), 0.0],
                           [0.0, 0.0, ti.cast(scales[i, 2], ti.f64)]], ti.f64)
            w = ti.Matrix([[viewmat[0, 0], viewmat[0, 1], viewmat[0, 2]],
                           [viewmat[1, 0], viewmat[1, 1], viewmat[1, 2]],
                           [viewmat[2, 0], viewmat[2, 1], viewmat[2, 2]]], ti.f64)
            m = w @ rot @ s
            cov = m @ m.transpose()
            # Jacobian at the mean with x/z, y/z clamped to 1.3x the half-FOV (INRIA/gsplat)
            tx = z * ti.min(lim_xp, ti.max(-lim_xn, x / z))
            ty = z * ti.min(lim_yp, ti.max(-lim_yn, y / z))
            j = ti.Matrix([[fx / z, 0.0, -fx * tx / (z * z)],
                           [0.0, fy / z, -fy * ty / (z * z)]], ti.f64)
            c2 = j @ cov @ j.transpose()
            a = c2[0, 0] + DILATION
            b = c2[0, 1]
            c = c2[1, 1] + DILATION
            det = a * c - b * b
            if det > 0:
                mid = 0.5 * (a + c)
                lam = mid + ti.sqrt(ti.max(0.1, mid * mid - det))
                r = ti.ceil(3.0 * ti.sqrt(lam))
                u = fx * x / z + cx
                v = fy * y / z + cy
                # clamp in floating point first: far off-screen splats would overflow i32
                x0 = ti.cast(ti.min(ti.max(ti.floor((u - r) / TILE), 0.0), tiles_x), ti.i32)
                x1 = ti.cast(ti.min(ti.max(ti.ceil((u + r) / TILE), 0.0), tiles_x), ti.i32)
                y0 = ti.cast(ti.min(ti.max(ti.floor((v - r) / TILE), 0.0), tiles_y), ti.i32)
                y1 = ti.cast(ti.min(ti.max(ti.ceil((v + r) / TILE), 0.0), tiles_y), ti.i32)
                if x1 > x0 and y1 > y0:
                    radii[i] = ti.cast(r, ti.i32)
                    rects[i, 0] = x0
                    rects[i, 1] = y0
                    rects[i, 2] = x1
                    rects[i, 3] = y1
                    means2d[i, 0] = ti.cast(u, ti.f32)
                    means2d[i, 1] = ti.cast(v, ti.f32)
                    conics[i, 0] = ti.cast(c / det, ti.f32)
                    conics[i, 1] = ti.cast(-b / det, ti.f32)
                    conics[i, 2] = ti.cast(a / det, ti.f32)


@ti.kernel
def sh_colors(sh: f32_3, means: f32_2, center_x: ti.f64, center_y: ti.f64, center_z: ti.f64,
              colors: f32_2):
    """colour = max(0, sum_k basis_k(dir) sh_k + 0.5), dir = unit(mean - camera centre)."""
    k = sh.shape[1]
    for i in range(sh.shape[0]):
        dx = ti.cast(means[i, 0], ti.f64) - center_x
        dy = ti.cast(means[i, 1], ti.f64) - center_y
        dz = ti.cast(means[i, 2], ti.f64) - center_z
        n = ti.sqrt(dx * dx + dy * dy + dz * dz)
        if n > 0:
            dx, dy, dz = dx / n, dy / n, dz / n
        x = ti.cast(dx, ti.f32)
        y = ti.cast(dy, ti.f32)
        z = ti.cast(dz, ti.f32)
        for ch in range(3):
            res = C0 * sh[i, 0, ch]
            if k > 1:
                res += -C1 * y * sh[i, 1, ch] + C1 * z * sh[i, 2, ch] - C1 * x * sh[i, 3, ch]
            if k > 4:
                xx, yy, zz = x * x, y * y, z * z
                xy, yz, xz = x * y, y * z, x * z
                res += (C2_0 * xy * sh[i, 4, ch] + C2_1 * yz * sh[i, 5, ch]
                        + C2_2 * (2.0 * zz - xx - yy) * sh[i, 6, ch]
                        + C2_3 * xz * sh[i, 7, ch] + C2_4 * (xx - yy) * sh[i, 8, ch])
                if k > 9:
                    res += (C3_0 * y * (3.0 * xx - yy) * sh[i, 9, ch]
                            + C3_1 * xy * z * sh[i, 10, ch]
                            + C3_2 * y * (4.0 * zz - xx - yy) * sh[i, 11, ch]
                            + C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * sh[i, 12, ch]
                            + C3_4 * x * (4.0 * zz - xx - yy) * sh[i, 13, ch]
                            + C3_5 * z * (xx - yy) * sh[i, 14, ch]
                            + C3_6 * x * (xx - 3.0 * yy) * sh[i, 15, ch])
            colors[i, ch] = ti.max(res + 0.5, 0.0)


# Depth-ordered splats are binned in this many consecutive chunks, one task each: a tile's list
# is chunk 0's entries, then chunk 1's..., each in depth order, so the lists come out sorted and
# the same whatever the thread count, and the scatter is no longer one serial loop.
BIN_CHUNKS = 16


@ti.func
def touches_tile(mx, my, ca, cb, cc, ra, rc, qlim, px0, py0, px1, py1):
    """1 if the ellipse q(d) = a dx^2 + 2 b dx dy + c dy^2 <= qlim around (mx, my) meets the
    rectangle [px0, px1] x [py0, py1] (a tile's pixel centres), float64; ra = -b/a, rc = -b/c.
    q is convex, so its minimum over the rectangle is at the mean when inside, else on an
    edge, where it is the edge's 1D minimum (dy = rc dx on a vertical edge) clamped to it."""
    lox = px0 - mx
    hix = px1 - mx
    loy = py0 - my
    hiy = py1 - my
    hit = 0
    if lox <= 0.0 and hix >= 0.0 and loy <= 0.0 and hiy >= 0.0:
        hit = 1
    else:
        best = qlim + 1.0
        for e in ti.static(range(2)):
            dx = lox if e == 0 else hix
            dy = ti.min(ti.max(rc * dx, loy), hiy)
            best = ti.min(best, ca * dx * dx + 2.0 * cb * dx * dy + cc * dy * dy)
            dy2 = loy if e == 0 else hiy
            dx2 = ti.min(ti.max(ra * dy2, lox), hix)
            best = ti.min(best, ca * dx2 * dx2 + 2.0 * cb * dx2 * dy2 + cc * dy2 * dy2)
        if best <= qlim:
            hit = 1
    return hit


@ti.kernel
def sort_bin_data(rank: i32_1, rects: i32_2, means2d: f32_2, conics: f32_2, qlims: f32_1,
                  s_rects: i32_2, s_geo: f64_2):
    """The binning's per-splat data in depth order, so that the serial chunk loops below stream
    through memory: splat i (rank[i] >= 0) goes to row k = rank[i], s_rects[k] = rects[i],
    s_geo[k] = (mx, my, a, b, c, -b/a, -b/c, q limit). Reads in index order and scatters the
    writes (stores do not stall as random reads would)."""
    for i in range(rank.shape[0]):
        k = rank[i]
        if k >= 0:
            for j in ti.static(range(4)):
                s_rects[k, j] = rects[i, j]
            ca = ti.cast(conics[i, 0], ti.f64)
            cb = ti.cast(conics[i, 1], ti.f64)
            cc = ti.cast(conics[i, 2], ti.f64)
            s_geo[k, 0] = ti.cast(means2d[i, 0], ti.f64)
            s_geo[k, 1] = ti.cast(means2d[i, 1], ti.f64)
            s_geo[k, 2] = ca
            s_geo[k, 3] = cb
            s_geo[k, 4] = cc
            s_geo[k, 5] = -cb / ca
            s_geo[k, 6] = -cb / cc
            s_geo[k, 7] = ti.cast(qlims[i], ti.f64)


@ti.func
def splat_in_tile(s_geo: ti.template(), k, tx, ty, width, height):
    """1 if depth-ordered splat k belongs in tile (tx, ty)'s list: always when its q limit is
    negative (plain 3-sigma rects), else when its alpha >= 1/255 ellipse reaches one of the
    tile's pixel centres."""
    hit = 1
    if s_geo[k, 7] >= 0:
        hit = touches_tile(s_geo[k, 0], s_geo[k, 1], s_geo[k, 2], s_geo[k, 3], s_geo[k, 4],
                           s_geo[k, 5], s_geo[k, 6], s_geo[k, 7], tx * TILE + 0.5,
                           ty * TILE + 0.5, ti.min(tx * TILE + TILE, width) - 0.5,
                           ti.min(ty * TILE + TILE, height) - 0.5)
    return hit


MASK_TILES = 63  # rects of up to this many tiles keep count_tiles' hits as bits for the scatter
i64_1 = ti.types.ndarray(dtype=ti.i64, ndim=1)


@ti.kernel
def count_tiles(s_rects: i32_2, s_geo: f64_2, tiles_x: ti.i32, width: ti.i32, height: ti.i32,
                counts: i32_2, hits: i64_1):
    """counts[c, t] = number of splats of depth-order chunk c in tile t's list (counts start at
    0). One task per chunk, so no atomics. hits[k] = splat k's tiles as bits, row-major over
    its rect (bit (ty - y0) * width + tx - x0), or -1 for a rect of more than MASK_TILES tiles,
    so that `scatter_tiles` need not test the ellipse again."""
    m = s_rects.shape[0]
    per = (m + BIN_CHUNKS - 1) // BIN_CHUNKS
    ti.loop_config(block_dim=1)
    for c in range(BIN_CHUNKS):
        for k in range(c * per, ti.min(m, (c + 1) * per)):
            rw = s_rects[k, 2] - s_rects[k, 0]
            bits = ti.cast(0, ti.i64)
            j = 0
            for ty in range(s_rects[k, 1], s_rects[k, 3]):
                for tx in range(s_rects[k, 0], s_rects[k, 2]):
                    if splat_in_tile(s_geo, k, tx, ty, width, height):
                        t = ty * tiles_x + tx
                        counts[c, t] = counts[c, t] + 1
                        if j < MASK_TILES:
                            bits |= ti.cast(1, ti.i64) << j
                    j += 1
            hits[k] = bits if rw * (s_rects[k, 3] - s_rects[k, 1]) <= MASK_TILES else -1


@ti.kernel
def scatter_tiles(order: i32_1, s_rects: i32_2, s_geo: f64_2, tiles_x: ti.i32, width: ti.i32,
                  height: ti.i32, hits: i64_1, cursor: i32_2, ids: i32_1):
    """Walk each chunk's splats front to back and append them to their tiles' lists from
    cursor[c, t] (where chunk c's part of tile t's list starts); every list comes out
    depth-sorted without a per-tile sort. A splat's tiles are count_tiles' `hits` bits, or
    tested again where it kept none."""
    m = s_rects.shape[0]
    per = (m + BIN_CHUNKS - 1) // BIN_CHUNKS
    ti.loop_config(block_dim=1)
    for c in range(BIN_CHUNKS):
        for k in range(c * per, ti.min(m, (c + 1) * per)):
            bits = hits[k]
            j = 0
            for ty in range(s_rects[k, 1], s_rects[k, 3]):
                for tx in range(s_rects[k, 0], s_rects[k, 2]):
                    hit = 0
                    if bits >= 0:
                        hit = ti.cast((bits >> j) & 1, ti.i32)
                    else:
                        hit = splat_in_tile(s_geo, k, tx, ty, width, height)
                    if hit:
                        t = ty * tiles_x + tx
                        ids[cursor[c, t]] = order[k]
                        cursor[c, t] = cursor[c, t] + 1
                    j += 1


SPAN_EPS = 1e-3  # pixels of slack on every extent bound (float rounding)
# A task composites one band of BAND rows of a 16x16 tile, its pixels' state in local arrays.
# The whole tile: each splat's record and extents are then read once per tile, not per band
# (~10% less compositing time than 8-row bands at 100k).
BAND = 16
NBAND = TILE // BAND
LANES = 8  # a band row is two aligned blocks of 8 pixels, each composited as one SIMD vector
PACK = 12  # floats per packed splat
LOG2E = 1.4426950408889634
assert TILE == 16 and LANES == 8 and BAND in (8, 16)  # the (r << 4) | (blk << 3) | lane indexing


@ti.func
def exp_f32(x):
    """exp(x) in float32 for x <= ~0 without a libm call, so that a block's 8 exponentials
    vectorise: Cephes `expf` (x = n ln 2 + r, |r| <= ln 2 / 2, exp(r) = 1 + r + r^2 P(r) with
    its degree-5 P, times 2^n built in the exponent bits), relative error ~1e-7. P is
    evaluated by Estrin's scheme: a shorter dependency chain than Horner's (~14% less
    compositing time). x is clamped below at -87 (exp = 0 for the compositor)."""
    xc = ti.max(x, -87.0)
    n = ti.floor(xc * LOG2E + 0.5)
    r = xc - n * 0.693359375 + n * 2.12194440e-4  # ln 2 in two parts: r stays exact
    r2 = r * r
    pp = ((5.0000001201e-1 + 1.6666665459e-1 * r) + r2 * (4.1665795894e-2 + 8.3334519073e-3 * r)
          + (r2 * r2) * (1.3981999507e-3 + 1.9875691500e-4 * r))
    return ((1.0 + r) + r2 * pp) * ti.bit_cast((ti.cast(n, ti.i32) + 127) << 23, ti.f32)


@ti.func
def pack_one(packed: ti.template(), s, mx, my, ca, cb, cc, op, z, cr, cg, cbl):
    """Write splat record s: (mx, my, -a/2, -b, -c/2, opacity, x half-extent, y half-extent,
    depth, r, g, b). The half-extents bound the ellipse q = d^T conic d <= qlim, qlim the
    binning's `tile_q_limits` (alpha >= 1/255 widened by 1% + 0.05), so every pixel whose
    alpha can pass the 1/255 test lies within them: |dx| <= sqrt(qlim c / det),
    |dy| <= sqrt(qlim a / det)."""
    qlim = 2.0 * ti.log(ti.max(op, ALPHA_MIN) / ALPHA_MIN) * 1.01 + 0.05
    det = ca * cc - cb * cb
    packed[s, 0] = mx
    packed[s, 1] = my
    packed[s, 2] = -0.5 * ca
    packed[s, 3] = -cb
    packed[s, 4] = -0.5 * cc
    packed[s, 5] = op
    packed[s, 6] = ti.sqrt(qlim * cc / det) + SPAN_EPS
    packed[s, 7] = ti.sqrt(qlim * ca / det) + SPAN_EPS
    packed[s, 8] = z
    packed[s, 9] = cr
    packed[s, 10] = cg
    packed[s, 11] = cbl


@ti.kernel
def first_sight(ids: i32_1, slot: i32_1, sids: i32_1):
    """slot[g] = how many distinct splats the tile lists held before g's first entry (slot
    starts at -1 everywhere), sids[k] = slot[ids[k]]. Packing the records in this order puts
    each tile's splats close together in memory, and the next tile's mostly in cache: the
    lists' depth order over input-ordered records would be a random walk through all of
    them (~1.5x slower compositing at 100k). One serial pass (~1 ms at 100k)."""
    n = 0
    ti.loop_config(serialize=True)
    for k in range(ids.shape[0]):
        g = ids[k]
        if slot[g] < 0:
            slot[g] = n
            n += 1
        sids[k] = slot[g]


@ti.kernel
def pack_splats(slot: i32_1, means2d: f32_2, conics: f32_2, opacities: f32_1, colors: f32_2,
                depths: f32_1, packed: f32_2):
    """Everything the compositor reads about splat g, in row slot[g] of `packed` (slot -1:
    in no tile's list, not written)."""
    for g in range(slot.shape[0]):
        s = slot[g]
        if s >= 0:
            pack_one(packed, s, means2d[g, 0], means2d[g, 1], conics[g, 0], conics[g, 1],
                     conics[g, 2], opacities[g], depths[g], colors[g, 0], colors[g, 1],
                     colors[g, 2])


@ti.func
def band_rect(mx, my, ext_x, ext_y, x0, y0, x1, y1):
    """(first row, last row, first block, last block) of the band [x0, x1) x [y0, y1) that
    the splat's extents reach, relative to (x0, y0); empty ranges when it reaches nothing."""
    ya = ti.max(ti.ceil(my - ext_y - 0.5), ti.cast(y0, ti.f32))
    yb = ti.min(ti.floor(my + ext_y - 0.5), ti.cast(y1 - 1, ti.f32))
    xa = ti.max(ti.ceil(mx - ext_x - 0.5), ti.cast(x0, ti.f32))
    xb = ti.min(ti.floor(mx + ext_x - 0.5), ti.cast(x1 - 1, ti.f32))
    ra = ti.cast(ya, ti.i32) - y0
    rb = ti.cast(yb, ti.i32) - y0
    b0 = 1
    b1 = 0
    if xa <= xb:
        b0 = (ti.cast(xa, ti.i32) - x0) // LANES
        b1 = (ti.cast(xb, ti.i32) - x0) // LANES
    return ra, rb, b0, b1


@ti.func
def lane_alpha(op, ha, bdy, cdy, dx):
    """min(0.99, opacity exp(-q/2)) at a pixel dx = mean x - pixel centre x of a row whose
    terms in dy are bdy = -b dy and cdy = -c dy^2 / 2 (the INRIA alpha)."""
    return ti.min(ALPHA_MAX, op * exp_f32((ha * dx + bdy) * dx + cdy))


@ti.kernel
def rasterize(offsets: i32_1, ids: i32_1, packed: f32_2, bg_r: ti.f32, bg_g: ti.f32,
              bg_b: ti.f32, out_rgb: f32_3, out_t: f32_2, out_depth: f32_2):
    """Front-to-back alpha compositing. One task per band of BAND rows of a 16x16 tile (tasks
    spread over the cores) walks the tile's depth-sorted list (entry k is record ids[k] of
    `packed`), its pixels' state in local arrays.

    Per splat only the rows and 8-pixel blocks that its extents reach are visited, and each
    block is composited branch-free as one vector: alpha from its own exponential at every
    pixel (no forward differencing), the alpha test, clamping and termination as INRIA's, as
    selects. A pixel that terminates keeps its transmittance stored negated; rows whose pixels
    have all terminated are skipped, and the band stops when all its pixels have. (INRIA also
    skips power > 0, which a positive-definite conic never gives.)
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
        # pixel (x0 + c, y0 + r) is entry (r << 4) | c. A tile cut by the image's right edge is
        # composited and counted in whole blocks: the lanes past the edge are pixels like any
        # other (never written out), so `remaining` and `row_left` need no lane mask
        st_t = ti.Vector([1.0] * (BAND * TILE), ti.f32)
        st_r = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        st_g = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        st_b = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        st_d = ti.Vector([0.0] * (BAND * TILE), ti.f32)
        cols = (x1 - x0 + LANES - 1) // LANES * LANES
        remaining = cols * ti.max(y1 - y0, 0)
        row_left = ti.Vector([0] * BAND, ti.i32)  # unfinished pixels per row of the band
        for r in range(y1 - y0):
            row_left[r] = cols
        for k in range(offsets[t], offsets[t + 1]):
            if remaining == 0:
                break
            s = ids[k]
            mx = packed[s, 0]
            my = packed[s, 1]
            ha = packed[s, 2]
            nb = packed[s, 3]
            hc = packed[s, 4]
            op = packed[s, 5]
            z = packed[s, 8]
            cr = packed[s, 9]
            cg = packed[s, 10]
            cbl = packed[s, 11]
            ra, rb, b0, b1 = band_rect(mx, my, packed[s, 6], packed[s, 7], x0, y0, x1, y1)
            for r in range(ra, rb + 1):
                if row_left[r] > 0:
                    dy = my - (ti.cast(y0 + r, ti.f32) + 0.5)
                    bdy = nb * dy
                    cdy = hc * dy * dy
                    ended = 0
                    for blk in ti.static(range(TILE // LANES)):
                        if b0 <= blk and blk <= b1:
                            dx0 = mx - (ti.cast(x0 + blk * LANES, ti.f32) + 0.5)
                            # the masked row index tells LLVM the 8 entries are consecutive
                            row = ((r & (BAND - 1)) << 4) | (blk << 3)
                            for lane in ti.static(range(LANES)):
                                p = row | lane
                                alpha = lane_alpha(op, ha, bdy, cdy, dx0 - lane)
                                tr = st_t[p]
                                draw = (alpha >= ALPHA_MIN) & (tr > 0)
                                a = alpha if draw else 0.0
                                test_t = tr * (1.0 - a)
                                end = draw & (test_t < T_MIN)
                                w = 0.0 if end else a * tr
                                st_r[p] += cr * w
                                st_g[p] += cg * w
                                st_b[p] += cbl * w
                                st_d[p] += z * w
                                st_t[p] = -tr if end else test_t
                                ended += ti.cast(end, ti.i32)
                    remaining -= ended
                    row_left[r] -= ended
        for iy in range(y0, y1):
            for ix in range(x0, x1):
                p = ((iy - y0) << 4) | (ix - x0)
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


def render_main(gaussians, camera):
    """Session 6's `pipeline.render` (background black), returning (rgb, alpha, depth)."""
    n = len(gaussians)
    means2d, depths = np.zeros((n, 2), np.float32), np.zeros(n, np.float32)
    conics, radii, rects = np.zeros((n, 3), np.float32), np.zeros(n, np.int32), np.zeros((n, 4), np.int32)
    project(gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
            np.ascontiguousarray(camera.world_to_camera, np.float64), camera.fx, camera.fy,
            camera.cx, camera.cy, camera.width, camera.height, 0.01, means2d, depths, conics,
            radii, rects)
    colors = np.zeros((n, 3), np.float32)
    c = camera.camera_center
    sh_colors(gaussians.sh, gaussians.means, float(c[0]), float(c[1]), float(c[2]), colors)
    # stage 3 (bin_gaussians with the opacities)
    tiles_x, tiles_y = tile_grid(camera)
    n_tiles = tiles_x * tiles_y
    visible = np.flatnonzero(radii > 0).astype(np.int32)
    offsets = np.zeros(n_tiles + 1, np.int32)
    order = visible[depth_order(depths[visible])]
    qlims = tile_q_limits(gaussians.opacities)
    s_rects = np.empty((len(order), 4), np.int32)
    s_geo = np.empty((len(order), 8), np.float64)
    rank = np.full(n, -1, np.int32)
    rank[order] = np.arange(len(order), dtype=np.int32)
    sort_bin_data(rank, rects, means2d, conics, qlims, s_rects, s_geo)
    args = (s_rects, s_geo, tiles_x, camera.width, camera.height)
    counts = np.zeros((BIN_CHUNKS, n_tiles), np.int32)
    hits = np.empty(len(order), np.int64)
    count_tiles(*args, counts, hits)
    np.cumsum(counts.sum(axis=0), out=offsets[1:])
    cursor = (np.cumsum(counts, axis=0) - counts + offsets[:-1]).astype(np.int32)
    ids = np.empty(int(offsets[-1]), np.int32)
    scatter_tiles(order, *args, hits, cursor, ids)
    # stage 4
    h, w = camera.height, camera.width
    rgb = np.empty((h, w, 3), np.float32)
    trans = np.empty((h, w), np.float32)
    depth = np.empty((h, w), np.float32)
    slot = np.full(n, -1, np.int32)
    sids = np.empty_like(ids)
    first_sight(ids, slot, sids)
    packed = np.empty((int(slot.max()) + 1, PACK), np.float32)
    pack_splats(slot, means2d, conics, np.ascontiguousarray(gaussians.opacities, np.float32),
                colors, depths, packed)
    rasterize(offsets, sids, packed, 0.0, 0.0, 0.0, rgb, trans, depth)
    return rgb, 1.0 - trans, depth
