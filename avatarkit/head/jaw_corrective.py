"""`JawCorrective`: a per-subject pose corrective on the jaw, carried in a head model's posedirs.

A FLAME-style head moves its vertices before skinning by `posedirs^T . vec(R_j - I)` over the
four non-root joints (`head.lbs`); the jaw's nine features are rows 9..17 of posedirs (joint 2,
`R_jaw - I` row-major). A jaw corrective is an addition to those rows over a few vertices:
`dirs` (9, n, 3) metres per unit of each feature at `vertex_index` (n,). It is zero at jaw 0
(every feature is), so the rest head, the bald Gaussians' binding and the hair rig do not see it.

The video build learns one from the tracked frames (`track.jaw_corrective`): how this person's
mouth opens beyond the template's for the same jaw rotation. `apply_jaw_corrective` returns a
copy of the model with the corrective added to its posedirs (to a FLAME model's own, or to
zeros for the template, which has none) and remembers it in `HeadModel.jaw_corrective`, so an
avatar can save it beside its manifest (`jaw_corrective.npz`, `save_npz` / `load_npz`) and add
it again on load: FLAME files are referenced, not copied, and the template is built in.
"""
from __future__ import annotations

import copy
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError

#: the jaw's features are posedirs rows JAW_ROWS (joint 2: the second non-root joint)
JAW_ROWS = slice(9, 18)
#: npz layout written by `save_npz`
NPZ_FORMAT = "avatarkit.jaw_corrective/1"
#: feature indices of `vec(R - I)` (row-major 3x3) whose half-difference is sin(angle) times the
#: rotation axis' x component: the jaw opening (`opening_feature`)
_R21, _R12 = 7, 5


@dataclass(eq=False)
class JawCorrective:
    """vertex_index (n,) int64 vertices moved; dirs (9, n, 3) float32 metres per unit of each of
    the jaw's nine pose features (`vec(R_jaw - I)`, row-major)."""

    vertex_index: np.ndarray
    dirs: np.ndarray

    def __post_init__(self):
        self.vertex_index = np.asarray(self.vertex_index, np.int64).reshape(-1)
        self.dirs = np.ascontiguousarray(self.dirs, np.float32)
        n = len(self.vertex_index)
        if self.dirs.shape != (9, n, 3):
            raise InputError(f"jaw corrective dirs must have shape (9, {n}, 3), got {self.dirs.shape}")
        if not np.isfinite(self.dirs).all():
            raise InputError("jaw corrective has non-finite values")
        if n and (self.vertex_index.min() < 0 or len(np.unique(self.vertex_index)) != n):
            raise InputError("jaw corrective vertex indices must be distinct and non-negative")

    @classmethod
    def from_opening(cls, vertex_index: np.ndarray, field: np.ndarray) -> "JawCorrective":
        """The corrective that moves `vertex_index` by `field` (n, 3) metres times the jaw's
        opening feature (`opening_feature`: sin(angle) times the axis' x component), put on the
        two features whose half-difference that is (R[2,1] and R[1,2])."""
        field = np.asarray(field, np.float32)
        dirs = np.zeros((9, len(field), 3), np.float32)
        dirs[_R21] = 0.5 * field
        dirs[_R12] = -0.5 * field
        return cls(vertex_index, dirs)

    @property
    def opening_field(self) -> np.ndarray:
        """(n, 3) metres per unit of `opening_feature` (exact for a corrective `from_opening`)."""
        return self.dirs[_R21] - self.dirs[_R12]

    def dense(self, num_vertices: int) -> np.ndarray:
        """(9, V*3) float32: the posedirs rows this corrective adds."""
        if len(self.vertex_index) and self.vertex_index.max() >= num_vertices:
            raise InputError(f"jaw corrective moves vertex {int(self.vertex_index.max())}, the head has "
                             f"{num_vertices}")
        out = np.zeros((9, num_vertices, 3), np.float32)
        out[:, self.vertex_index] = self.dirs
        return out.reshape(9, num_vertices * 3)

    def max_displacement(self, angle: float = 0.3) -> float:
        """The largest vertex motion (metres) at a pure opening of `angle` radians about x."""
        f = jaw_features(np.array([[angle, 0.0, 0.0]]))[0]
        return float(np.linalg.norm(np.einsum("f,fnd->nd", f, self.dirs), axis=1).max(initial=0.0))

    def summary(self) -> dict:
        return {"vertices": int(len(self.vertex_index)),
                "max_mm_at_0.3_rad": round(1000 * self.max_displacement(0.3), 2)}


