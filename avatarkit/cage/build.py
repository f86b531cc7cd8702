"""Build a coarse closed cage around a set of Gaussians (paper sec. 3.3; Xian et al. 2009).

Pipeline (all on voxel grids, no per-point Python loops):
 1. voxelise every point the cage must hold: centres and the six axis endpoints (`cage_points`);
 2. close: dilate by r_d with a Euclidean distance transform, fill enclosed cavities, erode by
    r_e < r_d (a morphological closing that also leaves each point r_d - r_e deep);
 3. the eroded set's signed distance field, lightly smoothed, is resampled on a coarse grid of
    spacing h and `skimage.measure.marching_cubes` extracts its zero level set;
 4. Taubin smoothing (trimesh) evens the triangulation without shrinking it.

Simplification: no quadric decimation is installed (trimesh's needs `fast_simplification`), so
the vertex count is controlled by the marching-cubes spacing instead: h is searched (count ~ h^-2)
for the largest count <= target_vertices. A uniform-grid surface also gives the even edge lengths
an XPBD cage wants.

Every result is checked (`check_cage`): watertight, consistently and outward oriented, manifold,
no degenerate faces, and every centre and axis endpoint at least `margin` inside. When a check
fails the next attempt of a fallback ladder runs (more slack between points and surface, less
smoothing, and last a finer target up to 2x); InputError only when every attempt fails.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from avatarkit.cage import points as _points
from avatarkit.cage.mesh import Cage, check_cage
from avatarkit.cage.points import cage_points
from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet

#: marching cubes makes ~KAPPA * area / h^2 vertices (measured on closed smooth shapes)
KAPPA = 1.2
MAX_FINE_VOXELS = 3_000_000


@dataclass(frozen=True)
class _Attempt:
    slack: float          # multiplies the gap between points and surface
    smoothing: int        # Taubin iterations
    target_factor: float  # allowed vertices = target * factor


def _ladder(smoothing: int) -> list[_Attempt]:
    return [_Attempt(1.0, smoothing, 1.0), _Attempt(1.5, smoothing, 1.0),
            _Attempt(2.0, smoothing // 2, 1.0), _Attempt(2.5, 0, 1.0),
            _Attempt(1.5, smoothing, 1.5), _Attempt(2.5, 0, 2.0)]


class _Grid:
    """The fine voxel grid of the points and its distance transform (shared by all attempts).

    Voxel (i, j, k) has its centre at origin + g * (i, j, k); d_out (X, Y, Z) float32 is the
    distance (metres) from each voxel centre to the nearest occupied voxel centre.
    """

    def __init__(self, points: np.ndarray, g: float, pad: float):
        self.origin = points.min(axis=0) - pad
        hi = points.max(axis=0) + pad
        self.g = g
        shape = np.ceil((hi - self.origin) / g).astype(int) + 1
        idx = np.floor((points - self.origin) / g + 0.5).astype(np.int64)
        occ = np.zeros(shape, bool)
        occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
        self.d_out = ndimage.distance_transform_edt(~occ, sampling=g).astype(np.float32)

    def closed_field(self, r_dilate: float, r_erode: float) -> np.ndarray:
        """Signed distance-like field (positive inside) of the points closed by (r_d, r_e):
        dilate by r_d, fill cavities, erode by r_e."""
        dilated = ndimage.binary_fill_holes(self.d_out <= r_dilate)
        d_in = ndimage.distance_transform_edt(dilated, sampling=self.g).astype(np.float32)
        # outside the dilated set, r_d - d_out is minus the distance to it (exact for the union
        # of balls), so the field is signed and continuous without another transform
        field = np.where(dilated, d_in, np.float32(r_dilate) - self.d_out)
        return field - np.float32(r_erode)


def _extract(field: np.ndarray, origin: np.ndarray, g: float, h: float):
    """Marching cubes of the field (already smoothed) resampled at spacing h -> (verts, faces)."""
    from skimage.measure import marching_cubes

    extent = (np.array(field.shape) - 1) * g
    n = np.floor(extent / h).astype(int) + 1
    if (n < 3).any():
        return None
    axes = [np.arange(k) * h / g for k in n]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"))
    coarse = ndimage.map_coordinates(field, grid.reshape(3, -1), order=1, mode="constant",
                                     cval=-1.0).reshape(tuple(n))
    coarse[[0, -1], :, :] = np.minimum(coarse[[0, -1], :, :], -h)  # a closed surface at the border
    coarse[:, [0, -1], :] = np.minimum(coarse[:, [0, -1], :], -h)
    coarse[:, :, [0, -1]] = np.minimum(coarse[:, :, [0, -1]], -h)
    if coarse.max() <= 0:
        return None
    # nudge exact zeros off the level so no triangle collapses onto a grid node
    coarse = np.where(coarse == 0, np.float32(1e-7 * h), coarse)
    verts, faces, _, _ = marching_cubes(coarse, level=0.0, spacing=(h, h, h), allow_degenerate=False)
    return verts + origin, faces


def _taubin(vertices: np.ndarray, faces: np.ndarray, iterations: int) -> np.ndarray:
    if iterations <= 0:
        return vertices
    import trimesh
    import trimesh.smoothing

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    trimesh.smoothing.filter_taubin(mesh, lamb=0.5, nu=0.53, iterations=iterations)
    return np.asarray(mesh.vertices)


def _surface_area(field: np.ndarray, g: float) -> float:
    from skimage.measure import marching_cubes, mesh_surface_area

    step = 2 if min(field.shape) > 8 else 1
    verts, faces, _, _ = marching_cubes(field, level=0.0, spacing=(g, g, g), step_size=step)
    return float(mesh_surface_area(verts, faces))


def build_cage(gaussians: GaussianSet, target_vertices: int = 500, margin: float | None = None,
               voxel_size: float | None = None, *, axis_sigma: float | None = None,
               smoothing: int = 10) -> Cage:
    """A closed cage (<= target_vertices vertices) around the Gaussians' centres and axis ends.

    margin: the least depth (metres) of every centre / axis endpoint inside the cage; default 1%
    of the points' bounding-box diagonal. voxel_size: the fine voxelisation spacing; default
    1/160 of that diagonal, coarsened if the grid would exceed MAX_FINE_VOXELS (the cage's own
    resolution is coarser, set by target_vertices). axis_sigma: where the axis endpoints sit (as
    in `deformation_points`). smoothing: Taubin iterations. The cage's `info` records the attempt
    used, the coarse cell size and the measured depth of the shallowest point.
    """
    axis_sigma = _points.AXIS_SIGMA if axis_sigma is None else axis_sigma
    if not isinstance(gaussians, GaussianSet):
        raise InputError("build_cage needs a GaussianSet")
    if len(gaussians) == 0:
        raise InputError("cannot build a cage around an empty set of Gaussians")
    if int(target_vertices) != target_vertices or target_vertices < 20:
        raise InputError(f"target_vertices must be an integer >= 20, got {target_vertices}")
    if margin is not None and not (np.isfinite(margin) and margin >= 0):
        raise InputError(f"margin must be >= 0, got {margin}")
    if voxel_size is not None and not (np.isfinite(voxel_size) and voxel_size > 0):
        raise InputError(f"voxel_size must be > 0, got {voxel_size}")
    points = cage_points(gaussians, axis_sigma)
    extent = points.max(0) - points.min(0)
    diag = float(np.linalg.norm(extent))
    if diag <= 0:
        diag = float(2 * gaussians.scales.max()) or 1e-3
    margin = 0.01 * diag if margin is None else float(margin)
    # first guess of the coarse spacing from the bounding box's area; refined per attempt
    box_area = 2 * (extent[0] * extent[1] + extent[1] * extent[2] + extent[0] * extent[2])
    h0 = float(np.sqrt(KAPPA * max(box_area, diag ** 2 / 4) / target_vertices))
    ladder = _ladder(int(smoothing))
    max_slack = max(a.slack for a in ladder)
    # room for the widest closing of the ladder plus two coarse cells (attempts cap h to fit)
    pad = h0 + max_slack * (margin + 0.5 * h0) + 2 * h0
    g = diag / 160 if voxel_size is None else float(voxel_size)
    voxels = float(np.prod((extent + 2 * pad) / g + 1))
    if voxel_size is None and voxels > MAX_FINE_VOXELS:
        g *= float(np.cbrt(voxels / MAX_FINE_VOXELS))
    grid = _Grid(points, g, pad)

    failures = []
    for number, attempt in enumerate(ladder):
        target = int(target_vertices * attempt.target_factor)
        result = _attempt(grid, points, margin, target, h0, pad, attempt)
        if isinstance(result, str):
            failures.append(f"attempt {number + 1}: {result}")
            continue
        result.info.update(attempt=number + 1, margin=margin, voxel_size=g,
                           axis_sigma=float(axis_sigma), target_vertices=int(target_vertices))
        return result
    raise InputError(f"could not build a valid cage around {len(gaussians)} Gaussians "
                     f"({'; '.join(failures)})")


def _attempt(grid: _Grid, points: np.ndarray, margin: float, target: int, h: float, pad: float,
             attempt: _Attempt):
    """One try: a Cage, or a string saying what went wrong."""
    g = grid.g
    field = None
    for _ in range(2):
        h = min(h, pad / 2)
        r_erode = max(h, 2 * g)
        r_dilate = min(r_erode + attempt.slack * (margin + 0.5 * h + 2 * g), pad - h)
        field = grid.closed_field(r_dilate, r_erode)
        h_new = max(float(np.sqrt(KAPPA * _surface_area(field, g) / target)), 2 * g)
        if abs(h_new - h) < 0.2 * h:
            break
        h = h_new
    smooth_field = ndimage.gaussian_filter(field, sigma=0.35 * h / g)
    # search the spacing for the largest vertex count <= target
    best = None
    for _ in range(10):
        mesh = _extract(smooth_field, grid.origin, g, h)
        if mesh is None:
            h *= 0.7
            continue
        count = len(mesh[0])
        if count <= target and (best is None or count > len(best[0][0])):
            best = (mesh, h)
        if 0.9 * target <= count <= target:
            break
        h *= float(np.clip(np.sqrt(count / (0.95 * target)), 0.8, 1.25))
    if best is None:
        return f"no surface with <= {target} vertices"
    (verts, faces), h = best
    verts = _taubin(verts, faces, attempt.smoothing)
    try:
        cage = Cage(verts, np.asarray(faces, np.int32))
    except InputError as e:
        return e.message
    if cage.volume() < 0:
        cage = Cage(cage.vertices, cage.faces[:, ::-1])
    check = check_cage(cage, points, margin)
    if not check.ok:
        return "; ".join(check.problems)
    cage.info.update(cell_size=h, min_depth=check.min_depth, components=check.components,
                     min_angle_deg=check.min_angle_deg)
    return cage
