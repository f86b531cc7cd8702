"""`HeadRef`: which head model an avatar rides (the built-in template, or a user's FLAME file named
by path and checked by SHA-256), as the avatar manifest stores it."""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avatarkit.errors import FormatError, InputError

HEAD_KINDS = ("template", "flame")


def head_geometry_sha256(head_model) -> str:
    """SHA-256 of a head model's rest geometry (template vertices and faces)."""
    h = hashlib.sha256(np.ascontiguousarray(head_model.v_template, "<f4").tobytes())
    h.update(np.ascontiguousarray(head_model.faces, "<i4").tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class HeadRef:
    """Which head model an avatar rides: the built-in template, or a user's FLAME file
    (.pkl, or an avatarkit .npz conversion) named by path and checked by SHA-256."""

    kind: str = "template"
    path: str | None = None
    sha256: str | None = None

    def __post_init__(self):
        if self.kind not in HEAD_KINDS:
            raise InputError(f"head model kind must be one of {', '.join(HEAD_KINDS)}, got {self.kind!r}")
        if self.kind == "flame" and not (self.path and self.sha256):
            raise InputError("a FLAME head model reference needs a path and a sha256")

    @classmethod
    def for_file(cls, path: str | os.PathLike) -> "HeadRef":
        """A reference to a FLAME model file (absolute path and its SHA-256)."""
        from avatarkit.fileio import file_sha256

        p = Path(path)
        if not p.is_file():
            raise InputError("head model file not found", p)
        return cls("flame", str(p.resolve()), file_sha256(p))

    def resolve(self, folder: Path | None) -> Path:
        """The model file: the path as stored, else relative to the avatar folder."""
        p = Path(self.path)
        if not p.is_absolute() and folder is not None:
            p = folder / p
        return p

    def load(self, folder: Path | None = None, manifest: Path | None = None):
        """The `HeadModel` this reference names (the file's hash must match)."""
        from avatarkit.head.model import HeadModel

        if self.kind == "template":
            return HeadModel.template()
        from avatarkit.fileio import file_sha256
        from avatarkit.head.io import load_head_model

        p = self.resolve(folder)
        if not p.is_file():
            raise FormatError(f"the avatar's FLAME head model {self.path} is not there "
                              "(FLAME files are referenced, not copied: put it back or re-save the avatar)",
                              manifest)
        digest = file_sha256(p)
        if digest != self.sha256:
            raise FormatError(f"the head model file {p} has changed since the avatar was made "
                              f"(sha256 {digest[:12]}..., expected {self.sha256[:12]}...)", manifest)
        return load_head_model(p)

    def to_json(self, head_model) -> dict:
        out: dict[str, Any] = {"kind": self.kind}
        if self.kind == "flame":
            out.update(path=self.path, sha256=self.sha256)
        else:
            if getattr(head_model, "source", ""):
                out["source"] = str(head_model.source)
            out["sha256"] = head_geometry_sha256(head_model)
        out.update(vertices=int(head_model.num_vertices), faces=int(head_model.num_faces))
        return out


__all__ = ["HEAD_KINDS", "HeadRef", "head_geometry_sha256"]
