"""The paper's collision ablation as numbers: how much hair sinks into the head, how far the
hair resting on the scalp is pushed off it, per simulation mode and motion clip.

penetration: the share of hair Gaussian centres inside the posed head (the rest head's grid SDF
    through the driver's `HeadSkin`: head joint, jaw and neck), per frame, before the driver's
    final push-out of the centres (`pushout`); reported as mean and max over frames.
gap: the mean distance to the head of the "contact layer" (the Gaussians within `contact_band`
    of the rest head: the hair lying on the scalp), counting penetrating ones as 0, averaged
    over frames. Vertex collision pushes cage vertices (which sit inside the head wherever the
    cage's margin reaches past the scalp) out, and the whole layer with them: the gap grows.
    Proxy collision only acts where a Gaussian would really sink in: the gap stays as modelled.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.sim.config import SimConfig
from avatarkit.head.sdf_grid import HeadSDF

MODES = ("static", "none", "vertex", "proxy")


@dataclass(frozen=True)
class AblationRow:
    mode: str
    clip: str
    frames: int
    penetration_mean: float  # share in [0, 1]
    penetration_max: float   # share in [0, 1], worst frame
    gap_mm: float            # millimetres
    rest_gap_mm: float       # the contact layer's gap at rest, for comparison


def _posed_distance(means, sdf, transform, skin):
    if skin is None:
        return sdf.query_posed(means, transform)[0]
    return skin.query_posed(sdf, means, transform)[0]


def penetration_share(means: np.ndarray, sdf: HeadSDF, transform: np.ndarray, skin=None) -> float:
    """Share of points (N, 3) inside the head posed by `transform` (4, 4), or with a `HeadSkin`
    by its joints' transforms (J, 4, 4)."""
    d = _posed_distance(means, sdf, transform, skin)
    return float(np.mean(d < 0)) if len(d) else 0.0


def layer_gap(means: np.ndarray, sdf: HeadSDF, transform: np.ndarray, skin=None) -> float:
    """Mean max(distance, 0) of points (N, 3) to the posed head, metres (transform as in
    `penetration_share`)."""
    d = _posed_distance(means, sdf, transform, skin)
    return float(np.mean(np.maximum(d, 0.0))) if len(d) else 0.0


def run_ablation(head_model, hair, cage, clips: dict, *, modes=None, config: SimConfig | None = None,
                 rest_vertices: np.ndarray | None = None, contact_band: float = 0.01,
                 warmup: float | None = None, progress=None, **build_options) -> list[AblationRow]:
    """Simulate every clip (name -> MotionClip) in every mode; one row per (mode, clip).

    The cage model (`CageModel.build(..., **build_options)`) and the hair's cage deformer are
    built once and shared by all runs. progress(done, total) is called after each run.
    """
    modes = MODES if modes is None else modes
    from avatarkit.cage.deform import CageDeformer
    from avatarkit.sim.driver import HairDriver

    config = config or SimConfig()
    rest_v = np.asarray(head_model.v_template if rest_vertices is None else rest_vertices, np.float32)
    base = HairDriver(head_model, hair, cage, config, rest_vertices=rest_v,
                      deformer=CageDeformer.build(hair, cage), **build_options)
    sdf = base.model.sdf
    rest_d, _ = sdf.query(hair.means)
    layer = rest_d < contact_band
    rest_gap = float(np.mean(np.maximum(rest_d[layer], 0.0))) if layer.any() else 0.0
    rows = []
    total, done = len(modes) * len(clips), 0
    for mode in modes:
        cfg = config.replace(static=True) if mode == "static" else config.replace(collision=mode, static=False)
        # the cage's own work: without the final push-out of the centres (which would hide it)
        driver = HairDriver(head_model, hair, cage, cfg, rest_vertices=rest_v, model=base.model,
                            deformer=base.deformer, head_joint=base.head_joint, skin=base.skin,
                            push_out=False)
        for name, clip in clips.items():
            pen, gap = [], []
            for frame in driver.simulate_clip(clip, warmup=warmup):
                joints = driver.frame.joint_transforms
                pen.append(penetration_share(frame.means, sdf, joints, driver.skin))
                gap.append(layer_gap(frame.means[layer], sdf, joints, driver.skin))
            rows.append(AblationRow(mode, name, len(pen), float(np.mean(pen)), float(np.max(pen)),
                                    1000 * float(np.mean(gap)), 1000 * rest_gap))
            done += 1
            if progress is not None:
                progress(done, total)
    return rows


def format_table(rows: list[AblationRow]) -> str:
    """A plain-text table of the rows."""
    lines = [f"{'mode':<8} {'clip':<8} {'frames':>6} {'penetration mean':>17} {'max':>7} "
             f"{'scalp gap (mm)':>15} {'rest gap':>9}"]
    for r in rows:
        lines.append(f"{r.mode:<8} {r.clip:<8} {r.frames:>6} {100 * r.penetration_mean:>16.2f}% "
                     f"{100 * r.penetration_max:>6.2f}% {r.gap_mm:>15.2f} {r.rest_gap_mm:>9.2f}")
    return "\n".join(lines)
