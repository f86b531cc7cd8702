"""The built-in lifter's bald head: flat discs on the fitted head's triangles, coloured from the
bald image where the camera sees them and by a screened harmonic fill elsewhere.

`n_bald` flat discs sampled on the fitted head's triangles (area-weighted, the face and
eyes `face_density` times denser than the back of the head), lying in their triangle's plane,
sized so neighbours overlap (with `INSET`, off, set in from the surface so that their outline
falls on the mesh's: `inset_depth`); with `EYE_DENSITY` above 1 (off), the eyes' surroundings (the
eyeballs' fronts and the lids, `_eye_area_faces`) that many times denser again, with smaller
discs, added to the n (the other discs stay as they were: `sample_bald`). Colour: the bald image sampled (bilinear) at each disc's
projection where the disc is visible from the input camera (its depth within `DEPTH_TOL` of
the renderer's depth map of the discs, facing the camera, and landing on skin in the bald
image's labels; neck discs also on body pixels). Unseen discs get a screened harmonic fill
on their k-nearest-neighbour graph: the colour of the nearest seen skin diffuses over the
surface and fades to the skin model's mean colour a few centimetres away (the back of the
head). Skin discs seen at a grazing angle (facing the camera less than `GRAZING`) take the
photo only in part, blended toward that fill made from the discs seen head-on (`photo_weight`):
their pixels are mostly the silhouette's edge. Eyeballs: seen through the lids, the photo; elsewhere iris (the photo's colour at the
eye landmarks) or sclera (the colour of the sclera the photo shows, `sclera_colour`). Mouth interior, and the unseen discs on the lips' faces that the jaw
stretches open (`_opening_faces`): a dark red. Extras: `binding` (the sampled triangle,
int32) and `part` (uint8: 0 skin, 1 eye, 2 mouth interior).
"""
from __future__ import annotations

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.fit import HeadFit
from avatarkit.recon.image_sampling import lookup, sample_image
from avatarkit.recon.visibility import depth_map, seen_from
from avatarkit.rotations import matrix_to_quat
from avatarkit.recon import visibility as _visibility  # its switches read at call time

