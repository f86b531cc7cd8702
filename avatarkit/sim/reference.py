"""A slow, obvious numpy twin of `_kernels.simulate_frame`, used only by tests.

Same algorithm, same constraint order, one Python statement per constraint, float64.
"""
from __future__ import annotations

import numpy as np

from avatarkit.sim.config import SimConfig
from avatarkit.sim.model import CageModel, CageState, HeadFrame
from avatarkit.sim.sdf import HeadSkin
from avatarkit.sim.solver import (MODE_CODES, check_step_inputs, joint_substep_transforms,
                                  proxy_denominators, skin_joints)


def reference_step(model: CageModel, config: SimConfig, state: CageState, frame_in: HeadFrame,
                   frame_out: HeadFrame, dt: float, skin: HeadSkin | None = None) -> CageState:
    """One frame (all substeps) of XPBD; returns the new state (float64 arrays)."""
    check_step_inputs(model, state, frame_in, frame_out, dt)
    skin = skin or HeadSkin.rigid()
    m = model
    x = state.positions.astype(np.float64).copy()
    v = state.velocities.astype(np.float64).copy()
    w = m.inv_mass.astype(np.float64)
    n_sub = config.substeps_for(dt)
    h = dt / n_sub
    alpha = {k: getattr(config, f"compliance_{k}") / (h * h)
             for k in ("stretch", "bending", "volume", "tether", "collision")}
    damp = np.exp(-config.damping * h)
    g = np.asarray(config.gravity)
    mode = MODE_CODES[config.collision]
    every = config.collision_every(dt)  # collision in every k-th substep and the last
    nj = skin_joints(skin, frame_in, frame_out)
    rotations, translations = joint_substep_transforms(frame_in, frame_out, n_sub, nj)
    transforms = np.zeros((n_sub, nj, 4, 4))
    transforms[:, :, :3, :3] = rotations[:, :nj]
    transforms[:, :, :3, 3] = translations[:, :nj]
    transforms[:, :, 3, 3] = 1.0
    # the skin's weights as the kernel reads them: float32 grid, only its first nj joints
    skin_s = HeadSkin(skin.weights, skin.joints[:nj], skin.origin.astype(np.float32), skin.spacing)
    proxy_den = proxy_denominators(m)
    root_a = frame_in.root_positions.astype(np.float64)
    root_b = frame_out.root_positions.astype(np.float64)

    def distance(a, b, rest, lam, alpha_):
        d = x[a] - x[b]
        length = np.linalg.norm(d)
        if length <= 1e-9:
            return lam
        n = d / length
        dl = (rest - length - alpha_ * lam) / (w[a] + w[b] + alpha_)
        x[a] += w[a] * dl * n
        x[b] -= w[b] * dl * n
        return lam + dl

    for s in range(n_sub):
        frac = (s + 1) / n_sub
        x_prev = x.copy()
        free = w > 0
        v[free] += h * g
        x[free] += h * v[free]
        x[m.roots] = (1.0 - frac) * root_a + frac * root_b
        lam_e = np.zeros(len(m.edges))
        lam_b = np.zeros(len(m.bend_pairs))
        lam_v = 0.0
        lam_t = np.zeros(len(x))
        lam_c = np.zeros(len(x))
        use_collision = (s + 1) % every == 0 or s == n_sub - 1
        if len(m.faces):
            x0 = x.copy()
            p = x - x[m.faces[0, 0]]
            a, b, c = p[m.faces[:, 0]], p[m.faces[:, 1]], p[m.faces[:, 2]]
            volume0 = np.einsum("ij,ij->", a, np.cross(b, c)) / 6
            grad = np.zeros_like(x)
            np.add.at(grad, m.faces[:, 0], np.cross(b, c) / 6)
            np.add.at(grad, m.faces[:, 1], np.cross(c, a) / 6)
            np.add.at(grad, m.faces[:, 2], np.cross(a, b) / 6)
            denom = np.sum(w * np.sum(grad * grad, axis=1))
        for _ in range(config.iterations):
            for e, (a, b) in enumerate(m.edges):
                lam_e[e] = distance(a, b, m.edge_lengths[e], lam_e[e], alpha["stretch"])
            for e, (a, b) in enumerate(m.bend_pairs):
                lam_b[e] = distance(a, b, m.bend_lengths[e], lam_b[e], alpha["bending"])
            if len(m.faces):
                volume = volume0 + np.sum(grad * (x - x0))  # linearised (see _kernels)
                dl = (m.rest_volume - volume - alpha["volume"] * lam_v) / (denom + alpha["volume"] + 1e-20)
                lam_v += dl
                x += w[:, None] * dl * grad
            for i in range(len(x)):
                r = m.tether_roots[i]
                if r < 0 or w[i] == 0:
                    continue
                d = x[i] - x[r]
                length = np.linalg.norm(d)
                dl = (length - m.tether_lengths[i] - alpha["tether"] * lam_t[i]) / (w[i] + alpha["tether"])
                new = max(lam_t[i] + dl, 0.0)
                dl, lam_t[i] = new - lam_t[i], new
                if length > 1e-9:
                    x[i] -= w[i] * dl * d / length
            if mode == 0 or not use_collision:
                continue
            for i in range(len(x)):
                if mode == 2:  # the proxy, from the current cage; gradient w_k n for vertex k
                    idx, wk = m.proxy_index[i], m.proxy_weight[i].astype(np.float64)
                    den = proxy_den[i]
                    p = wk @ x[idx]
                else:
                    idx, wk, den, p = np.array([i]), np.ones(1), w[i], x[i]
                if den <= 0:
                    continue
                dist, normal = skin_s.query_posed(m.sdf, p[None], transforms[s])
                dl = (config.collision_margin - dist[0] - alpha["collision"] * lam_c[i]) / (den + alpha["collision"])
                new = max(lam_c[i] + dl, 0.0)
                dl, lam_c[i] = new - lam_c[i], new
                n = normal[0]
                for j, wj in zip(idx, wk):
                    x[j] += w[j] * wj * dl * n
        v = (x - x_prev) / h
        v[free] *= damp
        speed = np.linalg.norm(v, axis=1)
        fast = free & (speed > config.max_speed)
        v[fast] *= (config.max_speed / speed[fast])[:, None]
    return CageState(x, v)
