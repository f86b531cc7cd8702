"""3D hair segmentation: 2D label images lifted to Gaussians, then boundary-aware reassignment.

Paper section 3.2 ("boundary-aware reassignment", Fig. "Hair Cleanup"). Three steps:

1. `recon.label_lifting.accumulate_weights`: every Gaussian's blending weight per pixel label
   in one view (the renderer's compositing);
2. `recon.label_lifting.lift_labels`: weights summed over K views, label = argmax;
3. `recon.hair_reassign.reassign_boundary`: the Gaussians at hair edges, seen from behind the
   surface, unseen or ambiguous are reclassified from their neighbours' colour and size.

`split_hair` chains the three and cuts the set in two. `recon.label_lifting` also makes exact
label images of a set whose per-Gaussian labels are known (`render_label_images`: the built-in
hair, tests) and the K orbit views (`default_label_cameras`).

Only the front view has a label image from the photo in the real pipeline. Lifting from that
one view labels what it sees; everything it does not see (the back and the sides of the head,
splats hidden under the hair) is UNSEEN and gets its label from the k-NN step, i.e. from the
nearest seen Gaussians whose colour and size it resembles.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon import segment as _segment
from avatarkit.recon.hair_reassign import ReassignConfig, Reassignment, reassign_boundary
from avatarkit.recon.label_lifting import LabelLift, lift_labels
from avatarkit.render.camera import Camera


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
               hair_label: int | None = None, n_labels: int | None = None, min_weight: float = 0.01,
               config: ReassignConfig | None = None, surface_distance: np.ndarray | None = None,
               clear: bool = True, **overrides) -> tuple[GaussianSet, GaussianSet, HairSplitReport]:
    """Lift, reassign, cut: (bald GaussianSet, hair GaussianSet, report).

    surface_distance: (N,) signed distances to the head surface (`reassign_boundary`); give
    them when only the photo's view is labelled. clear: `reassign_boundary`'s.
    Gaussians whose final label is `hair_label` form the hair set; every other one (skin,
    body, background floaters, and any left unseen) the bald set. Extras travel with them.
    """
    hair_label = _segment.HAIR if hair_label is None else hair_label
    t0 = time.perf_counter()
    lift = lift_labels(gaussians, cameras, label_images, n_labels, min_weight)
    t1 = time.perf_counter()
    overrides = dict(overrides, hair_label=hair_label)
    re = reassign_boundary(gaussians, lift, cameras, label_images, None, config, surface_distance,
                           clear=clear, **overrides)
    t2 = time.perf_counter()
    is_hair = re.labels == hair_label
    hair_index = np.flatnonzero(is_hair)
    bald_index = np.flatnonzero(~is_hair)
    report = HairSplitReport(lift, re, hair_index, bald_index, dict(lift=t1 - t0, reassign=t2 - t1))
    return gaussians.subset(bald_index), gaussians.subset(hair_index), report


__all__ = ["HairSplitReport", "split_hair"]
