"""Taichi CPU kernels of the fast renderer. Imported lazily (after `ensure_taichi()`).

The maths mirrors `reference.py` line for line; see `pipeline.py` for the conventions. Every
kernel takes `ti.types.ndarray` arguments (numpy arrays, no copies, no global fields) so it
compiles once per process (and is then served from Taichi's offline cache on disk).
"""


from avatarkit._taichi import ensure_taichi

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
MASK_TILES = 63  # rects of up to this many tiles keep their hits as bits for the scatter
i64_1 = ti.types.ndarray(dtype=ti.i64, ndim=1)

# The depth sort: a stable LSD radix sort of the visible splats' depths (positive float32,
# which order like their bit patterns as int32) less the least of them, RADIX_BITS a pass.
# Each pass is a chunked counting sort, SORT_CHUNKS tasks a loop, so the result does not
# depend on the thread count. It takes as many passes as the keys' spread needs: two while
# the largest depth is within ~2-4x the smallest (the spread of the keys < 2^24: the bench
# scene's 2-4 m, an avatar at 0.4-0.7 m), one for < 2^12 (depths within ~1e-3 of each
# other), else three. 11 bits and always three passes cost one pass more; 8 bits (4 passes)
# and 2 or 8 chunks measured no faster than 11 bits.
SORT_CHUNKS = 4
RADIX_BITS = 12
RADIX = 1 << RADIX_BITS
RADIX_PASSES = -(-31 // RADIX_BITS)  # at most; the sign bit is 0


def order_row(passes: int) -> int:
    """The row of `bin_prepare`'s `idx` that the last of `passes` sort passes wrote."""
    return (passes - 1) % 2


@ti.func
def clamp_sel(v, lo, hi):
    """min(max(v, lo), hi) for lo <= hi, as two compare-selects."""
    w = ti.select(v < lo, lo, v)
    return ti.select(w > hi, hi, w)


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
        # clamps and minima as compare-selects: ti.min/ti.max add NaN handling (nothing here
        # is NaN), ~10% of the binning's ellipse tests
        best = qlim + 1.0
        for e in ti.static(range(2)):
            dx = lox if e == 0 else hix
            dy = clamp_sel(rc * dx, loy, hiy)
            q = ca * dx * dx + 2.0 * cb * dx * dy + cc * dy * dy
            best = ti.select(q < best, q, best)
            dy2 = loy if e == 0 else hiy
            dx2 = clamp_sel(ra * dy2, lox, hix)
            q2 = ca * dx2 * dx2 + 2.0 * cb * dx2 * dy2 + cc * dy2 * dy2
            best = ti.select(q2 < best, q2, best)
        if best <= qlim:
            hit = 1
    return hit


@ti.func
def splat_geo(means2d: ti.template(), conics: ti.template(), opacities: ti.template(), snug, g):
    """Splat g's (mx, my, a, b, c, q limit) in float64 for the tile test; the q limit is
    `pipeline.tile_q_limits` (computed as there, in float64, then rounded to float32) with
    `snug`, else -1 (plain 3-sigma rects: every tile of the rect)."""
    qlim = ti.cast(-1.0, ti.f64)
    if snug:
        # float64 constants: a bare Python float in a kernel is a float32 literal
        op = ti.max(ti.cast(opacities[g], ti.f64), ti.f64(ALPHA_MIN))
        qlim = ti.cast(ti.cast(2.0 * ti.log(op / ti.f64(ALPHA_MIN)) * ti.f64(1.01) + ti.f64(0.05),
                               ti.f32), ti.f64)
    return (ti.cast(means2d[g, 0], ti.f64), ti.cast(means2d[g, 1], ti.f64),
            ti.cast(conics[g, 0], ti.f64), ti.cast(conics[g, 1], ti.f64),
            ti.cast(conics[g, 2], ti.f64), qlim)


@ti.func
def splat_in_tile(mx, my, ca, cb, cc, ra, rc, qlim, tx, ty, width, height):
    """1 if a splat belongs in tile (tx, ty)'s list: always when its q limit is negative
    (plain 3-sigma rects), else when its alpha >= 1/255 ellipse reaches one of the tile's
    pixel centres (float64; ra = -b/a, rc = -b/c, worked out once per splat)."""
    hit = 1
    if qlim >= 0:
        hit = touches_tile(mx, my, ca, cb, cc, ra, rc, qlim, tx * TILE + 0.5,
                           ty * TILE + 0.5, ti.min(tx * TILE + TILE, width) - 0.5,
                           ti.min(ty * TILE + TILE, height) - 0.5)
    return hit


@ti.func
def splat_tiles_again(means2d: ti.template(), conics: ti.template(), opacities: ti.template(),
                      snug, g, tx, ty, width, height):
    """`splat_in_tile` for splat g from the input arrays: for the rare splats whose rect has
    more than MASK_TILES tiles, which keep no hit bits."""
    mx, my, ca, cb, cc, qlim = splat_geo(means2d, conics, opacities, snug, g)
    return splat_in_tile(mx, my, ca, cb, cc, -cb / ca, -cb / cc, qlim, tx, ty, width, height)


RECT_BASE = 65536  # a rect corner (tx, ty) is kept as tx + RECT_BASE ty (tiles a side <= 1024)


@ti.func
def splat_rect(s_rect: ti.template(), k):
    """(x0, y0, x1, y1) of depth-ordered splat k's tile rect, from its s_rect row."""
    lo = s_rect[k, 0]
    hi = s_rect[k, 1]
    return lo % RECT_BASE, lo // RECT_BASE, hi % RECT_BASE, hi // RECT_BASE


@ti.kernel
def bin_prepare(depths: f32_1, radii: i32_1, rects: i32_2, means2d: f32_2, conics: f32_2,
                opacities: f32_1, snug: ti.i32, tiles_x: ti.i32, width: ti.i32, height: ti.i32,
                keys: i32_2, idx: i32_2, hist: i32_2, spans: i32_2, total: i32_1, rank: i32_1,
                s_rect: i32_2, s_hits: i64_1, s_first: i32_1, counts: i32_2, firsts: i32_2,
                offsets: i32_1):
    """The binning up to its prefix sums, in one launch (each launch costs ~0.1-0.2 ms of
    Python and C++ on the calling thread while the other cores wait):

    1. idx[order_row(total[1]), :m] = the m splats with radii > 0 in increasing depth, ties
       in index order (numpy's stable argsort: `pipeline.depth_order`); total[0] = m,
       total[1] = the sort passes run (1 to RADIX_PASSES), total[2] = the least key;
       rank[i] = splat i's place in that order, -1 where culled (rank starts at -1). keys,
       idx: (2, N), hist: (SORT_CHUNKS, RADIX) and spans: (SORT_CHUNKS, 2) (each chunk's
       least and greatest key) scratch.
    2. Per splat, in input order (one parallel loop over all splats, so the costly part, the
       ellipse-tile tests, is spread evenly over the cores), written to row k = rank[i] so
       that the chunk loops below and `scatter_tiles` read in depth order, streaming:
       s_hits[k] = its tiles as bits, row-major over its rect (bit (ty - y0) * width + tx -
       x0), or -1 for a rect of more than MASK_TILES tiles (tested again where needed);
       s_first[k] = its first tile (row-major), -1 if it reaches none; s_rect[k] = (x0 +
       RECT_BASE y0, x1 + RECT_BASE y1). Reading the input-ordered arrays in depth order
       instead (no copy) measured 1.6x slower.
    3. counts[c, t] = number of splats of depth-order chunk c (BIN_CHUNKS chunks) in tile t's
       list; firsts[c, t] = how many of them have t as their first tile, which sets the
       records' slots (`scatter_tiles`); both start at 0. One task per chunk, so no atomics.
    4. Prefix sums, serial (32k additions: less than numpy's calls on the calling thread):
       offsets (n_tiles + 1,) = where each tile's list starts; counts[c, t] becomes where
       chunk c's part of tile t's list starts (after all earlier tiles' entries and the
       earlier chunks' entries of tile t), firsts[c, t] likewise for the slots.
    """
    n_in = depths.shape[0]
    per_in = (n_in + SORT_CHUNKS - 1) // SORT_CHUNKS
    ti.loop_config(block_dim=1)
    for c in range(SORT_CHUNKS):
        lo = 0x7FFFFFFF
        hi = -1
        for k in range(c * per_in, ti.min(n_in, (c + 1) * per_in)):
            if radii[k] > 0:
                key = ti.bit_cast(depths[k], ti.i32)
                lo = ti.min(lo, key)
                hi = ti.max(hi, key)
        spans[c, 0] = lo
        spans[c, 1] = hi
    # the keys are sorted less the least of them: as many passes as their spread needs
    ti.loop_config(serialize=True)
    for _ in range(1):
        lo = 0x7FFFFFFF
        hi = -1
        for c in range(SORT_CHUNKS):
            lo = ti.min(lo, spans[c, 0])
            hi = ti.max(hi, spans[c, 1])
        passes = 1
        while passes < RADIX_PASSES and ((hi - lo) >> (passes * RADIX_BITS)) > 0:
            passes += 1
        total[1] = passes
        total[2] = lo
    for p in ti.static(range(RADIX_PASSES)):
        shift = p * RADIX_BITS
        src = (p + 1) % 2  # pass 0 reads the inputs, then each pass the buffer the last wrote
        dst = p % 2
        ti.loop_config(block_dim=1)
        for c in range(SORT_CHUNKS):
            for d in range(RADIX):
                hist[c, d] = 0
            n = n_in if p == 0 else (total[0] if p < total[1] else 0)
            per = (n + SORT_CHUNKS - 1) // SORT_CHUNKS
            for k in range(c * per, ti.min(n, (c + 1) * per)):
                if p > 0 or radii[k] > 0:
                    key = ti.bit_cast(depths[k], ti.i32) - total[2] if p == 0 else keys[src, k]
                    d = (key >> shift) & (RADIX - 1)
                    hist[c, d] = hist[c, d] + 1
        # digit d of chunk c goes after all smaller digits and the earlier chunks' digit d
        ti.loop_config(serialize=True)
        for _ in range(1):
            run = 0
            if p == 0 or p < total[1]:
                for d in range(RADIX):
                    for c in range(SORT_CHUNKS):
                        v = hist[c, d]
                        hist[c, d] = run
                        run += v
            if ti.static(p == 0):
                total[0] = run
        ti.loop_config(block_dim=1)
        for c in range(SORT_CHUNKS):
            n = n_in if p == 0 else (total[0] if p < total[1] else 0)
            last = p == total[1] - 1
            per = (n + SORT_CHUNKS - 1) // SORT_CHUNKS
            for k in range(c * per, ti.min(n, (c + 1) * per)):
                if p > 0 or radii[k] > 0:
                    key = ti.bit_cast(depths[k], ti.i32) - total[2] if p == 0 else keys[src, k]
                    i = k if p == 0 else idx[src, k]
                    d = (key >> shift) & (RADIX - 1)
                    pos = hist[c, d]
                    hist[c, d] = pos + 1
                    keys[dst, pos] = key
                    idx[dst, pos] = i
                    if last:
                        rank[i] = pos
    for i in range(n_in):
        k = rank[i]
        if k >= 0:
            x0, y0, x1, y1 = rects[i, 0], rects[i, 1], rects[i, 2], rects[i, 3]
            mx, my, ca, cb, cc, qlim = splat_geo(means2d, conics, opacities, snug, i)
            ra = -cb / ca
            rc = -cb / cc
            bits = ti.cast(0, ti.i64)
            f = -1
            j = 0
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    if splat_in_tile(mx, my, ca, cb, cc, ra, rc, qlim, tx, ty, width, height):
                        if f < 0:
                            f = ty * tiles_x + tx
                        if j < MASK_TILES:
                            bits |= ti.cast(1, ti.i64) << j
                    j += 1
            s_hits[k] = bits if (x1 - x0) * (y1 - y0) <= MASK_TILES else -1
            s_first[k] = f
            s_rect[k, 0] = x0 + RECT_BASE * y0
            s_rect[k, 1] = x1 + RECT_BASE * y1
    ti.loop_config(block_dim=1)
    for c in range(BIN_CHUNKS):
        m = total[0]
        per = (m + BIN_CHUNKS - 1) // BIN_CHUNKS
        for k in range(c * per, ti.min(m, (c + 1) * per)):
            f = s_first[k]
            if f >= 0:
                firsts[c, f] = firsts[c, f] + 1
            bits = s_hits[k]
            x0, y0, x1, y1 = splat_rect(s_rect, k)
            j = 0
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    hit = 0
                    if bits >= 0:
                        hit = ti.cast((bits >> j) & 1, ti.i32)
                    else:
                        hit = splat_tiles_again(means2d, conics, opacities, snug,
                                                idx[(total[1] - 1) % 2, k], tx, ty, width, height)
                    if hit:
                        t = ty * tiles_x + tx
                        counts[c, t] = counts[c, t] + 1
                    j += 1
    ti.loop_config(serialize=True)
    for _ in range(1):
        run = 0
        first_run = 0
        for t in range(offsets.shape[0] - 1):
            offsets[t] = run
            for c in range(BIN_CHUNKS):
                v = counts[c, t]
                counts[c, t] = run
                run += v
                f = firsts[c, t]
                firsts[c, t] = first_run
                first_run += f
        offsets[offsets.shape[0] - 1] = run


@ti.kernel
def scatter_tiles(order: i32_1, s_rect: i32_2, s_hits: i64_1, means2d: f32_2, conics: f32_2,
                  opacities: f32_1, snug: ti.i32, tiles_x: ti.i32, width: ti.i32,
                  height: ti.i32, cursor: i32_2, ids: i32_1, first_cursor: i32_2, slot: i32_1,
                  sids: i32_1):
    """Walk each chunk's splats front to back and append them to their tiles' lists from
    cursor[c, t] (where chunk c's part of tile t's list starts); every list comes out
    depth-sorted without a per-tile sort. A splat's tiles are `bin_prepare`'s `s_hits` bits,
    or tested again where it kept none.

    Also gives each listed splat g its record's row slot[g] (slot starts at -1) and
    sids[k] = slot[ids[k]]: the slots count up by first tile, and within one first tile in
    depth order, from first_cursor[c, t] (where chunk c's splats first seen in tile t start).
    That is the order in which a walk through the lists tile by tile first names the splats
    (`first_sight`, the serial definition), so a tile's records lie close together."""
    m = order.shape[0]
    per = (m + BIN_CHUNKS - 1) // BIN_CHUNKS
    ti.loop_config(block_dim=1)
    for c in range(BIN_CHUNKS):
        for k in range(c * per, ti.min(m, (c + 1) * per)):
            bits = s_hits[k]
            g = order[k]
            s = -1
            j = 0
            x0, y0, x1, y1 = splat_rect(s_rect, k)
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    hit = 0
                    if bits >= 0:
                        hit = ti.cast((bits >> j) & 1, ti.i32)
                    else:
                        hit = splat_tiles_again(means2d, conics, opacities, snug, g, tx, ty,
                                                width, height)
                    if hit:
                        t = ty * tiles_x + tx
                        if s < 0:
                            s = first_cursor[c, t]
                            first_cursor[c, t] = s + 1
                            slot[g] = s
                        ids[cursor[c, t]] = g
                        sids[cursor[c, t]] = s
                        cursor[c, t] = cursor[c, t] + 1
                    j += 1


SPAN_EPS = 1e-3  # pixels of slack on every extent bound (float rounding)
# Band compositing (one task per BAND rows of a tile, its pixels' state in local arrays, per
# splat the rows and aligned 8-pixel blocks its extents reach): the label-lifting kernel
# (`recon/_label_kernels.py`) composites that way with these constants and `band_rect`; the
# renderer's `rasterize` composites per 8x2 cell instead (below).
BAND = 16
NBAND = TILE // BAND
LANES = 8  # a tile row is two aligned blocks of 8 pixels
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
    xc = ti.select(x > -87.0, x, -87.0)  # as a compare-select: one maxps (ti.max adds NaN care)
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
    them (~1.5x slower compositing at 100k). One serial pass (~3 ms at 100k): the obvious
    definition of the order `scatter_tiles` gives in parallel, kept for tests and for
    TileBins made without slots."""
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
    al = op * exp_f32((ha * dx + bdy) * dx + cdy)
    # a compare-select compiles to one minps; ti.min's NaN handling costs two more vector
    # instructions per block (~4% of the compositing, measured). alpha is never NaN here.
    return ti.select(al < ALPHA_MAX, al, ALPHA_MAX)


u32_1 = ti.types.ndarray(dtype=ti.u32, ndim=1)
# A tile is composited in 16 cells of 8 pixels x 2 rows, each as one 16-lane vector: cell
# c = blk * 8 + p holds pixels (x0 + 8 blk + lane % 8, y0 + 2 p + lane // 8).
CELL_ROWS = 2
CELLS = (TILE // LANES) * (TILE // CELL_ROWS)
CELL_LANES = LANES * CELL_ROWS


@ti.func
def cell_mask(mx, my, ext_x, ext_y, x0, y0, x1, y1):
    """The tile's cells (bit blk * 8 + p) that a splat's extents reach in one of their
    pixels (`band_rect`); 0: none. Branch-free: the row-pair range becomes a run of bits."""
    ra, rb, b0, b1 = band_rect(mx, my, ext_x, ext_y, x0, y0, x1, y1)
    lo = ti.min(ti.max(ra, 0), TILE) // CELL_ROWS
    hi = (ti.min(ti.max(rb + 1, 0), TILE) + CELL_ROWS - 1) // CELL_ROWS  # cell rows [lo, hi)
    one = ti.cast(1, ti.u32)
    pairs = ((one << ti.cast(hi, ti.u32)) - one) & ~((one << ti.cast(lo, ti.u32)) - one)
    pairs = pairs if ra <= rb else ti.cast(0, ti.u32)
    m0 = pairs if b0 <= 0 and b1 >= 0 else ti.cast(0, ti.u32)
    m1 = (pairs << (TILE // CELL_ROWS)) if b0 <= 1 and b1 >= 1 else ti.cast(0, ti.u32)
    return m0 | m1


@ti.kernel
def rasterize(offsets: i32_1, ids: i32_1, packed: f32_2, lists: i32_1, bg_r: ti.f32,
              bg_g: ti.f32, bg_b: ti.f32, out_rgb: f32_3, out_alpha: f32_2, out_depth: f32_2):
    """Front-to-back alpha compositing, one task per 16x16 tile, cell by cell.

    The task first deals its depth-sorted list (entry k is record ids[k] of `packed`, n
    entries) out into one list per cell (8 pixels x 2 rows), in list order: entry k goes to
    the cells its extents reach (`cell_mask`); cell c's list fills lists[CELLS * offsets[t] +
    c * n:] (room for all n; `lists` has CELLS x the entries of all tiles). Then each cell
    walks its own list with its 16 pixels' state in registers, composited as one 16-lane
    vector (a visit is pure arithmetic: no loads and stores of the state, no tests of which
    rows and blocks a splat reaches), and stops as soon as all 16 pixels have terminated.

    Per cell and splat, branch-free: alpha from its own exponential at every pixel, the
    alpha test, clamping and termination as INRIA's, as selects. Each pixel sees the same
    splats in the same order, with the same arithmetic, as in a splat-major walk over the
    rows and 8-pixel blocks the splats' extents reach: a pixel of a cell outside them (the
    cell's other row) has alpha < 1/255 (`pack_one`), so it draws nothing. Cells cut by the
    image's right or bottom edge are composited whole; the lanes past the edge are never
    written out. (INRIA also skips power > 0, which a positive-definite conic never gives.)
    """
    height = out_rgb.shape[0]
    width = out_rgb.shape[1]
    tiles_x = (width + TILE - 1) // TILE
    ti.loop_config(block_dim=1)  # tiles cost very different amounts: hand them out one by one
    for t in range(offsets.shape[0] - 1):
        x0 = (t % tiles_x) * TILE
        y0 = (t // tiles_x) * TILE
        x1 = ti.min(x0 + TILE, width)
        y1 = ti.min(y0 + TILE, height)
        n = offsets[t + 1] - offsets[t]
        base = CELLS * offsets[t]
        cnt = ti.Vector([0] * CELLS, ti.i32)
        for k in range(offsets[t], offsets[t + 1]):
            s = ids[k]
            m = cell_mask(packed[s, 0], packed[s, 1], packed[s, 6], packed[s, 7], x0, y0, x1, y1)
            while m != 0:
                low = m & (~m + ti.cast(1, ti.u32))
                c = 31 - ti.cast(ti.math.clz(low), ti.i32)
                lists[base + c * n + cnt[c]] = s
                cnt[c] += 1
                m ^= low
        for c in range(CELLS):
            bx = x0 + (c // (TILE // CELL_ROWS)) * LANES
            by = y0 + (c % (TILE // CELL_ROWS)) * CELL_ROWS
            if bx < x1 and by < y1:
                st_t = ti.Vector([1.0] * CELL_LANES, ti.f32)
                st_r = ti.Vector([0.0] * CELL_LANES, ti.f32)
                st_g = ti.Vector([0.0] * CELL_LANES, ti.f32)
                st_b = ti.Vector([0.0] * CELL_LANES, ti.f32)
                st_d = ti.Vector([0.0] * CELL_LANES, ti.f32)
                final_t = ti.Vector([0.0] * CELL_LANES, ti.f32)
                left = CELL_LANES  # pixels not yet terminated (lanes past the edges count too)
                xc = ti.cast(bx, ti.f32) + 0.5
                for e in range(base + c * n, base + c * n + cnt[c]):
                    s = lists[e]
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
                    bdy = ti.Vector([0.0] * CELL_ROWS, ti.f32)
                    cdy = ti.Vector([0.0] * CELL_ROWS, ti.f32)
                    for j in ti.static(range(CELL_ROWS)):
                        dy = my - (ti.cast(by + j, ti.f32) + 0.5)
                        bdy[j] = nb * dy
                        cdy[j] = hc * dy * dy
                    dx0 = mx - xc
                    ended = 0
                    for lane in ti.static(range(CELL_LANES)):
                        # A terminated pixel holds T = 0 (its last T kept in final_t), so that
                        # no test of T comes before the product: the loop-carried chain per
                        # splat is one multiply, one compare and one select. With T = 0 every
                        # later splat adds exactly +0 (colours and depths are >= 0).
                        alpha = lane_alpha(op, ha, bdy[lane // LANES], cdy[lane // LANES],
                                           dx0 - (lane % LANES))
                        draw = alpha >= ALPHA_MIN
                        a = alpha if draw else 0.0
                        keep = 1.0 - a
                        tr = st_t[lane]
                        test_t = tr * keep
                        end = draw & (test_t < T_MIN)
                        w = 0.0 if end else a * tr
                        st_r[lane] += cr * w
                        st_g[lane] += cg * w
                        st_b[lane] += cbl * w
                        st_d[lane] += z * w
                        st_t[lane] = 0.0 if end else test_t
                        first = end & (tr > 0)
                        final_t[lane] = tr if first else final_t[lane]
                        ended += ti.cast(first, ti.i32)
                    left -= ended
                    if left == 0:
                        break
                for lane in ti.static(range(CELL_LANES)):
                    ix = bx + lane % LANES
                    iy = by + lane // LANES
                    if ix < x1 and iy < y1:
                        tr = st_t[lane] if st_t[lane] > 0 else final_t[lane]
                        out_alpha[iy, ix] = 1.0 - tr
                        out_rgb[iy, ix, 0] = st_r[lane] + tr * bg_r
                        out_rgb[iy, ix, 1] = st_g[lane] + tr * bg_g
                        out_rgb[iy, ix, 2] = st_b[lane] + tr * bg_b
                        acc = 1.0 - tr
                        d = 0.0
                        if acc > 0:
                            d = st_d[lane] / acc
                        out_depth[iy, ix] = d
