"""Head fit (issue 8 item 4): pose, shape (and so size) of the head model to one portrait.

Camera. A pinhole of a plausible portrait lens: 50 mm on a 36 mm-wide (full-frame) sensor
across the image's longer side, so fx = fy = (50 / 36) * max(W, H) pixels (~40 degrees across
the longer side), principal point at the image centre, square pixels. A single photo cannot
tell a big head far away from a small head close by; with the focal length fixed, the head's
size is held near the model's average adult size by the shape prior and the fit recovers the
distance.

Frames. The avatar lives in the head model's frame (metres, +Y up, face toward +Z), in the REST
pose: the head is never moved; the fitted pose is the camera's. `HeadFit.rotation` (axis-angle)
and `HeadFit.translation` place the rest head in a "view frame" whose camera sits at the origin
looking down -Z with +Y up (OpenGL-like): X_view = R X_head + t. The OpenCV camera of the
renderer then has world_to_camera = [C R | C t] with C = diag(1, -1, -1). A frontal portrait has
R ~ I and t ~ (0, y, -0.7 m): the camera is on +Z of the head, looking at the face.

What is fitted (torch autograd, L-BFGS, float64): rotation (3), translation (3) and the first
`shape_components` identity coefficients of the model (template: all 8; FLAME: 20), minimising,
in units of the inter-ocular distance (IOD) in pixels,

- landmarks: squared image distance between the detected 2D landmarks (eye centres, nose tip,
  mouth centre and corners from `PortraitAnalysis`) and the projections of named model vertices
  (`landmark_vertices`: pupils, nose tip, mouth centre and corners, derived from the model's
  regions and geometry); landmarks a detector found weigh 1, those estimated from average
  proportions 0.1-0.3 (they carry little information beyond the eyes);
- face width: at five heights between the nose and the jaw (in the eye frame), the leftmost and
  rightmost projected model vertex (a soft min/max) against the edges of the face's skin region;
- inside: every projected head vertex (neck and eyeballs excepted) inside the skin + hair
  silhouette (a one-sided penalty on the silhouette's signed distance field, sampled bilinearly);
- a Gaussian prior on the shape coefficients (they are in standard deviations).

Stages: a closed-form start (roll from the eye axis, distance from the IOD, position from the
eye midpoint), then pose from the landmarks alone, then pose + shape with every term.
`--flame-params` (a tracker's fit) fixes the shape to the file's and fits the pose only.
"""
from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.head.model import HeadModel, HeadParams
from avatarkit.render.camera import Camera
from avatarkit.rotations import axis_angle_to_matrix

#: assumed lens: 50 mm-equivalent on a 36 mm-wide sensor, across the image's longer side
FOCAL_35MM = 50.0
SENSOR_WIDTH_MM = 36.0

LANDMARK_VERTEX_NAMES = ("right_eye", "left_eye", "nose_tip", "mouth_center", "mouth_right",
                         "mouth_left", "chin")

#: weight of a landmark in the fit by how it was found (`Landmark.detected`)
DETECTED_WEIGHT = 1.0
ESTIMATED_WEIGHT = {"nose_tip": 0.1, "mouth_center": 0.3, "mouth_right": 0.2, "mouth_left": 0.2,
                    "right_eye": 0.5, "left_eye": 0.5}
#: heights (eye-frame v, IOD units below the eye line) where the face width is compared:
#: below the ears' lobes, down to the jaw
WIDTH_ROWS = (0.75, 0.9, 1.05, 1.2, 1.35)
#: prior weight per squared shape coefficient (IOD^2 units of the image terms)
SHAPE_PRIOR = 2e-3
#: at most this many vertices enter the silhouette terms (an even subsample)
MAX_SILHOUETTE_VERTICES = 2500
#: weight of the face-mesh landmark term (a weighted mean over the landmarks, IOD^2 units):
#: about the summed weight of the six named landmarks it joins
MESH_WEIGHT = 6.0
#: identity components fitted on a FLAME model (the rest stay 0)
FLAME_SHAPE_COMPONENTS = 20

_CV = np.diag([1.0, -1.0, -1.0])  # view frame (+Y up, looking down -Z) -> OpenCV camera axes


