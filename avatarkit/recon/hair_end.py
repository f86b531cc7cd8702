"""How low the hair reaches on the head, from a video's turned keyframes.

The single-view lifter lets its hidden strands (the back of the head) grow down to the height
of the photo's lowest hair beside the face (`hair_strands.HairShell.y_end`). For short hair
that is the temples, so the back of the head below them stays bald, and the profile's outline
at the nape falls short of the subject's hair (docs/video-build.md, "The hair at the back of the
head", session 12). A keyframe turned away from the reference shows the hair at the back:
`hair_end_from_views` is the rest-frame height of the lowest head-mesh vertices those keyframes
show under hair (the vertices facing the camera whose pixel the keyframe labels hair), a low
percentile over all of them. It only ever lowers the photo's own end (`lift.lift_hair`).
"""
from __future__ import annotations

import numpy as np

from avatarkit.head.regions import vertex_normals

#: the hair's end: this percentile of the heights of the vertices seen under hair
PERCENTILE = 2.0
#: at least this many vertices seen under hair (else no estimate)
MIN_VERTICES = 20
#: a vertex faces the camera when cos(normal, towards the camera) is above this
MIN_COS = 0.2


def hair_end_from_views(vertices: np.ndarray, faces: np.ndarray, views) -> float | None:
    """Rest-frame height (metres) of the lowest hair the non-reference labelled keyframes show
    on the head (module docstring); None when no such keyframe shows `MIN_VERTICES` vertices
    under hair. vertices (V, 3) / faces (F, 3): the rest head mesh; views: `multiview.View`s."""
    from avatarkit.recon.image_sampling import lookup
    from avatarkit.recon.segment import HAIR

    v = np.asarray(vertices, np.float64)
    normals = vertex_normals(v, faces)
    heights = []
    for view in views:
        if view.reference or view.labels is None:
            continue
        cam = view.camera
        labels = np.asarray(view.labels)
        towards = np.asarray(cam.camera_center, np.float64)[None] - v
        towards /= np.maximum(np.linalg.norm(towards, axis=1, keepdims=True), 1e-12)
        facing = np.einsum("ij,ij->i", normals, towards) > MIN_COS
        px, z = cam.project(v)
        inside = facing & np.isfinite(px).all(axis=1) & (z > 0)
        px = np.where(inside[:, None], px, -1.0)
        inside &= (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        # labels may be at another size than the camera
        h, w = labels.shape
        scale = np.array([w / cam.width, h / cam.height])
        under = inside & (lookup(labels, px * scale) == HAIR)
        heights.append(v[under, 1])
    heights = np.concatenate(heights) if heights else np.zeros(0)
    if len(heights) < MIN_VERTICES:
        return None
    return float(np.percentile(heights, PERCENTILE))


__all__ = ["MIN_COS", "MIN_VERTICES", "PERCENTILE", "hair_end_from_views"]
