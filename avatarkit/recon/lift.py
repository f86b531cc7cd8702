"""Lifting (issue 8 item 5): the portrait -> a bald head and a hair volume of 3D Gaussians.

One interface, two lifters:

    result = lifter.lift(image, analysis, segmentation, bald, fit)   # -> LiftResult(bald, hair)

`BuiltinLifter` (offline, no learned model), in the rest head's frame (see `recon.fit`):

- bald: `n_bald` flat discs sampled on the fitted head's triangles (area-weighted, the face and
  eyes `face_density` times denser than the back of the head), lying in their triangle's plane,
  sized so neighbours overlap. Colour: the bald image sampled (bilinear) at each disc's
  projection where the disc is visible from the input camera (its depth within `DEPTH_TOL` of
  the renderer's depth map of the discs, facing the camera, and landing on skin in the bald
  image's labels; neck discs also on body pixels). Unseen discs get a screened harmonic fill
  on their k-nearest-neighbour graph: the colour of the nearest seen skin diffuses over the
  surface and fades to the skin model's mean colour a few centimetres away (the back of the
  head). Eyeballs: seen through the lids, the photo; elsewhere iris (the photo's colour at the
  eye landmarks) or sclera. Mouth interior: a dark red. Extras: `binding` (the sampled triangle,
  int32) and `part` (uint8: 0 skin, 1 eye, 2 mouth interior).
- hair: strands grown from roots on the fitted scalp, one Gaussian per 4 mm segment, thin and
  oriented along the strand (scale index 0 along it, 1 across, 2 along the surface normal).
  * shell thickness: along rays from the projected head centre, the gap between the head's
    projected silhouette and the outer edge of the hair mask, in metres at the head's depth,
    as a function of the ray's polar angle; a 3D point takes the thickness of the polar angle
    of its projection, which extrapolates the silhouette to the hidden back of the head;
  * growth: each strand keeps a random layer between `MARGIN` and that thickness above the
    scalp (signed distance of the rest head) while above the jaw, and falls freely below it.
    Where it is seen from the camera, it follows the 2D hair flow (the structure tensor of the
    hair pixels: the direction of least intensity change, coherence-weighted and smoothed)
    lifted to the head's tangent plane, and it stops when it leaves the hair mask. Where it is
    hidden (behind the head, or behind the neck and body), it is combed away from the crown
    and down, and stops at the hair's lowest extent in the photo (back-projected at the head's
    depth): hair that reaches below the chin in the photo falls down the back to that length;
  * colour: seen hair takes the photo's colour at its projection; hidden hair a random hair
    pixel from the same image rows (a height band); inner layers are slightly darker.
  Extras: `strand` (int32 strand id) and `seen` (uint8: 1 where the camera saw the segment).

`ImportLifter(head_splats, bald_splats)`: 3DGS PLYs from an image-to-3D lifter (FaceLift-style:
the photo lifted with hair, and the bald image lifted). The bald splats are aligned to the
fitted head by a similarity transform (trimmed ICP with scale, Umeyama, from four starting
orientations, against dense samples of the head's skin), the head splats move with them, and
hair = head splats not explained by the bald splats (farther than a few times the bald splats'
spacing from any of them, or of clearly another colour than the nearest ones). Bald splats far
from the head surface (stray floaters) are dropped. The 3D segmentation (item 6) cleans the hair.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.fit import HeadFit, project_mask
from avatarkit.rotations import matrix_to_quat

#: a disc counts as seen when it is this close (metres) behind the rendered depth
DEPTH_TOL = 0.004
#: and faces the camera at least this much (cosine)
MIN_FACING = 0.15
#: bald disc radius = COVERAGE x the radius that would tile its share of the surface
COVERAGE = 1.5
FLATNESS = 0.15
SCLERA_RGB = (0.86, 0.83, 0.8)
MOUTH_RGB = (0.32, 0.12, 0.12)
#: hair keeps at least this clearance (metres) above the scalp
MARGIN = 0.002
#: strand segment length (metres)
SEGMENT = 0.004
#: hair strand half-width and half-thickness (metres, 1 sigma)
HAIR_WIDTH = 0.0012
HAIR_THICKNESS = 0.0003
#: HAIR_WIDTH is for this many hair Gaussians; fewer get wider strands (up to 4x)
HAIR_REFERENCE_COUNT = 40_000
#: share of the hair budget kept for filling the photo's hair silhouette (`fill_coverage`)
FILL_SHARE = 0.1
#: hair pixels whose rendered alpha is below this get fill Gaussians
FILL_ALPHA = 0.9
#: the shell is never thicker than this (metres)
MAX_SHELL = 0.06
PART_SKIN, PART_EYE, PART_MOUTH = 0, 1, 2


@dataclass(eq=False)
class LiftResult:
    """bald: rest-pose Gaussians of the hairless head (world = rest head frame); hair: the hair
    Gaussians; info: figures of what the lifter did (counts, shares)."""

    bald: GaussianSet
    hair: GaussianSet
    info: dict = field(default_factory=dict)


@runtime_checkable
class Lifter(Protocol):
    """Turns one portrait (and its 2D analysis, segmentation, bald image and head fit) into a
    bald and a hair GaussianSet in the fitted rest head's frame."""

    name: str

    def lift(self, image: np.ndarray, analysis, segmentation, bald, fit: HeadFit) -> LiftResult: ...


# ---------------------------------------------------------------------------------------------
# image helpers

