"""A small triangle-mesh rasteriser (numpy z-buffer): the renderer of the mesh-made synthetic
subject (`synthetic.mesh_head`), so that a test subject's pixels do not come from our own
Gaussian splatting.

`rasterise` draws triangles with per-vertex attributes (C channels) into an image: pixel
centres at (i + 0.5, j + 0.5) inside a triangle (screen-space edge functions, top-left rule not
needed: ties go to the nearer triangle), the nearest triangle wins, attributes interpolated
perspective-correctly (barycentrics divided by depth). All triangles are drawn at once: each
triangle's bounding box of pixels is expanded into candidate (triangle, pixel) pairs, the
inside ones sorted by (pixel, depth) and the first of each pixel kept. `rasterise_reference` is
the obvious loop over triangles with a running depth buffer; a test compares the two.
Anti-aliasing is the caller's (render at k times the size and `downsample`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.render.camera import Camera


@dataclass
class Raster:
    """attributes (H, W, C) float64 (0 where nothing is drawn); covered (H, W) bool; depth
    (H, W) float64 camera z (inf where nothing is drawn)."""

    attributes: np.ndarray
    covered: np.ndarray
    depth: np.ndarray


def _screen(vertices: np.ndarray, faces: np.ndarray, camera: Camera):
    """Per-face screen corners (F, 3, 2), depths (F, 3) and the faces every corner of which
    is in front of the camera (F,) bool."""
    px, z = camera.project(np.asarray(vertices, np.float64))
    tri, tz = px[faces], z[faces]
    ok = np.isfinite(tri).all(axis=(1, 2)) & (tz > 0).all(axis=1)
    return tri, tz, ok


def _barycentric(tri: np.ndarray, x: np.ndarray, y: np.ndarray):
    """Screen-space barycentrics (P, 3) of points (x, y) (P,) in triangles tri (P, 3, 2)
    and whether the triangle has area (P,) bool."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    w0 = (b[:, 0] - x) * (c[:, 1] - y) - (b[:, 1] - y) * (c[:, 0] - x)
    w1 = (c[:, 0] - x) * (a[:, 1] - y) - (c[:, 1] - y) * (a[:, 0] - x)
    good = np.abs(area) > 1e-12
    safe = np.where(good, area, 1.0)
    l0, l1 = w0 / safe, w1 / safe
    return np.stack([l0, l1, 1.0 - l0 - l1], axis=1), good


def _interpolate(lam: np.ndarray, tz: np.ndarray, attrs: np.ndarray):
    """Perspective-correct depth (P,) and attributes (P, C) from screen barycentrics (P, 3),
    corner depths (P, 3) and corner attributes (P, 3, C)."""
    w = lam / tz
    s = w.sum(axis=1)
    depth = 1.0 / s
    return depth, np.einsum("pk,pkc->pc", w / s[:, None], attrs)


