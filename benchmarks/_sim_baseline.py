"""The previous XPBD frame kernel (main before issue 18's session 7), kept as the same-process
baseline of `benchmarks/sim.py`: the kernel and its buffer packing as they were, launched the same
way (`BoundLaunch`), so the benchmark's ratio is the session's own gain. Benchmark-only: nothing in
the library or the tests uses it.

What changed since (docs/simulation.md, "Speed work (session 7)"): collision in every k-th substep
(`SimConfig.collision_period`), no distance-constraint multiplier stores after a substep's last
sweep, the default proxy size's sums unrolled, and a contact-free skull lookup no longer followed
by the jaw and neck lookups. Run it with `collision_period=0` (collision in every substep, as it
was): it ignores the setting.

`PreviousSolver(model, config, skin)` steps like `XPBDSolver`. Its trajectories differ from the
current solver's at float rounding (the unrolled proxy sums) and by the collision substeps.
"""
import sys

import numpy as np

from avatarkit._taichi import ensure_taichi
from avatarkit.sim._launch import BoundLaunch
from avatarkit.sim._skin_math import JMAX, RIGID_WEIGHT
from avatarkit.sim.config import SimConfig
from avatarkit.sim.model import CageModel, CageState, HeadFrame
from avatarkit.sim.sdf import HeadSkin
from avatarkit.sim.solver import (MODE_CODES, XPBDSolver, check_step_inputs, frame_params,
                                  joint_substep_transforms, proxy_denominators, skin_joints)

ti = ensure_taichi()

vec3 = ti.math.vec3
vec4 = ti.math.vec4

# ibuf header slots
(H_SUBSTEPS, H_ITERATIONS, H_MODE, H_NC, H_NE, H_NB, H_NF, H_NR, H_NK, H_EDGES, H_FACES,
 H_TETHER, H_PROXY_IDX, H_ROOTS, H_INV_MASS, H_EDGE_DATA, H_TETHER_LEN, H_PROXY_W,
 H_LAMBDA, H_ROT, H_TRANS, H_CACHE, H_PROXY_DEN, H_NJ, H_DEVIATION) = range(25)