@contextlib.contextmanager
def torch_single_thread():
    """Run small torch problems on one thread: a few thousand vertices gain nothing from more,
    and on a busy machine OpenMP threads waiting for each other made the fit 20x slower."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def portrait_focal(width: int, height: int, focal_mm: float | None = None) -> float:
    """Focal length in pixels of the assumed portrait lens (see the module docstring), or of the
    lens the user gave: `focal_mm` 35 mm-equivalent across the image's longer side (a phone's
    main camera ~26, its selfie camera ~24: docs/video-build.md, "The camera's lens")."""
    mm = FOCAL_35MM if focal_mm is None else float(focal_mm)
    return mm / SENSOR_WIDTH_MM * max(int(width), int(height))


def view_camera(rotation, translation, width: int, height: int, focal: float | None = None) -> Camera:
    """The OpenCV camera seeing the rest head posed by (rotation (3,) axis-angle, translation (3,))
    in the view frame."""
    f = portrait_focal(width, height) if focal is None else float(focal)
    r = axis_angle_to_matrix(np.asarray(rotation, np.float64))
    m = np.eye(4)
    m[:3, :3] = _CV @ r
    m[:3, 3] = _CV @ np.asarray(translation, np.float64)
    return Camera(f, f, width / 2.0, height / 2.0, int(width), int(height), m)


@dataclass(eq=False)
class HeadFit:
    """The fitted head and the camera that saw it.

    model: the `HeadModel`; params: `HeadParams` of the REST pose (identity `shape`, zero pose and
    expression); camera: the input view's `Camera` (world = the rest head's frame);
    rotation (3,) axis-angle and translation (3,): the head's pose in the view frame (module
    docstring); rest_vertices: (V, 3) float32 rest head with this shape;
    landmarks: name -> vertex index used; residuals: figures of merit (pixels);
    source: "fitted" or "imported" (shape from a tracker's file).
    """

    model: HeadModel
    params: HeadParams
    camera: Camera
    rotation: np.ndarray
    translation: np.ndarray
    rest_vertices: np.ndarray
    landmarks: dict[str, int] = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)
    source: str = "fitted"

    @property
    def shape(self) -> np.ndarray:
        """(S,) float32 identity coefficients."""
        s = np.asarray(self.params.shape, np.float32)
        return s if s.ndim == 1 else s[0]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rest-frame points (N, 3) -> (pixels (N, 2), camera depth (N,))."""
        return self.camera.project(points)

    def with_shape(self, shape: np.ndarray) -> "HeadFit":
        """The same fit with other identity coefficients (S,) (rest vertices recomputed)."""
        params = HeadParams(shape=np.asarray(shape, np.float32),
                            expr=np.zeros((1, self.model.num_expr), np.float32))
        rest = self.model.forward(params)[0][0]
        return HeadFit(self.model, params, self.camera, self.rotation, self.translation, rest,
                       dict(self.landmarks), dict(self.residuals), self.source)

    def summary(self) -> dict:
        """JSON-able description (for the avatar's provenance)."""
        r = self.residuals
        mesh = ({"face_mesh_landmarks": int(r["face_mesh_landmarks"]),
                 "face_mesh_median_px": round(float(r["face_mesh_median_px"]), 3)}
                if "face_mesh_landmarks" in r else {})
        return {"source": self.source, "focal_px": round(self.camera.fx, 3),
                "rotation_deg": [round(float(x), 3) for x in np.degrees(self.rotation)],
                "translation_m": [round(float(x), 5) for x in self.translation],
                "shape": [round(float(x), 4) for x in self.shape],
                "landmark_rms_px": round(float(r.get("landmark_rms_px", float("nan"))), 3),
                "width_rms_px": round(float(r.get("width_rms_px", float("nan"))), 3),
                "outside_fraction": round(float(r.get("outside_fraction", float("nan"))), 4), **mesh}


# ---------------------------------------------------------------------------------------------
# named vertices on the model

def landmark_vertices(model: HeadModel, vertices: np.ndarray | None = None) -> dict[str, int]:
    """Vertex index per landmark name (LANDMARK_VERTEX_NAMES), derived from the model's regions
    and geometry (rest template, +Y up, face toward +Z): each pupil is the eyeball vertex
    farthest forward from its eye joint; the nose tip the foremost face vertex near the midline
    between the eyes and the mouth; the mouth centre the foremost lip vertex at the height of the
    mouth line on the midline; the corners the lip/mouth vertices farthest to either side; the
    chin the lowest face vertex near the midline."""
    v = np.asarray(model.v_template if vertices is None else vertices, np.float64)
    need = ("left_eye", "right_eye", "face", "lips")
    missing = [r for r in need if r not in model.regions or len(model.regions[r]) == 0]
    if missing:
        raise InputError(f"the head model has no {', '.join(missing)} region: cannot place landmarks")
    joints = model.rest_joints()[0].astype(np.float64)
    el, er = joints[3], joints[4]
    mid = 0.5 * (el + er)
    u = float(np.linalg.norm(el - er)) or 0.064
    out: dict[str, int] = {}
    for name, region, centre in (("left_eye", "left_eye", el), ("right_eye", "right_eye", er)):
        idx = model.regions[region]
        out[name] = int(idx[np.argmax(v[idx, 2] - centre[2])])
    x, y, z = (v - mid).T
    face = model.regions["face"]
    near_mid = face[np.abs(x[face]) < 0.2 * u]
    mouth = np.unique(np.concatenate([model.regions["lips"], model.regions.get("mouth_interior", [])]))
    mouth = mouth.astype(np.int64)
    mouth_y = float(np.median(y[model.regions["mouth_interior"]])) \
        if len(model.regions.get("mouth_interior", [])) else float(np.median(y[mouth]))
    nose = near_mid[(y[near_mid] < -0.1 * u) & (y[near_mid] > mouth_y + 0.2 * u)]
    if len(nose) == 0:
        nose = near_mid
    out["nose_tip"] = int(nose[np.argmax(z[nose])])
    centre = mouth[np.abs(x[mouth]) < 0.1 * u]
    if len(centre) == 0:
        centre = mouth
    band = centre[np.abs(y[centre] - mouth_y) < 0.08 * u]
    out["mouth_center"] = int(band[np.argmax(z[band])]) if len(band) else \
        int(centre[np.argmin(np.abs(y[centre] - mouth_y))])
    out["mouth_right"] = int(mouth[np.argmin(x[mouth])])   # subject's right: -X
    out["mouth_left"] = int(mouth[np.argmax(x[mouth])])
    chin = face[(np.abs(x[face]) < 0.15 * u) & (z[face] > 0)]
    if len(chin) == 0:
        chin = face
    out["chin"] = int(chin[np.argmin(y[chin])])
    return out


def _silhouette_vertices(model: HeadModel) -> np.ndarray:
    """Vertices that must project inside the head's silhouette: skin that is not neck."""
    mask = np.ones(model.num_vertices, bool)
    for region in ("neck", "eyes"):
        if region in model.regions:
            mask[model.regions[region]] = False
    return np.flatnonzero(mask)


# ---------------------------------------------------------------------------------------------
# image targets

def _signed_distance_px(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32 signed distance to the mask's boundary: > 0 outside, < 0 inside (pixels)."""
    import cv2

    m = np.ascontiguousarray(mask, np.uint8)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, 5)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, 5)
    return (outside - inside).astype(np.float32)