def rasterise(vertices: np.ndarray, faces: np.ndarray, attributes: np.ndarray, camera: Camera) -> Raster:
    """Draw the mesh (vertices (V, 3) in the camera's world, faces (F, 3) int) with per-vertex
    attributes (V, C) (module docstring)."""
    faces = np.asarray(faces, np.int64)
    attributes = np.asarray(attributes, np.float64).reshape(len(vertices), -1)
    W, H, C = camera.width, camera.height, attributes.shape[1]
    out = Raster(np.zeros((H, W, C)), np.zeros((H, W), bool), np.full((H, W), np.inf))
    tri, tz, ok = _screen(vertices, faces, camera)
    ids = np.flatnonzero(ok)
    if len(ids) == 0:
        return out
    t = tri[ids]
    x0 = np.clip(np.ceil(t[:, :, 0].min(axis=1) - 0.5), 0, W).astype(np.int64)
    x1 = np.clip(np.floor(t[:, :, 0].max(axis=1) - 0.5), -1, W - 1).astype(np.int64)
    y0 = np.clip(np.ceil(t[:, :, 1].min(axis=1) - 0.5), 0, H).astype(np.int64)
    y1 = np.clip(np.floor(t[:, :, 1].max(axis=1) - 0.5), -1, H - 1).astype(np.int64)
    bw, bh = np.maximum(x1 - x0 + 1, 0), np.maximum(y1 - y0 + 1, 0)
    count = bw * bh
    keep = count > 0
    ids, x0, y0, bw, count = ids[keep], x0[keep], y0[keep], bw[keep], count[keep]
    if len(ids) == 0:
        return out
    # every (triangle, pixel of its bounding box) pair
    owner = np.repeat(np.arange(len(ids)), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    px = x0[owner] + local % bw[owner]
    py = y0[owner] + local // bw[owner]
    f = ids[owner]
    lam, good = _barycentric(tri[f], px + 0.5, py + 0.5)
    inside = good & (lam >= 0).all(axis=1)
    f, px, py, lam = f[inside], px[inside], py[inside], lam[inside]
    depth, values = _interpolate(lam, tz[f], attributes[faces[f]])
    pixel = py * W + px
    order = np.lexsort((depth, pixel))
    first = order[np.r_[True, pixel[order][1:] != pixel[order][:-1]]]
    p = pixel[first]
    out.attributes.reshape(-1, C)[p] = values[first]
    out.covered.reshape(-1)[p] = True
    out.depth.reshape(-1)[p] = depth[first]
    return out


def rasterise_reference(vertices: np.ndarray, faces: np.ndarray, attributes: np.ndarray,
                        camera: Camera) -> Raster:
    """`rasterise` the obvious way: one triangle at a time (its bounding box of pixels) into a
    running depth buffer (a
    strictly nearer sample replaces; on equal depth the first drawn stays, as in the sort)."""
    faces = np.asarray(faces, np.int64)
    attributes = np.asarray(attributes, np.float64).reshape(len(vertices), -1)
    W, H, C = camera.width, camera.height, attributes.shape[1]
    out = Raster(np.zeros((H, W, C)), np.zeros((H, W), bool), np.full((H, W), np.inf))
    tri, tz, ok = _screen(vertices, faces, camera)
    for i in np.flatnonzero(ok):
        t = tri[i]
        xs = np.arange(max(0, int(np.ceil(t[:, 0].min() - 0.5))), min(W - 1, int(np.floor(t[:, 0].max() - 0.5))) + 1)
        ys = np.arange(max(0, int(np.ceil(t[:, 1].min() - 0.5))), min(H - 1, int(np.floor(t[:, 1].max() - 0.5))) + 1)
        if len(xs) == 0 or len(ys) == 0:
            continue
        gx, gy = (a.ravel() for a in np.meshgrid(xs, ys))
        lam, good = _barycentric(np.repeat(t[None], len(gx), axis=0), gx + 0.5, gy + 0.5)
        inside = good & (lam >= 0).all(axis=1)
        d, v = _interpolate(lam[inside], np.repeat(tz[i][None], inside.sum(), axis=0),
                            np.repeat(attributes[faces[i]][None], inside.sum(), axis=0))
        for x, y, di, vi in zip(gx[inside], gy[inside], d, v):
            if di < out.depth[y, x]:
                out.depth[y, x], out.attributes[y, x], out.covered[y, x] = di, vi, True
    return out


def downsample(image: np.ndarray, k: int) -> np.ndarray:
    """(H*k, W*k, ...) -> (H, W, ...): the mean of each k x k block (box-filter anti-aliasing)."""
    if k == 1:
        return image
    h, w = image.shape[0] // k, image.shape[1] // k
    return image[:h * k, :w * k].reshape(h, k, w, k, *image.shape[2:]).mean(axis=(1, 3))


__all__ = ["Raster", "downsample", "rasterise", "rasterise_reference"]
