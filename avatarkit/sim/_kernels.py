"""The XPBD frame kernel: every substep of one frame in a single Taichi launch.

All loops run serially inside one outer iteration: Gauss-Seidel over the constraints in a fixed
order is deterministic, converges faster than Jacobi, and for a ~500-vertex cage a launch per
frame beats any parallel split (a parallel loop costs a thread sync per constraint colour).
The outer loop is serialized, so the kernel runs on the calling thread: handing one task to
Taichi's thread pool and waiting for it cost ~0.15 ms a launch under load, for nothing.
`reference.py` is the obvious numpy twin of this file; keep the two in the same order.

Updates of the buffers are written `x[i] = x[i] + ...`, never `x[i] += ...`: inside a
parallel loop (which the outer loop was until session 4) Taichi compiles `+=` on an ndarray to
an atomic compare-and-swap loop, which cost more than the arithmetic of a constraint.

Inputs are packed into four buffers because Taichi's Python side spends ~15 us per kernel
argument: the launch costs about as much as 10 constraint sweeps otherwise. Layout (offsets in
the `ibuf` header, filled by `solver.PackedModel`):
  xbuf (vec3): [x (C) | v (C) | x_prev (C) | volume gradient (C) | volume linearisation point (C) |
                root targets at frame start (R) | at frame end (R)]
  ibuf (i32):  header (H_COUNT) | edges (2E) | bend pairs (2B) | faces (3F) | tether root (C) |
               proxy index (C*K) | roots (R)
  fbuf (f32):  params (FP_COUNT) | inv_mass (C) | edge data (8E) | bend data (8B) |
               tether length (C) | proxy weight (C*K) | multipliers (1 + 2C) |
               joint rotations per substep (9 S JMAX, row-major) | translations (3 S JMAX) |
               collision cache: last tested rest-frame point (3C) and its distance (C) |
               collision denominator sum_k w_k^2 / m_k of each proxy (C) |
               per substep, a bound on how far inverse LBS puts a point from where the head
               joint alone would (S)
  A distance constraint's record is [rest length l0, k = 1 / (w_a + w_b + alpha~), w_a k, w_b k,
  multiplier, alpha~, -, -]: one 32-byte block instead of scattered reads and a division (filled
  per time step; the multiplier is 0 at each substep's start, see `simulate_frame`). Edges and
  bend pairs, and their records, are adjacent: one loop sweeps stretch then bending in order.
  sdf (vec4, 3-D): the rest head SDF grid, [distance, unit gradient].
  skin (vec4, 3-D): the skinning weights of up to JMAX joints (joint 0: the head joint) of the
  rest head surface nearest each node of a coarse grid (`sdf.HeadSkin`).

Collision (mode 1: the vertex, mode 2: its proxy p = sum_k w_k x_k, evaluated from the current
cage at every test) is C(x) = sdf(p) - margin >= 0 with gradient w_k n for cage vertex k, so an
XPBD step moves x_k by w_k / m_k * dlambda * n with dlambda = (margin - sdf - alpha~ lambda) /
(sum_k w_k^2 / m_k + alpha~). The posed head is the rest SDF seen through inverse LBS: a world
point is taken to the rest frame by the head joint; where the skinning field there is not all
head joint (jaw, neck), by the inverse of the blend sum_j w_j T_j of this substep's joint
transforms instead.
"""
from avatarkit._taichi import ensure_taichi
from avatarkit.sim._skin_math import JMAX, RIGID_WEIGHT

ti = ensure_taichi()

vec3 = ti.math.vec3
vec4 = ti.math.vec4

# ibuf header slots
(H_SUBSTEPS, H_ITERATIONS, H_MODE, H_NC, H_NE, H_NB, H_NF, H_NR, H_NK, H_EDGES, H_FACES,
 H_TETHER, H_PROXY_IDX, H_ROOTS, H_INV_MASS, H_EDGE_DATA, H_TETHER_LEN, H_PROXY_W,
 H_LAMBDA, H_ROT, H_TRANS, H_CACHE, H_PROXY_DEN, H_NJ, H_DEVIATION, H_COLLISION_EVERY) = range(26)
