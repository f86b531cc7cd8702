"""The import lifter: splats from an image-to-3D tool, aligned to the fitted head and split into
bald and hair.

`ImportLifter(head_splats, bald_splats)`: 3DGS PLYs from an image-to-3D lifter (FaceLift-style:
the photo lifted with hair, and the bald image lifted). The bald splats are aligned to the
fitted head by a similarity transform (trimmed ICP with scale, Umeyama, from four starting
orientations, against dense samples of the head's skin), the head splats move with them, and
hair = head splats not explained by the bald splats (farther than a few times the bald splats'
spacing from any of them, or of clearly another colour than the nearest ones). Bald splats far
from the head surface (stray floaters) are dropped. The 3D segmentation (item 6) cleans the hair.
"""
from __future__ import annotations

import os

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.fit import HeadFit
from avatarkit.recon.lifter import LiftResult
from avatarkit.recon.mesh_distance import closest_points
from avatarkit.rig.frames import points_on_triangles

def _read_splats(source, what: str) -> tuple[GaussianSet, str | None]:
    from avatarkit.gaussians.ply import read_ply

    if isinstance(source, GaussianSet):
        return source, None
    path = os.fspath(source)
    if not os.path.exists(path):
        raise InputError(f"{what} file not found", path)
    try:
        gs = read_ply(path)
    except FormatError:
        raise
    except InputError as e:
        raise FormatError(e.message, path) from None
    if len(gs) < 10:
        raise FormatError(f"{what} holds {len(gs)} Gaussians: too few to be a lifted head", path)
    return gs, path


def head_surface_samples(fit: HeadFit, n: int = 20000, seed: int = 0) -> np.ndarray:
    """(n, 3) points uniformly by area on the rest head (neck and eyeballs included: a lifted
    bald head has them too)."""
    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    faces = model.faces
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    ids = rng.choice(len(faces), size=n, p=area / area.sum())
    return points_on_triangles(tri[ids], rng)


#: ICP steps every starting orientation gets before the best one is continued
START_STEPS = 12


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity dst ~ s R src + t for paired points (N, 3) -> (s, R, t)."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    cov = b.T @ a / len(src)
    u, sig, vt = np.linalg.svd(cov)
    d = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[2, 2] = -1
    r = u @ d @ vt
    var = (a * a).sum() / len(src)
    s = float(np.trace(np.diag(sig) @ d) / max(var, 1e-30))
    return s, r, mu_d - s * r @ mu_s