#: bald disc radius = COVERAGE x the radius that would tile its share of the surface
COVERAGE = 1.5
FLATNESS = 0.15
#: a seen skin disc facing the camera less than this (cosine of the angle between its normal and
#: the way to the camera: 0.5 is 60 degrees) takes the photo only in part: its colour is
#: blended toward what the fill gives from the discs seen head-on, linearly from all photo at
#: GRAZING to none at `visibility.MIN_FACING`. Seen that obliquely a disc's pixel is mostly the
#: silhouette's edge: the ear's rim, the wall behind, the collar (the pale patch below the ear)
GRAZING = 0.5
SCLERA_RGB = (0.86, 0.83, 0.8)
#: seen sclera discs needed before their colour replaces SCLERA_RGB (`sclera_colour`)
SCLERA_SAMPLES = 12
MOUTH_RGB = (0.32, 0.12, 0.12)
PART_SKIN, PART_EYE, PART_MOUTH = 0, 1, 2
#: the eyes' surroundings (`_eye_area_faces`: the faces in front of an eyeball's centre within
#: EYE_AREA_REACH of it: the eyeballs' fronts, the lids, the lash lines, the corners) are
#: sampled this many times denser than the rest of the face, their discs sqrt of it smaller,
#: added to n (1: as dense as the face, off). At the face's density a disc there is ~7 px wide
#: at 480 px, as wide as the iris: the pupil, the iris, the white and the lash line blur into
#: one pale bluish patch. 2 or 4 sharpen the eyes and gain on both shared clips with the
#: refined tracking (eye box +0.2-0.5 dB), but with the landmark fit's poses (a pixel or two
#: off) the sharper eyes cost grey's eye box 0.04 dB (2) / 0.46 dB (4), and the synthetic
#: turning video's profile gain moved +3.22 -> +3.17: off (session 17, docs/video-build.md
#: "The eyes in the video build")
EYE_DENSITY = 1.0
EYE_AREA_REACH = 0.018
#: a lips face whose vertices' jaw weights differ by this much opens with the jaw (`_opening_faces`)
OPENING_SPREAD = 0.5
#: a point of the head's surface that the discs cover with less than this alpha (their opacities
#: composited where they overlap it, seen head-on: `surface_coverage`) gets an extra disc
#: (`fill_holes`; None: none). The discs are drawn at random (independently), so by chance some
#: patches a disc wide are left thin: seen head-on at 512-768 px the face layer's alpha fell to
#: 0.4-0.9 there (the bob's video build: 3.5 % of the face's pixels below 0.95 at 768 px), and the
#: back of the head showed through it as specks wherever its colour differs from the face's (the
#: video build's scalp fill, `multiview.SCALP_FILL`: the hair's dark colour). At 192 px the
#: renderer's dilation blurs them shut. docs/video-build.md, "The face's holes (session 22)"
HOLE_ALPHA: float | None = 0.95
#: surface points per disc where `fill_holes` measures the coverage, and its rounds (each adds
#: discs at the thinnest points, at least a disc's share of the surface apart, then measures again)
HOLE_PROBES = 2
HOLE_ROUNDS = 3
#: the opacity `surface_coverage` counts for every disc (the discs' are drawn in [0.95, 1.0])
HOLE_OPACITY = 0.95
#: the extra discs' radius as a share of the one the drawn discs have on the same face: a hole is
#: smaller than a disc, and a disc of the full size spreads the one colour it takes over its
#: neighbours' (the sample portrait's front view: 28.07 dB without the fill, 27.98 with discs of
#: the full size, 28.19 at 0.7)
HOLE_SIZE = 0.7
#: True: `fill_holes` measures with the slow, obvious reference (`surface_coverage` over every
#: probe, `_spread_reference`) instead of the fast path (`thin_coverage`, `_spread`); the discs
#: are bit for bit the same (tests/test_bald_holes.py compares them), only slower
HOLE_REFERENCE = False
#: `thin_coverage`'s first pass: the alpha of a probe's `HOLE_FIRST` nearest discs alone (a subset
#: of the k nearest `surface_coverage` composites, so never more than its alpha); a probe whose
#: first pass already reaches the threshold by more than `HOLE_MARGIN` (far above the 1e-15 the
#: products' rounding can differ by) is covered, and only the others get the exact measure (the
#: exact one point by point: the discs added and their order are the reference's, bit for bit)
HOLE_FIRST = 8
HOLE_MARGIN = 1e-9
#: the discs' centres are set in from the head's surface, along their face's inward normal, by
#: `inset_depth`: INSET x the face's disc sigma (the radius `_discs_on` gives it before its
#: random spread) plus the renderer's dilation's part at the input camera's pixel (None: on the
#: surface). Why: at the outline several discs stand edge-on or tilted along one line of sight,
#: each at its full opacity, and a flat disc tangent to a curved surface stands out of it by
#: t^2 / 2R at t from its centre; their composite alpha passes 0.5 beyond the surface. A sphere
#: of discs drawn as `sample_bald` draws them (COVERAGE 1.5, FLATNESS 0.15, the hole fill,
#: opacity 0.95-1), radius R 30-100 mm, disc sigma 3.3-7.5 mm, seen at 1536 px (the dilation's
#: part gone): the 0.5 outline lies 0.41-0.64 sigma outside it (0.41-0.50 for R / sigma 9-15,
#: a head's; the tighter the curve the more): 0.45 puts it on the surface. Every build's outline
#: stands 1-2 px beyond the head's (the mesh subject's neck 49.9 px wide against the truth's 45.9
#: at 192 px): a haloed, fattened head. Off (session 23, docs/video-build.md "The bald layer's
#: outline (session 23)"): the mesh subject (a hard-edged head, as a person's) gains 0.8-1.4 dB
#: in every view of both builds and the sample portrait's front view +0.12 dB, but the sample
#: avatar's and the bob's truths are themselves discs whose outline stands out as the build's
#: did, and the sample avatar's profile gain falls +3.47 -> +1.97 (its video build -4 dB at
#: +-90). 0.45 turns it on
INSET: float | None = None
#: the dilation's part (the renderer's 0.3 px^2 widens every splat at full opacity, so a stack
#: of them reaches further): INSET_PIXEL x p^2 / (sigma + p / 2), p the input camera's pixel
#: (metres at the head's depth). The same spheres at 192 and 384 px (p / sigma 0.19-0.67): the
#: outline 0.26-0.75 p further out than at 1536 px; never more than one pixel (a stack of splats
#: no wider than the dilation passes 0.5 about 2.2 of its 0.55 px sigmas out, ~1.2 px, the
#: discs' own part included). At the input's resolution the outline falls on the surface; seen
#: much finer it lies that much (under a pixel of the input's) inside
INSET_PIXEL = 1.5
#: the head model's regions whose discs stay on the surface ("eyes": the eyeballs and their
#: surroundings, `_eye_area_faces`: the lids). Where two surfaces meet in a crease (the closed
#: lips, a lid on its eyeball) setting both in opens a gap the mouth's or the eye's inside shows
#: through: the synthetic head's lift, face inside its outline 30.13 dB -> 28.93 with them set in
#: (a dark seam between the lips, the lids' edges), 30.04 kept
INSET_KEEP = ("lips", "mouth_interior", "eyes")


