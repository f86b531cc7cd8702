"""3D hair segmentation: 2D label images lifted to Gaussians, then boundary-aware reassignment.

Paper section 3.2 ("boundary-aware reassignment", Fig. "Hair Cleanup"). Three steps:

1. `accumulate_weights`: for one view, every pixel adds each Gaussian's blending weight
   w_i = alpha_i T_i (the renderer's 3DGS compositing: 0.3 px dilation, alpha < 1/255 skipped,
   stop before T < 1e-4) to that Gaussian's entry for the pixel's label. Summed over all
   pixels and labels, w_i is the Gaussian's whole contribution to the rendered alpha. This is
   the closed-form version of the paper's semantic-feature optimisation: with an L1 loss on
   rendered one-hot labels, a Gaussian's label follows the labels of the pixels it covers,
   weighted by how much it shows there.
2. `lift_labels`: weights summed over K views; label = argmax, UNSEEN (-1) where the total
   weight is below `min_weight`; confidence = winning weight / total.
3. `reassign_boundary`: the boundary set is the Gaussians that show mostly in a band around
   the 2D hair edges of the label images or around depth jumps near the hair (measured with
   the same weights, so an occluded Gaussian is not "at" an edge it hides behind). Those,
   the ones that show mostly from behind the rendered surface (a scalp seen through gaps in
   the hair carries the hair's pixel labels), the unseen ones and the ambiguous ones (low
   confidence) are reclassified. The rest are the reference: hair members and bald members
   (background excluded), minus those whose appearance is nearer the other class's median.
   Among a candidate's k nearest reference Gaussians (in space), each class gives a local
   centre in a colour + scale feature space (DC colour, sorted log-scales, standardised);
   the candidate joins the nearer centre. Where its neighbourhood holds only one class, the
   global (median) centres of both classes decide.

`split_hair` chains the three and cuts the set in two; `render_label_images` makes exact label
images of a set whose per-Gaussian labels are known (the built-in hair, tests);
`default_label_cameras` gives the K orbit views.

Only the front view has a label image from the photo in the real pipeline. Lifting from that
one view labels what it sees; everything it does not see (the back and the sides of the head,
splats hidden under the hair) is UNSEEN and gets its label from the k-NN step, i.e. from the
nearest seen Gaussians whose colour and size it resembles.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.segment import BACKGROUND, HAIR, LABEL_NAMES, SKIN
from avatarkit.render.camera import Camera

UNSEEN = -1


# --- label images ---------------------------------------------------------------------------

def _check_gaussians(gaussians) -> None:
    if not isinstance(gaussians, GaussianSet):
        raise InputError(f"label lifting needs a GaussianSet, got {type(gaussians).__name__}")


def _check_label_image(label_image, camera: Camera, n_labels: int, what: str = "label image") -> np.ndarray:
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


def _check_views(cameras, label_images) -> tuple[list, list]:
    cameras, label_images = list(cameras), list(label_images)
    if not cameras:
        raise InputError("label lifting needs at least one camera and label image")
    if len(cameras) != len(label_images):
        raise InputError(f"got {len(cameras)} cameras but {len(label_images)} label images")
    return cameras, label_images


# --- step 1: per-Gaussian weights of one view ---------------------------------------------

def _accumulate(gaussians: GaussianSet, camera: Camera, labels: np.ndarray, n_labels: int):
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

    packed = np.zeros((n, k.PACK), np.float32)
    k.pack_splats(proj.means2d, proj.conics, np.ascontiguousarray(gaussians.opacities, np.float32),
                  proj.depths, proj.radii, packed)
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
    _check_gaussians(gaussians)
    n_labels = _check_n_labels(n_labels)
    labels = _check_label_image(label_image, camera, n_labels)
    return _accumulate(gaussians, camera, labels, n_labels)[0].astype(np.float32)


def accumulate_weights_reference(gaussians: GaussianSet, camera: Camera, label_image: np.ndarray,
                                 n_labels: int) -> np.ndarray:
    """The slow, obvious twin of `accumulate_weights` (tests only): float64 projection from the
    reference renderer, then for every tile its covering splats in depth order, composited
    one at a time over the tile's pixels, each splat's weights binned by label. (N, L) float64."""
    from avatarkit.render.pipeline import ALPHA_MAX, ALPHA_MIN, TILE_SIZE, TRANSMITTANCE_MIN, tile_grid
    from avatarkit.render.reference import project_reference

    _check_gaussians(gaussians)
    n_labels = _check_n_labels(n_labels)
    labels = _check_label_image(label_image, camera, n_labels)
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


# --- step 2: lifting over K views -----------------------------------------------------------

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
    _check_gaussians(gaussians)
    cameras, label_images = _check_views(cameras, label_images)
    n_labels = _n_labels_of(label_images, n_labels)
    if not (np.isfinite(min_weight) and min_weight >= 0):
        raise InputError(f"min_weight must be >= 0, got {min_weight!r}")
    n = len(gaussians)
    weights = np.zeros((n, n_labels), np.float64)
    view_weights = np.zeros((n, len(cameras)), np.float32)
    alphas, depths = [], []
    for v, (cam, img) in enumerate(zip(cameras, label_images)):
        labels = _check_label_image(img, cam, n_labels, f"label image {v}")
        wv, alpha, depth = _accumulate(gaussians, cam, labels, n_labels)
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


# --- step 3: boundary-aware reassignment --------------------------------------------------

@dataclass(frozen=True)
class ReassignConfig:
    """Settings of `reassign_boundary`. Defaults suit label images of 128..1024 px."""

    k: int = 16                      # neighbours (in space) that form the local class centres
    hair_label: int = HAIR
    background_label: int | None = BACKGROUND  # not a bald class member (None: it is)
    bald_label: int = SKIN           # label given to a Gaussian moved out of the hair with no other vote
    band: float = 0.02               # half-width of the band around hair edges and depth jumps,
                                     # a fraction of the label image's shorter side (>= 1 px)
    depth_jump: float = 0.02         # relative depth step between neighbouring pixels that is a jump
    near_hair: float = 0.05          # depth jumps count only this close to the hair (same unit)
    min_alpha: float = 0.5           # pixels below this rendered alpha have no depth to compare
    boundary_fraction: float = 0.25  # share of a Gaussian's weight inside the band -> boundary
    occlusion: float = 0.02          # relative depth behind the rendered surface that is hidden,
    occlusion_sigmas: float = 2.0    # plus this many of the Gaussian's largest standard deviation
    occluded_fraction: float = 0.5   # share of a Gaussian's weight from views that hide it
    min_confidence: float = 0.7      # below: ambiguous, reclassified as well
    colour_weight: float = 1.0       # feature weights (each group standardised first)
    scale_weight: float = 0.5
    distance_weight: float = 2.0     # signed distance to the head surface, where it is given
    layer_quantile: float = 0.95     # the bald layer's thickness: this quantile of |distance| over
    min_layer: float = 0.001         # the confident bald-label members, at least min_layer (m)
    local: bool = True               # False: compare with the global class centres only

    def __post_init__(self):
        if isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)) or self.k < 1:
            raise InputError(f"reassignment k must be a positive integer, got {self.k!r}")
        for name in ("band", "near_hair", "depth_jump", "min_alpha", "boundary_fraction", "occlusion",
                     "occlusion_sigmas", "occluded_fraction", "min_confidence",
                     "colour_weight", "scale_weight", "distance_weight", "layer_quantile",
                     "min_layer"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating)) or not np.isfinite(v) or v < 0:
                raise InputError(f"reassignment {name} must be a number >= 0, got {v!r}")


@dataclass
class Reassignment:
    labels: np.ndarray      # (N,) int32 final labels (no UNSEEN left unless no class was known)
    changed: np.ndarray     # (N,) bool label differs from the lifted one
    boundary: np.ndarray    # (N,) bool in the boundary set
    occluded: np.ndarray    # (N,) bool seen mostly from views where it lies behind the surface
    candidates: np.ndarray  # (N,) bool reclassified: boundary | occluded | unseen | low confidence


def _pixels(fraction: float, shape) -> int:
    return max(1, int(round(fraction * min(shape))))


def _hair_edge_band(labels: np.ndarray, depth: np.ndarray, covered: np.ndarray,
                    cfg: ReassignConfig) -> np.ndarray:
    """(H, W) bool: pixels within `band` of a hair / not-hair label edge or of a depth jump
    close to the hair."""
    from scipy import ndimage

    hair = labels == cfg.hair_label
    edges = np.zeros_like(hair)
    # a pixel is on an edge if a 4-neighbour differs (both sides of the edge get marked)
    dh = hair[:, 1:] != hair[:, :-1]
    dv = hair[1:, :] != hair[:-1, :]
    edges[:, 1:] |= dh
    edges[:, :-1] |= dh
    edges[1:, :] |= dv
    edges[:-1, :] |= dv
    if cfg.depth_jump > 0 and hair.any():
        z = np.where(covered, depth, 0.0)
        jumps = np.zeros_like(hair)
        horizontal = ((slice(None), slice(1, None)), (slice(None), slice(None, -1)))
        vertical = ((slice(1, None), slice(None)), (slice(None, -1), slice(None)))
        for a, b in (horizontal, vertical):
            both = covered[a] & covered[b]
            step = np.abs(z[a] - z[b]) > cfg.depth_jump * np.minimum(z[a], z[b])
            jumps[a] |= both & step
            jumps[b] |= both & step
        near = ndimage.binary_dilation(hair, iterations=_pixels(cfg.near_hair, hair.shape))
        edges |= jumps & near
    if edges.any():
        edges = ndimage.binary_dilation(edges, iterations=_pixels(cfg.band, hair.shape))
    return edges


def _features(gaussians: GaussianSet, cfg: ReassignConfig, ref: np.ndarray,
              surface_distance: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """(N, 6) float64 appearance features: DC colour and sorted log-scales (so the order of a
    Gaussian's axes does not matter), each group standardised on the reference Gaussians;
    (N, 7) with the signed distance to the head surface as a seventh. The distance is what
    one view cannot corrupt: hair hidden behind hair has the hair's layer height whatever
    colour the lifter gave it, and the bald layer sits on the surface."""
    colour = gaussians.colors.astype(np.float64)
    logs = -np.sort(-np.log(gaussians.scales.astype(np.float64)), axis=1)
    groups = [(colour, cfg.colour_weight), (logs, cfg.scale_weight)]
    if surface_distance is not None:
        # clipped: only "on the surface" vs "above it" matters, not how far out a strand hangs
        sd, layer = surface_distance
        groups.append((np.clip(sd, -layer, 3.0 * layer)[:, None], cfg.distance_weight))
    parts = []
    for x, wgt in groups:
        mu = x[ref].mean(axis=0)
        sd = float(np.sqrt(((x[ref] - mu) ** 2).sum(axis=1).mean()))
        parts.append((x - mu) * (wgt / max(sd, 1e-6)))
    return np.concatenate(parts, axis=1)


def _classify(gaussians: GaussianSet, feats: np.ndarray, cand: np.ndarray, hair_ref: np.ndarray,
              bald_ref: np.ndarray, cfg: ReassignConfig) -> np.ndarray:
    """(M,) bool: is each candidate closer to the hair centre than to the bald one."""
    from scipy.spatial import cKDTree

    # class centres robust to the mislabelled members the reassignment is there to fix: the
    # median, then members nearer the other class's median leave the reference
    g_hair = np.median(feats[hair_ref], axis=0)
    g_bald = np.median(feats[bald_ref], axis=0)
    closer_hair = (np.linalg.norm(feats - g_hair, axis=1) < np.linalg.norm(feats - g_bald, axis=1))
    keep_h, keep_b = hair_ref & closer_hair, bald_ref & ~closer_hair
    if keep_h.any() and keep_b.any():
        hair_ref, bald_ref = keep_h, keep_b
    ref = np.flatnonzero(hair_ref | bald_ref)
    is_hair = hair_ref[ref]
    fc = feats[cand]
    d_hair = np.linalg.norm(fc - g_hair, axis=1)
    d_bald = np.linalg.norm(fc - g_bald, axis=1)
    if cfg.local:
        k = min(cfg.k, len(ref))
        _, nb = cKDTree(gaussians.means[ref].astype(np.float64)).query(
            gaussians.means[cand].astype(np.float64), k=k)
        nb = nb.reshape(len(fc), k)
        nh = is_hair[nb]                                  # (M, k)
        cnt_h = nh.sum(axis=1)
        cnt_b = k - cnt_h
        fn = feats[ref][nb]                               # (M, k, F)
        both = (cnt_h > 0) & (cnt_b > 0)
        c_hair = (fn * nh[..., None]).sum(axis=1) / np.maximum(cnt_h, 1)[:, None]
        c_bald = (fn * ~nh[..., None]).sum(axis=1) / np.maximum(cnt_b, 1)[:, None]
        d_hair = np.where(both, np.linalg.norm(fc - c_hair, axis=1), d_hair)
        d_bald = np.where(both, np.linalg.norm(fc - c_bald, axis=1), d_bald)
    return d_hair < d_bald


def _occluded_share(gaussians: GaussianSet, cameras, depths, covered, view_weights,
                    cfg: ReassignConfig) -> np.ndarray:
    """(N,) share of each Gaussian's weight that comes from views in which its centre lies
    behind the rendered depth D at its pixel by more than occlusion * D + occlusion_sigmas *
    its largest standard deviation: there it shows only through gaps of what is in front,
    whose label its pixels carry. (The sigma term: on a curved surface, the splats beside a
    large splat cover its centre pixel in front of it.)"""
    hidden = np.zeros(len(gaussians))
    slack = cfg.occlusion_sigmas * gaussians.scales.max(axis=1).astype(np.float64)
    for v, (cam, depth, cov) in enumerate(zip(cameras, depths, covered)):
        uv, z = cam.project(gaussians.means)
        inside = np.isfinite(uv).all(axis=1)
        px = np.clip(np.floor(np.nan_to_num(uv[:, 0])), 0, cam.width - 1).astype(np.intp)
        py = np.clip(np.floor(np.nan_to_num(uv[:, 1])), 0, cam.height - 1).astype(np.intp)
        inside &= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        d = depth[py, px]
        behind = inside & cov[py, px] & (z > d * (1.0 + cfg.occlusion) + slack)
        hidden += np.where(behind, view_weights[:, v], 0.0)
    total = view_weights.astype(np.float64).sum(axis=1)
    return hidden / np.maximum(total, 1e-12)


def _boundary_share(gaussians: GaussianSet, cameras, bands) -> tuple[np.ndarray, np.ndarray]:
    """(band weight (N,), total weight (N,)) summed over the views."""
    inside = np.zeros(len(gaussians))
    total = np.zeros(len(gaussians))
    for cam, band in zip(cameras, bands):
        w, _, _ = _accumulate(gaussians, cam, band.astype(np.int32), 2)
        inside += w[:, 1]
        total += w.sum(axis=1)
    return inside, total


def reassign_boundary(gaussians: GaussianSet, lift: LabelLift, cameras: list[Camera],
                      label_images: list[np.ndarray], depths: list[np.ndarray] | None = None,
                      config: ReassignConfig | None = None, surface_distance: np.ndarray | None = None,
                      **overrides) -> Reassignment:
    """The paper's boundary-aware reassignment (module docstring, step 3).

    lift: `lift_labels` of the same Gaussians, cameras and label images.
    depths: K rendered depth images (H, W); default the lift's own. Pixels count as covered
    where the lift's rendered alpha >= min_alpha (or, without it, where depth > 0).
    config / overrides: `ReassignConfig` fields, e.g. `reassign_boundary(..., k=8)`.
    surface_distance: (N,) signed distance (metres, > 0 outside) of each Gaussian's centre to
    the fitted head surface, a feature beside colour and scale (weight `distance_weight`).
    Give it when few views are labelled (the photo's only): the hair behind the visible hair
    and at the back of the head is then told from the scalp under it by its height over the
    surface, not by colours the lifter had to guess.
    A candidate that joins the hair gets `hair_label`; one that leaves it (or an unseen one
    that joins the bald class) gets its best non-hair lifted label, or `bald_label`.
    """
    _check_gaussians(gaussians)
    cfg = config or ReassignConfig()
    if overrides:
        unknown = set(overrides) - {f.name for f in dataclasses.fields(ReassignConfig)}
        if unknown:
            raise InputError(f"unknown reassignment setting(s): {', '.join(sorted(unknown))}")
        cfg = dataclasses.replace(cfg, **overrides)
    cameras, label_images = _check_views(cameras, label_images)
    n = len(gaussians)
    n_labels = lift.weights.shape[1]
    if lift.weights.shape[0] != n:
        raise InputError(f"the label lift is for {lift.weights.shape[0]} Gaussians, got {n}")
    if lift.view_weights.shape[1] != len(cameras):
        raise InputError(f"the label lift has {lift.view_weights.shape[1]} views, "
                         f"got {len(cameras)} cameras")
    if not 0 <= cfg.hair_label < n_labels or not 0 <= cfg.bald_label < n_labels:
        raise InputError(f"hair_label {cfg.hair_label} / bald_label {cfg.bald_label} must lie in "
                         f"0..{n_labels - 1}")
    if surface_distance is not None:
        surface_distance = np.asarray(surface_distance, np.float64)
        if surface_distance.shape != (n,) or not np.isfinite(surface_distance).all():
            raise InputError(f"surface_distance must be ({n},) finite distances, "
                             f"got shape {surface_distance.shape}")
    if depths is None:
        depths = lift.depths
    depths = list(depths)
    if len(depths) != len(cameras):
        raise InputError(f"got {len(depths)} depth images for {len(cameras)} cameras")

    bands, covers, zs = [], [], []
    for v, (cam, img, depth) in enumerate(zip(cameras, label_images, depths)):
        labels = _check_label_image(img, cam, n_labels, f"label image {v}")
        depth = np.asarray(depth, np.float32)
        if depth.shape != labels.shape:
            raise InputError(f"depth image {v} has shape {depth.shape}, expected {labels.shape}")
        alpha = lift.alphas[v] if len(lift.alphas) == len(cameras) else None
        covered = (alpha >= cfg.min_alpha) if alpha is not None and alpha.shape == depth.shape \
            else depth > 0
        bands.append(_hair_edge_band(labels, depth, covered, cfg))
        covers.append(covered)
        zs.append(depth)
    inside, total = _boundary_share(gaussians, cameras, bands)
    seen = lift.seen
    boundary = seen & (inside >= cfg.boundary_fraction * np.maximum(total, 1e-12)) & (total > 0)
    hidden = _occluded_share(gaussians, cameras, zs, covers, lift.view_weights, cfg)
    occluded = seen & (hidden >= cfg.occluded_fraction)
    cand = boundary | occluded | ~seen | (lift.confidence < cfg.min_confidence)
    ref = ~cand
    if cfg.background_label is not None:
        ref &= lift.labels != cfg.background_label
    hair_ref = ref & (lift.labels == cfg.hair_label)
    bald_ref = ref & (lift.labels != cfg.hair_label)
    # A class seen only near edges (thin hair seen in one view lies wholly in the band) has no
    # confident member: its seen, unoccluded members stand in for the reference then.
    member = lift.seen & ~occluded
    if cfg.background_label is not None:
        member &= lift.labels != cfg.background_label
    if not hair_ref.any():
        hair_ref = member & (lift.labels == cfg.hair_label)
    if not bald_ref.any():
        bald_ref = member & (lift.labels != cfg.hair_label)
    distance = None
    if surface_distance is not None:
        # Seen through the gaps of a hair volume, the scalp carries the hair's pixel labels
        # without being behind the rendered depth by much: a confident "hair" member that sits
        # in the bald layer is no reference, it is a candidate like the rest.
        on_skin = bald_ref & (lift.labels == cfg.bald_label)
        layer = cfg.min_layer
        if on_skin.any():
            layer = max(layer, float(np.quantile(np.abs(surface_distance[on_skin]), cfg.layer_quantile)))
        in_layer = hair_ref & (surface_distance <= layer)
        hair_ref &= ~in_layer
        cand |= in_layer
        distance = (surface_distance, layer)

    # where no hair is known, nothing can join it (and vice versa): candidates keep their
    # lifted labels, unseen ones take the one class there is
    new = lift.labels.copy()
    if hair_ref.any() and bald_ref.any():
        idx = np.flatnonzero(cand)
        to_hair = np.zeros(n, bool)
        if len(idx):
            feats = _features(gaussians, cfg, hair_ref | bald_ref, distance)
            to_hair[idx] = _classify(gaussians, feats, idx, hair_ref, bald_ref, cfg)
    else:
        to_hair = np.where(seen, lift.labels == cfg.hair_label, hair_ref.any())
        to_hair &= cand
    not_hair = lift.weights.astype(np.float64).copy()
    not_hair[:, cfg.hair_label] = -1.0
    best_other = np.argmax(not_hair, axis=1)
    best_other = np.where(not_hair[np.arange(n), best_other] > 0, best_other, cfg.bald_label)
    new[cand & to_hair] = cfg.hair_label
    leave = cand & ~to_hair & ((new == cfg.hair_label) | (new == UNSEEN))
    new[leave] = best_other[leave]
    if not (hair_ref.any() or bald_ref.any()):
        new[~seen] = UNSEEN  # nothing confident anywhere: unseen stays unseen
    return Reassignment(new.astype(np.int32), new != lift.labels, boundary, occluded, cand)


# --- the convenience the build pipeline calls ---------------------------------------------

@dataclass
class HairSplitReport:
    lift: LabelLift
    reassignment: Reassignment
    hair_index: np.ndarray   # (N_hair,) int64 indices into the input set
    bald_index: np.ndarray   # (N_bald,) int64
    timings: dict = field(default_factory=dict)  # seconds: lift, reassign

    @property
    def labels(self) -> np.ndarray:
        """(N,) int32 final labels."""
        return self.reassignment.labels

    def summary(self) -> dict:
        r = self.reassignment
        return dict(n=int(len(r.labels)), hair=int(len(self.hair_index)),
                    bald=int(len(self.bald_index)), unseen=int((~self.lift.seen).sum()),
                    boundary=int(r.boundary.sum()), reclassified=int(r.candidates.sum()),
                    changed=int(r.changed.sum()))


def split_hair(gaussians: GaussianSet, cameras: list[Camera], label_images: list[np.ndarray],
               hair_label: int = HAIR, n_labels: int | None = None, min_weight: float = 0.01,
               config: ReassignConfig | None = None, surface_distance: np.ndarray | None = None,
               **overrides) -> tuple[GaussianSet, GaussianSet, HairSplitReport]:
    """Lift, reassign, cut: (bald GaussianSet, hair GaussianSet, report).

    surface_distance: (N,) signed distances to the head surface (`reassign_boundary`); give
    them when only the photo's view is labelled.
    Gaussians whose final label is `hair_label` form the hair set; every other one (skin,
    body, background floaters, and any left unseen) the bald set. Extras travel with them.
    """
    t0 = time.perf_counter()
    lift = lift_labels(gaussians, cameras, label_images, n_labels, min_weight)
    t1 = time.perf_counter()
    overrides = dict(overrides, hair_label=hair_label)
    re = reassign_boundary(gaussians, lift, cameras, label_images, None, config, surface_distance,
                           **overrides)
    t2 = time.perf_counter()
    is_hair = re.labels == hair_label
    hair_index = np.flatnonzero(is_hair)
    bald_index = np.flatnonzero(~is_hair)
    report = HairSplitReport(lift, re, hair_index, bald_index, dict(lift=t1 - t0, reassign=t2 - t1))
    return gaussians.subset(bald_index), gaussians.subset(hair_index), report


# --- label images of a labelled set, and the views ----------------------------------------

def render_label_images(gaussians: GaussianSet, labels: np.ndarray, cameras: list[Camera],
                        n_labels: int | None = None, background_label: int = BACKGROUND,
                        min_alpha: float = 0.5) -> list[np.ndarray]:
    """Exact label images of a set with known per-Gaussian labels (N,) int in [0, n_labels):
    per pixel the label with the largest summed blending weight, or `background_label` where
    the rendered alpha is below `min_alpha`. K x (H, W) int32."""
    from avatarkit.render import bin_gaussians, project_gaussians, rasterize

    _check_gaussians(gaussians)
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
