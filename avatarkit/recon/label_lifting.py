"""2D label images lifted to Gaussians: per-Gaussian label weights of one view and the labels
they give over K views (paper section 3.2, the first two steps of the 3D hair segmentation;
`recon.labels3d` chains them with `recon.hair_reassign`).

1. `accumulate_weights`: for one view, every pixel adds each Gaussian's blending weight
   w_i = alpha_i T_i (the renderer's 3DGS compositing: 0.3 px dilation, alpha < 1/255 skipped,
   stop before T < 1e-4) to that Gaussian's entry for the pixel's label. Summed over all
   pixels and labels, w_i is the Gaussian's whole contribution to the rendered alpha. This is
   the closed-form version of the paper's semantic-feature optimisation: with an L1 loss on
   rendered one-hot labels, a Gaussian's label follows the labels of the pixels it covers,
   weighted by how much it shows there.
2. `lift_labels`: weights summed over K views; label = argmax, UNSEEN (-1) where the total
   weight is below `min_weight`; confidence = winning weight / total.

`render_label_images` makes exact label images of a set whose per-Gaussian labels are known (the
built-in hair, tests); `default_label_cameras` gives the K orbit views.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon import segment as _segment
from avatarkit.recon.segment import LABEL_NAMES
from avatarkit.render.camera import Camera

UNSEEN = -1


# --- label images ----------------------------------------------------------------------------

def check_gaussians(gaussians) -> None:
    if not isinstance(gaussians, GaussianSet):
        raise InputError(f"label lifting needs a GaussianSet, got {type(gaussians).__name__}")


def check_label_image(label_image, camera: Camera, n_labels: int, what: str = "label image") -> np.ndarray:
    """(H, W) int32 labels in [0, n_labels) for `camera`, or InputError."""
    if not isinstance(camera, Camera):
        raise InputError(f"expected a Camera, got {type(camera).__name__}")
    a = np.asarray(label_image)
    if a.shape != (camera.height, camera.width):
        raise InputError(f"{what} has shape {a.shape}, but its camera is "
                         f"{camera.height}x{camera.width} (rows x columns)")
    if a.dtype == bool:
        a = a.astype(np.int32)
    if not np.issubdtype(a.dtype, np.integer):
        raise InputError(f"{what} must hold integer labels, got dtype {a.dtype}")
    if a.size and (a.min() < 0 or a.max() >= n_labels):
        raise InputError(f"{what} holds labels {int(a.min())}..{int(a.max())}, "
                         f"expected 0..{n_labels - 1}")
    return np.ascontiguousarray(a, np.int32)


def _check_n_labels(n_labels) -> int:
    if isinstance(n_labels, bool) or not isinstance(n_labels, (int, np.integer)) or n_labels < 1:
        raise InputError(f"n_labels must be a positive integer, got {n_labels!r}")
    return int(n_labels)


def check_views(cameras, label_images) -> tuple[list, list]:
    cameras, label_images = list(cameras), list(label_images)
    if not cameras:
        raise InputError("label lifting needs at least one camera and label image")
    if len(cameras) != len(label_images):
        raise InputError(f"got {len(cameras)} cameras but {len(label_images)} label images")
    return cameras, label_images


# --- step 1: per-Gaussian weights of one view ------------------------------------------------

def accumulate_view(gaussians: GaussianSet, camera: Camera, labels: np.ndarray, n_labels: int):
    """Fast path. labels: (H, W) int32, already checked. Returns (weights (N, L) float64,
    alpha (H, W) float32, depth (H, W) float32); alpha and depth as `render` gives them."""
    from avatarkit.render import bin_gaussians, project_gaussians

    n = len(gaussians)
    h, w = camera.height, camera.width
    weights = np.zeros((n, n_labels), np.float64)
    proj = project_gaussians(gaussians, camera)
    bins = bin_gaussians(proj, camera)
    if len(bins.gaussian_ids) == 0:
        return weights, np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    from avatarkit.recon import _label_kernels as k
    from avatarkit.render import _kernels as rk

    # the renderer's records, splat g in row g (colours unused)
    slot = np.where(proj.radii > 0, np.arange(n, dtype=np.int32), -1).astype(np.int32)
    packed = np.zeros((n, rk.PACK), np.float32)
    rk.pack_splats(slot, proj.means2d, proj.conics,
                   np.ascontiguousarray(gaussians.opacities, np.float32),
                   np.zeros((n, 3), np.float32), proj.depths, packed)
    trans = np.empty((h, w), np.float32)
    depth = np.empty((h, w), np.float32)
    k.accumulate(bins.tile_offsets, bins.gaussian_ids, packed, labels, weights, trans, depth)
    return weights, 1.0 - trans, depth


def accumulate_weights(gaussians: GaussianSet, camera: Camera, label_image: np.ndarray,
                       n_labels: int) -> np.ndarray:
    """(N, n_labels) float32: entry (i, l) = sum over the pixels labelled l of Gaussian i's
    blending weight alpha_i T_i in this view (the renderer's compositing, Taichi on the CPU).

    label_image: (camera.height, camera.width) integer labels in [0, n_labels).
    Row sums are each Gaussian's total contribution to the rendered alpha; column sums over
    Gaussians of a one-pixel label give that pixel's alpha.
    """
    check_gaussians(gaussians)
    n_labels = _check_n_labels(n_labels)
    labels = check_label_image(label_image, camera, n_labels)
    return accumulate_view(gaussians, camera, labels, n_labels)[0].astype(np.float32)


def accumulate_weights_reference(gaussians: GaussianSet, camera: Camera, label_image: np.ndarray,
                                 n_labels: int) -> np.ndarray:
    """The slow, obvious twin of `accumulate_weights` (tests only): float64 projection from the
    reference renderer, then for every tile its covering splats in depth order, composited
    one at a time over the tile's pixels, each splat's weights binned by label. (N, L) float64."""
    from avatarkit.render.pipeline import ALPHA_MAX, ALPHA_MIN, TILE_SIZE, TRANSMITTANCE_MIN, tile_grid
    from avatarkit.render.reference import project_reference

    check_gaussians(gaussians)
    n_labels = _check_n_labels(n_labels)
    labels = check_label_image(label_image, camera, n_labels)
    proj = project_reference(gaussians, camera)
    opacities = gaussians.opacities.astype(np.float64)
    weights = np.zeros((len(gaussians), n_labels))
    tiles_x, tiles_y = tile_grid(camera)
    rects, visible = proj.tile_rects, proj.radii > 0
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            x0, y0 = tx * TILE_SIZE, ty * TILE_SIZE
            x1, y1 = min(x0 + TILE_SIZE, camera.width), min(y0 + TILE_SIZE, camera.height)
            inside = (visible & (rects[:, 0] <= tx) & (tx < rects[:, 2])
                      & (rects[:, 1] <= ty) & (ty < rects[:, 3]))
            idx = np.flatnonzero(inside)
            idx = idx[np.argsort(proj.depths[idx], kind="stable")]
            px, py = np.meshgrid(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
            lab = labels[y0:y1, x0:x1]
            t = np.ones(px.shape)
            done = np.zeros(px.shape, bool)
            for g in idx:
                dx = proj.means2d[g, 0] - px
                dy = proj.means2d[g, 1] - py
                ca, cb, cc = proj.conics[g]
                power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                alpha = np.minimum(ALPHA_MAX, opacities[g] * np.exp(power))
                use = (alpha >= ALPHA_MIN) & ~done
                test_t = t * (1 - alpha)
                stop = use & (test_t < TRANSMITTANCE_MIN)
                done |= stop
                use &= ~stop
                weights[g] += np.bincount(lab[use], (alpha * t)[use], minlength=n_labels)
                t = np.where(use, test_t, t)
                if done.all():
                    break
    return weights


# --- step 2: lifting over K views ------------------------------------------------------------

@dataclass
class LabelLift:
    """Labels of N Gaussians lifted from K labelled views."""

    weights: np.ndarray       # (N, L) float32 blending weight per label, summed over views
    labels: np.ndarray        # (N,) int32 argmax label; UNSEEN (-1) where total < min_weight
    confidence: np.ndarray    # (N,) float32 winning weight / total weight; 0 where unseen
    view_weights: np.ndarray  # (N, K) float32 total weight of each Gaussian in each view
    alphas: list = field(default_factory=list)  # K x (H, W) float32 rendered alpha per view
    depths: list = field(default_factory=list)  # K x (H, W) float32 rendered depth per view
    min_weight: float = 0.0

    @property
    def total(self) -> np.ndarray:
        """(N,) float32 total weight over labels and views."""
        return self.weights.sum(axis=1)

    @property
    def seen(self) -> np.ndarray:
        """(N,) bool."""
        return self.labels != UNSEEN


def _n_labels_of(label_images, n_labels) -> int:
    if n_labels is not None:
        return _check_n_labels(n_labels)
    top = max((int(np.max(a)) for a in label_images if np.size(a)), default=0)
    return max(len(LABEL_NAMES), top + 1)


def lift_labels(gaussians: GaussianSet, cameras: list[Camera], label_images: list[np.ndarray],
                n_labels: int | None = None, min_weight: float = 0.01) -> LabelLift:
    """Lift K label images (each (H_k, W_k) int, for cameras[k]) to the Gaussians.

    n_labels: defaults to max(4, largest label + 1) (the 2D segmentation's 4 labels).
    min_weight: total blending weight (in pixels: a fully opaque pixel counts 1) below which a
    Gaussian is UNSEEN; culled and fully occluded Gaussians have exactly 0.
    """
    check_gaussians(gaussians)
    cameras, label_images = check_views(cameras, label_images)
    n_labels = _n_labels_of(label_images, n_labels)
    if not (np.isfinite(min_weight) and min_weight >= 0):
        raise InputError(f"min_weight must be >= 0, got {min_weight!r}")
    n = len(gaussians)
    weights = np.zeros((n, n_labels), np.float64)
    view_weights = np.zeros((n, len(cameras)), np.float32)
    alphas, depths = [], []
    for v, (cam, img) in enumerate(zip(cameras, label_images)):
        labels = check_label_image(img, cam, n_labels, f"label image {v}")
        wv, alpha, depth = accumulate_view(gaussians, cam, labels, n_labels)
        weights += wv
        view_weights[:, v] = wv.sum(axis=1)
        alphas.append(alpha)
        depths.append(depth)
    total = weights.sum(axis=1)
    seen = total >= max(min_weight, 1e-12)
    labels = np.where(seen, np.argmax(weights, axis=1), UNSEEN).astype(np.int32)
    confidence = np.where(seen, weights.max(axis=1, initial=0.0) / np.where(seen, total, 1.0), 0.0)
    return LabelLift(weights.astype(np.float32), labels, confidence.astype(np.float32),
                     view_weights, alphas, depths, float(min_weight))


# --- label images of a labelled set, and the views -------------------------------------------

def render_label_images(gaussians: GaussianSet, labels: np.ndarray, cameras: list[Camera],
                        n_labels: int | None = None, background_label: int | None = None,
                        min_alpha: float = 0.5) -> list[np.ndarray]:
    """Exact label images of a set with known per-Gaussian labels (N,) int in [0, n_labels):
    per pixel the label with the largest summed blending weight, or `background_label` where
    the rendered alpha is below `min_alpha`. K x (H, W) int32."""
    background_label = _segment.BACKGROUND if background_label is None else background_label
    from avatarkit.render import bin_gaussians, project_gaussians, rasterize

    check_gaussians(gaussians)
    labels = np.asarray(labels)
    if labels.shape != (len(gaussians),) or not np.issubdtype(labels.dtype, np.integer):
        raise InputError(f"labels must be ({len(gaussians)},) integers, got {labels.shape} {labels.dtype}")
    top = int(labels.max(initial=0))
    n_labels = max(top + 1, background_label + 1) if n_labels is None else _check_n_labels(n_labels)
    if top >= n_labels or labels.min(initial=0) < 0 or not 0 <= background_label < n_labels:
        raise InputError(f"labels and background_label must lie in 0..{n_labels - 1}")
    out = []
    for cam in cameras:
        proj = project_gaussians(gaussians, cam)
        bins = bin_gaussians(proj, cam)
        cover = np.zeros((cam.height, cam.width, 3 * (-(-n_labels // 3))), np.float32)
        alpha = np.zeros((cam.height, cam.width), np.float32)
        for p in range(0, n_labels, 3):
            onehot = (labels[:, None] == np.arange(p, p + 3)[None]).astype(np.float32)
            rgb, alpha, _ = rasterize(proj, onehot, gaussians.opacities, bins, cam)
            cover[..., p:p + 3] = rgb
        img = np.argmax(cover[..., :n_labels], axis=2).astype(np.int32)
        img[alpha < min_alpha] = background_label
        out.append(img)
    return out


def default_label_cameras(center, radius: float, n_views: int = 8, fov_deg: float = 30.0,
                          size: int = 512, margin: float = 1.15) -> list[Camera]:
    """K orbit cameras around a head at `center` (3,) with bounding radius `radius` (metres).

    View 0 looks at the face from the front (the photo's view); the others are spread evenly
    in azimuth, alternately 30 degrees above and 10 below the equator (so the crown, the
    hairline and under the chin are all seen).
    """
    from avatarkit.render.camera import focal_from_fov

    if isinstance(n_views, bool) or not isinstance(n_views, (int, np.integer)) or n_views < 1:
        raise InputError(f"n_views must be a positive integer, got {n_views!r}")
    if not (np.isfinite(radius) and radius > 0):
        raise InputError(f"radius must be > 0, got {radius!r}")
    half = np.arctan(0.5 * size / focal_from_fov(fov_deg, size))
    distance = radius * margin / np.sin(half)
    cams = []
    for i in range(int(n_views)):
        elevation = 0.0 if i == 0 else (30.0 if i % 2 else -10.0)
        cams.append(Camera.orbit(center, 360.0 * i / n_views, elevation, distance, fov_deg,
                                 size, size))
    return cams


__all__ = ["LabelLift", "UNSEEN", "accumulate_view", "accumulate_weights", "accumulate_weights_reference",
           "check_gaussians", "check_label_image", "check_views", "default_label_cameras", "lift_labels",
           "render_label_images"]