def sample_image(image: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, C) float32 of an (H, W, C) image at continuous pixel coordinates
    (N, 2) (pixel i's centre at i + 0.5); outside the image the border is repeated."""
    import cv2

    img = np.asarray(image, np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    p = np.asarray(px, np.float32).reshape(-1, 2) - 0.5
    p = np.nan_to_num(p, nan=-1e6)
    out = np.empty((len(p), img.shape[2]), np.float32)
    chunk = 1 << 14  # cv2.remap's maps must stay below 32767 in each dimension
    for s in range(0, len(p), chunk):
        q = p[s:s + chunk]
        out[s:s + chunk] = cv2.remap(img, q[:, 0][None], q[:, 1][None], cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE).reshape(len(q), -1)
    return out


def lookup(mask: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Nearest-pixel values of an (H, W) array at pixel coordinates (N, 2); False/0 outside."""
    h, w = mask.shape[:2]
    p = np.nan_to_num(np.asarray(px, np.float64), nan=-1.0)
    xi = np.floor(p[:, 0]).astype(np.int64)
    yi = np.floor(p[:, 1]).astype(np.int64)
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = np.zeros(len(p), dtype=mask.dtype)
    out[ok] = mask[yi[ok], xi[ok]]
    return out


def depth_map(gaussians: GaussianSet, camera, max_side: int = 512):
    """The renderer's depth (H, W) of `gaussians` seen by `camera`, rendered at most `max_side`
    pixels wide and returned with the camera it was rendered with."""
    from avatarkit.render import render

    k = min(1.0, max_side / max(camera.width, camera.height))
    cam = camera if k >= 1 else camera.with_size(max(1, round(camera.width * k)),
                                                 max(1, round(camera.height * k)))
    r = render(gaussians, cam)
    return r.depth, r.alpha, cam


def seen_from(points: np.ndarray, normals: np.ndarray | None, camera, depth: np.ndarray,
              depth_camera, tol: float = DEPTH_TOL, min_facing: float = MIN_FACING):
    """(seen (N,) bool, pixels (N, 2) in `camera`, facing (N,)): points within `tol` of the
    rendered depth (from `depth_camera`) and, with normals (N, 3), facing the camera."""
    px, z = camera.project(points)
    dpx, dz = depth_camera.project(points)
    d = lookup(depth, dpx)
    inside = np.isfinite(px).all(axis=1) & (px[:, 0] >= 0) & (px[:, 0] < camera.width) \
        & (px[:, 1] >= 0) & (px[:, 1] < camera.height)
    seen = inside & (d > 0) & (dz <= d + tol)
    facing = np.ones(len(points))
    if normals is not None:
        view = camera.camera_center[None] - points
        view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-12)
        facing = np.einsum("ij,ij->i", view, normals)
        seen &= facing >= min_facing
    return seen, px, facing


def propagate_colors(points: np.ndarray, colors: np.ndarray, known: np.ndarray, fallback,
                     k: int = 8, reach: float = 0.03) -> np.ndarray:
    """Fill unknown colours (N, 3) over the k-nearest-neighbour graph of points (N, 3):
    the screened harmonic solution (L + s I) c = s fallback on the unknown nodes, the known ones
    fixed. Known colour fades into `fallback` about as exp(-distance / reach) (metres) along a
    sampled surface."""
    from scipy import sparse
    from scipy.sparse.linalg import splu
    from scipy.spatial import cKDTree

    pts = np.asarray(points, np.float64)
    out = np.asarray(colors, np.float64).copy()
    known = np.asarray(known, bool)
    unknown = np.flatnonzero(~known)
    fb = np.broadcast_to(np.asarray(fallback, np.float64), (3,))
    if len(unknown) == 0:
        return out.astype(np.float32)
    if not known.any() or len(pts) < 2:
        out[unknown] = fb
        return out.astype(np.float32)
    kk = min(k + 1, len(pts))
    dist, nb = cKDTree(pts).query(pts, k=kk)
    dist, nb = dist[:, 1:], nb[:, 1:]
    n = len(pts)
    rows = np.repeat(np.arange(n), kk - 1)
    a = sparse.coo_matrix((np.ones(len(rows)), (rows, nb.ravel())), shape=(n, n)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64)                  # symmetric adjacency
    deg = np.asarray(a.sum(axis=1)).ravel()
    lap = sparse.diags(deg) - a
    # On a surface sampled this way the graph Laplacian is about (sum_j r_j^2 / 4) times the
    # continuous one, so this screening makes colour fade as exp(-distance / reach).
    mu = float(np.mean((dist ** 2).sum(axis=1))) / (4.0 * reach ** 2)
    luu = lap[unknown][:, unknown] + sparse.diags(np.full(len(unknown), mu))
    kn = np.flatnonzero(known)
    rhs = -(lap[unknown][:, kn] @ out[kn]) + mu * fb[None]
    out[unknown] = splu(luu.tocsc()).solve(rhs)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# the bald head

def _face_parts(model) -> np.ndarray:
    """(F,) uint8 part of each head face: eye (2 of 3 vertices on an eyeball), mouth interior, skin."""
    f = model.faces
    part = np.zeros(len(f), np.uint8)
    if "mouth_interior" in model.regions:
        part[model.region_mask("mouth_interior")[f].sum(axis=1) >= 2] = PART_MOUTH
    if "eyes" in model.regions:
        part[model.region_mask("eyes")[f].sum(axis=1) >= 2] = PART_EYE
    return part


def _face_weights(model) -> np.ndarray:
    """(F,) bool: faces in front of the ears (the face region, eyes, mouth) are sampled denser."""
    f = model.faces
    dense = np.zeros(len(f), bool)
    for region in ("face", "eyes", "lips", "mouth_interior"):
        if region in model.regions:
            dense |= model.region_mask(region)[f].sum(axis=1) >= 2
    return dense


def sample_bald(fit: HeadFit, n: int, rng: np.random.Generator, face_density: float = 3.0):
    """Discs on the rest head: (means (n, 3), quats (n, 4), scales (n, 3), face ids (n,) int32,
    normals (n, 3)). Area-weighted, `face_density` times denser on the face."""
    from avatarkit.rig.frames import degenerate_faces, triangle_frames

    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    faces = np.asarray(model.faces)
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    density = np.where(_face_weights(model), face_density, 1.0)
    density[degenerate_faces(v, faces)] = 0.0
    weight = area * density
    if not weight.sum() > 0:
        raise InputError("the head mesh has no area to put Gaussians on")
    ids = rng.choice(len(faces), size=n, p=weight / weight.sum()).astype(np.int32)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    points = np.einsum("nk,nkc->nc", bary, tri[ids])
    _, rot, _ = triangle_frames(v, faces[ids])                     # columns e0, n, b
    # each disc's share of the surface: total weighted area / n, divided by the local density
    share = weight.sum() / n / density[ids]
    radius = COVERAGE * np.sqrt(share / np.pi) * rng.uniform(0.85, 1.15, n)
    scales = np.stack([radius, FLATNESS * radius, radius * rng.uniform(0.85, 1.15, n)], axis=1)
    return points, matrix_to_quat(rot), scales, ids, rot[:, :, 1]


def _eye_colours(image: np.ndarray, analysis) -> np.ndarray:
    """(2, 3) iris colours in [0, 1] at the right and left eye landmarks: the darker half of a
    small disc around each (the iris and pupil, not the sclera or lids)."""
    h, w = image.shape[:2]
    r = max(1.0, 0.07 * analysis.eye_distance)
    out = []
    for name in ("right_eye", "left_eye"):
        cx, cy = analysis.point(name)
        y0, y1 = int(max(0, cy - r)), int(min(h, cy + r + 1))
        x0, x1 = int(max(0, cx - r)), int(min(w, cx + r + 1))
        patch = image[y0:y1, x0:x1].reshape(-1, 3).astype(np.float64) / 255.0
        if len(patch) == 0:
            out.append((0.25, 0.2, 0.18))
            continue
        lum = patch.mean(axis=1)
        out.append(patch[lum <= np.median(lum)].mean(axis=0))
    return np.array(out)


def lift_bald(image: np.ndarray, analysis, segmentation, bald, fit: HeadFit, n: int,
              rng: np.random.Generator, face_density: float = 3.0) -> tuple[GaussianSet, dict]:
    """The built-in bald lifting (module docstring) -> (GaussianSet with `binding` and `part`
    extras, info)."""
    from avatarkit.recon.segment import BODY, SKIN

    model = fit.model
    cam = fit.camera
    means, quats, scales, ids, normals = sample_bald(fit, n, rng, face_density)
    part = _face_parts(model)[ids]
    geo = GaussianSet.from_colors(means, quats, scales, np.full(n, 0.98), np.full((n, 3), 0.5))
    depth, _, dcam = depth_map(geo, cam)
    seen, px, facing = seen_from(means, normals, cam, depth, dcam)

    labels = bald.labels if getattr(bald, "labels", None) is not None else segmentation.labels
    lab = lookup(labels, px)
    neck = np.zeros(model.num_faces, bool)
    if "neck" in model.regions:
        neck = model.region_mask("neck")[model.faces].sum(axis=1) >= 2
    ok_label = (lab == SKIN) | ((lab == BODY) & neck[ids])
    eye = part == PART_EYE
    known = seen & (ok_label | eye) & (part != PART_MOUTH)
    photo = sample_image(bald.image, px) / 255.0
    rgb = np.zeros((n, 3), np.float32)
    rgb[known] = photo[known]

    skin_rgb = segmentation.skin_model.rgb.astype(np.float64) / 255.0
    skin = part == PART_SKIN
    rgb[skin] = propagate_colors(means[skin], rgb[skin], known[skin], skin_rgb)
    if eye.any():
        iris_rgb = _eye_colours(image, analysis)
        fill = np.tile(np.asarray(SCLERA_RGB, np.float64), (int(eye.sum()), 1))
        joints = model.rest_joints(fit.params)[0].astype(np.float64)
        for k, (centre, region) in enumerate(((joints[4], "right_iris"), (joints[3], "left_iris"))):
            if region in model.regions:
                iris_face = model.region_mask(region)[model.faces].sum(axis=1) >= 2
                fill[iris_face[ids[eye]]] = iris_rgb[k]
        rgb[eye] = np.where(known[eye][:, None], rgb[eye], fill)
    rgb[part == PART_MOUTH] = MOUTH_RGB
    opacity = rng.uniform(0.95, 1.0, n)
    out = GaussianSet.from_colors(means, quats, scales, opacity, np.clip(rgb, 0, 1),
                                  extras={"binding": ids, "part": part})
    info = {"bald": n, "bald_seen": int(known.sum()),
            "bald_seen_share": round(float(known.mean()), 4)}
    return out, info


# ---------------------------------------------------------------------------------------------
# hair: 2D flow and shell

def hair_flow(image: np.ndarray, hair: np.ndarray, scale_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The 2D direction of the hair: (flow (H, W, 2) unit vectors, coherence (H, W) in [0, 1]).

    Structure tensor J = G * (grad I grad I^T) of the grey image; hair runs along the
    eigenvector of the smaller eigenvalue. Orientations are averaged as doubled angles
    (sign-free), weighted by coherence ((l1 - l2) / (l1 + l2))^2, inside the hair mask and over
    `scale_px`, so the field is smooth and defined on every hair pixel."""
    import cv2

    grey = cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    s = max(1.0, 0.01 * scale_px)
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), s)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), s)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), s)
    tr = jxx + jyy
    diff = np.sqrt((jxx - jyy) ** 2 + 4 * jxy ** 2)
    coherence = np.where(tr > 1e-9, diff / np.maximum(tr, 1e-9), 0.0) ** 2
    # gradient orientation (doubled angle); hair runs perpendicular: negate the doubled vector
    c2 = -(jxx - jyy) / np.maximum(diff, 1e-9)
    s2 = -2 * jxy / np.maximum(diff, 1e-9)
    m = np.asarray(hair, np.float32)
    wgt = (coherence * m).astype(np.float32)
    big = max(1.0, 0.12 * scale_px)
    num_c = cv2.GaussianBlur(c2 * wgt, (0, 0), big)
    num_s = cv2.GaussianBlur(s2 * wgt, (0, 0), big)
    den = cv2.GaussianBlur(wgt, (0, 0), big)
    mag = np.sqrt(num_c ** 2 + num_s ** 2)
    angle = 0.5 * np.arctan2(num_s, num_c)
    flow = np.stack([np.cos(angle), np.sin(angle)], axis=-1).astype(np.float32)
    strength = np.where(den > 1e-6, mag / np.maximum(den, 1e-6), 0.0) * np.clip(den / 0.05, 0, 1)
    return flow, np.clip(strength, 0, 1).astype(np.float32)