H_COUNT = 25
#: a bound on |grad| of the trilinear grid SDF (sqrt(3) for samples of a 1-Lipschitz field, plus
#: slack for the approximate far field): a point that moved less than (d - margin) / LIPSCHITZ
#: since it was last found d away from the head cannot touch it, so its lookup is skipped
LIPSCHITZ = 2.0
#: squared lengths below SLACK x a squared limit are certainly under the limit (the square root and
#: its float rounding, ~1e-7, cannot take them over): tests that skip a square root use it
SLACK = 0.9999

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
def solve_distance(xb: ti.template(), fb: ti.template(), a, b, od, first):
    """XPBD distance constraint; od: offset of its record (see the module docstring) in fb;
    first: the substep's first sweep, whose multiplier is 0 (not read: see `simulate_frame`).

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
                for e in range(ne + nb):  # stretch, then bending (adjacent tables)
                    solve_distance(xb, fb, ib[o_edge + 2 * e], ib[o_edge + 2 * e + 1],
                                   o_edata + 8 * e, first)
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
                if mode > 0:
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
                                hit = posed_sdf(sdf, skin, fb, p, q1, rs, o_rot, o_trans, s, nj, origin, inv_h,
                                                skin_origin, skin_inv_h, ti.math.inf)
                                fb[o_cache + 3 * i] = q1[0]
                                fb[o_cache + 3 * i + 1] = q1[1]
                                fb[o_cache + 3 * i + 2] = q1[2]
                                fb[o_cdist + i] = hit[0] - LIPSCHITZ * fb[o_dev + s]
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


class PreviousPackedModel:
    """The model's tables packed into the kernel's buffers (layout in `_kernels`' docstring),
    with room for up to `substeps` substeps per frame."""

    def __init__(self, model: CageModel, substeps: int, skin: HeadSkin):
        K = sys.modules[__name__]

        m = model
        c, r = m.num_vertices, len(m.roots)
        e, b, f = len(m.edges), len(m.bend_pairs), len(m.faces)
        k = m.proxy_index.shape[1]
        ints = [m.edges.ravel(), m.bend_pairs.ravel(), m.faces.ravel(), m.tether_roots,
                m.proxy_index.ravel(), m.roots]
        ioff = np.cumsum([K.H_COUNT] + [len(a) for a in ints])
        # inv_mass padded so the 8-float constraint records start on a 32-byte boundary
        pad = -(K.FP_COUNT + c) % 8
        floats = [np.r_[m.inv_mass, np.zeros(pad)], np.zeros(8 * e), np.zeros(8 * b), m.tether_lengths,
                  m.proxy_weight.ravel(), np.zeros(1 + 2 * c), np.zeros(9 * JMAX * substeps),
                  np.zeros(3 * JMAX * substeps), np.zeros(4 * c), proxy_denominators(m),
                  np.zeros(substeps)]
        foff = np.cumsum([K.FP_COUNT] + [len(a) for a in floats])
        header = np.zeros(K.H_COUNT, np.int64)
        header[[K.H_NC, K.H_NE, K.H_NB, K.H_NF, K.H_NR, K.H_NK]] = [c, e, b, f, r, k]
        # bend pairs and their records follow the edges' (one loop sweeps both): no slots of their own
        header[[K.H_EDGES, K.H_FACES, K.H_TETHER, K.H_PROXY_IDX, K.H_ROOTS]] = ioff[[0, 2, 3, 4, 5]]
        header[[K.H_INV_MASS, K.H_EDGE_DATA, K.H_TETHER_LEN, K.H_PROXY_W, K.H_LAMBDA, K.H_ROT,
                K.H_TRANS, K.H_CACHE, K.H_PROXY_DEN, K.H_DEVIATION]] = foff[[0, 1, 3, 4, 5, 6, 7, 8, 9, 10]]
        header[K.H_SUBSTEPS] = substeps
        header[K.H_NJ] = len(skin.joints)
        self.ibuf = np.concatenate([header] + ints).astype(np.int32)
        self.fbuf = np.concatenate([np.zeros(K.FP_COUNT)] + floats).astype(np.float32)
        self.xbuf = np.zeros((5 * c + 2 * r, 3), np.float32)
        self.edge_data = self.fbuf[foff[1]:foff[2]].reshape(e, 8)
        self.bend_data = self.fbuf[foff[2]:foff[3]].reshape(b, 8)
        self.rot_slice = slice(int(foff[6]), int(foff[7]))
        self.trans_slice = slice(int(foff[7]), int(foff[8]))
        self.dev_slice = slice(int(foff[10]), int(foff[11]))
        # A zero cached distance makes every vertex's first collision test a real lookup.
        self.c, self.r, self.substeps = c, r, substeps
        self.model, self.skin = m, skin
        #: the frame kernel's launch on these buffers (bound on the first step)
        self.launch: BoundLaunch | None = None

    def set_time_step(self, config: SimConfig, dt: float, substeps: int) -> None:
        """Fill the parameters and the per-constraint data that depend on the substep length."""
        K = sys.modules[__name__]

        m = self.model
        h2 = (dt / substeps) ** 2
        self.fbuf[:K.FP_COUNT] = frame_params(m, config, dt, substeps, self.skin)
        self.ibuf[K.H_SUBSTEPS] = substeps
        w = m.inv_mass.astype(np.float64)
        for data, pairs, rest, compliance in (
                (self.edge_data, m.edges, m.edge_lengths, config.compliance_stretch),
                (self.bend_data, m.bend_pairs, m.bend_lengths, config.compliance_bending)):
            wa, wb = w[pairs[:, 0]], w[pairs[:, 1]]
            alpha = compliance / h2
            denom = wa + wb + alpha
            # two kinematic ends with zero compliance: the constraint cannot move anything
            k = np.divide(1.0, denom, out=np.zeros_like(denom), where=denom > 0)
            data[:, :6] = np.stack([rest, k, wa * k, wb * k, np.zeros_like(k), np.full_like(k, alpha)],
                                   axis=1)


class PreviousSolver(XPBDSolver):
    """`XPBDSolver` on the previous kernel and packing."""

    def step(self, state_in: CageState, state_out: CageState, frame_in: HeadFrame,
             frame_out: HeadFrame, dt: float) -> None:
        """Advance state_in by dt seconds (head moving from frame_in to frame_out) into
        state_out. state_in is not modified; state_out may be the same object."""
        m, cfg = self.model, self.config
        check_step_inputs(m, state_in, frame_in, frame_out, dt)
        if cfg.static:
            t = frame_out.transform
            x = (m.rest_positions.astype(np.float64) @ t[:3, :3].T + t[:3, 3]).astype(np.float32)
            x[m.roots] = frame_out.root_positions
            v = ((x - state_in.positions) / np.float32(dt)).astype(np.float32)
            state_out.positions, state_out.velocities = x, v
            return
        _kernels = sys.modules[__name__]

        n_sub = cfg.substeps_for(dt)
        if self._packed is None or self._packed.substeps < n_sub:
            self._packed = PreviousPackedModel(m, n_sub, self.skin)
            self._packed.ibuf[_kernels.H_ITERATIONS] = cfg.iterations
            self._packed.ibuf[_kernels.H_MODE] = MODE_CODES[cfg.collision]
            self._dt = None
        p = self._packed
        if self._dt != dt:
            p.set_time_step(cfg, dt, n_sub)
            self._dt = dt
        c, r = p.c, p.r
        p.xbuf[:c] = state_in.positions
        p.xbuf[c:2 * c] = state_in.velocities
        p.xbuf[5 * c:5 * c + r] = frame_in.root_positions
        p.xbuf[5 * c + r:5 * c + 2 * r] = frame_out.root_positions
        nj = skin_joints(self.skin, frame_in, frame_out)
        p.ibuf[_kernels.H_NJ] = nj
        rotations, translations = joint_substep_transforms(frame_in, frame_out, n_sub, nj)
        p.fbuf[p.rot_slice][:9 * JMAX * n_sub] = rotations.ravel()
        p.fbuf[p.trans_slice][:3 * JMAX * n_sub] = translations.ravel()
        arrays = (p.xbuf, p.ibuf, p.fbuf, m.sdf.values_grad, self.skin.weights)
        if p.launch is None or not p.launch.binds(*arrays):  # a model or skin given new grids
            p.launch = BoundLaunch(_kernels.simulate_frame, *arrays)
        p.launch()
        state_out.positions = p.xbuf[:c].copy()
        state_out.velocities = p.xbuf[c:2 * c].copy()