def align_similarity(points: np.ndarray, target: np.ndarray, iterations: int = 100, keep: float = 0.85,
                     seed: int = 0, mesh: tuple | None = None, refine: int = 8
                     ) -> tuple[float, np.ndarray, np.ndarray, float]:
    """Trimmed ICP with scale: the similarity (s, R (3, 3), t (3,)) taking `points` (N, 3) onto
    the surface sampled by `target` (M, 3), and the trimmed RMS distance after it. Starts from
    the four orientations identity and 180 degrees about X, Y and Z, each with centroids and
    RMS radii matched; each runs `START_STEPS` steps and the best is continued up to
    `iterations` (or until it stops improving). Each iteration pairs every point with its nearest
    target sample, keeps the `keep` closest pairs and solves Umeyama on them. mesh: (vertices,
    faces) the samples came from: the best start is then refined `refine` times against the
    closest points on its triangles (exact, not snapped to the samples)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    p = np.asarray(points, np.float64)
    if len(p) > 6000:
        p = p[rng.choice(len(p), 6000, replace=False)]
    q = np.asarray(target, np.float64)
    tree = cKDTree(q)
    mu_p, mu_q = p.mean(axis=0), q.mean(axis=0)
    rad_p = np.sqrt(((p - mu_p) ** 2).sum(axis=1).mean())
    rad_q = np.sqrt(((q - mu_q) ** 2).sum(axis=1).mean())
    starts = [np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]

    def icp(s, r, t, steps):
        prev = np.inf
        for it in range(steps):
            x = s * p @ r.T + t
            d, j = tree.query(x)
            sel = d <= np.quantile(d, keep)
            s, r, t = umeyama(p[sel], q[j[sel]])
            err = float(np.mean(d[sel] ** 2))
            if it > 5 and prev - err < 1e-6 * prev:
                break
            prev = err
        d, _ = tree.query(s * p @ r.T + t)
        return s, r, t, float(np.sqrt(np.mean(np.sort(d)[: max(1, int(keep * len(d)))] ** 2)))

    # every start a few steps (enough to tell the right orientation), then the best one on
    tries = []
    for r0 in starts:
        s0 = rad_q / max(rad_p, 1e-30)
        tries.append(icp(s0, r0, mu_q - s0 * r0 @ mu_p, START_STEPS))
    best = min(tries, key=lambda x: x[3])
    best = icp(*best[:3], iterations)
    if mesh is None:
        return best
    # refine the winner against the surface itself: nearest samples snap to a lattice that is a
    # couple of millimetres coarse, the closest point on the triangles does not
    s, r, t, _ = best
    v, f = mesh
    sub = p[rng.choice(len(p), min(len(p), 3000), replace=False)]
    for _ in range(refine):
        x = s * sub @ r.T + t
        _, _, c, d = closest_points(x, v, f)
        sel = d <= np.quantile(d, keep)
        s, r, t = umeyama(sub[sel], c[sel])
    x = s * sub @ r.T + t
    d = closest_points(x, v, f)[3]
    rms = float(np.sqrt(np.mean(np.sort(d)[: max(1, int(keep * len(d)))] ** 2)))
    return s, r, t, rms


class ImportLifter:
    """Lifted splats from an image-to-3D tool (module docstring).

    head_splats: the portrait lifted with its hair (PLY path or GaussianSet); bald_splats: the
    bald image lifted, in the same frame. explained: a head splat within this many times the
    bald splats' median spacing of a bald splat (and of a similar colour) is bald, not hair.
    max_distance: bald splats farther than this (metres, after alignment) from the head surface
    are dropped as floaters.
    """

    name = "import"

    def __init__(self, head_splats, bald_splats, *, explained: float = 3.0, max_distance: float = 0.03,
                 colour_tolerance: float = 0.25):
        self.head, self.head_path = _read_splats(head_splats, "head splats")
        self.bald, self.bald_path = _read_splats(bald_splats, "bald splats")
        # extras of another tool (a `binding` to its own mesh, say) mean nothing here
        self.head = self.head.replace(extras={})
        self.bald = self.bald.replace(extras={})
        self.explained = float(explained)
        self.max_distance = float(max_distance)
        self.colour_tolerance = float(colour_tolerance)

    def lift(self, image, analysis, segmentation, bald, fit: HeadFit) -> LiftResult:
        from scipy.spatial import cKDTree

        from avatarkit.rig.nearest import nearest_faces

        target = head_surface_samples(fit)
        s, r, t, rms = align_similarity(self.bald.means, target,
                                        mesh=(fit.rest_vertices, fit.model.faces))
        if not (np.isfinite(s) and s > 0):
            raise FormatError("cannot align the bald splats to the head (degenerate point set)",
                              self.bald_path)
        bald_set = self.bald.transform(r, t, s)
        head_set = self.head.transform(r, t, s)
        _, dist = nearest_faces(bald_set.means, fit.rest_vertices, fit.model.faces)
        near = dist <= self.max_distance
        if near.mean() < 0.5:
            raise FormatError(f"only {near.mean():.0%} of the bald splats lie within "
                              f"{self.max_distance * 100:.0f} cm of the fitted head after alignment "
                              f"(trimmed RMS {rms * 1000:.1f} mm): not a lifted head in a frame we can align",
                              self.bald_path)
        bald_set = bald_set.subset(near)
        tree = cKDTree(bald_set.means)
        spacing = float(np.median(tree.query(bald_set.means, k=2)[0][:, 1]))
        d, j = tree.query(head_set.means, k=4)
        reach = self.explained * max(spacing, 1e-4)
        colour_gap = np.linalg.norm(head_set.colors[:, None] - bald_set.colors[j], axis=2).min(axis=1)
        hair = (d[:, 0] > reach) | (colour_gap > self.colour_tolerance)
        hair_set = head_set.subset(hair)
        info = {"lifter": self.name, "scale": round(s, 6), "align_rms_mm": round(rms * 1000, 3),
                "bald": len(bald_set), "bald_dropped": int((~near).sum()), "hair": len(hair_set),
                "head_splats": len(head_set)}
        return LiftResult(bald_set, hair_set, info)


__all__ = ["ImportLifter", "START_STEPS", "align_similarity", "head_surface_samples", "umeyama"]
