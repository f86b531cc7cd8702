"""The open mouth: teeth and a dark cavity behind the lips, and lips that part instead of
stretching a sheet across the opening.

The head model is a closed surface (the template's lips meet at a shallow crease; FLAME's lips
close over a hole): when the jaw opens, the triangles whose vertices are skinned partly to the
jaw and partly to the skull stretch across the opening, and the Gaussians bound to them stretch
with them (`rig.binding`): a pink and dark-red sheet between the lips, nothing behind it.

`open_mouth` does two things, both from the model's geometry and skinning weights (never vertex
ids, so a FLAME-compatible model works the same way):

1. Parting the lips. The lips' and mouth interior's faces whose area grows with the jaw (posed
   at `PROBE_JAW` rad: area ratio above `STRETCH`) carry no Gaussians: each Gaussian on one is
   bound instead to the nearest face that does not stretch on its own side of the mouth (its
   face's jaw weight above or below 0.5). At rest nothing moves (the Gaussian keeps its place;
   only its host changes).
2. Teeth and cavity. An upper and a lower row of flat Gaussians along a parabolic arch behind the
   lips' crease (the front teeth `TEETH_BEHIND` behind the deepest point of the mouth interior
   on the midline; heights from the lips' inner edges, `UPPER_SHOW`, `LOWER_HIDE`), and a
   mouth-coloured wall `CAVITY_BEHIND` further back; the upper row and the upper half of the
   wall ride faces that stay with the skull when the jaw opens, the lower ones faces that move
   rigidly with the jaw (`rigid_faces`: measured by posing the model, pose correctives
   included), so nothing of them stretches. Each half of the wall reaches past the mouth line
   into the other side (`CAVITY_REACH_*` eye distances, leaning back `CAVITY_LEAN`), so the two
   overlap up to a wide opening. Only Gaussians at least `INSIDE_MARGIN` (`TEETH_MARGIN`) inside
   the rest head (its signed distance) are kept: hidden behind the closed lips at rest.

Colour: the photo's teeth when it shows them (`photo_teeth_colour`: bright, unsaturated pixels
inside the inner-lip landmarks), else `TEETH_RGB`; shaded darker toward the back of the arch.
The cavity is `CAVITY_RGB`, darker toward its far edges. The new Gaussians are bald Gaussians
with a `binding` (and `part` `PART_TEETH` / `PART_MOUTH` where the set carries a `part` extra).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.cage.mesh import face_areas
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.rotations import matrix_to_quat

#: jaw opening (rad) at which faces are probed for stretching
PROBE_JAW = 0.3
#: a face whose area grows by more than this factor at PROBE_JAW opens with the jaw
STRETCH = 1.3
#: a face whose vertices stay within this (m) of the skull's / the jaw's rigid motion at PROBE_JAW
RIGID_TOL = 0.00005
#: front teeth this far (m) behind the deepest point of the mouth interior on the midline
TEETH_BEHIND = 0.004
#: the lower row this far (m) behind the upper one
LOWER_BEHIND = 0.0015
#: the cavity wall this far (m) behind the teeth
CAVITY_BEHIND = 0.006
#: teeth heights. The upper row from UPPER_SHOW below the upper lip's inner edge (the lowest
#: point of the mouth's skull-side vertices on the midline: what stays of the lip when the jaw
#: drops) up to UPPER_TOP above the mouth line: that band shows under the upper lip when the
#: mouth opens. The lower row from LOWER_BOTTOM up to LOWER_HIDE below the lower lip's inner edge
#: (the highest jaw-side vertex): the lower teeth hide behind the lower lip, as in the clips. A
#: lower row level with the lip's edge showed a bright band 3 mm high (seen from the camera's
#: height over a jaw tilted down) filling the half-open mouth where the clips show a dark one
#: (grey, jaw 0.1-0.2 rad: -1.0 to -1.6 dB in the mouth box)
UPPER_SHOW, UPPER_TOP = 0.0025, 0.008
LOWER_HIDE, LOWER_BOTTOM = 0.002, -0.010
#: half the arch's width and how far back its ends are, in eye distances
ARCH_HALF = 0.30
ARCH_BACK = 0.15
#: how far past the mouth line each half of the cavity reaches into the other side, in eye
#: distances, on the midline (less toward the corners: the opening is lens-shaped). The lower
#: half (on the jaw) reaches far up: opening, the jaw swings it down and back behind the upper
#: teeth. The upper half (on the skull) only a little down: the jaw swings the lower lip back
#: (17 mm at 0.3 rad on the template), so a long upper half stood in front of it, seen from the side
CAVITY_REACH_LOWER = 0.45
CAVITY_REACH_UPPER = 0.12
#: metres back per metre the cavity reaches past the mouth line
CAVITY_LEAN = 0.7
#: the cavity kept only this far (m) inside the rest head: the skin's discs do not hide what
#: lies just under them (2 mm showed dark specks on the cheeks); the teeth, behind the lips'
#: crease, TEETH_MARGIN
INSIDE_MARGIN = 0.006
TEETH_MARGIN = 0.002
#: spacing (m) of the Gaussians on the teeth and the cavity
SPACING = 0.0008
TEETH_RGB = (0.72, 0.68, 0.58)
#: the bald discs' mouth colour (`recon.bald_discs.MOUTH_RGB`): the near-black of a first try
#: (0.16, 0.05, 0.05) lost PSNR where the video's open mouth shows a lit tongue
CAVITY_RGB = (0.32, 0.12, 0.12)
PART_MOUTH, PART_TEETH = 2, 3
#: a photo's teeth: pixels inside the inner lips brighter than this (0-1) and less saturated
TEETH_VALUE, TEETH_SATURATION, TEETH_MIN_PIXELS = 0.55, 0.35, 30


@dataclass
class MouthGeometry:
    """Where the mouth is on a rest head (metres, the model's frame: +Y up, face toward +Z).

    centre: (3,) the mouth line's point on the midline at the teeth's front; u: eye distance;
    half_width: half the lips' width; upper_edge, lower_edge: the upper lip's lowest and the
    lower lip's highest point on the midline, relative to the mouth line (the template: about
    +-2 mm, the lip crease)."""

    centre: np.ndarray
    u: float
    half_width: float
    upper_edge: float = 0.002
    lower_edge: float = -0.002


def mouth_geometry(model, vertices: np.ndarray) -> MouthGeometry | None:
    """The mouth of `model` with rest `vertices` (V, 3), from its `lips` and `mouth_interior`
    regions; None when the model has neither (no teeth then)."""
    if "mouth_interior" not in model.regions or "lips" not in model.regions:
        return None
    v = np.asarray(vertices, np.float64)
    inner = model.region_mask("mouth_interior")
    lips = model.region_mask("lips")
    if inner.sum() < 3 or lips.sum() < 3:
        return None
    from avatarkit.head.lbs import _regress

    # the joints of this head (its shape), not the mean head's: the eyes' spacing sizes the teeth
    joints = np.asarray(_regress(model.J_regressor, v[None]), np.float64)[0]
    u = float(np.linalg.norm(joints[3] - joints[4])) or 0.064
    mid_x = 0.5 * (joints[3, 0] + joints[4, 0])
    near = inner & (np.abs(v[:, 0] - mid_x) < 0.15 * u)
    near = near if near.sum() >= 2 else inner
    y = float(np.median(v[inner, 1]))
    z = float(v[near, 2].min()) - TEETH_BEHIND
    half = float(np.abs(v[lips, 0] - mid_x).max())
    from avatarkit.face.fit import JAW_JOINT

    mid = (inner | lips) & (np.abs(v[:, 0] - mid_x) < 0.05 * u)
    jaw = (np.asarray(model.weights[:, JAW_JOINT]) >= 0.5) if model.weights.shape[1] > JAW_JOINT \
        else np.zeros(len(v), bool)
    up, low = mid & ~jaw, mid & jaw
    upper = float(v[up, 1].min()) - y if up.any() else 0.002
    lower = float(v[low, 1].max()) - y if low.any() else -0.002
    return MouthGeometry(np.array([mid_x, y, z]), u, half, upper, lower)


def posed_rest(model, shape: np.ndarray, jaw: float) -> np.ndarray:
    """(V, 3) the rest head with the jaw opened by `jaw` rad about the axis that opens it."""
    from avatarkit.head.model import HeadParams

    v, _ = model.forward(HeadParams(jaw=np.array([jaw, 0.0, 0.0]), shape=np.asarray(shape, np.float32)))
    return v[0].astype(np.float64)


@dataclass(frozen=True)
class JawProbe:
    """The rest head and the head with its jaw opened PROBE_JAW, posed once for the tests below
    (each used to pose the model again: 8 forwards for one open mouth)."""

    sign: float            # +1 / -1: the jaw x rotation that moves the jaw's front down
    rest: np.ndarray       # (V, 3) float64
    opened: np.ndarray     # (V, 3) float64, jaw opened by sign * PROBE_JAW
    jaw_transform: np.ndarray   # (4, 4) the jaw joint's rest-to-opened transform


def jaw_probe(model, shape: np.ndarray) -> JawProbe:
    from avatarkit.face.fit import JAW_JOINT
    from avatarkit.head.model import HeadParams

    rest = posed_rest(model, shape, 0.0)
    front = model.weights[:, JAW_JOINT] > 0.5
    sign = 1.0
    if front.any():
        dy = posed_rest(model, shape, 0.1)[front, 1] - rest[front, 1]
        sign = 1.0 if dy.mean() < 0 else -1.0
    v, T = model.forward(HeadParams(jaw=np.array([sign * PROBE_JAW, 0.0, 0.0]),
                                    shape=np.asarray(shape, np.float32)))
    return JawProbe(sign, rest, v[0].astype(np.float64), T[0, JAW_JOINT].astype(np.float64))


def opening_sign(model, shape: np.ndarray) -> float:
    """+1 or -1: the sign of a jaw x rotation that moves the jaw's front vertices down."""
    return jaw_probe(model, shape).sign


