"""HeadModel files: our plain `.npz` conversion, and `load_head_model` (template / .pkl / .npz).

npz layout (`NPZ_FORMAT`): arrays `faces (F,3) int32`, `v_template (V,3)`, `shapedirs (V,3,S)`,
`exprdirs (V,3,E)`, optional `posedirs (P,V*3)`, `J_regressor (J,V)` (dense), `kintree_parents (J,)`,
`weights (V,J)`, one `region__<name>` int64 index array per region, and `meta`: a JSON string
with format, name, source, expression_names, shape_names. No pickles: loads with allow_pickle=False.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import atomic_path, json_loads, read_npz
from avatarkit.head.model import NPZ_FORMAT, HeadModel

_REQUIRED = ("faces", "v_template", "shapedirs", "exprdirs", "J_regressor", "kintree_parents", "weights", "meta")


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_npz(model: HeadModel, path: str | os.PathLike) -> None:
    """Write `model` as a plain npz (atomically: nothing is left under `path` on failure)."""
    jr = model.J_regressor.toarray() if hasattr(model.J_regressor, "toarray") else model.J_regressor
    arrays = {"faces": model.faces, "v_template": model.v_template, "shapedirs": model.shapedirs,
              "exprdirs": model.exprdirs, "J_regressor": np.asarray(jr, dtype=np.float32),
              "kintree_parents": model.kintree_parents, "weights": model.weights}
    if model.posedirs is not None:
        arrays["posedirs"] = model.posedirs
    for name, idx in model.regions.items():
        arrays[f"region__{name}"] = idx
    meta = {"format": NPZ_FORMAT, "name": model.name, "source": model.source,
            "expression_names": model.expression_names, "shape_names": model.shape_names}
    arrays["meta"] = np.array(json.dumps(meta))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:  # a file object: np.savez would append ".npz" to a bare name
            np.savez(fh, **arrays)


def load_npz(path: str | os.PathLike) -> HeadModel:
    """Read a head model written by `save_npz`. Errors name the file and the key."""
    path = Path(path)
    if not path.is_file():
        raise InputError("head model file not found", path)
    data = read_npz(path, "not a readable npz head model")
    for key in _REQUIRED:
        if key not in data:
            raise FormatError(f"missing key {key!r} (not a head model written by avatarkit)", path)
    try:
        meta = json_loads(str(data["meta"]), path)
    except (ValueError, TypeError) as e:
        raise FormatError(f"key 'meta' is not valid JSON ({e})", path) from None
    if not isinstance(meta, dict) or meta.get("format") != NPZ_FORMAT:
        raise FormatError(f"key 'meta' does not name format {NPZ_FORMAT!r}", path)
    regions = {k[len("region__"):]: v for k, v in data.items() if k.startswith("region__")}
    try:
        return HeadModel(faces=data["faces"], v_template=data["v_template"], shapedirs=data["shapedirs"],
                         exprdirs=data["exprdirs"], J_regressor=data["J_regressor"],
                         kintree_parents=data["kintree_parents"], weights=data["weights"],
                         posedirs=data.get("posedirs"), regions=regions,
                         expression_names=meta.get("expression_names", []),
                         shape_names=meta.get("shape_names", []),
                         name=str(meta.get("name", "head")), source=str(meta.get("source", "")))
    except InputError as e:
        raise FormatError(e.message, path) from None


def load_head_model(path: str | os.PathLike | None = None) -> HeadModel:
    """None -> the built-in template head; `.pkl` -> a FLAME model file; `.npz` -> `load_npz`."""
    if path is None:
        from avatarkit.head.template import load_template
        return load_template()
    suffix = Path(path).suffix.lower()
    if suffix == ".pkl":
        from avatarkit.head.flame import load_flame
        return load_flame(path)
    if suffix == ".npz":
        return load_npz(path)
    raise InputError("unknown head model format: expected a FLAME .pkl or an avatarkit .npz", path)