H_COUNT = 26
#: a bound on |grad| of the trilinear grid SDF (sqrt(3) for samples of a 1-Lipschitz field, plus
#: slack for the approximate far field): a point that moved less than (d - margin) / LIPSCHITZ
#: since it was last found d away from the head cannot touch it, so its lookup is skipped
LIPSCHITZ = 2.0
#: squared lengths below SLACK x a squared limit are certainly under the limit (the square root and
#: its float rounding, ~1e-7, cannot take them over): tests that skip a square root use it
SLACK = 0.9999
#: the proxy size (`model.PROXY_K`) the kernel unrolls its proxy sums for; other sizes (rigs
#: saved with 32 weights) take a plain loop, with the same sum in the same order
PROXY_UNROLL = 8

# fbuf parameter slots (compliances already divided by h^2)
(FP_H, FP_ALPHA_S, FP_ALPHA_B, FP_ALPHA_V, FP_ALPHA_T, FP_ALPHA_C, FP_DAMP, FP_MARGIN,
 FP_GX, FP_GY, FP_GZ, FP_VMAX, FP_VOLUME, FP_OX, FP_OY, FP_OZ, FP_SDF_INV,
 FP_SKIN_OX, FP_SKIN_OY, FP_SKIN_OZ, FP_SKIN_INV, FP_BOX_LO, FP_BOX_HI) = (*range(21), 21, 24)
FP_COUNT = 27  # the box's corners take 3 slots each


@ti.func
def trilinear(grid: ti.template(), uc):
    """Trilinear vec4 of grid (a 3-D field of vec4) at grid coordinates uc, already clamped to
    [0, n - 1] (the Taichi twin of `head.sdf_grid.trilinear`)."""
    i0 = ti.min(ti.cast(ti.floor(uc), ti.i32),
                ti.math.ivec3(grid.shape[0] - 2, grid.shape[1] - 2, grid.shape[2] - 2))
    t = uc - ti.cast(i0, ti.f32)
    out = vec4(0.0)
    for dx, dy, dz in ti.static(ti.ndrange(2, 2, 2)):
        wx = dx * t[0] + (1 - dx) * (1.0 - t[0])
        wy = dy * t[1] + (1 - dy) * (1.0 - t[1])
        wz = dz * t[2] + (1 - dz) * (1.0 - t[2])
        out += wx * wy * wz * grid[i0[0] + dx, i0[1] + dy, i0[2] + dz]
    return out


@ti.func
def sdf_lookup(sdf: ti.template(), q, origin, inv_h):
    """Trilinear [value, unit gradient] (vec4) at rest-frame point q; outside the box the
    distance to it is added to the value at the nearest node."""
    nx, ny, nz = sdf.shape[0], sdf.shape[1], sdf.shape[2]
    u = (q - origin) * inv_h
    uc = ti.math.clamp(u, 0.0, vec3(nx - 1, ny - 1, nz - 1))
    outside = (u - uc).norm() / inv_h
    out = trilinear(sdf, uc)
    g = vec3(out[1], out[2], out[3])
    g = g / ti.max(g.norm(), 1e-12)
    return vec4(out[0] + outside, g[0], g[1], g[2])


@ti.func
def skin_lookup(skin: ti.template(), q, origin, inv_h):
    """Trilinear joint weights (vec4) at rest-frame point q, clamped to the grid (outside it the
    nearest surface's weights are those of the border nodes)."""
    nx, ny, nz = skin.shape[0], skin.shape[1], skin.shape[2]
    return trilinear(skin, ti.math.clamp((q - origin) * inv_h, 0.0, vec3(nx - 1, ny - 1, nz - 1)))


