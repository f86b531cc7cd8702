"""The built-in lifter's hair strands: the 2D hair flow, the hair shell around the head, and
strands grown through it from roots on the scalp (`recon.lift.lift_hair` puts them together).

Strands grown from roots on the fitted scalp, one Gaussian per 4 mm segment, thin and
oriented along the strand (scale index 0 along it, 1 across, 2 along the surface normal).
* shell thickness: along rays from the projected head centre, the gap between the head's
  projected silhouette and the outer edge of the hair mask, in metres at the head's depth,
  as a function of the ray's polar angle; a 3D point takes the thickness of the polar angle
  of its projection, which extrapolates the silhouette to the hidden back of the head;
* growth: each strand keeps a random layer between `MARGIN` and that thickness above the
  scalp (signed distance of the rest head) while above the jaw, and falls freely below it.
  Where it is seen from the camera, it follows the 2D hair flow (the structure tensor of the
  hair pixels: the direction of least intensity change, coherence-weighted and smoothed)
  lifted to the head's tangent plane, and it stops when it leaves the hair mask. Where it is
  hidden (behind the head, or behind the neck and body), it is combed away from the crown
  and down, and stops at the hair's lowest extent in the photo (back-projected at the head's
  depth): hair that reaches below the chin in the photo falls down the back to that length.
  Short hair, whose lowest extent beside the face is the temples, still covers the scalp
  behind the ears down to the nape: hidden roots below that extent grow strands along the
  scalp down to the scalp region's lower edge at their azimuth (`Hairline`, the head model's
  anatomical hairline);
* colour: seen hair takes the photo's colour at its projection; hidden hair a random hair
  pixel from the same image rows (a height band); inner layers are slightly darker.
Extras: `strand` (int32 strand id) and `seen` (uint8: 1 where the camera saw the segment).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.recon.fit import HeadFit, project_mask
from avatarkit.recon.image_sampling import lookup, sample_image
from avatarkit.rig.frames import points_on_triangles
from avatarkit.recon import visibility as _visibility  # its switches read at call time

#: hair keeps at least this clearance (metres) above the scalp
MARGIN = 0.002
#: strand segment length (metres)
SEGMENT = 0.004
#: `Hairline`'s azimuth bins, and the bins either side its lower edge is smoothed over
HAIRLINE_BINS = 36
HAIRLINE_SMOOTH = 1
#: hidden roots below the photo's lowest hair grow strands down to the scalp's lower edge (`Hairline`)
#: (read when the lifter runs, so a caller may switch it)
NAPE_HAIR = True
#: hair strand half-width and half-thickness (metres, 1 sigma)
HAIR_WIDTH = 0.0012
HAIR_THICKNESS = 0.0003
#: HAIR_WIDTH is for this many hair Gaussians; fewer get wider strands (up to 4x)
HAIR_REFERENCE_COUNT = 40_000
#: the shell is never thicker than this (metres)
MAX_SHELL = 0.06


# ---------------------------------------------------------------------------------------------
# 2D flow and shell

def hair_flow(image: np.ndarray, hair: np.ndarray, scale_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The 2D direction of the hair: (flow (H, W, 2) unit vectors, coherence (H, W) in [0, 1]).

    Structure tensor J = G * (grad I grad I^T) of the grey image; hair runs along the
    eigenvector of the smaller eigenvalue. Orientations are averaged as doubled angles
    (sign-free), weighted by coherence ((l1 - l2) / (l1 + l2))^2, inside the hair mask and over
    `scale_px`, so the field is smooth and defined on every hair pixel."""
    import cv2

    grey = cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    s = max(1.0, 0.01 * scale_px)
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), s)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), s)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), s)
    tr = jxx + jyy
    diff = np.sqrt((jxx - jyy) ** 2 + 4 * jxy ** 2)
    coherence = np.where(tr > 1e-9, diff / np.maximum(tr, 1e-9), 0.0) ** 2
    # gradient orientation (doubled angle); hair runs perpendicular: negate the doubled vector
    c2 = -(jxx - jyy) / np.maximum(diff, 1e-9)
    s2 = -2 * jxy / np.maximum(diff, 1e-9)
    m = np.asarray(hair, np.float32)
    wgt = (coherence * m).astype(np.float32)
    big = max(1.0, 0.12 * scale_px)
    num_c = cv2.GaussianBlur(c2 * wgt, (0, 0), big)
    num_s = cv2.GaussianBlur(s2 * wgt, (0, 0), big)
    den = cv2.GaussianBlur(wgt, (0, 0), big)
    mag = np.sqrt(num_c ** 2 + num_s ** 2)
    angle = 0.5 * np.arctan2(num_s, num_c)
    flow = np.stack([np.cos(angle), np.sin(angle)], axis=-1).astype(np.float32)
    strength = np.where(den > 1e-6, mag / np.maximum(den, 1e-6), 0.0) * np.clip(den / 0.05, 0, 1)
    return flow, np.clip(strength, 0, 1).astype(np.float32)


