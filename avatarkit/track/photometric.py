"""Refine one frame's rigid head pose against the frame by rendering the avatar (analysis by
synthesis), when the avatar the video shows is known (`track --avatar`, `evaluate`).

The landmark fit (`track.solve`) reads the pose from the face mesh's 468 points, which sit on a
turned face with a pose-dependent bias (docs/tracking.md). Here the avatar is rendered at the
frame's tracked parameters and compared with the frame itself; the rigid pose (rotation,
translation) moves, and with `Settings.jaw` the jaw's opening; the rest of the jaw, the
expression and eyes stay the landmark fit's.

`PoseRefiner.refine` (the fast path), per outer iteration:
1. render the avatar posed by the frame's parameters at `Settings.size` pixels (longer side),
   over the frame itself (so the background compares equal), the hair riding the head rigidly
   (`subject_calibration._turned`), the head's Gaussians following jaw, expression and eyes;
2. rasterise the posed head mesh (`synthetic.mesh_raster`) for each pixel's 3D point on the head,
   keeping only the pixels of the face and scalp (not the neck: in a talking-head video it does
   not move with the head, docs/tracking.md "The head on the neck") that the render covers;
3. dense optical flow render -> frame (`cv2.DISOpticalFlow`), kept where the flow back frame ->
   render returns to within `fb_tolerance` pixels;
4. a robust (Huber, iteratively reweighted) Gauss-Newton for the 6-DoF pose change that moves
   the 3D points onto their flowed image positions (a linearised PnP), the rotation about the
   points' centroid; a small ridge keeps a poorly seen direction (depth) from running away.
It stops after `Settings.iterations` renders or when a pass's change is below
`Settings.tolerance` (rotation) and `Settings.shift_tolerance` (translation).

What makes a pass cheap (session 13, second round; docs/tracking.md): the avatar is posed
(jaw, expression, eyes) and turned to the frame's starting pose once per frame; each pass's pose
change is the inverse rigid change of the CAMERA (`Settings.move_camera`), so no pass re-turns
the ~80k Gaussians. Optionally (`Settings.crop_margin`, off) only the head's box on the image
(the projected face-and-scalp mesh at the pass's pose plus a margin) is rendered, rasterised and
flowed, through a `Camera` of that size whose principal point is shifted by the box's corner
(`crop_camera`: the same pixels as the whole frame's render). `render` (the avatar turned by the
pose) stays as the obvious version; a test compares the two. Since session 15 the frame's
Gaussians are made at the starting pose directly (`placed`: the head's bound to the turned mesh,
only the hair turned), the Gauss-Newton's Jacobian rows are written out
(`solve_pose_delta_reference` is the obvious one), and `Settings.front_faces` (off) rasterises only
the mesh's faces turned to the camera: together 1.4-1.5x (1.7x with front faces) a refined frame,
docs/tracking.md "Session 15". Session 16's cheaper pass (`CHEAP_PASS`: the solve on every 2nd
pixel's row and column, the head mesh rasterised once per frame at half the size and warped to
each pass's pose): docs/tracking.md "Session 16: a cheaper pass".

The jaw (`Settings.jaw`, session 14): the jaw's opening (the FLAME jaw pose's first axis) is
a seventh unknown of the same Gauss-Newton. Each 3D point carries its derivative by the opening
(`jaw_derivative`: a central difference of the posed head vertices, rasterised with the points,
so the lips and chin, skinned to the jaw joint, move with it and the rest does not); the mouth's
inside (`mouth_interior`) is left out of the points (a poor model: dark discs where the lips
part). A quadratic prior pulls the opening toward the landmark fit's (`jaw_sigma`: an opening
that far from it costs as much as one pixel's error on every point used), so an opening the
frame barely shows does not run away. A pass whose opening changed re-poses the Gaussians the
jaw moves (~1/6 of them) and turns them to the frame's starting pose (`rejawed`; the rest, the
hair included, keep their turn).

Why a pass recovered only ~2/3 of the turn (session 14, `Settings.render_depth`): the 3D
points came from the head mesh, while the image the flow follows is the splats', whose surface
sits off the mesh (portrait build: a median 1.6 mm, more at the hairline and the outline). The
parallax that tells a turn from a shift is read with the wrong depths. With each pixel's point
taken from the render's own depth (`render_moved(depth=True)`, `unproject`; the mesh raster still
gives the face-and-scalp weight and the jaw's derivative), one pass from 2.7 deg off lands 0.50
deg off instead of 0.99 (with the true image motion in place of the flow: 0.17 / 0.08; the
flow's gain against the true motion is ~1 everywhere, so it is not the flow's scale).

`refine_reference` (the slow obvious reference): a pattern search (`register.pattern_search`)
over the same 6 parameters on the mean squared colour difference between the render (over the
frame) and the frame inside the face region of the starting pose, dilated (with the jaw: over
the opening too, without the prior).

Poses are the tracker's view frame (`track.tracker`): X_view = R X_head + t, X_head the head
model's vertices at zero root pose with the frame's jaw, expression and eyes; the camera is the
OpenCV pinhole diag(1, -1, -1) at the origin, focal `focal`, principal point at the image centre.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.render.camera import Camera
from avatarkit.rotations import axis_angle_to_matrix, matrix_to_axis_angle

_C = np.diag([1.0, -1.0, -1.0])


@dataclass
class Settings:
    """size: the longer side (px) rendered and compared at; iterations: renders (outer
    iterations) at most; tolerance: stop when the rotation changes less than this (radians) and
    the translation less than `shift_tolerance` (m); gauss_newton: reweighted solves per render;
    supersample: the render is made at this many times `size` and area-averaged down as the
    frame is (a splat render at 224 px compared with a 480 px frame scaled down read the pose
    0.56 deg / 2.2 mm off the truth on the portrait avatar: a splat's footprint does not scale
    with the image);
    huber: the Huber threshold (px, at `size`); fb_tolerance: forward-backward flow mismatch
    (px) above which a pixel is dropped; min_points: fewer kept pixels: no change; ridge: the
    normal equations' ridge relative to their trace / 6;
    move_camera: a pass's pose change moves the camera, the Gaussians turned once per frame
    (False: each pass turns them, `render`); crop_margin: render and flow only the head's box on
    the image plus this many pixels (at `size`) each side (None, the default: the whole frame;
    the crop saves little, a render's cost is its Gaussians', and DIS on the smaller image flows
    differently: mirrored synthetic clip 2.05 -> 2.31 deg at 16 px, docs/tracking.md).
    Until session 13's second round: tolerance 2e-4, shift_tolerance 2e-5, move_camera False,
    crop_margin None (`SESSION13`).
    jaw: also refine the jaw's opening (FLAME jaw pose, its first axis; the other two stay the
    landmark fit's) with the pose (module docstring, "The jaw"); jaw_sigma: its prior toward the
    landmark fit's opening (radians): an opening that far from it costs as much as one pixel's
    error on every point used; jaw_tolerance: with the jaw, a pass also stops the refinement
    only when the opening changes less than this (radians).
    render_depth: each pixel's 3D point from the render's own depth (the splats' expected
    depth) instead of the head mesh's raster (which still gives the face weight and the jaw's
    derivative): module docstring, "Why a pass recovered only ~2/3".
    front_faces: rasterise only the head mesh's faces that face the camera (a closed head's
    others lie behind them; the raster takes ~0.7x the time; where a lip's inside was the
    nearest face, the next one behind it is drawn).
    Session 16's cheaper-pass settings (docs/tracking.md "Session 16: a cheaper pass"):
    stride: the Gauss-Newton uses the kept pixels on every stride-th row and column only (the
    flow is smooth at `size`; the jaw's prior scales with the points used, so it weighs the
    same against them); raster_once: with `render_depth`, the head mesh is rasterised (the
    face weight, the jaw's derivative) once per frame, at the first pass's pose, and each later
    pass reads it where its pixels' points (from its render's depth) were at that pose
    (`warped`; read where it was drawn instead, the jaw's derivative and the mouth's edge sit
    a first pass's change (~3 px) off: -0.14 dB on the grey clip); raster_scale: with
    `render_depth`, the head mesh is rasterised at this fraction of `size` and resized back
    (`scaled_points`)."""

    size: int = 224
    supersample: int = 2
    iterations: int = 4
    tolerance: float = float(np.radians(0.05))
    shift_tolerance: float = 2e-4
    gauss_newton: int = 4
    huber: float = 1.0
    fb_tolerance: float = 1.0
    min_points: int = 150
    ridge: float = 1e-3
    move_camera: bool = True
    crop_margin: int | None = None
    jaw: bool = False
    jaw_sigma: float = 0.3
    render_depth: bool = False
    jaw_tolerance: float = 2e-3
    front_faces: bool = False
    stride: int = 1
    raster_once: bool = False
    raster_scale: float = 1.0


# session 16's cheaper pass (docs/tracking.md "Session 16: a cheaper pass")
CHEAP_PASS = dict(stride=2, raster_once=True, raster_scale=0.5)

# the first round's settings (every pass turns the Gaussians and renders the whole frame; the
# passes stop only at 0.011 deg / 0.02 mm): the speed baseline of docs/tracking.md
SESSION13 = dict(tolerance=2e-4, shift_tolerance=2e-5, move_camera=False, crop_margin=None)


@dataclass
class Refinement:
    """rotation (3,) axis-angle and translation (3,) metres: the refined pose (view frame);
    renders: outer iterations run; points: pixels used in the last solve; residual: their
    median image distance (px at `Settings.size`) after it, before it: `start_residual`; jaw
    (3,): the refined jaw pose (the one given where `Settings.jaw` is off)."""

    rotation: np.ndarray
    translation: np.ndarray
    renders: int
    points: int
    residual: float
    start_residual: float
    jaw: np.ndarray | None = None


def view_camera(focal: float, size: tuple[int, int], longer: int | None) -> Camera:
    """The tracker's camera (module docstring) for a frame of `size` (W, H), scaled so its
    longer side is `longer` pixels (None: as it is)."""
    W, H = int(size[0]), int(size[1])
    w2c = np.eye(4)
    w2c[:3, :3] = _C
    cam = Camera(float(focal), float(focal), W / 2.0, H / 2.0, W, H, w2c)
    if longer is None or max(W, H) <= longer:
        return cam
    k = longer / max(W, H)
    return cam.with_size(max(1, int(round(W * k))), max(1, int(round(H * k))))


def pose_matrix(rotation, translation) -> np.ndarray:
    """(4, 4) X_view = R X + t."""
    a = np.eye(4)
    a[:3, :3] = axis_angle_to_matrix(np.asarray(rotation, np.float64)).astype(np.float64)
    a[:3, 3] = np.asarray(translation, np.float64)
    return a


def apply_delta(rotation, translation, delta: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose moved by delta (6,) (w: a turn (axis-angle) about `centre` (3,), view frame;
    d: then a shift): R' = exp(w) R, t' = exp(w) (t - centre) + centre + d."""
    E = axis_angle_to_matrix(delta[:3])
    R = axis_angle_to_matrix(rotation)
    t = np.asarray(translation, np.float64)
    c = np.asarray(centre, np.float64)
    return matrix_to_axis_angle(E @ R), E @ (t - c) + c + np.asarray(delta[3:6], np.float64)


class PoseRefiner:
    """An avatar's head-pose refiner for frames of `size` (W, H) seen with focal `focal` px
    (module docstring). The posed avatar of the last (jaw, expression, eyes) is kept, so the
    outer iterations of one frame pose the Gaussians once."""

    def __init__(self, avatar, focal: float, size: tuple[int, int], settings: Settings | None = None):
        from avatarkit.track.subject_calibration import _rest_person

        self.avatar = avatar
        self.model = avatar.head_model
        self.shape = np.asarray(avatar.shape, np.float32).reshape(-1)
        self.settings = settings or Settings()
        self.size = (int(size[0]), int(size[1]))
        self.focal = float(focal)
        self.camera = view_camera(self.focal, self.size, self.settings.size)
        rest, self.axis = _rest_person(avatar)
        n_bald = len(avatar.bald)
        self.hair = rest.replace(means=rest.means[n_bald:], quats=rest.quats[n_bald:], scales=rest.scales[n_bald:],
                                 opacities=rest.opacities[n_bald:], sh=rest.sh[n_bald:], extras={}) \
            if len(rest) > n_bald else None
        # the face and scalp: every vertex that is not the neck's (the neck stays with the body)
        weight = np.ones(self.model.num_vertices)
        if "neck" in self.model.regions:
            weight[self.model.regions["neck"]] = 0.0
        self.vertex_weight = weight
        # with the jaw: not the mouth's inside either (a poor model: where the lips part the
        # render shows whatever the avatar put there, dark discs on a portrait's build)
        jw = weight.copy()
        if "mouth_interior" in self.model.regions:
            jw[self.model.regions["mouth_interior"]] = 0.0
        self.jaw_weight = jw
        self._jaw_ids = None
        self._key = None
        self._posed = None

    # -- the avatar at a frame's non-rigid parameters, root at rest ----------------------------
    def _params(self, jaw, expr, eyes):
        from avatarkit.head.model import HeadParams

        E = self.model.num_expr
        ex = np.zeros(E)
        e = np.asarray(expr, np.float64).reshape(-1)[:E]
        ex[:len(e)] = e
        return ex, HeadParams(expr=ex[None].astype(np.float32), rotation=np.zeros((1, 3), np.float32),
                              translation=np.zeros((1, 3), np.float32), neck=np.zeros((1, 3), np.float32),
                              jaw=np.asarray(jaw, np.float32).reshape(1, 3),
                              eyes=np.asarray(eyes, np.float32).reshape(1, 6), shape=self.shape)

    def posed(self, jaw, expr, eyes):
        """(GaussianSet of the avatar at zero root pose with this jaw (3,), expression (E,) and
        eyes (6,); head vertices (V, 3) float64)."""
        from avatarkit.gaussians.gaussian_set import GaussianSet
        from avatarkit.rig.binding_kernel import binding_to_world

        ex, params = self._params(jaw, expr, eyes)
        key = (tuple(np.round(np.asarray(jaw, np.float64), 12)), tuple(np.round(ex, 12)),
               tuple(np.round(np.asarray(eyes, np.float64), 12)))
        if key != self._key:
            v = self.model.forward(params)[0][0]
            means, quats, scales = binding_to_world(self.avatar.binding, np.ascontiguousarray(v, np.float32))
            parts = [self.avatar.bald.replace(means=means, quats=quats, scales=scales, extras={})]
            if self.hair is not None:
                parts.append(self.hair)
            self._posed = (GaussianSet.concat(parts), v.astype(np.float64))
            self._key = key
        return self._posed

    def placed(self, jaw, expr, eyes, a0: np.ndarray, binding=None):
        """(what `_turned(posed(jaw, expr, eyes)[0], axis, a0)` draws: the avatar at this jaw
        (3,), expression (E,) and eyes (6,) turned and shifted by a0 (4, 4); the head vertices
        (V, 3) float64 at zero root pose), made without turning the head's Gaussians: they are
        bound to the head mesh turned by a0 (a triangle's frame turns with it), so only the hair
        is turned (session 15: a turn of all ~80k, validated, cost 2-4x binding them; a test
        compares the two). binding: the head's Gaussians' (a subset's, `rejawed`); then only
        those, (means, quats, scales) and the vertices."""
        from avatarkit.gaussians.gaussian_set import GaussianSet
        from avatarkit.rig.binding_kernel import binding_to_world
        from avatarkit.track.subject_calibration import _turned

        v = self.model.forward(self._params(jaw, expr, eyes)[1])[0][0].astype(np.float64)
        # bound to the turned mesh about the head's origin, then shifted: float32 vertices half
        # a metre off would round the small triangles' frames ~10x more than these
        vt = np.ascontiguousarray(v @ a0[:3, :3].T, np.float32)
        m, q, sc = binding_to_world(self.avatar.binding if binding is None else binding, vt)
        m = (m + a0[:3, 3]).astype(np.float32)
        if binding is not None:
            return (m, q, sc), v
        bald = self.avatar.bald
        if self.hair is None:
            return GaussianSet.from_checked(m, q, sc, bald.opacities, bald.sh), v
        hair = _turned(self.hair, self.axis, a0)
        k = max(bald.sh.shape[1], hair.sh.shape[1])
        sh = np.zeros((len(bald) + len(hair), k, 3), np.float32)
        sh[:len(bald), :bald.sh.shape[1]], sh[len(bald):, :hair.sh.shape[1]] = bald.sh, hair.sh
        return GaussianSet.from_checked(np.concatenate([m, hair.means]), np.concatenate([q, hair.quats]),
                                        np.concatenate([sc, hair.scales]),
                                        np.concatenate([bald.opacities, hair.opacities]), sh), v

    def jaw_derivative(self, jaw, expr, eyes, step: float = 0.01) -> np.ndarray:
        """(V, 3) the head vertices' derivative (zero root pose) by the jaw's opening (its first
        axis), a central difference of `step` radians (the model is float32: a smaller step is
        rounding; the opening moves the vertices by a turn about the jaw joint, skinned, plus
        pose correctives: smooth at this scale)."""
        out = []
        for k in (1.0, -1.0):
            j = np.asarray(jaw, np.float64).reshape(3).copy()
            j[0] += k * step
            out.append(self.model.forward(self._params(j, expr, eyes)[1])[0][0].astype(np.float64))
        return (out[0] - out[1]) / (2.0 * step)

    def render(self, person, rotation, translation, frame_small: np.ndarray,
               camera: Camera | None = None, depth: bool = False):
        """(render over the frame (h, w, 3) float32 in [0, 1], alpha (h, w)[, depth (h, w)]) of
        the posed `person` turned and shifted by the pose (the obvious way: every Gaussian
        moved), seen by `camera` (a `crop_camera`; None: the small camera), `frame_small` its
        size."""
        from avatarkit.track.subject_calibration import _turned

        return self.render_moved(_turned(person, self.axis, pose_matrix(rotation, translation)), np.eye(4),
                                 frame_small, camera, depth)

    def render_moved(self, moved, change: np.ndarray, frame_small: np.ndarray,
                     camera: Camera | None = None, depth: bool = False):
        """`render` of Gaussians `moved` (already turned to a pose a0, view frame) at the pose
        change @ a0, change (4, 4): the camera moves by the inverse change instead of the
        Gaussians (the same image up to the hair's twist: `_turned` turns a principal-axis
        hair Gaussian by the shortest arc, which a composition of turns does only to second
        order). depth: also the splats' expected camera depth (h, w) (the renderer's, weighted by
        its alpha, area-averaged as the colours are, divided by the averaged alpha: 0 where
        nothing is drawn)."""
        from avatarkit.render import render

        import cv2

        cam = self.camera if camera is None else camera
        k = max(1, int(self.settings.supersample))
        big = cam.with_size(cam.width * k, cam.height * k)
        big = Camera(big.fx, big.fy, big.cx, big.cy, big.width, big.height,
                     big.world_to_camera @ np.asarray(change, np.float64))
        r = render(moved, big, (0.0, 0.0, 0.0))
        # the renderer's depth is already divided by its alpha: weight it back by the alpha
        # before the area average, so a pixel's depth is the average over what its sub-pixels drew
        rgb, alpha, za = r.rgb, r.alpha, r.depth * r.alpha
        if k > 1:
            size = (cam.width, cam.height)
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
            alpha = cv2.resize(alpha, size, interpolation=cv2.INTER_AREA)
            za = cv2.resize(za, size, interpolation=cv2.INTER_AREA) if depth else za
        a = np.clip(alpha, 0.0, 1.0)[..., None]
        comp = np.clip(rgb + (1.0 - a) * frame_small, 0.0, 1.0).astype(np.float32)
        if not depth:
            return comp, alpha
        return comp, alpha, np.where(alpha > 1e-3, za / np.maximum(alpha, 1e-3), 0.0)

    def box(self, vertices: np.ndarray, rotation, translation, margin: int) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1): the small camera's pixels holding the face-and-scalp mesh at the
        pose, `margin` pixels more each side, within the image."""
        a = pose_matrix(rotation, translation)
        v = vertices[self.vertex_weight > 0] @ a[:3, :3].T + a[:3, 3]
        uv, _ = project(v, self.camera)
        W, H = self.camera.width, self.camera.height
        x0, y0 = np.floor(uv.min(0)).astype(int) - margin
        x1, y1 = np.ceil(uv.max(0)).astype(int) + margin
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(W, x1), min(H, y1)
        if x1 - x0 < 8 or y1 - y0 < 8:                 # off the image: the whole frame
            return 0, 0, W, H
        return int(x0), int(y0), int(x1), int(y1)

    def crop_camera(self, box: tuple[int, int, int, int]) -> Camera:
        """The small camera's view of `box`'s pixels only (the principal point shifted by its
        corner): its pixel (i, j) is the small camera's (i + y0, j + x0)."""
        x0, y0, x1, y1 = box
        c = self.camera
        return Camera(c.fx, c.fy, c.cx - x0, c.cy - y0, x1 - x0, y1 - y0, c.world_to_camera)

    def points(self, vertices: np.ndarray, rotation, translation, camera: Camera | None = None,
               derivative: np.ndarray | None = None, weight: np.ndarray | None = None):
        """Per pixel of `camera` (None: the small camera): (the head's 3D point (h, w, 3), view
        frame; the face weight (h, w), 0 where the head mesh does not cover the pixel or it is
        the neck's (`weight` (V,): this per-vertex weight instead of `vertex_weight`)); with
        `derivative` (V, 3) (head frame, `jaw_derivative`) also the point's derivative (h, w, 3),
        view frame, interpolated as the points are."""
        from avatarkit.synthetic.mesh_raster import rasterise

        a = pose_matrix(rotation, translation)
        v = vertices @ a[:3, :3].T + a[:3, 3]
        wv = self.vertex_weight if weight is None else weight
        cols = [v, wv[:, None]] + ([] if derivative is None else [derivative @ a[:3, :3].T])
        faces = self.model.faces
        if self.settings.front_faces:
            # the camera is at the origin: a face faces it when its normal points back at it
            n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
            faces = faces[np.einsum("ij,ij->i", n, v[faces].mean(axis=1)) < 0]
        ras = rasterise(v, faces, np.concatenate(cols, 1), self.camera if camera is None else camera)
        w = np.where(ras.covered, ras.attributes[..., 3], 0.0)
        if derivative is None:
            return ras.attributes[..., :3], w
        return ras.attributes[..., :3], w, ras.attributes[..., 4:7]

    def scaled_points(self, vertices: np.ndarray, rotation, translation, camera: Camera, scale: float,
                      derivative: np.ndarray | None = None, weight: np.ndarray | None = None):
        """`points` rasterised at `scale` times `camera`'s size and resized back to it
        (bilinear; `Settings.raster_scale`: the weight's and the derivative's edges blur by
        about a pixel; the points too, so only where the render's depth replaces them)."""
        import cv2

        small = camera.with_size(max(1, int(round(camera.width * scale))), max(1, int(round(camera.height * scale))))
        out = self.points(vertices, rotation, translation, small, derivative, weight)
        return tuple(cv2.resize(a, (camera.width, camera.height), interpolation=cv2.INTER_LINEAR) for a in out)

    def warped(self, raster, drawn: np.ndarray, now: np.ndarray, X: np.ndarray, camera: Camera):
        """(face weight (h, w), the jaw's derivative (h, w, 3) or None) of `points`' answer
        `raster` drawn at pose `drawn` (4, 4), moved to pose `now` (4, 4): each pixel's point X
        (h, w, 3) (view frame, at `now`; 0 where nothing is drawn) taken back to where it was at
        `drawn` and the raster read there (bilinear), the derivative turned with the head
        (`Settings.raster_once`)."""
        import cv2

        back = drawn @ np.linalg.inv(now)                               # now's view frame -> drawn's
        h, w = X.shape[:2]
        P = X.reshape(-1, 3) @ back[:3, :3].T + back[:3, 3]
        z = np.where(-P[:, 2] > 1e-6, -P[:, 2], np.inf)                  # the camera looks down -Z
        mx = (camera.fx * P[:, 0] / z + camera.cx - 0.5).reshape(h, w).astype(np.float32)
        my = (-camera.fy * P[:, 1] / z + camera.cy - 0.5).reshape(h, w).astype(np.float32)
        weight = cv2.remap(raster[1].astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=0.0)
        if len(raster) < 3:
            return weight, None
        turn = now[:3, :3] @ drawn[:3, :3].T
        d = cv2.remap(raster[2].astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=(0.0, 0.0, 0.0))
        return weight, d.astype(np.float64) @ turn.T

    def shrink(self, rgb: np.ndarray) -> np.ndarray:
        """The frame (H, W, 3) uint8 at the small camera's size (uint8; a frame already that
        size as it is): what `refine` needs of a frame, to keep while it waits."""
        import cv2

        im = np.asarray(rgb)
        if im.shape[:2] == (self.camera.height, self.camera.width):
            return im
        return cv2.resize(im, (self.camera.width, self.camera.height), interpolation=cv2.INTER_AREA)

    def small(self, rgb: np.ndarray) -> np.ndarray:
        """`shrink`, float32 in [0, 1]."""
        return self.shrink(rgb).astype(np.float32) / 255.0

    # -- the fast path -------------------------------------------------------------------------
    def refine(self, rgb: np.ndarray, rotation, translation, jaw, expr, eyes) -> Refinement:
        """The refined pose of frame `rgb` (H, W, 3) uint8 (the refiner's size, or `shrink`'s
        answer) starting from the
        landmark fit's rotation (3,), translation (3,), with its jaw (3,), expr (E,), eyes (6,)
        (with `Settings.jaw`, the jaw's opening too, pulled toward the fit's)."""
        s = self.settings
        target = self.small(rgb)
        jaw0 = np.asarray(jaw, np.float64).reshape(3)
        rot, tr = np.asarray(rotation, np.float64), np.asarray(translation, np.float64)
        jaw_now = jaw0.copy()
        a0 = pose_matrix(rot, tr)
        if s.move_camera:
            moved, verts = self.placed(jaw_now, expr, eyes, a0)                  # once per frame
        else:
            person, verts = self.posed(jaw_now, expr, eyes)
        jaw_drawn = jaw_now.copy()                                                # the jaw `moved` has
        # the head mesh's raster (the face weight, the jaw's derivative): each pass's, or with
        # `raster_once` the first pass's (the points come from each pass's render depth)
        first, raster, raster_pose = None, None, None
        reuse = s.raster_once and s.render_depth and s.crop_margin is None
        n, res, renders = 0, float("nan"), 0
        for _ in range(s.iterations):
            if s.jaw and not np.array_equal(jaw_drawn, jaw_now):
                if s.move_camera:
                    moved, verts = self.rejawed(moved, jaw_now, expr, eyes, a0)
                else:
                    person, verts = self.posed(jaw_now, expr, eyes)
                jaw_drawn = jaw_now.copy()
            if s.crop_margin is None:
                x0, y0, cam, tgt = 0, 0, self.camera, target
            else:
                x0, y0, x1, y1 = self.box(verts, rot, tr, int(s.crop_margin))
                cam, tgt = self.crop_camera((x0, y0, x1, y1)), target[y0:y1, x0:x1]
            if s.move_camera:
                image = self.render_moved(moved, pose_matrix(rot, tr) @ np.linalg.inv(a0), tgt, cam, s.render_depth)
            else:
                image = self.render(person, rot, tr, tgt, cam, s.render_depth)
            comp, alpha = image[:2]
            renders += 1
            if raster is None or not reuse:
                derivative = self.jaw_derivative(jaw_now, expr, eyes) if s.jaw else None
                if s.render_depth and s.raster_scale != 1.0:
                    raster = self.scaled_points(verts, rot, tr, cam, s.raster_scale, derivative,
                                                self.jaw_weight if s.jaw else None)
                elif s.jaw:
                    raster = self.points(verts, rot, tr, cam, derivative, self.jaw_weight)
                else:
                    raster = self.points(verts, rot, tr, cam)
                raster_pose = pose_matrix(rot, tr)
            X, w = raster[:2]
            dX = raster[2] if s.jaw else None
            if s.render_depth:
                # the surface the image shows is the splats', not the mesh's (a few mm off it,
                # more at the hairline): its depth sets the parallax the turn is read from
                X = unproject(image[2], cam)
                if reuse and renders > 1:
                    w, dX = self.warped(raster, raster_pose, pose_matrix(rot, tr), X, cam)
            keep = (w > 0.5) & (alpha > 0.5)
            flow, ok = consistent_flow(comp, tgt, s.fb_tolerance)
            keep &= ok
            if s.stride > 1:
                grid = np.zeros_like(keep)
                grid[::s.stride, ::s.stride] = True
                keep &= grid
            n = int(keep.sum())
            if n < s.min_points:
                break
            ys, xs = np.nonzero(keep)
            uv = np.stack([xs + 0.5, ys + 0.5], 1) + flow[ys, xs]
            P = X[ys, xs]
            if s.jaw:
                # the prior: an opening jaw_sigma from the landmark fit's costs as much as a
                # pixel's error on every point used
                delta, centre, before, res = solve_pose_delta(
                    P, uv, cam, s.huber, s.gauss_newton, s.ridge, extra=dX[ys, xs][:, :, None],
                    prior=np.array([n / s.jaw_sigma ** 2]), prior_target=np.array([jaw0[0] - jaw_now[0]]))
                jaw_now[0] += delta[6]
            else:
                delta, centre, before, res = solve_pose_delta(P, uv, cam, s.huber, s.gauss_newton, s.ridge)
            first = before if first is None else first
            rot, tr = apply_delta(rot, tr, delta[:6], centre)
            if np.linalg.norm(delta[:3]) < s.tolerance and np.linalg.norm(delta[3:6]) < s.shift_tolerance \
                    and (not s.jaw or abs(delta[6]) < s.jaw_tolerance):
                break
        return Refinement(rot, tr, renders, n, res, float("nan") if first is None else first, jaw_now)

    def _jaw_part(self) -> tuple[np.ndarray, object]:
        """(indices (M,) of the head's Gaussians the jaw's opening moves: those on a triangle
        with a vertex that moves (the jaw's skinning or its pose correctives), their binding)."""
        if self._jaw_ids is None:
            zeros = np.zeros(3)
            v = [self.model.forward(self._params(np.array([j, 0.0, 0.0]), zeros, np.zeros(6))[1])[0][0]
                 for j in (0.0, 0.3)]
            moving = np.any(v[0] != v[1], axis=1)                         # (V,)
            b = self.avatar.binding
            self._jaw_ids = np.flatnonzero(moving[np.asarray(b.faces)[np.asarray(b.face_ids)]].any(axis=1))
            self._jaw_binding = b.subset(self._jaw_ids)
        return self._jaw_ids, self._jaw_binding

    def rejawed(self, moved, jaw, expr, eyes, a0: np.ndarray):
        """(`moved` (the avatar posed at another opening and turned by a0 (4, 4), `_turned`)
        with the Gaussians the jaw moves re-posed at this jaw (3,) and turned by a0; the head
        vertices (V, 3) at it, zero root pose): what `_turned(posed(jaw, ...)[0], axis, a0)`
        draws, at the cost of the ~1/6 of the Gaussians that move (a test compares them)."""
        from avatarkit.gaussians.gaussian_set import GaussianSet

        ids, binding = self._jaw_part()
        (m, q, sc), v = self.placed(jaw, expr, eyes, a0, binding)
        means, quats, scales = moved.means.copy(), moved.quats.copy(), moved.scales.copy()
        means[ids], quats[ids], scales[ids] = m, q, sc
        return GaussianSet.from_checked(means, quats, scales, moved.opacities, moved.sh), v

    # -- the slow obvious reference ------------------------------------------------------------
    def refine_reference(self, rgb: np.ndarray, rotation, translation, jaw, expr, eyes,
                         steps=(0.02, 0.02, 0.02, 0.004, 0.004, 0.004, 0.02), rounds: int = 5) -> Refinement:
        """`refine` by a pattern search on the masked colour error (module docstring); with
        `Settings.jaw` over the jaw's opening too (steps' last), with no prior (the colour
        error's own minimum)."""
        import cv2

        from avatarkit.track.register import pattern_search

        target = self.small(rgb)
        jaw0 = np.asarray(jaw, np.float64).reshape(3)
        person, verts = self.posed(jaw0, expr, eyes)
        rot0, tr0 = np.asarray(rotation, np.float64), np.asarray(translation, np.float64)
        X, w = self.points(verts, rot0, tr0)
        mask = cv2.dilate((w > 0.5).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        centre = X[w > 0.5].mean(axis=0)
        k = 7 if self.settings.jaw else 6
        n = [0]

        def jaw_of(p):
            return jaw0 + np.array([p[6] if k == 7 else 0.0, 0.0, 0.0])

        def cost(p) -> float:
            n[0] += 1
            r, t = apply_delta(rot0, tr0, p[:6], centre)
            comp, _ = self.render(self.posed(jaw_of(p), expr, eyes)[0], r, t, target)
            return float(np.mean((comp[mask] - target[mask]) ** 2))

        p, _ = pattern_search(cost, np.zeros(k), cost(np.zeros(k)), tuple(steps)[:k], rounds)
        r, t = apply_delta(rot0, tr0, p[:6], centre)
        return Refinement(r, t, n[0], int(mask.sum()), float("nan"), float("nan"), jaw_of(p))


def _grey(im: np.ndarray) -> np.ndarray:
    import cv2

    a = np.asarray(im)
    if a.dtype != np.uint8:
        a = np.clip(np.round(a * 255.0), 0, 255).astype(np.uint8)
    return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY)


