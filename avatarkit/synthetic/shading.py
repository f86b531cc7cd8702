"""Person-like looks for synthetic head renders: Lambert shading that moves with the pose, and a
dark mouth interior that shows when the jaw opens.

Why: the accuracy targets of the face front end and the tracker are measured on renders of the
template head with known pose. Painted with flat colours (the albedo alone), the head gives
MediaPipe's face mesh no shading cue, and its pose reads biased by several degrees; and an open
jaw shows only a thin stretched band of lip colour, no dark mouth, so the mesh reads the lower
lip's drop as a nod. A person under room light shows both cues; these two additions give them
to the render (docs/face.md, docs/tracking.md).

Light: a direction toward the light, given in the camera's frame (x right, y down, z forward).
Our synthetic cameras never move, so a light fixed to the camera is also fixed in the world: as
the head turns, its shading moves over it, as in a video shot under a room's light. Each
Gaussian's colour is scaled by ambient + (1 - ambient) max(0, n . l), n its host triangle's
outward normal in the posed mesh.

Mouth interior: the template's surface is closed; as the jaw opens, the triangles of the lips
and the lip-crease band that straddle the switch of the jaw's skinning weight stretch (the
inner lips: 2-8x their rest area at 0.22 rad), while the rest of each lip only moves. Where a
real mouth would show its dark inside, these stretched triangles are: a Gaussian on a lip or
band triangle is blended toward `MOUTH_DARK` by how much its triangle has grown
(`mouth_opening`), so a closed mouth looks as before and an open one shows a dark gap between
the lips that widens with the jaw.
"""
from __future__ import annotations

import numpy as np

#: toward the light in the camera frame: upper left, in front (as a portrait is usually lit)
LIGHT = (-0.4, -0.5, -1.0)
#: share of the colour lit by the room regardless of the direction
AMBIENT = 0.35
#: colour of the mouth's interior (a dark, slightly red cavity)
MOUTH_DARK = (0.06, 0.025, 0.025)
#: a mouth triangle whose area has grown by this factor over its rest area is fully open
MOUTH_STRETCH = 1.6


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals (right-handed winding: outward on the template) of the triangles
    faces (F, 3) on vertices (V, 3)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def light_in_world(camera, light=None) -> np.ndarray:
    """(3,) unit direction toward the light in world coordinates, for `light` (3,) given in the
    frame of `camera` (a render.Camera: world -> camera rotation `camera.rotation`)."""
    light = LIGHT if light is None else light
    d = np.asarray(light, np.float64)
    return np.asarray(camera.rotation, np.float64).T @ (d / np.linalg.norm(d))


def lambert(colors: np.ndarray, normals: np.ndarray, to_light: np.ndarray, ambient: float | None = None
            ) -> np.ndarray:
    """colors (N, 3) in [0, 1] scaled by ambient + (1 - ambient) max(0, n . l); normals (N, 3)
    unit, to_light (3,) unit, both in one frame. Returns (N, 3) float32."""
    ambient = AMBIENT if ambient is None else ambient
    shade = ambient + (1.0 - ambient) * np.clip(np.asarray(normals, np.float64) @ np.asarray(to_light, np.float64),
                                                0.0, None)
    return np.clip(np.asarray(colors, np.float64) * shade[:, None], 0.0, 1.0).astype(np.float32)


def shade_gaussians(gaussians, vertices: np.ndarray, faces: np.ndarray, to_light: np.ndarray,
                    ambient: float | None = None):
    """A GaussianSet bound to faces (its `binding` extra: host face per Gaussian) with its
    colours Lambert-shaded by its host triangle's normal on the posed vertices (V, 3)."""
    ambient = AMBIENT if ambient is None else ambient
    n = face_normals(vertices, faces)[np.asarray(gaussians.extras["binding"], np.int64)]
    return gaussians.with_colors(lambert(gaussians.colors, n, to_light, ambient))


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) areas of the triangles faces (F, 3) on vertices (V, 3)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def mouth_faces(model) -> np.ndarray:
    """(F,) bool: the lips' and the mouth band's triangles (at least two corners in `lips` or
    `mouth_interior`); all False for a model that names neither."""
    faces = np.asarray(model.faces)
    out = np.zeros(len(faces), bool)
    for region in ("lips", "mouth_interior"):
        if region in model.regions:
            out |= model.region_mask(region)[faces].sum(axis=1) >= 2
    return out


def mouth_opening(rest_area: np.ndarray, area: np.ndarray, mouth: np.ndarray) -> np.ndarray:
    """(F,) in [0, 1]: how open the mouth is on each triangle: 0 at its rest area, 1 once it has
    grown by `MOUTH_STRETCH`, linear between; 0 off the mouth (mouth (F,) bool)."""
    grow = area / np.maximum(rest_area, 1e-18)
    return np.where(mouth, np.clip((grow - 1.0) / (MOUTH_STRETCH - 1.0), 0.0, 1.0), 0.0)


def darken_mouth(colors: np.ndarray, opening: np.ndarray) -> np.ndarray:
    """colors (N, 3) blended toward `MOUTH_DARK` by opening (N,) in [0, 1]. (N, 3) float32."""
    s = np.asarray(opening, np.float64)[:, None]
    c = np.asarray(colors, np.float64)
    return (c + s * (np.asarray(MOUTH_DARK) - c)).astype(np.float32)