@dataclass(eq=False)
class HairShell:
    """What the 2D masks say about the hair volume.

    center2d (2,) pixels and center3d (3,) rest frame: the head centre; depth: its camera z;
    angles (A,): polar angle bins (radians, image axes); thickness (A,): hair thickness above
    the head's silhouette per bin (metres); hair: (H, W) bool hair connected to the head;
    head: (H, W) bool projected head (no neck); y_end: rest-frame height of the hair's lowest
    extent beside the face (metres); y_jaw: rest-frame height of the jaw (below it hair hangs)."""

    center2d: np.ndarray
    center3d: np.ndarray
    depth: float
    angles: np.ndarray
    thickness: np.ndarray
    hair: np.ndarray
    head: np.ndarray
    y_end: float
    y_jaw: float

    def thickness_at(self, px: np.ndarray) -> np.ndarray:
        """Shell thickness (N,) for pixel positions (N, 2) by their polar angle."""
        d = np.nan_to_num(np.asarray(px, np.float64) - self.center2d)
        a = np.arctan2(d[:, 1], d[:, 0])
        step = self.angles[1] - self.angles[0]
        i = np.floor((a - self.angles[0]) / step).astype(np.int64)
        t = (a - self.angles[0]) / step - i
        n = len(self.angles)
        return (1 - t) * self.thickness[i % n] + t * self.thickness[(i + 1) % n]


def back_project(fit: HeadFit, px: np.ndarray, depth: float) -> np.ndarray:
    """Pixels (N, 2) at camera depth `depth` -> rest-frame points (N, 3)."""
    cam = fit.camera
    p = np.asarray(px, np.float64).reshape(-1, 2)
    c = np.stack([(p[:, 0] - cam.cx) * depth / cam.fx, (p[:, 1] - cam.cy) * depth / cam.fy,
                  np.full(len(p), depth)], axis=1)
    r, t = cam.rotation, cam.translation
    return (c - t) @ r   # R^T (c - t), row form


def _first_run(a: np.ndarray, run: int) -> np.ndarray:
    """Per row of a (A, R) bool array: the first index that starts `run` True values in a row
    (R - 1 when none does)."""
    ok = a[:, : a.shape[1] - run + 1].copy()
    for k in range(1, run):
        ok &= a[:, k: a.shape[1] - run + 1 + k]
    return np.where(ok.any(axis=1), np.argmax(ok, axis=1), a.shape[1] - 1)


