"""`load_head_model`: a head model from any file we read (template / FLAME `.pkl` / our `.npz`).

The readers themselves: `avatarkit.head.flame` (FLAME pickles), `avatarkit.head.npz` (our npz),
`avatarkit.head.model.load_template` (the built-in head).
"""
from __future__ import annotations

import os
from pathlib import Path

from avatarkit.errors import InputError
from avatarkit.head.flame import load_flame
from avatarkit.head.model import HeadModel, load_template
from avatarkit.head.npz import load_npz


def load_head_model(path: str | os.PathLike | None = None) -> HeadModel:
    """None -> the built-in template head; `.pkl` -> a FLAME model file; `.npz` -> `load_npz`."""
    if path is None:
        return load_template()
    suffix = Path(path).suffix.lower()
    if suffix == ".pkl":
        return load_flame(path)
    if suffix == ".npz":
        return load_npz(path)
    raise InputError("unknown head model format: expected a FLAME .pkl or an avatarkit .npz", path)