def consistent_flow(source: np.ndarray, target: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """(flow (h, w, 2) source -> target in pixels, ok (h, w) bool: where the backward flow,
    sampled where the forward flow lands, comes back to within `tolerance` px). Images (h, w,
    3) float in [0, 1] or uint8."""
    import cv2

    a, b = _grey(source), _grey(target)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    fwd = dis.calc(a, b, None)
    bwd = dis.calc(b, a, None)
    h, w = a.shape
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    mx, my = gx + fwd[..., 0], gy + fwd[..., 1]
    back = cv2.remap(bwd, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(1e3, 1e3))
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    ok = inside & (np.linalg.norm(fwd + back, axis=-1) < tolerance)
    return fwd.astype(np.float64), ok


def project(points: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(pixel coordinates (N, 2), Jacobian (N, 2, 3) of them by the view-frame point) of view-
    frame points (N, 3) in `camera` (the tracker's: w2c = [diag(1, -1, -1) | 0])."""
    pc = points @ _C.T
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    uv = np.stack([camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy], 1)
    J = np.zeros((len(points), 2, 3))
    J[:, 0, 0] = camera.fx / z
    J[:, 0, 2] = -camera.fx * x / z ** 2
    J[:, 1, 1] = camera.fy / z
    J[:, 1, 2] = -camera.fy * y / z ** 2
    return uv, J @ _C


def unproject(depth: np.ndarray, camera: Camera) -> np.ndarray:
    """(h, w, 3) view-frame points of each pixel centre of `camera` (the tracker's) at camera
    depth `depth` (h, w) (positive, in front): `project`'s inverse."""
    h, w = depth.shape
    gx, gy = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    z = np.asarray(depth, np.float64)
    pc = np.stack([(gx - camera.cx) * z / camera.fx, (gy - camera.cy) * z / camera.fy, z], -1)
    return pc @ _C.T                                                  # _C is its own inverse


def _skew(v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cross-product matrices of v (N, 3)."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def _gauss_newton_step(A: np.ndarray, r: np.ndarray, w: np.ndarray, delta: np.ndarray, E: np.ndarray,
                       ridge: float, pw: np.ndarray, pt: np.ndarray) -> np.ndarray:
    """One reweighted Gauss-Newton step of `solve_pose_delta` (and its reference, which differ
    only in how they build the Jacobian A (N, 2, 6 + K)): residuals r (N, 2), Huber weights w
    (N,), the change so far delta (6 + K,) whose turn is E (3, 3), a ridge relative to the
    normal matrix's trace, and the K extra parameters' prior weights pw / targets pt -> the new
    delta. The turn's increment is composed after E (left); the rest adds."""
    K = A.shape[2] - 6
    A2 = A.reshape(-1, 6 + K)
    w2 = np.repeat(w, 2)
    H = A2.T @ (w2[:, None] * A2)
    g = A2.T @ (w2 * r.reshape(-1))
    H += ridge * np.trace(H) / (6.0 + K) * np.eye(6 + K)
    H[6:, 6:] += np.diag(pw)
    g[6:] += pw * (delta[6:] - pt)
    step = -np.linalg.solve(H, g)
    out = delta.copy()
    out[:3] = matrix_to_axis_angle(axis_angle_to_matrix(step[:3]) @ E)
    out[3:] = delta[3:] + step[3:]
    return out


def solve_pose_delta(points: np.ndarray, targets: np.ndarray, camera: Camera, huber: float = 1.0,
                     iterations: int = 4, ridge: float = 1e-3, extra: np.ndarray | None = None,
                     prior: np.ndarray | None = None, prior_target: np.ndarray | None = None):
    """The rigid change delta (6,) (turn about the points' centroid, then shift: `apply_delta`)
    that moves view-frame points (N, 3) to project onto targets (N, 2) px, by iteratively
    reweighted Gauss-Newton with Huber weights (threshold `huber` px). Returns (delta, centre
    (3,), median residual before, after).

    extra: (N, 3, K) the points' derivatives (view frame) by K more parameters a (the jaw's
    opening): the points moved are E (P + extra a - c) + c + d, and delta is (6 + K,), a last;
    prior: (K,) weights (px^2 per unit^2) of a quadratic pull of a toward prior_target (K,)
    (zeros where None).

    The same steps as `solve_pose_delta_reference` (a test compares them), with each Jacobian
    row written out (session 15: ~1.5x faster at ~10k points): the projection's rows in the view
    frame are (fx / z, 0, fx x / z^2) and (0, -fy / z, fy y / z^2) (camera x = X, y = -Y, z =
    -Z), and a row j's turn columns, -j [E (P - c)]x, are the cross product E (P - c) x j."""
    P = np.asarray(points, np.float64)
    q = np.asarray(targets, np.float64)
    N = len(P)
    D = np.zeros((N, 3, 0)) if extra is None else np.asarray(extra, np.float64).reshape(N, 3, -1)
    K = D.shape[2]
    pw = np.zeros(K) if prior is None else np.asarray(prior, np.float64).reshape(K)
    pt = np.zeros(K) if prior_target is None else np.asarray(prior_target, np.float64).reshape(K)
    c = P.mean(axis=0)
    Pc = P - c
    delta = np.zeros(6 + K)
    fx, fy, cx, cy = float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)
    Dt = np.ascontiguousarray(D.transpose(0, 2, 1))                  # (N, K, 3)

    def moved(d):
        E = axis_angle_to_matrix(d[:3]).astype(np.float64)
        local = Pc + ((d[6:] @ Dt) if K else 0.0)                          # (N, 3) before the turn
        return E, local @ E.T

    def residual(turned, d):
        X = turned + c + d[3:6]
        z = -X[:, 2]
        u = fx * X[:, 0] / z + cx
        v = -fy * X[:, 1] / z + cy
        return X, z, np.stack([u - q[:, 0], v - q[:, 1]], 1)

    before = None
    A = np.empty((N, 2, 6 + K))
    for _ in range(max(1, iterations)):
        E, turned = moved(delta)
        X, z, r = residual(turned, delta)
        dist = np.sqrt(r[:, 0] ** 2 + r[:, 1] ** 2)
        if before is None:
            before = float(np.median(dist))
        w = np.where(dist <= huber, 1.0, huber / np.maximum(dist, 1e-12))
        iz = 1.0 / z
        ju = np.zeros((N, 3))
        ju[:, 0], ju[:, 2] = fx * iz, fx * X[:, 0] * iz * iz
        jv = np.zeros((N, 3))
        jv[:, 1], jv[:, 2] = -fy * iz, -fy * X[:, 1] * iz * iz
        tx, ty, tz = turned[:, 0], turned[:, 1], turned[:, 2]
        ED = (Dt.reshape(-1, 3) @ E.T).reshape(N, K, 3) if K else None     # E D, (N, K, 3)
        for row, j in ((0, ju), (1, jv)):
            A[:, row, 0] = ty * j[:, 2] - tz * j[:, 1]
            A[:, row, 1] = tz * j[:, 0] - tx * j[:, 2]
            A[:, row, 2] = tx * j[:, 1] - ty * j[:, 0]
            A[:, row, 3:6] = j
            if K:
                A[:, row, 6:] = (ED * j[:, None, :]).sum(axis=2)                # j . E D
        delta = _gauss_newton_step(A, r, w, delta, E, ridge, pw, pt)
    E, turned = moved(delta)
    _, _, r = residual(turned, delta)
    return delta, c, before, float(np.median(np.sqrt(r[:, 0] ** 2 + r[:, 1] ** 2)))


def solve_pose_delta_reference(points: np.ndarray, targets: np.ndarray, camera: Camera, huber: float = 1.0,
                               iterations: int = 4, ridge: float = 1e-3, extra: np.ndarray | None = None,
                               prior: np.ndarray | None = None, prior_target: np.ndarray | None = None):
    """`solve_pose_delta` the obvious way (batched 2x3 Jacobians, cross-product matrices, one
    product each): the reference a test holds the fast one to.

    The rigid change delta (6,) (turn about the points' centroid, then shift: `apply_delta`)
    that moves view-frame points (N, 3) to project onto targets (N, 2) px, by iteratively
    reweighted Gauss-Newton with Huber weights (threshold `huber` px). Returns (delta, centre
    (3,), median residual before, after).

    extra: (N, 3, K) the points' derivatives (view frame) by K more parameters a (the jaw's
    opening): the points moved are E (P + extra a - c) + c + d, and delta is (6 + K,), a last;
    prior: (K,) weights (px^2 per unit^2) of a quadratic pull of a toward prior_target (K,)
    (zeros where None)."""
    P = np.asarray(points, np.float64)
    q = np.asarray(targets, np.float64)
    D = np.zeros((len(P), 3, 0)) if extra is None else np.asarray(extra, np.float64).reshape(len(P), 3, -1)
    K = D.shape[2]
    pw = np.zeros(K) if prior is None else np.asarray(prior, np.float64).reshape(K)
    pt = np.zeros(K) if prior_target is None else np.asarray(prior_target, np.float64).reshape(K)
    c = P.mean(axis=0)
    delta = np.zeros(6 + K)

    def moved(d):
        E = axis_angle_to_matrix(d[:3])
        local = P + D @ d[6:] - c                                     # (N, 3) before the turn
        return E, local @ E.T

    before = None
    for _ in range(max(1, iterations)):
        E, turned = moved(delta)
        X = turned + c + delta[3:6]
        uv, J = project(X, camera)
        r = uv - q                                                    # (N, 2)
        dist = np.linalg.norm(r, axis=1)
        if before is None:
            before = float(np.median(dist))
        w = np.where(dist <= huber, 1.0, huber / np.maximum(dist, 1e-12))
        # d X / d (a small turn w applied after E) = -[E (P - c)]x ; d X / d (shift) = I;
        # d X / d a = E D
        cols = [-J @ _skew(turned), J]
        if K:
            cols.append(J @ (E[None] @ D))
        A = np.concatenate(cols, axis=2)                              # (N, 2, 6 + K)
        delta = _gauss_newton_step(A, r, w, delta, E, ridge, pw, pt)
    E, turned = moved(delta)
    uv, _ = project(turned + c + delta[3:6], camera)
    return delta, c, before, float(np.median(np.linalg.norm(uv - q, axis=1)))


__all__ = ["CHEAP_PASS", "PoseRefiner", "Refinement", "SESSION13", "Settings", "apply_delta", "consistent_flow",
           "pose_matrix", "project", "solve_pose_delta", "solve_pose_delta_reference", "unproject", "view_camera"]
