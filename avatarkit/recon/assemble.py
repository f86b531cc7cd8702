"""Assembly (issue 8 items 7 and 8): rig the bald Gaussians, then fit the hair and head together.

Rigging (item 7, `rig_bald`): every bald Gaussian is bound to a triangle of the fitted rest head
(`TriangleBinding.bind`): the triangle it was sampled on when it carries a `binding` extra (the
built-in lifter), else its nearest triangle, with two part rules: a Gaussian within
`EYE_SNAP` of an eyeball rides the eyeball (never an eyelid, so it turns with the gaze), and one
whose nearest triangle borders the mouth interior rides that region's nearest triangle when it
lies behind the lips.

Assembly (item 8, the paper's L_geo with a differentiable proxy for its render term).
Optimised jointly with torch autograd (L-BFGS, float64), in three rounds:

- variables: an offset per hair Gaussian centre (N, 3) and a change of the head's first
  `shape_components` identity coefficients (the template: all 8; FLAME: 20);
- collision: sum of relu(margin - d_i)^2 over the hair, where d_i is the signed distance of
  hair centre i to the head of the current shape, linearised per round: the nearest head
  triangle and the barycentric point on it are found on the round's mesh, and
  d_i = n_f . (x_i - q_i(shape)) with q_i moving with the shape blendshapes;
- render proxy, for the hair the camera saw (`seen` extra): the squared image distance of each
  centre's projection from where it started (in inter-ocular distances), so hair may slide
  along its camera ray (in depth, which one photo does not fix) but not across the photo;
  unseen hair: a weak pull to its start (metres);
- head: the fit's landmark term (the head's landmark vertices keep projecting onto the
  detected 2D landmarks, so the bald render stays on the face in the photo) plus a prior on
  the shape change (the adjustment stays small).

After the rounds, a hard pass guarantees the result: any hair centre still closer than
margin / 2 to the final head (exact point-triangle distance, signed by the side of the closest
feature's angle-weighted pseudo-normal) is moved out along that normal
to the margin. The bald Gaussians keep their triangle-local values and follow the new shape
(GaussianAvatars' T_l2g). `refine_colours` then matches the input-view render to the photo
(inside the head's pixels) by a few rounds of residual back-projection onto the Gaussians the
camera sees.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.fit import HeadFit, _CV, torch_single_thread
from avatarkit.recon.image_sampling import sample_image
from avatarkit.recon.mesh_distance import (closest_points, face_normals, feature_normals, inside_by_feature,
                                           signed_distance)
from avatarkit.rig.binding import TriangleBinding

#: a Gaussian within this distance (metres) of an eyeball's surface rides the eyeball
EYE_SNAP = 0.002
#: hair clearance above the head after assembly (metres)
HAIR_MARGIN = 0.0015
#: hair farther than this (metres, by the screening SDF) from the head skips the exact tests
SCREEN_REACH = 0.008
#: weights of the assembly terms
W_COLLISION = 1.0 / 0.001 ** 2     # a 1 mm violation costs as much as 1 IOD^2 of image motion
W_IMAGE = 1.0
W_ANCHOR = 1.0 / 0.01 ** 2         # unseen hair: a 1 cm move costs 1
W_LANDMARKS = 1.0
W_SHAPE = 0.05


# ---------------------------------------------------------------------------------------------
# rigging

def rig_bald(bald: GaussianSet, fit: HeadFit, vertices: np.ndarray | None = None) -> TriangleBinding:
    """Bind the bald Gaussians to the rest head (see the module docstring). Returns the binding;
    its `local` set keeps the Gaussians' extras (minus `binding`)."""
    model = fit.model
    v = np.asarray(fit.rest_vertices if vertices is None else vertices, np.float64)
    faces = model.faces
    if "binding" in bald.extras:
        ids = np.asarray(bald.extras["binding"]).astype(np.int64)
        if len(ids) and (ids.min() < 0 or ids.max() >= len(faces)):
            raise InputError(f"bald Gaussians are bound to faces outside 0..{len(faces) - 1}")
        return TriangleBinding.bind(bald, v, faces, face_ids=ids)
    ids, _, _, dist = closest_points(bald.means, v, faces)
    if "eyes" in model.regions:
        eye_faces = np.flatnonzero(model.region_mask("eyes")[faces].sum(axis=1) >= 2)
        if len(eye_faces):
            from avatarkit.rig.nearest import nearest_faces

            eids, edist = nearest_faces(bald.means, v, faces[eye_faces])
            snap = edist <= np.minimum(dist + EYE_SNAP, EYE_SNAP * 2)
            ids[snap] = eye_faces[eids[snap]]
    if "mouth_interior" in model.regions:
        mouth_faces = np.flatnonzero(model.region_mask("mouth_interior")[faces].sum(axis=1) >= 2)
        lips = model.region_mask("lips") if "lips" in model.regions else np.zeros(model.num_vertices, bool)
        at_lips = lips[faces[ids]].any(axis=1)
        if len(mouth_faces) and at_lips.any():
            from avatarkit.rig.nearest import nearest_faces

            sel = np.flatnonzero(at_lips)
            mids, mdist = nearest_faces(bald.means[sel], v, faces[mouth_faces])
            # behind the lips' front (deeper than the lip triangle's plane): the mouth
            normals = face_normals(v, faces)[ids[sel]]
            centroid = v[faces[ids[sel]]].mean(axis=1)
            behind = np.einsum("ij,ij->i", bald.means[sel] - centroid, normals) < 0
            take = behind & (mdist <= dist[sel] + EYE_SNAP)
            ids[sel[take]] = mouth_faces[mids[take]]
    return TriangleBinding.bind(bald, v, faces, face_ids=ids)


