"""`XPBDSolver`: one frame of the paper's Algorithm 1 (cage deformation by PBD, section 3.3).

Per frame, for each of n substeps of h = dt / n (n = `substeps`, more if h would exceed
`max_substep`):
  1. kinematic roots at their targets, linearly interpolated between the previous and the
     current frame; free vertices predicted with gravity (v += h g, x += h v);
  2. proxy points from the predicted positions (each vertex's nearest hair Gaussian, rebuilt
     through its MVC weights), kept as offsets from their vertex;
  3. `iterations` Gauss-Seidel sweeps of XPBD (Macklin, Mueller and Chentanez 2016) over
     stretch, bending, volume (linearised at the predicted positions), tether and collision
     constraints, multipliers reset per substep;
     collision tests the proxy (or the vertex) against the head SDF placed by this substep's
     head joint transform (rotation slerped, translation interpolated), and moves the vertex
     (in every k-th substep, `SimConfig.collision_every`, and the frame's last);
  4. v = (x - x_prev) / h, then damping and a speed clamp.
All substeps of a frame run in one Taichi launch (`_kernels.simulate_frame`).
In `static` mode the cage moves rigidly with the head joint (roots still on their targets).
"""
from __future__ import annotations

import math

import numpy as np

from avatarkit.errors import InputError
from avatarkit.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from avatarkit.sim.config import SimConfig
from avatarkit.sim._launch import BoundLaunch
from avatarkit.sim._skin_math import JMAX
from avatarkit.sim.model import CageModel, CageState, HeadFrame
from avatarkit.sim.sdf import HeadSkin

MODE_CODES = {"none": 0, "vertex": 1, "proxy": 2}


