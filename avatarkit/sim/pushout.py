"""The last guard of the hair against the head: hair Gaussian centres that the cage deformation
leaves inside (or closer than a clearance to) the posed head are moved out along its normal.

The cage's proxy collision keeps each cage vertex's proxy Gaussian out, but between proxies
the mean value interpolation of a coarse cage can still carry a centre a few millimetres into
the skull during a fast move (measured on the whip: up to 4.3 mm in ~100 of 6k Gaussians in a
frame). Pushing those centres out costs one SDF lookup per Gaussian (a parallel Taichi loop,
`_kernels.push_out_points`); `push_out_reference` is its numpy twin. The posed head is the
same as the solver's: the rest SDF seen through `HeadSkin` (inverse LBS, jaw and neck).
"""
from __future__ import annotations

import numpy as np

from avatarkit.sim._skin_math import JMAX
from avatarkit.head.sdf_grid import CELL_STEP, HeadSDF
from avatarkit.sim.sdf import HeadSkin

#: where a pushed centre ends up: this far outside the head (metres); half a millimetre keeps a
#: float32 centre outside after rounding and costs nothing visible
CLEARANCE = 0.0005
#: Newton steps on the SDF (the second fixes the few centres in a concave spot)
ROUNDS = 2
#: how far above the clearance a cell's floor must be for the screen to pass its points: far
#: more than the float32 rounding of a trilinear blend (~1e-7 m)
SCREEN_SLACK = 1e-5


def screen_limit(clearance: float) -> int:
    """The `HeadSDF.cell_floor` code from which a cell is far enough from the head to leave its
    points alone (0: no screen, for a clearance beyond what the codes hold)."""
    limit = int(np.ceil((clearance + SCREEN_SLACK) / CELL_STEP))
    return limit if 0 < limit <= 255 else 0


def _pose_buffer(sdf: HeadSDF, skin: HeadSkin, transforms: np.ndarray) -> np.ndarray:
    t = np.asarray(transforms, dtype=np.float64)
    rot = np.zeros((JMAX, 3, 3))
    trans = np.zeros((JMAX, 3))
    rot[:len(t)] = t[:, :3, :3]
    trans[:len(t)] = t[:, :3, 3]
    from avatarkit.sim.solver import deviation_box, skin_deviation

    dev = skin_deviation(skin, sdf, rot[None], trans[None], len(t))[0]
    lo, hi = deviation_box(sdf)  # the box skin_deviation's bound holds in
    return np.concatenate([sdf.origin, [1.0 / sdf.spacing], skin.origin, [1.0 / skin.spacing],
                           rot.ravel(), trans.ravel(), [dev], lo, hi]).astype(np.float32)


def push_out(points: np.ndarray, sdf: HeadSDF, skin: HeadSkin, transforms: np.ndarray,
             clearance: float | None = None, rounds: int | None = None, screen: bool = True) -> np.ndarray:
    """Points (N, 3) (a float32 copy is returned) moved out of the head posed by the transforms
    (J, 4, 4) of the skin's joints (J = 1: the head joint only).

    screen: first rule out, from one byte read (`HeadSDF.cell_floor` at the point in the head
    joint's frame, less LIPSCHITZ times the pose's bound on how far the skinned pieces move
    against the skull), then for the rest from one trilinear lookup of the rest SDF there, the
    points that no piece of the posed head comes within the clearance of, and leave them as
    they are: the full lookup would too, so the result is the same bit
    for bit (most hair centres lie millimetres to centimetres off the scalp); False: the full
    lookup for every point (the reference the tests compare with)."""
    clearance = CLEARANCE if clearance is None else clearance
    rounds = ROUNDS if rounds is None else rounds
    from avatarkit.sim import _kernels

    out = np.array(points, dtype=np.float32, copy=True, order="C").reshape(-1, 3)
    t = np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4)
    nj = min(len(t), len(skin.joints))
    if len(out):
        pose = _pose_buffer(sdf, skin, t[:nj])
        dev = float(pose[8 + 12 * JMAX])
        reach = float(clearance) + _kernels.LIPSCHITZ * dev
        limit = screen_limit(reach) if screen else 0
        _push_out_call()(out, pose, sdf.values_grad, skin.weights, sdf.cell_floor, nj,
                         float(clearance), int(rounds), limit, reach + SCREEN_SLACK)
    return out


_CALL: list = []


def _push_out_call():
    """`_kernels.push_out_points` through one `KernelCall` (its per-call cost is the bake's,
    every frame)."""
    if not _CALL:
        from avatarkit.sim import _kernels
        from avatarkit.sim._launch import KernelCall

        _CALL.append(KernelCall(_kernels.push_out_points))
    return _CALL[0]


def push_out_reference(points: np.ndarray, sdf: HeadSDF, skin: HeadSkin, transforms: np.ndarray,
                       clearance: float | None = None, rounds: int | None = None) -> np.ndarray:
    """The obvious numpy twin of `push_out` (float64)."""
    clearance = CLEARANCE if clearance is None else clearance
    rounds = ROUNDS if rounds is None else rounds
    t = np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4)
    nj = min(len(t), len(skin.joints))
    sk = HeadSkin(skin.weights, skin.joints[:nj], skin.origin.astype(np.float32), skin.spacing)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3).copy()
    for _ in range(rounds):
        d, n = sk.query_posed(sdf, p, t[:nj])
        inside = d < clearance
        p[inside] += (clearance - d[inside])[:, None] * n[inside]
    return p
