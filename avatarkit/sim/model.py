"""`CageModel` (what never changes during a simulation), `CageState` and `HeadFrame` (per-frame input).

The split follows NVIDIA Warp's `sim`: the model holds rest positions, inverse masses and the
constraint tables; the state holds positions and velocities; the head frame (Warp's "control")
holds the kinematic inputs of one frame: where the roots are and how the skull is posed.

Constraints (Macklin et al. 2016, XPBD), all built from the closed cage mesh:
- stretch: every cage edge keeps its rest length;
- bending: for every edge shared by two triangles, the distance between the two vertices
  opposite to it keeps its rest value. We prefer this to the dihedral-angle constraint: it is a
  plain distance constraint, so it has no singularity when the two triangles fold flat or become
  degenerate, it is cheap, and it behaves the same for every compliance;
- volume: one global constraint on the signed volume of the closed cage;
- tether (long-range attachment, Kim et al. 2012): every free vertex stays within its rest
  geodesic distance (shortest path along cage edges) of its nearest root, so a long hair cage
  cannot stretch away from the head however few iterations run;
- collision: the head's grid SDF (`HeadSDF`, rest head, head-joint frame), tested at the vertex
  or at its proxy point (the paper's proxy-based collision).

Roots are kinematic (inverse mass 0). Each is attached to the nearest point of the rest head
surface: a head face, barycentric coordinates on it, and an offset from that point expressed in
the face's frame (the GaussianAvatars triangle frame, unscaled). Its target in a posed frame is
the barycentric point of the posed face plus the offset turned by the posed face frame, so roots
follow the head's skinning (LBS) exactly, neck and jaw included, and move rigidly with a rigid head.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.head.sdf_grid import HeadSDF

#: cage vertices (MVC weights) kept per proxy. The solver sums every proxy in every substep, so
#: this is its largest per-vertex cost; 8 measured as good as 32 on the whip (issue 18, session 5:
#: strain, volume, rest and penetration within the tests' bounds) and the kernel ~20 % cheaper.
#: Plain renormalised truncation (no correction) put proxies 13-20 mm off their Gaussians at rest
#: and broke the strain bound at every K tried (8-24): hence `sparsify_weights`' correction.
PROXY_K = 8


@dataclass(eq=False)
class CageState:
    """positions, velocities: (C, 3) float32 (metres, metres per second)."""

    positions: np.ndarray
    velocities: np.ndarray

    def __post_init__(self):
        self.positions = np.ascontiguousarray(self.positions, dtype=np.float32)
        self.velocities = np.ascontiguousarray(self.velocities, dtype=np.float32)
        if self.positions.ndim != 2 or self.positions.shape[1] != 3:
            raise InputError(f"positions must have shape (C, 3), got {self.positions.shape}")
        if self.velocities.shape != self.positions.shape:
            raise InputError(f"velocities have shape {self.velocities.shape}, "
                             f"positions {self.positions.shape}")

    def copy(self) -> "CageState":
        return CageState(self.positions.copy(), self.velocities.copy())

    def kinetic_energy(self, inv_mass: np.ndarray) -> float:
        """0.5 * sum m |v|^2 over the free vertices (unit mass each where inv_mass > 0)."""
        free = np.asarray(inv_mass) > 0
        m = 1.0 / np.asarray(inv_mass, dtype=np.float64)[free]
        return float(0.5 * np.sum(m * np.sum(self.velocities[free].astype(np.float64) ** 2, axis=1)))


@dataclass(eq=False)
class HeadFrame:
    """The kinematic input of one frame. root_positions: (R, 3) targets of the root vertices;
    transform: (4, 4) the head joint's skinning transform (rest -> posed), which places the SDF;
    joint_transforms: (J, 4, 4) the transforms of a `HeadSkin`'s joints (the first is
    `transform`), which let the SDF follow the jaw and neck; None: the head joint alone."""

    root_positions: np.ndarray
    transform: np.ndarray
    joint_transforms: np.ndarray | None = None

    def __post_init__(self):
        self.root_positions = np.ascontiguousarray(self.root_positions, dtype=np.float32)
        self.transform = np.asarray(self.transform, dtype=np.float64)
        if self.joint_transforms is not None:
            jt = np.asarray(self.joint_transforms, dtype=np.float64)
            if jt.ndim != 3 or jt.shape[1:] != (4, 4) or len(jt) == 0 or not np.isfinite(jt).all():
                raise InputError(f"joint_transforms must be finite (J, 4, 4), got {jt.shape}")
            if not _close(jt[0], self.transform, 1e-6):
                raise InputError("joint_transforms[0] must be the head transform")
            self.joint_transforms = jt
        if self.root_positions.ndim != 2 or self.root_positions.shape[1] != 3:
            raise InputError(f"root_positions must have shape (R, 3), got {self.root_positions.shape}")
        if self.transform.shape != (4, 4) or not np.isfinite(self.transform).all():
            raise InputError(f"transform must be a finite (4, 4) matrix, got {self.transform.shape}")
        r = self.transform[:3, :3]
        # det by the triple product: np.linalg.det and np.allclose cost ~10x more, every frame
        det = (r[0, 0] * (r[1, 1] * r[2, 2] - r[1, 2] * r[2, 1]) - r[0, 1] * (r[1, 0] * r[2, 2] - r[1, 2] * r[2, 0])
               + r[0, 2] * (r[1, 0] * r[2, 1] - r[1, 1] * r[2, 0]))
        if not _close(r @ r.T, _EYE3, 1e-4) or det < 0:
            raise InputError("the head transform's upper 3x3 must be a rotation")
        if not np.isfinite(self.root_positions).all():
            raise InputError("root_positions has a non-finite value")


_EYE3 = np.eye(3)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b of (N, 3) arrays (np.cross costs ~4x more on small arrays)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _close(a: np.ndarray, b: np.ndarray, atol: float) -> bool:
    """np.allclose(a, b, atol=atol) for finite arrays, without its per-call overhead."""
    return bool((np.abs(a - b) <= atol + 1e-5 * np.abs(b)).all())


def _i32(name, a, tail):
    arr = np.ascontiguousarray(a, dtype=np.int32)
    if arr.ndim != 1 + len(tail) or arr.shape[1:] != tail:
        raise InputError(f"{name} must have shape (n{''.join(f', {t}' for t in tail)}), got {arr.shape}")
    return arr


def _f32(name, a, tail):
    arr = np.ascontiguousarray(a, dtype=np.float32)
    if arr.ndim != 1 + len(tail) or arr.shape[1:] != tail:
        raise InputError(f"{name} must have shape (n{''.join(f', {t}' for t in tail)}), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} has a non-finite value")
    return arr


@dataclass(eq=False)
class CageModel:
    """Everything about a hair cage that does not change while it is simulated.

    rest_positions (C, 3) f32; inv_mass (C,) f32 (0 for roots);
    edges (E, 2) i32 + edge_lengths (E,) f32 (stretch); bend_pairs (B, 2) i32 + bend_lengths (B,)
    (bending); faces (F, 3) i32 of the closed cage, outward, and rest_volume (m^3) (volume; F = 0
    turns it off); roots (R,) i32 with root_faces (R,) i32 into head_faces (Fh, 3) i32,
    root_bary (R, 3) f32 and root_offsets (R, 3) f32 (the offset in the face frame);
    tether_roots (C,) i32 (the vertex index of each vertex's nearest root, -1 for none) and
    tether_lengths (C,) f32; proxy_index (C, K) i32 and proxy_weight (C, K) f32 (each row: the
    cage vertices and MVC weights that reproduce the vertex's nearest hair Gaussian centre);
    sdf: the rest head's `HeadSDF`.
    """

    rest_positions: np.ndarray
    inv_mass: np.ndarray
    edges: np.ndarray
    edge_lengths: np.ndarray
    bend_pairs: np.ndarray
    bend_lengths: np.ndarray
    faces: np.ndarray
    rest_volume: float
    roots: np.ndarray
    head_faces: np.ndarray
    root_faces: np.ndarray
    root_bary: np.ndarray
    root_offsets: np.ndarray
    tether_roots: np.ndarray
    tether_lengths: np.ndarray
    proxy_index: np.ndarray
    proxy_weight: np.ndarray
    sdf: HeadSDF

    def __post_init__(self):
        self.rest_positions = _f32("rest_positions", self.rest_positions, (3,))
        c = len(self.rest_positions)
        self.inv_mass = _f32("inv_mass", self.inv_mass, ())
        self.edges = _i32("edges", self.edges, (2,))
        self.edge_lengths = _f32("edge_lengths", self.edge_lengths, ())
        self.bend_pairs = _i32("bend_pairs", self.bend_pairs, (2,))
        self.bend_lengths = _f32("bend_lengths", self.bend_lengths, ())
        self.faces = _i32("faces", self.faces, (3,))
        self.rest_volume = float(self.rest_volume)
        self.roots = _i32("roots", self.roots, ())
        self.head_faces = _i32("head_faces", self.head_faces, (3,))
        self.root_faces = _i32("root_faces", self.root_faces, ())
        self.root_bary = _f32("root_bary", self.root_bary, (3,))
        self.root_offsets = _f32("root_offsets", self.root_offsets, (3,))
        self.tether_roots = _i32("tether_roots", self.tether_roots, ())
        self.tether_lengths = _f32("tether_lengths", self.tether_lengths, ())
        self.proxy_index = np.ascontiguousarray(np.atleast_2d(self.proxy_index), dtype=np.int32)
        self.proxy_weight = np.ascontiguousarray(np.atleast_2d(self.proxy_weight), dtype=np.float32)
        if not isinstance(self.sdf, HeadSDF):
            raise InputError("sdf must be a HeadSDF")
        checks = [
            ("inv_mass", len(self.inv_mass), c), ("edge_lengths", len(self.edge_lengths), len(self.edges)),
            ("bend_lengths", len(self.bend_lengths), len(self.bend_pairs)),
            ("root_faces", len(self.root_faces), len(self.roots)),
            ("root_bary", len(self.root_bary), len(self.roots)),
            ("root_offsets", len(self.root_offsets), len(self.roots)),
            ("tether_roots", len(self.tether_roots), c), ("tether_lengths", len(self.tether_lengths), c),
            ("proxy_index", len(self.proxy_index), c), ("proxy_weight", len(self.proxy_weight), c),
        ]
        for name, got, want in checks:
            if got != want:
                raise InputError(f"{name} has {got} rows, expected {want}")
        if self.proxy_index.shape != self.proxy_weight.shape:
            raise InputError(f"proxy_index {self.proxy_index.shape} and proxy_weight "
                             f"{self.proxy_weight.shape} differ in shape")
        for name, idx, n in [("edges", self.edges, c), ("bend_pairs", self.bend_pairs, c),
                             ("faces", self.faces, c), ("roots", self.roots, c),
                             ("proxy_index", self.proxy_index, c),
                             ("root_faces", self.root_faces, len(self.head_faces))]:
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                raise InputError(f"{name} has an index outside 0..{n - 1}")
        if ((self.tether_roots < -1) | (self.tether_roots >= c)).any():
            raise InputError(f"tether_roots must be -1 or a vertex index below {c}")
        if len(self.roots) == 0:
            raise InputError("a hair cage needs at least one root vertex attached to the head")
        if (self.inv_mass[self.roots] != 0).any():
            raise InputError("root vertices must have inverse mass 0")
        if (self.inv_mass < 0).any():
            raise InputError("inverse masses must be >= 0")
        # per-frame constants of root_targets
        self._head_size = int(self.head_faces.max()) + 1 if self.head_faces.size else 0
        self._root_corners = self.head_faces[self.root_faces]                     # (R, 3)
        self._root_bary64 = self.root_bary.astype(np.float64)
        self._root_offsets64 = self.root_offsets.astype(np.float64)

    # --- sizes -------------------------------------------------------------------------------
    @property
    def num_vertices(self) -> int:
        return len(self.rest_positions)

    @property
    def free(self) -> np.ndarray:
        """(C,) bool: the simulated (non-root) vertices."""
        return self.inv_mass > 0

    def rest_state(self) -> CageState:
        return CageState(self.rest_positions.copy(), np.zeros_like(self.rest_positions))

    # --- kinematic input -----------------------------------------------------------------------
    def root_targets(self, head_vertices: np.ndarray) -> np.ndarray:
        """Posed head vertices (V, 3) -> root positions (R, 3) float32 (see module docstring).

        The face frames are written out here (e0 along the first edge, n the normal, b = e0 x n,
        as `rig.frames.triangle_frames`, which `root_targets_reference` uses): this runs every
        frame, and the general routine's ~25 array calls on (R, 3, 3) stacks cost ~2x more."""
        from avatarkit.rig.frames import MIN_EDGE, MIN_RELATIVE_HEIGHT

        v = np.asarray(head_vertices)
        self._check_head(v)
        c = v[self._root_corners].astype(np.float64)                             # (R, 3, 3)
        a = c[:, 0]
        d1 = c[:, 1] - a
        d2 = c[:, 2] - a
        len0 = np.sqrt(np.einsum("ri,ri->r", d1, d1))
        e0 = d1 / np.where(len0 > MIN_EDGE, len0, 1.0)[:, None]
        n = _cross(e0, d2)
        height = np.sqrt(np.einsum("ri,ri->r", n, n))
        flat = (len0 <= MIN_EDGE) | (height <= MIN_RELATIVE_HEIGHT * len0)
        n /= np.where(flat, 1.0, height)[:, None]
        o = self._root_offsets64
        # a degenerate face's frame is the identity (as triangle_frames gives it)
        turned = np.where(flat[:, None], o, o[:, :1] * e0 + o[:, 1:2] * n + o[:, 2:] * _cross(e0, n))
        return (np.einsum("rk,rkc->rc", self._root_bary64, c) + turned).astype(np.float32)

    def root_targets_reference(self, head_vertices: np.ndarray) -> np.ndarray:
        """`root_targets` through `rig.frames.triangle_frames` (the tests compare the two)."""
        from avatarkit.rig.frames import triangle_frames

        v = np.asarray(head_vertices)
        self._check_head(v)
        # gather the root faces' corners first: the head has thousands of vertices, roots ~100s
        corners = v[self.head_faces[self.root_faces]].astype(np.float64)          # (R, 3, 3)
        points = np.einsum("rk,rkc->rc", self.root_bary.astype(np.float64), corners)
        flat = np.arange(3 * len(corners)).reshape(-1, 3)
        _, rotations, _ = triangle_frames(corners.reshape(-1, 3), flat)        # (R, 3, 3)
        return (points + np.einsum("rij,rj->ri", rotations, self.root_offsets)).astype(np.float32)

    def _check_head(self, v: np.ndarray) -> None:
        if v.ndim != 2 or v.shape[1] != 3:
            raise InputError(f"head vertices must have shape (V, 3), got {v.shape}")
        if self._head_size > len(v):
            raise InputError(f"the cage's roots ride head faces over {self._head_size} "
                             f"vertices, but the head has {len(v)}")

    def head_frame(self, head_vertices: np.ndarray, transform: np.ndarray,
                   joint_transforms: np.ndarray | None = None) -> HeadFrame:
        """The solver's input for one frame: posed head vertices (V, 3), head joint (4, 4),
        optionally the transforms (J, 4, 4) of a `HeadSkin`'s joints."""
        return HeadFrame(self.root_targets(head_vertices), transform, joint_transforms)

    # --- construction --------------------------------------------------------------------------
    @classmethod
    def from_arrays(cls, rest_positions: np.ndarray, faces: np.ndarray, roots: np.ndarray,
                    head_vertices: np.ndarray, head_faces: np.ndarray, *,
                    proxy_points: np.ndarray | None = None, proxy_weights: np.ndarray | None = None,
                    proxy_k: int | None = None, attach_faces: np.ndarray | None = None,
                    sdf: HeadSDF | None = None, sdf_spacing: float = 0.0025,
                    tether_slack: float = 0.0) -> "CageModel":
        """Derive every table from a closed cage mesh and a rest head.

        rest_positions (C, 3), faces (F, 3) of the cage; roots (R,) vertex indices;
        head_vertices (V, 3), head_faces (Fh, 3) of the REST head; proxy_weights (C, C): row j
        reproduces vertex j's proxy point from the cage vertices (MVC weights of its nearest hair
        Gaussian's centre), kept as the `proxy_k` largest by magnitude and corrected to rebuild
        `proxy_points` (C, 3) exactly (see `sparsify_weights`); None makes every vertex its own
        proxy. attach_faces (Fa,): the head
        faces roots may attach to (default all: the nearest point of the whole head).
        """
        proxy_k = PROXY_K if proxy_k is None else proxy_k
        import scipy.sparse
        from scipy.sparse.csgraph import dijkstra
        import trimesh

        x = _f32("rest_positions", rest_positions, (3,)).astype(np.float64)
        f = _i32("faces", faces, (3,))
        c = len(x)
        roots = np.unique(_i32("roots", np.atleast_1d(roots), ()))
        if len(roots) == 0:
            raise InputError("no root vertices: the hair cage would not be attached to the head")
        if f.size == 0 or f.min() < 0 or f.max() >= c:
            raise InputError(f"cage faces must index the {c} cage vertices")
        if roots.min() < 0 or roots.max() >= c:
            raise InputError(f"root indices must lie in 0..{c - 1}")
        mesh = trimesh.Trimesh(x, f, process=False)

        inv_mass = np.ones(c, np.float32)
        inv_mass[roots] = 0
        free = inv_mass > 0

        edges = np.asarray(mesh.edges_unique, dtype=np.int64)
        edges = edges[free[edges].any(axis=1)]  # a constraint between two roots never acts
        edge_lengths = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
        if (edge_lengths <= 0).any():
            raise InputError("the cage has a zero-length edge")
        bends = np.sort(np.asarray(mesh.face_adjacency_unshared, dtype=np.int64), axis=1)
        bends = np.unique(bends[bends[:, 0] != bends[:, 1]], axis=0)
        bends = bends[free[bends].any(axis=1)]
        bend_lengths = np.linalg.norm(x[bends[:, 0]] - x[bends[:, 1]], axis=1)

        if mesh.is_watertight and mesh.is_winding_consistent:
            volume = float(mesh.volume)
            vol_faces = f if volume > 0 else f[:, ::-1]
            volume = abs(volume)
        else:  # an open cage has no volume to keep
            vol_faces, volume = np.zeros((0, 3), np.int32), 0.0

        # Tethers: geodesic (along edges) distance to the nearest root: never shorter than
        # any inextensible deformation of the cage, so it only acts against real stretching.
        all_edges = np.asarray(mesh.edges_unique, dtype=np.int64)
        lengths = np.linalg.norm(x[all_edges[:, 0]] - x[all_edges[:, 1]], axis=1)
        graph = scipy.sparse.coo_matrix((lengths, (all_edges[:, 0], all_edges[:, 1])), shape=(c, c))
        dist, _, sources = dijkstra(graph, directed=False, indices=roots, min_only=True,
                                    return_predecessors=True)
        reach = np.isfinite(dist) & free
        # Constraint order: outward from the roots in bands one (median) edge long, pseudo-random
        # within a band. Gauss-Seidel then carries a root's move down the whole cage in one sweep
        # (a hanging cage held from its top converges like a chain solved top-down), and
        # consecutive constraints of a band rarely share a vertex, so the CPU overlaps their
        # arithmetic in the serial sweep (the sorted order trimesh gives is ~2x slower).
        rng = np.random.default_rng(0x5EED)
        depth = np.where(np.isfinite(dist), dist, np.nanmax(np.where(np.isfinite(dist), dist, np.nan)))
        band = float(np.median(lengths))
        edges, edge_lengths = _outward(rng, edges, edge_lengths, depth, band)
        bends, bend_lengths = _outward(rng, bends, bend_lengths, depth, band)
        vol_faces = vol_faces[rng.permutation(len(vol_faces))]
        tether_roots = np.where(reach, sources, -1).astype(np.int32)
        tether_lengths = np.where(reach, dist * (1.0 + tether_slack), 0.0)

        hv = np.asarray(head_vertices, dtype=np.float64)
        hf = _i32("head_faces", head_faces, (3,))
        if hv.ndim != 2 or hv.shape[1] != 3 or hf.size == 0 or hf.max() >= len(hv):
            raise InputError("head_vertices (V, 3) and head_faces (F, 3) must describe a mesh")
        root_faces, root_bary, root_offsets = _attach(x[roots], hv, hf, attach_faces)

        if proxy_weights is None:
            proxy_index = np.arange(c, dtype=np.int32)[:, None]
            proxy_weight = np.ones((c, 1), np.float32)
        else:
            proxy_index, proxy_weight = sparsify_weights(proxy_weights, proxy_k, proxy_points, x)
        if sdf is None:
            sdf = HeadSDF.build(hv, hf, spacing=sdf_spacing)
        return cls(x, inv_mass, edges, edge_lengths, bends, bend_lengths, vol_faces, volume,
                   roots, hf, root_faces, root_bary, root_offsets, tether_roots, tether_lengths,
                   proxy_index, proxy_weight, sdf)

    @classmethod
    def build(cls, cage, hair, head_model, rest_head_vertices: np.ndarray | None = None, *,
              roots: np.ndarray | None = None, root_distance: float = 0.015, min_roots: int = 3,
              root_region: str = "scalp", proxy_k: int | None = None, sdf: HeadSDF | None = None,
              sdf_spacing: float = 0.0025, tether_slack: float = 0.0) -> "CageModel":
        """A model for a hair cage over a head.

        cage: has `vertices` (C, 3) and `faces` (F, 3) (avatarkit.cage.Cage); hair: the hair
        GaussianSet the cage was built around; head_model: has `faces` and `regions`
        (avatarkit.head.HeadModel); rest_head_vertices (V, 3): the head the hair was fitted to
        (default `head_model.v_template`).
        Roots (unless given) are chosen by `select_roots` (cage vertices over the `root_region`
        faces that, or whose nearest hair Gaussian, lie within `root_distance` of the head);
        they attach to those faces.
        """
        proxy_k = PROXY_K if proxy_k is None else proxy_k
        from scipy.spatial import cKDTree

        from avatarkit.cage.mvc import mvc_weights

        cv = np.asarray(cage.vertices, dtype=np.float64)
        cf = np.asarray(cage.faces, dtype=np.int64)
        hv = np.asarray(head_model.v_template if rest_head_vertices is None else rest_head_vertices,
                        dtype=np.float64)
        hf = np.asarray(head_model.faces, dtype=np.int64)
        regions = getattr(head_model, "regions", {}) or {}
        if root_region in regions:
            in_region = np.zeros(len(hv), bool)
            in_region[np.asarray(regions[root_region])] = True
            attach = np.flatnonzero(in_region[hf].all(axis=1))
            if len(attach) == 0:
                raise InputError(f"the head's {root_region!r} region has no whole faces")
        else:
            attach = np.arange(len(hf))
        if sdf is None:
            sdf = HeadSDF.build(hv, hf, spacing=sdf_spacing)
        means = np.asarray(hair.means, dtype=np.float64)
        if len(means) == 0:
            raise InputError("the hair GaussianSet is empty")
        _, nearest = cKDTree(means).query(cv)
        if roots is None:
            roots = select_roots(cv, hv, hf, attach, sdf, root_distance, min_roots, means[nearest])
        weights = mvc_weights(means[nearest], cv, cf)
        return cls.from_arrays(cv, cf, roots, hv, hf, proxy_points=means[nearest],
                               proxy_weights=weights, proxy_k=proxy_k,
                               attach_faces=attach, sdf=sdf, sdf_spacing=sdf_spacing,
                               tether_slack=tether_slack)


def select_roots(cage_vertices: np.ndarray, head_vertices: np.ndarray, head_faces: np.ndarray,
                 region_faces: np.ndarray, sdf: HeadSDF, root_distance: float = 0.015,
                 min_roots: int = 3, proxy_points: np.ndarray | None = None) -> np.ndarray:
    """Cage vertices (C, 3) that become kinematic roots.

    A vertex is a root when its nearest head surface is in `region_faces` (the scalp) and it,
    or its proxy point (C, 3) (the hair Gaussian nearest to it), lies inside the rest head or
    within `root_distance` of it. A cage wraps its hair with a margin and is coarse (cells of
    a few cm for ~500 vertices), so the shell over the scalp sits a few cm inside and outside
    the skull; what it holds is hair lying on the scalp, which is attached there, not swinging.
    Cage vertices near the neck or face (where long hair falls past them) are not over the
    scalp and stay free. If fewer than `min_roots` qualify, the `min_roots` vertices nearest
    the region are used.
    """
    from avatarkit.rig.nearest import nearest_faces

    cv = np.asarray(cage_vertices, dtype=np.float64)
    _, to_region = nearest_faces(cv, head_vertices, head_faces[region_faces])
    _, to_head = nearest_faces(cv, head_vertices, head_faces)
    near, _ = sdf.query(cv)
    if proxy_points is not None:
        near = np.minimum(near, sdf.query(proxy_points)[0])
    over_region = to_region <= to_head + 1e-4
    roots = np.flatnonzero(over_region & (near <= root_distance))
    if len(roots) < min_roots:
        roots = np.argsort(to_region, kind="stable")[:min_roots]
    return roots


def _outward(rng, pairs, lengths, depth, band):
    """Pairs (n, 2) and their lengths in bands of `band` of the pair's mean root distance,
    shuffled within each band."""
    order = rng.permutation(len(pairs))
    if os.environ.get("AK_ORDER") == "random":
        return pairs[order], lengths[order]
    key = np.floor(depth[pairs[order]].mean(axis=1) / band)
    order = order[np.argsort(key, kind="stable")]
    return pairs[order], lengths[order]


def sparsify_weights(weights: np.ndarray, k: int, points: np.ndarray | None = None,
                     vertices: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Dense weights (P, C) -> the k largest in magnitude per row: index (P, k) i32, weight (P, k)
    f32. Mean value coordinates fall off slowly (k = 16 of a 500-vertex cage carry ~2 cm of
    error), so the kept weights are corrected by the smallest change that makes them sum to 1
    and rebuild `points` (P, 3) exactly from `vertices` (C, 3) (linear precision at rest): the
    proxy is then exactly its Gaussian at rest, with no offset; without points they are only
    renormalised to sum 1 (translation invariance)."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 2 or not np.isfinite(w).all():
        raise InputError(f"proxy weights must be a finite (P, C) matrix, got shape {w.shape}")
    k = int(min(max(k, 1), w.shape[1]))
    idx = np.argsort(-np.abs(w), axis=1, kind="stable")[:, :k]
    top = np.take_along_axis(w, idx, axis=1)
    if points is None or vertices is None:
        total = top.sum(axis=1, keepdims=True)
        if (np.abs(total) < 1e-6).any():
            raise InputError("proxy weights of some row sum to ~0: not barycentric coordinates")
        return idx.astype(np.int32), (top / total).astype(np.float32)
    x = np.asarray(vertices, dtype=np.float64)[idx]                            # (P, k, 3)
    p = np.asarray(points, dtype=np.float64)
    # min |dw|^2  s.t.  A (w + dw) = [p; 1]  with A = [x^T; 1^T] (4 x k):  dw = A^T (A A^T)^-1 r
    a = np.concatenate([x.transpose(0, 2, 1), np.ones((len(idx), 1, k))], axis=1)  # (P, 4, k)
    r = np.concatenate([p - np.einsum("pk,pkc->pc", top, x), 1 - top.sum(axis=1, keepdims=True)], axis=1)
    gram = a @ a.transpose(0, 2, 1)
    scale = np.trace(gram, axis1=1, axis2=2)[:, None, None]
    mult = np.linalg.solve(gram + 1e-12 * scale * np.eye(4), r[..., None])[..., 0]
    return idx.astype(np.int32), (top + np.einsum("pjk,pj->pk", a, mult)).astype(np.float32)


def _attach(points: np.ndarray, hv: np.ndarray, hf: np.ndarray, attach_faces=None):
    """Nearest point on the head (restricted to attach_faces) of each point (R, 3): face id into
    hf, barycentric coordinates, and the offset point - nearest in that face's frame."""
    import trimesh

    from avatarkit.rig.frames import degenerate_faces, triangle_frames
    from avatarkit.rig.nearest import nearest_faces

    cand = np.arange(len(hf)) if attach_faces is None else np.asarray(attach_faces, dtype=np.int64)
    cand = cand[~degenerate_faces(hv, hf[cand])]
    if len(cand) == 0:
        raise InputError("no usable head faces to attach the hair roots to")
    tri, _ = nearest_faces(points, hv, hf[cand])
    face = cand[tri]
    corners = hv[hf[face]]                                                   # (R, 3, 3)
    closest = trimesh.triangles.closest_point(corners, points)
    bary = trimesh.triangles.points_to_barycentric(corners, closest)
    _, rotations, _ = triangle_frames(hv, hf[face])
    # Re-evaluate the attachment point from the barycentrics so the offset absorbs their rounding.
    on_face = np.einsum("rk,rkc->rc", bary, corners)
    offsets = np.einsum("rji,rj->ri", rotations, points - on_face)            # R^T (p - q)
    return face.astype(np.int32), bary.astype(np.float32), offsets.astype(np.float32)
