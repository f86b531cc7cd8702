"""How low the hair reaches on the head, from a video's turned keyframes.

The single-view lifter lets its hidden strands (the back of the head) grow down to the height
of the photo's lowest hair beside the face (`hair_strands.HairShell.y_end`). For short hair
that is the temples, so the back of the head below them stays bald, and the profile's outline
at the nape falls short of the subject's hair (docs/video-build.md, "The hair at the back of the
head", session 12). A keyframe turned away from the reference shows the hair at the back:
`hair_end_from_views` is the rest-frame height of the lowest head-mesh vertices those keyframes
show under hair, a low percentile over all of them. It only ever lowers the photo's own end
(`lift.lift_hair`).

Which vertices and which hair count (session 13: the mesh subject's end read at chin height,
-93 mm, 70 mm below its hair, docs/video-build.md "The hair's end, made robust"):
- only the back of the head (`back_of_head`): behind the face region and above the neck. The
  face's vertices under hair are the brows, a fringe, or hair in front of the face, none of
  which says how low the hair at the back reaches; the neck's are hair hanging over it or the
  segmentation's spill onto its shaded edge;
- only the hair connected to the body of the hair (`connected_hair`): the keyframes'
  segmentation labels hair on specks along the neck's shaded edge and on the ear's shadow,
  islands a few pixels wide apart from the hair above them.
"""
from __future__ import annotations

import numpy as np

from avatarkit.head.regions import vertex_normals

#: the hair's end: this percentile of the heights of the vertices seen under hair
PERCENTILE = 2.0
#: at least this many vertices seen under hair (else no estimate)
MIN_VERTICES = 20
#: a vertex faces the camera when cos(normal, towards the camera) is above this: 0, so that the
#: back of the head's outline in a profile keyframe (where the nape's hair shows) counts
MIN_COS = 0.0
#: hair pixels this share of the image's larger side apart still belong to one body of hair
#: (a dark streak the segmentation misses between two labelled ones)
CONNECT = 0.01


def back_of_head(vertices: np.ndarray, regions: dict) -> np.ndarray:
    """(V,) bool: the head mesh's vertices behind the face region's back edge (the temples'
    line, `head.regions`) that are not the neck's or the eyes'. vertices (V, 3) rest frame;
    regions: name -> vertex indices (a HeadModel's `regions`). Without a face region, every
    vertex not the neck's."""
    v = np.asarray(vertices, np.float64)
    keep = np.ones(len(v), bool)
    for name in ("neck", "eyes"):
        if name in regions:
            keep[np.asarray(regions[name], np.int64)] = False
    face = np.asarray(regions.get("face", []), np.int64)
    if len(face):
        keep &= v[:, 2] < v[face, 2].min()
    return keep


def connected_hair(hair: np.ndarray) -> np.ndarray:
    """(H, W) bool: the hair pixels of `hair` (H, W) bool that belong to its largest body, gaps
    up to `CONNECT` of the image's larger side bridged (the bridge itself is not returned)."""
    from scipy import ndimage

    hair = np.asarray(hair, bool)
    if not hair.any():
        return hair
    reach = max(1, int(round(CONNECT * max(hair.shape))))
    lab, n = ndimage.label(ndimage.binary_dilation(hair, iterations=reach))
    sizes = ndimage.sum(hair, lab, np.arange(1, n + 1))
    return hair & (lab == 1 + int(np.argmax(sizes)))


def hair_end_from_views(vertices: np.ndarray, faces: np.ndarray, views,
                        back: np.ndarray | None = None) -> float | None:
    """Rest-frame height (metres) of the lowest hair the non-reference labelled keyframes show
    on the head (module docstring); None when no such keyframe shows `MIN_VERTICES` vertices
    under hair. vertices (V, 3) / faces (F, 3): the rest head mesh; views: `multiview.View`s;
    back (V,) bool: the vertices that may count (`back_of_head`; None: all)."""
    from avatarkit.recon.image_sampling import lookup
    from avatarkit.recon.segment import HAIR

    v = np.asarray(vertices, np.float64)
    normals = vertex_normals(v, faces)
    allowed = np.ones(len(v), bool) if back is None else np.asarray(back, bool)
    heights = []
    for view in views:
        if view.reference or view.labels is None:
            continue
        cam = view.camera
        hair = connected_hair(np.asarray(view.labels) == HAIR)
        towards = np.asarray(cam.camera_center, np.float64)[None] - v
        towards /= np.maximum(np.linalg.norm(towards, axis=1, keepdims=True), 1e-12)
        facing = allowed & (np.einsum("ij,ij->i", normals, towards) > MIN_COS)
        px, z = cam.project(v)
        inside = facing & np.isfinite(px).all(axis=1) & (z > 0)
        px = np.where(inside[:, None], px, -1.0)
        inside &= (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        # labels may be at another size than the camera
        h, w = hair.shape
        scale = np.array([w / cam.width, h / cam.height])
        under = inside & lookup(hair, px * scale)
        heights.append(v[under, 1])
    heights = np.concatenate(heights) if heights else np.zeros(0)
    if len(heights) < MIN_VERTICES:
        return None
    return float(np.percentile(heights, PERCENTILE))


__all__ = ["CONNECT", "MIN_COS", "MIN_VERTICES", "PERCENTILE", "back_of_head", "connected_hair",
           "hair_end_from_views"]
