"""Motion clip files: chosen by extension, one reader and one writer per format.

- `.npz` in the GaussianAvatars / VHAP layout: `rotation, translation, neck_pose, jaw_pose`
  (T, 3), `eyes_pose` (T, 6), `expr` (T, E), `shape` (S,) / (1, S) / (T, S); singleton axes as
  in VHAP's per-frame files ((1, 3), (T, 1, 3)) are accepted. We add `fps` (and `name`) when
  we write; a file without `fps` plays at 25 fps (VHAP's default) unless told otherwise.
  Other keys (static_offset, dynamic_offset, timestep_id, focal_length, ...) are ignored.
- a folder of per-frame `.npz` files (VHAP's `export_as_nerf_dataset`: `flame_param/00000.npz`
  ...), read in natural order; the folder itself or its `flame_param/` subfolder.
- `.json`: our format, validated by `schemas/motion.schema.json`.
"""
from __future__ import annotations

import json
import os
import re
import warnings
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.fileio import atomic_path, json_loads, open_npz
from avatarkit.motion.clip import CHANNELS, DEFAULT_FPS, MotionClip, check_channel, check_fps

JSON_FORMAT = "avatarkit.motion"
JSON_VERSION = 1

#: clip channel -> npz key we write; readers also accept the aliases
NPZ_KEYS = {"rotation": "rotation", "translation": "translation", "neck": "neck_pose",
            "jaw": "jaw_pose", "eyes": "eyes_pose", "expr": "expr"}
NPZ_ALIASES = {"neck": ("neck",), "jaw": ("jaw",), "eyes": ("eyes",)}


# --- npz -------------------------------------------------------------------------------------
def _open_npz(path: Path):
    # sizes are checked before anything is inflated or allocated (fileio.MAX_NPZ_BYTES)
    return open_npz(path)


def _npz_array(data, key: str, path: Path) -> np.ndarray:
    arr = data[key]  # FormatError naming the file and key when unreadable
    if arr.dtype.kind not in "fiub":
        raise FormatError(f"key {key!r} holds {arr.dtype} data, expected numbers", path)
    return arr


def _frames_2d(arr: np.ndarray) -> np.ndarray:
    """(W,) -> one frame (1, W); (T, 1, W) or (T, W1, W2) -> (T, W1*W2)."""
    if arr.ndim == 1:
        return arr[None]
    # not reshape(T, -1): with T = 0 numpy cannot infer the width
    return arr.reshape(arr.shape[0], int(np.prod(arr.shape[1:], dtype=np.int64)))