@dataclass(eq=False)
class HairShell:
    """What the 2D masks say about the hair volume.

    center2d (2,) pixels and center3d (3,) rest frame: the head centre; depth: its camera z;
    angles (A,): polar angle bins (radians, image axes); thickness (A,): hair thickness above
    the head's silhouette per bin (metres); hair: (H, W) bool hair connected to the head;
    head: (H, W) bool projected head (no neck); y_end: rest-frame height of the hair's lowest
    extent beside the face (metres); y_jaw: rest-frame height of the jaw (below it hair hangs)."""

    center2d: np.ndarray
    center3d: np.ndarray
    depth: float
    angles: np.ndarray
    thickness: np.ndarray
    hair: np.ndarray
    head: np.ndarray
    y_end: float
    y_jaw: float

    def thickness_at(self, px: np.ndarray) -> np.ndarray:
        """Shell thickness (N,) for pixel positions (N, 2) by their polar angle."""
        d = np.nan_to_num(np.asarray(px, np.float64) - self.center2d)
        a = np.arctan2(d[:, 1], d[:, 0])
        step = self.angles[1] - self.angles[0]
        i = np.floor((a - self.angles[0]) / step).astype(np.int64)
        t = (a - self.angles[0]) / step - i
        n = len(self.angles)
        return (1 - t) * self.thickness[i % n] + t * self.thickness[(i + 1) % n]