def hair_shell(fit: HeadFit, hair_mask: np.ndarray, analysis, bins: int = 90) -> HairShell:
    """Measure the hair shell from the hair mask and the fitted head (see `HairShell`)."""
    from scipy import ndimage

    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    keep = np.ones(model.num_faces, bool)
    not_neck = np.ones(model.num_vertices, bool)
    if "neck" in model.regions:
        not_neck = ~model.region_mask("neck")
        keep = not_neck[model.faces].any(axis=1)
    head = project_mask(fit, model.faces[keep])
    lo, hi = v[not_neck].min(axis=0), v[not_neck].max(axis=0)
    center3d = 0.5 * (lo + hi)
    (c2,), (cz,) = fit.camera.project(center3d[None])
    hair = np.asarray(hair_mask, bool)
    # hair connected to the head (a dilated head touches it): stray hair-coloured blobs are not
    lab, n = ndimage.label(hair)
    if n:
        touch = np.unique(lab[ndimage.binary_dilation(head, iterations=3) & hair])
        keep_lab = np.zeros(n + 1, bool)
        keep_lab[touch] = True
        keep_lab[0] = False
        hair = keep_lab[lab]
    h, w = hair.shape
    both = hair | head
    angles = np.linspace(-np.pi, np.pi, bins, endpoint=False)
    rmax = 1.5 * max(h, w)
    r = np.arange(0.0, rmax, 1.0)
    dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    pts = c2[None, None] + r[None, :, None] * dirs[:, None, :]           # (A, R, 2)
    flat = pts.reshape(-1, 2)
    in_head = lookup(head, flat).reshape(len(angles), -1)
    in_both = lookup(both, flat).reshape(len(angles), -1)
    # the head's edge: where the ray first leaves the head; the hair's: where it first leaves
    # head + hair. Gaps of a few pixels (thin partings, mask noise) do not count as leaving.
    first_out = _first_run(~in_head, 3)
    last_in = _first_run(~in_both, 5)
    gap_px = np.maximum(last_in - first_out, 0).astype(np.float64)
    thickness = gap_px * cz / fit.camera.fx
    # smooth over the angle (circular): median against single-ray outliers, then a small box
    padded = np.concatenate([thickness[-3:], thickness, thickness[:3]])
    med = np.array([np.median(padded[i:i + 7]) for i in range(len(thickness))])
    padded = np.concatenate([med[-2:], med, med[:2]])
    thickness = np.convolve(padded, np.ones(5) / 5, mode="valid")
    thickness = np.clip(thickness, 0.0, MAX_SHELL)

    joints = model.rest_joints(fit.params)[0].astype(np.float64)
    chin = v[fit.landmarks["chin"]] if "chin" in fit.landmarks else v[not_neck].min(axis=0)
    y_jaw = float(chin[1] + 0.25 * (joints[2][1] - chin[1]))
    # the hair's lowest extent beside the face: the lowest hair row outside the face's width
    ex, _ = analysis.face_axes()
    ys, xs = np.nonzero(hair)
    y_end = float(center3d[1])
    if len(ys):
        u = ((np.stack([xs + 0.5, ys + 0.5], axis=1) - analysis.eye_mid) @ ex) / analysis.eye_distance
        side = np.abs(u) > 0.9
        if side.any():
            low = np.percentile(ys[side] + 0.5, 98)
            x_side = float(np.median(xs[side] + 0.5))
        else:
            low = float(ys.max()) + 0.5
            x_side = float(c2[0])
        y_end = float(back_project(fit, np.array([[x_side, low]]), float(cz))[0, 1])
    return HairShell(np.asarray(c2, np.float64), center3d, float(cz), angles, thickness, hair, head,
                     y_end, y_jaw)


# ---------------------------------------------------------------------------------------------
# strands

def unit_vectors(a: np.ndarray) -> np.ndarray:
    return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)


@dataclass(eq=False)
class Hairline:
    """The lower edge of the rest head's scalp region, by azimuth about the vertical axis
    through `centre` (3,): heights (B,) metres, the lowest scalp vertex of each of B equal
    azimuth bins (azimuth 0 faces +Z, the face), smoothed over `HAIRLINE_SMOOTH` bins either
    side; a bin with no scalp vertex takes its neighbours' by circular interpolation."""

    centre: np.ndarray
    heights: np.ndarray

    @classmethod
    def from_scalp(cls, vertices: np.ndarray, centre: np.ndarray, bins: int | None = None) -> "Hairline":
        """vertices (S, 3): the scalp region's rest vertices."""
        bins = HAIRLINE_BINS if bins is None else bins
        v = np.asarray(vertices, np.float64)
        centre = np.asarray(centre, np.float64)
        b = _azimuth_bin(v, centre, bins)
        low = np.full(bins, np.inf)
        np.minimum.at(low, b, v[:, 1])
        have = np.isfinite(low)
        if not have.any():
            raise InputError("the head model's scalp region is empty")
        k = np.arange(bins)
        low = np.interp(k, k[have], low[have], period=bins)
        r = HAIRLINE_SMOOTH
        low = np.mean([np.roll(low, j) for j in range(-r, r + 1)], axis=0)
        return cls(centre, low)

    def at(self, p: np.ndarray) -> np.ndarray:
        """The hairline's height (N,) at the azimuth of each point (N, 3), linear between the
        bins' centres (a step at each bin's edge would show as a stair in the hair's end)."""
        bins = len(self.heights)
        x = _azimuth_bin_coordinate(np.asarray(p, np.float64), self.centre, bins) - 0.5
        return np.interp(x, np.arange(bins), self.heights, period=bins)


