"""`HairDriver`: head pose per frame -> simulated cage -> deformed hair Gaussians.

The whole inference chain of the paper's Algorithm 1 for the hair: roots from the posed head
(LBS, step 2), XPBD on the cage (step 3), hair Gaussians through the cage's mean value
coordinates (step 4, `avatarkit.cage.deform.CageDeformer`).

Warm start: `reset` places the rest cage rigidly at the first pose and then simulates
`SimConfig.warmup_seconds` (default 1 s) with the head held still, so the hair has settled under
gravity (sagged to rest, velocities ~0) before frame 0 instead of dropping during the first
frames of the clip. Pass `warmup=0` to start from the modelled shape exactly.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.sim.config import SimConfig
from avatarkit.sim.model import CageModel, CageState, HeadFrame
from avatarkit.sim.sdf import HeadSkin
from avatarkit.sim.solver import XPBDSolver

#: frames posed per call of the head model in `simulate_clip` (bounds memory on long clips)
POSE_CHUNK = 64


@dataclass
class SimFrame:
    """One simulated frame: cage (C, 3); hair means (N, 3), quats (N, 4) wxyz, scales (N, 3)
    (None when the driver was asked for the cage only); head_transform (4, 4) of the head joint."""

    index: int
    cage: np.ndarray
    means: np.ndarray | None
    quats: np.ndarray | None
    scales: np.ndarray | None
    head_transform: np.ndarray


def head_joint_of(head_model, region: str = "scalp") -> int:
    """The joint that carries the skull: the one with the most skinning weight on `region`
    (FLAME: joint 1, "neck", which turns the head)."""
    weights = np.asarray(head_model.weights)
    regions = getattr(head_model, "regions", {}) or {}
    rows = weights[np.asarray(regions[region])] if region in regions else weights
    return int(np.argmax(rows.sum(axis=0)))


class HairDriver:
    """Drives a hair cage (and its Gaussians) from head poses.

    head_model: an `avatarkit.head.HeadModel`; hair: the hair GaussianSet at rest (fitted to the
    rest head); cage: the rest `Cage` around it; config: `SimConfig`. rest_vertices (V, 3): the
    head the hair was fitted to (default the model's template). head_joint: the joint whose
    skinning transform places the collision SDF (default: `head_joint_of`). model: a prebuilt
    `CageModel` (else built with `CageModel.build(..., **build_options)`); deformer: a prebuilt
    `CageDeformer` of this hair and cage (drivers of the same avatar can share both).
    skin: the `HeadSkin` that lets collision follow the posed jaw and neck (default: built from
    the head model's skinning weights; `HeadSkin.rigid` for the rest head moved by the head joint
    alone). push_out: move hair Gaussian centres that end up inside the posed head out of it
    (`pushout.push_out`) in `hair_arrays` / `hair`.

    Head poses are given as the head joint's transform (4, 4) or, to follow the jaw and neck,
    as all joints' transforms (J, 4, 4) as `HeadModel.forward` returns them.
    """

    def __init__(self, head_model, hair: GaussianSet, cage, config: SimConfig | None = None, *,
                 rest_vertices: np.ndarray | None = None, head_joint: int | None = None,
                 model: CageModel | None = None, deformer=None, skin: HeadSkin | None = None,
                 push_out: bool = True, **build_options):
        self.head_model = head_model
        self.hair_rest = hair
        self.cage = cage
        self.rest_vertices = np.asarray(head_model.v_template if rest_vertices is None else rest_vertices,
                                        dtype=np.float32)
        self.model = model or CageModel.build(cage, hair, head_model, self.rest_vertices, **build_options)
        if self.model.num_vertices != len(np.asarray(cage.vertices)):
            raise InputError(f"the cage has {len(cage.vertices)} vertices, the model "
                             f"{self.model.num_vertices}")
        self.head_joint = head_joint_of(head_model) if head_joint is None else int(head_joint)
        if skin is None:
            weights = getattr(head_model, "weights", None)
            if weights is None or np.asarray(weights).shape[0] != len(self.rest_vertices):
                skin = HeadSkin.rigid(self.head_joint)
            else:
                skin = HeadSkin.build(self.rest_vertices, weights, self.head_joint, sdf=self.model.sdf)
        if int(skin.joints[0]) != self.head_joint:
            raise InputError(f"the skin's first joint is {int(skin.joints[0])}, the head joint "
                             f"{self.head_joint}")
        self.skin = skin
        self.push_out = bool(push_out)
        self.solver = XPBDSolver(self.model, config or SimConfig(), skin=skin)
        self.state: CageState | None = None
        self._frame: HeadFrame | None = None
        self._deformer = deformer

    @property
    def config(self) -> SimConfig:
        return self.solver.config

    @property
    def deformer(self):
        """The `CageDeformer` of the hair (built on first use: its MVC weights take a while)."""
        if self._deformer is None:
            from avatarkit.cage.deform import CageDeformer

            self._deformer = CageDeformer.build(self.hair_rest, self.cage)
        return self._deformer

    # --- stepping ------------------------------------------------------------------------------
    def head_frame(self, head_vertices: np.ndarray, transforms: np.ndarray) -> HeadFrame:
        """The solver's input for posed head vertices (V, 3) and the head joint's transform
        (4, 4) or every joint's (J, 4, 4)."""
        t = np.asarray(transforms, dtype=np.float64)
        if t.ndim == 3:
            if t.shape[0] <= max(self.head_joint, int(self.skin.joints.max())):
                raise InputError(f"{t.shape[0]} joint transforms given, the head joint is "
                                 f"{self.head_joint}")
            return self.model.head_frame(head_vertices, t[self.head_joint], t[self.skin.joints])
        return self.model.head_frame(head_vertices, t)

    @property
    def frame(self) -> HeadFrame | None:
        """The head frame of the last reset or step (None before the first)."""
        return self._frame

    def reset(self, head_vertices: np.ndarray | None = None, head_transform: np.ndarray | None = None,
              *, warmup: float | None = None, dt: float = 1 / 30) -> np.ndarray:
        """Start at a pose: head vertices (V, 3) (default rest) and head joint transform (4, 4)
        (default identity). The cage is the rest cage moved rigidly by the transform, then
        settled for `warmup` seconds (default `config.warmup_seconds`) in steps of dt.
        Returns the cage positions (C, 3)."""
        v = self.rest_vertices if head_vertices is None else head_vertices
        frame = self.head_frame(v, np.eye(4) if head_transform is None else head_transform)
        t = frame.transform
        x = (self.model.rest_positions.astype(np.float64) @ t[:3, :3].T + t[:3, 3]).astype(np.float32)
        x[self.model.roots] = frame.root_positions
        self.state = CageState(x, np.zeros_like(x))
        self._frame = frame
        seconds = self.config.warmup_seconds if warmup is None else float(warmup)
        if seconds < 0 or not np.isfinite(seconds):
            raise InputError(f"warmup must be >= 0 seconds, got {warmup}")
        if not self.config.static:
            for _ in range(int(round(seconds / dt))):
                self.solver.step(self.state, self.state, frame, frame, dt)
            self.state.velocities[:] = 0
        return self.state.positions.copy()

    def step(self, head_vertices: np.ndarray, head_transform: np.ndarray, dt: float) -> np.ndarray:
        """Advance dt seconds to the pose (posed head vertices (V, 3), head joint transform (4, 4));
        returns the cage positions (C, 3). The first call (or one after no reset) resets."""
        if self.state is None:
            return self.reset(head_vertices, head_transform, dt=dt)
        frame = self.head_frame(head_vertices, head_transform)
        self.solver.step(self.state, self.state, self._frame, frame, dt)
        self._frame = frame
        return self.state.positions.copy()

    @property
    def cage_positions(self) -> np.ndarray:
        if self.state is None:
            raise InputError("the driver has not been reset or stepped yet")
        return self.state.positions

    def hair_arrays(self, cage_positions: np.ndarray | None = None, frame: HeadFrame | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(means (N, 3), quats (N, 4), scales (N, 3)) of the hair for the current cage (or the
        given positions (C, 3)), centres pushed out of the head of `frame` (default: the
        current one) when `push_out` is on."""
        means, quats, scales = self.deformer.deform_arrays(
            self.cage_positions if cage_positions is None else cage_positions)
        return self.pushed_out(means, frame), quats, scales

    def pushed_out(self, means: np.ndarray, frame: HeadFrame | None = None) -> np.ndarray:
        """Hair centres (N, 3) moved out of the head of `frame` (default: the current one);
        unchanged when `push_out` is off or no frame is known yet."""
        frame = frame or self._frame
        if not self.push_out or frame is None:
            return means
        from avatarkit.sim.pushout import push_out

        t = frame.transform[None] if frame.joint_transforms is None else frame.joint_transforms
        return push_out(means, self.model.sdf, self.skin, t)

    def hair(self, cage_positions: np.ndarray | None = None) -> GaussianSet:
        """The deformed hair GaussianSet for the current cage (or the given positions)."""
        hair = self.deformer.deform(self.cage_positions if cage_positions is None else cage_positions)
        if self.push_out and self._frame is not None:
            hair.means = self.pushed_out(np.asarray(hair.means))
        return hair

    # --- clips ---------------------------------------------------------------------------------
    def simulate_clip(self, clip, *, with_hair: bool = True, warmup: float | None = None,
                      head_params=None) -> Iterator[SimFrame]:
        """Yield one `SimFrame` per frame of a `MotionClip` (streaming: the head is posed
        POSE_CHUNK frames at a time). Frame 0 resets the driver at the clip's first pose.
        head_params: `HeadParams` to use instead of `HeadParams.from_clip(clip)`."""
        from avatarkit.head.model import HeadParams

        params = HeadParams.from_clip(clip) if head_params is None else head_params
        dt = 1.0 / float(clip.fps)
        n = params.num_frames
        for start in range(0, n, POSE_CHUNK):
            idx = np.arange(start, min(n, start + POSE_CHUNK))
            vertices, transforms = self.head_model.forward(params.select(idx))
            for k, i in enumerate(idx):
                t = transforms[k].astype(np.float64)
                if i == 0:
                    cage = self.reset(vertices[k], t, warmup=warmup, dt=dt)
                else:
                    cage = self.step(vertices[k], t, dt)
                t = t[self.head_joint]
                means = quats = scales = None
                if with_hair:
                    means, quats, scales = self.hair_arrays(cage)
                yield SimFrame(int(i), cage, means, quats, scales, t)