# ---------------------------------------------------------------------------------------------
# assembly

@dataclass(eq=False)
class AssemblyResult:
    """hair: assembled hair (rest frame); shape: (S,) final identity coefficients; fit: the
    HeadFit with that shape; bald: the bald Gaussians posed on the final rest head (with their
    `binding` extra); binding: their TriangleBinding on it; report: figures (metres, counts)."""

    hair: GaussianSet
    shape: np.ndarray
    fit: HeadFit
    bald: GaussianSet
    binding: TriangleBinding
    report: dict = field(default_factory=dict)


def assemble(fit: HeadFit, binding: TriangleBinding, hair: GaussianSet, analysis, *,
             margin: float | None = None, rounds: int = 3, iterations: int = 25,
             shape_components: int | None = None, adjust_shape: bool = True,
             screen=None) -> AssemblyResult:
    """Push the hair out of the head with a small joint head-shape adjustment (module docstring).

    binding: the bald Gaussians bound to `fit.rest_vertices` (`rig_bald`); hair: its `seen`
    extra (uint8, optional) marks hair the camera saw; analysis: the `PortraitAnalysis`
    (landmarks for the head's image term). screen: a `HeadSDF` of about this head (a coarse
    one is built if not given) that spares the exact distance test for hair far from it."""
    margin = HAIR_MARGIN if margin is None else margin
    import torch

    from avatarkit.head.lbs import axis_angle_to_matrix_torch
    from avatarkit.lbfgs import LBFGS
    from avatarkit.recon.fit import FLAME_SHAPE_COMPONENTS, _landmark_targets

    model = fit.model
    faces = np.asarray(model.faces)
    S = model.num_shape
    if shape_components is None:
        k = S if model.name == "template" else min(S, FLAME_SHAPE_COMPONENTS)
    else:
        k = max(0, min(S, int(shape_components)))
    if not adjust_shape:
        k = 0
    shape0 = np.asarray(fit.shape, np.float64).copy()
    report: dict = {"hair": len(hair)}
    if len(hair) == 0:
        bald = binding.to_world(fit.rest_vertices)
        return AssemblyResult(hair, shape0.astype(np.float32), fit, bald, binding,
                              {**report, "inside_before": 0, "inside_after": 0})
    if screen is None:
        from avatarkit.head.sdf_grid import HeadSDF

        screen = HeadSDF.build(fit.rest_vertices, faces, spacing=0.004)

    x0 = hair.means.astype(np.float64)
    sd0 = signed_distance(x0, fit.rest_vertices, faces, screen)
    report["inside_before"] = int((sd0 < 0).sum())
    report["closer_than_margin_before"] = int((sd0 < margin).sum())

    cam = fit.camera
    w, h, f = cam.width, cam.height, cam.fx
    iod = max(analysis.eye_distance, 1e-6)
    seen = np.asarray(hair.extras.get("seen", np.ones(len(hair))), bool)
    names, targets, weights = _landmark_targets(analysis)
    lm_ids = np.array([fit.landmarks[n] for n in names])

    v_template = model.v_template.astype(np.float64)
    basis_all = model.shapedirs.astype(np.float64)                       # (V, 3, S)
    rest_base = v_template + basis_all @ shape0                          # (V, 3)
    t_rest = torch.from_numpy(rest_base)
    t_basis = torch.from_numpy(np.ascontiguousarray(basis_all[:, :, :k]))
    rot = axis_angle_to_matrix_torch(torch.from_numpy(np.asarray(fit.rotation, np.float64)))
    trans = torch.from_numpy(np.asarray(fit.translation, np.float64))
    cv = torch.from_numpy(_CV)

    def project(p):
        c = (p @ rot.T + trans) @ cv.T
        z = c[:, 2].clamp_min(1e-3)
        return torch.stack([f * c[:, 0] / z + w / 2, f * c[:, 1] / z + h / 2], dim=1)

    tx0 = torch.from_numpy(x0)
    px0 = project(tx0)
    t_seen = torch.from_numpy(seen)
    t_lm = torch.from_numpy(targets)
    t_w = torch.from_numpy(weights)
    t_lm_ids = torch.from_numpy(lm_ids)
    offset = torch.zeros_like(tx0, requires_grad=True)
    dshape = torch.zeros(k, dtype=torch.float64, requires_grad=True)
    n_all = len(x0)

    def head_vertices():
        return t_rest + t_basis @ dshape if k else t_rest

    shape_now = shape0.copy()
    for _ in range(rounds):
        with torch.no_grad():
            cur_v = head_vertices().numpy()
            cur_x = (tx0 + offset).numpy()
        # only hair near the head can collide this round (the head moves by millimetres)
        near = np.flatnonzero(screen.query(cur_x)[0] < SCREEN_REACH)
        ids, bary, closest, dist = closest_points(cur_x[near], cur_v, faces)
        normals = face_normals(cur_v, faces)[ids]
        # the linearised distance n . (x - q) must carry the exact inside test's sign
        inside = inside_by_feature(cur_x[near], closest, ids, bary, cur_v, faces)
        along = np.einsum("ij,ij->i", cur_x[near] - closest, normals)
        flip = ((along < 0) != inside) & (np.abs(along) > 1e-9)
        normals[flip] *= -1
        t_near = torch.from_numpy(near)
        t_ids = torch.from_numpy(faces[ids].astype(np.int64))         # (M, 3)
        t_bary = torch.from_numpy(bary)
        t_n = torch.from_numpy(normals)

        def closure():
            opt.zero_grad()
            hv = head_vertices()
            x = tx0 + offset
            q = (hv[t_ids] * t_bary[:, :, None]).sum(1)
            d = ((x[t_near] - q) * t_n).sum(1)
            col = W_COLLISION * torch.relu(margin - d).pow(2).sum() / n_all
            moved = ((project(x) - px0) / iod).pow(2).sum(1)
            img = W_IMAGE * (moved * t_seen).sum() / n_all
            anchor = W_ANCHOR * (offset.pow(2).sum(1) * ~t_seen).sum() / n_all
            loss = col + img + anchor
            if k:
                lpx = project(hv[t_lm_ids])
                loss = loss + W_LANDMARKS * (t_w * ((lpx - t_lm) ** 2).sum(1)).sum() / iod ** 2
                loss = loss + W_SHAPE * dshape.pow(2).sum()
            loss.backward()
            return loss

        params = [offset, dshape] if k else [offset]
        opt = LBFGS(params, lr=1.0, max_iter=iterations, line_search_fn="strong_wolfe",
                                tolerance_grad=1e-12, tolerance_change=1e-14, history_size=10)
        with torch_single_thread():
            opt.step(closure)
    with torch.no_grad():
        x = (tx0 + offset).numpy()
        if k:
            shape_now[:k] += dshape.numpy()

    new_fit = fit.with_shape(shape_now.astype(np.float32)) if k else fit
    v_final = np.asarray(new_fit.rest_vertices, np.float64)
    x = push_out(x, v_final, faces, margin, screen)
    sd = signed_distance(x, v_final, faces, screen)
    report.update(inside_after=int((sd < 0).sum()), closer_than_half_margin=int((sd < margin / 2).sum()),
                  mean_move_mm=round(float(np.linalg.norm(x - x0, axis=1).mean() * 1000), 3),
                  max_move_mm=round(float(np.linalg.norm(x - x0, axis=1).max() * 1000), 3),
                  shape_change=[round(float(a), 4) for a in (shape_now - shape0)[:k]])
    new_hair = hair.replace(means=x)
    posed_binding = TriangleBinding(binding.faces, binding.face_ids, binding.local, binding.sh_frame)
    bald = posed_binding.to_world(v_final)
    return AssemblyResult(new_hair, shape_now.astype(np.float32), new_fit, bald, posed_binding, report)