def _azimuth_bin_coordinate(p: np.ndarray, centre: np.ndarray, bins: int) -> np.ndarray:
    """(N,) azimuth about the vertical axis through centre, in bins from -pi: [0, bins)."""
    a = np.arctan2(p[:, 0] - centre[0], p[:, 2] - centre[2])           # (N,) in [-pi, pi]
    return (a + np.pi) / (2 * np.pi) * bins


def _azimuth_bin(p: np.ndarray, centre: np.ndarray, bins: int) -> np.ndarray:
    return np.floor(_azimuth_bin_coordinate(p, centre, bins)).astype(np.int64) % bins


@dataclass(eq=False)
class GrowthContext:
    """Everything a strand step needs."""

    fit: HeadFit
    sdf: object
    shell: HairShell
    flow: np.ndarray
    coherence: np.ndarray
    head_depth: np.ndarray      # (h, w) of the depth camera
    depth_camera: object
    labels: np.ndarray
    crown: np.ndarray
    neck_z: float
    hairline: Hairline | None = None

    def nape_roots(self, roots: np.ndarray) -> np.ndarray:
        """(S,) bool: roots (S, 3) below the photo's lowest hair, which only the `hairline`
        lets grow (behind the ears, the nape); none without one."""
        if self.hairline is None:
            return np.zeros(len(roots), bool)
        return np.asarray(roots, np.float64)[:, 1] < self.shell.y_end

    def hidden_end(self, p: np.ndarray, nape: np.ndarray) -> np.ndarray:
        """Height (N,) below which a hidden strand at p (N, 3) stops: the photo's lowest hair
        (`HairShell.y_end`), or for a strand from a nape root (`nape` (N,) bool) the scalp's
        lower edge at p's azimuth."""
        end = np.full(len(p), self.shell.y_end)
        if nape.any():
            end[nape] = self.hairline.at(p[nape])
        return end


def hidden_from_camera(g: GrowthContext, p: np.ndarray, px: np.ndarray) -> np.ndarray:
    """(N,) bool: points the camera cannot see: behind the head, or behind the neck and body."""
    from avatarkit.recon.segment import BODY, SKIN

    dpx, dz = g.depth_camera.project(p)
    d = lookup(g.head_depth, dpx)
    behind_head = (d > 0) & (dz > d + _visibility.DEPTH_TOL)
    lab = lookup(g.labels, px)
    behind_body = ((lab == BODY) | ((lab == SKIN) & ~lookup(g.shell.head, px))) & (p[:, 2] < g.neck_z)
    return behind_head | behind_body