def face_width_targets(skin: np.ndarray, analysis, rows=None) -> np.ndarray:
    """(R, 3) rows (v, u_left, u_right) in eye-frame IOD units: the edges of the skin run that
    contains the face's midline at each height v (NaN edges where the midline is not skin)."""
    rows = WIDTH_ROWS if rows is None else rows
    h, w = skin.shape
    us = np.arange(-2.0, 2.0 + 1e-9, 0.5 / max(analysis.eye_distance, 1.0))
    out = []
    for v in rows:
        uv = np.stack([us, np.full_like(us, v)], axis=1)
        xy = analysis.from_face(uv)
        xi = np.floor(xy[:, 0]).astype(int)
        yi = np.floor(xy[:, 1]).astype(int)
        ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        s = np.zeros(len(us), bool)
        s[ok] = skin[yi[ok], xi[ok]]
        c = len(us) // 2
        if not s[c]:
            out.append((v, np.nan, np.nan))
            continue
        left = c
        while left > 0 and s[left - 1]:
            left -= 1
        right = c
        while right < len(us) - 1 and s[right + 1]:
            right += 1
        # a run that reaches the scan's end is not a face edge (skin to the image border)
        out.append((v, us[left] if left > 0 else np.nan, us[right] if right < len(us) - 1 else np.nan))
    return np.array(out, np.float64)


