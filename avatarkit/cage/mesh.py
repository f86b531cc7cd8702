"""`Cage`: a closed triangle mesh around the hair, its topology checks and its files.

A usable cage is watertight (every edge shared by exactly two faces), consistently oriented with
normals pointing out (positive signed volume), manifold at every vertex (one fan of faces around
it), uses every vertex, and has no degenerate (near zero-area) faces. `check_cage` reports all of
these, plus how deep given points sit inside (see `avatarkit.cage.inside`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.fileio import atomic_path

#: file extensions a cage can be saved to / loaded from (all keep the vertex order)
CAGE_FORMATS = (".ply", ".obj", ".off")
#: a face whose area is below this fraction of (mean edge length)^2 counts as degenerate
DEGENERATE_AREA = 1e-4


@dataclass(eq=False)
class Cage:
    """A closed triangle mesh: vertices (C, 3) float32 metres, faces (M, 3) int32, outward normals.

    `info` says how a built cage was made (voxel size, margin, attempt); it is not saved to files.
    """

    vertices: np.ndarray  # (C, 3) float32
    faces: np.ndarray     # (M, 3) int32
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        try:
            v = np.ascontiguousarray(self.vertices, dtype=np.float32)
            f = np.asarray(self.faces)
        except (TypeError, ValueError) as e:
            raise InputError(f"cage arrays are not numeric: {e}") from None
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise InputError(f"cage vertices must have shape (C, 3) with C >= 4, got {v.shape}")
        if not np.isfinite(v).all():
            raise InputError("cage vertices have a non-finite value")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4:
            raise InputError(f"cage faces must have shape (M, 3) with M >= 4, got {f.shape}")
        if not np.issubdtype(f.dtype, np.integer):
            if not np.array_equal(f, np.round(f)):
                raise InputError("cage faces must hold integer vertex indices")
        f = np.ascontiguousarray(f, dtype=np.int64)
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"cage faces index vertices outside 0..{len(v) - 1}")
        self.vertices = v
        self.faces = f.astype(np.int32)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    def edges(self) -> np.ndarray:
        """Unique undirected edges (E, 2) int32, each sorted (low, high)."""
        return mesh_edges(self.faces)[0]

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices.astype(np.float64), self.faces, process=False)

    def volume(self) -> float:
        """Signed volume (positive when the faces point outward)."""
        return signed_volume(self.vertices, self.faces)

    def replace_vertices(self, vertices: np.ndarray) -> "Cage":
        """The same connectivity with new vertex positions (C, 3), e.g. a deformed frame."""
        return Cage(vertices, self.faces, dict(self.info))

    def __repr__(self) -> str:
        return f"Cage(vertices={len(self.vertices)}, faces={len(self.faces)})"


def mesh_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """faces (M, 3) -> (edges (E, 2) int32 sorted pairs, face_edges (M, 3) int32) where
    face_edges[f, i] is the edge opposite corner i (between corners i+1 and i+2)."""
    f = np.asarray(faces, dtype=np.int64)
    pairs = np.stack([f[:, [1, 2]], f[:, [2, 0]], f[:, [0, 1]]], axis=1).reshape(-1, 2)  # (3M, 2)
    pairs = np.sort(pairs, axis=1)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    return edges.astype(np.int32), inverse.reshape(-1, 3).astype(np.int32)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    v = np.asarray(vertices, np.float64)
    tri = v[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


@dataclass
class CageCheck:
    """What `check_cage` found. `ok` is True when `problems` is empty."""

    watertight: bool
    oriented: bool           # every edge is used once in each direction
    outward: bool            # positive signed volume
    manifold: bool           # one fan of faces around every vertex
    degenerate_faces: int
    unused_vertices: int
    components: int
    min_angle_deg: float
    min_depth: float | None = None   # smallest depth of the points inside (negative: outside)
    points_outside: int = 0
    points_shallow: int = 0          # inside but closer than the margin to the surface
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def _vertex_manifold(faces: np.ndarray, n_vertices: int) -> bool:
    """True when the faces around every vertex form one fan (connected through shared edges).

    Corners (face, vertex) are nodes; two corners of the same vertex are joined when their faces
    share an edge through that vertex. A manifold vertex's corners form one component.
    """
    f = np.asarray(faces, dtype=np.int64)
    m = len(f)
    corner_vertex = f.ravel()                               # corner id = 3 * face + slot
    # directed half-edges (a -> b) of each face; the twin (b -> a) is in the neighbouring face
    a = f.ravel()
    b = np.roll(f, -1, axis=1).ravel()
    key = a * n_vertices + b
    twin_key = b * n_vertices + a
    order = np.argsort(key)
    pos = np.searchsorted(key[order], twin_key)
    pos = np.clip(pos, 0, len(key) - 1)
    found = key[order][pos] == twin_key
    he = np.arange(3 * m)
    twin = np.where(found, order[pos], -1)
    # half-edge h = (a -> b) in face F starts at corner h (vertex a) and ends at the next corner
    # (vertex b). Its twin (b -> a) in face G starts at b: join corner(b in F) with corner(b in G),
    # and corner(a in F) with the corner where the twin ends (a in G).
    face_of = he // 3
    nxt = face_of * 3 + (he % 3 + 1) % 3
    ok = twin >= 0
    tw = twin[ok]
    tw_next = (tw // 3) * 3 + (tw % 3 + 1) % 3
    rows = np.concatenate([nxt[ok], he[ok]])
    cols = np.concatenate([tw, tw_next])
    graph = scipy.sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * m, 3 * m))
    n_comp, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    used = np.unique(corner_vertex)
    # components per vertex: count distinct labels among its corners
    pairs = np.unique(np.stack([corner_vertex, labels], axis=1), axis=0)
    per_vertex = np.bincount(pairs[:, 0], minlength=n_vertices)
    return bool((per_vertex[used] == 1).all())


def check_cage(cage: Cage, points: np.ndarray | None = None, margin: float = 0.0) -> CageCheck:
    """Check the guarantees of a cage; with `points` (P, 3), also that each lies inside at a depth
    of at least `margin` (metres). Never raises for a bad cage: read `problems`."""
    from avatarkit.cage.inside import clipped_depth

    v = cage.vertices.astype(np.float64)
    f = cage.faces.astype(np.int64)
    problems: list[str] = []
    # orientation and watertightness from directed half-edges
    a = f.ravel()
    b = np.roll(f, -1, axis=1).ravel()
    n = len(v)
    directed = a * n + b
    uniq, counts = np.unique(directed, return_counts=True)
    reverse_present = np.isin(b * n + a, uniq)
    edges, _ = mesh_edges(f)
    undirected_counts = np.unique(np.sort(np.stack([a, b], 1), axis=1), axis=0, return_counts=True)[1]
    watertight = bool((undirected_counts == 2).all())
    oriented = bool((counts == 1).all() and reverse_present.all())
    if not watertight:
        problems.append(f"not watertight: {(undirected_counts != 2).sum()} edges are not shared by exactly two faces")
    elif not oriented:
        problems.append("faces are not consistently oriented")
    vol = signed_volume(v, f)
    outward = vol > 0
    if not outward:
        problems.append(f"faces point inward (signed volume {vol:.3g})")
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    areas = face_areas(v, f)
    mean_edge = float(np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1).mean())
    degenerate = int((repeated | (areas < DEGENERATE_AREA * mean_edge ** 2)).sum())
    if degenerate:
        problems.append(f"{degenerate} degenerate faces")
    manifold = watertight and _vertex_manifold(f, n)
    if watertight and not manifold:
        problems.append("not manifold: some vertex joins two separate fans of faces")
    unused = int(n - len(np.unique(f)))
    if unused:
        problems.append(f"{unused} vertices are not used by any face")
    graph = scipy.sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    components = int(scipy.sparse.csgraph.connected_components(graph, directed=False)[0]) - unused
    tri = v[f]
    angles = []
    for i in range(3):
        e1 = tri[:, (i + 1) % 3] - tri[:, i]
        e2 = tri[:, (i + 2) % 3] - tri[:, i]
        cos = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    check = CageCheck(watertight, oriented, outward, manifold, degenerate, unused, components,
                      float(np.min(angles)), problems=problems)
    if points is not None and len(points):
        if not (watertight and oriented):
            problems.append("points not checked: the cage is not closed")
            return check
        depth = clipped_depth(points, v, f, radius=max(float(margin), 0.25 * mean_edge))
        check.min_depth = float(depth.min())
        check.points_outside = int((depth <= 0).sum())
        check.points_shallow = int(((depth > 0) & (depth < margin)).sum())
        if check.points_outside:
            problems.append(f"{check.points_outside} of {len(depth)} points lie outside the cage")
        if check.points_shallow:
            problems.append(f"{check.points_shallow} of {len(depth)} points are inside but closer "
                            f"than the margin {margin:.4g} to the surface")
    return check


# --- files ---------------------------------------------------------------------------------

def save_cage(path: str | os.PathLike, cage: Cage) -> None:
    """Write a cage as PLY (binary), OBJ or OFF, chosen by the extension; atomic."""
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in CAGE_FORMATS:
        raise OutputError(f"unknown cage format {ext!r}; use one of {', '.join(CAGE_FORMATS)}", path)
    mesh = cage.to_trimesh()
    with atomic_path(path) as tmp:
        if ext == ".obj":
            data = mesh.export(file_type="obj", include_normals=False, include_texture=False)
        else:
            data = mesh.export(file_type=ext[1:])
        with open(tmp, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)


def load_cage(path: str | os.PathLike) -> Cage:
    """Read a triangle mesh (PLY, OBJ, OFF) as a Cage, keeping its vertex order."""
    import trimesh

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in CAGE_FORMATS:
        raise InputError(f"unknown cage format {ext!r}; use one of {', '.join(CAGE_FORMATS)}", path)
    if not os.path.isfile(path):
        raise InputError("file not found", path)
    try:
        mesh = trimesh.load(path, force="mesh", process=False, maintain_order=True)
    except Exception as e:  # trimesh raises many types for broken files
        raise FormatError(f"cannot read mesh: {e}", path) from None
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) < 4:
        raise FormatError(f"no closed triangle mesh in the file (faces {faces.shape})", path)
    try:
        return Cage(np.asarray(mesh.vertices), faces)
    except InputError as e:
        raise FormatError(e.message, path) from None