def back_project(fit: HeadFit, px: np.ndarray, depth: float) -> np.ndarray:
    """Pixels (N, 2) at camera depth `depth` -> rest-frame points (N, 3)."""
    cam = fit.camera
    p = np.asarray(px, np.float64).reshape(-1, 2)
    c = np.stack([(p[:, 0] - cam.cx) * depth / cam.fx, (p[:, 1] - cam.cy) * depth / cam.fy,
                  np.full(len(p), depth)], axis=1)
    r, t = cam.rotation, cam.translation
    return (c - t) @ r   # R^T (c - t), row form


def _first_run(a: np.ndarray, run: int) -> np.ndarray:
    """Per row of a (A, R) bool array: the first index that starts `run` True values in a row
    (R - 1 when none does)."""
    ok = a[:, : a.shape[1] - run + 1].copy()
    for k in range(1, run):
        ok &= a[:, k: a.shape[1] - run + 1 + k]
    return np.where(ok.any(axis=1), np.argmax(ok, axis=1), a.shape[1] - 1)


def hair_shell(fit: HeadFit, hair_mask: np.ndarray, analysis, bins: int = 90) -> HairShell:
    """Measure the hair shell from the hair mask and the fitted head (see `HairShell`)."""
    from scipy import ndimage

    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    keep = np.ones(model.num_faces, bool)
    not_neck = np.ones(model.num_vertices, bool)
    if "neck" in model.regions:
        not_neck = ~model.region_mask("neck")
        keep = not_neck[model.faces].any(axis=1)
    head = project_mask(fit, model.faces[keep])
    lo, hi = v[not_neck].min(axis=0), v[not_neck].max(axis=0)
    center3d = 0.5 * (lo + hi)
    (c2,), (cz,) = fit.camera.project(center3d[None])
    hair = np.asarray(hair_mask, bool)
    # hair connected to the head (a dilated head touches it): stray hair-coloured blobs are not
    lab, n = ndimage.label(hair)
    if n:
        touch = np.unique(lab[ndimage.binary_dilation(head, iterations=3) & hair])
        keep_lab = np.zeros(n + 1, bool)
        keep_lab[touch] = True
        keep_lab[0] = False
        hair = keep_lab[lab]
    h, w = hair.shape
    both = hair | head
    angles = np.linspace(-np.pi, np.pi, bins, endpoint=False)
    rmax = 1.5 * max(h, w)
    r = np.arange(0.0, rmax, 1.0)
    dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    pts = c2[None, None] + r[None, :, None] * dirs[:, None, :]           # (A, R, 2)
    flat = pts.reshape(-1, 2)
    in_head = lookup(head, flat).reshape(len(angles), -1)
    in_both = lookup(both, flat).reshape(len(angles), -1)
    # the head's edge: where the ray first leaves the head; the hair's: where it first leaves
    # head + hair. Gaps of a few pixels (thin partings, mask noise) do not count as leaving.
    first_out = _first_run(~in_head, 3)
    last_in = _first_run(~in_both, 5)
    gap_px = np.maximum(last_in - first_out, 0).astype(np.float64)
    thickness = gap_px * cz / fit.camera.fx
    # smooth over the angle (circular): median against single-ray outliers, then a small box
    padded = np.concatenate([thickness[-3:], thickness, thickness[:3]])
    med = np.array([np.median(padded[i:i + 7]) for i in range(len(thickness))])
    padded = np.concatenate([med[-2:], med, med[:2]])
    thickness = np.convolve(padded, np.ones(5) / 5, mode="valid")
    thickness = np.clip(thickness, 0.0, MAX_SHELL)

    joints = model.rest_joints(fit.params)[0].astype(np.float64)
    chin = v[fit.landmarks["chin"]] if "chin" in fit.landmarks else v[not_neck].min(axis=0)
    y_jaw = float(chin[1] + 0.25 * (joints[2][1] - chin[1]))
    # the hair's lowest extent beside the face: the lowest hair row outside the face's width
    ex, _ = analysis.face_axes()
    ys, xs = np.nonzero(hair)
    y_end = float(center3d[1])
    if len(ys):
        u = ((np.stack([xs + 0.5, ys + 0.5], axis=1) - analysis.eye_mid) @ ex) / analysis.eye_distance
        side = np.abs(u) > 0.9
        if side.any():
            low = np.percentile(ys[side] + 0.5, 98)
            x_side = float(np.median(xs[side] + 0.5))
        else:
            low = float(ys.max()) + 0.5
            x_side = float(c2[0])
        y_end = float(back_project(fit, np.array([[x_side, low]]), float(cz))[0, 1])
    return HairShell(np.asarray(c2, np.float64), center3d, float(cz), angles, thickness, hair, head,
                     y_end, y_jaw)


# ---------------------------------------------------------------------------------------------
# hair: strands

def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)


@dataclass(eq=False)
class _Growth:
    """Everything a strand step needs."""

    fit: HeadFit
    sdf: object
    shell: HairShell
    flow: np.ndarray
    coherence: np.ndarray
    head_depth: np.ndarray      # (h, w) of the depth camera
    depth_camera: object
    labels: np.ndarray
    crown: np.ndarray
    neck_z: float


def _hidden(g: _Growth, p: np.ndarray, px: np.ndarray) -> np.ndarray:
    """(N,) bool: points the camera cannot see: behind the head, or behind the neck and body."""
    from avatarkit.recon.segment import BODY, SKIN

    dpx, dz = g.depth_camera.project(p)
    d = lookup(g.head_depth, dpx)
    behind_head = (d > 0) & (dz > d + DEPTH_TOL)
    lab = lookup(g.labels, px)
    behind_body = ((lab == BODY) | ((lab == SKIN) & ~lookup(g.shell.head, px))) & (p[:, 2] < g.neck_z)
    return behind_head | behind_body