def push_out(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, margin: float,
             screen=None, rounds: int = 4) -> np.ndarray:
    """Points (N, 3) closer than margin / 2 to the head (or inside it) moved out along the
    closest feature's pseudo-normal to `margin` outside. Repeated (a move can land near another
    part of the surface) until none is left or `rounds` are done; points still too close then
    walk away from the head's centre in steps of `margin` until clear. screen: see
    `signed_distance`."""
    x = np.asarray(points, np.float64).copy()
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    for _ in range(rounds):
        sd = signed_distance(x, v, f, screen)
        bad = np.flatnonzero(sd < margin / 2)
        if len(bad) == 0:
            return x
        ids, bary, closest, _ = closest_points(x[bad], v, f)
        x[bad] = closest + feature_normals(ids, bary, v, f) * margin
    # what is still too close sits in a crevice narrower than the margin (behind an ear, say),
    # where the normals of its two walls send it back and forth: walk it straight away from
    # the head's centre until it is clear
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    bad = np.flatnonzero(signed_distance(x, v, f, screen) < margin / 2)
    for _ in range(64):
        if len(bad) == 0:
            break
        out = x[bad] - centre
        x[bad] += margin * out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
        bad = bad[signed_distance(x[bad], v, f, screen) < margin / 2]
    return x