@ti.func
def joint_rotation(fb: ti.template(), o_rot, s, j):
    r = ti.math.mat3(0.0)
    base = o_rot + 9 * (s * JMAX + j)
    for a in ti.static(range(3)):
        for b in ti.static(range(3)):
            r[a, b] = fb[base + 3 * a + b]
    return r


@ti.func
def joint_translation(fb: ti.template(), o_trans, s, j):
    base = o_trans + 3 * (s * JMAX + j)
    return vec3(fb[base], fb[base + 1], fb[base + 2])


@ti.func
def solve_distance(xb: ti.template(), fb: ti.template(), a, b, od, first, last):
    """XPBD distance constraint; od: offset of its record (see the module docstring) in fb;
    first: the substep's first sweep, whose multiplier is 0 (not read: see `simulate_frame`);
    last: the substep's last sweep, whose multiplier nothing reads (not written: with the
    default single sweep that is ~2,200 strided stores a substep).

    The correction w_a dl / |d| is rewritten as (r w_a k) / |d| - w_a k with r = l0 - alpha~ lambda
    (dl = (r - |d|) k): the chain from the positions just written by the previous constraint to
    the ones written here is then a dot product, a square root, a division and two multiply-adds, which
    is what bounds a serial Gauss-Seidel sweep; everything else overlaps with it."""
    d = xb[a] - xb[b]
    len2 = d.dot(d)
    if len2 > 1e-18:
        inv_len = ti.rsqrt(len2)
        lam = 0.0
        if not first:
            lam = fb[od + 4]
        r = fb[od] - fb[od + 5] * lam
        wak = fb[od + 2]
        wbk = fb[od + 3]
        if not last:
            fb[od + 4] = lam + (r - len2 * inv_len) * fb[od + 1]
        xb[a] = xb[a] + ((r * wak) * inv_len - wak) * d
        xb[b] = xb[b] - ((r * wbk) * inv_len - wbk) * d


@ti.func
def skull_preimage(skin: ti.template(), fb: ti.template(), p, q1, rs, o_rot, o_trans, s, nj, skin_origin,
                   skin_inv_h):
    """The rest point of world point p on the skull's piece of the posed head, and the linear
    part of the transform that places it: q1 (p in the head joint's rest frame) and the head
    joint's rotation rs where the skinning field at q1 is all head joint, else the inverse of
    the LBS blend with the weights found at q1 (jaw, neck)."""
    q = q1
    lin = rs
    if nj > 1:
        wj = skin_lookup(skin, q1, skin_origin, skin_inv_h)
        if wj[0] < RIGID_WEIGHT:
            lin = ti.math.mat3(0.0)
            tb = vec3(0.0)
            for j in ti.static(range(JMAX)):
                if j < nj:
                    lin += wj[j] * joint_rotation(fb, o_rot, s, j)
                    tb += wj[j] * joint_translation(fb, o_trans, s, j)
            q = ti.math.inverse(lin) @ (p - tb)
    return q, lin


@ti.func
def posed_sdf(sdf: ti.template(), skin: ti.template(), fb: ti.template(), p, q1, rs, o_rot, o_trans, s, nj,
              origin, inv_h, skin_origin, skin_inv_h, enough):
    """[distance, unit world normal] of world point p to the posed head of substep s; q1: p in
    the head joint's rest frame, rs its rotation. The posed head is the union of its skinned
    pieces: the rest SDF at the inverse of the LBS blend with the weights found at q1 and, for
    every other joint j, at T_j^-1 p where that point lies in j's region (weight > 1/2); the
    smallest wins (a point the jaw swung onto is inside the jaw wherever the skull's preimage
    puts it). enough: when the first value is at least this, the other pieces are not tried
    (pass +inf to always try them)."""
    q, lin = skull_preimage(skin, fb, p, q1, rs, o_rot, o_trans, s, nj, skin_origin, skin_inv_h)
    hit = sdf_lookup(sdf, q, origin, inv_h)
    n = ti.math.inverse(lin).transpose() @ vec3(hit[1], hit[2], hit[3])
    for j in ti.static(range(1, JMAX)):
        if j < nj and hit[0] < enough:
            rj = joint_rotation(fb, o_rot, s, j)
            qj = rj.transpose() @ (p - joint_translation(fb, o_trans, s, j))
            if skin_lookup(skin, qj, skin_origin, skin_inv_h)[j] > 0.5:
                hj = sdf_lookup(sdf, qj, origin, inv_h)
                if hj[0] < hit[0]:
                    hit = hj
                    n = rj @ vec3(hj[1], hj[2], hj[3])
    n = n / ti.max(n.norm(), 1e-12)
    return vec4(hit[0], n[0], n[1], n[2])


