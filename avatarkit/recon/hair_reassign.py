"""Boundary-aware reassignment of lifted labels (paper section 3.2, "boundary-aware
reassignment", Fig. "Hair Cleanup"): the third step of the 3D hair segmentation, after
`recon.label_lifting`.

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
   global (median) centres of both classes decide. With several views, `CLEAR_SHARE` (off) lets
   the votes from pixels clear of every view's band overrule that for a candidate put in the hair.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.label_lifting import (UNSEEN, LabelLift, accumulate_view, check_gaussians, check_label_image,
                                           check_views)
from avatarkit.recon.segment import BACKGROUND, HAIR, SKIN
from avatarkit.render.camera import Camera

#: with at least two labelled views (a video build's keyframes), a candidate the reassignment
#: puts in the hair leaves it when, of its votes from pixels outside every view's edge band
#: (`clear_votes`: where a view's label is not within `band` of a hair edge or depth jump),
#: more than this share are skin or body labels (None: the reassignment alone decides). The
#: band marks where a view's labels cannot be trusted; with one view a Gaussian there has no
#: other evidence than its neighbours' colour and size, but another view may see the same
#: Gaussian well away from any edge. The lifter's shell reaches over the temples and ears of
#: a short-haired head where the reference photo's hair mask meets its silhouette: every one of
#: those Gaussians lies in some view's band, is a candidate, and looks like the hair it was made
#: as (the photo's hair colour, a strand's size, the shell's height), so the neighbours' features
#: kept them all, while the keyframes turned toward that side see skin there clear of any edge.
#: Off (docs/video-build.md, "The temples' hair and the clear votes (session 23)"): at 0.5, with
#: `CLEAR_VETO` 0.5, in the final build only, the mesh subject's profile gain +2.58 -> +2.62
#: (seed 0), the held-out bob's views +0.2..+0.5 dB but at seed 1 its -90 view -0.05 (its
#: strands stand off the head: the keyframes see past them onto skin, and the shell's Gaussians
#: taken out were what stood in for them at the profile)
CLEAR_SHARE: float | None = None
#: ... and only with at least this much clear vote weight (pixels' worth of alpha x T)
CLEAR_MIN = 0.5
#: ... unless one view's clear votes give it at least this much hair weight (None: no view
#: can keep it alone)
CLEAR_VETO: float | None = 0.5
#: ... and in the drafts a video build registers its turned keyframes against too (False:
#: `recon.pipeline` passes `clear=False` for a draft, and the turned keyframes are registered
#: against the drafts as before). In the drafts too (no veto), the mesh subject's registered
#: turns moved by up to 3 degrees and it lost the back of its head's outline at -90 (profile gain
#: +2.61 against +2.64 in the final build alone), the bob its -45 view (-0.30 dB against main,
#: +0.52 in the final build alone)
CLEAR_IN_DRAFTS = False


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
    min_reference: float = 0.05      # a class with fewer confident members than this share of its
                                     # seen, unoccluded ones (or fewer than k) takes those as well
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
                     "occlusion_sigmas", "occluded_fraction", "min_confidence", "min_reference",
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
            gaussians.means[cand].astype(np.float64), k=k, workers=-1)
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
        w, _, _ = accumulate_view(gaussians, cam, band.astype(np.int32), 2)
        inside += w[:, 1]
        total += w.sum(axis=1)
    return inside, total


def clear_votes(gaussians: GaussianSet, cameras, label_images, bands, n_labels: int,
                per_view: bool = False):
    """(N, n_labels) float64: each Gaussian's blending weight per label summed over the views,
    counting only the pixels outside that view's edge band (`bands`: K (H, W) bool); with
    per_view, (K, N, n_labels) each view's."""
    out = np.zeros((len(cameras), len(gaussians), n_labels))
    for k, (cam, img, band) in enumerate(zip(cameras, label_images, bands)):
        lab = np.where(band, n_labels, np.asarray(img, np.int32)).astype(np.int32)
        w, _, _ = accumulate_view(gaussians, cam, lab, n_labels + 1)
        out[k] = w[:, :n_labels]
    return out if per_view else out.sum(axis=0)


def _reference_minimum(members: np.ndarray, cfg: ReassignConfig) -> float:
    """The fewest confident members that stand for a class of `members` (N,) bool seen,
    unoccluded members: `min_reference` of them, and at least one local neighbourhood (k)."""
    return min(float(members.sum()), max(float(cfg.k), cfg.min_reference * float(members.sum())))


