"""The tracked head's motion carried by the neck joint, the body held at one pose.

The tracker fits a rigid head: each frame's pose is a global rotation R_t (about the root joint
J0, the neck base) and translation tau_t, with `neck` = 0. Driven that way the avatar turns its
whole neck, its shoulders and the build frame's collar with the head; in a talking-head video
the body stays and the head turns on the neck (session 9 measured the neck / collar region at
27 % of the held-out squared error on talking_man_glasses.mp4).

`head_on_neck` re-expresses the same head motion through FLAME's kinematic chain (root 0 ->
neck 1 -> jaw 2, eyes 3, 4): the global rotation is held at a reference R_0 and the neck joint
carries the rest, R_n,t = R_0^T R_t. With G_1 = [R_0 | J0 + tau] [R_n | J1 - J0], the neck
joint's world transform, and every joint below it (jaw, eyes) are those of today's clip exactly
when

    tau'_t = tau_t + (R_t - R_0) (J1 - J0)

(J0, J1: that frame's rest joints, shaped and with its expression), so every vertex weighted
only to the neck, jaw and eyes lands where the tracked fit put it. Root-weighted vertices (the
neck's base, the shoulders, the build frame's collar) keep the reference rotation and move
only by a translation: R_0 x + (R_t J1 + tau_t + J0 - R_t J0) - R_0 J1, i.e. they follow the
neck joint's tracked position. Only the neck's blend region between them bends. (With pose
correctives, as a FLAME model's `posedirs` has, the neck's R_n - I feature also moves vertices;
the template head has none.)

The reference: the build frame's pose when the avatar was built from this video (`avatarkit
evaluate`, `track --avatar` with the avatar's own video), so the collar is where the build saw
it; otherwise the clip's median rotation (the body's typical pose: half the frames turn either
way of it, and no single frame's lean is taken as the body's).
"""
from __future__ import annotations

import numpy as np

from avatarkit.rotations import axis_angle_to_matrix, matrix_to_axis_angle

#: `--head-on` choices: where the tracked head motion goes
HEAD_ON = ("neck", "global")
#: what `track`, `evaluate` and the video build's frame colours use (docs/tracking.md: measured)
DEFAULT_HEAD_ON = "neck"
#: with the head on the neck, also keep the neck's base where the reference frame has it
#: (`hold_base`) rather than letting it follow the neck joint's tracked position
HOLD_BASE = False


def _matrices(aa: np.ndarray) -> np.ndarray:
    return axis_angle_to_matrix(np.asarray(aa, np.float64).reshape(-1, 3)).astype(np.float64)


def head_rotation(rotation: np.ndarray, neck: np.ndarray | None) -> np.ndarray:
    """(T, 3) axis-angle: the head's rotation (global then neck, R_global R_neck) of clip channels
    rotation (T, 3) and neck (T, 3) or None. The channel to read where "the head's rotation" is
    meant (yaw, pitch, pose errors): it is the same whether the clip carries the head on the
    neck or globally."""
    rot = np.asarray(rotation, np.float64).reshape(-1, 3)
    if neck is None or not np.any(np.asarray(neck)):
        return rot.copy()
    return matrix_to_axis_angle(_matrices(rot) @ _matrices(neck)).astype(np.float64).reshape(-1, 3)


def clip_head_rotation(clip) -> np.ndarray:
    """(T, 3) `head_rotation` of a `MotionClip` (or any object with `rotation` and, optionally,
    `neck`)."""
    return head_rotation(clip.rotation, getattr(clip, "neck", None))


def describe(info: dict | None) -> str:
    """Where `carry_on_neck`'s answer holds the body, in words."""
    if info is None:
        return "global (the body turns with the head)"
    where = "the clip's median pose" if info["reference"] == "median" else f"{info['reference']}'s pose"
    return f"neck (the body held at {where})"


