"""The lifting interface (issue 8 item 5): the portrait -> a bald head and a hair volume of 3D
Gaussians, in the fitted rest head's frame (see `recon.fit`).

    result = lifter.lift(image, analysis, segmentation, bald, fit)   # -> LiftResult(bald, hair)

Two lifters: `recon.lift.BuiltinLifter` (offline, no learned model: `recon.bald_discs`,
`recon.hair_strands`, `recon.hair_fill`) and `recon.import_lifter.ImportLifter` (splats from an
image-to-3D tool).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.fit import HeadFit


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


__all__ = ["LiftResult", "Lifter"]