def _landmark_targets(analysis) -> tuple[list[str], np.ndarray, np.ndarray]:
    names, pts, weights = [], [], []
    for name, lm in analysis.landmarks.items():
        names.append(name)
        pts.append(lm.xy)
        weights.append(DETECTED_WEIGHT if lm.detected else ESTIMATED_WEIGHT.get(name, 0.1))
    return names, np.array(pts, np.float64), np.array(weights, np.float64)


# ---------------------------------------------------------------------------------------------
# the fit

def _initial_pose(analysis, rest: np.ndarray, lm: dict[str, int], focal: float, size,
                  rotation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form start: roll from the eye axis (unless `rotation` is given), distance from the
    IOD, the eyes' midpoint on its pixel."""
    w, h = size
    eyes3 = rest[[lm["right_eye"], lm["left_eye"]]].astype(np.float64)
    iod3 = float(np.linalg.norm(eyes3[1] - eyes3[0]))
    depth = focal * iod3 / max(analysis.eye_distance, 1e-6)
    if rotation is None:
        rotation = np.array([0.0, 0.0, -math.radians(analysis.roll_deg)])
    r = axis_angle_to_matrix(rotation)
    mid3 = eyes3.mean(axis=0)
    px = analysis.eye_mid
    target = np.array([(px[0] - w / 2) * depth / focal, -(px[1] - h / 2) * depth / focal, -depth])
    return rotation, target - r @ mid3


def _mesh_targets(analysis, model: HeadModel, embedding=None):
    """(LandmarkTargets, LandmarkModel) from the analysis's face mesh, or (None, None) when
    it has none or the model has no embedding."""
    mesh = getattr(analysis, "mesh", None)
    if mesh is None:
        return None, None
    from avatarkit.face.correspondence import embedding_for
    from avatarkit.face.fit import LandmarkModel, LandmarkTargets

    # no jaw in the portrait fit: the file's lower-lip hosting (`embedding_for`'s carry_jaw)
    emb = embedding if embedding is not None else embedding_for(model, carry_jaw=False)
    if emb is None:
        return None, None
    emb.check(model.num_faces)
    return LandmarkTargets.from_mesh(mesh, emb, analysis.image_size), LandmarkModel(model, emb)


def fit_head(analysis, segmentation, model: HeadModel | None = None, *, shape: np.ndarray | None = None,
             fit_shape: bool = True, focal: float | None = None, shape_components: int | None = None,
             iterations: int = 40, initial_rotation: np.ndarray | None = None,
             embedding=None) -> HeadFit:
    """Fit the head model to a portrait.

    analysis: `PortraitAnalysis`; segmentation: `Segmentation` of the same image (skin + hair
    labels give the silhouette). model: default the built-in template. shape: (S,) starting (or,
    with fit_shape=False, fixed) identity coefficients. focal: pixels (default `portrait_focal`).
    shape_components: how many leading coefficients are fitted (default all of the template's,
    FLAME_SHAPE_COMPONENTS of a FLAME). iterations: L-BFGS iterations per stage.
    initial_rotation: (3,) axis-angle start (default: solvePnP on the face mesh when the analysis
    has one, else roll from the eyes). embedding: the face-mesh `LandmarkEmbedding` of `model`
    (default: the shipped one for the template; a FLAME model needs one to use the face mesh).
    """
    import torch

    from avatarkit.lbfgs import LBFGS
    from avatarkit.recon.segment import HAIR, SKIN

    model = HeadModel.template() if model is None else model
    w, h = analysis.image_size
    labels = np.asarray(segmentation.labels)
    if labels.shape != (h, w):
        raise InputError(f"segmentation is {labels.shape[1]}x{labels.shape[0]} but the analysis was made "
                         f"on a {w}x{h} image")
    f = portrait_focal(w, h) if focal is None else float(focal)
    S = model.num_shape
    shape0 = np.zeros(S) if shape is None else np.asarray(shape, np.float64).reshape(-1)
    if len(shape0) != S:
        shape0 = np.concatenate([shape0[:S], np.zeros(max(0, S - len(shape0)))])
    if not np.isfinite(shape0).all():
        raise InputError("shape coefficients must be finite")
    k = S if shape_components is None else int(shape_components)
    if shape_components is None and model.name != "template":
        k = min(S, FLAME_SHAPE_COMPONENTS)
    k = max(0, min(S, k)) if fit_shape else 0

    rest0 = model.forward(HeadParams(shape=shape0.astype(np.float32),
                                     expr=np.zeros((1, model.num_expr), np.float32)))[0][0]
    lm = landmark_vertices(model, rest0)
    names, targets, weights = _landmark_targets(analysis)
    lm_ids = np.array([lm[n] for n in names])
    mesh_targets, lmodel = _mesh_targets(analysis, model, embedding)
    if mesh_targets is not None and initial_rotation is None:
        from avatarkit.face.fit import initial_pose

        rot0, trans0 = initial_pose(lmodel.points_numpy(shape0), mesh_targets, f)
    else:
        rot0, trans0 = _initial_pose(analysis, rest0, lm, f, (w, h),
                                     None if initial_rotation is None
                                     else np.asarray(initial_rotation, np.float64).reshape(3))
    depth0 = -float(trans0[2])
    iod = max(analysis.eye_distance, 1e-6)

    head = np.isin(labels, (SKIN, HAIR))
    sdf = torch.from_numpy(_signed_distance_px(head))[None, None].double()
    widths = face_width_targets(labels == SKIN, analysis)
    ex, ey = analysis.face_axes()
    frame = torch.tensor(np.stack([ex, ey], axis=1), dtype=torch.float64)   # (2, 2): px -> (u, v)
    eye_mid = torch.tensor(analysis.eye_mid, dtype=torch.float64)
    sil = _silhouette_vertices(model)
    sil = sil[:: max(1, len(sil) // MAX_SILHOUETTE_VERTICES)]
    used = np.concatenate([lm_ids, sil] + ([lmodel.used] if lmodel is not None else []))
    t_lm = torch.from_numpy(targets)
    t_w = torch.from_numpy(weights)
    lm_idx = torch.arange(len(lm_ids))
    sil_ids = torch.arange(len(lm_ids), len(lm_ids) + len(sil))
    if lmodel is not None:
        from avatarkit.face.fit import landmark_loss

        mesh_corners = torch.from_numpy(len(lm_ids) + len(sil) + lmodel.corner_rows)   # (K, 3)
        mesh_bary = torch.from_numpy(lmodel.bary)[:, :, None]
    cv = torch.tensor(_CV, dtype=torch.float64)
    # The rest pose is the template plus the shape blendshapes (no pose, so no skinning): linear
    # in the coefficients, evaluated as such on the vertices the losses use.
    base = torch.from_numpy(rest0[used].astype(np.float64))
    basis = torch.from_numpy(model.shapedirs[used][:, :, :k].astype(np.float64))   # (U, 3, k)
    shape_start = torch.from_numpy(shape0[:k])

    rot = torch.tensor(rot0, dtype=torch.float64, requires_grad=True)
    dtrans = torch.zeros(3, dtype=torch.float64, requires_grad=True)   # in units of the distance
    dshape = torch.zeros(k, dtype=torch.float64, requires_grad=True)
    trans_base = torch.from_numpy(trans0)

    from avatarkit.head.lbs import axis_angle_to_matrix_torch

    def pixels(verts, idx, with_depth=False):
        r = axis_angle_to_matrix_torch(rot)
        p = (verts[idx] if idx is not None else verts) @ r.T + trans_base + depth0 * dtrans
        c = p @ cv.T
        z = c[:, 2].clamp_min(1e-3)
        px = torch.stack([f * c[:, 0] / z + w / 2, f * c[:, 1] / z + h / 2], dim=1)
        return (px, z) if with_depth else px

    def mesh_points(v):
        return (mesh_bary * v[mesh_corners]).sum(1)

    def vertices():
        return base + basis @ dshape if k else base

    def to_face(px):
        return (px - eye_mid) @ frame / iod

    def losses(use_silhouette: bool):
        v = vertices()
        px = pixels(v, lm_idx)
        d2 = ((px - t_lm) ** 2).sum(1) / iod ** 2
        out = {"landmarks": (t_w * d2).sum()}
        if lmodel is not None:
            mpx, mz = pixels(mesh_points(v), None, with_depth=True)
            terms = landmark_loss(mpx, mz, mesh_targets, f)
            out["face_mesh"] = MESH_WEIGHT * terms["points"]
            out["face_mesh_depth"] = MESH_WEIGHT * terms["depth"]
        if use_silhouette:
            sp = pixels(v, sil_ids)
            grid = torch.stack([2 * sp[:, 0] / w - 1, 2 * sp[:, 1] / h - 1], dim=1)[None, None]
            dist = torch.nn.functional.grid_sample(sdf, grid, align_corners=False, padding_mode="border")[0, 0, 0]
            out["inside"] = 0.5 * (torch.relu(dist - 1.0) / iod).pow(2).mean()
            uv = to_face(sp)
            width = uv.new_zeros(())
            tau, band = 0.02, 0.04
            for row_v, left, right in widths:
                logm = -((uv[:, 1] - row_v) / band) ** 2
                if not np.isnan(left):
                    soft_min = -tau * torch.logsumexp(-uv[:, 0] / tau + logm, 0)
                    width = width + (soft_min - left) ** 2
                if not np.isnan(right):
                    soft_max = tau * torch.logsumexp(uv[:, 0] / tau + logm, 0)
                    width = width + (soft_max - right) ** 2
            out["width"] = width
            out["prior"] = SHAPE_PRIOR * ((shape_start + dshape) ** 2).sum() if k else width.new_zeros(())
        return out

    def run(params, use_silhouette):
        opt = LBFGS(params, lr=1.0, max_iter=iterations, line_search_fn="strong_wolfe",
                                tolerance_grad=1e-10, tolerance_change=1e-12, history_size=20)

        def closure():
            opt.zero_grad()
            loss = sum(losses(use_silhouette).values())
            loss.backward()
            return loss
        opt.step(closure)

    with torch_single_thread():
        run([rot, dtrans], False)
        run([rot, dtrans, dshape] if k else [rot, dtrans], True)

    with torch.no_grad():
        final = {n: float(x) for n, x in losses(True).items()}
        v = vertices()
        px = pixels(v, lm_idx).numpy()
        sp = pixels(v, sil_ids).numpy()
        uv = to_face(torch.from_numpy(sp)).numpy()
        mesh_px = pixels(mesh_points(v), None).numpy() if lmodel is not None else None
    rotation = rot.detach().numpy().copy()
    translation = (trans0 + depth0 * dtrans.detach().numpy()).copy()
    shape_final = shape0.copy()
    if k:
        shape_final[:k] += dshape.detach().numpy()
    params = HeadParams(shape=shape_final.astype(np.float32), expr=np.zeros((1, model.num_expr), np.float32))
    rest = model.forward(params)[0][0]
    camera = view_camera(rotation, translation, w, h, f)

    err = np.linalg.norm(px - targets, axis=1)
    detected = np.array([analysis.landmarks[n].detected for n in names])
    sel = detected if detected.any() else np.ones(len(names), bool)
    xi = np.clip(np.floor(sp[:, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.floor(sp[:, 1]).astype(int), 0, h - 1)
    inside_img = (sp[:, 0] >= 0) & (sp[:, 0] < w) & (sp[:, 1] >= 0) & (sp[:, 1] < h)
    outside = ~(inside_img & head[yi, xi])
    width_err = []
    for row_v, left, right in widths:
        in_row = np.abs(uv[:, 1] - row_v) < 0.03
        if not in_row.any():
            continue
        if not np.isnan(left):
            width_err.append((uv[in_row, 0].min() - left) * iod)
        if not np.isnan(right):
            width_err.append((uv[in_row, 0].max() - right) * iod)
    residuals = {
        "landmark_rms_px": float(np.sqrt(np.mean(err[sel] ** 2))),
        "landmark_px": {n: round(float(e), 3) for n, e in zip(names, err)},
        "width_rms_px": float(np.sqrt(np.mean(np.square(width_err)))) if width_err else float("nan"),
        "outside_fraction": float(outside.mean()),
        "loss": final,
    }
    if lmodel is not None:
        from avatarkit.face.fit import pixel_errors

        mesh_err = pixel_errors(mesh_px, mesh_targets)
        residuals["face_mesh_landmarks"] = len(mesh_err)
        residuals["face_mesh_median_px"] = float(np.median(mesh_err))
    return HeadFit(model, params, camera, rotation, translation, rest, lm, residuals,
                   "fitted" if fit_shape else "imported")


# ---------------------------------------------------------------------------------------------
# a tracker's parameters

def load_flame_params(path: str | os.PathLike) -> HeadParams:
    """Read a tracker's FLAME fit (npz with GaussianAvatars / VHAP keys: `shape` (S,) or (1, S),
    optionally rotation, translation, neck_pose, jaw_pose, eyes_pose, expr). Only the identity
    shape (and the first frame's rotation, as a starting point) is used by the build."""
    from avatarkit.fileio import read_npz

    p = Path(path)
    if not p.is_file():
        raise InputError("FLAME parameter file not found", p)
    data = read_npz(p)
    if "shape" not in data and "betas" not in data:
        raise FormatError(f"no 'shape' array (keys: {', '.join(sorted(data)) or 'none'}); a FLAME "
                          "tracker's npz stores the identity as 'shape' (S,) or (1, S)", p)
    try:
        params = HeadParams.from_dict(data)
    except InputError as e:
        raise FormatError(e.message, p) from None
    shape = params.shape
    if shape.ndim == 2:  # per-frame shape: a tracker that did not share it; take the mean
        params = HeadParams.from_dict({**{k: v for k, v in data.items() if k not in ("shape", "betas")},
                                       "shape": shape.mean(axis=0)})
    return params


def fit_with_params(analysis, segmentation, model: HeadModel, params: HeadParams, **kwargs) -> HeadFit:
    """The head fit for a tracker's parameters: their identity shape is kept as is, only the
    camera (head pose) is fitted to the landmarks and silhouette, starting from their rotation."""
    shape = np.asarray(params.shape, np.float64)
    rotation = np.asarray(params.rotation[0], np.float64) if params.rotation is not None else None
    if rotation is not None and not np.any(rotation):
        rotation = None
    return fit_head(analysis, segmentation, model, shape=shape, fit_shape=False,
                    initial_rotation=rotation, **kwargs)


# ---------------------------------------------------------------------------------------------
# masks of the fitted head

def project_mask(fit: HeadFit, faces: np.ndarray | None = None, vertices: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: pixels covered by the projection of the given faces (default all) of the rest
    head (or of `vertices` (V, 3)) in the input view."""
    import cv2

    v = fit.rest_vertices if vertices is None else np.asarray(vertices)
    f = fit.model.faces if faces is None else np.asarray(faces)
    cam = fit.camera
    px, z = cam.project(v)
    tri = px[f]
    ok = np.isfinite(tri).all(axis=(1, 2)) & (z[f] > 0).all(axis=1)
    out = np.zeros((cam.height, cam.width), np.uint8)
    if ok.any():
        shift = 4  # sub-pixel vertices: cv2 takes fixed point with `shift` fractional bits
        pts = np.round((tri[ok] - 0.5) * (1 << shift)).astype(np.int32)
        # one polygon per call: fillPoly's scanline fill of many contours at once is even-odd,
        # so the front and back of the head would cancel where they overlap
        for tri_px in pts:
            cv2.fillConvexPoly(out, tri_px, 1, lineType=cv2.LINE_8, shift=shift)
        # triangles smaller than a pixel may cover no pixel centre: draw every edge too
        cv2.polylines(out, list(pts), True, 1, lineType=cv2.LINE_8, shift=shift)
    return out.astype(bool)


def scalp_hint(fit: HeadFit) -> np.ndarray:
    """(H, W) bool: where the fitted bald head is in the image (the head without the neck), for
    the 2D bald filter's scalp fill."""
    model = fit.model
    keep = np.ones(model.num_faces, bool)
    if "neck" in model.regions:
        keep &= ~model.region_mask("neck")[model.faces].all(axis=1)
    return project_mask(fit, model.faces[keep])


# ---------------------------------------------------------------------------------------------
# a synthetic portrait with a known answer (tests, benchmarks)

@dataclass(eq=False)
class SyntheticHead:
    """A rendered template head with known pose and shape: image (H, W, 3) uint8; analysis
    (landmarks = the true projections of the landmark vertices, flagged detected); segmentation
    (skin where the head renders, background elsewhere); truth: the exact `HeadFit`."""

    image: np.ndarray
    analysis: object
    segmentation: object
    truth: HeadFit
    alpha: np.ndarray


def synthetic_head_view(rotation=(0.0, 0.0, 0.0), distance: float = 0.6, shape=None, size: int = 256,
                        n_gaussians: int = 30000, seed: int = 0, offset=(0.0, 0.0),
                        background=(0.47, 0.59, 0.73), light=None, ambient: float = 0.35,
                        focal: float | None = None) -> SyntheticHead:
    """Render the template head (bald Gaussians on its surface, `synthetic.sample_avatar`) posed
    by `rotation` (3,) axis-angle in the view frame, its eye midpoint at `distance` metres in
    front of the camera, shifted by `offset` (x, y) metres.

    light: None (flat colours, as the avatar's), or a direction (3,) toward the light in the
    camera's frame (x right, y down, z forward: e.g. (-0.4, -0.5, -1) from the upper left
    front): each Gaussian's colour is scaled by ambient + (1 - ambient) max(0, n.l) with n its
    host triangle's normal, so the shading follows the head's pose like a photo's. focal: the
    camera's, pixels (default `portrait_focal`: another lens is a mismatch the fit is told of)."""
    import dataclasses

    from avatarkit.export.images import to_uint8
    from avatarkit.recon.portrait import Landmark, analysis_from_box
    from avatarkit.recon.segment import BACKGROUND, SKIN, ColourModel, Segmentation, rgb_to_lab
    from avatarkit.render import render
    from avatarkit.synthetic.sample_avatar import make_bald

    model = HeadModel.template()
    s = np.zeros(model.num_shape, np.float32) if shape is None else np.asarray(shape, np.float32)
    params = HeadParams(shape=s, expr=np.zeros((1, model.num_expr), np.float32))
    rest = model.forward(params)[0][0]
    lm = landmark_vertices(model, rest)
    rot = np.asarray(rotation, np.float64)
    mid = rest[[lm["right_eye"], lm["left_eye"]]].astype(np.float64).mean(axis=0)
    trans = np.array([offset[0], offset[1], -distance]) - axis_angle_to_matrix(rot) @ mid
    cam = view_camera(rot, trans, size, size, focal)
    bald = make_bald(model, rest, n_gaussians, seed)
    if light is not None:
        tri = np.asarray(rest, np.float64)[model.faces[bald.extras["binding"]]]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        to_light = cam.rotation.T @ (np.asarray(light, np.float64) / np.linalg.norm(light))  # world frame
        shade = ambient + (1.0 - ambient) * np.clip(n @ to_light, 0.0, None)
        bald = bald.with_colors(np.clip(bald.colors * shade[:, None], 0.0, 1.0))
    r = render(bald, cam, background=background)
    image = to_uint8(r.rgb)
    labels = np.where(r.alpha > 0.5, SKIN, BACKGROUND).astype(np.uint8)
    px, _ = cam.project(rest[[lm[n] for n in ("right_eye", "left_eye")]])
    iod = float(np.linalg.norm(px[1] - px[0]))
    bw = iod / 0.46
    centre = px.mean(axis=0)
    box = (int(centre[0] - bw / 2), int(centre[1] - 0.375 * bw), int(bw), int(bw))
    analysis = analysis_from_box((size, size), box)
    names = ("right_eye", "left_eye", "nose_tip", "mouth_center", "mouth_right", "mouth_left")
    pts, _ = cam.project(rest[[lm[n] for n in names]])
    landmarks = {n: Landmark(p[0], p[1], True, "truth") for n, p in zip(names, pts)}
    analysis = dataclasses.replace(analysis, landmarks=landmarks,
                                   roll_deg=float(np.degrees(np.arctan2(pts[1, 1] - pts[0, 1], pts[1, 0] - pts[0, 0]))))
    skin = rgb_to_lab(image[labels == SKIN])
    segmentation = Segmentation(labels, ColourModel.fit(skin), None, "none")
    truth = HeadFit(model, params, cam, rot, trans, rest, lm, {}, "truth")
    return SyntheticHead(image, analysis, segmentation, truth, r.alpha)


__all__ = ["FOCAL_35MM", "HeadFit", "LANDMARK_VERTEX_NAMES", "face_width_targets", "fit_head",
           "fit_with_params", "landmark_vertices", "load_flame_params", "portrait_focal",
           "project_mask", "scalp_hint", "synthetic_head_view", "view_camera"]