def stretching_faces(model, shape: np.ndarray, probe: JawProbe | None = None) -> np.ndarray:
    """(F,) bool: faces whose area grows by more than STRETCH when the jaw opens PROBE_JAW."""
    probe = probe or jaw_probe(model, shape)
    faces = np.asarray(model.faces)
    a0 = face_areas(probe.rest, faces)
    a1 = face_areas(probe.opened, faces)
    return a1 > STRETCH * np.maximum(a0, 1e-12)


def rigid_faces(model, shape: np.ndarray, probe: JawProbe | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(F,) bool twice: the faces that stay put with the skull / move rigidly with the jaw when
    it opens PROBE_JAW (every vertex within RIGID_TOL of that), pose correctives included: a
    jaw weight of 0 is not enough where the model's posedirs move the upper lip."""
    probe = probe or jaw_probe(model, shape)
    rest, v, t = probe.rest, probe.opened, probe.jaw_transform
    still = np.linalg.norm(v - rest, axis=1) < RIGID_TOL
    with_jaw = np.linalg.norm(v - (rest @ t[:3, :3].T + t[:3, 3]), axis=1) < RIGID_TOL
    f = np.asarray(model.faces)
    return still[f].all(axis=1), with_jaw[f].all(axis=1)


def part_lips(model, vertices: np.ndarray, shape: np.ndarray, gaussians: GaussianSet,
              probe: JawProbe | None = None, degenerate: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """New host faces (N,) for `gaussians` (with a `binding` extra on `model`'s faces): those on
    faces that stretch with the jaw go to the nearest non-stretching face on their side of the
    mouth -> (binding, how many moved)."""
    from avatarkit.face.fit import JAW_JOINT
    from avatarkit.rig.frames import degenerate_faces
    from avatarkit.rig.nearest import nearest_faces

    ids = np.asarray(gaussians.extras["binding"], np.int64).copy()
    if model.weights.shape[1] <= JAW_JOINT:
        return ids, 0
    faces = np.asarray(model.faces)
    mouth = np.zeros(model.num_vertices, bool)
    for region in ("lips", "mouth_interior"):
        if region in model.regions:
            mouth |= model.region_mask(region)
    # only the lips' and mouth's: the cheeks' stretching faces keep their skin over the corners
    stretch = stretching_faces(model, shape, probe) & (mouth[faces].sum(axis=1) >= 2)
    moving = np.flatnonzero(stretch[ids])
    if len(moving) == 0:
        return ids, 0
    w = np.asarray(model.weights[:, JAW_JOINT], np.float64)[faces].mean(axis=1)    # (F,)
    if degenerate is None:
        degenerate = degenerate_faces(np.asarray(vertices, np.float64), faces)
    bad = stretch | degenerate
    lower = w[ids[moving]] >= 0.5
    for side, sel in ((True, lower), (False, ~lower)):
        if not sel.any():
            continue
        exclude = bad | ((w >= 0.5) != side)
        if exclude.all():
            continue
        new, _ = nearest_faces(gaussians.means[moving[sel]], vertices, faces, exclude=exclude)
        ids[moving[sel]] = new
    return ids, len(moving)


def _arch(geo: MouthGeometry, x: np.ndarray) -> np.ndarray:
    """z of the arch at x (relative to the midline): a parabola ARCH_BACK u deep at ARCH_HALF u."""
    return geo.centre[2] - (ARCH_BACK / ARCH_HALF ** 2 / geo.u) * x ** 2


def _sheet(geo: MouthGeometry, half_width: float, y_span: tuple[float, float], back: float):
    """Points (P, 3), normals (P, 3) and |x| / half_width (P,) on a vertical sheet along the arch
    `back` m behind it, from y_span[0] to y_span[1] around the mouth line, SPACING apart."""
    n_x = max(2, int(np.ceil(2 * half_width / SPACING)) + 1)
    n_y = max(2, int(np.ceil((y_span[1] - y_span[0]) / SPACING)) + 1)
    xs = np.linspace(-half_width, half_width, n_x)
    ys = np.linspace(*y_span, n_y)
    X, Y = np.meshgrid(xs, ys)
    X, Y = X.ravel(), Y.ravel()
    Z = _arch(geo, X) - back
    pts = np.stack([geo.centre[0] + X, geo.centre[1] + Y, Z], axis=1)
    # the arch's outward normal in the xz plane: (2 c x, 0, 1) normalised
    c = ARCH_BACK / ARCH_HALF ** 2 / geo.u
    nrm = np.stack([2 * c * X, np.zeros_like(X), np.ones_like(X)], axis=1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return pts, nrm, np.abs(X) / half_width, Y


def _discs(points: np.ndarray, normals: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Flat discs facing `normals`: quats (P, 4) with the disc's thin axis (local y) on the
    normal, as `recon.bald_discs` lays them, and scales (P, 3)."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    e0 = np.cross(np.array([0.0, 1.0, 0.0]), n)
    e0 /= np.maximum(np.linalg.norm(e0, axis=1, keepdims=True), 1e-12)
    b = np.cross(e0, n)
    rot = np.stack([e0, n, b], axis=2)                  # columns e0, n, b
    scales = np.tile([radius, 0.15 * radius, radius], (len(points), 1))
    return matrix_to_quat(rot), scales


#: MediaPipe face-mesh points around the inner lips, in order (upper lip left to right, lower back)
INNER_LIPS = (78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308, 324, 318, 402, 317, 14, 87, 178, 88, 95)


def inner_lips(mesh) -> np.ndarray | None:
    """(K, 2) the inner-lip polygon in array pixel coordinates of a `FaceMesh` (None: no mesh)."""
    if mesh is None:
        return None
    return np.asarray(mesh.points, np.float64)[list(INNER_LIPS), :2] - 0.5


def photo_teeth_colour(image: np.ndarray | None, inner_lips: np.ndarray | None) -> np.ndarray | None:
    """(3,) the teeth's colour in [0, 1] where the photo (H, W, 3) uint8 shows them: the median
    of the bright, unsaturated pixels inside the inner-lip polygon `inner_lips` (K, 2) pixels;
    None when there are fewer than TEETH_MIN_PIXELS of them (a closed mouth)."""
    if image is None or inner_lips is None or len(inner_lips) < 3:
        return None
    import cv2

    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.fillPoly(mask, [np.round(np.asarray(inner_lips)).astype(np.int32)], 1)
    px = image[mask > 0].astype(np.float64) / 255.0
    if len(px) == 0:
        return None
    hi, lo = px.max(axis=1), px.min(axis=1)
    sat = (hi - lo) / np.maximum(hi, 1e-6)
    teeth = px[(hi > TEETH_VALUE) & (sat < TEETH_SATURATION)]
    if len(teeth) < TEETH_MIN_PIXELS:
        return None
    return np.median(teeth, axis=0)


#: the signed distance is taken on the head's faces within this many eye distances of the mouth
#: (their nearest surface is there), on a grid of SDF_SPACING (m)
SDF_REACH, SDF_SPACING = 1.0, 0.0015


def _mouth_sdf(v: np.ndarray, faces: np.ndarray, geo: MouthGeometry):
    """A `HeadSDF` of the rest head's faces around the mouth: a whole-head grid this fine costs
    seconds; the teeth and cavity lie within a few centimetres of the mouth."""
    from avatarkit.head.sdf_grid import HeadSDF

    near = np.linalg.norm(v[faces].mean(axis=1) - geo.centre, axis=1) < SDF_REACH * geo.u
    used, local = np.unique(faces[near], return_inverse=True)
    return HeadSDF.build(v[used], local.reshape(-1, 3), spacing=SDF_SPACING, margin=0.005)


def teeth_and_cavity(model, vertices: np.ndarray, shape: np.ndarray, sdf=None,
                     teeth_rgb=None, probe: JawProbe | None = None,
                     degenerate: np.ndarray | None = None) -> tuple[GaussianSet, np.ndarray, dict]:
    """The teeth and cavity Gaussians at rest (module docstring) -> (GaussianSet, host faces (P,)
    int64, info); an empty set when the model has no mouth regions or jaw weights.

    vertices: (V, 3) the rest head; sdf: a `HeadSDF` of it, fine enough for INSIDE_MARGIN (one
    of the mouth's region is built here when None)."""
    from avatarkit.face.fit import JAW_JOINT
    from avatarkit.rig.frames import degenerate_faces
    from avatarkit.rig.nearest import nearest_faces

    v = np.asarray(vertices, np.float64)
    geo = mouth_geometry(model, v)
    empty = GaussianSet.empty(), np.zeros(0, np.int64)
    if geo is None or model.weights.shape[1] <= JAW_JOINT:
        return (*empty, {"teeth": 0, "cavity": 0, "why": "no mouth regions"})
    faces = np.asarray(model.faces)
    bad = degenerate_faces(v, faces) if degenerate is None else degenerate
    still, with_jaw = rigid_faces(model, shape, probe)
    upper_faces, lower_faces = ~bad & still, ~bad & with_jaw
    if not upper_faces.any() or not lower_faces.any():
        return (*empty, {"teeth": 0, "cavity": 0, "why": "no faces rigid with the skull and the jaw"})
    base = np.asarray(TEETH_RGB if teeth_rgb is None else teeth_rgb, np.float64)
    half = min(ARCH_HALF * geo.u, geo.half_width)
    cav_half = max(geo.half_width, half)
    parts = []
    up, low = CAVITY_REACH_UPPER * geo.u, CAVITY_REACH_LOWER * geo.u
    upper_span = (min(geo.upper_edge - UPPER_SHOW, 0.0), UPPER_TOP)
    lower_span = (LOWER_BOTTOM, min(geo.lower_edge - LOWER_HIDE, 0.0))
    #  (y span, back, half width, lower jaw?, part, reach)
    for span, back, hw, lower, part, reach in (
            (upper_span, 0.0, half, False, PART_TEETH, 0.0),
            (lower_span, LOWER_BEHIND, half, True, PART_TEETH, 0.0),
            ((-up, UPPER_TOP), CAVITY_BEHIND, cav_half, False, PART_MOUTH, up),
            ((LOWER_BOTTOM, low), CAVITY_BEHIND + 0.5 * SPACING, cav_half, True, PART_MOUTH, low)):
        pts, nrm, side, y = _sheet(geo, hw, span, back)
        if part == PART_MOUTH:
            # lens-shaped: the far half of each wall narrows toward the corners
            far = -y if not lower else y
            lens = far <= reach * np.sqrt(np.clip(1 - side ** 2, 0, 1))
            pts, nrm, side, y, far = pts[lens], nrm[lens], side[lens], y[lens], far[lens]
            # and leans back as it reaches into the other side: inside the head at rest (under
            # the nose, behind the chin), and the way the jaw swings it when the mouth opens
            pts[:, 2] -= CAVITY_LEAN * np.maximum(far, 0.0)
            nrm = nrm + np.stack([np.zeros_like(y), np.where(far > 0, np.sign(y) * CAVITY_LEAN, 0.0),
                                  np.zeros_like(y)], axis=1)
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        if part == PART_TEETH:
            # the arch's sides and the gums' edge in the shade of the lips and cheeks
            gum = np.abs(y - (span[1] if not lower else span[0])) / (span[1] - span[0])
            shade = (1.0 - 0.55 * side ** 2) * (0.55 + 0.45 * np.clip(gum * 1.6, 0, 1))
            rgb = base[None] * shade[:, None]
        else:
            edge = np.clip(np.abs(y) / reach, 0, 1)
            rgb = np.asarray(CAVITY_RGB)[None] * (1.0 - 0.4 * np.maximum(side, edge) ** 2)[:, None]
        parts.append((pts, nrm, np.clip(rgb, 0, 1), lower, part))
    pts = np.concatenate([p[0] for p in parts])
    nrm = np.concatenate([p[1] for p in parts])
    rgb = np.concatenate([p[2] for p in parts])
    lower = np.concatenate([np.full(len(p[0]), p[3]) for p in parts])
    part = np.concatenate([np.full(len(p[0]), p[4], np.uint8) for p in parts])
    d = _mouth_sdf(v, faces, geo).query(pts)[0] if sdf is None else sdf.query(pts)[0]
    keep = d < -np.where(part == PART_TEETH, TEETH_MARGIN, INSIDE_MARGIN)
    pts, nrm, rgb, lower, part = pts[keep], nrm[keep], rgb[keep], lower[keep], part[keep]
    ids = np.zeros(len(pts), np.int64)
    for side, faces_ok in ((True, lower_faces), (False, upper_faces)):
        sel = lower == side
        if sel.any():
            ids[sel], _ = nearest_faces(pts[sel], v, faces, exclude=~faces_ok)
    quats, scales = _discs(pts, nrm, 1.2 * SPACING)
    gs = GaussianSet.from_colors(pts, quats, scales, np.full(len(pts), 0.99), np.clip(rgb, 0, 1))
    info = {"teeth": int((part == PART_TEETH).sum()), "cavity": int((part == PART_MOUTH).sum()),
            "dropped_outside": int((~keep).sum()), "teeth_rgb": [round(float(c), 3) for c in base],
            "teeth_from_photo": teeth_rgb is not None}
    return gs.replace(extras={"part": part}), ids, info


def open_mouth(model, vertices: np.ndarray, shape: np.ndarray, bald: GaussianSet, sdf=None,
               teeth_rgb=None) -> tuple[GaussianSet, dict]:
    """`bald` (with a `binding` extra) with its lips parted (`part_lips`) and the teeth and cavity
    appended (`teeth_and_cavity`) -> (GaussianSet, info). Other extras of `bald` are kept; the
    new Gaussians get zeros in them (`part`: PART_TEETH / PART_MOUTH)."""
    from avatarkit.face.fit import JAW_JOINT
    from avatarkit.rig.frames import degenerate_faces

    # a model without a jaw joint has nothing to part (and cannot be posed by HeadParams)
    probe = jaw_probe(model, shape) if model.weights.shape[1] > JAW_JOINT else None
    degenerate = degenerate_faces(np.asarray(vertices, np.float64), np.asarray(model.faces))
    ids, moved = part_lips(model, vertices, shape, bald, probe, degenerate)
    bald = bald.replace(extras={**bald.extras, "binding": ids.astype(bald.extras["binding"].dtype)})
    extra, extra_ids, info = teeth_and_cavity(model, vertices, shape, sdf, teeth_rgb, probe, degenerate)
    info["lips_rebound"] = moved
    if len(extra) == 0:
        return bald, info
    extras = {}
    for k, a in bald.extras.items():
        if k == "binding":
            add = extra_ids.astype(a.dtype)
        elif k == "part":
            add = extra.extras["part"].astype(a.dtype)
        else:
            add = np.zeros((len(extra), *a.shape[1:]), a.dtype)
        extras[k] = np.concatenate([a, add])
    new = extra.replace(extras={}).with_sh_degree(bald.sh_degree)
    out = GaussianSet.concat([bald.replace(extras={}), new])
    return out.replace(extras=extras), info


def open_avatar_mouth(avatar, teeth_rgb=None):
    """`open_mouth` on a built `Avatar` (its bald set bound to its own head model, the rest head
    of its identity), in place -> (avatar, info). What `pipeline.OPEN_MOUTH` does at the end of
    the colours stage, for a build that decides later: the video build, before its frame-colours
    stage colours the teeth and cavity from the frames that show them (`track.video_build.OPEN_MOUTH`).
    An avatar folder keeps only the bald set's `binding` extra, so that is all it keeps here."""
    rest = np.asarray(avatar.rest_head_vertices, np.float64)
    bald, info = open_mouth(avatar.head_model, rest, avatar.shape, avatar.bald, teeth_rgb=teeth_rgb)
    avatar.bald = bald.replace(extras={"binding": bald.extras["binding"].astype(avatar.bald.extras["binding"].dtype)})
    # the cached binding was of the set before
    avatar.__dict__.pop("binding", None)
    return avatar, info


__all__ = ["INNER_LIPS", "JawProbe", "MouthGeometry", "inner_lips", "jaw_probe", "mouth_geometry", "open_avatar_mouth", "open_mouth", "part_lips",
           "photo_teeth_colour", "rigid_faces", "stretching_faces", "teeth_and_cavity"]