def propagate_colors(points: np.ndarray, colors: np.ndarray, known: np.ndarray, fallback,
                     k: int = 8, reach: float = 0.03) -> np.ndarray:
    """Fill unknown colours (N, 3) over the k-nearest-neighbour graph of points (N, 3):
    the screened harmonic solution (L + s I) c = s fallback on the unknown nodes, the known ones
    fixed. Known colour fades into `fallback` about as exp(-distance / reach) (metres) along a
    sampled surface."""
    from scipy import sparse
    from scipy.sparse.linalg import splu
    from scipy.spatial import cKDTree

    pts = np.asarray(points, np.float64)
    out = np.asarray(colors, np.float64).copy()
    known = np.asarray(known, bool)
    unknown = np.flatnonzero(~known)
    fb = np.broadcast_to(np.asarray(fallback, np.float64), (3,))
    if len(unknown) == 0:
        return out.astype(np.float32)
    if not known.any() or len(pts) < 2:
        out[unknown] = fb
        return out.astype(np.float32)
    kk = min(k + 1, len(pts))
    dist, nb = cKDTree(pts).query(pts, k=kk)
    dist, nb = dist[:, 1:], nb[:, 1:]
    n = len(pts)
    rows = np.repeat(np.arange(n), kk - 1)
    a = sparse.coo_matrix((np.ones(len(rows)), (rows, nb.ravel())), shape=(n, n)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64)                  # symmetric adjacency
    deg = np.asarray(a.sum(axis=1)).ravel()
    lap = sparse.diags(deg) - a
    # On a surface sampled this way the graph Laplacian is about (sum_j r_j^2 / 4) times the
    # continuous one, so this screening makes colour fade as exp(-distance / reach).
    mu = float(np.mean((dist ** 2).sum(axis=1))) / (4.0 * reach ** 2)
    luu = lap[unknown][:, unknown] + sparse.diags(np.full(len(unknown), mu))
    kn = np.flatnonzero(known)
    rhs = -(lap[unknown][:, kn] @ out[kn]) + mu * fb[None]
    out[unknown] = splu(luu.tocsc()).solve(rhs)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def photo_weight(facing: np.ndarray) -> np.ndarray:
    """(N,) share of the photo in a seen skin disc's colour, from its facing (N,) (`GRAZING`):
    1 from GRAZING up, 0 at `visibility.MIN_FACING` and below, linear between."""
    low = _visibility.MIN_FACING
    return np.clip((np.asarray(facing, np.float64) - low) / (GRAZING - low), 0.0, 1.0)


def _face_parts(model) -> np.ndarray:
    """(F,) uint8 part of each head face: eye (2 of 3 vertices on an eyeball), mouth interior, skin."""
    f = model.faces
    part = np.zeros(len(f), np.uint8)
    if "mouth_interior" in model.regions:
        part[model.region_mask("mouth_interior")[f].sum(axis=1) >= 2] = PART_MOUTH
    if "eyes" in model.regions:
        part[model.region_mask("eyes")[f].sum(axis=1) >= 2] = PART_EYE
    return part


def _opening_faces(model) -> np.ndarray:
    """(F,) bool: the lips' and mouth's faces that open with the jaw: their vertices' skinning
    weights to the jaw differ by at least `OPENING_SPREAD`, so the jaw stretches them across
    the parted lips (the template's: 45 faces, 148 mm^2 at rest, 1009 mm^2 at 0.25 rad)."""
    from avatarkit.face.fit import JAW_JOINT

    f = model.faces
    if model.weights.shape[1] <= JAW_JOINT:
        return np.zeros(len(f), bool)
    mouth = np.zeros(model.num_vertices, bool)
    for region in ("lips", "mouth_interior"):
        if region in model.regions:
            mouth |= model.region_mask(region)
    w = np.asarray(model.weights[:, JAW_JOINT], np.float64)[f]
    return (mouth[f].sum(axis=1) >= 2) & (w.max(axis=1) - w.min(axis=1) >= OPENING_SPREAD)


def _face_weights(model) -> np.ndarray:
    """(F,) bool: faces in front of the ears (the face region, eyes, mouth) are sampled denser."""
    f = model.faces
    dense = np.zeros(len(f), bool)
    for region in ("face", "eyes", "lips", "mouth_interior"):
        if region in model.regions:
            dense |= model.region_mask(region)[f].sum(axis=1) >= 2
    return dense


def _eye_area_faces(model, vertices: np.ndarray, reach: float | None = None) -> np.ndarray:
    """(F,) bool: the faces whose centroid lies within `reach` (metres) of an eyeball's centre
    and in front of it (+Z, where the face looks) on the rest head `vertices` (V, 3): the
    eyeballs' fronts, the lids, the lash lines, the corners (the eyeballs' backs are hidden)."""
    reach = EYE_AREA_REACH if reach is None else reach
    v = np.asarray(vertices, np.float64)
    faces = np.asarray(model.faces)
    if model.weights.shape[1] < 5:
        return np.zeros(len(faces), bool)
    w = np.asarray(model.weights, np.float64)
    centroid = v[faces].mean(axis=1)
    out = np.zeros(len(faces), bool)
    for j in (3, 4):
        on = w[:, j] > 0.5
        if not on.any():
            continue
        c = v[on].mean(axis=0)                     # the eyeball's centre: its vertices' mean
        d = centroid - c
        out |= (np.linalg.norm(d, axis=1) < reach) & (d[:, 2] > 0)
    return out


