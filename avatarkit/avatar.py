"""`Avatar`: the compositional head avatar (bald head on a parametric head + hair in a cage) and
its folder format.

An avatar folder holds:

    avatar.json   manifest (schemas/avatar.schema.json): head model reference, identity shape,
                  parts with their files and counts, provenance
    bald.ply      bald head Gaussians, REST pose, world space, with a `binding` extra (the head
                  face each rides), so splat viewers open it as is
    hair.ply      hair Gaussians, rest pose, world space
    cage.ply      the closed hair cage at rest (its vertex order is the simulation's)
    rig.npz       what the hair driver needs that is slow to compute: the simulation model (roots
                  and their attachment to the head, proxy weights, tethers, head SDF) and the
                  cage deformer's settings, plus a SHA-256 of its inputs (~2 MB)
    jaw_corrective.npz  (optional) the subject's jaw corrective the video build learned
                  (`head.jaw_corrective`): added to the head model's posedirs on load, so
                  every pose of this avatar's head (bake, track --avatar, evaluate) opens the
                  mouth as the person's did; named by avatar.json's head_model.jaw_corrective
    preview.png   a front view (optional)

A hairless avatar (a bald person: its hair part has 0 Gaussians) has no cage and no rig
(`cage=None`, `rig=None`): its manifest lists only the bald part (and the preview), and the
folder holds no hair.ply, cage.ply or rig.npz. It bakes without simulation.

The rest pose is the head model with the avatar's identity shape, zero expression, zero pose.
Triangle-local values of the bald Gaussians are not stored: `TriangleBinding.bind` recomputes
them on load from the rest head and the `binding` ids (deterministic, so a loaded avatar bakes
exactly like a freshly loaded copy of itself). The rig's weights are only valid for the hair,
cage and head they were computed from; their hash is checked on load and the rig rebuilt, with
a `RigRebuiltWarning`, when it does not match (an edited hair.ply, for instance).

The cage deformer's mean value coordinate weights (C x 2N float32: 205 MB for 50k hair
Gaussians) are NOT stored (rig format 2): they are recomputed from hair.ply and cage.ply with
the Taichi MVC kernel (~2 s of 2 cores for 50k hair) when the loaded avatar's hair first moves
(`CageDeformer.deferred`), exactly the weights a save of the loaded avatar would have stored. Top-k sparse weights were measured and rejected: on the whip
clip they move hair up to 4.7 mm (k=64) from the dense result (docs/baking-and-outputs.md, "Avatars and baking").
Rig format 1 files, which hold the dense weights, are still read (and their weights used).

`Avatar.save(folder)` writes a complete folder beside the target and renames it into place:
an interrupted save leaves the old folder (or nothing) under the requested name.
"""
from __future__ import annotations

import datetime
import functools
import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from avatarkit.errors import AvatarKitError, FormatError, InputError, OutputError
from avatarkit.fileio import atomic_folder, check_output_folder, json_loads
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.hair_rig import HairRig, rig_inputs_sha256, sdf_inputs_sha256, stored_sdf
from avatarkit.head.ref import HeadRef, head_geometry_sha256

AVATAR_FORMAT = "avatarkit.avatar"
AVATAR_VERSION = 1

MANIFEST = "avatar.json"
BALD_FILE = "bald.ply"
HAIR_FILE = "hair.ply"
CAGE_FILE = "cage.ply"
RIG_FILE = "rig.npz"
JAW_CORRECTIVE_FILE = "jaw_corrective.npz"
PREVIEW_FILE = "preview.png"
#: optional extra views beside preview.png; the manifest schema has no place for them (its
#: parts allow no extra fields), so they travel as plain files found by name
EXTRA_PREVIEW_FILES = ("preview_three_quarter.png", "preview_profile.png")
PREVIEW_SIZE = 512
#: the `part` extra of `Avatar.rest_gaussians()` / `load_rest_splats()` (uint8)
PART_BALD, PART_HAIR = 0, 1