def median_rotation(rotation: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """(3,) axis-angle: a robust middle of rotations (T, 3): the per-axis median of the rotation
    vectors taken relative to their chordal mean (small spreads: a talking head turns tens of
    degrees at most), mapped back. weights (T,) > 0 select the frames used (None: all)."""
    rot = np.asarray(rotation, np.float64).reshape(-1, 3)
    if weights is not None:
        rot = rot[np.asarray(weights) > 0]
    Rs = _matrices(rot)
    u, _, vt = np.linalg.svd(Rs.sum(0))
    mean = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt       # chordal mean
    rel = matrix_to_axis_angle(np.einsum("ji,tjk->tik", mean, Rs)).astype(np.float64).reshape(-1, 3)
    return matrix_to_axis_angle(mean @ _matrices(np.median(rel, axis=0))[0]).astype(np.float64).reshape(3)


def head_on_neck(rotation: np.ndarray, translation: np.ndarray, neck: np.ndarray | None,
                 joints: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Carry a clip's head motion on the neck joint (module docstring).

    rotation, translation (T, 3) and neck (T, 3) or None: the clip's channels (an existing neck
    rotation is kept inside the head's rotation); joints: (T, J, 3) or (J, 3) rest joints (0 root,
    1 neck); reference: the global rotation to hold, axis-angle (3,), or (T, 3) one per frame
    (`head_rotation` of the clip itself: the head back on the global rotation, neck 0).
    Returns (rotation (T, 3) = reference, neck (T, 3), translation (T, 3)) float64."""
    R = _matrices(head_rotation(rotation, neck))                                   # (T, 3, 3)
    T = len(R)
    ref = np.broadcast_to(np.asarray(reference, np.float64).reshape(-1, 3), (T, 3))
    R0 = _matrices(ref)                                                            # (T, 3, 3)
    J = np.asarray(joints, np.float64)
    J = np.broadcast_to(J, (T,) + J.shape[-2:]) if J.ndim == 2 else J.reshape(T, -1, 3)
    rel = J[:, 1] - J[:, 0]                                                        # (T, 3)
    # G_1's translation, R_g (J1 - J0) + J0 + tau, held: R_g the clip's own global rotation (any
    # split of the head's rotation between root and neck gives the same G_1)
    R_old = _matrices(rotation)
    tau = np.asarray(translation, np.float64).reshape(T, 3) + np.einsum("tij,tj->ti", R_old - R0, rel)
    new_neck = matrix_to_axis_angle(np.einsum("tji,tjk->tik", R0, R)).astype(np.float64).reshape(T, 3)
    return ref.copy(), new_neck, tau


def clip_joints(model, clip) -> np.ndarray:
    """(T, J, 3) rest joints of `model` with the clip's shape and each frame's expression (the
    joints are regressed from the shaped, expressed mesh)."""
    from avatarkit.head.model import HeadParams

    T = clip.n_frames
    expr = np.asarray(clip.expr, np.float32).reshape(T, -1)
    shape = np.asarray(clip.shape, np.float32).reshape(-1)
    params = HeadParams(shape=shape, expr=expr, num_frames=T)
    return model.rest_joints(params).astype(np.float64)


def carry_on_neck(result, reference_row: int | None = None, hold: bool | None = None) -> dict:
    """Put a `TrackResult`'s head motion on the neck joint, in place (`head_on_neck`), with the
    joints of the head model it was tracked with (`result.model`). reference_row: the clip row
    whose pose the body keeps (the avatar's build frame); None: the clip's median rotation over
    the frames with a face. hold: then keep the neck's base where the reference frame has it
    (`hold_base`; for the median, the median of its positions); None: `HOLD_BASE`. Returns {"reference": "frame
    N" | "median", "rotation": [3 floats], "hold_base": hold}."""
    clip = result.clip
    found = np.asarray(result.found, bool)
    hold = HOLD_BASE if hold is None else hold
    if reference_row is None:
        reference = median_rotation(clip.rotation, found)
        kind = "median"
    else:
        reference = head_rotation(clip.rotation, clip.neck)[int(reference_row)]
        kind = f"frame {int(result.frame_index[int(reference_row)])}"
    joints = clip_joints(result.model, clip)
    rot, neck, tau = head_on_neck(clip.rotation, clip.translation, clip.neck, joints, reference)
    if hold:
        bases = joints[:, 0] + tau                                  # the root joint, posed
        base = bases[int(reference_row)] if reference_row is not None else np.median(bases[found], axis=0)
        rot, neck, tau = hold_base(rot, tau, neck, joints, base)
    dt = np.asarray(clip.rotation).dtype
    clip.rotation, clip.neck, clip.translation = rot.astype(dt), neck.astype(dt), tau.astype(dt)
    return {"reference": kind, "rotation": [float(v) for v in reference], "hold_base": bool(hold)}


def place_head(result, build_frame: int | None, head_on: str) -> dict | None:
    """`head_on` "neck": carry a `TrackResult`'s head motion on the neck joint in place
    (`carry_on_neck`), the body held at video frame `build_frame`'s pose (the clip's median when
    it is None or not in the clip); "global": leave the clip as tracked. -> what was applied
    (`carry_on_neck`'s answer) or None."""
    if head_on == "global":
        return None
    if head_on != "neck":
        raise ValueError(f"head_on must be one of {HEAD_ON}, not {head_on!r}")
    rows = np.flatnonzero(np.asarray(result.frame_index) == build_frame) if build_frame is not None else []
    return carry_on_neck(result, int(rows[0]) if len(rows) else None)


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T, 3, 3): the smallest rotations taking the directions of a (T, 3) onto those of b."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(s, np.einsum("ti,ti->t", a, b))
    aa = np.where(s[:, None] > 1e-12, axis / np.maximum(s, 1e-300)[:, None] * angle[:, None], 0.0)
    return _matrices(aa)


def hold_base(rotation: np.ndarray, translation: np.ndarray, neck: np.ndarray | None,
              joints: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep the root joint (the neck's base) at world point `base` (3,) as far as the neck's
    length allows: each frame's global rotation turned by the smallest rotation that points the
    root-to-neck segment at where the neck joint is, the neck rotation taking the rest of the
    head's rotation, and the translation keeping the neck joint (and so the head) exactly where
    it was. What the segment's length cannot reach (the neck joint nearer or farther from the
    base than the rest neck is long) moves the base along the segment. Returns (rotation,
    neck, translation) (T, 3) float64."""
    rot = np.asarray(rotation, np.float64).reshape(-1, 3)
    T = len(rot)
    Rg = _matrices(rot)
    R = _matrices(head_rotation(rot, neck))
    J = np.asarray(joints, np.float64)
    J = np.broadcast_to(J, (T,) + J.shape[-2:]) if J.ndim == 2 else J.reshape(T, -1, 3)
    J0, d = J[:, 0], J[:, 1] - J[:, 0]
    tau = np.asarray(translation, np.float64).reshape(T, 3)
    a = np.einsum("tij,tj->ti", Rg, d)
    p = a + J0 + tau                                             # the neck joint, posed
    Rg_new = _min_rotation(a, p - np.asarray(base, np.float64).reshape(1, 3)) @ Rg
    neck_new = matrix_to_axis_angle(np.einsum("tji,tjk->tik", Rg_new, R)).astype(np.float64).reshape(T, 3)
    tau_new = p - J0 - np.einsum("tij,tj->ti", Rg_new, d)
    return matrix_to_axis_angle(Rg_new).astype(np.float64).reshape(T, 3), neck_new, tau_new