def _discs_on(v: np.ndarray, faces: np.ndarray, ids: np.ndarray, share: np.ndarray, rng: np.random.Generator):
    """Discs on the faces `ids` (k,) of the mesh (v (V, 3), faces (F, 3)), each covering `share`
    (k,) m^2 of the surface: (points (k, 3), quats (k, 4), scales (k, 3), normals (k, 3))."""
    from avatarkit.rig.frames import points_on_triangles, triangle_frames

    n = len(ids)
    points = points_on_triangles(v[faces[ids]], rng)
    _, rot, _ = triangle_frames(v, faces[ids])                     # columns e0, n, b
    radius = COVERAGE * np.sqrt(share / np.pi) * rng.uniform(0.85, 1.15, n)
    scales = np.stack([radius, FLATNESS * radius, radius * rng.uniform(0.85, 1.15, n)], axis=1)
    return points, matrix_to_quat(rot), scales, rot[:, :, 1]


def surface_coverage(points: np.ndarray, normals: np.ndarray, means: np.ndarray, rotations: np.ndarray,
                     scales: np.ndarray, opacity: float | None = None, k: int = 32,
                     chunk: int = 20000, tree=None) -> np.ndarray:
    """(P,) the alpha the discs (means (K, 3), rotations (K, 3, 3) with columns e0, n, b, scales
    (K, 3) along them) give the surface points (P, 3) with outward normals (P, 3), seen head-on:
    1 - prod(1 - opacity exp(-(u^2 / s0^2 + w^2 / s2^2) / 2)) over the k nearest discs whose
    normal agrees with the point's (cos > 0.5: not the other side of an ear or a lip), (u, w) the
    point's offset along the disc's in-plane axes, out to 3 sigma as the renderer cuts them.
    tree: a `cKDTree(means)` made before (`thin_coverage`'s), or None to make one."""
    from scipy.spatial import cKDTree

    opacity = HOLE_OPACITY if opacity is None else float(opacity)
    points = np.asarray(points, np.float64)
    out = np.zeros(len(points))
    if len(means) == 0 or len(points) == 0:
        return out
    means = np.asarray(means, np.float64)
    rot = np.asarray(rotations, np.float64)
    sc = np.asarray(scales, np.float64)
    k = int(min(k, len(means)))
    tree = cKDTree(means) if tree is None else tree
    reach = 3.0 * float(sc[:, [0, 2]].max())
    for lo in range(0, len(points), chunk):
        p = points[lo:lo + chunk]
        d, idx = tree.query(p, k=k, distance_upper_bound=reach)
        d, idx = np.asarray(d).reshape(len(p), k), np.asarray(idx).reshape(len(p), k)
        valid = np.isfinite(d)
        idx = np.where(valid, idx, 0)
        off = p[:, None, :] - means[idx]                                   # (p, k, 3)
        u = np.einsum("pkc,pkc->pk", off, rot[idx, :, 0]) / sc[idx, 0]
        w = np.einsum("pkc,pkc->pk", off, rot[idx, :, 2]) / sc[idx, 2]
        q = u * u + w * w
        same = np.einsum("pc,pkc->pk", np.asarray(normals, np.float64)[lo:lo + chunk], rot[idx, :, 1]) > 0.5
        a = np.where(valid & same & (q <= 9.0), opacity * np.exp(-0.5 * q), 0.0)
        out[lo:lo + chunk] = 1.0 - np.prod(1.0 - a, axis=1)
    return out