class RigRebuiltWarning(UserWarning):
    """An avatar's rig.npz did not match its hair, cage or head and was recomputed on load."""


class HeadModelChangedWarning(UserWarning):
    """The built-in template head differs from the one an avatar was made on (same topology,
    other geometry): the bald Gaussians keep their saved rest positions, which may no longer
    lie on the head's surface."""


# --- the avatar ------------------------------------------------------------------------------------

def _rest_vertices(head_model, shape: np.ndarray) -> np.ndarray:
    from avatarkit.head.model import HeadParams

    params = HeadParams(shape=shape, expr=np.zeros((1, head_model.num_expr), np.float32))
    return head_model.forward(params)[0][0]


@dataclass(eq=False)
class Avatar:
    """A compositional head avatar.

    head_model: `HeadModel` the bald Gaussians ride; shape: (S,) float32 identity coefficients
    (padded with zeros to the model's S); bald: `GaussianSet` (N) in the rest pose, world space,
    with extras["binding"] (N,) int32 host face ids; hair: `GaussianSet` (M) at rest; cage: the
    rest `Cage` around the hair; rig: `HairRig` of that hair and cage (both None when the hair
    has 0 Gaussians: a hairless avatar, `has_hair` False); head_ref: where the head
    model comes from; sh_frame: how the bald SH turns ("local": with its triangle, "world": not);
    preview: (H, W, 3) uint8 front view or None; path: the folder it was loaded from;
    extra_previews: file name (one of EXTRA_PREVIEW_FILES) -> (H, W, 3) uint8 view.
    """

    head_model: Any
    bald: GaussianSet
    hair: GaussianSet
    cage: Any | None
    rig: HairRig | None
    shape: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    head_ref: HeadRef = field(default_factory=HeadRef)
    name: str = "avatar"
    sh_frame: str = "local"
    provenance: dict = field(default_factory=dict)
    preview: np.ndarray | None = None
    path: Path | None = None
    extra_previews: dict = field(default_factory=dict)

    def __post_init__(self):
        m = self.head_model
        shape = np.asarray(self.shape, dtype=np.float32).reshape(-1)
        if not np.isfinite(shape).all():
            raise InputError("identity shape has a non-finite value")
        if len(shape) > m.num_shape:
            if np.any(shape[m.num_shape:] != 0):
                raise InputError(f"identity shape has {len(shape)} coefficients, the head model "
                                 f"{m.num_shape}")
            shape = shape[:m.num_shape]
        self.shape = np.concatenate([shape, np.zeros(m.num_shape - len(shape), np.float32)])
        for part in ("bald", "hair"):
            if not isinstance(getattr(self, part), GaussianSet):
                raise InputError(f"{part} must be a GaussianSet")
        ids = self.bald.extras.get("binding")
        if ids is None:
            raise InputError("the bald Gaussians have no 'binding' extra (their host head faces)")
        ids = np.asarray(ids)
        if ids.ndim != 1 or ids.dtype.kind not in "iu":
            raise InputError(f"'binding' must be integer face ids (N,), got {ids.dtype} {ids.shape}")
        if len(ids) and (ids.min() < 0 or ids.max() >= m.num_faces):
            bad = int(np.flatnonzero((ids < 0) | (ids >= m.num_faces))[0])
            raise InputError(f"bald Gaussian {bad} is bound to face {int(ids[bad])}, but the head "
                             f"model has {m.num_faces} faces")
        if ids.dtype != np.int32:
            self.bald = self.bald.replace(extras={**self.bald.extras, "binding": ids.astype(np.int32)})
        if self.sh_frame not in ("local", "world"):
            raise InputError(f"sh_frame must be 'local' or 'world', got {self.sh_frame!r}")
        if len(self.hair) == 0:
            # a rig needs something to carry: a hairless avatar has neither cage nor rig
            if self.cage is not None or self.rig is not None:
                raise InputError("an avatar without hair Gaussians has no cage and no rig "
                                 "(pass cage=None, rig=None)")
        elif self.cage is None or self.rig is None:
            raise InputError("an avatar with hair needs its cage and its rig")
        elif len(self.rig.deformer.rest) != len(self.hair):
            raise InputError(f"the rig is for {len(self.rig.deformer.rest)} hair Gaussians, "
                             f"the avatar has {len(self.hair)}")
        elif self.rig.model.num_vertices != self.cage.n_vertices:
            raise InputError(f"the rig is for a {self.rig.model.num_vertices}-vertex cage, the avatar's "
                             f"has {self.cage.n_vertices}")
        if self.preview is not None:
            p = np.asarray(self.preview)
            if p.ndim != 3 or p.shape[2] != 3 or p.dtype != np.uint8:
                raise InputError(f"preview must be a (H, W, 3) uint8 image, got {p.dtype} {p.shape}")
        self.extra_previews = dict(self.extra_previews or {})
        for key, p in self.extra_previews.items():
            if key not in EXTRA_PREVIEW_FILES:
                raise InputError(f"extra preview {key!r} is not one of {', '.join(EXTRA_PREVIEW_FILES)}")
            p = np.asarray(p)
            if p.ndim != 3 or p.shape[2] != 3 or p.dtype != np.uint8:
                raise InputError(f"{key} must be a (H, W, 3) uint8 image, got {p.dtype} {p.shape}")

    # --- construction ---------------------------------------------------------------------------
    @classmethod
    def assemble(cls, head_model, bald: GaussianSet, hair: GaussianSet, cage=None, *,
                 shape: np.ndarray | None = None, head_ref: HeadRef | None = None,
                 name: str = "avatar", sh_frame: str = "local", provenance: dict | None = None,
                 cage_vertices: int = 500, method: str = "principal_axis",
                 progress: Callable[[int, int], None] | None = None) -> "Avatar":
        """An avatar from its parts: builds the cage (unless given) and the hair rig.

        bald: rest-pose world Gaussians with a `binding` extra (host face ids), or without one
        (then each is bound to its nearest head triangle). hair with 0 Gaussians makes a
        hairless avatar (no cage, no rig; `cage` must then be None)."""
        from avatarkit.cage.build import build_cage

        shape = np.zeros(head_model.num_shape, np.float32) if shape is None else np.asarray(shape, np.float32)
        rest = _rest_vertices(head_model, np.concatenate(
            [shape[:head_model.num_shape], np.zeros(max(0, head_model.num_shape - len(shape)), np.float32)]))
        if "binding" not in bald.extras:
            from avatarkit.rig.binding import TriangleBinding

            ids = TriangleBinding.bind(bald, rest, head_model.faces).face_ids
            bald = bald.replace(extras={**bald.extras, "binding": ids})
        if len(hair) == 0:
            if cage is not None:
                raise InputError("a cage was given but there is no hair to put in it")
            rig = None
        else:
            if cage is None:
                cage = build_cage(hair, target_vertices=cage_vertices)
            rig = HairRig.build(head_model, rest, hair, cage, method, progress=progress)
        prov = {"tool": "avatarkit", "version": _tool_version(), "created": _now()}
        prov.update(provenance or {})
        return cls(head_model, bald, hair, cage, rig, shape, head_ref or HeadRef(), name, sh_frame, prov)

    # --- derived --------------------------------------------------------------------------------
    @functools.cached_property
    def rest_head_vertices(self) -> np.ndarray:
        """(V, 3) float32: the head model with this identity, zero expression and pose."""
        return _rest_vertices(self.head_model, self.shape)

    @functools.cached_property
    def binding(self):
        """`TriangleBinding` of the bald Gaussians on the rest head (triangle-local values)."""
        from avatarkit.rig.binding import TriangleBinding

        return TriangleBinding.bind(self.bald, self.rest_head_vertices, self.head_model.faces,
                                    face_ids=self.bald.extras["binding"],
                                    rotate_sh=self.sh_frame == "local")

    @property
    def has_hair(self) -> bool:
        """False for a hairless avatar (0 hair Gaussians, no cage, no rig)."""
        return len(self.hair) > 0

    @property
    def hair_mode(self) -> str:
        """"cage" (simulated), "rigid" (short hair that moves with the scalp), as built, or
        "none" (a hairless avatar)."""
        if not self.has_hair:
            return "none"
        return "rigid" if self.provenance.get("hair_mode") == "rigid" else "cage"

    def hair_driver(self, config=None):
        """A `HairDriver` for this avatar (shares the rig: no weights are recomputed).
        InputError for a hairless avatar (nothing to simulate)."""
        if self.rig is None:
            raise InputError(f"avatar {self.name!r} has no hair: there is no hair to simulate")
        return self.rig.driver(self.head_model, self.rest_head_vertices, config)

    def rest_gaussians(self) -> GaussianSet:
        """Bald and hair together at rest, with a `part` extra (uint8: 0 bald, 1 hair)."""
        return _join_parts(self.bald, self.hair)

    def render_preview(self, size: int | None = None, background=(1.0, 1.0, 1.0)) -> np.ndarray:
        """A front view (size x size, uint8 RGB) of the avatar at rest."""
        size = PREVIEW_SIZE if size is None else size
        from avatarkit.export.images import to_uint8
        from avatarkit.render import frame_camera, render

        gs = self.rest_gaussians()
        return to_uint8(render(gs, frame_camera(gs, width=size, height=size), background).rgb)

    def counts(self) -> dict[str, int]:
        return {"bald": len(self.bald), "hair": len(self.hair),
                "cage_vertices": self.cage.n_vertices if self.cage is not None else 0,
                "head_vertices": self.head_model.num_vertices}

    def __repr__(self) -> str:
        cage = f"cage={self.cage.n_vertices} vertices" if self.cage is not None else "no cage"
        return (f"Avatar(name={self.name!r}, head={self.head_ref.kind}, bald={len(self.bald)}, "
                f"hair={len(self.hair)}, {cage})")

    # --- files ----------------------------------------------------------------------------------
    def manifest(self, rig_sha256: str | None, preview_size: tuple[int, int] | None,
                 jaw_sha256: str | None = None) -> dict:
        """The avatar.json content for this avatar (rig_sha256: hash of the rig's inputs; None
        for a hairless avatar, whose parts are the bald head (and preview) only; jaw_sha256:
        the SHA-256 of the saved jaw corrective file, None when the head carries none)."""
        parts: dict[str, Any] = {
            "bald": {"file": BALD_FILE, "count": len(self.bald), "sh_degree": self.bald.sh_degree,
                     "sh_frame": self.sh_frame}}
        if self.has_hair:
            parts.update({
                "hair": {"file": HAIR_FILE, "count": len(self.hair), "sh_degree": self.hair.sh_degree},
                "cage": {"file": CAGE_FILE, "vertices": self.cage.n_vertices, "faces": len(self.cage.faces)},
                "rig": {"file": RIG_FILE, "deformation": self.rig.method, "inputs_sha256": rig_sha256},
            })
        if preview_size is not None:
            parts["preview"] = {"file": PREVIEW_FILE, "width": preview_size[1], "height": preview_size[0]}
        # `created` is when the avatar was made (kept across re-saves); `version` what wrote it
        prov = {**self.provenance, "tool": "avatarkit", "version": _tool_version(),
                "created": str(self.provenance.get("created") or _now())}
        head = self.head_ref.to_json(self.head_model)
        if jaw_sha256 is not None:
            head["jaw_corrective"] = {"file": JAW_CORRECTIVE_FILE, "sha256": jaw_sha256,
                                      "vertices": int(len(self.head_model.jaw_corrective.vertex_index))}
        return {"format": AVATAR_FORMAT, "version": AVATAR_VERSION, "name": self.name,
                "head_model": head,
                "identity": {"shape": [float(x) for x in self.shape]},
                "parts": parts, "provenance": prov}

    def save(self, folder: str | os.PathLike, *, preview: bool = True) -> Path:
        """Write the avatar folder atomically (a sibling temp folder renamed into place).

        An existing avatar folder under that name is replaced; any other existing folder or
        file is refused (OutputError). preview: render preview.png if the avatar has none.
        Returns the folder's path."""
        from avatarkit.cage.mesh import load_cage, save_cage
        from avatarkit.export.images import write_png
        from avatarkit.gaussians.ply import read_ply, write_ply
        from avatarkit.schemas import validate

        target = check_avatar_target(folder)
        image = self.preview
        if image is None and preview:
            image = self.render_preview()
        with atomic_folder(target) as tmp:
            write_ply(tmp / BALD_FILE, self.bald)
            sha = None
            if self.has_hair:
                write_ply(tmp / HAIR_FILE, self.hair)
                save_cage(tmp / CAGE_FILE, self.cage)
                # hash what a loader will read back (PLY stores log-scales: the floats may move)
                sha = rig_inputs_sha256(read_ply(tmp / HAIR_FILE), load_cage(tmp / CAGE_FILE),
                                        self.rest_head_vertices, self.head_model.faces, self.rig.method)
                self.rig.save(tmp / RIG_FILE, sha,
                              sdf_inputs_sha256(self.rest_head_vertices, self.head_model.faces))
            if image is not None:
                write_png(tmp / PREVIEW_FILE, image)
            for key, extra in self.extra_previews.items():
                write_png(tmp / key, np.asarray(extra))
            jaw_sha = None
            if getattr(self.head_model, "jaw_corrective", None) is not None:
                from avatarkit.fileio import file_sha256
                from avatarkit.head.jaw_corrective import save_npz

                save_npz(self.head_model.jaw_corrective, tmp / JAW_CORRECTIVE_FILE)
                jaw_sha = file_sha256(tmp / JAW_CORRECTIVE_FILE)
            manifest = self.manifest(sha, None if image is None else image.shape[:2], jaw_sha)
            validate(manifest, "avatar", tmp / MANIFEST)
            (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
        return target

    @classmethod
    def load(cls, folder: str | os.PathLike) -> "Avatar":
        """Read and check an avatar folder. Every problem is a FormatError naming the file."""
        return load_avatar(folder)


def check_avatar_target(folder: str | os.PathLike) -> Path:
    """Raise OutputError unless `folder` can receive an avatar: its parent exists and is
    writable, and it is absent, empty or an avatar folder (which a save replaces)."""
    target = Path(folder)
    check_output_folder(target.parent)
    if target.exists() and not target.is_dir():
        raise OutputError("exists and is not a folder", target)
    if target.is_dir() and any(target.iterdir()) and not (target / MANIFEST).is_file():
        raise OutputError("folder exists and is not an avatar folder (no avatar.json): "
                          "refusing to replace it", target)
    return target


def _tool_version() -> str:
    from avatarkit import __version__
    return __version__


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")


# --- loading -----------------------------------------------------------------------------------------

def is_avatar_folder(path: str | os.PathLike) -> bool:
    p = Path(path)
    return p.is_dir() and (p / MANIFEST).is_file()


def read_manifest(folder: str | os.PathLike) -> dict:
    """avatar.json of `folder`, parsed and validated against the schema."""
    from avatarkit.schemas import validate

    folder = Path(folder)
    if not folder.exists():
        raise InputError("avatar folder not found", folder)
    if not folder.is_dir():
        raise InputError("not an avatar folder (a file, not a folder)", folder)
    path = folder / MANIFEST
    if not path.is_file():
        raise FormatError(f"not an avatar folder: no {MANIFEST}", folder)
    try:
        manifest = json_loads(path.read_text(encoding="utf-8"), path)
    except (UnicodeDecodeError, ValueError) as e:
        raise FormatError(f"not valid JSON ({e})", path) from None
    if isinstance(manifest, dict) and manifest.get("format") == AVATAR_FORMAT \
            and isinstance(manifest.get("version"), int) and manifest["version"] > AVATAR_VERSION:
        raise FormatError(f"avatar format version {manifest['version']} is newer than this avatarkit "
                          f"reads ({AVATAR_VERSION}); upgrade avatarkit", path)
    validate(manifest, "avatar", path)
    return manifest


def _part_file(folder: Path, entry: dict) -> Path:
    p = folder / entry["file"]
    if not p.is_file():
        raise FormatError("file missing (listed in avatar.json)", p)
    return p


def _read_splats(path: Path) -> GaussianSet:
    from avatarkit.gaussians.ply import read_ply

    try:
        return read_ply(path)
    except AvatarKitError as e:
        if isinstance(e, FormatError) and e.path:
            raise
        raise FormatError(e.message, path) from None


def _join_parts(bald: GaussianSet, hair: GaussianSet | None) -> GaussianSet:
    """Bald and hair as one set with a `part` extra (uint8: PART_BALD, PART_HAIR)."""
    parts = [bald.replace(extras={"part": np.full(len(bald), PART_BALD, np.uint8)})]
    if hair is not None:
        parts.append(hair.replace(extras={"part": np.full(len(hair), PART_HAIR, np.uint8)}))
    return GaussianSet.concat(parts)


def load_rest_splats(folder: str | os.PathLike) -> GaussianSet:
    """The Gaussians of an avatar folder at rest, as `Avatar.rest_gaussians()` gives them, read
    from its bald and hair PLYs alone: no head model, cage or hair rig (what a preview needs).
    FormatError naming the file when the manifest or a part is wrong."""
    folder = Path(folder)
    parts = read_manifest(folder)["parts"]
    sets = {}
    for key in ("bald", "hair"):
        if key in parts:  # a hairless avatar has no hair part
            path = _part_file(folder, parts[key])
            sets[key] = _read_splats(path)
            _count_check(path, "Gaussians", len(sets[key]), parts[key]["count"])
    return _join_parts(sets["bald"], sets.get("hair"))


def _count_check(path: Path, what: str, got: int, want: int) -> None:
    if got != want:
        raise FormatError(f"has {got} {what} but avatar.json says {want}", path)


def _load_hair(folder: Path, parts: dict, head, rest: np.ndarray):
    """(hair, cage, rig) of an avatar folder that has hair (FormatError naming the file)."""
    from avatarkit.cage.mesh import load_cage

    hair_path = _part_file(folder, parts["hair"])
    hair = _read_splats(hair_path)
    _count_check(hair_path, "Gaussians", len(hair), parts["hair"]["count"])

    cage_path = _part_file(folder, parts["cage"])
    try:
        cage = load_cage(cage_path)
    except AvatarKitError as e:
        raise FormatError(e.message, cage_path) from None
    _count_check(cage_path, "vertices", cage.n_vertices, parts["cage"]["vertices"])
    _count_check(cage_path, "faces", len(cage.faces), parts["cage"]["faces"])

    rig_path = _part_file(folder, parts["rig"])
    method = parts["rig"]["deformation"]
    data = HairRig.read_file(rig_path)
    stored = str(data["inputs_sha256"])
    if stored != parts["rig"]["inputs_sha256"]:
        raise FormatError("belongs to another avatar (its inputs hash differs from avatar.json's)", rig_path)
    if str(data["deform_method"]) != method:
        raise FormatError(f"rig uses {data['deform_method']} deformation, avatar.json says {method}", rig_path)
    if rig_inputs_sha256(hair, cage, rest, head.faces, method) == stored:
        rig = HairRig.from_file_arrays(data, hair, cage, rig_path)
    else:
        warnings.warn(f"{rig_path}: the hair, cage or head changed since the rig was computed; "
                      "recomputing it (save the avatar again to keep the result)", RigRebuiltWarning,
                      stacklevel=3)
        same_head = str(data["sdf_inputs_sha256"]) == sdf_inputs_sha256(rest, head.faces)
        try:
            rig = HairRig.build(head, rest, hair, cage, method, sdf=stored_sdf(data) if same_head else None)
        except InputError as e:
            raise FormatError(f"cannot rebuild the hair rig: {e.message}", rig_path) from None
    return hair, cage, rig


def load_avatar_head(folder: str | os.PathLike) -> tuple[Any, np.ndarray, HeadRef, dict]:
    """The head model, identity shape (S,) float64, head reference and manifest of an avatar
    folder, without reading the splats (what a tracker needs to drive this avatar)."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    mpath = folder / MANIFEST
    ref_json = manifest["head_model"]
    ref = HeadRef() if ref_json["kind"] == "template" else HeadRef("flame", ref_json["path"], ref_json["sha256"])
    head = ref.load(folder, mpath)
    if (head.num_vertices, head.num_faces) != (ref_json["vertices"], ref_json["faces"]):
        raise FormatError(f"the avatar was made for a head model with {ref_json['vertices']} vertices "
                          f"and {ref_json['faces']} faces; this {ref.kind} head has {head.num_vertices} "
                          f"and {head.num_faces}", mpath)
    if "jaw_corrective" in ref_json:
        head = _with_jaw_corrective(folder, ref_json["jaw_corrective"], head)
    if ref.kind == "template" and "sha256" in ref_json and ref_json["sha256"] != head_geometry_sha256(head):
        warnings.warn(f"{mpath}: the built-in template head has changed since this avatar was made "
                      f"({ref_json.get('source', 'unknown version')}); its bald Gaussians may not lie on "
                      "the head any more: make the avatar again", HeadModelChangedWarning, stacklevel=3)
    shape = np.asarray(manifest["identity"]["shape"], np.float64)
    if len(shape) > head.num_shape:
        raise FormatError(f"identity shape has {len(shape)} coefficients, the head model "
                          f"{head.num_shape}", mpath)
    return head, shape, ref, manifest


def _with_jaw_corrective(folder: Path, entry: dict, head):
    """`head` with the avatar's jaw corrective (manifest entry `entry`) added to its posedirs."""
    from avatarkit.fileio import file_sha256
    from avatarkit.head.jaw_corrective import apply_jaw_corrective, load_npz

    path = _part_file(folder, entry)
    if file_sha256(path) != entry["sha256"]:
        raise FormatError("belongs to another avatar (its SHA-256 differs from avatar.json's)", path)
    corrective = load_npz(path)
    if len(corrective.vertex_index) != entry["vertices"]:
        raise FormatError(f"moves {len(corrective.vertex_index)} vertices, avatar.json says {entry['vertices']}", path)
    try:
        return apply_jaw_corrective(head, corrective)
    except InputError as e:
        raise FormatError(e.message, path) from None


def load_avatar(folder: str | os.PathLike) -> Avatar:
    """Read and check an avatar folder (see the module docstring)."""
    folder = Path(folder)
    head, shape, ref, manifest = load_avatar_head(folder)
    mpath = folder / MANIFEST
    parts = manifest["parts"]

    bald_path = _part_file(folder, parts["bald"])
    bald = _read_splats(bald_path)
    _count_check(bald_path, "Gaussians", len(bald), parts["bald"]["count"])
    ids = bald.extras.get("binding")
    if ids is None:
        raise FormatError("no 'binding' property (the head face each Gaussian rides)", bald_path)
    if ids.dtype.kind not in "iu" and not (ids.dtype.kind == "f" and np.array_equal(ids, np.round(ids))):
        raise FormatError(f"'binding' holds {ids.dtype} values, expected integer face ids", bald_path)
    ids = ids.astype(np.int64)
    if len(ids) and (ids.min() < 0 or ids.max() >= head.num_faces):
        bad = int(np.flatnonzero((ids < 0) | (ids >= head.num_faces))[0])
        raise FormatError(f"Gaussian {bad} is bound to face {int(ids[bad])}, but the head model has "
                          f"{head.num_faces} faces (0..{head.num_faces - 1})", bald_path)
    bald = bald.replace(extras={**bald.extras, "binding": ids.astype(np.int32)})

    rest = _rest_vertices(head, np.concatenate([shape, np.zeros(head.num_shape - len(shape))]).astype(np.float32))
    if "hair" in parts:
        hair, cage, rig = _load_hair(folder, parts, head, rest)
    else:  # a hairless avatar (the schema allows no cage or rig without hair)
        hair, cage, rig = GaussianSet.empty(bald.sh_degree), None, None

    image = None
    if "preview" in parts:
        from avatarkit.export.images import read_png

        ppath = _part_file(folder, parts["preview"])
        try:
            image = read_png(ppath)[..., :3].copy()
        except AvatarKitError:
            raise FormatError("not a readable image", ppath) from None

    extras = {}
    for key in EXTRA_PREVIEW_FILES:
        if (folder / key).is_file():
            from avatarkit.export.images import read_png

            try:
                extras[key] = read_png(folder / key)[..., :3].copy()
            except AvatarKitError:
                raise FormatError("not a readable image", folder / key) from None
    try:
        avatar = Avatar(head, bald, hair, cage, rig, shape.astype(np.float32), ref,
                        manifest.get("name", folder.name), parts["bald"]["sh_frame"],
                        dict(manifest["provenance"]), image, folder, extras)
    except InputError as e:
        raise FormatError(e.message, mpath) from None
    try:
        avatar.binding  # noqa: B018 -- check now that every host triangle has a frame
    except InputError as e:
        raise FormatError(e.message, bald_path) from None
    return avatar


# --- inspection ----------------------------------------------------------------------------------

def inspect_avatar(path: Path):
    """`avatarkit inspect` summary of an avatar folder (reads the manifest and file sizes only)."""
    from avatarkit.inspect import ByteCount, Summary

    folder = Path(path)
    m = read_manifest(folder)
    s = Summary("avatar folder", str(folder))
    s.add("name", m.get("name", folder.name))
    head = m["head_model"]
    label = "built-in template" if head["kind"] == "template" else f"FLAME {head['path']}"
    s.add("head model", f"{label} ({head['vertices']:,} vertices, {head['faces']:,} faces)")
    if "jaw_corrective" in head:
        s.add("jaw corrective", f"learned from a video ({head['jaw_corrective']['vertices']:,} vertices)")
    shape = m["identity"]["shape"]
    nonzero = sum(1 for x in shape if x != 0)
    s.add("identity shape", f"{len(shape)} coefficients, {nonzero} non-zero")
    parts = m["parts"]
    s.add("bald Gaussians", parts["bald"]["count"]).add("bald SH degree", parts["bald"]["sh_degree"])
    if "hair" in parts:
        s.add("hair Gaussians", parts["hair"]["count"]).add("hair SH degree", parts["hair"]["sh_degree"])
        s.add("cage", f"{parts['cage']['vertices']:,} vertices, {parts['cage']['faces']:,} faces")
        s.add("hair deformation", parts["rig"]["deformation"])
    else:
        s.add("hair Gaussians", 0).add("cage", "none (hairless avatar)")
    files = []
    total = 0
    for key, entry in parts.items():
        p = folder / entry["file"]
        size = p.stat().st_size if p.is_file() else None
        total += size or 0
        files.append({"name": entry["file"], "bytes": size if size is not None else "MISSING"})
    s.add("files", files).add("total size", ByteCount(total))
    prov = m["provenance"]
    s.add("created", prov.get("created", "")).add("made by", f"avatarkit {prov.get('version', '?')}")
    if prov.get("generator"):
        s.add("generator", prov["generator"])
    if prov.get("source_image"):
        s.add("source image", prov["source_image"])
    return s


__all__ = ["AVATAR_FORMAT", "AVATAR_VERSION", "Avatar", "JAW_CORRECTIVE_FILE", "HeadModelChangedWarning", "PART_BALD", "PART_HAIR",
           "RigRebuiltWarning", "check_avatar_target", "inspect_avatar", "is_avatar_folder", "load_avatar",
           "load_avatar_head", "load_rest_splats", "read_manifest"]
