"""Keep the source's skin out of transferred hair (the paper's boundary-aware reassignment, as it
applies to a transfer: "removes residual skin from hair Gaussians, yielding smoother and more
natural cross-identity hairstyle transfer").

Residual skin in a hair set sits where the hair met the skin: on the source head's surface
(a hairline splat, scalp showing between strands). So the boundary set is the hair Gaussians
within `band` of the source head's surface, or of the target's after re-seating. Each of those is
classified in the same feature space as `recon.labels3d`'s reassignment: DC colour and sorted
log-scales (a splat's size and flatness, whatever the order of its axes), each group
standardised over all the Gaussians involved. It is skin when it lies nearer to a local skin
centre than to the hair centre:
- skin centres: the mean features of the `k` source bald Gaussians nearest to where it was on
  the source (the skin it would have come from), and of the `k` target bald Gaussians nearest
  to where it lands (the skin it would sit on, in case the source's skin colour is unknown);
- the hair centre: the median features of the whole hairstyle (a minority of skin does not move
  it).
Not rendered: a transfer has no photo, so there are no 2D hair masks to lift (the lifted-label
step of `recon.labels3d` needs them); at a few thousand hair Gaussians, strands are thin enough
that almost every one touches a rendered hair edge, which makes every one a boundary candidate.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet


@dataclass(frozen=True)
class SkinCleanup:
    """band: metres from either head's surface within which a hair Gaussian may be skin;
    k: bald neighbours forming a local skin centre; colour_weight / scale_weight: weights of the
    two standardised feature groups (as in `recon.hair_reassign.ReassignConfig`; here size counts as
    much as colour: blond highlights are skin-coloured, but thin, while skin splats are broad
    discs)."""

    band: float = 0.01
    k: int = 16
    colour_weight: float = 1.0
    scale_weight: float = 1.0

    def __post_init__(self):
        if not (np.isfinite(self.band) and self.band > 0):
            raise InputError(f"the skin clean-up band must be > 0 metres, got {self.band!r}")
        if isinstance(self.k, bool) or int(self.k) != self.k or self.k < 1:
            raise InputError(f"the skin clean-up k must be a positive integer, got {self.k!r}")
        for name in ("colour_weight", "scale_weight"):
            w = getattr(self, name)
            if not (np.isfinite(w) and w >= 0):
                raise InputError(f"the skin clean-up {name} must be >= 0, got {w!r}")


def features(sets: list[GaussianSet], config: SkinCleanup) -> list[np.ndarray]:
    """(N_i, 6) float64 features of each set: DC colour and descending log-scales, each group
    standardised (centred, divided by its RMS spread) over all the sets together."""
    colour = [s.colors.astype(np.float64) for s in sets]
    logs = [-np.sort(-np.log(s.scales.astype(np.float64)), axis=1) for s in sets]
    out = [[] for _ in sets]
    for group, weight in ((colour, config.colour_weight), (logs, config.scale_weight)):
        everything = np.concatenate(group)
        mu = everything.mean(axis=0)
        sd = float(np.sqrt(((everything - mu) ** 2).sum(axis=1).mean()))
        for i, x in enumerate(group):
            out[i].append((x - mu) * (weight / max(sd, 1e-9)))
    return [np.concatenate(parts, axis=1) for parts in out]


def _local_centre(bald_means: np.ndarray, bald_feats: np.ndarray, at: np.ndarray, k: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    k = min(k, len(bald_means))
    _, nb = cKDTree(np.asarray(bald_means, np.float64)).query(np.asarray(at, np.float64), k=k)
    return bald_feats[nb.reshape(len(at), k)].mean(axis=1)


def skin_in_hair(hair: GaussianSet, seated_means: np.ndarray, source_bald: GaussianSet,
                 source_head: tuple[np.ndarray, np.ndarray], target_bald: GaussianSet,
                 target_head: tuple[np.ndarray, np.ndarray], config: SkinCleanup | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Which hair Gaussians are skin (module docstring).

    hair: the hair at the SOURCE (N); seated_means (N, 3): where it lands on the target;
    source_bald / target_bald: the two avatars' bald Gaussians at rest; source_head /
    target_head: (vertices (V, 3), faces (F, 3)) of the two rest heads.
    Returns (is_skin (N,) bool, candidates (N,) bool: the boundary set that was classified).
    """
    from avatarkit.cage.inside import surface_distance

    cfg = config or SkinCleanup()
    n = len(hair)
    seated = np.asarray(seated_means, np.float64).reshape(-1, 3)
    if len(seated) != n:
        raise InputError(f"{len(seated)} seated positions for {n} hair Gaussians")
    near_source = surface_distance(hair.means, *source_head, radius=cfg.band) < cfg.band
    near_target = surface_distance(seated, *target_head, radius=cfg.band) < cfg.band
    cand = near_source | near_target
    is_skin = np.zeros(n, bool)
    idx = np.flatnonzero(cand)
    # each skin reference with the points its local centres are taken at
    present = [(bald, at) for bald, at in ((source_bald, hair.means[idx]), (target_bald, seated[idx]))
               if len(bald)]
    if len(idx) == 0 or not present:
        return is_skin, cand
    feats = features([hair] + [bald for bald, _ in present], cfg)
    f_cand = feats[0][idx]
    d_hair = np.linalg.norm(f_cand - np.median(feats[0], axis=0), axis=1)
    d_skin = np.full(len(idx), np.inf)
    for (bald, at), f_bald in zip(present, feats[1:]):
        local = _local_centre(bald.means, f_bald, at, cfg.k)
        d_skin = np.minimum(d_skin, np.linalg.norm(f_cand - local, axis=1))
    is_skin[idx] = d_skin < d_hair
    return is_skin, cand


__all__ = ["SkinCleanup", "features", "skin_in_hair"]
