"""Named vertex regions derived from geometry, with one set of rules for every head model.

FLAME ships its masks in a separate file we do not have, so regions come from the mesh itself,
measured in units of the eye distance `u` (|left eye joint - right eye joint|, ~0.064 m) from
the eye midpoint `M` (the eye joints' centre; +Y up, face toward +Z):

- left_eye / right_eye: vertices skinned mainly (> 0.5) to joint 3 / 4 (FLAME and the template
  weight their eyeballs fully to the eye joints); eyes: both; left_iris / right_iris: eyeball
  vertices within 30 degrees of the eye's forward (+Z) axis.
- neck: below a plane tilted from just under the chin (front) up to M.y - 1.25 u at the back.
- scalp: above a hairline that runs at M.y + 1.0 u over the forehead, M.y + 0.35 u at the
  temples (z = M.z - 1.0 u) and M.y - 1.15 u behind the ears (z <= M.z - 1.9 u); not neck.
- face: the rest of the skin in front of the ears (z > M.z - 1.0 u); forehead: its part above
  M.y + 0.35 u.
- mouth line: where the jaw weight crosses 0.5 down the front midline (M.y - 1.1 u if no jaw
  weights); mouth_interior: skin within 0.42 u sideways and 0.13 u vertically of it whose normal
  does not face forward (the inner lips; the template's lip crease); lips: the rest of that box
  within 0.4 u sideways and 0.2 u vertically.
"""
from __future__ import annotations

import numpy as np


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3) float64 of a triangle mesh; (0, 0, 0) where undefined
    (a vertex in no face, or whose faces' normals cancel).

    vertices: (V, 3); faces: (F, 3) int, counter-clockwise seen from outside.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # (F, 3), |fn| = 2 * area
    idx = f.reshape(-1)
    # bincount rather than np.add.at: the same sums, several times faster on a head mesh
    n = np.stack([np.bincount(idx, np.repeat(fn[:, c], 3), minlength=len(v)) for c in range(3)], axis=1)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def derive_regions(model, vertices: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Regions of `model` (a HeadModel with FLAME joints) from its template geometry."""
    v = np.asarray(model.v_template if vertices is None else vertices, dtype=np.float64)
    joints = model.rest_joints()[0].astype(np.float64)
    W = model.weights
    el, er = joints[3], joints[4]
    M = 0.5 * (el + er)
    u = float(np.linalg.norm(el - er)) or 0.064
    x, y, z = (v - M).T
    normals = vertex_normals(v, model.faces)

    left = W[:, 3] > 0.5
    right = W[:, 4] > 0.5
    skin = ~(left | right)
    regions: dict[str, np.ndarray] = {"left_eye": np.flatnonzero(left), "right_eye": np.flatnonzero(right),
                                      "eyes": np.flatnonzero(left | right)}
    for name, mask, c in (("left_iris", left, el), ("right_iris", right, er)):
        d = v - c
        cosang = d[:, 2] / np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        regions[name] = np.flatnonzero(mask & (cosang > np.cos(np.radians(30))))

    front_mid = skin & (np.abs(x) < 0.3 * u) & (z > -0.2 * u)
    chin_y = y[front_mid].min() if front_mid.any() else -1.8 * u
    z_back = -2.2 * u
    y_back = -1.25 * u
    neck_plane = (chin_y - 0.05 * u) + (y_back - (chin_y - 0.05 * u)) * (z / z_back)
    neck = skin & (y < neck_plane)

    hair_y = np.interp(z, [-1.9 * u, -1.0 * u, -0.3 * u], [-1.15 * u, 0.35 * u, 1.0 * u])
    scalp = skin & ~neck & (y > hair_y)
    face = skin & ~neck & ~scalp & (z > -1.0 * u)

    mouth_y = _mouth_line(y, x, z, W, skin, u)
    box = skin & (np.abs(x) < 0.42 * u) & (z > -0.3 * u)
    mouth_interior = box & (np.abs(y - mouth_y) < 0.13 * u) & (normals[:, 2] < 0.3)
    lips = box & (np.abs(x) < 0.4 * u) & (np.abs(y - mouth_y) < 0.2 * u) & (z > 0) & ~mouth_interior
    regions.update(scalp=np.flatnonzero(scalp), neck=np.flatnonzero(neck), face=np.flatnonzero(face),
                   forehead=np.flatnonzero(face & (y > 0.35 * u)), lips=np.flatnonzero(lips & face),
                   mouth_interior=np.flatnonzero(mouth_interior))
    return regions


def _mouth_line(y, x, z, W, skin, u) -> float:
    """Height (relative to the eye midpoint) where the jaw weight crosses 0.5 on the front midline."""
    strip = skin & (np.abs(x) < 0.15 * u) & (z > 0) & (y < -0.5 * u)
    lower = strip & (W[:, 2] >= 0.5)
    if not lower.any():
        return -1.1 * u
    top_lower = y[lower].max()
    upper = strip & (W[:, 2] < 0.5) & (y > top_lower)
    if not upper.any():
        return -1.1 * u
    return 0.5 * (top_lower + y[upper].min())
