"""The slow, obvious twin of the fast renderer: numpy, float64, loops over tiles and splats.

Used by the tests (stage by stage against `pipeline.py`) and as the benchmark baseline; never
by the product. Same conventions as `pipeline.py` (read its docstring): pixel centres at
(i + 0.5, j + 0.5), near plane 0.01, 16x16 tiles from the 3-sigma radius, INRIA compositing.
"""
from __future__ import annotations

import math

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.sh import eval_sh
from avatarkit.render import pipeline as _pipeline
from avatarkit.render.camera import Camera
from avatarkit.render.pipeline import (ALPHA_MAX, ALPHA_MIN, DILATION, TILE_SIZE,
                                       TRANSMITTANCE_MIN, Projection, RenderResult,
                                       check_background, tile_grid)
from avatarkit.rotations import quat_to_matrix


def project_reference(gaussians: GaussianSet, camera: Camera, near: float | None = None) -> Projection:
    """Stage 1 in float64 (fields kept float64; radii and tile rects int)."""
    near = _pipeline.NEAR_PLANE if near is None else near
    n = len(gaussians)
    w = camera.rotation
    pc = camera.to_camera(gaussians.means)                       # (N, 3)
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    rot = quat_to_matrix(gaussians.quats.astype(np.float64))    # (N, 3, 3)
    m = w @ rot * gaussians.scales.astype(np.float64)[:, None, :]
    cov = m @ m.transpose(0, 2, 1)                               # camera-space (N, 3, 3)
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    tan_x, tan_y = camera.tan_half_fov
    safe_z = np.where(z > near, z, 1.0)
    tx = safe_z * np.clip(x / safe_z, -(cx / fx + 0.3 * tan_x), (camera.width - cx) / fx + 0.3 * tan_x)
    ty = safe_z * np.clip(y / safe_z, -(cy / fy + 0.3 * tan_y), (camera.height - cy) / fy + 0.3 * tan_y)
    jac = np.zeros((n, 2, 3))
    jac[:, 0, 0] = fx / safe_z
    jac[:, 0, 2] = -fx * tx / safe_z ** 2
    jac[:, 1, 1] = fy / safe_z
    jac[:, 1, 2] = -fy * ty / safe_z ** 2
    cov2d = jac @ cov @ jac.transpose(0, 2, 1)
    a = cov2d[:, 0, 0] + DILATION
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + DILATION
    det = a * c - b * b
    ok = (z > near) & (gaussians.opacities >= np.float32(ALPHA_MIN)) & (det > 0)
    safe_det = np.where(ok, det, 1.0)
    mid = 0.5 * (a + c)
    radius = np.ceil(3.0 * np.sqrt(mid + np.sqrt(np.maximum(0.1, mid * mid - det))))
    u = fx * x / safe_z + cx
    v = fy * y / safe_z + cy
    tiles_x, tiles_y = tile_grid(camera)
    rects = np.stack([np.clip(np.floor((u - radius) / TILE_SIZE), 0, tiles_x),
                      np.clip(np.floor((v - radius) / TILE_SIZE), 0, tiles_y),
                      np.clip(np.ceil((u + radius) / TILE_SIZE), 0, tiles_x),
                      np.clip(np.ceil((v + radius) / TILE_SIZE), 0, tiles_y)], 1)
    ok &= (rects[:, 2] > rects[:, 0]) & (rects[:, 3] > rects[:, 1])
    return Projection(means2d=np.stack([u, v], 1), depths=z,
                      conics=np.stack([c, -b, a], 1) / safe_det[:, None],
                      radii=np.where(ok, radius, 0).astype(np.int64),
                      tile_rects=np.where(ok[:, None], rects, 0).astype(np.int64))


def sh_colors_reference(gaussians: GaussianSet, camera: Camera) -> np.ndarray:
    """Stage 2 in float64 through `avatarkit.gaussians.sh.eval_sh`."""
    d = gaussians.means.astype(np.float64) - camera.camera_center
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return eval_sh(gaussians.sh.astype(np.float64), d)