def substep_transforms(t_in: np.ndarray, t_out: np.ndarray, substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """Head transforms at the end of each substep: rotations (S, 3, 3), translations (S, 3).
    The rotation turns at a constant rate about the fixed axis of R_out R_in^T (slerp)."""
    r_in, r_out = t_in[:3, :3], t_out[:3, :3]
    frac = np.arange(1, substeps + 1, dtype=np.float64) / substeps
    if np.array_equal(r_in, r_out):  # a still head: skip the (slow, small) slerp
        rotations = np.broadcast_to(r_out, (substeps, 3, 3))
    else:
        rel = r_out @ r_in.T
        two_sin = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
        two_cos = np.trace(rel) - 1.0
        s = float(np.linalg.norm(two_sin))
        if two_cos > 0.0 and s > 0.0:
            # a turn under 90 degrees a frame (always, in practice): axis and angle straight from
            # the skew part, Rodrigues per substep; this runs every frame and scipy's
            # Rotation costs ~0.1 ms here
            axis = two_sin / s
            angles = frac * np.arctan2(s, two_cos)
            k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
            rotations = (np.eye(3) + np.sin(angles)[:, None, None] * k
                         + (1.0 - np.cos(angles))[:, None, None] * (k @ k)) @ r_in
        else:  # near a half turn the skew part loses the axis
            axis_angle = matrix_to_axis_angle(rel)
            rotations = axis_angle_to_matrix(frac[:, None] * axis_angle) @ r_in
    translations = t_in[:3, 3] + frac[:, None] * (t_out[:3, 3] - t_in[:3, 3])
    return rotations, translations


def frame_params(model: CageModel, config: SimConfig, dt: float, substeps: int,
                 skin: HeadSkin) -> np.ndarray:
    """The float parameters of one frame (slots `_kernels.FP_*`)."""
    h = dt / substeps
    h2 = h * h
    sdf = model.sdf
    return np.array([
        h, config.compliance_stretch / h2, config.compliance_bending / h2,
        config.compliance_volume / h2, config.compliance_tether / h2,
        config.compliance_collision / h2, np.exp(-config.damping * h), config.collision_margin,
        *config.gravity, config.max_speed, model.rest_volume, *sdf.origin, 1.0 / sdf.spacing,
        *skin.origin, 1.0 / skin.spacing, *deviation_box(sdf)[0], *deviation_box(sdf)[1],
    ], dtype=np.float32)


def deviation_box(sdf) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) of the box where `skin_deviation`'s bound holds: the SDF grid grown by
    DEVIATION_REACH."""
    lo = sdf.origin - DEVIATION_REACH
    hi = sdf.origin + sdf.spacing * (np.asarray(sdf.shape) - 1) + DEVIATION_REACH
    return lo, hi


def proxy_denominators(model: CageModel) -> np.ndarray:
    """(C,) sum_k w_k^2 / m_k over each proxy's cage vertices: |grad C|^2 weighted by inverse
    mass, the denominator of the proxy collision's XPBD step. 0 (no constraint) for a root's
    proxy: that hair lies on the scalp, placed by the roots; pushing it out through the few free
    vertices it also depends on would throw them (a root's proxy is in contact all the time)."""
    inv_mass = model.inv_mass.astype(np.float64)
    den = np.sum(model.proxy_weight.astype(np.float64) ** 2 * inv_mass[model.proxy_index], axis=1)
    return np.where(inv_mass > 0, den, 0.0)


def joint_substep_transforms(frame_in: HeadFrame, frame_out: HeadFrame, substeps: int,
                             joints: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (S, JMAX, 3, 3) and translations (S, JMAX, 3) of the first `joints` joints at
    the end of each substep (the rest zero); joint 0 is the head joint. Frames without joint
    transforms have the head joint only (joints must then be 1).

    `substep_transforms` of every joint at once, with the per-substep rotation expanded as
    R_s = R_in + sin(a_s) (K R_in) + (1 - cos(a_s)) (K^2 R_in): elementwise arrays, no stack
    of 3x3 matrix products (numpy hands each of those to BLAS on its own, ~2 us apiece: this
    runs every frame). A joint whose turn Rodrigues cannot take from the skew part (a still
    joint, a half turn) goes through `substep_transforms` itself."""
    a, b = _joint_stack(frame_in, joints), _joint_stack(frame_out, joints)
    rot = np.zeros((substeps, JMAX, 3, 3))
    trans = np.zeros((substeps, JMAX, 3))
    frac = np.arange(1, substeps + 1, dtype=np.float64) / substeps
    r_in, r_out = a[:, :3, :3], b[:, :3, :3]
    rel = np.einsum("jab,jcb->jac", r_out, r_in)                               # R_out R_in^T
    flat = rel.reshape(joints, 9)
    # the skew part (R21 - R12, R02 - R20, R10 - R01), in C order: einsum sums in another order
    # for a transposed layout, and the bits must not depend on it
    two_sin = np.ascontiguousarray(flat[:, [7, 2, 3]] - flat[:, [5, 6, 1]])
    two_cos = flat[:, 0] + flat[:, 4] + flat[:, 8] - 1.0
    sin_norm = np.sqrt(np.einsum("ja,ja->j", two_sin, two_sin))
    still = (r_in == r_out).all(axis=(1, 2))
    fast = (two_cos > 0.0) & (sin_norm > 0.0) & ~still
    every = bool(fast.all())  # the usual case: no boolean selections (each a numpy call)
    if every or fast.any():
        sel = slice(None) if every else fast
        axis = two_sin[sel] / sin_norm[sel, None]
        angles = frac[:, None] * np.arctan2(sin_norm[sel], two_cos[sel])     # (S, Jf)
        k = np.zeros((len(axis), 9))
        # K = [[0, -z, y], [z, 0, -x], [-y, x, 0]] (flat slots 1, 2, 5, 3, 6, 7)
        k[:, [1, 2, 5, 3, 6, 7]] = axis[:, [2, 1, 0, 2, 1, 0]] * _SKEW_SIGNS
        k = k.reshape(-1, 3, 3)
        r_fast = np.ascontiguousarray(r_in) if every else r_in[fast]
        kr = np.einsum("jab,jbc->jac", k, r_fast)
        kkr = np.einsum("jab,jbc->jac", k, kr)
        rot[:, slice(0, joints) if every else np.flatnonzero(fast)] = (
            r_fast + np.sin(angles)[..., None, None] * kr + (1.0 - np.cos(angles))[..., None, None] * kkr)
    if not every:
        # a still joint (the jaw and neck of most frames) is R_out at every substep, as
        # `substep_transforms` gives it, without the call
        rot[:, np.flatnonzero(still)] = r_out[still]
        for j in np.flatnonzero(~fast & ~still):
            rot[:, j] = substep_transforms(a[j], b[j], substeps)[0]
    trans[:, :joints] = a[None, :, :3, 3] + frac[:, None, None] * (b[:, :3, 3] - a[:, :3, 3])[None]
    return rot, trans


_SKEW_SIGNS = np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0])


def _joint_stack(frame: HeadFrame, joints: int) -> np.ndarray:
    """(joints, 4, 4): the head transform, then joint_transforms[1:joints]."""
    if joints == 1:
        return frame.transform[None].copy()
    out = frame.joint_transforms[:joints].copy()
    out[0] = frame.transform
    return out


def skin_joints(skin: HeadSkin, frame_in: HeadFrame, frame_out: HeadFrame) -> int:
    """How many of the skin's joints a step can follow: all when both frames carry their
    transforms, else the head joint only."""
    n = len(skin.joints)
    for f in (frame_in, frame_out):
        if f.joint_transforms is None:
            return 1
        if len(f.joint_transforms) < n:
            raise InputError(f"head frame has {len(f.joint_transforms)} joint transforms, the "
                             f"skin {n} joints")
    return n


#: how far past the SDF grid `skin_deviation` bounds the deviation (hair hangs below the neck)
DEVIATION_REACH = 0.25


def skin_deviation(skin: HeadSkin, sdf, rotations: np.ndarray, translations: np.ndarray,
                   joints: int) -> np.ndarray:
    """(S,) per substep, a bound on |q - q1| where q1 = T_0^-1 x (head joint) and q is the rest
    point inverse LBS finds (x = sum_j w_j T_j q): |q1 - q| <= max_j |T_0^-1 T_j q - q|, an
    affine function's norm, so its maximum over a box (the SDF grid, grown by
    DEVIATION_REACH) is at a corner. 0 with the head joint alone. Lets the solver skip the
    skinning and SDF lookups of points provably far from the head. The solver's kernel computes
    the same per substep itself (`_kernels.simulate_frame`); this is its reference and the
    push-out's bound."""
    if joints <= 1:
        return np.zeros(len(rotations))
    lo, hi = deviation_box(sdf)
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
    r0, t0 = rotations[:, 0], translations[:, 0]
    rel_r = np.einsum("sba,sjbc->sjac", r0, rotations[:, 1:joints])             # R0^T Rj
    rel_t = np.einsum("sba,sjb->sja", r0, translations[:, 1:joints] - t0[:, None])  # R0^T (tj - t0)
    moved = np.einsum("sjac,kc->sjka", rel_r, corners) + (rel_t[:, :, None] - corners)
    return np.sqrt(np.einsum("sjka,sjka->sjk", moved, moved)).max(axis=(1, 2))


class PackedModel:
    """The model's tables packed into the kernel's buffers (layout in `_kernels`' docstring),
    with room for up to `substeps` substeps per frame."""

    def __init__(self, model: CageModel, substeps: int, skin: HeadSkin):
        from avatarkit.sim import _kernels as K

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
        from avatarkit.sim import _kernels as K

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


def check_step_inputs(model: CageModel, state_in: CageState, frame_in: HeadFrame,
                      frame_out: HeadFrame, dt: float) -> None:
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"time step must be > 0 seconds, got {dt}")
    if state_in.positions.shape != model.rest_positions.shape:
        raise InputError(f"state has {len(state_in.positions)} vertices, the cage "
                         f"{model.num_vertices}")
    for frame in (frame_in, frame_out):
        if frame.root_positions.shape != (len(model.roots), 3):
            raise InputError(f"head frame has {len(frame.root_positions)} root positions, "
                             f"the cage {len(model.roots)} roots")


class XPBDSolver:
    """Steps a `CageModel` with `SimConfig` settings; holds only scratch buffers between steps.
    skin: a `HeadSkin` so that collision follows the posed head's jaw and neck (frames then
    carry its joints' transforms); None: the rest head moved rigidly by the head joint."""

    def __init__(self, model: CageModel, config: SimConfig | None = None, skin: HeadSkin | None = None):
        self.model = model
        self.config = config or SimConfig()
        self.skin = skin or HeadSkin.rigid()
        self._packed: PackedModel | None = None
        self._dt: float | None = None

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
        from avatarkit.sim import _kernels

        n_sub = cfg.substeps_for(dt)
        if self._packed is None or self._packed.substeps < n_sub:
            self._packed = PackedModel(m, n_sub, self.skin)
            self._packed.ibuf[_kernels.H_ITERATIONS] = cfg.iterations
            self._packed.ibuf[_kernels.H_MODE] = MODE_CODES[cfg.collision]
            self._dt = None
        p = self._packed
        if self._dt != dt:
            p.set_time_step(cfg, dt, n_sub)
            p.ibuf[_kernels.H_COLLISION_EVERY] = cfg.collision_every(dt)
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
