"""The fast renderer: the standard 3DGS image formation as four stages on Taichi CPU kernels.

Stages (each its own function, gsplat-style, each with a float64 numpy twin in `reference.py`):

1. `project_gaussians`: EWA splatting. Camera-space mean t, covariance W Sigma W^T, the
   Jacobian of the perspective projection at t with x/z and y/z clamped to the image's
   half-extent plus 0.3x the half-FOV (that is INRIA's 1.3 tan(fov/2) for a centred principal
   point; gsplat's form for an off-centre one), 2D covariance J W Sigma W^T J^T + 0.3 I
   (low-pass dilation), conic = its inverse, radius = ceil(3 sqrt(largest eigenvalue)) with
   INRIA's 0.1 floor on the eigenvalue gap. Culled (radius 0): depth z <= `near` (0.01 m, the
   gsplat default: avatars are viewed from tens of centimetres, where INRIA's 0.2 would cut the
   face), opacity < 1/255 (it can never pass the alpha test), a singular 2D covariance, and
   a 3-sigma footprint that touches no tile of the image (frustum culling).
2. `sh_colors`: colour = max(0, SH(dir) + 0.5) up to degree 3, dir = unit(mean - camera
   centre), the INRIA `computeColorFromSH`. Not clamped above (as INRIA).
3. `bin_gaussians`: 16x16 tiles; each Gaussian goes to every tile its 3-sigma square touches
   and, given the opacities (as `render` does), that its alpha >= 1/255 ellipse
   (d^T conic d <= 2 ln(255 opacity), widened by 1%) reaches with a pixel centre: an exact
   ellipse-rectangle test that drops only tiles the compositor would find nothing to draw in
   (the image is the same; ~28% fewer pairs on the bench scene). Depths are sorted once
   (stable, so ties keep input order: a parallel radix sort in as many 12-bit passes as the
   depths' spread needs, `depth_order` is its numpy twin); the ellipse-tile tests run in one
   parallel loop over the splats in input order, each splat's tiles kept as bits in its
   depth-ordered row; the depth-ordered Gaussians are then cut into 16 chunks that are
   counted and scattered in parallel, chunk after chunk within each tile's list, so the
   per-tile lists (`tile_offsets`, `gaussian_ids`) come out depth-sorted. The same passes
   number the listed Gaussians in the order the lists, tile by tile, first name them
   (`TileBins.slots`).
4. `rasterize`: each splat's record (mean, conic, opacity, colour, depth and the half-extents
   of its alpha >= 1/255 ellipse) is packed in row `slots[g]`, so a tile's records lie close
   together in memory; per pixel, in list order, d = mean2d - pixel
   centre, alpha = min(0.99, opacity exp(-0.5 d^T conic d)); alpha < 1/255 is skipped; if
   compositing would bring the transmittance T below 1e-4 the pixel stops *before* that splat
   (INRIA); colour += c alpha T, T *= 1 - alpha. One task per 16x16 tile deals the tile's
   list out into one list per cell of 8 pixels x 2 rows (the cells a splat's extents reach,
   in list order), then composites cell by cell: the cell's 16 pixels are one 16-lane SIMD
   vector held in registers while the cell walks its list, each with its own exponential (an
   inlined float32 `exp`, Cephes `expf`, ~1e-7 relative error), and the cell stops when all
   16 pixels have. Output rgb = colour + T background, alpha = 1 - T,
   depth = the alpha-weighted expected camera-space z (sum z alpha T / (1 - T); 0 where
   nothing was drawn). The stages' working arrays are per-thread buffers kept between
   calls (`_scratch_array`); what they return is always fresh.

Pixel convention (as gsplat/COLMAP): pixel (i, j) has its centre at (i + 0.5, j + 0.5) and
means2d = (fx x/z + cx, fy y/z + cy). The result is deterministic: every tile is composited by
one thread in a fixed order.

Precision: projection runs in float64 (so radii and tile lists match the reference), the
compositing in float32 as in INRIA's CUDA code. Against the float64 reference images differ by
~1e-4; a pixel differs by up to ~1.5e-3 only where some splat's alpha lies within float32
rounding of the 1/255 threshold (about one pixel in 262k on the 50k bench scene).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.limits import MAX_RENDER_PIXELS, MAX_RENDER_SIDE
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.render.camera import Camera

TILE_SIZE = 16
NEAR_PLANE = 0.01
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4
DILATION = 0.3


@dataclass
class Projection:
    """Screen-space Gaussians (stage 1). Rows with radius 0 are culled; their other fields
    are unspecified (zero on the fast path)."""

    means2d: np.ndarray   # (N, 2) float32 pixels
    depths: np.ndarray    # (N,) float32 camera-space z
    conics: np.ndarray    # (N, 3) float32 (a, b, c) of the inverse 2D covariance [[a, b], [b, c]]
    radii: np.ndarray     # (N,) int32 3-sigma radius in pixels, 0 = culled
    tile_rects: np.ndarray  # (N, 4) int32 tiles (x0, y0, x1, y1), half-open

    @property
    def visible(self) -> np.ndarray:
        """(N,) bool."""
        return self.radii > 0


@dataclass
class TileBins:
    """Per-tile, depth-sorted lists of Gaussian indices (stage 3)."""

    tiles_x: int
    tiles_y: int
    tile_offsets: np.ndarray  # (tiles_y * tiles_x + 1,) int32; tile t's list is ids[off[t]:off[t+1]]
    gaussian_ids: np.ndarray  # (P,) int32, P = Gaussian-tile pairs
    # Where `rasterize` packs each splat's record: slots (N,) int32, -1 for a splat in no list;
    # slot_ids (P,) int32 = slots[gaussian_ids]. The order in which the lists, tile by tile,
    # first name the splats (`_kernels.first_sight`). None: rasterize works them out itself.
    slots: np.ndarray | None = None
    slot_ids: np.ndarray | None = None

    @property
    def tile_counts(self) -> np.ndarray:
        """(tiles_y, tiles_x) int32 number of Gaussians in each tile's list."""
        return np.diff(self.tile_offsets).reshape(self.tiles_y, self.tiles_x)


