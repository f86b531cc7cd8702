"""Register a video frame the face mesh no longer follows, by analysis by synthesis.

Past ~50-60 degrees of turn the face-mesh landmarks degrade and then vanish (measured on the
synthetic eased turn to 80 degrees at 192 px: the tracker loses the face from ~55-65 degrees
on, docs/video-build.md), so a video build's keyframes never see the back half of the head.
Such a frame is registered against an avatar built from the frames that are well tracked: the
avatar is rendered (our CPU splat renderer) at a candidate head pose over the frame's
background colour (or over the video's wall plate where it knows a busy wall: `plate_background`),
and the pose that best reproduces the frame (mean squared colour error over the whole image: the
silhouette and the colours both count) is kept.

Poses are the tracker's (`track.tracker`, X_view = R X + t, Y-X-Z Euler yaw/pitch/roll as
`track.keyframes.yaw_pitch`), relative to the video build's reference keyframe: a pose P gives
the avatar's rest-frame camera C P M_r^-1 C W_ref, where W_ref is the reference keyframe's
camera (the build's, `provenance.build.camera`), M_r the reference keyframe's pose and C the
OpenCV flip, as `recon.multiview.keyframe_cameras` composes it.

`register_frame` (the fast path): the frame and the camera scaled to `SIZE` pixels, a coarse
search over yaw in a given range (the rest of the pose from the guess), then a pattern search
over yaw, pitch, roll and translation with halving steps. `register_frame_exhaustive` (the slow
obvious reference): every pose of a grid over yaw and pitch at the frame's full size.

`register_aligned`: the same search over yaw, pitch and roll, each candidate's render first laid
over the frame by the image similarity (scale, shift) that best overlays the silhouettes and
then the colours (`aligned_error`); the position follows from that similarity
(`pose_with_alignment`). For a first build whose head is the wrong size or turns about the
wrong centre (`video_build.REGISTER_MODE = "aligned"`; not the default, docs/video-build.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from avatarkit.render.camera import Camera

#: the longer side (pixels) the fast path renders and compares at
SIZE = 96
#: the search compares a window around the head, not the whole frame, where the head is small in
#: it: the draft's Gaussians at the reference pose (their 1st-99th percentile box in the reference
#: camera) grown by this share of the box's larger side on every side, cut to the frame
#: (`head_window`); a window that reaches every edge of the frame is the whole frame, as before.
#: None: always the whole frame. The synthetic turning clip (192 px) placed in a 960x540 landscape
#: frame put the head at 19 px in the 96 px comparison, and both turn ends registered some 55
#: degrees short with pitch 21-33 degrees: the profile views fell 3.4-4.2 dB, under the
#: single-frame build's (docs/video-build.md, session 28)
WINDOW_MARGIN = 0.5
#: coarse yaw step (radians)
COARSE_STEP = math.radians(4.0)
#: the pattern search's first steps: yaw, pitch, roll (radians), translation x, y, z (metres)
REFINE_STEPS = (math.radians(2.0), math.radians(2.0), math.radians(2.0), 0.004, 0.004, 0.01)
#: halvings of the pattern search's steps
REFINE_ROUNDS = 3
#: `register_frame(shifted=True)`: each coarse yaw's head moved to fit, from these steps (tx, ty metres)
SHIFT_STEPS = (0.008, 0.008)

#: `register_frame(discount_hair=True)`: the plain search runs too, and the hair-discounted yaw
#: replaces its pose only where it is turned further from the reference pose's yaw by more than
#: this (radians; None: always). Every bias this registration is known for reads a turn short
#: (the landmarks' saturation, a draft's hair); a yaw within a few degrees of the plain one's is
#: noise, and moving it costs a build that agrees with its own registration: ungated, the sample
#: avatar's poses moved by under a degree and its -90 view lost 0.16-0.23 dB (seed 1); gated at 3
#: degrees its builds (seeds 0, 1) are the plain ones to the digit and the mesh subject keeps its
#: gain (session 24, docs/video-build.md)
HAIR_GATE = math.radians(3.0)

_C = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class Registration:
    """pose (4, 4) the head pose found (the tracker's convention, X_view = R X + t); error: the
    mean squared colour error (images in [0, 1]) there; evaluations: renders made; coarse:
    (K, 2) yaw (radians) and error of the coarse search."""

    pose: np.ndarray
    error: float
    evaluations: int
    coarse: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    #: `register_frame(discount_hair=True)` with its plain search run (`HAIR_GATE`, or keep_plain):
    #: (4, 4) the plain search's pose (every pixel's error), whichever `pose` the gate took;
    #: None where no plain search ran
    plain_pose: np.ndarray | None = None
    #: whether `pose` is the hair-discounted search's (False: the plain search's, or no discount)
    discounted: bool = False
    #: whether the render was composited over the video's wall plate (`plate_background`: the
    #: plate knew a wall unlike the border's colour), not over the flat border colour
    over_plate: bool = False

    @property
    def yaw_pitch_roll(self) -> np.ndarray:
        return params_from_pose(self.pose)[:3]


def pose_from_params(params) -> np.ndarray:
    """(6,) yaw, pitch, roll (radians, Y-X-Z Euler), tx, ty, tz (metres) -> (4, 4) pose."""
    from scipy.spatial.transform import Rotation

    p = np.asarray(params, np.float64)
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("YXZ", p[:3]).as_matrix()
    m[:3, 3] = p[3:6]
    return m


def params_from_pose(pose) -> np.ndarray:
    """(4, 4) pose -> (6,) yaw, pitch, roll, tx, ty, tz (the inverse of `pose_from_params`)."""
    from scipy.spatial.transform import Rotation

    m = np.asarray(pose, np.float64)
    return np.concatenate([Rotation.from_matrix(m[:3, :3]).as_euler("YXZ"), m[:3, 3]])


def pose_camera(reference_camera: Camera, reference_pose, pose) -> Camera:
    """The rest avatar's camera for a frame with head pose `pose` (4, 4): C P M_r^-1 C W_ref
    (module docstring)."""
    w2c = _C @ np.asarray(pose, np.float64) @ np.linalg.inv(np.asarray(reference_pose, np.float64)) @ _C \
        @ np.asarray(reference_camera.world_to_camera, np.float64)
    c = reference_camera
    return Camera(c.fx, c.fy, c.cx, c.cy, c.width, c.height, w2c)


def background_colour(image: np.ndarray) -> np.ndarray:
    """(3,) in [0, 1]: the median of the image's border pixels (the wall behind the person).
    image: (H, W, 3) uint8 or float in [0, 1]."""
    im = np.asarray(image)
    im = im.astype(np.float64) / 255.0 if im.dtype == np.uint8 else im.astype(np.float64)
    border = np.concatenate([im[0], im[-1], im[:, 0], im[:, -1]])
    return np.median(border, axis=0)


def head_window(gaussians, camera: Camera, shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) pixels: the window of an (H, W) = `shape` frame the registration compares
    (`WINDOW_MARGIN`), or None for the whole frame (the switch off, a window reaching every edge,
    or no Gaussian in front of the camera). gaussians: the avatar at rest; camera: the reference
    keyframe's, at the frame's size."""
    margin = WINDOW_MARGIN
    if margin is None:
        return None
    h, w = (int(v) for v in shape)
    cam = np.asarray(camera.world_to_camera, np.float64)
    x = np.asarray(gaussians.means, np.float64) @ cam[:3, :3].T + cam[:3, 3]
    x = x[x[:, 2] > 1e-6]
    if len(x) == 0:
        return None
    u = camera.fx * x[:, 0] / x[:, 2] + camera.cx
    v = camera.fy * x[:, 1] / x[:, 2] + camera.cy
    (u0, u1), (v0, v1) = np.quantile(u, [0.01, 0.99]), np.quantile(v, [0.01, 0.99])
    m = margin * max(u1 - u0, v1 - v0)
    x0, y0 = max(0, int(np.floor(u0 - m))), max(0, int(np.floor(v0 - m)))
    x1, y1 = min(w, int(np.ceil(u1 + m))), min(h, int(np.ceil(v1 + m)))
    if (x0, y0, x1, y1) == (0, 0, w, h) or x1 - x0 < 8 or y1 - y0 < 8:
        return None
    return x0, y0, x1, y1


def window_camera(camera: Camera, window: tuple[int, int, int, int]) -> Camera:
    """`camera` seeing only the pixels of `window` (x0, y0, x1, y1): the same view, cropped."""
    x0, y0, x1, y1 = window
    return Camera(camera.fx, camera.fy, camera.cx - x0, camera.cy - y0, x1 - x0, y1 - y0, camera.world_to_camera)


def plate_background(plate, frame_shape: tuple[int, int], shape: tuple[int, int], flat,
                     window: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """What a registration composites its render over, from a video's wall plate
    (`track.background_plate.Plate`, None: no plate): (3,) the flat colour `flat` where the plate
    adds nothing (no plate, or its known pixels all within `background_plate.AGREE` of `flat` in
    every channel: a plain wall), else (H, W, 3) float in [0, 1] at `shape` (H, W): the plate's
    colour where it is known and differs from `flat`, `flat` elsewhere (behind the head, where
    no frame showed the wall). The plate is taken at the frame's size `frame_shape` (H, W) and
    scaled as `_target` scales the frame (area averaging: a textured wall scaled otherwise does
    not match the frame's pixels); a pixel is the plate's only where every frame pixel it averages
    is. A cluttered wall's poster and post beside a turned head are then the background's, not a
    head pose's to explain (`video_build.REGISTER_PLATE`, docs/video-build.md)."""
    import cv2

    flat = np.asarray(flat, np.float64)
    if plate is None:
        return flat
    from avatarkit.track import background_plate

    colour, known = plate.at(tuple(int(v) for v in frame_shape))
    if window is not None:
        # the frame's window the registration compares (`head_window`)
        x0, y0, x1, y1 = window
        colour, known = colour[y0:y1, x0:x1], known[y0:y1, x0:x1]
    colour = colour.astype(np.float64) / 255.0
    differs = known & (np.abs(colour - flat).max(axis=-1) > background_plate.AGREE / 255.0)
    if not differs.any():
        return flat
    h, w = (int(v) for v in shape)
    if (h, w) != differs.shape:
        colour = cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA)
        differs = cv2.resize(differs.astype(np.float64), (w, h), interpolation=cv2.INTER_AREA) > 1.0 - 1e-6
    return np.where(differs[..., None], colour, flat)


def photometric_error(gaussians, camera: Camera, target: np.ndarray, background, above: float = 1.0,
                      hair=None) -> float:
    """Mean squared difference between the render of `gaussians` by `camera` over `background`
    ((3,) a colour, or (H, W, 3) an image in [0, 1]: `plate_background`) and target (H, W, 3)
    float in [0, 1] (the camera's size), over the image rows above
    `above` (share of the height from the top: the head without the neck, `register_frame`).
    hair: None (every pixel weighs 1) or `hair_marker(gaussians)`: each pixel weighs the share
    of the render that is not hair (`hair_share`), the mean taken over those weights."""
    from avatarkit.render import render

    bg = np.asarray(background, np.float64)
    if bg.ndim == 1:
        rgb = render(gaussians, camera, background=tuple(float(x) for x in bg)).rgb
    else:
        # the render over black is its premultiplied colour; the image shows through 1 - alpha
        r = render(gaussians, camera, background=(0.0, 0.0, 0.0))
        rgb = r.rgb + (1.0 - r.alpha[..., None]) * bg
    rows = max(1, int(round(above * camera.height)))
    if hair is None:
        return float(np.mean((np.clip(rgb[:rows], 0.0, 1.0) - target[:rows]) ** 2))
    err = np.mean((np.clip(rgb[:rows], 0.0, 1.0) - target[:rows]) ** 2, axis=-1)     # (rows, W)
    w = 1.0 - hair_share(hair, camera)[:rows]
    # a render that is all hair has nothing else to compare: the plain mean
    return float(np.sum(w * err) / np.sum(w)) if np.sum(w) > 1e-6 else float(np.mean(err))


def hair_marker(gaussians):
    """The Gaussians (a `GaussianSet` with a `part` extra, 1 = hair: `Avatar.rest_gaussians`)
    coloured white where hair and black elsewhere, for `hair_share`; None where the set has no
    hair (or no `part`)."""
    from avatarkit.gaussians.sh import rgb_to_dc

    part = gaussians.extras.get("part")
    if part is None or not np.any(np.asarray(part) == 1):
        return None
    sh = np.zeros_like(gaussians.sh)
    sh[:, 0, :] = rgb_to_dc(np.where((np.asarray(part) == 1)[:, None], 1.0, 0.0))
    return gaussians.replace(sh=sh)


def hair_share(marker, camera: Camera) -> np.ndarray:
    """(H, W) in [0, 1]: how much of each pixel's render is the hair's (the composited weight of
    `hair_marker`'s white Gaussians over black)."""
    from avatarkit.render import render

    return np.clip(render(marker, camera, background=(0.0, 0.0, 0.0)).rgb[..., 0], 0.0, 1.0)


def _target(image: np.ndarray, size: int | None) -> np.ndarray:
    import cv2

    im = np.asarray(image)
    h, w = im.shape[:2]
    if size is not None and max(h, w) > size:
        k = size / max(h, w)
        im = cv2.resize(im, (max(1, int(round(w * k))), max(1, int(round(h * k)))), interpolation=cv2.INTER_AREA)
    return im.astype(np.float64) / 255.0 if im.dtype == np.uint8 else im.astype(np.float64)


def head_rows(vertices: np.ndarray, neck: np.ndarray | None, camera: Camera) -> float:
    """The share of the image height above the lowest projected head vertex that is not the
    neck's: vertices (V, 3) rest head; neck (V,) bool (None: no neck region); camera: the
    guess's. The neck is left out of the comparison: a person's neck does not turn with the
    head, and a build's neck is the single photo's guess (on the mesh subject the wider built
    neck pulled the registered yaw of an 80-degree frame to 60)."""
    v = np.asarray(vertices, np.float64)
    if neck is not None:
        v = v[~np.asarray(neck, bool)]
    cam = camera.world_to_camera
    x = v @ cam[:3, :3].T + cam[:3, 3]
    front = x[:, 2] > 1e-6
    if not front.any():
        return 1.0
    y = camera.fy * x[front, 1] / x[front, 2] + camera.cy
    return float(np.clip(y.max() / camera.height, 0.0, 1.0))


def register_frame(gaussians, image: np.ndarray, reference_camera: Camera, reference_pose, guess,
                   yaw_range: tuple[float, float], size: int | None = None, coarse_step: float | None = None,
                   steps=None, rounds: int | None = None, above: float = 1.0,
                   shifted: bool = False, discount_hair: bool = False, keep_plain: bool = False,
                   plate=None) -> Registration:
    """The head pose at which `gaussians` (the avatar at rest) best reproduce `image` (H, W, 3)
    uint8 (module docstring). guess (4, 4): the starting pose (its pitch, roll and translation
    start the search); yaw_range: (lo, hi) radians, the absolute yaws searched (the coarse grid
    and the refinement's bounds);
    above: only the image rows above this share of the height count (`head_rows`);
    shifted: the coarse grid also searched with each yaw's head shifted to fit
    (`yaw_then_pattern_search`'s `shift_steps`: `SHIFT_STEPS`), the refinement run from both
    grids' best and the lower error kept;
    discount_hair: the yaw is searched with each pixel's error weighted by the share of the
    render that is not the Gaussians' hair (their `part` extra, 1 = hair: `photometric_error(hair=)`),
    the rest of the pose then again at that yaw by every pixel's error (a set without hair: the
    plain search); with `HAIR_GATE` the plain search's pose is kept unless that yaw is turned
    further than its own by more than the gate. A draft's hair is its least faithful layer, and a turned frame's pose where
    its wrong outline and streaks match best is short of the truth (`video_build.HAIR_DISCOUNT`).
    keep_plain: with discount_hair, the plain search runs even without a gate; its pose is the
    result's `plain_pose` (with a gate too), `discounted` says which of the two `pose` is (the
    video build's second pose per keyframe, `video_build.SKIN_POSE`).
    plate: the video's wall plate (`track.background_plate.Plate`; None: none): the render is
    composited over it where it knows a wall that is not the border's colour
    (`plate_background`), else over the border's colour (`background_colour`)."""
    size = SIZE if size is None else size
    coarse_step = COARSE_STEP if coarse_step is None else coarse_step
    steps = REFINE_STEPS if steps is None else steps
    rounds = REFINE_ROUNDS if rounds is None else rounds
    frame_shape = np.asarray(image).shape[:2]
    window = head_window(gaussians, reference_camera, frame_shape)
    if window is not None:
        # a head small in the frame: the window around it is what is scaled to `size`; `above`
        # (a share of the frame's height) becomes the same row's share of the window's
        x0, y0, x1, y1 = window
        image = np.asarray(image)[y0:y1, x0:x1]
        reference_camera = window_camera(reference_camera, window)
        above = float(np.clip((above * frame_shape[0] - y0) / (y1 - y0), 0.0, 1.0))
    target = _target(image, size)
    bg = plate_background(plate, frame_shape, target.shape[:2], background_colour(target), window)
    over = np.ndim(bg) == 3
    cam0 = reference_camera.with_size(target.shape[1], target.shape[0])
    n = [0]
    hair = hair_marker(gaussians) if discount_hair else None

    def cost(p, marker=None) -> float:
        n[0] += 1
        return photometric_error(gaussians, pose_camera(cam0, reference_pose, pose_from_params(p)), target, bg,
                                 above, marker)

    best, err, coarse = yaw_then_pattern_search(lambda p: cost(p, hair), params_from_pose(guess), yaw_range,
                                                coarse_step, steps, rounds, SHIFT_STEPS if shifted else None)
    if hair is not None:
        # the yaw is the hair-discounted error's; the rest of the pose is searched again at that
        # yaw by every pixel's error: without the hair the crown's outline no longer holds the
        # pitch and the height, and a pose found without it cost the sample avatar 0.35-0.46 dB
        # at +-90 for a yaw within a degree of the plain one's (session 24)
        yaw = best[0]
        held, held_err = pattern_search(cost, best, cost(best), steps, rounds + 1, allowed=lambda p: p[0] == yaw)
        best, err = held, held_err
        gate = HAIR_GATE
        if gate is not None or keep_plain:
            plain, plain_err, plain_coarse = yaw_then_pattern_search(cost, params_from_pose(guess), yaw_range,
                                                                     coarse_step, steps, rounds,
                                                                     SHIFT_STEPS if shifted else None)
            r0 = params_from_pose(reference_pose)[0]
            if gate is not None and abs(yaw - r0) <= abs(plain[0] - r0) + gate:
                return Registration(pose_from_params(plain), plain_err, n[0], plain_coarse,
                                    pose_from_params(plain), False, over)
            return Registration(pose_from_params(best), err, n[0], coarse, pose_from_params(plain), True, over)
        return Registration(pose_from_params(best), err, n[0], coarse, None, True, over)
    return Registration(pose_from_params(best), err, n[0], coarse, over_plate=over)


def yaw_then_pattern_search(cost, start: np.ndarray, yaw_range: tuple[float, float], coarse_step: float, steps,
                            rounds: int, shift_steps=None) -> tuple[np.ndarray, float, np.ndarray]:
    """The search `register_frame` and `register_aligned` share: the yaw (start[0], radians)
    every `coarse_step` over yaw_range with the other parameters start's, then from the best a
    pattern search over the first len(steps) parameters with halving steps (`rounds` halvings;
    the yaw kept within the range). Returns (best parameters, their cost, coarse (n, 2): yaw,
    cost). shift_steps (2,) metres (None: not done): every grid yaw is tried a second time with
    the head moved to fit (a pattern search over tx, ty, start[3:5], from these steps, one
    halving); where that grid's best yaw is more than a grid step from the plain grid's, the
    refinement starts from it as well, and the lower of the two ends is kept. A head turned far from the guess sits centimetres off the guess's position
    (the person turns about the neck, not the head's origin): at the guess's position the true
    yaw can cost more than a yaw short of it, and the refinement from there stops in that
    nearer minimum (the held-out bob's -80-degree frame: -61 from the plain grid's -53)."""
    start = np.asarray(start, np.float64)
    lo, hi = sorted(yaw_range)
    yaws = np.arange(lo, hi + 1e-9, coarse_step)
    coarse = np.array([[y, cost(np.concatenate([[y], start[1:]]))] for y in yaws])
    starts = [(np.concatenate([[coarse[int(np.argmin(coarse[:, 1])), 0]], start[1:]]), float(coarse[:, 1].min()))]
    if shift_steps is not None and len(start) >= 5:
        moved = []
        for (y, e) in coarse:
            p = np.concatenate([[y], start[1:]])

            def shift_cost(q, p=p) -> float:
                return cost(np.concatenate([p[:3], q, p[5:]]))

            q, e2 = pattern_search(shift_cost, p[3:5], float(e), shift_steps, 2)
            moved.append((np.concatenate([p[:3], q, p[5:]]), e2))
        other = min(moved, key=lambda m: m[1])
        # a start a grid step or less from the plain grid's lies in the same basin: the
        # refinement from there would only repeat the first (at three times the renders)
        if abs(other[0][0] - starts[0][0][0]) > coarse_step + 1e-9:
            starts.append(other)
    # the yaw stays within the range it was given
    ends = [pattern_search(cost, p, e, steps, rounds + 1, allowed=lambda p: lo <= p[0] <= hi) for p, e in starts]
    best, err = min(ends, key=lambda m: m[1])
    return best, err, coarse


def pattern_search(cost, x: np.ndarray, err: float, steps, rounds: int, allowed=None) -> tuple[np.ndarray, float]:
    """Coordinate pattern search from x (n,) whose cost is err: each parameter tried +- its
    step, the first improvement taken, until none improves; then the steps halve, `rounds`
    times in all. allowed(p) -> bool rules candidates out. Returns (x, cost)."""
    x = np.asarray(x, np.float64)
    step = np.asarray(steps, np.float64).copy()
    for _ in range(rounds):
        improved = True
        while improved:
            improved = False
            for i in range(len(step)):
                for s in (+step[i], -step[i]):
                    p = x.copy()
                    p[i] += s
                    if allowed is not None and not allowed(p):
                        continue
                    e = cost(p)
                    if e < err - 1e-12:
                        x, err, improved = p, e, True
                        break
        step /= 2.0
    return x, err


def register_frame_exhaustive(gaussians, image: np.ndarray, reference_camera: Camera, reference_pose, guess,
                              yaw_range: tuple[float, float], yaw_step: float = math.radians(1.0),
                              pitch_range: float = math.radians(6.0),
                              pitch_step: float = math.radians(2.0), above: float = 1.0) -> Registration:
    """The slow obvious reference of `register_frame`: every (yaw, pitch) of a grid (yaw over
    `yaw_range`, pitch within +-`pitch_range` of the guess's), roll and translation the guess's,
    rendered at the image's own size; the best of them."""
    target = _target(image, None)
    bg = background_colour(target)
    start = params_from_pose(guess)
    lo, hi = sorted(yaw_range)
    best, err, n = start, math.inf, 0
    for y in np.arange(lo, hi + 1e-9, yaw_step):
        for dp in np.arange(-pitch_range, pitch_range + 1e-9, pitch_step):
            p = np.concatenate([[y, start[1] + dp], start[2:]])
            e = photometric_error(gaussians, pose_camera(reference_camera, reference_pose, pose_from_params(p)),
                                  target, bg, above)
            n += 1
            if e < err:
                best, err = p, e
    return Registration(pose_from_params(best), float(err), n)


#: `align_silhouette`'s grid: image scales about the centre, and shifts (pixels, each way)
ALIGN_SCALES = tuple(np.round(np.arange(0.85, 1.151, 0.025), 3))
ALIGN_SHIFT = 10
#: a target pixel is the person's where a channel differs from the border colour by this much
SILHOUETTE_STEP = 0.08


def silhouette(image: np.ndarray, background) -> np.ndarray:
    """(H, W) bool: the pixels of image (H, W, 3) float in [0, 1] that are not the background
    colour (3,) (by more than `SILHOUETTE_STEP` in a channel)."""
    return np.abs(np.asarray(image, np.float64) - np.asarray(background, np.float64)).max(-1) > SILHOUETTE_STEP


def _similarity(scale: float, dx: float, dy: float, width: int, height: int) -> np.ndarray:
    """(2, 3) the image map u' = scale (u - centre) + centre + (dx, dy)."""
    return np.float32([[scale, 0, (1 - scale) * width / 2 + dx], [0, scale, (1 - scale) * height / 2 + dy]])


def align_silhouette(alpha: np.ndarray, mask: np.ndarray, rows: int, scales=None,
                     shift: int | None = None) -> tuple[float, int, int, float]:
    """The image similarity (scale about the centre, whole-pixel shift) that best lays a
    render's silhouette (alpha (H, W) > 0.5) over a frame's (mask (H, W) bool), by
    intersection over union over the rows above `rows`: (scale, dx, dy, iou). Every grid
    point is tried (the grid is small at `SIZE` pixels)."""
    scales = ALIGN_SCALES if scales is None else scales
    shift = ALIGN_SHIFT if shift is None else shift
    import cv2

    a = np.asarray(alpha, np.float32)
    m = np.asarray(mask, bool)[:rows]
    h, w = a.shape
    best = (1.0, 0, 0, -1.0)
    for s in scales:
        scaled = cv2.warpAffine(a, _similarity(float(s), 0, 0, w, h), (w, h)) > 0.5
        big = np.zeros((h + 2 * shift, w + 2 * shift), bool)
        big[shift:shift + h, shift:shift + w] = scaled
        for dy in range(-shift, shift + 1):
            for dx in range(-shift, shift + 1):
                r = big[shift - dy:shift - dy + h, shift - dx:shift - dx + w][:rows]
                iou = float((r & m).sum()) / max(1, int((r | m).sum()))
                if iou > best[3]:
                    best = (float(s), dx, dy, iou)
    return best


def aligned_error(gaussians, camera: Camera, target: np.ndarray, background, above: float = 1.0):
    """The colour error of `photometric_error` after the render is laid over the frame's
    silhouette by `align_silhouette`: (error, (scale, dx, dy, iou)). A build whose head is a
    few per cent too large or off-centre (the one photo's guess of its size and of where it
    turns about) then still matches a turned frame at its yaw: on the mesh subject's
    80-degree frames the plain error was flat from 60 to 80 degrees, the silhouettes
    overlapping 0.77-0.80 (IoU) at every yaw; laid over them they overlap 0.95."""
    import cv2
    from avatarkit.render import render

    r = render(gaussians, camera, background=tuple(float(x) for x in background))
    rows = max(1, int(round(above * camera.height)))
    s, dx, dy, iou = align_silhouette(r.alpha, silhouette(target, background), rows)
    rgb = np.clip(r.rgb, 0.0, 1.0).astype(np.float32)
    bgc = tuple(float(x) for x in background)
    tgt = np.asarray(target, np.float32)[:rows]

    def err(q) -> float:
        moved = cv2.warpAffine(rgb, _similarity(q[0], q[1], q[2], camera.width, camera.height),
                               (camera.width, camera.height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=bgc)
        return float(np.mean((moved[:rows] - tgt) ** 2))

    # the silhouette's grid is whole pixels: the colours are then laid to a sixteenth of a pixel
    # (a textured render half a pixel off costs more than a few degrees of yaw)
    q = np.array([s, float(dx), float(dy)])
    q, e = pattern_search(err, q, err(q), (0.0125, 0.5, 0.5), 4)
    return e, (float(q[0]), float(q[1]), float(q[2]), iou)


def pose_with_alignment(pose, camera: Camera, reference_pose, centre, alignment) -> np.ndarray:
    """(4, 4) `pose` with its translation moved so that the head's centre (rest frame (3,))
    lands where `aligned_error`'s similarity (scale, dx, dy) put it, at the depth that gives its
    scale (a head at depth z looks `scale` times larger at z / scale). Solved by Newton steps
    on the translation with a finite-difference Jacobian (the camera's own projection: no
    axis convention to get wrong)."""
    s, dx, dy = (float(v) for v in alignment[:3])
    c = np.asarray(centre, np.float64)[None]

    def where(t):
        p = np.asarray(pose, np.float64).copy()
        p[:3, 3] = t
        cam = pose_camera(camera, reference_pose, p)
        uv, z = cam.project(c)
        return np.array([uv[0, 0], uv[0, 1], float(np.ravel(z)[0])])

    t = np.asarray(pose, np.float64)[:3, 3].copy()
    u0 = where(t)
    goal = np.array([s * (u0[0] - camera.width / 2) + camera.width / 2 + dx,
                     s * (u0[1] - camera.height / 2) + camera.height / 2 + dy, u0[2] / s])
    for _ in range(3):
        f = where(t)
        J = np.stack([(where(t + e) - f) / 1e-4 for e in np.eye(3) * 1e-4], axis=1)
        t = t + np.linalg.solve(J, goal - f)
    out = np.asarray(pose, np.float64).copy()
    out[:3, 3] = t
    return out


def register_aligned(gaussians, image: np.ndarray, reference_camera: Camera, reference_pose, guess,
                     yaw_range: tuple[float, float], centre, size: int | None = None, coarse_step: float | None = None,
                     steps=None, rounds: int | None = None, above: float = 1.0) -> Registration:
    """The head pose at which `gaussians` best reproduce `image` by `aligned_error` (each
    candidate's render laid over the frame's silhouette first): yaw every `coarse_step` over
    yaw_range (pitch and roll the guess's), then a pattern search over yaw, pitch and roll with
    halving steps (`register_frame`'s, yaw kept within the range). The position is not searched:
    the alignment stands for it (and for a head of the wrong size); the pose returned is the
    guess's moved by the best pose's alignment (`pose_with_alignment`; centre: the head's
    centre in the rest frame)."""
    size = SIZE if size is None else size
    coarse_step = COARSE_STEP if coarse_step is None else coarse_step
    steps = REFINE_STEPS[:3] if steps is None else steps
    rounds = REFINE_ROUNDS if rounds is None else rounds
    target = _target(image, size)
    bg = background_colour(target)
    cam0 = reference_camera.with_size(target.shape[1], target.shape[0])
    start = params_from_pose(guess)
    seen: dict[tuple, tuple[float, tuple]] = {}

    def cost(angles) -> float:
        key = tuple(np.round(angles, 9))
        if key not in seen:
            p = start.copy()
            p[:3] = angles
            seen[key] = aligned_error(gaussians, pose_camera(cam0, reference_pose, pose_from_params(p)), target, bg,
                                      above)
        return seen[key][0]

    best, err, coarse = yaw_then_pattern_search(cost, start[:3], yaw_range, coarse_step, steps, rounds)
    p = start.copy()
    p[:3] = best
    pose = pose_with_alignment(pose_from_params(p), cam0, reference_pose, centre, seen[tuple(np.round(best, 9))][1])
    return Registration(pose, err, len(seen), coarse)


__all__ = ["ALIGN_SCALES", "ALIGN_SHIFT", "COARSE_STEP", "SILHOUETTE_STEP", "align_silhouette", "aligned_error",
           "pose_with_alignment", "register_aligned", "silhouette", "REFINE_ROUNDS", "REFINE_STEPS", "SHIFT_STEPS", "SIZE", "HAIR_GATE",
           "WINDOW_MARGIN", "head_window", "window_camera", "Registration", "background_colour", "hair_marker", "hair_share", "head_rows", "plate_background",
           "params_from_pose", "photometric_error", "pose_camera", "pose_from_params", "register_frame",
           "pattern_search", "register_frame_exhaustive", "yaw_then_pattern_search"]