# ---------------------------------------------------------------------------------------------
# colours against the photo

_BLUR_SIGMAS = (0.0, 1.0, 2.0, 4.0)


def footprint_residuals(rendered: np.ndarray, target: np.ndarray, mask: np.ndarray, px: np.ndarray,
                        radii: np.ndarray | None, level: np.ndarray | None = None):
    """The residual target - rendered (H, W, 3) inside mask (H, W) at k Gaussians' projections
    px (k, 2): (k, 3) float32, each Gaussian's averaged over about its own footprint (the residual
    blurred at the `_BLUR_SIGMAS` step nearest a third of its radius, radii (k,) pixels). This is
    SIRT's weighted mean of the residual a Gaussian contributes to, which keeps the colour
    refinements from amplifying detail finer than the splats can show. Returns (residuals,
    level): pass level back on the next round (the radii are then not needed)."""
    import cv2

    if level is None:
        level = np.argmin(np.abs(np.asarray(radii)[:, None] / 3.0 - np.array(_BLUR_SIGMAS)[None]), axis=1)
    err = (target - rendered) * mask[:, :, None]
    delta = np.zeros((len(px), 3), np.float32)
    for j, sg in enumerate(_BLUR_SIGMAS):
        sel = level == j
        if sel.any():
            e = cv2.GaussianBlur(err, (0, 0), sg) if sg > 0 else err
            delta[sel] = sample_image(e, px[sel])
    return delta, level