def ellipse_meets_tiles(means2d: np.ndarray, conics: np.ndarray, qlims: np.ndarray, tx: int,
                        ty: int, camera: Camera) -> np.ndarray:
    """(N,) bool: does splat i's ellipse q = d^T conic d <= qlims[i] reach the rectangle of
    tile (tx, ty)'s pixel centres? The numpy float64 twin of the fast binning's test (q is
    convex: its minimum over the rectangle is at the mean when inside, else on an edge, at the
    edge's 1D minimum clamped to the edge)."""
    x0, y0 = tx * TILE_SIZE + 0.5, ty * TILE_SIZE + 0.5
    x1 = min(tx * TILE_SIZE + TILE_SIZE, camera.width) - 0.5
    y1 = min(ty * TILE_SIZE + TILE_SIZE, camera.height) - 0.5
    m = np.asarray(means2d, np.float64)
    a, b, c = (np.asarray(conics, np.float64)[:, j] for j in range(3))
    best = np.full(len(m), np.inf)
    for X in (x0, x1):
        dx = X - m[:, 0]
        dy = np.clip(-b * dx / c, y0 - m[:, 1], y1 - m[:, 1])
        best = np.minimum(best, a * dx * dx + 2 * b * dx * dy + c * dy * dy)
    for Y in (y0, y1):
        dy = Y - m[:, 1]
        dx = np.clip(-b * dy / a, x0 - m[:, 0], x1 - m[:, 0])
        best = np.minimum(best, a * dx * dx + 2 * b * dx * dy + c * dy * dy)
    inside = (m[:, 0] >= x0) & (m[:, 0] <= x1) & (m[:, 1] >= y0) & (m[:, 1] <= y1)
    return inside | (best <= np.asarray(qlims, np.float64))


def rasterize_reference(proj: Projection, colors: np.ndarray, opacities: np.ndarray,
                        camera: Camera, background=(0.0, 0.0, 0.0)):
    """Stage 3+4: for every tile, the Gaussians whose rect covers it, sorted by depth (stable),
    composited one at a time over the tile's pixels. Returns float64 (rgb, alpha, depth)."""
    bg = check_background(background).astype(np.float64)
    h, w = camera.height, camera.width
    rgb = np.zeros((h, w, 3))
    trans = np.ones((h, w))
    acc_depth = np.zeros((h, w))
    tiles_x, tiles_y = tile_grid(camera)
    rects = proj.tile_rects
    visible = proj.radii > 0
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            x0, y0 = tx * TILE_SIZE, ty * TILE_SIZE
            x1, y1 = min(x0 + TILE_SIZE, w), min(y0 + TILE_SIZE, h)
            inside = visible & (rects[:, 0] <= tx) & (tx < rects[:, 2]) & (rects[:, 1] <= ty) & (ty < rects[:, 3])
            idx = np.flatnonzero(inside)
            idx = idx[np.argsort(proj.depths[idx], kind="stable")]
            px, py = np.meshgrid(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
            t = np.ones(px.shape)
            col = np.zeros(px.shape + (3,))
            dep = np.zeros(px.shape)
            done = np.zeros(px.shape, bool)
            for g in idx:
                dx = proj.means2d[g, 0] - px
                dy = proj.means2d[g, 1] - py
                ca, cb, cc = proj.conics[g]
                power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                alpha = np.minimum(ALPHA_MAX, opacities[g] * np.exp(power))
                use = (power <= 0) & (alpha >= ALPHA_MIN) & ~done
                test_t = t * (1 - alpha)
                stop = use & (test_t < TRANSMITTANCE_MIN)
                done |= stop
                use &= ~stop
                wgt = np.where(use, alpha * t, 0.0)
                col += wgt[..., None] * colors[g]
                dep += wgt * proj.depths[g]
                t = np.where(use, test_t, t)
                if done.all():
                    break
            rgb[y0:y1, x0:x1] = col
            trans[y0:y1, x0:x1] = t
            acc_depth[y0:y1, x0:x1] = dep
    alpha = 1 - trans
    depth = np.where(alpha > 0, acc_depth / np.where(alpha > 0, alpha, 1.0), 0.0)
    return rgb + trans[..., None] * bg, alpha, depth


def render_reference(gaussians: GaussianSet, camera: Camera, background=(0.0, 0.0, 0.0),
                     near: float | None = None) -> RenderResult:
    """The whole reference pipeline; float64 arrays; meta holds the projection and colours."""
    near = _pipeline.NEAR_PLANE if near is None else near
    proj = project_reference(gaussians, camera, near)
    colors = sh_colors_reference(gaussians, camera)
    rgb, alpha, depth = rasterize_reference(proj, colors, gaussians.opacities.astype(np.float64),
                                            camera, background)
    return RenderResult(rgb, alpha, depth, dict(means2d=proj.means2d, depths=proj.depths,
                                                conics=proj.conics, radii=proj.radii,
                                                tile_rects=proj.tile_rects, colors=colors))


def isotropic_screen_sigma(scale: float, depth: float, focal: float) -> float:
    """Screen-space standard deviation (pixels) of an isotropic Gaussian of world std `scale`
    seen head-on at the image centre from `depth`: sqrt((f s / z)^2 + 0.3) (EWA + dilation)."""
    return math.sqrt((focal * scale / depth) ** 2 + DILATION)