def _spread_reference(points: np.ndarray, order: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Indices of `points` (P, 3) taken in `order`, each kept only when no point kept before lies
    within its `spacing` (P,) (a greedy thinning on a grid of the largest spacing). The slow,
    obvious reference of `_spread` (`HOLE_REFERENCE`)."""
    cell = float(spacing.max()) if len(spacing) else 1.0
    grid: dict = {}
    kept = []
    for i in order:
        key = tuple(np.floor(points[i] / cell).astype(np.int64))
        near = [j for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                for j in grid.get((key[0] + dx, key[1] + dy, key[2] + dz), ())]
        if near and (np.linalg.norm(points[near] - points[i], axis=1) < spacing[i]).any():
            continue
        grid.setdefault(key, []).append(i)
        kept.append(i)
    return np.asarray(kept, np.int64)


def thin_coverage(points: np.ndarray, normals: np.ndarray, means: np.ndarray, rotations: np.ndarray,
                  scales: np.ndarray, threshold: float, opacity: float | None = None, k: int = 32,
                  chunk: int = 20000) -> tuple:
    """The points (P, 3) with normals (P, 3) that the discs (as `surface_coverage` takes them)
    cover less than `threshold`: (idx (T,) ascending, cov (T,) their `surface_coverage`, bit for
    bit). Fast: a first pass over each point's `HOLE_FIRST` nearest discs gives a lower bound of
    its alpha (1 - prod(1 - a) over a subset of the k nearest's terms, each in [0, opacity]);
    `surface_coverage` itself measures only the points whose bound is below threshold +
    `HOLE_MARGIN` (on the synthetic head ~1/8 of the probes). `surface_coverage` works point by
    point, so its values on the subset are the ones it gives over all the points."""
    from scipy.spatial import cKDTree

    opacity = HOLE_OPACITY if opacity is None else float(opacity)
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    first = int(min(HOLE_FIRST, k, len(means)))
    if len(points) == 0 or first <= 0 or first >= min(k, len(means)):
        cov = surface_coverage(points, normals, means, rotations, scales, opacity=opacity, k=k, chunk=chunk)
        idx = np.flatnonzero(cov < threshold)
        return idx, cov[idx]
    means = np.asarray(means, np.float64)
    rot = np.asarray(rotations, np.float64)
    sc = np.asarray(scales, np.float64)
    # the per-disc terms gathered once, side by side: (K, 12) centre, e0 / s0, e2 / s2, normal
    terms = np.concatenate([means, rot[:, :, 0] / sc[:, :1], rot[:, :, 2] / sc[:, 2:], rot[:, :, 1]], axis=1)
    tree = cKDTree(means)
    reach = 3.0 * float(sc[:, [0, 2]].max())
    # the points taken cell by cell (cells `reach` wide): neighbours query the tree's same leaves
    cells = np.floor((points - points.min(axis=0)) / max(reach, 1e-12)).astype(np.int64)
    walk = np.lexsort((cells[:, 2], cells[:, 1], cells[:, 0]))      # (P,)
    bound = np.zeros(len(points))
    for lo in range(0, len(points), chunk):
        at = walk[lo:lo + chunk]
        p = points[at]
        d, idx = tree.query(p, k=first, distance_upper_bound=reach)
        d, idx = np.asarray(d).reshape(len(p), first), np.asarray(idx).reshape(len(p), first)
        valid = np.isfinite(d)
        t = terms[np.where(valid, idx, 0)]                                 # (p, first, 12)
        off = p[:, None, :] - t[:, :, 0:3]
        u = np.einsum("pkc,pkc->pk", off, t[:, :, 3:6])
        w = np.einsum("pkc,pkc->pk", off, t[:, :, 6:9])
        q = u * u + w * w
        # a disc counts only where surface_coverage surely counts it too: its cos and q are
        # summed in another order here, which may differ from it in the last bit
        facing = np.einsum("pc,pkc->pk", normals[at], t[:, :, 9:12]) > 0.5 + HOLE_MARGIN
        hit = valid & facing & (q <= 9.0 - HOLE_MARGIN)
        bound[at] = 1.0 - np.prod(1.0 - np.where(hit, opacity * np.exp(-0.5 * q), 0.0), axis=1)
    maybe = np.flatnonzero(bound < threshold + HOLE_MARGIN)
    cov = surface_coverage(points[maybe], normals[maybe], means, rot, sc, opacity=opacity, k=k, chunk=chunk,
                           tree=tree)
    thin = cov < threshold
    return maybe[thin], cov[thin]


def _spread(points: np.ndarray, order: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """`_spread_reference`'s greedy thinning, the same indices: the pairs closer than the later
    one's spacing found at once (a k-d tree's pairs within the largest spacing, their distance
    computed as the reference does), then one pass in `order` over each point's earlier
    neighbours. The reference's grid cell is the largest spacing, so it sees every such pair."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64)
    order = np.asarray(order, np.int64)
    if len(order) == 0:
        return np.zeros(0, np.int64)
    cell = float(spacing.max())
    rank = np.empty(len(points), np.int64)
    rank[order] = np.arange(len(order))
    pairs = cKDTree(points).query_pairs(cell * (1.0 + 1e-9), output_type="ndarray")     # (E, 2)
    later = np.where(rank[pairs[:, 0]] > rank[pairs[:, 1]], pairs[:, 0], pairs[:, 1])  # (E,)
    earlier = pairs[:, 0] + pairs[:, 1] - later
    close = np.linalg.norm(points[earlier] - points[later], axis=1) < spacing[later]
    later, earlier = later[close], earlier[close]
    # each point's earlier neighbours, grouped by the point (CSR)
    by = np.argsort(later, kind="stable")
    later, earlier = later[by], earlier[by]
    start = np.searchsorted(later, np.arange(len(points) + 1))
    earlier = earlier.tolist()
    start = start.tolist()
    kept = bytearray(len(points))
    out = []
    for i in order.tolist():
        for j in earlier[start[i]:start[i + 1]]:
            if kept[j]:
                break
        else:
            kept[i] = 1
            out.append(i)
    return np.asarray(out, np.int64)


def fill_holes(v: np.ndarray, faces: np.ndarray, weight: np.ndarray, share_of: np.ndarray,
               discs: tuple, rng: np.random.Generator, threshold: float | None = None,
               probes: int | None = None, rounds: int | None = None) -> tuple:
    """Extra discs where the random discs leave the surface thin (`HOLE_ALPHA`). v (V, 3), faces
    (F, 3); weight (F,) the sampling weight (area x density; 0: no discs); share_of (F,) a disc's
    share of the surface (m^2) on each face; discs: (points, quats, scales, ids, normals) as
    `sample_bald` gives them. Probes: `HOLE_PROBES` x n surface points drawn as the discs are
    (from `rng`); those covered less than `threshold` (`surface_coverage`), thinnest first and a
    disc's share apart, get a disc `HOLE_SIZE` times their face's size, lying in its plane;
    `HOLE_ROUNDS` rounds.
    Returns the discs with the extra ones appended (the others untouched)."""
    from avatarkit.rig.frames import points_on_triangles, triangle_frames
    from avatarkit.rotations import quat_to_matrix

    threshold = HOLE_ALPHA if threshold is None else threshold
    probes = HOLE_PROBES if probes is None else probes
    rounds = HOLE_ROUNDS if rounds is None else rounds
    points, quats, scales, ids, normals = discs
    if threshold is None or rounds <= 0 or len(points) == 0:
        return discs
    m = int(probes * len(points))
    pid = rng.choice(len(faces), size=m, p=weight / weight.sum())
    probe = points_on_triangles(v[faces[pid]], rng)
    _, frames, _ = triangle_frames(v, faces)
    frames = np.asarray(frames, np.float64)
    probe_n = frames[pid, :, 1]
    rot = quat_to_matrix(np.asarray(quats, np.float64))
    out = [np.asarray(points), np.asarray(quats), np.asarray(scales), np.asarray(ids), np.asarray(normals)]
    todo = np.arange(m)
    for _ in range(rounds):
        if HOLE_REFERENCE:
            cov = surface_coverage(probe[todo], probe_n[todo], out[0], rot, out[2])
            thin = cov < threshold
            todo, cov = todo[thin], cov[thin]
        else:
            thin, cov = thin_coverage(probe[todo], probe_n[todo], out[0], rot, out[2], threshold)
            todo = todo[thin]
        if len(todo) == 0:
            break
        spacing = np.sqrt(share_of[pid[todo]] / np.pi)
        spread = _spread_reference if HOLE_REFERENCE else _spread
        take = todo[spread(probe[todo], np.argsort(cov, kind="stable"), spacing)]
        f = pid[take]
        radius = HOLE_SIZE * COVERAGE * np.sqrt(share_of[f] / np.pi)
        new_rot = frames[f]
        new = (probe[take].astype(out[0].dtype), matrix_to_quat(new_rot).astype(out[1].dtype),
               np.stack([radius, FLATNESS * radius, radius], axis=1).astype(out[2].dtype),
               f.astype(out[3].dtype), new_rot[:, :, 1].astype(out[4].dtype))
        out = [np.concatenate([a, b]) for a, b in zip(out, new)]
        rot = np.concatenate([rot, new_rot])
    return tuple(out)


def inset_depth(sigma: np.ndarray, pixel: float) -> np.ndarray:
    """(F,) metres the discs of faces whose disc sigma is `sigma` (F,) (metres) are set in, seen
    by a camera whose pixel is `pixel` metres at the head (`INSET`, `INSET_PIXEL`; 0 with INSET None)."""
    sigma = np.asarray(sigma, np.float64)
    if INSET is None:
        return np.zeros_like(sigma)
    p = max(float(pixel), 0.0)
    return INSET * sigma + np.minimum(INSET_PIXEL * p * p / np.maximum(sigma + 0.5 * p, 1e-12), p)


def set_in(points: np.ndarray, normals: np.ndarray, ids: np.ndarray, depth_of: np.ndarray) -> np.ndarray:
    """The disc centres `points` (N, 3) on faces `ids` (N,) moved along their outward unit
    `normals` (N, 3) into the head by `depth_of` (F,) metres of their face: every disc of a face
    alike (the drawn ones, the holes' and the eyes'), so the surface they make is the mesh's,
    offset."""
    depth = np.asarray(depth_of, np.float64)[np.asarray(ids)]
    return (np.asarray(points, np.float64) - depth[:, None] * np.asarray(normals, np.float64)).astype(
        np.asarray(points).dtype)


def camera_pixel(camera, points: np.ndarray) -> float:
    """The width (metres) of one of `camera`'s pixels at the median depth of `points` (N, 3)."""
    z = camera.to_camera(np.asarray(points, np.float64))[:, 2]
    z = z[z > 0]
    if len(z) == 0:
        return 0.0
    return float(np.median(z)) / (0.5 * (float(camera.fx) + float(camera.fy)))


def _set_in_discs(discs: tuple, fit: HeadFit, v: np.ndarray, share_of: np.ndarray) -> tuple:
    """`set_in` on `sample_bald`'s discs (points, quats, scales, ids, normals): each face's
    depth from its disc sigma (its disc share (F,) m^2, as `_discs_on` sizes them) and the fit's
    camera's pixel; the `INSET_KEEP` faces' discs stay on the surface."""
    if INSET is None:
        return discs
    points, quats, scales, ids, normals = discs
    sigma_of = COVERAGE * np.sqrt(np.maximum(share_of, 0.0) / np.pi)
    pixel = camera_pixel(fit.camera, v) if getattr(fit, "camera", None) is not None else 0.0
    depth_of = np.where(_inset_kept(fit.model, v), 0.0, inset_depth(sigma_of, pixel))
    return set_in(points, normals, ids, depth_of), quats, scales, ids, normals


def _inset_kept(model, v: np.ndarray) -> np.ndarray:
    """(F,) bool: faces whose discs stay on the surface (`INSET_KEEP` regions and the eyes'
    surroundings)."""
    f = model.faces
    keep = np.zeros(len(f), bool)
    for region in INSET_KEEP:
        if region in model.regions:
            keep |= model.region_mask(region)[f].sum(axis=1) >= 2
    if "eyes" in INSET_KEEP:
        keep |= _eye_area_faces(model, v)
    return keep


def sample_bald(fit: HeadFit, n: int, rng: np.random.Generator, face_density: float = 3.0,
                eye_density: float | None = None):
    """Discs on the rest head: (means (n', 3), quats (n', 4), scales (n', 3), face ids (n',) int32,
    normals (n', 3)). Area-weighted, `face_density` times denser on the face.

    eye_density (None: `EYE_DENSITY`) above 1: the eyes' surroundings (`_eye_area_faces`) are
    sampled that many times denser again, with smaller discs, and n' = n plus the extra discs
    there. The n discs are drawn first as without it, and those that land in the eyes'
    surroundings are replaced in place (then the extra ones appended) by discs drawn from a
    child of `rng` (`Generator.spawn`, which leaves `rng`'s stream as it was): every disc
    elsewhere, and what the caller draws from `rng` next, are the same as with eye_density 1.
    With `INSET` (off) every disc is then set in along its face's normal (`inset_depth` of the
    face's disc sigma and the fit camera's pixel; the `INSET_KEEP` faces' stay)."""
    from avatarkit.rig.frames import degenerate_faces

    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    faces = np.asarray(model.faces)
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    density = np.where(_face_weights(model), face_density, 1.0)
    density[degenerate_faces(v, faces)] = 0.0
    weight = area * density
    if not weight.sum() > 0:
        raise InputError("the head mesh has no area to put Gaussians on")
    ids = rng.choice(len(faces), size=n, p=weight / weight.sum()).astype(np.int32)
    # each disc's share of the surface: total weighted area / n, divided by the local density
    share = weight.sum() / n / density[ids]
    points, quats, scales, normals = _discs_on(v, faces, ids, share, rng)
    share_of = weight.sum() / n / np.maximum(density, 1e-12)       # (F,) a disc's share per face
    eye_density = EYE_DENSITY if eye_density is None else float(eye_density)
    eye = _eye_area_faces(model, v) & (weight > 0)
    if eye_density <= 1.0 or not eye.any():
        # the holes' probes from a child stream: what the caller draws from rng next is as
        # without them (and with HOLE_ALPHA None no child is spawned: the builds before it)
        discs = (points, quats, scales, ids, normals)
        if HOLE_ALPHA is not None:
            discs = fill_holes(v, faces, weight, share_of, discs,
                          rng.spawn(1)[0])
        return _set_in_discs(discs, fit, v, share_of)
    child = rng.spawn(1)[0]
    k = max(1, int(round(eye_density * n * weight[eye].sum() / weight.sum())))
    eye_ids = np.flatnonzero(eye)
    new_ids = eye_ids[child.choice(len(eye_ids), size=k, p=weight[eye_ids] / weight[eye_ids].sum())].astype(np.int32)
    new = _discs_on(v, faces, new_ids, weight[eye].sum() / k / density[new_ids], child)
    slots = np.flatnonzero(eye[ids])
    put = min(len(slots), k)
    out = [points, quats, scales, ids, normals]
    for i, (a, b) in enumerate(zip(out, (new[0], new[1], new[2], new_ids, new[3]))):
        a = a.copy()
        a[slots[:put]] = b[:put]
        out[i] = np.concatenate([a, b[put:]]) if put < k else np.delete(a, slots[put:], axis=0)
    # (the eye discs' share is smaller: their faces' holes are measured with their own sizes)
    share_eye = share_of.copy()
    share_eye[eye] = weight[eye].sum() / k / density[eye]
    discs = tuple(out)
    if HOLE_ALPHA is not None:
        discs = fill_holes(v, faces, weight, share_eye, discs, rng.spawn(1)[0])
    return _set_in_discs(discs, fit, v, share_eye)


def _eye_colours(image: np.ndarray, analysis) -> np.ndarray:
    """(2, 3) iris colours in [0, 1] at the right and left eye landmarks: the darker half of a
    small disc around each (the iris and pupil, not the sclera or lids)."""
    h, w = image.shape[:2]
    r = max(1.0, 0.07 * analysis.eye_distance)
    out = []
    for name in ("right_eye", "left_eye"):
        cx, cy = analysis.point(name)
        y0, y1 = int(max(0, cy - r)), int(min(h, cy + r + 1))
        x0, x1 = int(max(0, cx - r)), int(min(w, cx + r + 1))
        patch = image[y0:y1, x0:x1].reshape(-1, 3).astype(np.float64) / 255.0
        if len(patch) == 0:
            out.append((0.25, 0.2, 0.18))
            continue
        lum = patch.mean(axis=1)
        out.append(patch[lum <= np.median(lum)].mean(axis=0))
    return np.array(out)


def sclera_colour(seen: np.ndarray, least: int | None = None) -> np.ndarray:
    """(3,) the colour the eyeballs' unseen sclera takes: the median of the brighter half of
    `seen` (K, 3), the photo's colours of the eyeball discs it sees outside the irises (the
    sclera between the lids, with the lids' edges and lashes in the darker half), never
    brighter than `SCLERA_RGB`; `SCLERA_RGB` itself when fewer than `least` are seen.

    A fixed bright white showed as a glaring crescent where a raised lid or a turned eye
    uncovered sclera the photo did not see: the photo's sclera is in the face's light."""
    least = SCLERA_SAMPLES if least is None else least
    seen = np.asarray(seen, np.float64).reshape(-1, 3)
    if len(seen) < least:
        return np.asarray(SCLERA_RGB, np.float64)
    lum = seen.mean(axis=1)
    colour = np.median(seen[lum >= np.median(lum)], axis=0)
    return np.minimum(colour, np.asarray(SCLERA_RGB, np.float64))


def lift_bald(image: np.ndarray, analysis, segmentation, bald, fit: HeadFit, n: int,
              rng: np.random.Generator, face_density: float = 3.0) -> tuple[GaussianSet, dict]:
    """The built-in bald lifting (module docstring) -> (GaussianSet with `binding` and `part`
    extras, info)."""
    from avatarkit.recon.segment import BODY, SKIN

    model = fit.model
    cam = fit.camera
    means, quats, scales, ids, normals = sample_bald(fit, n, rng, face_density)
    n_drawn, n = n, len(means)              # n plus the extra discs (the eyes' `EYE_DENSITY`, the holes' `HOLE_ALPHA`)
    part = _face_parts(model)[ids]
    geo = GaussianSet.from_colors(means, quats, scales, np.full(n, 0.98), np.full((n, 3), 0.5))
    depth, _, dcam = depth_map(geo, cam)
    seen, px, facing = seen_from(means, normals, cam, depth, dcam)

    labels = bald.labels if getattr(bald, "labels", None) is not None else segmentation.labels
    lab = lookup(labels, px)
    neck = np.zeros(model.num_faces, bool)
    if "neck" in model.regions:
        neck = model.region_mask("neck")[model.faces].sum(axis=1) >= 2
    ok_label = (lab == SKIN) | ((lab == BODY) & neck[ids])
    eye = part == PART_EYE
    known = seen & (ok_label | eye) & (part != PART_MOUTH)
    photo = sample_image(bald.image, px) / 255.0
    rgb = np.zeros((n, 3), np.float32)
    rgb[known] = photo[known]

    skin_rgb = segmentation.skin_model.rgb.astype(np.float64) / 255.0
    skin = part == PART_SKIN
    trust = photo_weight(facing)
    head_on = known & (trust >= 1.0)
    filled = propagate_colors(means[skin], rgb[skin], head_on[skin], skin_rgb)
    w = np.where(known[skin], trust[skin], 0.0)[:, None]
    rgb[skin] = w * rgb[skin] + (1.0 - w) * filled
    if eye.any():
        iris_rgb = _eye_colours(image, analysis)
        iris = [eye & (model.region_mask(r)[model.faces].sum(axis=1) >= 2)[ids] if r in model.regions
                else np.zeros(n, bool) for r in ("right_iris", "left_iris")]
        fill = np.tile(sclera_colour(rgb[known & eye & ~iris[0] & ~iris[1]]), (n, 1))
        for k in range(2):
            fill[iris[k]] = iris_rgb[k]
        rgb[eye] = np.where(known[eye][:, None], rgb[eye], fill[eye])
    rgb[part == PART_MOUTH] = MOUTH_RGB
    # the lips' faces that the jaw stretches across the parted lips: unseen in the photo (a
    # closed mouth hides them), they are the mouth's inside when they show, not the lips'
    # colour the fill spreads onto them (on the shared clips a pink sheet filled the open mouth)
    rgb[_opening_faces(model)[ids] & ~known] = MOUTH_RGB
    # the extra discs' opacities from a child stream: what the caller draws from rng next
    # (the hair) is as without them
    opacity = rng.uniform(0.95, 1.0, n_drawn)
    if n > n_drawn:
        opacity = np.concatenate([opacity, rng.spawn(1)[0].uniform(0.95, 1.0, n - n_drawn)])
    out = GaussianSet.from_colors(means, quats, scales, opacity, np.clip(rgb, 0, 1),
                                  extras={"binding": ids, "part": part})
    info = {"bald": n, "bald_extra": n - n_drawn, "bald_seen": int(known.sum()),
            "bald_seen_share": round(float(known.mean()), 4),
            "bald_seen_grazing": int((known & skin & (trust < 1.0)).sum())}
    return out, info


__all__ = ["COVERAGE", "FLATNESS", "GRAZING", "HOLE_ALPHA", "HOLE_OPACITY", "HOLE_PROBES", "HOLE_REFERENCE", "HOLE_ROUNDS", "HOLE_SIZE", "HOLE_FIRST", "HOLE_MARGIN", "INSET", "INSET_KEEP", "INSET_PIXEL", "MOUTH_RGB", "PART_EYE", "PART_MOUTH", "PART_SKIN", "SCLERA_RGB", "lift_bald", "sclera_colour",
           "camera_pixel", "fill_holes", "inset_depth", "photo_weight", "set_in", "propagate_colors", "sample_bald", "surface_coverage", "thin_coverage"]