@ti.func
def grid_cell(cells: ti.template(), q, origin, inv_h):
    """The cell of a per-cell grid (one less per axis than its node grid at origin, spacing
    1 / inv_h) that a trilinear lookup at rest point q reads: clamped like `trilinear`."""
    top = ti.math.ivec3(cells.shape[0], cells.shape[1], cells.shape[2])
    uc = ti.math.clamp((q - origin) * inv_h, 0.0, ti.cast(top, ti.f32))
    return ti.min(ti.cast(ti.floor(uc), ti.i32), top - 1)


@ti.func
def may_touch(floors: ti.template(), q, origin, inv_h, limit):
    """False when the SDF in rest point q's grid cell is provably at least limit * CELL_STEP
    (the cell's `HeadSDF.cell_floor` code is at least limit)."""
    c = grid_cell(floors, q, origin, inv_h)
    return ti.cast(floors[c[0], c[1], c[2]], ti.i32) < limit


@ti.func
def update_velocity(xb: ti.template(), fb: ti.template(), i, o_v, o_prev, o_w, h, damp, vmax):
    """Step 4 for vertex i: v = (x - x_prev) / h, then (free vertices) damping and the clamp."""
    vi = (xb[i] - xb[o_prev + i]) / h
    if fb[o_w + i] > 0.0:
        vi *= damp
        if vi.dot(vi) > SLACK * vmax * vmax:  # (a square root only near the limit)
            speed = vi.norm()
            if speed > vmax:
                vi *= vmax / speed
    xb[o_v + i] = vi


@ti.func
def proxy_point(xb: ti.template(), ib: ti.template(), fb: ti.template(), oi, ow, nk):
    """sum_k w_k x_k over a proxy's nk cage vertices (indices at ib[oi:], weights at fb[ow:]),
    one running sum in k order (as `reference.py`; four interleaved sums measured no faster)."""
    p = vec3(0.0)
    if nk == PROXY_UNROLL:
        # the default, unrolled: the 8 index -> position loads of every proxy are independent
        for k in ti.static(range(PROXY_UNROLL)):
            p += fb[ow + k] * xb[ib[oi + k]]
    else:
        for k in range(nk):
            p += fb[ow + k] * xb[ib[oi + k]]
    return p


