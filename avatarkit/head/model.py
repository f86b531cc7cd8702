"""`HeadModel` (a FLAME-compatible parametric head) and `HeadParams` (its per-frame inputs), and
the built-in template head as a `HeadModel` (`load_template`; its geometry comes from
`avatarkit.head.template`). Files: `avatarkit.head.npz` (our npz), `avatarkit.head.flame`
(FLAME pickles), `avatarkit.head.io.load_head_model` (any of them by suffix).

Joint layout (DESIGN.md, FLAME): 0 root/global, 1 neck, 2 jaw, 3 left eye, 4 right eye; parents
[-1, 0, 1, 1, 1]. Parameter names follow FLAME / GaussianAvatars / VHAP: `rotation` (global
axis-angle), `translation`, `neck`/`jaw` (`neck_pose`, `jaw_pose` in their files), `eyes`
(`eyes_pose`: left eye then right eye), `expr`, `shape`.
"""
from __future__ import annotations

import copy
import functools
import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from avatarkit.errors import InputError
from avatarkit.head import lbs as _lbs
from avatarkit.head import template as _template
from avatarkit.head.joints import FLAME_PARENTS, JOINT_NAMES
from avatarkit.head.regions import derive_regions

# Per-frame fields of HeadParams and their widths; FLAME-file aliases map onto them.
_FRAME_FIELDS = {"rotation": 3, "translation": 3, "neck": 3, "jaw": 3, "eyes": 6}
_ALIASES = {"neck_pose": "neck", "jaw_pose": "jaw", "eyes_pose": "eyes", "global_orient": "rotation",
            "transl": "translation", "expression": "expr", "betas": "shape"}


def _finite(name: str, a: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} contains NaN or infinite values")
    return a


@dataclass(eq=False)
class HeadParams:
    """FLAME parameters for T frames. Missing fields are zeros; 1-D per-frame fields mean T = 1.

    expr: (T, E); rotation, translation, neck, jaw: (T, 3) (axis-angle radians, metres);
    eyes: (T, 6) (left eye axis-angle, then right eye); shape: (S,) static or (T, S) per frame.
    """

    expr: np.ndarray | None = None
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    neck: np.ndarray | None = None
    jaw: np.ndarray | None = None
    eyes: np.ndarray | None = None
    shape: np.ndarray | None = None
    num_frames: int | None = None

    def __post_init__(self):
        T = self.num_frames
        for name in (*_FRAME_FIELDS, "expr"):
            value = getattr(self, name)
            if value is None:
                continue
            a = np.asarray(value, dtype=np.float32)
            if a.ndim == 1:
                a = a[None]
            if a.ndim != 2:
                raise InputError(f"{name} must have shape (T, k), got {a.shape}")
            if name in _FRAME_FIELDS and a.shape[1] != _FRAME_FIELDS[name]:
                raise InputError(f"{name} must have shape (T, {_FRAME_FIELDS[name]}), got {a.shape}")
            if T is None:
                T = a.shape[0]
            elif a.shape[0] != T:
                raise InputError(f"{name} has {a.shape[0]} frames, expected {T}")
            setattr(self, name, _finite(name, a))
        T = 1 if T is None else int(T)
        if T < 1:
            raise InputError("HeadParams needs at least one frame")
        self.num_frames = T
        for name, width in _FRAME_FIELDS.items():
            if getattr(self, name) is None:
                setattr(self, name, np.zeros((T, width), dtype=np.float32))
        if self.expr is None:
            self.expr = np.zeros((T, 0), dtype=np.float32)
        shape = np.zeros(0, np.float32) if self.shape is None else np.asarray(self.shape, dtype=np.float32)
        if shape.ndim not in (1, 2) or (shape.ndim == 2 and shape.shape[0] != T):
            raise InputError(f"shape must have shape (S,) or ({T}, S), got {shape.shape}")
        self.shape = _finite("shape", shape)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "HeadParams":
        """From a mapping with our names or FLAME/GaussianAvatars/VHAP ones (`neck_pose`, ...).
        Unknown keys (e.g. `static_offset`, `fps`) are ignored."""
        kwargs = {}
        for key, value in data.items():
            name = _ALIASES.get(key, key)
            if name in _FRAME_FIELDS or name in ("expr", "shape"):
                kwargs[name] = np.asarray(value)
        shape = kwargs.get("shape")
        if shape is not None and shape.ndim == 2 and shape.shape[0] == 1:
            kwargs["shape"] = shape[0]  # VHAP stores the static shape as (1, S)
        return cls(**kwargs)

    @classmethod
    def from_clip(cls, clip, frames=None) -> "HeadParams":
        """From a `MotionClip`-like object (fields rotation, translation, neck, jaw, eyes, expr,
        shape); `frames` selects frames (an index array or slice)."""
        sel = slice(None) if frames is None else frames
        get = lambda name: None if getattr(clip, name, None) is None else np.asarray(getattr(clip, name))[sel]
        params = cls(expr=get("expr"), rotation=get("rotation"), translation=get("translation"),
                     neck=get("neck"), jaw=get("jaw"), eyes=get("eyes"),
                     shape=None if getattr(clip, "shape", None) is None else np.asarray(clip.shape))
        return params

    @classmethod
    def zeros(cls, num_frames: int = 1) -> "HeadParams":
        return cls(num_frames=num_frames)

    def to_dict(self, flame_names: bool = True) -> dict[str, np.ndarray]:
        """Arrays keyed as GaussianAvatars/VHAP write them (or by our field names)."""
        names = {"neck": "neck_pose", "jaw": "jaw_pose", "eyes": "eyes_pose"} if flame_names else {}
        out = {names.get(k, k): getattr(self, k) for k in (*_FRAME_FIELDS, "expr", "shape")}
        return out

    def select(self, frames) -> "HeadParams":
        """A subset of frames (index, array of indices or slice)."""
        idx = np.arange(self.num_frames)[frames]
        idx = np.atleast_1d(idx)
        shape = self.shape[idx] if self.shape.ndim == 2 else self.shape
        return HeadParams(expr=self.expr[idx], rotation=self.rotation[idx], translation=self.translation[idx],
                          neck=self.neck[idx], jaw=self.jaw[idx], eyes=self.eyes[idx], shape=shape)

    @property
    def full_pose(self) -> np.ndarray:
        """(T, 5, 3): rotation, neck, jaw, left eye, right eye (FLAME's pose vector order)."""
        return np.concatenate([self.rotation, self.neck, self.jaw, self.eyes], axis=1).reshape(-1, 5, 3)


