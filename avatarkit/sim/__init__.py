"""XPBD simulation of the hair cage (the paper's section 3.3 and Algorithm 1), in Taichi on the CPU.

Model / State / Config as in NVIDIA Warp's `sim`: `CageModel` (never changes), `CageState`
(positions, velocities), `HeadFrame` (the per-frame kinematic input), `SimConfig` (solver
settings), `XPBDSolver.step`. `HairDriver` runs the whole chain head pose -> cage -> hair.
Taichi is imported only when a solver first steps.
"""
from avatarkit.sim.config import COLLISION_MODES, SimConfig
from avatarkit.sim.model import CageModel, CageState, HeadFrame
from avatarkit.sim.solver import XPBDSolver

__all__ = ["COLLISION_MODES", "CageModel", "CageState", "HeadFrame", "SimConfig",
           "XPBDSolver"]