def shell_thickness(g: GrowthContext, p: np.ndarray, px: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Shell thickness (N,) at points p: the silhouette's, by polar angle, where the surface is
    seen edge-on or from behind; thinner where it faces the camera (over the forehead the
    photo shows no depth, and hair lying there is thin)."""
    view = g.fit.camera.camera_center[None] - p
    facing = np.einsum("ij,ij->i", unit_vectors(view), normal)
    return g.shell.thickness_at(px) * (1.0 - 0.75 * np.clip(facing, 0.0, 1.0))


def comb_direction(g: GrowthContext, p: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Direction (N, 3) of hidden hair: away from the crown along the scalp, turning downward."""
    radial = p - g.crown
    radial[:, 1] = np.minimum(radial[:, 1], 0.0)
    top, bottom = g.crown[1], g.shell.y_jaw
    a = np.clip((p[:, 1] - bottom) / max(top - bottom, 1e-6), 0.0, 1.0)[:, None] ** 2
    d = a * unit_vectors(radial) + (1 - a) * np.array([0.0, -1.0, 0.0])
    d = d - np.einsum("ij,ij->i", d, normal)[:, None] * normal * (a > 0.05)
    return unit_vectors(d)


def flow_to_tangent(g: GrowthContext, f2: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Image directions (N, 2) -> tangent directions (N, 3) that project onto them."""
    r = g.fit.camera.rotation                  # rows: camera x, y, z axes in the rest frame
    eu, ev, ez = r[0], r[1], r[2]
    a = f2[:, :1] * eu + f2[:, 1:] * ev        # (N, 3) in the image plane
    nz = normal @ ez
    lam = -np.einsum("ij,ij->i", a, normal) / np.where(np.abs(nz) > 0.2, nz, np.sign(nz + 1e-12) * 0.2)
    return unit_vectors(a + np.clip(lam, -2.0, 2.0)[:, None] * ez)


def grow_strands(g: GrowthContext, roots: np.ndarray, layer: np.ndarray, max_steps: int,
                 segment: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grow strands from roots (S, 3) with layer fractions (S,) in [0, 1].

    Returns points (S, K+1, 3), alive (S, K) bool (segment k exists), seen (S, K) bool."""
    segment = SEGMENT if segment is None else segment
    cam = g.fit.camera
    s_count = len(roots)
    dist, grad = g.sdf.query(roots)
    # a strand starts on its layer (the rise from the scalp is hidden under the layers above)
    px, _ = cam.project(roots)
    start = MARGIN + layer * np.maximum(shell_thickness(g, roots, px, grad) - MARGIN, 0.0)
    p = roots + grad * (start - dist)[:, None]
    d = comb_direction(g, p, grad)
    nape = g.nape_roots(roots)
    pts = np.empty((s_count, max_steps + 1, 3))
    pts[:, 0] = p
    alive = np.zeros((s_count, max_steps), bool)
    seen = np.zeros((s_count, max_steps), bool)
    live = np.ones(s_count, bool)
    for k in range(max_steps):
        idx = np.flatnonzero(live)
        if len(idx) == 0:
            break
        q = pts[idx, k]
        sd, n = g.sdf.query(q)
        px, _ = cam.project(q)
        hidden = hidden_from_camera(g, q, px)
        want = comb_direction(g, q, n)
        f2 = np.stack([lookup(g.flow[..., 0], px), lookup(g.flow[..., 1], px)], axis=1)
        coh = lookup(g.coherence, px)
        use = ~hidden & (coh > 0.05)
        if use.any():
            # the flow is sign-free: take the sense that agrees with where the strand is going
            cur2 = np.stack([d[idx[use]] @ cam.rotation[0], d[idx[use]] @ cam.rotation[1]], axis=1)
            sgn = np.sign(np.einsum("ij,ij->i", f2[use], cur2) + 1e-9)
            lifted = flow_to_tangent(g, f2[use] * sgn[:, None], n[use])
            wf = np.clip(coh[use] * 2, 0, 0.8)[:, None]
            want[use] = unit_vectors(wf * lifted + (1 - wf) * want[use])
        step = unit_vectors(0.6 * d[idx] + 0.4 * want)
        nxt = q + segment * step
        # keep to the strand's layer in the shell above the jaw; fall freely below it
        nsd, nn = g.sdf.query(nxt)
        npx, _ = cam.project(nxt)
        target = MARGIN + layer[idx] * np.maximum(shell_thickness(g, nxt, npx, nn) - MARGIN, 0.0)
        hug = (nxt[:, 1] > g.shell.y_jaw) & (nsd < target + 0.02)
        # rise to (or sink toward) the layer gradually: a jump would make one long spike. A nape
        # strand sinks as fast as a step: under the back of the skull the scalp turns inward
        # more steeply than half a step per step
        lift = np.clip(target - nsd, np.where(nape[idx], -1.0, -0.5) * segment, 0.5 * segment)
        nxt[hug] += nn[hug] * lift[hug, None]
        low = nsd < MARGIN
        nxt[low & ~hug] += nn[low & ~hug] * (MARGIN - nsd[low & ~hug])[:, None]
        # stop: seen and off the hair mask, or hidden and below the hair's length
        npx, _ = cam.project(nxt)
        nhidden = hidden_from_camera(g, nxt, npx)
        in_hair = lookup(g.shell.hair, npx)
        stop = (~nhidden & ~in_hair) | (nhidden & (nxt[:, 1] < g.hidden_end(nxt, nape[idx])))
        # a nape strand only goes on along the scalp: one that leaves it (over an ear, off the
        # back of the skull) would hang in the air as a wisp
        stop |= nhidden & nape[idx] & ~hug
        ok = ~stop
        d[idx] = unit_vectors(nxt - q)
        pts[idx, k + 1] = nxt
        alive[idx[ok], k] = True
        seen[idx[ok], k] = ~nhidden[ok]
        live[idx[stop]] = False
    return pts, alive, seen


def scalp_roots(fit: HeadFit, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points (n, 3) uniformly by area on the rest head's scalp region."""
    model = fit.model
    v = np.asarray(fit.rest_vertices, np.float64)
    if "scalp" not in model.regions or len(model.regions["scalp"]) == 0:
        raise InputError("the head model has no scalp region to grow hair from")
    faces = model.faces[model.region_mask("scalp")[model.faces].sum(axis=1) >= 2]
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    ids = rng.choice(len(faces), size=n, p=area / area.sum())
    return points_on_triangles(tri[ids], rng)


def hair_colours(image: np.ndarray, hair: np.ndarray, px: np.ndarray, seen: np.ndarray,
                  rng: np.random.Generator, below_end: np.ndarray | None = None) -> np.ndarray:
    """Seen segments: the photo at their projection; hidden ones: a random hair pixel from the
    same band of image rows (whole image's hair when the band has none). Hidden segments
    `below_end` (N,) bool (hair the photo does not reach down to: the nape behind short hair)
    take a random pixel of the hair's interior instead: the rows they project to show face,
    and the lowest hair rows are the hair's edge, half skin or wall."""
    import cv2

    h, w = hair.shape
    rgb = sample_image(image, px) / 255.0
    hidden_mask = ~np.asarray(seen, bool)
    if below_end is not None:
        nape = np.flatnonzero(hidden_mask & below_end)
        hidden_mask &= ~below_end
        inner = cv2.erode(hair.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        iy, ix = np.nonzero(inner if inner.any() else hair)
        if len(nape) and len(iy):
            pick = rng.integers(0, len(iy), len(nape))
            rgb[nape] = image[iy[pick], ix[pick]].astype(np.float32) / 255.0
    ys, xs = np.nonzero(hair)
    hidden = np.flatnonzero(hidden_mask)
    if len(hidden) and len(ys):
        order = np.argsort(ys, kind="stable")
        ys, xs = ys[order], xs[order]
        band = max(2, int(0.03 * h))
        row = np.clip(np.nan_to_num(px[hidden, 1], nan=h / 2), 0, h - 1).astype(np.int64)
        lo = np.searchsorted(ys, row - band)
        hi = np.searchsorted(ys, row + band, side="right")
        empty = hi <= lo
        lo[empty], hi[empty] = 0, len(ys)
        pick = lo + (rng.random(len(hidden)) * (hi - lo)).astype(np.int64)
        pick = np.minimum(pick, len(ys) - 1)
        rgb[hidden] = image[ys[pick], xs[pick]].astype(np.float32) / 255.0
    return rgb


__all__ = ["GrowthContext", "HAIR_REFERENCE_COUNT", "HAIR_THICKNESS", "HAIR_WIDTH", "HairShell", "MARGIN",
           "MAX_SHELL", "SEGMENT", "back_project", "comb_direction", "flow_to_tangent", "grow_strands",
           "hair_colours", "hair_flow", "hair_shell", "hidden_from_camera", "scalp_roots", "shell_thickness",
           "unit_vectors"]