class CoefficientCountWarning(UserWarning):
    """A shape/expression vector did not match the model's basis and was truncated or padded."""


def _count_mismatch(name: str, k: int, n: int, dropped_nonzero: bool) -> None:
    # Truncating zeros loses nothing (clips often carry FLAME's 100 expression slots, mostly 0).
    if k > n and dropped_nonzero:
        warnings.warn(f"{name} has {k} coefficients but the head model has {n}: ignoring the extra ones",
                      CoefficientCountWarning, stacklevel=4)
    elif 0 < k < n:
        warnings.warn(f"{name} has {k} coefficients but the head model has {n}: padding with zeros",
                      CoefficientCountWarning, stacklevel=4)


def _fit_columns(name: str, a: np.ndarray, n: int) -> np.ndarray:
    """Truncate or zero-pad the last axis of `a` to `n` (warning: `_count_mismatch`)."""
    k = a.shape[-1]
    if k == n:
        return a
    _count_mismatch(name, k, n, k > n and bool(np.any(a[..., n:])))
    if k > n:
        return a[..., :n]
    pad = np.zeros(a.shape[:-1] + (n - k,), dtype=a.dtype)
    return np.concatenate([a, pad], axis=-1)


@dataclass(eq=False)
class HeadModel:
    """A FLAME-compatible head: template mesh, linear shape and expression bases, 5 joints, LBS.

    faces: (F, 3) int32; v_template: (V, 3) float32 metres, +Y up, face toward +Z;
    shapedirs: (V, 3, S) float32 (identity); exprdirs: (V, 3, E) float32 (expression);
    posedirs: (P, V*3) float32 or None (FLAME: P = 36, from the 4 non-root joints' R - I);
    J_regressor: (J, V) float32 dense or scipy.sparse; kintree_parents: (J,) int64, FLAME layout;
    weights: (V, J) float32, rows sum to 1; regions: name -> vertex indices (int64);
    expression_names: (E,) names of the expression components; shape_names: (S,).
    `name` says what it is ("template", "flame"); `source` where it came from (file + sha256).
    `jaw_corrective` (not a constructor argument): the per-subject `head.jaw_corrective.
    JawCorrective` already added to posedirs' jaw rows (`apply_jaw_corrective`), or None.
    """

    faces: np.ndarray
    v_template: np.ndarray
    shapedirs: np.ndarray
    exprdirs: np.ndarray
    J_regressor: Any
    kintree_parents: np.ndarray
    weights: np.ndarray
    posedirs: np.ndarray | None = None
    regions: dict[str, np.ndarray] = field(default_factory=dict)
    expression_names: list[str] = field(default_factory=list)
    shape_names: list[str] = field(default_factory=list)
    name: str = "head"
    source: str = ""

    def __post_init__(self):
        self.v_template = np.ascontiguousarray(self.v_template, dtype=np.float32)
        V = len(self.v_template)
        if self.v_template.ndim != 2 or self.v_template.shape[1] != 3:
            raise InputError(f"v_template must have shape (V, 3), got {self.v_template.shape}")
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int32)
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise InputError(f"faces must have shape (F, 3), got {self.faces.shape}")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= V):
            raise InputError(f"faces index vertices outside 0..{V - 1}")
        for name in ("shapedirs", "exprdirs"):
            a = np.ascontiguousarray(getattr(self, name), dtype=np.float32)
            if a.ndim == 2 and a.shape[1] == 0:
                a = a.reshape(V, 3, 0)
            if a.ndim != 3 or a.shape[:2] != (V, 3):
                raise InputError(f"{name} must have shape ({V}, 3, k), got {a.shape}")
            setattr(self, name, a)
        self.kintree_parents = np.asarray(self.kintree_parents, dtype=np.int64)
        J = len(self.kintree_parents)
        if J < 1 or self.kintree_parents[0] != -1 or np.any(self.kintree_parents[1:] >= np.arange(1, J)) \
                or np.any(self.kintree_parents[1:] < 0):
            raise InputError(f"kintree_parents must start with -1 and list each parent before its child, "
                             f"got {self.kintree_parents.tolist()}")
        if not hasattr(self.J_regressor, "toarray"):
            self.J_regressor = np.asarray(self.J_regressor, dtype=np.float32)
        if tuple(self.J_regressor.shape) != (J, V):
            raise InputError(f"J_regressor must have shape ({J}, {V}), got {tuple(self.J_regressor.shape)}")
        self.weights = np.ascontiguousarray(self.weights, dtype=np.float32)
        if self.weights.shape != (V, J):
            raise InputError(f"weights must have shape ({V}, {J}), got {self.weights.shape}")
        if self.posedirs is not None:
            p = np.ascontiguousarray(self.posedirs, dtype=np.float32)
            if p.ndim != 2 or p.shape != (9 * (J - 1), V * 3):
                raise InputError(f"posedirs must have shape ({9 * (J - 1)}, {V * 3}), got {p.shape}")
            self.posedirs = p
        self.regions = {k: np.asarray(v, dtype=np.int64) for k, v in self.regions.items()}
        for k, idx in self.regions.items():
            if idx.ndim != 1 or (idx.size and (idx.min() < 0 or idx.max() >= V)):
                raise InputError(f"region {k!r} must be a 1-D array of vertex indices in 0..{V - 1}")
        self.expression_names = list(self.expression_names) or [f"expr_{i:03d}" for i in range(self.num_expr)]
        self.shape_names = list(self.shape_names) or [f"shape_{i:03d}" for i in range(self.num_shape)]
        if len(self.expression_names) != self.num_expr or len(self.shape_names) != self.num_shape:
            raise InputError("expression_names / shape_names must have one name per component")
        self._torch_cache: dict = {}
        self.jaw_corrective = None

    # -- sizes ---------------------------------------------------------------------------------
    @property
    def num_vertices(self) -> int:
        return len(self.v_template)

    @property
    def num_faces(self) -> int:
        return len(self.faces)

    @property
    def num_joints(self) -> int:
        return len(self.kintree_parents)

    @property
    def num_shape(self) -> int:
        return self.shapedirs.shape[2]

    @property
    def num_expr(self) -> int:
        return self.exprdirs.shape[2]

    @property
    def joint_names(self) -> tuple[str, ...]:
        return JOINT_NAMES if self.num_joints == 5 else tuple(f"joint_{i}" for i in range(self.num_joints))

    # -- constructors --------------------------------------------------------------------------
    @classmethod
    def template(cls) -> "HeadModel":
        """The built-in procedural head (no files needed). See `avatarkit.head.template`."""
        return load_template()

    # -- evaluation ----------------------------------------------------------------------------
    def neutral_params(self, num_frames: int = 1) -> HeadParams:
        return HeadParams(expr=np.zeros((num_frames, self.num_expr), np.float32),
                          shape=np.zeros(self.num_shape, np.float32), num_frames=num_frames)

    def _blend_inputs(self, params: HeadParams) -> tuple[np.ndarray, np.ndarray]:
        shape = _fit_columns("shape", params.shape, self.num_shape)
        expr = _fit_columns("expr", params.expr, self.num_expr)
        return shape, expr

    def shaped_vertices(self, params: HeadParams) -> np.ndarray:
        """Template + shape + expression offsets, before posing: (T, V, 3) float32."""
        shape, expr = self._blend_inputs(params)
        T, V = params.num_frames, self.num_vertices
        base = self.v_template.reshape(1, V * 3)
        if self.num_shape:
            sd = self.shapedirs.reshape(V * 3, -1)
            base = base + (shape.reshape(-1, self.num_shape) @ sd.T)  # (1 or T, V*3)
        out = np.broadcast_to(base, (T, V * 3)).astype(np.float32, copy=True)
        if self.num_expr:
            out += expr @ self.exprdirs.reshape(V * 3, -1).T
        return out.reshape(T, V, 3)

    def rest_joints(self, params: HeadParams | None = None) -> np.ndarray:
        """Joint positions (T, J, 3) of the shaped, unposed mesh (T = 1 without params)."""
        params = params or self.neutral_params()
        return _lbs._regress(self.J_regressor, self.shaped_vertices(params).astype(np.float64)).astype(np.float32)

    def forward(self, params: HeadParams) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices (T, V, 3) float32 and joint transforms (T, J, 4, 4) float32.

        Steps (FLAME): shape + expression blendshapes; joints regressed from that mesh; Rodrigues;
        pose correctives; LBS; global translation. `joint_transforms[t, j]` maps a rest-pose
        point (after blendshapes) to its posed position when fully weighted to joint j.
        """
        if self.num_joints != 5:
            raise InputError(f"HeadParams drive 5 FLAME joints; this model has {self.num_joints}")
        v_shaped = self.shaped_vertices(params)
        return _lbs.lbs(v_shaped, self.J_regressor, self.kintree_parents, self.weights,
                        params.full_pose, params.translation, self.posedirs)

    def forward_torch(self, params: Mapping[str, Any] | HeadParams, dtype=None, device=None):
        """`forward` in torch, differentiable w.r.t. the parameters.

        params: a HeadParams or a mapping of tensors with the HeadParams field names (missing
        ones are zeros). Returns (vertices (T, V, 3), joint transforms (T, J, 4, 4)) tensors.
        """
        import torch

        if isinstance(params, HeadParams):
            params = {k: torch.as_tensor(getattr(params, k)) for k in
                      ("expr", "rotation", "translation", "neck", "jaw", "eyes", "shape")}
        dtype = dtype or next((v.dtype for v in params.values() if torch.is_tensor(v) and v.is_floating_point()),
                              torch.float32)
        consts = self._torch_constants(dtype, device)
        per_frame = [params[k] for k in ("rotation", "translation", "neck", "jaw", "eyes", "expr")
                     if params.get(k) is not None]
        T = per_frame[0].reshape(-1, per_frame[0].shape[-1]).shape[0] if per_frame else 1
        get = lambda k, w: (params[k].to(dtype).reshape(T, w) if params.get(k) is not None
                            else torch.zeros(T, w, dtype=dtype, device=device))
        V = self.num_vertices
        expr = params.get("expr")
        expr = torch.zeros(T, 0, dtype=dtype, device=device) if expr is None else expr.to(dtype).reshape(T, -1)
        shape = params.get("shape")
        shape = torch.zeros(0, dtype=dtype, device=device) if shape is None else shape.to(dtype)
        expr = _fit_columns_torch("expr", expr, self.num_expr)
        shape = _fit_columns_torch("shape", shape, self.num_shape)
        v = consts["v_template"].reshape(1, V * 3).expand(T, V * 3)
        if self.num_shape:
            v = v + shape.reshape(-1, self.num_shape) @ consts["shapedirs"].T
        if self.num_expr:
            v = v + expr @ consts["exprdirs"].T
        pose = torch.cat([get("rotation", 3), get("neck", 3), get("jaw", 3), get("eyes", 6)], dim=1)
        return _lbs.lbs_torch(v.reshape(T, V, 3), consts["J_regressor"], self.kintree_parents.tolist(),
                              consts["weights"], pose, get("translation", 3), consts.get("posedirs"))

    def _torch_constants(self, dtype, device) -> dict:
        import torch

        key = (str(dtype), str(device))
        if key not in self._torch_cache:
            V = self.num_vertices
            jr = self.J_regressor.toarray() if hasattr(self.J_regressor, "toarray") else self.J_regressor
            c = {"v_template": self.v_template, "shapedirs": self.shapedirs.reshape(V * 3, -1),
                 "exprdirs": self.exprdirs.reshape(V * 3, -1), "J_regressor": np.asarray(jr),
                 "weights": self.weights}
            if self.posedirs is not None:
                c["posedirs"] = self.posedirs
            self._torch_cache[key] = {k: torch.as_tensor(np.ascontiguousarray(v), dtype=dtype, device=device)
                                      for k, v in c.items()}
        return self._torch_cache[key]

    # -- regions and export helpers ------------------------------------------------------------
    def region_faces(self, name: str, mode: str = "all") -> np.ndarray:
        """Indices of the faces in region `name`: `mode="all"` needs all three vertices in it,
        `"majority"` two of three, `"any"` one."""
        if name not in self.regions:
            raise InputError(f"unknown region {name!r}; this head has {sorted(self.regions)}")
        need = {"all": 3, "majority": 2, "any": 1}.get(mode)
        if need is None:
            raise InputError(f"mode must be 'all', 'majority' or 'any', got {mode!r}")
        mask = np.zeros(self.num_vertices, dtype=bool)
        mask[self.regions[name]] = True
        return np.flatnonzero(mask[self.faces].sum(axis=1) >= need)

    def region_mask(self, name: str) -> np.ndarray:
        """(V,) bool mask of region `name`."""
        if name not in self.regions:
            raise InputError(f"unknown region {name!r}; this head has {sorted(self.regions)}")
        mask = np.zeros(self.num_vertices, dtype=bool)
        mask[self.regions[name]] = True
        return mask

    def to_trimesh(self, vertices: np.ndarray | None = None):
        """A trimesh.Trimesh of the template (or of posed `vertices` (V, 3))."""
        import trimesh

        v = self.v_template if vertices is None else np.asarray(vertices)
        return trimesh.Trimesh(v, self.faces, process=False)

    def describe(self) -> dict:
        """A small JSON-able summary (sizes, joints, regions, source)."""
        lo, hi = self.v_template.min(0).astype(np.float64), self.v_template.max(0).astype(np.float64)
        return {"name": self.name, "source": self.source, "vertices": self.num_vertices,
                "faces": self.num_faces, "shape_components": self.num_shape,
                "expression_components": self.num_expr, "pose_correctives": self.posedirs is not None,
                "jaw_corrective": None if self.jaw_corrective is None else self.jaw_corrective.summary(),
                "joints": list(self.joint_names), "bbox_min": lo.round(4).tolist(),
                "bbox_max": hi.round(4).tolist(),
                "regions": {k: int(len(v)) for k, v in sorted(self.regions.items())}}


def _fit_columns_torch(name, t, n):
    import torch

    k = t.shape[-1]
    if k == n:
        return t
    _count_mismatch(name, k, n, k > n and bool((t[..., n:] != 0).any()))
    if k > n:
        return t[..., :n]
    return torch.cat([t, t.new_zeros(t.shape[:-1] + (n - k,))], dim=-1)


def build_template() -> HeadModel:
    """Generate the template head (uncached; ~1-2 s). Use `load_template` instead."""
    model = HeadModel(**_template.build_template_arrays())
    model.regions = derive_regions(model)
    return model


@functools.lru_cache(maxsize=1)
def _cached_template() -> HeadModel:
    return build_template()


def load_template() -> HeadModel:
    """The built-in template head (generated once per process; each call returns a fresh copy)."""
    model = copy.deepcopy(_cached_template())
    model._torch_cache = {}
    return model


__all__ = ["HeadModel", "HeadParams", "CoefficientCountWarning", "JOINT_NAMES", "FLAME_PARENTS",
           "build_template", "load_template"]