def jaw_features(jaw: np.ndarray) -> np.ndarray:
    """jaw (T, 3) axis-angle -> (T, 9) `vec(R - I)`, the jaw's pose-corrective features."""
    from avatarkit.rotations import axis_angle_to_matrix

    R = axis_angle_to_matrix(np.asarray(jaw, np.float64).reshape(-1, 3)).reshape(-1, 3, 3)
    return (R - np.eye(3)).reshape(len(R), 9)


def opening_feature(jaw: np.ndarray) -> np.ndarray:
    """jaw (T, 3) axis-angle -> (T,) (R[2,1] - R[1,2]) / 2 = sin(angle) times the axis' x
    component: the opening, blind to the jaw's small turns about the other axes."""
    f = jaw_features(jaw)
    return 0.5 * (f[:, _R21] - f[:, _R12])


def apply_jaw_corrective(model, corrective: JawCorrective | None):
    """A copy of `model` (a 5-joint `HeadModel`) with `corrective` added to its posedirs' jaw
    rows (replacing any corrective it carried; None: only removing it)."""
    if model.num_joints != 5:
        raise InputError(f"a jaw corrective needs the 5 FLAME joints; this head has {model.num_joints}")
    out = copy.copy(model)
    V = model.num_vertices
    old = getattr(model, "jaw_corrective", None)
    P = None if model.posedirs is None else model.posedirs.copy()
    if old is not None and P is not None:
        P[JAW_ROWS] -= old.dense(V)
        if getattr(model, "own_posedirs", True) is False:
            P = None                                     # the model had none of its own
    if corrective is not None:
        if P is None:
            P = np.zeros((36, V * 3), np.float32)
            out.own_posedirs = False
        elif old is None:
            out.own_posedirs = True
        P[JAW_ROWS] += corrective.dense(V)
    out.posedirs = P
    out.jaw_corrective = corrective
    out._torch_cache = {}
    return out


def save_npz(corrective: JawCorrective, path: str | os.PathLike) -> None:
    """Write the corrective (vertex_index, dirs, meta) to `path`."""
    from avatarkit.fileio import atomic_path

    meta = {"format": NPZ_FORMAT, "features": "jaw R - I, row-major (posedirs rows 9..17)"}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, vertex_index=corrective.vertex_index, dirs=corrective.dirs, meta=np.array(json.dumps(meta)))


def load_npz(path: str | os.PathLike) -> JawCorrective:
    """Read a corrective written by `save_npz`; FormatError naming the file otherwise."""
    from avatarkit.fileio import read_npz

    path = Path(path)
    data = read_npz(path, "not a readable jaw corrective")
    for key in ("vertex_index", "dirs", "meta"):
        if key not in data:
            raise FormatError(f"missing key {key!r} (not a jaw corrective written by avatarkit)", path)
    try:
        meta = json.loads(str(data["meta"]))
    except ValueError:
        meta = None
    if not isinstance(meta, dict) or meta.get("format") != NPZ_FORMAT:
        raise FormatError(f"key 'meta' does not name format {NPZ_FORMAT!r}", path)
    try:
        return JawCorrective(data["vertex_index"], data["dirs"])
    except InputError as e:
        raise FormatError(e.message, path) from None


__all__ = ["JAW_ROWS", "JawCorrective", "NPZ_FORMAT", "apply_jaw_corrective", "jaw_features", "load_npz",
           "opening_feature", "save_npz"]