@ti.kernel
def simulate_frame(xb: ti.types.ndarray(dtype=vec3, ndim=1), ib: ti.types.ndarray(dtype=ti.i32, ndim=1),
                   fb: ti.types.ndarray(dtype=ti.f32, ndim=1), sdf: ti.types.ndarray(dtype=vec4, ndim=3),
                   skin: ti.types.ndarray(dtype=vec4, ndim=3)):
    ti.loop_config(serialize=True)  # on the calling thread (module docstring)
    for _ in range(1):  # one serial task: Gauss-Seidel, deterministic
        n_sub = ib[H_SUBSTEPS]
        n_iter = ib[H_ITERATIONS]
        mode = ib[H_MODE]
        nc = ib[H_NC]
        ne = ib[H_NE]
        nb = ib[H_NB]
        nf = ib[H_NF]
        nr = ib[H_NR]
        nk = ib[H_NK]
        nj = ib[H_NJ]
        coll_every = ib[H_COLLISION_EVERY]
        o_edge = ib[H_EDGES]
        o_face = ib[H_FACES]
        o_tether = ib[H_TETHER]
        o_pidx = ib[H_PROXY_IDX]
        o_root = ib[H_ROOTS]
        o_w = ib[H_INV_MASS]
        o_edata = ib[H_EDGE_DATA]
        o_tlen = ib[H_TETHER_LEN]
        o_pw = ib[H_PROXY_W]
        o_lam = ib[H_LAMBDA]
        o_rot = ib[H_ROT]
        o_trans = ib[H_TRANS]
        o_cache = ib[H_CACHE]
        o_cdist = o_cache + 3 * nc
        o_pden = ib[H_PROXY_DEN]
        o_dev = ib[H_DEVIATION]
        # vec3 buffer sections
        o_v = nc
        o_prev = 2 * nc
        o_grad = 3 * nc
        o_x0 = 4 * nc
        o_ra = 5 * nc
        o_rb = 5 * nc + nr
        # multiplier sections
        l_vol = o_lam
        l_tether = l_vol + 1
        l_coll = l_tether + nc

        h = fb[FP_H]
        a_v = fb[FP_ALPHA_V]
        a_t = fb[FP_ALPHA_T]
        a_c = fb[FP_ALPHA_C]
        damp = fb[FP_DAMP]
        margin = fb[FP_MARGIN]
        gravity = vec3(fb[FP_GX], fb[FP_GY], fb[FP_GZ])
        vmax = fb[FP_VMAX]
        rest_volume = fb[FP_VOLUME]
        origin = vec3(fb[FP_OX], fb[FP_OY], fb[FP_OZ])
        inv_h = fb[FP_SDF_INV]
        skin_origin = vec3(fb[FP_SKIN_OX], fb[FP_SKIN_OY], fb[FP_SKIN_OZ])
        skin_inv_h = fb[FP_SKIN_INV]

        # Per substep, the bound on how far inverse LBS puts a point from where the head joint
        # alone would (`solver.skin_deviation`, its numpy twin: max over the box's corners q of
        # |T_0^-1 T_j q - q|); here rather than in numpy, where ~15 array calls on (S, J, 8, 3)
        # stacks cost ~0.2 ms a frame. Rounding makes no difference: the bound only decides
        # which collision tests are skipped, and a skipped test would have changed nothing.
        lo = vec3(fb[FP_BOX_LO], fb[FP_BOX_LO + 1], fb[FP_BOX_LO + 2])
        hi = vec3(fb[FP_BOX_HI], fb[FP_BOX_HI + 1], fb[FP_BOX_HI + 2])
        for s in range(n_sub):
            dev = 0.0
            r0 = joint_rotation(fb, o_rot, s, 0)
            t0 = joint_translation(fb, o_trans, s, 0)
            for j in range(1, nj):
                rel = r0.transpose() @ joint_rotation(fb, o_rot, s, j)
                rel_t = r0.transpose() @ (joint_translation(fb, o_trans, s, j) - t0)
                for c in ti.static(range(8)):
                    q = lo + (hi - lo) * vec3(ti.static(float((c >> 2) & 1)), ti.static(float((c >> 1) & 1)),
                                              ti.static(float(c & 1)))
                    dev = ti.max(dev, (rel @ q + rel_t - q).norm())
            fb[o_dev + s] = dev
        for s in range(n_sub):
            # 1. kinematic roots (linear between the frame's start and end) and prediction
            # (x0, the volume's linearisation point below, is the position after this step;
            # set here rather than in a pass of its own)
            frac = ti.cast(s + 1, ti.f32) / ti.cast(n_sub, ti.f32)
            for i in range(nc):
                if s > 0:  # step 4 of the previous substep, in this pass to read x once
                    update_velocity(xb, fb, i, o_v, o_prev, o_w, h, damp, vmax)
                xb[o_prev + i] = xb[i]
                if fb[o_w + i] > 0.0:
                    xb[o_v + i] = xb[o_v + i] + h * gravity
                    xb[i] = xb[i] + h * xb[o_v + i]
                xb[o_x0 + i] = xb[i]
                xb[o_grad + i] = vec3(0.0)
            for r in range(nr):
                root = ib[o_root + r]
                xb[root] = (1.0 - frac) * xb[o_ra + r] + frac * xb[o_rb + r]
                xb[o_x0 + root] = xb[root]
            # Multipliers start each substep at 0. The first sweep takes them as 0 without reading
            # them, so with one sweep (the default) there is nothing to reset: ~3,000 stores a
            # substep, most of them strided through the constraint records.
            if n_iter > 1:
                for li in range(1 + 2 * nc):
                    fb[o_lam + li] = 0.0
                for e in range(ne + nb):
                    fb[o_edata + 8 * e + 4] = 0.0
            rs = joint_rotation(fb, o_rot, s, 0)
            ts = joint_translation(fb, o_trans, s, 0)
            # The volume constraint is linearised once per substep at the predicted positions
            # x0: V(x) ~ V0 + sum_i g_i . (x_i - x0_i), g_i = dV/dx_i (a sixth of the summed
            # face cross products). Moves within a substep are millimetres, so the error is
            # second order, and each sweep then costs C dot products instead of a face pass.
            vol0 = 0.0
            vol_denom = 0.0
            if nf > 0:
                centre = xb[ib[o_face]]  # volumes about a nearby point keep float32 precise
                for f in range(nf):
                    ia = ib[o_face + 3 * f]
                    ic_b = ib[o_face + 3 * f + 1]
                    ic = ib[o_face + 3 * f + 2]
                    pa = xb[ia] - centre
                    pb = xb[ic_b] - centre
                    pc = xb[ic] - centre
                    bc = pb.cross(pc)
                    vol0 += pa.dot(bc)
                    xb[o_grad + ia] = xb[o_grad + ia] + bc
                    xb[o_grad + ic_b] = xb[o_grad + ic_b] + pc.cross(pa)
                    xb[o_grad + ic] = xb[o_grad + ic] + pa.cross(pb)
                vol0 /= 6.0
                for i in range(nc):
                    xb[o_grad + i] = xb[o_grad + i] / 6.0
                    vol_denom += fb[o_w + i] * xb[o_grad + i].norm_sqr()
            # 3. constraint projection
            for it in range(n_iter):
                first = it == 0
                last = it == n_iter - 1
                for e in range(ne + nb):  # stretch, then bending (adjacent tables)
                    solve_distance(xb, fb, ib[o_edge + 2 * e], ib[o_edge + 2 * e + 1],
                                   o_edata + 8 * e, first, last)
                dl_vol = 0.0
                if nf > 0:
                    vol = vol0
                    for i in range(nc):
                        vol += xb[o_grad + i].dot(xb[i] - xb[o_x0 + i])
                    lam_vol = 0.0
                    if not first:
                        lam_vol = fb[l_vol]
                    dl_vol = (rest_volume - vol - a_v * lam_vol) / (vol_denom + a_v + 1e-20)
                    fb[l_vol] = lam_vol + dl_vol
                # Volume and tether updates of vertex i read only x_i and its (kinematic) root,
                # so one pass per vertex gives exactly what two passes would.
                for i in range(nc):
                    wi = fb[o_w + i]
                    if wi > 0.0:
                        xb[i] = xb[i] + (wi * dl_vol) * xb[o_grad + i]
                        r = ib[o_tether + i]
                        if r >= 0:
                            d = xb[i] - xb[r]
                            li = l_tether + i
                            lam = 0.0
                            if not first:
                                lam = fb[li]
                            tlen = fb[o_tlen + i]
                            # A slack tether with no force yet is left alone (the max below
                            # would give 0): no square root and no divisions for most of them.
                            # The factor keeps the test clear of float rounding.
                            if lam > 0.0 or d.dot(d) > SLACK * tlen * tlen:
                                length = d.norm()
                                dl = (length - tlen - a_t * lam) / (wi + a_t)
                                new = ti.max(lam + dl, 0.0)  # a tether only pulls
                                dl = new - lam
                                fb[li] = new
                                if length > 1e-9:
                                    xb[i] = xb[i] - (wi * dl / length) * d
                # collision acts in every k-th substep and the last (`SimConfig.collision_period`)
                if mode > 0 and ((s + 1) % coll_every == 0 or s == n_sub - 1):
                    for i in range(nc):
                        den = fb[o_w + i]
                        if mode == 2:
                            den = fb[o_pden + i]
                        if den > 0.0:
                            p = xb[i]
                            if mode == 2:  # the proxy, live from the current cage
                                p = proxy_point(xb, ib, fb, o_pidx + i * nk, o_pw + i * nk, nk)
                            q1 = rs.transpose() @ (p - ts)
                            li = l_coll + i
                            lam = 0.0
                            if not first:
                                lam = fb[li]
                            cq = vec3(fb[o_cache + 3 * i], fb[o_cache + 3 * i + 1], fb[o_cache + 3 * i + 2])
                            # Skipping is exact: with no contact force yet (lambda = 0) and the
                            # point provably outside the margin, the update below is zero. The
                            # cache holds the head-joint point q1 of the last lookup and a lower
                            # bound of the distance there (the found one less LIPSCHITZ times
                            # that substep's deviation bound); the true rest point is within
                            # this substep's deviation bound of q1. Most points are far: a test on
                            # squares, 1 um and SLACK short of the bound, clears them without the
                            # square root; the rest take the test itself.
                            dq = q1 - cq
                            reach = (fb[o_cdist + i] - margin) / LIPSCHITZ - fb[o_dev + s] - 1e-6
                            near = lam > 0.0 or reach <= 0.0 or dq.dot(dq) > SLACK * reach * reach
                            if near:
                                near = lam > 0.0 or LIPSCHITZ * (dq.norm() + fb[o_dev + s]) >= fb[o_cdist + i] - margin
                            if near:
                                # With no contact force yet, a skull piece at least `enough` away
                                # leaves the jaw and neck pieces unlooked-up: they can be nearer
                                # only by twice the deviation bound (as in the push-out), so the
                                # contact stays off, as the full lookup would leave it (1 um for
                                # rounding). The cached bound then takes off that much more.
                                enough = ti.math.inf
                                if lam == 0.0 and (q1 >= lo).all() and (q1 <= hi).all():
                                    enough = margin + 2.0 * LIPSCHITZ * fb[o_dev + s] + 1e-6
                                hit = posed_sdf(sdf, skin, fb, p, q1, rs, o_rot, o_trans, s, nj, origin, inv_h,
                                                skin_origin, skin_inv_h, enough)
                                fb[o_cache + 3 * i] = q1[0]
                                fb[o_cache + 3 * i + 1] = q1[1]
                                fb[o_cache + 3 * i + 2] = q1[2]
                                bound = hit[0] - LIPSCHITZ * fb[o_dev + s]
                                if hit[0] >= enough:
                                    bound -= 2.0 * LIPSCHITZ * fb[o_dev + s]
                                fb[o_cdist + i] = bound
                                dl = (margin - hit[0] - a_c * lam) / (den + a_c)
                                new = ti.max(lam + dl, 0.0)  # contact only pushes
                                dl = new - lam
                                fb[li] = new
                                if dl != 0.0:
                                    n = vec3(hit[1], hit[2], hit[3])
                                    if mode == 2:
                                        for k in range(nk):
                                            j = ib[o_pidx + i * nk + k]
                                            xb[j] = xb[j] + (fb[o_w + j] * fb[o_pw + i * nk + k] * dl) * n
                                    else:
                                        xb[i] = xb[i] + (den * dl) * n
            # 4. velocities: in the next substep's first pass, after the last one below
        if n_sub > 0:
            for i in range(nc):
                update_velocity(xb, fb, i, o_v, o_prev, o_w, h, damp, vmax)