def bald_layer(surface_distance: np.ndarray, on_skin: np.ndarray, hair_ref: np.ndarray,
               cfg: ReassignConfig) -> float:
    """The bald layer's thickness (metres): the `layer_quantile` of |surface_distance| (N,) over
    the confident bald-label members `on_skin` (N,) bool, at least `min_layer`, and below half
    the median height of the hair members `hair_ref` (N,) bool.

    The cap is what keeps mislabelled hair from widening the layer: hair the label images call
    skin sits at the hair's height, and once it is more than 1 - layer_quantile of the skin
    members the quantile jumps to that height. A short-hair shell then lies wholly inside the
    layer, and a few degrees of pose decided whether all unseen hair went bald (session 17)."""
    layer = cfg.min_layer
    if on_skin.any():
        layer = max(layer, float(np.quantile(np.abs(surface_distance[on_skin]), cfg.layer_quantile)))
    if hair_ref.any():
        layer = min(layer, max(cfg.min_layer, 0.5 * float(np.median(surface_distance[hair_ref]))))
    return layer


def reassign_boundary(gaussians: GaussianSet, lift: LabelLift, cameras: list[Camera],
                      label_images: list[np.ndarray], depths: list[np.ndarray] | None = None,
                      config: ReassignConfig | None = None, surface_distance: np.ndarray | None = None,
                      clear: bool = True, **overrides) -> Reassignment:
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
    clear: with two or more views, the clear votes may overrule the neighbours (`CLEAR_SHARE`).
    """
    check_gaussians(gaussians)
    cfg = config or ReassignConfig()
    if overrides:
        unknown = set(overrides) - {f.name for f in dataclasses.fields(ReassignConfig)}
        if unknown:
            raise InputError(f"unknown reassignment setting(s): {', '.join(sorted(unknown))}")
        cfg = dataclasses.replace(cfg, **overrides)
    cameras, label_images = check_views(cameras, label_images)
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
        labels = check_label_image(img, cam, n_labels, f"label image {v}")
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
    # confident member, or a stray few that cannot stand for it (three scalp splats for 1,270
    # seen hair members decided the whip clip's hair, session 17): its seen, unoccluded
    # members join the reference then.
    member = lift.seen & ~occluded
    if cfg.background_label is not None:
        member &= lift.labels != cfg.background_label
    hair_member = member & (lift.labels == cfg.hair_label)
    bald_member = member & (lift.labels != cfg.hair_label)
    if hair_ref.sum() < _reference_minimum(hair_member, cfg):
        hair_ref = hair_ref | hair_member
    if bald_ref.sum() < _reference_minimum(bald_member, cfg):
        bald_ref = bald_ref | bald_member
    distance = None
    if surface_distance is not None:
        # Seen through the gaps of a hair volume, the scalp carries the hair's pixel labels
        # without being behind the rendered depth by much: a confident "hair" member that sits
        # in the bald layer is no reference, it is a candidate like the rest.
        layer = bald_layer(surface_distance, bald_ref & (lift.labels == cfg.bald_label), hair_ref, cfg)
        in_layer = hair_ref & (surface_distance <= layer)
        if in_layer.all(where=hair_ref) and hair_ref.any():
            # The hair lies wholly within the bald layer (a thin shell): height cannot tell
            # them apart here, and dropping every hair member would hand all unseen hair to
            # the bald class. Colour and scale decide alone.
            in_layer[:] = False
        else:
            distance = (surface_distance, layer)
        hair_ref &= ~in_layer
        cand |= in_layer

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
    if clear and CLEAR_SHARE is not None and len(cameras) >= 2 and (cand & to_hair).any():
        # the views that see a candidate clear of every edge overrule its neighbours' looks
        each = clear_votes(gaussians, cameras, label_images, bands, n_labels, per_view=True)
        votes = each.sum(axis=0)
        if CLEAR_VETO is not None:
            # one view that sees hair there clear of any edge keeps it
            to_hair_kept = (each[:, :, cfg.hair_label] >= CLEAR_VETO).any(axis=0)
        else:
            to_hair_kept = np.zeros(n, bool)
        other = votes.sum(axis=1) - votes[:, cfg.hair_label]
        if cfg.background_label is not None:
            other -= votes[:, cfg.background_label]
        total = other + votes[:, cfg.hair_label]
        to_hair &= ~((total >= CLEAR_MIN) & (other > CLEAR_SHARE * total)) | to_hair_kept
    new[cand & to_hair] = cfg.hair_label
    leave = cand & ~to_hair & ((new == cfg.hair_label) | (new == UNSEEN))
    new[leave] = best_other[leave]
    if not (hair_ref.any() or bald_ref.any()):
        new[~seen] = UNSEEN  # nothing confident anywhere: unseen stays unseen
    return Reassignment(new.astype(np.int32), new != lift.labels, boundary, occluded, cand)


__all__ = ["CLEAR_IN_DRAFTS", "CLEAR_MIN", "CLEAR_SHARE", "CLEAR_VETO", "ReassignConfig", "Reassignment", "bald_layer", "clear_votes",
           "reassign_boundary"]
