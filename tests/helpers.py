"""Shared test fixtures: random but valid Gaussian sets."""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.sh import SH_COUNTS


def random_quats(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) unit wxyz quaternions, uniformly distributed rotations."""
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random proper rotation matrix (3, 3)."""
    from scipy.spatial.transform import Rotation
    return Rotation.random(random_state=rng.integers(2**31)).as_matrix()


def random_gaussians(n: int = 100, sh_degree: int = 0, seed: int = 0, extras=()) -> GaussianSet:
    """A valid GaussianSet of `n` splats with every field random.

    extras: names from {"binding" (N,) int32, "part" (N,) uint8, "feat" (N, 4) float32,
    "weight" (N,) float64}, or a dict name -> array to pass through as given.
    """
    rng = np.random.default_rng(seed)
    k = SH_COUNTS[sh_degree]
    sh = rng.normal(scale=0.5, size=(n, k, 3))
    made = {
        "binding": lambda: rng.integers(0, 10_000, n).astype(np.int32),
        "part": lambda: rng.integers(0, 4, n).astype(np.uint8),
        "feat": lambda: rng.normal(size=(n, 4)).astype(np.float32),
        "weight": lambda: rng.uniform(size=n),
    }
    ex = dict(extras) if isinstance(extras, dict) else {name: made[name]() for name in extras}
    return GaussianSet(
        means=rng.normal(scale=0.2, size=(n, 3)),
        quats=random_quats(n, rng),
        scales=np.exp(rng.uniform(-7, -2, size=(n, 3))),
        opacities=rng.uniform(0, 1, size=n),
        sh=sh,
        extras=ex,
    )


def plane_grid(xs, ys, z: float = 0.0, rgb=0.5, opacity: float = 0.99) -> GaussianSet:
    """Flat discs (8 mm wide, 1 mm thick) on the grid xs x ys at depth z, of one colour (a grey
    level or RGB in [0, 1]) and one opacity."""
    from avatarkit.gaussians.gaussian_set import rgb_to_dc

    X, Y = np.meshgrid(xs, ys)
    n = X.size
    means = np.stack([X.ravel(), Y.ravel(), np.full(n, z)], 1)
    colours = np.broadcast_to(np.asarray(rgb, np.float32), (n, 3))
    return GaussianSet(means, np.tile([1.0, 0, 0, 0], (n, 1)), np.tile([0.008, 0.008, 0.001], (n, 1)),
                       np.full(n, opacity), rgb_to_dc(np.ascontiguousarray(colours)))


def splat_plane(z: float, x_range, colour, step: float = 0.01) -> GaussianSet:
    """Flat, nearly opaque discs (8 mm wide, 1 mm thick) tiling the plane at depth z over
    x in x_range, y in [-0.1, 0.1], all of one colour (RGB in [0, 1])."""
    return plane_grid(np.arange(x_range[0], x_range[1] + 1e-9, step), np.arange(-0.1, 0.1 + 1e-9, step), z, colour)


def region_model(faces: np.ndarray, regions: dict[str, np.ndarray], n_vertices: int):
    """A stand-in head model with faces, named vertex regions and `region_mask` (what
    `frame_colours.fusion_selection` reads)."""
    from types import SimpleNamespace

    def region_mask(name):
        m = np.zeros(n_vertices, bool)
        m[regions[name]] = True
        return m

    return SimpleNamespace(faces=faces, regions=regions, region_mask=region_mask)


def gaussian_shell(radius: float, keep, colour, n: int, seed: int, scale: float = 0.006,
                   extras: dict | None = None) -> GaussianSet:
    """Flat Gaussians lying on a sphere of `radius` about the origin: `n` random directions, those
    `keep(points)` (unit vectors, (n, 3) -> (n,) bool) selects; a head or a hair cap for the
    multi-view hair tests. `extras`: name -> value, each filled for every Gaussian kept."""
    from avatarkit.rotations import matrix_to_quat
    from avatarkit.recon.hair_strands import unit_vectors

    rng = np.random.default_rng(seed)
    p = unit_vectors(rng.normal(size=(n, 3)))
    p = p[keep(p)] * radius
    m = len(p)
    nrm = unit_vectors(p)
    t = unit_vectors(np.cross(nrm, [1.0, 0, 0]) + 1e-9)
    rot = np.stack([t, np.cross(nrm, t), nrm], axis=2)
    ex = {k: np.full(m, v, np.asarray(v).dtype) for k, v in extras.items()} if extras else None
    return GaussianSet.from_colors(p, matrix_to_quat(rot), np.tile([scale, scale, 0.001], (m, 1)),
                                   np.full(m, 0.95), np.tile(colour, (m, 1)), extras=ex)


def one_error_line(cap) -> str:
    """The CLI's stderr (a pytest capture) is exactly one `error: ...` line and no traceback:
    returns that line."""
    lines = [line for line in cap.err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), cap.err
    assert "Traceback" not in cap.err
    return lines[0]


def uv_sphere(radius: float, nu: int = 120, nv: int = 60):
    """A UV sphere of triangles about the origin (vertices on the sphere, faces wound outward):
    (V, 3), (F, 3)."""
    th = np.linspace(0.0, np.pi, nv + 1)[1:-1]
    ph = np.linspace(0.0, 2 * np.pi, nu, endpoint=False)
    ring = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                     np.cos(th)[:, None] * np.ones_like(ph)], axis=-1).reshape(-1, 3)
    v = radius * np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    j = np.arange(nu)
    faces = [np.stack([np.zeros(nu, int), 1 + j, 1 + (j + 1) % nu], 1)]
    for i in range(nv - 2):
        a, b = 1 + i * nu, 1 + (i + 1) * nu
        faces += [np.stack([a + j, b + j, b + (j + 1) % nu], 1), np.stack([a + j, b + (j + 1) % nu, a + (j + 1) % nu], 1)]
    a = 1 + (nv - 2) * nu
    faces.append(np.stack([a + j, np.full(nu, len(v) - 1), a + (j + 1) % nu], 1))
    faces = np.concatenate(faces)
    tri = v[faces]
    outward = np.einsum("fc,fc->f", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.mean(1)) > 0
    faces[~outward] = faces[~outward][:, ::-1]
    return v, faces
