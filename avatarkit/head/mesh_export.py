"""Write a (posed) head mesh to a standard mesh file, coloured by region.

Formats by extension, written by trimesh's exporters: .obj, .ply, .glb, .stl, .off (single-file
formats only). PLY and GLB carry per-vertex colours (skin, scalp, lips, mouth interior, eye
whites, irises) so the regions can be seen in any viewer; OBJ gets them through the common
`v x y z r g b` extension; STL and OFF carry geometry only.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from avatarkit.errors import InputError, OutputError
from avatarkit.fileio import atomic_path

MESH_FORMATS = (".obj", ".ply", ".glb", ".stl", ".off")

# Region -> RGB; later entries win where regions overlap.
REGION_COLORS = {
    "face": (224, 178, 152), "neck": (214, 166, 140), "scalp": (196, 150, 128),
    "lips": (186, 100, 96), "mouth_interior": (70, 22, 26), "eyes": (238, 236, 230),
    "left_iris": (70, 92, 120), "right_iris": (70, 92, 120),
}
_DEFAULT_COLOR = (214, 170, 146)


def region_colors(model) -> np.ndarray:
    """(V, 4) uint8 RGBA per-vertex colours from the model's regions."""
    rgba = np.empty((model.num_vertices, 4), dtype=np.uint8)
    rgba[:, :3] = _DEFAULT_COLOR
    rgba[:, 3] = 255
    for name, rgb in REGION_COLORS.items():
        if name in model.regions:
            rgba[model.regions[name], :3] = rgb
    return rgba


def check_mesh_path(path: str | os.PathLike) -> str:
    """The lower-case extension of `path`, or OutputError when it is not a format we write."""
    ext = Path(path).suffix.lower()
    if ext not in MESH_FORMATS:
        raise OutputError(f"unknown mesh format {ext or '(none)'!r}; use one of {', '.join(MESH_FORMATS)}", path)
    return ext


def write_mesh(model, path: str | os.PathLike, vertices: np.ndarray | None = None, colors: bool = True) -> None:
    """Write `model`'s faces with `vertices` (V, 3) (default: the template) to `path`, atomically."""
    import trimesh

    path = Path(path)
    ext = check_mesh_path(path)
    v = model.v_template if vertices is None else np.asarray(vertices, dtype=np.float64)
    if v.shape != (model.num_vertices, 3):
        raise InputError(f"vertices must have shape ({model.num_vertices}, 3), got {v.shape}")
    mesh = trimesh.Trimesh(v, model.faces, process=False,
                           vertex_colors=region_colors(model) if colors and ext in (".ply", ".glb", ".obj") else None)
    data = mesh.export(file_type=ext[1:])
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
