"""`SimConfig`: the solver's settings (Warp's "integrator" parameters), kept off the model.

Compliances are XPBD alphas (inverse stiffness, m/N-like units; 0 = hard constraint).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from avatarkit.errors import InputError

COLLISION_MODES = ("none", "vertex", "proxy")


@dataclass(frozen=True)
class SimConfig:
    """Settings of `XPBDSolver` (Algorithm 1 of the paper, Macklin et al. 2016 XPBD).

    gravity: (3,) m/s^2, +Y up. substeps per frame, iterations per substep (Gauss-Seidel sweeps).
    compliance_*: XPBD alpha per constraint type. damping: velocity decay rate in 1/s
    (v *= exp(-damping * h) after every substep). collision_margin: epsilon in metres (a
    collision point is pushed to sdf >= epsilon). collision: "none" | "vertex" (test the cage
    vertex itself) | "proxy" (test the vertex's proxy Gaussian, the paper's method).
    static: True: the hair follows the head joint rigidly, no dynamics; False: simulated; None
    (default): the avatar decides when baking (`bake.bake` takes static for an avatar built with
    short, rigid hair, dynamic for the rest); a solver or driver used alone simulates. max_speed:
    m/s, a safety clamp
    on particle speed so a violent pose jump cannot explode the cage. max_substep: the longest
    substep in seconds; a long frame gets more than `substeps` substeps so that gravity's drop per
    substep (g h^2) stays small against what 15 iterations can pull back (with h = 0.1 s a
    10 cm drop per substep leaves a 22 cm cage ~60% stretched; with h <= 1/60 s it stays
    within a few percent). warmup_seconds: how long `HairDriver.reset` lets the hair settle at
    the first pose before frame 0. collision_period: seconds; the collision constraints act in
    every k-th substep, k the most substeps that fit in this time (at least 1), and in the
    frame's last. The default, 1/600 s, is every 2nd substep at 30 fps and 40 substeps: half the
    collision tests (the kernel's second-largest cost), with the whip's strain, rest, penetration
    and the ablation within the tests' bounds (docs/simulation.md; every 8th let the hair bounce on
    the scalp). Long frames (h over the period) get collision in every substep. 0: every substep.
    """

    gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)
    substeps: int = 40
    iterations: int = 1
    compliance_stretch: float = 0.0
    compliance_bending: float = 2e-4
    compliance_volume: float = 0.0
    compliance_tether: float = 0.0
    compliance_collision: float = 0.0
    damping: float = 2.0
    collision_margin: float = 0.002
    collision: str = "proxy"
    static: bool | None = None
    max_speed: float = 15.0
    max_substep: float = 1.0 / 60.0
    warmup_seconds: float = 1.0
    collision_period: float = 1.0 / 600.0

    def __post_init__(self):
        g = np.asarray(self.gravity, dtype=np.float64)
        if g.shape != (3,) or not np.isfinite(g).all():
            raise InputError(f"gravity must be 3 finite numbers, got {self.gravity!r}")
        object.__setattr__(self, "gravity", tuple(float(c) for c in g))
        for name in ("substeps", "iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        for f in fields(self):
            if f.name.startswith("compliance_") or f.name in ("damping", "collision_margin",
                                                              "warmup_seconds", "collision_period"):
                value = getattr(self, f.name)
                if not (np.isfinite(value) and value >= 0):
                    raise InputError(f"{f.name} must be a finite number >= 0, got {value!r}")
        if not (np.isfinite(self.max_speed) and self.max_speed > 0):
            raise InputError(f"max_speed must be > 0, got {self.max_speed!r}")
        if not self.max_substep > 0:  # inf allowed: exactly `substeps` substeps per frame
            raise InputError(f"max_substep must be > 0 seconds, got {self.max_substep!r}")
        if self.static is not None and not isinstance(self.static, (bool, np.bool_)):
            raise InputError(f"static must be true, false or unset, got {self.static!r}")
        if self.static is not None:
            object.__setattr__(self, "static", bool(self.static))
        if self.collision not in COLLISION_MODES:
            raise InputError(f"collision must be one of {', '.join(COLLISION_MODES)}, "
                             f"got {self.collision!r}")

    def replace(self, **changes) -> "SimConfig":
        return replace(self, **changes)

    def substeps_for(self, dt: float) -> int:
        """Substeps for a frame of dt seconds: `substeps`, or more if a substep would be longer
        than `max_substep`."""
        # (math, not numpy: this runs every step, and numpy's scalar calls cost ~10x more)
        if not math.isfinite(self.max_substep):
            return self.substeps
        return max(self.substeps, math.ceil(dt / self.max_substep - 1e-9))

    def collision_every(self, dt: float) -> int:
        """k: collision acts in every k-th substep of a dt-second frame (and in its last)."""
        h = dt / self.substeps_for(dt)
        return max(1, math.floor(self.collision_period / h + 1e-9))