def _npz_channels(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray, float | None, str | None]:
    """Read one npz: channels (T, W) each, shape (S,), fps or None, name or None."""
    with _open_npz(path) as data:
        keys = set(data.files)
        channels: dict[str, np.ndarray] = {}
        missing = []
        for channel, key in NPZ_KEYS.items():
            found = next((k for k in (key, *NPZ_ALIASES.get(channel, ())) if k in keys), None)
            if found is None:
                missing.append(key)
                continue
            arr = _frames_2d(_npz_array(data, found, path))
            try:
                channels[channel] = check_channel(found, arr, CHANNELS[channel])
            except InputError as e:
                raise FormatError(e.message, path) from None
        if missing:
            raise FormatError(f"missing key{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                              f"(a FLAME motion .npz needs {', '.join(NPZ_KEYS.values())})", path)
        counts = {NPZ_KEYS[c]: len(a) for c, a in channels.items()}
        if len(set(counts.values())) > 1:
            detail = ", ".join(f"{k} {n}" for k, n in counts.items())
            raise FormatError(f"channels have different frame counts ({detail})", path)
        shape = np.zeros(0, np.float32)
        if "shape" in keys:
            shape = _static_shape(_npz_array(data, "shape", path), path)
        fps = None
        if "fps" in keys:
            raw = _npz_array(data, "fps", path)
            try:
                fps = check_fps(raw.reshape(-1)[0] if raw.size == 1 else raw)
            except InputError as e:
                raise FormatError(e.message, path) from None
        name = None
        if "name" in keys:
            try:
                raw = data["name"]
            except FormatError:  # an object array: not ours, ignore it
                raw = None
            if raw is not None and raw.dtype.kind == "U" and raw.size == 1:
                name = str(raw.reshape(-1)[0])
    return channels, shape, fps, name


def _static_shape(arr: np.ndarray, path: Path) -> np.ndarray:
    if arr.ndim == 2 and len(arr) >= 1:
        if len(arr) > 1 and not np.allclose(arr, arr[:1], atol=1e-6):
            warnings.warn(f"{path}: 'shape' varies over {len(arr)} frames; using frame 0", stacklevel=4)
        arr = arr[0]
    if arr.ndim != 1:
        raise FormatError(f"'shape' must have shape (S,), (1, S) or (T, S), got {arr.shape}", path)
    if not np.isfinite(arr).all():
        raise FormatError("'shape' has a non-finite value", path)
    return arr.astype(np.float32)


def _load_npz(path: Path, fps: float | None) -> MotionClip:
    channels, shape, file_fps, name = _npz_channels(path)
    return _build(path, channels, shape, fps if fps is not None else file_fps, name or path.stem)


def _save_npz(path: Path, clip: MotionClip, extras: dict | None = None) -> None:
    arrays = dict(extras or {})
    arrays.update({NPZ_KEYS[c]: getattr(clip, c).astype(np.float32) for c in CHANNELS})
    arrays["shape"] = clip.shape.astype(np.float32)
    # float64 so readers that keep only float32 arrays (GaussianAvatars) skip it
    arrays["fps"] = np.array(clip.fps, np.float64)
    if clip.name:
        arrays["name"] = np.array(clip.name)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


# --- folder of per-frame npz files -----------------------------------------------------------
def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]


def _load_folder(path: Path, fps: float | None) -> MotionClip:
    folder = path / "flame_param" if (path / "flame_param").is_dir() else path
    files = sorted((p for p in folder.glob("*.npz") if p.is_file()), key=_natural_key)
    if not files:
        raise FormatError("folder holds no per-frame .npz files (looked in it and in flame_param/)", path)
    parts, shape, file_fps = [], None, None
    for f in files:
        channels, s, f_fps, _ = _npz_channels(f)
        parts.append(channels)
        if shape is None:
            shape = s
        if file_fps is None:
            file_fps = f_fps
    expr_widths = {p["expr"].shape[1] for p in parts}
    if len(expr_widths) > 1:
        raise FormatError(f"per-frame files disagree on the number of expression coefficients "
                          f"({sorted(expr_widths)})", folder)
    channels = {c: np.concatenate([p[c] for p in parts]) for c in CHANNELS}
    return _build(folder, channels, shape, fps if fps is not None else file_fps, path.name)


# --- json ------------------------------------------------------------------------------------
def _json_numbers(arr: np.ndarray) -> list:
    """float32 values as the shortest decimals that read back to the same float32."""
    arr = np.asarray(arr, np.float32) + np.float32(0.0)  # -0.0 -> 0.0
    flat = [float(np.format_float_positional(x, unique=True, trim="0")) for x in arr.ravel()]
    if arr.ndim == 1:
        return flat
    width = arr.shape[1]
    return [flat[i:i + width] for i in range(0, len(flat), width)] if width else [[] for _ in arr]