@dataclass
class RenderResult:
    rgb: np.ndarray    # (H, W, 3) float32, not clamped (SH colours may exceed 1)
    alpha: np.ndarray  # (H, W) float32 = 1 - final transmittance
    depth: np.ndarray  # (H, W) float32 alpha-weighted expected camera z; 0 where alpha == 0
    meta: dict = field(default_factory=dict)  # intermediate stages and timings (see `render`)


def tile_grid(camera: Camera) -> tuple[int, int]:
    """(tiles_x, tiles_y) covering the image."""
    return -(-camera.width // TILE_SIZE), -(-camera.height // TILE_SIZE)


def check_background(background) -> np.ndarray:
    """(3,) float32 background colour, or InputError."""
    try:
        bg = np.asarray(background, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"background must be 3 numbers (r, g, b), got {background!r}") from None
    if bg.shape != (3,) or not np.isfinite(bg).all():
        raise InputError(f"background must be 3 finite numbers (r, g, b), got {background!r}")
    return bg.astype(np.float32)


def _check(gaussians, camera, near: float | None = None) -> None:
    near = NEAR_PLANE if near is None else near
    if not isinstance(gaussians, GaussianSet):
        raise InputError(f"render needs a GaussianSet, got {type(gaussians).__name__}")
    if not isinstance(camera, Camera):
        raise InputError(f"render needs a Camera, got {type(camera).__name__}")
    if not (isinstance(near, (int, float)) and np.isfinite(near) and near > 0):
        raise InputError(f"near plane must be a positive distance, got {near!r}")
    check_render_size(camera.width, camera.height)


def check_render_size(width: int, height: int) -> None:
    """InputError unless a `width` x `height` image is within the stated bounds
    (`avatarkit.limits.MAX_RENDER_SIDE`, `MAX_RENDER_PIXELS`): checked before allocating."""
    if max(width, height) > MAX_RENDER_SIDE or width * height > MAX_RENDER_PIXELS:
        raise InputError(f"a {width}x{height} render is too large: at most {MAX_RENDER_SIDE} pixels a "
                         f"side and {MAX_RENDER_PIXELS:,} pixels in all")


def _kernels():
    from avatarkit.render import _kernels
    return _kernels


_calls: dict = {}


def _launch(name: str, *args) -> None:
    """`_kernels.<name>(*args)` through `avatarkit._kernel_call.KernelCall`, which skips Taichi's per-call
    Python work (~0.05 ms of this thread per array argument while the kernel threads wait;
    a 100k frame's launches pass ~55 arrays). The same kernel on the same memory."""
    call = _calls.get(name)
    if call is None:
        from avatarkit._kernel_call import KernelCall
        call = _calls[name] = KernelCall(getattr(_kernels(), name))
    call(*args)


_scratch = threading.local()


def _scratch_array(name: str, shape: tuple, dtype) -> np.ndarray:
    """An uninitialised array for a stage's own working data, which never leaves the stage:
    one buffer per name and thread, kept between calls and grown when too small. A fresh
    array's pages fault in (and are zeroed by the kernel) on first touch: ~3800 faults,
    ~15 MB, per 100k frame, several ms of CPU; reused buffers skip that for everything but
    the arrays a stage returns. Holds ~27 MB per rendering thread at 100k splats (18 of them
    the compositor's cell lists, 16 int32 per splat-tile pair; the binning's ~4)."""
    arrays = getattr(_scratch, "arrays", None)
    if arrays is None:
        arrays = _scratch.arrays = {}
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    buf = arrays.get(name)
    if buf is None or buf.nbytes < nbytes:
        buf = arrays[name] = np.empty(max(nbytes, 8), np.uint8)
    return buf[:nbytes].view(dtype).reshape(shape)


def project_gaussians(gaussians: GaussianSet, camera: Camera, near: float | None = None) -> Projection:
    """Stage 1 (see the module docstring)."""
    near = NEAR_PLANE if near is None else near
    _check(gaussians, camera, near)
    n = len(gaussians)
    proj = Projection(np.zeros((n, 2), np.float32), np.zeros(n, np.float32),
                      np.zeros((n, 3), np.float32), np.zeros(n, np.int32), np.zeros((n, 4), np.int32))
    if n:
        _launch("project", gaussians.means, gaussians.quats, gaussians.scales,
                gaussians.opacities, np.ascontiguousarray(camera.world_to_camera, np.float64),
                camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height,
                float(near), proj.means2d, proj.depths, proj.conics, proj.radii, proj.tile_rects)
    return proj


def sh_colors(gaussians: GaussianSet, camera: Camera) -> np.ndarray:
    """Stage 2: view-dependent colours (N, 3) float32 (see the module docstring)."""
    _check(gaussians, camera)
    colors = np.zeros((len(gaussians), 3), np.float32)
    if len(gaussians):
        c = camera.camera_center
        _launch("sh_colors", gaussians.sh, gaussians.means, float(c[0]), float(c[1]),
                float(c[2]), colors)
    return colors


def depth_order(depths: np.ndarray) -> np.ndarray:
    """Stable argsort (ties keep input order) of positive float32 depths (M,) -> (M,) int32.

    Positive IEEE floats order like their bit patterns, so this is an LSD radix sort on two
    16-bit halves, each numpy's stable radix sort: ~10x faster than argsort(kind="stable").
    The numpy twin of the binning's own sort (`_kernels.bin_prepare`, parallel, the same
    order); the tests and the benchmark's baseline use it.
    """
    keys = np.ascontiguousarray(depths, np.float32).view(np.uint32)
    order = np.argsort((keys & 0xFFFF).astype(np.uint16), kind="stable")
    order = order[np.argsort((keys >> 16).astype(np.uint16)[order], kind="stable")]
    return order.astype(np.int32)


def tile_q_limits(opacities: np.ndarray) -> np.ndarray:
    """(N,) float32 bound on q = d^T conic d beyond which a splat's alpha is below 1/255
    (the numpy twin of the binning kernel's own, identical computation):
    alpha = opacity exp(-q / 2) >= 1/255 <=> q <= 2 ln(255 opacity); widened by 1% + 0.05 so
    float32 rounding in the compositor (errors ~1e-7 of the largest term of q) can never make
    a pixel the tile test left out pass the alpha test."""
    op = np.maximum(np.asarray(opacities, np.float64), ALPHA_MIN)
    return (2.0 * np.log(op / ALPHA_MIN) * 1.01 + 0.05).astype(np.float32)


def bin_gaussians(proj: Projection, camera: Camera, opacities: np.ndarray | None = None) -> TileBins:
    """Stage 3 (see the module docstring). With `opacities` (N,) a splat goes only to the tiles
    of its 3-sigma rect that its alpha >= 1/255 ellipse reaches (exact ellipse-rectangle test,
    `tile_q_limits`): the same image, ~30% fewer pairs on the bench scene."""
    tiles_x, tiles_y = tile_grid(camera)
    n_tiles = tiles_x * tiles_y
    n = len(proj.radii)
    offsets = np.zeros(n_tiles + 1, np.int32)
    slots = np.full(n, -1, np.int32)
    if not (proj.radii > 0).any():
        return TileBins(tiles_x, tiles_y, offsets, np.zeros(0, np.int32), slots, np.zeros(0, np.int32))
    k = _kernels()
    snug = opacities is not None
    ops = np.ascontiguousarray(opacities if snug else np.zeros(n), np.float32)
    total = _scratch_array("bin_total", (3,), np.int32)  # visible splats, sort passes, least key
    idx = _scratch_array("bin_idx", (2, n), np.int32)
    # depth-ordered rows [:m], m = visible splats
    s_rect = _scratch_array("bin_rect", (n, 2), np.int32)
    s_hits = _scratch_array("bin_hits", (n,), np.int64)
    s_first = _scratch_array("bin_first", (n,), np.int32)
    # [0]: list entries, [1]: first tiles; then where each chunk's part of them starts
    counts = _scratch_array("bin_counts", (2, k.BIN_CHUNKS, n_tiles), np.int32)
    counts.fill(0)
    rank = _scratch_array("bin_rank", (n,), np.int32)
    rank.fill(-1)
    _launch("bin_prepare", proj.depths, proj.radii, proj.tile_rects, proj.means2d, proj.conics,
            ops, int(snug), tiles_x, camera.width, camera.height,
            _scratch_array("bin_keys", (2, n), np.int32), idx,
            _scratch_array("bin_hist", (k.SORT_CHUNKS, k.RADIX), np.int32),
            _scratch_array("bin_spans", (k.SORT_CHUNKS, 2), np.int32), total, rank,
            s_rect, s_hits, s_first, counts[0], counts[1], offsets)
    ids = np.empty(int(offsets[-1]), np.int32)
    slot_ids = np.empty_like(ids)
    _launch("scatter_tiles", idx[k.order_row(int(total[1])), :int(total[0])], s_rect, s_hits,
            proj.means2d, proj.conics, ops, int(snug), tiles_x, camera.width, camera.height,
            counts[0], ids, counts[1], slots, slot_ids)
    return TileBins(tiles_x, tiles_y, offsets, ids, slots, slot_ids)


def rasterize(proj: Projection, colors: np.ndarray, opacities: np.ndarray, bins: TileBins,
              camera: Camera, background=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 4: (rgb (H, W, 3), alpha (H, W), depth (H, W)), float32 (see the module docstring).

    colors: (N, 3) float32; opacities: (N,) float32.
    """
    bg = check_background(background)
    h, w = camera.height, camera.width
    rgb = np.empty((h, w, 3), np.float32)
    alpha = np.empty((h, w), np.float32)
    depth = np.empty((h, w), np.float32)
    if len(bins.gaussian_ids) == 0:
        rgb[:] = bg
        return rgb, np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    k = _kernels()
    slot, sids = bins.slots, bins.slot_ids
    if slot is None or sids is None:
        slot = np.full(len(proj.radii), -1, np.int32)
        sids = np.empty_like(bins.gaussian_ids)
        _launch("first_sight", bins.gaussian_ids, slot, sids)
    packed = _scratch_array("packed", (int(slot.max()) + 1, k.PACK), np.float32)
    _launch("pack_splats", slot, proj.means2d, proj.conics,
            np.ascontiguousarray(opacities, np.float32), np.ascontiguousarray(colors, np.float32),
            proj.depths, packed)
    lists = _scratch_array("cell_lists", (k.CELLS * len(sids),), np.int32)
    _launch("rasterize", bins.tile_offsets, sids, packed, lists, float(bg[0]), float(bg[1]),
            float(bg[2]), rgb, alpha, depth)
    return rgb, alpha, depth


def render(gaussians: GaussianSet, camera: Camera, background=(0.0, 0.0, 0.0),
           near: float | None = None) -> RenderResult:
    """Render splats with the standard 3DGS image formation (module docstring), on the CPU.

    background: (r, g, b) in linear [0, 1] units, composited under the splats.
    meta: means2d, depths, conics, radii, tile_rects (per Gaussian, stage 1), colors (stage 2),
    tile_offsets, gaussian_ids, tile_counts (tiles_y, tiles_x), n_visible, n_pairs (stage 3),
    timings {project, sh, bin, rasterize, total} in seconds.
    """
    near = NEAR_PLANE if near is None else near
    _check(gaussians, camera, near)
    bg = check_background(background)
    t0 = time.perf_counter()
    proj = project_gaussians(gaussians, camera, near)
    t1 = time.perf_counter()
    colors = sh_colors(gaussians, camera)
    t2 = time.perf_counter()
    bins = bin_gaussians(proj, camera, gaussians.opacities)
    t3 = time.perf_counter()
    rgb, alpha, depth = rasterize(proj, colors, gaussians.opacities, bins, camera, bg)
    t4 = time.perf_counter()
    meta = dict(means2d=proj.means2d, depths=proj.depths, conics=proj.conics, radii=proj.radii,
                tile_rects=proj.tile_rects, colors=colors, tile_offsets=bins.tile_offsets,
                gaussian_ids=bins.gaussian_ids, tile_counts=bins.tile_counts,
                n_visible=int(np.count_nonzero(proj.radii)), n_pairs=int(len(bins.gaussian_ids)),
                timings=dict(project=t1 - t0, sh=t2 - t1, bin=t3 - t2, rasterize=t4 - t3,
                             total=t4 - t0))
    return RenderResult(rgb, alpha, depth, meta)