@ti.kernel
def push_out_points(points: ti.types.ndarray(dtype=vec3, ndim=1), fb: ti.types.ndarray(dtype=ti.f32, ndim=1),
                    sdf: ti.types.ndarray(dtype=vec4, ndim=3), skin: ti.types.ndarray(dtype=vec4, ndim=3),
                    floors: ti.types.ndarray(dtype=ti.u8, ndim=3), nj: ti.i32, clearance: ti.f32, rounds: ti.i32,
                    limit: ti.i32, far: ti.f32):
    """Move every point (N,) closer than `clearance` to the posed head out along the head's
    normal to `clearance` (`rounds` Newton steps on the SDF). fb: [sdf origin (3), 1 / spacing,
    skin origin (3), 1 / spacing, rotations (9 JMAX), translations (3 JMAX), deviation bound
    (`solver.skin_deviation`), the box that bound holds in (lo (3), hi (3))] of one pose.

    The screen: every skinned piece's rest point lies within the deviation bound of q1 (the
    point in the head joint's frame) when q1 is in the box, so where q1's cell of `floors`
    (`HeadSDF.cell_floor`) has a code of at least `limit` (worked out by `pushout` from the
    clearance plus LIPSCHITZ times the bound) no piece comes within the clearance and the point
    is left as the full lookup would leave it, for one byte read instead of a skin lookup and
    8 corners of the 32 MB grid. limit <= 0: no screen. The points a cell's floor cannot rule
    out (hair lying on the scalp, ~15 % of it) get a second screen: the rest SDF at q1 itself, at
    least `far` (clearance + slack + LIPSCHITZ times the bound) proves the same for one trilinear
    lookup instead of the skinning lookups and the jaw and neck pieces."""
    origin = vec3(fb[0], fb[1], fb[2])
    inv_h = fb[3]
    skin_origin = vec3(fb[4], fb[5], fb[6])
    skin_inv_h = fb[7]
    r0 = joint_rotation(fb, 8, 0, 0)
    t0 = joint_translation(fb, 8 + 9 * JMAX, 0, 0)
    o_box = 8 + 12 * JMAX + 1
    lo = vec3(fb[o_box], fb[o_box + 1], fb[o_box + 2])
    hi = vec3(fb[o_box + 3], fb[o_box + 4], fb[o_box + 5])
    for i in range(points.shape[0]):
        p = points[i]
        near = True
        if limit > 0:  # (nested ifs: Taichi's `and` / `or` evaluate both sides)
            q1 = r0.transpose() @ (p - t0)
            if (q1 >= lo).all() and (q1 <= hi).all():
                near = may_touch(floors, q1, origin, inv_h, limit)
                if near:
                    near = sdf_lookup(sdf, q1, origin, inv_h)[0] < far
        if near:
            for _r in range(rounds):
                q1 = r0.transpose() @ (p - t0)
                # another piece can only be nearer than the first value by twice the bound on
                # how far the pieces move against the skull (fb[8 + 12 JMAX])
                hit = posed_sdf(sdf, skin, fb, p, q1, r0, 8, 8 + 9 * JMAX, 0, nj, origin, inv_h,
                                skin_origin, skin_inv_h, clearance + 2.0 * LIPSCHITZ * fb[8 + 12 * JMAX])
                if hit[0] >= clearance:
                    break
                p = p + (clearance - hit[0]) * vec3(hit[1], hit[2], hit[3])
            points[i] = p