def _load_json(path: Path, fps: float | None) -> MotionClip:
    from avatarkit.schemas import validate

    try:
        with open(path, encoding="utf-8") as fh:
            doc = json_loads(fh.read(), path)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FormatError(f"not valid JSON ({e})", path) from None
    if isinstance(doc, dict) and doc.get("format") == JSON_FORMAT and isinstance(doc.get("version"), int) \
            and doc["version"] > JSON_VERSION:
        raise FormatError(f"motion format version {doc['version']} is newer than this avatarkit "
                          f"reads ({JSON_VERSION})", path)
    validate(doc, "motion", path)
    frames = doc["frames"]
    channels = {}
    for c in CHANNELS:
        label = f"frames.{c}"
        rows = frames[c]
        if c == "expr" and len({len(r) for r in rows}) > 1:
            raise FormatError(f"{label!r} rows have different lengths", path)
        try:
            channels[c] = check_channel(label, _frames_2d(np.asarray(rows, np.float64)), CHANNELS[c])
        except InputError as e:
            raise FormatError(e.message, path) from None
    counts = {c: len(a) for c, a in channels.items()}
    if len(set(counts.values())) > 1:
        detail = ", ".join(f"{k} {n}" for k, n in counts.items())
        raise FormatError(f"channels in 'frames' have different frame counts ({detail})", path)
    shape = np.asarray(doc.get("shape", []), np.float32)
    return _build(path, channels, shape, fps if fps is not None else doc["fps"],
                  doc.get("name") or path.stem)


def _save_json(path: Path, clip: MotionClip, extras: dict | None = None) -> None:
    if extras:
        raise OutputError("extra arrays (a tracked clip's camera, confidence) are kept only in .npz "
                          "clips", path)
    doc = {"format": JSON_FORMAT, "version": JSON_VERSION, "name": clip.name, "fps": clip.fps,
           "shape": _json_numbers(clip.shape),
           "frames": {c: _json_numbers(getattr(clip, c)) for c in CHANNELS}}
    text = _dump(doc)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)


def _dump(doc: dict) -> str:
    """JSON with one frame per line: readable and diffable, still compact."""
    head = [f'  "{k}": {json.dumps(v, allow_nan=False)}' for k, v in doc.items() if k != "frames"]
    channels = []
    for c, rows in doc["frames"].items():
        body = ",\n      ".join(json.dumps(r, allow_nan=False) for r in rows)
        channels.append(f'    "{c}": [\n      {body}\n    ]')
    return "{\n" + ",\n".join(head) + ',\n  "frames": {\n' + ",\n".join(channels) + "\n  }\n}\n"


# --- dispatch --------------------------------------------------------------------------------
def _build(path: Path, channels: dict, shape, fps, name) -> MotionClip:
    try:
        return MotionClip(fps=DEFAULT_FPS if fps is None else fps, shape=shape, name=name, **channels)
    except InputError as e:
        raise FormatError(e.message, path) from None


_loaders = {".npz": _load_npz, ".json": _load_json}
_savers = {".npz": _save_npz, ".json": _save_json}


def load_clip(path: str | os.PathLike, fps: float | None = None) -> MotionClip:
    """Read a motion clip: `.npz`, `.json`, or a folder of per-frame `.npz` files.

    fps: the frame rate to use; by default the file's own, else 25 (VHAP's default).
    Errors are InputError/FormatError naming the file (and the key) at fault.
    """
    p = Path(path)
    if fps is not None:
        fps = check_fps(fps)
    if p.is_dir():
        return _load_folder(p, fps)
    if not p.exists():
        raise InputError("no such file or folder", p)
    loader = _loaders.get(p.suffix.lower())
    if loader is None:
        raise FormatError(f"unknown motion clip format {p.suffix or '(no extension)'!r}: expected "
                          f"{', '.join(_loaders)} or a folder of per-frame .npz files", p)
    try:
        return loader(p, fps)
    except PermissionError as e:
        raise InputError(f"cannot read: {e.strerror}", p) from None


def save_clip(path: str | os.PathLike, clip: MotionClip, extras: dict | None = None) -> None:
    """Write `clip` as `.npz` (GaussianAvatars/VHAP keys + fps) or `.json`, atomically.

    extras: more named arrays to keep in an .npz (a tracked clip's camera and confidence);
    readers of the motion ignore keys they do not know."""
    p = Path(path)
    saver = _savers.get(p.suffix.lower())
    if saver is None:
        raise OutputError(f"cannot write a motion clip as {p.suffix or '(no extension)'!r}: "
                          f"use {' or '.join(_savers)}", p)
    saver(p, clip, extras)