def _thickness(g: _Growth, p: np.ndarray, px: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Shell thickness (N,) at points p: the silhouette's, by polar angle, where the surface is
    seen edge-on or from behind; thinner where it faces the camera (over the forehead the
    photo shows no depth, and hair lying there is thin)."""
    view = g.fit.camera.camera_center[None] - p
    facing = np.einsum("ij,ij->i", _unit(view), normal)
    return g.shell.thickness_at(px) * (1.0 - 0.75 * np.clip(facing, 0.0, 1.0))


def _comb(g: _Growth, p: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Direction (N, 3) of hidden hair: away from the crown along the scalp, turning downward."""
    radial = p - g.crown
    radial[:, 1] = np.minimum(radial[:, 1], 0.0)
    top, bottom = g.crown[1], g.shell.y_jaw
    a = np.clip((p[:, 1] - bottom) / max(top - bottom, 1e-6), 0.0, 1.0)[:, None] ** 2
    d = a * _unit(radial) + (1 - a) * np.array([0.0, -1.0, 0.0])
    d = d - np.einsum("ij,ij->i", d, normal)[:, None] * normal * (a > 0.05)
    return _unit(d)


def _lift_flow(g: _Growth, f2: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Image directions (N, 2) -> tangent directions (N, 3) that project onto them."""
    r = g.fit.camera.rotation                  # rows: camera x, y, z axes in the rest frame
    eu, ev, ez = r[0], r[1], r[2]
    a = f2[:, :1] * eu + f2[:, 1:] * ev        # (N, 3) in the image plane
    nz = normal @ ez
    lam = -np.einsum("ij,ij->i", a, normal) / np.where(np.abs(nz) > 0.2, nz, np.sign(nz + 1e-12) * 0.2)
    return _unit(a + np.clip(lam, -2.0, 2.0)[:, None] * ez)


def grow_strands(g: _Growth, roots: np.ndarray, layer: np.ndarray, max_steps: int,
                 segment: float = SEGMENT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grow strands from roots (S, 3) with layer fractions (S,) in [0, 1].

    Returns points (S, K+1, 3), alive (S, K) bool (segment k exists), seen (S, K) bool."""
    cam = g.fit.camera
    s_count = len(roots)
    dist, grad = g.sdf.query(roots)
    # a strand starts on its layer (the rise from the scalp is hidden under the layers above)
    px, _ = cam.project(roots)
    start = MARGIN + layer * np.maximum(_thickness(g, roots, px, grad) - MARGIN, 0.0)
    p = roots + grad * (start - dist)[:, None]
    d = _comb(g, p, grad)
    pts = np.empty((s_count, max_steps + 1, 3))
    pts[:, 0] = p
    alive = np.zeros((s_count, max_steps), bool)
    seen = np.zeros((s_count, max_steps), bool)
    live = np.ones(s_count, bool)
    for k in range(max_steps):
        idx = np.flatnonzero(live)
        if len(idx) == 0:
            break
        q = pts[idx, k]
        sd, n = g.sdf.query(q)
        px, _ = cam.project(q)
        hidden = _hidden(g, q, px)
        want = _comb(g, q, n)
        f2 = np.stack([lookup(g.flow[..., 0], px), lookup(g.flow[..., 1], px)], axis=1)
        coh = lookup(g.coherence, px)
        use = ~hidden & (coh > 0.05)
        if use.any():
            # the flow is sign-free: take the sense that agrees with where the strand is going
            cur2 = np.stack([d[idx[use]] @ cam.rotation[0], d[idx[use]] @ cam.rotation[1]], axis=1)
            sgn = np.sign(np.einsum("ij,ij->i", f2[use], cur2) + 1e-9)
            lifted = _lift_flow(g, f2[use] * sgn[:, None], n[use])
            wf = np.clip(coh[use] * 2, 0, 0.8)[:, None]
            want[use] = _unit(wf * lifted + (1 - wf) * want[use])
        step = _unit(0.6 * d[idx] + 0.4 * want)
        nxt = q + segment * step
        # keep to the strand's layer in the shell above the jaw; fall freely below it
        nsd, nn = g.sdf.query(nxt)
        npx, _ = cam.project(nxt)
        target = MARGIN + layer[idx] * np.maximum(_thickness(g, nxt, npx, nn) - MARGIN, 0.0)
        hug = (nxt[:, 1] > g.shell.y_jaw) & (nsd < target + 0.02)
        # rise to (or sink toward) the layer gradually: a jump would make one long spike
        lift = np.clip(target - nsd, -0.5 * segment, 0.5 * segment)
        nxt[hug] += nn[hug] * lift[hug, None]
        low = nsd < MARGIN
        nxt[low & ~hug] += nn[low & ~hug] * (MARGIN - nsd[low & ~hug])[:, None]
        # stop: seen and off the hair mask, or hidden and below the hair's length
        npx, _ = cam.project(nxt)
        nhidden = _hidden(g, nxt, npx)
        in_hair = lookup(g.shell.hair, npx)
        stop = (~nhidden & ~in_hair) | (nhidden & (nxt[:, 1] < g.shell.y_end))
        ok = ~stop
        d[idx] = _unit(nxt - q)
        pts[idx, k + 1] = nxt
        alive[idx[ok], k] = True
        seen[idx[ok], k] = ~nhidden[ok]
        live[idx[stop]] = False
    return pts, alive, seen


def _scalp_roots(fit: HeadFit, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points (n, 3) uniformly by area on the rest head's scalp region."""
    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    if "scalp" not in model.regions or len(model.regions["scalp"]) == 0:
        raise InputError("the head model has no scalp region to grow hair from")
    faces = model.faces[model.region_mask("scalp")[model.faces].sum(axis=1) >= 2]
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    ids = rng.choice(len(faces), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    return np.einsum("nk,nkc->nc", bary, tri[ids])


def _hair_colours(image: np.ndarray, hair: np.ndarray, px: np.ndarray, seen: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray:
    """Seen segments: the photo at their projection; hidden ones: a random hair pixel from the
    same band of image rows (whole image's hair when the band has none)."""
    h, w = hair.shape
    rgb = sample_image(image, px) / 255.0
    ys, xs = np.nonzero(hair)
    hidden = np.flatnonzero(~seen)
    if len(hidden) and len(ys):
        order = np.argsort(ys, kind="stable")
        ys, xs = ys[order], xs[order]
        band = max(2, int(0.03 * h))
        row = np.clip(np.nan_to_num(px[hidden, 1], nan=h / 2), 0, h - 1).astype(np.int64)
        lo = np.searchsorted(ys, row - band)
        hi = np.searchsorted(ys, row + band, side="right")
        empty = hi <= lo
        lo[empty], hi[empty] = 0, len(ys)
        pick = lo + (rng.random(len(hidden)) * (hi - lo)).astype(np.int64)
        pick = np.minimum(pick, len(ys) - 1)
        rgb[hidden] = image[ys[pick], xs[pick]].astype(np.float32) / 255.0
    return rgb


def lift_hair(image: np.ndarray, analysis, segmentation, fit: HeadFit, n: int,
              rng: np.random.Generator, sdf=None, bald_set: GaussianSet | None = None
              ) -> tuple[GaussianSet, dict]:
    """The built-in hair lifting (module docstring) -> (GaussianSet with `strand` and `seen`
    extras, info). An empty set when the portrait has no hair."""
    from avatarkit.sim.sdf import HeadSDF

    model = fit.model
    hair_mask = segmentation.hair
    empty = GaussianSet.empty()
    if n <= 0 or not hair_mask.any():
        return empty, {"hair": 0, "strands": 0}
    v = np.asarray(fit.rest_vertices, np.float64)
    if sdf is None:
        sdf = HeadSDF.build(v, model.faces)
    shell = hair_shell(fit, hair_mask, analysis)
    if not shell.hair.any():
        return empty, {"hair": 0, "strands": 0}
    flow, coherence = hair_flow(image, shell.hair, analysis.eye_distance)
    if bald_set is None:
        bald_set, _ = lift_bald(image, analysis, segmentation,
                                _NoBald(image, segmentation.labels), fit, 20000, rng)
    head_depth, _, dcam = depth_map(bald_set, fit.camera)
    scalp = model.regions["scalp"]
    crown = v[scalp][np.argmax(v[scalp, 1])].copy()
    crown[2] -= 0.25 * (crown[2] - v[scalp, 2].min())     # the whorl sits toward the back
    neck_z = float(np.median(v[model.regions["neck"], 2])) if "neck" in model.regions else float(shell.center3d[2])
    g = _Growth(fit, sdf, shell, flow, coherence, head_depth, dcam, segmentation.labels, crown, neck_z)

    span = max(float(crown[1] - min(shell.y_end, shell.y_jaw)), 0.05)
    max_steps = int(min(160, math.ceil(1.6 * span / SEGMENT) + 10))

    def candidate_roots(count):
        roots = _scalp_roots(fit, count, rng)
        _, normal = sdf.query(roots)
        px, _ = fit.camera.project(roots)
        hidden = _hidden(g, roots + normal * MARGIN, px)
        visible_ok = lookup(shell.hair, px)
        # hidden roots grow where the silhouette shows hair at their polar angle
        hidden_ok = shell.thickness_at(px) > 0.003
        return roots[np.where(hidden, hidden_ok, visible_ok)]

    pilot = candidate_roots(600)
    if len(pilot) == 0:
        return empty, {"hair": 0, "strands": 0}
    pts, alive, _ = grow_strands(g, pilot, rng.random(len(pilot)), max_steps)
    per = max(float(alive.sum(axis=1).mean()), 1.0)
    keep_share = len(pilot) / 600
    want = int(math.ceil(1.1 * n / per / max(keep_share, 1e-3)))
    roots = candidate_roots(min(want, 60000))
    layer = rng.random(len(roots)) ** 0.7          # more strands toward the outside
    pts, alive, seen = grow_strands(g, roots, layer, max_steps)

    lengths = alive.sum(axis=1)
    order = rng.permutation(len(roots))
    total = np.cumsum(lengths[order])
    chosen = order[: int(np.searchsorted(total, (1 - FILL_SHARE) * n, side="right"))]
    chosen = chosen[lengths[chosen] > 0]
    sel_s, sel_k = np.nonzero(alive[chosen])
    strand = chosen[sel_s]
    a, b = pts[strand, sel_k], pts[strand, sel_k + 1]
    means = 0.5 * (a + b)
    t = _unit(b - a)
    _, normal = sdf.query(means)
    nrm = _unit(normal - np.einsum("ij,ij->i", normal, t)[:, None] * t)
    side = np.cross(nrm, t)
    rot = np.stack([t, side, nrm], axis=2)           # columns: along, across, out of the scalp
    m = len(means)
    seg = np.linalg.norm(b - a, axis=1)
    # fewer strands must each cover more: widen them below the reference count
    width = HAIR_WIDTH * float(np.clip(np.sqrt(HAIR_REFERENCE_COUNT / max(n, 1)), 1.0, 4.0))
    scales = np.stack([np.maximum(0.5 * seg, 1e-4), np.full(m, width) * rng.uniform(0.7, 1.3, m),
                       np.full(m, HAIR_THICKNESS)], axis=1)
    px, _ = fit.camera.project(means)
    seen_m = seen[strand, sel_k]
    rgb = _hair_colours(image, shell.hair, px, seen_m, rng)
    rgb *= (0.8 + 0.2 * layer[strand])[:, None]    # inner layers a little darker
    opacity = rng.uniform(0.75, 1.0, m)
    hair = GaussianSet.from_colors(means, matrix_to_quat(rot), scales, opacity, np.clip(rgb, 0, 1),
                                   extras={"strand": strand.astype(np.int32),
                                           "seen": seen_m.astype(np.uint8)})
    hair = GaussianSet.concat([hair, fill_coverage(fit, g, image, bald_set, hair, int(FILL_SHARE * n), rng)])
    m = len(hair)
    info = {"hair": m, "strands": int(len(np.unique(strand))), "hair_fill": int(m - len(strand)),
            "hair_seen_share": round(float(hair.extras["seen"].mean()), 4) if m else 0.0,
            "hair_end_y": round(shell.y_end, 4), "shell_max_m": round(float(shell.thickness.max()), 4)}
    return hair, info


def fill_coverage(fit: HeadFit, g: _Growth, image: np.ndarray, bald_set: GaussianSet,
                  hair: GaussianSet, budget: int, rng: np.random.Generator) -> GaussianSet:
    """Hair Gaussians for the hair pixels the strands left uncovered in the input view (their
    rendered alpha below `FILL_ALPHA`), so the photo's hair silhouette is filled: one small
    Gaussian per uncovered pixel (at most `budget`, evenly thinned), at the depth of the nearest
    covered hair pixel, lying along the 2D hair flow in the head's tangent plane, coloured from
    the photo. Extras as the strands' (`strand` -1, `seen` 1). With more holes than budget,
    a random subset of hole pixels gets proportionally larger Gaussians."""
    from scipy import ndimage

    from avatarkit.render import render

    cam = fit.camera
    empty = GaussianSet.empty().replace(extras={"strand": np.zeros(0, np.int32), "seen": np.zeros(0, np.uint8)})
    if budget <= 0 or len(hair) == 0:
        return empty
    both = GaussianSet.concat([bald_set.replace(extras={}), hair.replace(extras={})])
    alpha = render(both, cam).alpha
    hair_depth = render(hair.replace(extras={}), cam).depth
    hole = g.shell.hair & (alpha < FILL_ALPHA)
    known = hair_depth > 0
    if not hole.any() or not known.any():
        return empty
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    ys, xs = np.nonzero(hole)
    spread = 1.0
    if len(ys) > budget:
        keep = rng.choice(len(ys), budget, replace=False)
        ys, xs = ys[keep], xs[keep]
        spread = float(np.sqrt(hole.sum() / budget))   # fewer, larger Gaussians cover the holes
    px = np.stack([xs + rng.random(len(xs)), ys + rng.random(len(ys))], axis=1)
    depth = hair_depth[iy[ys, xs], ix[ys, xs]].astype(np.float64)
    means = back_project(fit, px, 1.0)  # direction only at depth 1: scale below
    centre = cam.camera_center
    means = centre + (means - centre) * depth[:, None]
    _, normal = g.sdf.query(means)
    f2 = np.stack([g.flow[ys, xs, 0], g.flow[ys, xs, 1]], axis=1)
    t = _lift_flow(g, f2, normal)
    nrm = _unit(normal - np.einsum("ij,ij->i", normal, t)[:, None] * t)
    rot = np.stack([t, np.cross(nrm, t), nrm], axis=2)
    pixel = spread * depth / cam.fx                         # metres per pixel at that depth
    m = len(means)
    scales = np.stack([1.6 * pixel, 0.8 * pixel, np.full(m, HAIR_THICKNESS)], axis=1)
    rgb = sample_image(image, px) / 255.0
    return GaussianSet.from_colors(means, matrix_to_quat(rot), scales, np.full(m, 0.9), rgb,
                                   extras={"strand": np.full(m, -1, np.int32), "seen": np.ones(m, np.uint8)})


@dataclass(eq=False)
class _NoBald:
    """A stand-in bald result (the photo itself) for lifting hair without a bald image."""

    image: np.ndarray
    labels: np.ndarray


class BuiltinLifter:
    """The offline lifter (module docstring). n_bald / n_hair: Gaussian counts (hair: at most);
    face_density: how much denser the face is sampled than the back of the head."""

    name = "builtin"

    def __init__(self, n_bald: int = 40_000, n_hair: int = 40_000, seed: int = 0,
                 face_density: float = 4.0):
        for label, value in (("n_bald", n_bald), ("n_hair", n_hair)):
            if int(value) != value or value < (1 if label == "n_bald" else 0):
                raise InputError(f"{label} must be a {'positive' if label == 'n_bald' else 'non-negative'} "
                                 f"integer, got {value!r}")
        self.n_bald, self.n_hair, self.seed = int(n_bald), int(n_hair), int(seed)
        self.face_density = float(face_density)
        self.sdf = None  # the rest head's HeadSDF, set by the pipeline to share it

    def lift(self, image, analysis, segmentation, bald, fit: HeadFit) -> LiftResult:
        rng = np.random.default_rng([self.seed, 11])
        bald_set, info = lift_bald(image, analysis, segmentation, bald, fit, self.n_bald, rng,
                                   self.face_density)
        hair, hinfo = lift_hair(image, analysis, segmentation, fit, self.n_hair, rng, sdf=self.sdf,
                                bald_set=bald_set)
        return LiftResult(bald_set, hair, {**info, **hinfo, "lifter": self.name})


# ---------------------------------------------------------------------------------------------
# import

def _read_splats(source, what: str) -> tuple[GaussianSet, str | None]:
    from avatarkit.gaussians.ply import read_ply

    if isinstance(source, GaussianSet):
        return source, None
    path = os.fspath(source)
    if not os.path.exists(path):
        raise InputError(f"{what} file not found", path)
    try:
        gs = read_ply(path)
    except FormatError:
        raise
    except InputError as e:
        raise FormatError(e.message, path) from None
    if len(gs) < 10:
        raise FormatError(f"{what} holds {len(gs)} Gaussians: too few to be a lifted head", path)
    return gs, path


def head_surface_samples(fit: HeadFit, n: int = 20000, seed: int = 0) -> np.ndarray:
    """(n, 3) points uniformly by area on the rest head (neck and eyeballs included: a lifted
    bald head has them too)."""
    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    faces = model.faces
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    ids = rng.choice(len(faces), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    return np.einsum("nk,nkc->nc", bary, tri[ids])


#: ICP steps every starting orientation gets before the best one is continued
START_STEPS = 12


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity dst ~ s R src + t for paired points (N, 3) -> (s, R, t)."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    cov = b.T @ a / len(src)
    u, sig, vt = np.linalg.svd(cov)
    d = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[2, 2] = -1
    r = u @ d @ vt
    var = (a * a).sum() / len(src)
    s = float(np.trace(np.diag(sig) @ d) / max(var, 1e-30))
    return s, r, mu_d - s * r @ mu_s


def align_similarity(points: np.ndarray, target: np.ndarray, iterations: int = 100, keep: float = 0.85,
                     seed: int = 0, mesh: tuple | None = None, refine: int = 8
                     ) -> tuple[float, np.ndarray, np.ndarray, float]:
    """Trimmed ICP with scale: the similarity (s, R (3, 3), t (3,)) taking `points` (N, 3) onto
    the surface sampled by `target` (M, 3), and the trimmed RMS distance after it. Starts from
    the four orientations identity and 180 degrees about X, Y and Z, each with centroids and
    RMS radii matched; each runs `START_STEPS` steps and the best is continued up to
    `iterations` (or until it stops improving). Each iteration pairs every point with its nearest
    target sample, keeps the `keep` closest pairs and solves Umeyama on them. mesh: (vertices,
    faces) the samples came from: the best start is then refined `refine` times against the
    closest points on its triangles (exact, not snapped to the samples)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    p = np.asarray(points, np.float64)
    if len(p) > 6000:
        p = p[rng.choice(len(p), 6000, replace=False)]
    q = np.asarray(target, np.float64)
    tree = cKDTree(q)
    mu_p, mu_q = p.mean(axis=0), q.mean(axis=0)
    rad_p = np.sqrt(((p - mu_p) ** 2).sum(axis=1).mean())
    rad_q = np.sqrt(((q - mu_q) ** 2).sum(axis=1).mean())
    starts = [np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]

    def icp(s, r, t, steps):
        prev = np.inf
        for it in range(steps):
            x = s * p @ r.T + t
            d, j = tree.query(x)
            sel = d <= np.quantile(d, keep)
            s, r, t = umeyama(p[sel], q[j[sel]])
            err = float(np.mean(d[sel] ** 2))
            if it > 5 and prev - err < 1e-6 * prev:
                break
            prev = err
        d, _ = tree.query(s * p @ r.T + t)
        return s, r, t, float(np.sqrt(np.mean(np.sort(d)[: max(1, int(keep * len(d)))] ** 2)))

    # every start a few steps (enough to tell the right orientation), then the best one on
    tries = []
    for r0 in starts:
        s0 = rad_q / max(rad_p, 1e-30)
        tries.append(icp(s0, r0, mu_q - s0 * r0 @ mu_p, START_STEPS))
    best = min(tries, key=lambda x: x[3])
    best = icp(*best[:3], iterations)
    if mesh is None:
        return best
    # refine the winner against the surface itself: nearest samples snap to a lattice that is a
    # couple of millimetres coarse, the closest point on the triangles does not
    from avatarkit.recon.assemble import closest_points

    s, r, t, _ = best
    v, f = mesh
    sub = p[rng.choice(len(p), min(len(p), 3000), replace=False)]
    for _ in range(refine):
        x = s * sub @ r.T + t
        _, _, c, d = closest_points(x, v, f)
        sel = d <= np.quantile(d, keep)
        s, r, t = umeyama(sub[sel], c[sel])
    x = s * sub @ r.T + t
    d = closest_points(x, v, f)[3]
    rms = float(np.sqrt(np.mean(np.sort(d)[: max(1, int(keep * len(d)))] ** 2)))
    return s, r, t, rms


class ImportLifter:
    """Lifted splats from an image-to-3D tool (module docstring).

    head_splats: the portrait lifted with its hair (PLY path or GaussianSet); bald_splats: the
    bald image lifted, in the same frame. explained: a head splat within this many times the
    bald splats' median spacing of a bald splat (and of a similar colour) is bald, not hair.
    max_distance: bald splats farther than this (metres, after alignment) from the head surface
    are dropped as floaters.
    """

    name = "import"

    def __init__(self, head_splats, bald_splats, *, explained: float = 3.0, max_distance: float = 0.03,
                 colour_tolerance: float = 0.25):
        self.head, self.head_path = _read_splats(head_splats, "head splats")
        self.bald, self.bald_path = _read_splats(bald_splats, "bald splats")
        # extras of another tool (a `binding` to its own mesh, say) mean nothing here
        self.head = self.head.replace(extras={})
        self.bald = self.bald.replace(extras={})
        self.explained = float(explained)
        self.max_distance = float(max_distance)
        self.colour_tolerance = float(colour_tolerance)

    def lift(self, image, analysis, segmentation, bald, fit: HeadFit) -> LiftResult:
        from scipy.spatial import cKDTree

        from avatarkit.rig.nearest import nearest_faces

        target = head_surface_samples(fit)
        s, r, t, rms = align_similarity(self.bald.means, target,
                                        mesh=(fit.rest_vertices, fit.model.faces))
        if not (np.isfinite(s) and s > 0):
            raise FormatError("cannot align the bald splats to the head (degenerate point set)",
                              self.bald_path)
        bald_set = self.bald.transform(r, t, s)
        head_set = self.head.transform(r, t, s)
        _, dist = nearest_faces(bald_set.means, fit.rest_vertices, fit.model.faces)
        near = dist <= self.max_distance
        if near.mean() < 0.5:
            raise FormatError(f"only {near.mean():.0%} of the bald splats lie within "
                              f"{self.max_distance * 100:.0f} cm of the fitted head after alignment "
                              f"(trimmed RMS {rms * 1000:.1f} mm): not a lifted head in a frame we can align",
                              self.bald_path)
        bald_set = bald_set.subset(near)
        tree = cKDTree(bald_set.means)
        spacing = float(np.median(tree.query(bald_set.means, k=2)[0][:, 1]))
        d, j = tree.query(head_set.means, k=4)
        reach = self.explained * max(spacing, 1e-4)
        colour_gap = np.linalg.norm(head_set.colors[:, None] - bald_set.colors[j], axis=2).min(axis=1)
        hair = (d[:, 0] > reach) | (colour_gap > self.colour_tolerance)
        hair_set = head_set.subset(hair)
        info = {"lifter": self.name, "scale": round(s, 6), "align_rms_mm": round(rms * 1000, 3),
                "bald": len(bald_set), "bald_dropped": int((~near).sum()), "hair": len(hair_set),
                "head_splats": len(head_set)}
        return LiftResult(bald_set, hair_set, info)


__all__ = ["BuiltinLifter", "HairShell", "ImportLifter", "LiftResult", "Lifter", "align_similarity",
           "depth_map", "grow_strands", "hair_flow", "hair_shell", "head_surface_samples", "lift_bald",
           "lift_hair", "lookup", "propagate_colors", "sample_bald", "sample_image", "seen_from",
           "umeyama"]