def refine_colours(gaussians: GaussianSet, camera, photo: np.ndarray, mask: np.ndarray,
                   iterations: int = 4, step: float = 1.0, min_weight: float = 0.05,
                   max_side: int = 1024) -> tuple[GaussianSet, dict]:
    """Match the render of `gaussians` from `camera` to `photo` (H, W, 3) uint8 inside `mask`
    (H, W) bool. Each round renders, takes the residual photo - render, and adds `step` times
    the residual at each Gaussian's projection to its DC colour (clamped to [0, 1]), for the
    Gaussians that show: whose blending weight summed over the mask's pixels
    (`label_lifting.accumulate_weights`, the renderer's compositing) is at least `min_weight`
    pixels. Where the Gaussians covering a pixel have weights summing to its alpha (~1 inside
    the head), adding the same residual to each corrects that pixel exactly (a Jacobi step of
    the linear least-squares problem render(colours) = photo); the rounds mop up the rest.
    Returns the recoloured set and the PSNR inside the mask before and after."""
    import cv2

    from avatarkit.recon.label_lifting import accumulate_weights
    from avatarkit.render import render

    h, w = photo.shape[:2]
    k = min(1.0, max_side / max(h, w))
    cam = camera if k >= 1 else camera.with_size(max(1, round(w * k)), max(1, round(h * k)))
    target = photo.astype(np.float32) / 255.0
    m = np.asarray(mask, bool)
    if k < 1:
        target = cv2.resize(target, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        m = cv2.resize(m.astype(np.uint8), (cam.width, cam.height), interpolation=cv2.INTER_NEAREST).astype(bool)
    bg = np.median(target[~m], axis=0) if (~m).any() else np.zeros(3, np.float32)
    rgb = gaussians.colors.astype(np.float32)
    gs = gaussians
    px, _ = cam.project(gs.means)
    shows = accumulate_weights(gs, cam, m.astype(np.int32), 2)[:, 1] >= min_weight
    shows &= np.isfinite(px).all(axis=1)
    history = []
    level = None
    for it in range(iterations + 1):
        r = render(gs, cam, background=bg)
        history.append(psnr(r.rgb, target, m))
        if it == iterations or not shows.any():
            break
        delta, level = footprint_residuals(r.rgb, target, m, px[shows], r.meta["radii"][shows], level)
        rgb[shows] = np.clip(rgb[shows] + step * delta, 0.0, 1.0)
        gs = gs.with_colors(rgb)
    return gs, {"psnr_before": round(float(history[0]), 3), "psnr_after": round(float(history[-1]), 3),
                "recoloured": int(shows.sum())}


def psnr(image: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR (dB) of two float images in [0, 1] (H, W, 3), over the pixels of `mask` (H, W)."""
    d = (np.clip(image, 0, 1) - np.clip(target, 0, 1)) ** 2
    if mask is not None:
        d = d[np.asarray(mask, bool)]
    mse = float(np.mean(d)) if d.size else 0.0
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


__all__ = ["AssemblyResult", "EYE_SNAP", "HAIR_MARGIN", "assemble", "psnr", "push_out", "refine_colours",
           "rig_bald"]
