"""The renderer: fast (Taichi) vs reference (numpy float64) stage by stage, analytic cases,
culling, compositing rules, SH, determinism and bad input."""
import math
from dataclasses import replace

import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.sh import SH_COUNTS, rgb_to_dc, sh_basis
from avatarkit.render import (Camera, Projection, bin_gaussians, project_gaussians, rasterize,
                              render, sh_colors)
from avatarkit.render.pipeline import depth_order, tile_q_limits
from avatarkit.render.reference import (ellipse_meets_tiles, isotropic_screen_sigma, project_reference,
                                        render_reference, sh_colors_reference)

IDENTITY_QUAT = [1.0, 0.0, 0.0, 0.0]


def random_scene(n, seed, sh_degree=0, width=67, height=45, spread=1.0):
    """n random splats in front of a random camera with an off-centre principal point."""
    rng = np.random.default_rng(seed)
    target = rng.normal(size=3) * 0.1
    cam = Camera.orbit(target, rng.uniform(0, 360), rng.uniform(-40, 40), 2.0,
                       rng.uniform(25, 50), width, height)
    cam = Camera(cam.fx * rng.uniform(0.9, 1.1), cam.fy, cam.cx + rng.uniform(-5, 5),
                 cam.cy + rng.uniform(-5, 5), width, height, cam.world_to_camera)
    means = target + rng.normal(size=(n, 3)) * 0.35 * spread
    q = rng.normal(size=(n, 4))
    scales = 0.02 * np.exp(0.6 * rng.normal(size=(n, 3)))
    sh = rng.normal(scale=0.4, size=(n, SH_COUNTS[sh_degree], 3))
    sh[:, 0] = rgb_to_dc(rng.uniform(size=(n, 3)))
    gs = GaussianSet(means, q / np.linalg.norm(q, axis=1, keepdims=True), scales,
                     rng.uniform(0.05, 1.0, n), sh)
    return gs, cam


def single(mean, scale, opacity, rgb, quat=IDENTITY_QUAT):
    return GaussianSet.from_colors([mean], [quat], [[scale] * 3 if np.isscalar(scale) else scale],
                                   [opacity], [rgb])


def head_on_camera(width=64, height=64, f=80.0):
    # principal point on a pixel centre, so a splat on the axis peaks exactly on pixel (32, 32)
    return Camera(f, f, width // 2 + 0.5, height // 2 + 0.5, width, height)


# --- fast vs reference ------------------------------------------------------------------------

@pytest.mark.parametrize("seed, sh_degree", [(0, 0), (1, 1), (2, 2), (3, 3), (4, 3)])
def test_fast_matches_reference_on_random_scenes(seed, sh_degree):
    gs, cam = random_scene(400, seed, sh_degree)
    bg = np.random.default_rng(seed).uniform(size=3)
    fast = render(gs, cam, bg)
    ref = render_reference(gs, cam, bg)
    assert fast.rgb.dtype == np.float32 and fast.rgb.shape == (45, 67, 3)
    assert np.abs(fast.rgb - ref.rgb).max() < 1e-3
    assert np.abs(fast.alpha - ref.alpha).max() < 1e-3
    drawn = ref.alpha > 0.05
    assert np.abs(fast.depth - ref.depth)[drawn].max() < 1e-3 * ref.depth[drawn].max()
    assert ref.alpha.max() > 0.5 and (ref.alpha < 0.01).any()  # a scene with content and gaps


@pytest.mark.parametrize("width", [48, 45])
def test_fast_matches_reference_with_early_termination(width):
    # many opaque splats on one spot: most pixels stop at T < 1e-4. Width 45 cuts the last
    # tile column at 13 pixels: the compositor's 8-pixel blocks there reach past the image
    gs, cam = random_scene(600, 7, 1, width=width, height=40, spread=0.8)
    gs = gs.replace(opacities=np.full(len(gs), 0.97, np.float32), scales=gs.scales * 4)
    fast = render(gs, cam)
    ref = render_reference(gs, cam)
    assert (ref.alpha > 1 - 1e-3).mean() > 0.3
    assert np.abs(fast.rgb - ref.rgb).max() < 1e-3
    assert np.abs(fast.alpha - ref.alpha).max() < 1e-3


def test_fast_matches_reference_on_large_and_needle_splats():
    # wide splats (rows of many 8-pixel blocks) and thin rotated ellipses (the extents)
    rng = np.random.default_rng(8)
    n = 60
    scales = np.where(rng.uniform(size=(n, 1)) < 0.5, [0.4, 0.002, 0.002], [0.3, 0.25, 0.2])
    q = rng.normal(size=(n, 4))
    gs = GaussianSet.from_colors(rng.normal(size=(n, 3)) * 0.3, q, scales * rng.uniform(0.2, 1, (n, 1)),
                                 rng.uniform(0.02, 0.9, n), rng.uniform(size=(n, 3)))
    cam = Camera.orbit((0, 0, 0), 20, 10, 1.5, 60, 80, 72)
    fast, ref = render(gs, cam, (0.3, 0.3, 0.3)), render_reference(gs, cam, (0.3, 0.3, 0.3))
    assert np.abs(fast.rgb - ref.rgb).max() < 1e-3
    assert np.abs(fast.alpha - ref.alpha).max() < 1e-3
    assert fast.meta["radii"].max() > 40


@pytest.mark.parametrize("width, height", [(37, 29), (16, 17)])
def test_fast_matches_reference_at_odd_sizes(width, height):
    # the compositor's cells are 8 pixels x 2 rows: an odd height cuts the last cell row in
    # half and a width of 37 the last tile column at 5 pixels; lanes past the edges are
    # composited but must never be written out
    gs, cam = random_scene(500, 9, 1, width=width, height=height, spread=2.0)
    fast, ref = render(gs, cam, (0.2, 0.5, 0.9)), render_reference(gs, cam, (0.2, 0.5, 0.9))
    assert fast.rgb.shape == (height, width, 3)
    assert np.abs(fast.rgb - ref.rgb).max() < 1e-3
    assert np.abs(fast.alpha - ref.alpha).max() < 1e-3
    assert ref.alpha[-1].max() > 0.05 and ref.alpha[:, -1].max() > 0.05  # content at the edges


def test_cells_cover_every_pixel_a_splat_draws():
    # `cell_mask` decides which (splat, 8x2 cell) pairs the compositor visits: every pixel
    # where a listed splat's alpha (float64, from its packed record) reaches 1/255 must lie in
    # one of that splat's cells, and the cells must stay within the splat's extents
    from avatarkit.render import _kernels as k

    ti = k.ti

    @ti.kernel
    def cell_masks(offsets: k.i32_1, ids: k.i32_1, packed: k.f32_2, width: ti.i32,
                   height: ti.i32, out: k.u32_1):
        tiles_x = (width + k.TILE - 1) // k.TILE
        for t in range(offsets.shape[0] - 1):
            x0 = (t % tiles_x) * k.TILE
            y0 = (t // tiles_x) * k.TILE
            for e in range(offsets[t], offsets[t + 1]):
                s = ids[e]
                out[e] = k.cell_mask(packed[s, 0], packed[s, 1], packed[s, 6], packed[s, 7], x0,
                                     y0, ti.min(x0 + k.TILE, width), ti.min(y0 + k.TILE, height))

    for seed, spread in ((0, 1.0), (1, 0.3)):
        gs, cam = random_scene(250, 20 + seed, 0, width=53, height=37, spread=spread)
        gs = gs.replace(scales=gs.scales * np.random.default_rng(seed).uniform(0.3, 3, (len(gs), 1)))
        proj = project_gaussians(gs, cam)
        bins = bin_gaussians(proj, cam, gs.opacities)
        packed = np.zeros((int(bins.slots.max()) + 1, k.PACK), np.float32)
        k.pack_splats(bins.slots, proj.means2d, proj.conics, gs.opacities,
                      sh_colors(gs, cam), proj.depths, packed)
        masks = np.empty(len(bins.slot_ids), np.uint32)
        cell_masks(bins.tile_offsets, bins.slot_ids, packed, cam.width, cam.height, masks)
        py, px = np.mgrid[0:cam.height, 0:cam.width] + 0.5
        drawn = cells = 0
        for t in range(bins.tiles_x * bins.tiles_y):
            x0, y0 = (t % bins.tiles_x) * 16, (t // bins.tiles_x) * 16
            tile = (slice(y0, y0 + 16), slice(x0, x0 + 16))
            cell_of = ((px[tile] - x0) // 8 * 8 + (py[tile] - y0) // 2).astype(np.uint32)
            sel = slice(bins.tile_offsets[t], bins.tile_offsets[t + 1])
            for s, m in zip(bins.slot_ids[sel], masks[sel]):
                rec = packed[s].astype(np.float64)
                dx, dy = rec[0] - px[tile], rec[1] - py[tile]
                q = -2 * (rec[2] * dx * dx + rec[3] * dx * dy + rec[4] * dy * dy)
                draws = rec[5] * np.exp(-0.5 * q) >= 1 / 255
                inside = (m >> cell_of) & 1 == 1
                assert inside[draws].all()
                drawn += draws.sum()
                cells += bin(int(m)).count("1")
                # no cell beyond the extents' rectangle (rows and 8-pixel blocks)
                near = (np.abs(dx) <= rec[6] + 8) & (np.abs(dy) <= rec[7] + 2)
                assert not (inside & ~near).any()
        assert drawn > 1000 and cells < 0.8 * len(masks) * k.CELLS


def test_scratch_buffers_carry_nothing_between_frames():
    # the binning's and compositor's working arrays are reused between calls (per thread):
    # a small scene rendered after a large one must come out bit for bit as from scratch
    from avatarkit.render import pipeline

    big, big_cam = random_scene(3000, 30, 1, width=96, height=80, spread=1.5)
    small, small_cam = random_scene(150, 31, 1, width=40, height=33)
    pipeline._scratch.arrays = {}
    fresh = render(small, small_cam)
    render(big, big_cam)
    again = render(small, small_cam)
    for a, b in ((fresh.rgb, again.rgb), (fresh.alpha, again.alpha), (fresh.depth, again.depth)):
        np.testing.assert_array_equal(a, b)
    assert pipeline._scratch.arrays["bin_hits"].nbytes >= 3000 * 8  # the buffers did carry over


def test_kernel_call_launches_like_taichis_plain_call(monkeypatch):
    # the stages launch their kernels through `avatarkit._kernel_call.KernelCall`, which fills Taichi's
    # launch context itself: a frame through it must be Taichi's own call's, bit for bit
    # (arrays of 1-3 dimensions, ints and floats: the background, the camera), and the
    # fast path must be the one taken
    from avatarkit.render import pipeline

    gs, cam = random_scene(800, 40, 3, width=70, height=50)
    fast = render(gs, cam, background=(0.2, 0.3, 0.4))
    assert {"project", "sh_colors", "bin_prepare", "scatter_tiles", "pack_splats",
            "rasterize"} <= set(pipeline._calls)
    assert all(i is not False for c in pipeline._calls.values() for i in c._instances.values())
    monkeypatch.setattr(pipeline, "_launch",
                        lambda name, *args: getattr(pipeline._kernels(), name)(*args))
    plain = render(gs, cam, background=(0.2, 0.3, 0.4))
    for a, b in ((fast.rgb, plain.rgb), (fast.alpha, plain.alpha), (fast.depth, plain.depth),
                 (fast.meta["gaussian_ids"], plain.meta["gaussian_ids"]),
                 (fast.meta["conics"], plain.meta["conics"])):
        np.testing.assert_array_equal(a, b)
    assert fast.alpha.max() > 0.5


def test_compositor_exp_matches_numpy():
    # the compositor's inlined float32 exp (Cephes expf), over every exponent it meets: alpha
    # >= 1/255 needs x >= ln(1/255) ~ -5.5; far lanes of a block go down to the -87 clamp
    from avatarkit.render import _kernels as k

    ti = k.ti

    @ti.kernel
    def exp_all(x: k.f32_1, out: k.f32_1):
        for i in range(x.shape[0]):
            out[i] = k.exp_f32(x[i])

    x = np.concatenate([np.linspace(-87.0, 0.0, 20001), -np.geomspace(1e-8, 1.0, 200), [0.0]])
    x = x.astype(np.float32)
    got = np.empty_like(x)
    exp_all(x, got)
    want = np.exp(x.astype(np.float64))
    assert np.abs(got / want - 1).max() < 3e-7  # ~2 ulp
    assert got[-1] == 1.0
    below = np.array([-87.0, -100.0, -1e4], np.float32)
    exp_all(below, got[:3])
    assert (got[:3] == got[0]).all() and 0 < got[0] < 1e-37  # clamped: alpha far below 1/255


def test_projection_stage_matches_reference():
    gs, cam = random_scene(500, 11, 0)
    fast = project_gaussians(gs, cam)
    ref = project_reference(gs, cam)
    np.testing.assert_array_equal(fast.radii, ref.radii)
    np.testing.assert_array_equal(fast.tile_rects, ref.tile_rects)
    vis = ref.radii > 0
    assert 50 < vis.sum() < len(gs)
    np.testing.assert_allclose(fast.means2d[vis], ref.means2d[vis], rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(fast.depths, ref.depths, rtol=1e-6)
    np.testing.assert_allclose(fast.conics[vis], ref.conics[vis], rtol=1e-5, atol=1e-8)


def test_sh_color_stage_matches_reference():
    for degree in range(4):
        gs, cam = random_scene(300, 20 + degree, degree)
        np.testing.assert_allclose(sh_colors(gs, cam), sh_colors_reference(gs, cam), atol=2e-6)


def test_binning_gives_depth_sorted_lists_of_covering_splats():
    gs, cam = random_scene(300, 5, 0)
    proj = project_gaussians(gs, cam)
    bins = bin_gaussians(proj, cam)
    rects = proj.tile_rects
    for t in range(bins.tiles_x * bins.tiles_y):
        ty, tx = divmod(t, bins.tiles_x)
        covering = np.flatnonzero((proj.radii > 0) & (rects[:, 0] <= tx) & (tx < rects[:, 2])
                                  & (rects[:, 1] <= ty) & (ty < rects[:, 3]))
        expected = covering[np.argsort(proj.depths[covering], kind="stable")]
        got = bins.gaussian_ids[bins.tile_offsets[t]:bins.tile_offsets[t + 1]]
        np.testing.assert_array_equal(got, expected)
    assert bins.tile_counts.shape == (bins.tiles_y, bins.tiles_x)


def test_snug_binning_drops_only_tiles_the_splat_cannot_reach():
    # more splats than binning chunks, large and needle-like ones among them
    gs, cam = random_scene(400, 6, 0, width=83, height=61)
    gs = gs.replace(scales=gs.scales * np.where(np.arange(len(gs))[:, None] % 7 == 0, [8.0, 0.1, 0.1], 1.0))
    proj = project_gaussians(gs, cam)
    loose, snug = bin_gaussians(proj, cam), bin_gaussians(proj, cam, gs.opacities)
    qlims = tile_q_limits(gs.opacities)
    # float64 alpha of every splat at every pixel centre
    py, px = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    a, b, c = (proj.conics[:, j, None, None].astype(np.float64) for j in range(3))
    dx = proj.means2d[:, 0, None, None] - px
    dy = proj.means2d[:, 1, None, None] - py
    alpha = gs.opacities[:, None, None] * np.exp(-0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy)
    dropped_any = 0
    for tx, ty, all_ids, meets in _snug_lists_match_numpy(loose, snug, proj, qlims, cam):
        dropped = all_ids[~meets]
        dropped_any += len(dropped)
        tile = alpha[dropped, ty * 16:(ty + 1) * 16, tx * 16:(tx + 1) * 16]
        assert tile.size == 0 or tile.max() < 0.9 / 255  # a dropped splat never reaches 1/255
    assert 0.1 * len(loose.gaussian_ids) < dropped_any  # the test is not vacuous
    full_lists = rasterize(proj, sh_colors(gs, cam), gs.opacities, loose, cam)[0]
    np.testing.assert_array_equal(render(gs, cam).rgb, full_lists)  # the same image


def _snug_lists_match_numpy(loose, snug, proj, qlims, cam):
    """Per tile: assert the snug list is the loose (3-sigma) list cut by the numpy ellipse test,
    in the same depth order; yield (tx, ty, loose ids, which of them meet the tile)."""
    for t in range(snug.tiles_x * snug.tiles_y):
        ty, tx = divmod(t, snug.tiles_x)
        all_ids = loose.gaussian_ids[loose.tile_offsets[t]:loose.tile_offsets[t + 1]]
        got = snug.gaussian_ids[snug.tile_offsets[t]:snug.tile_offsets[t + 1]]
        meets = ellipse_meets_tiles(proj.means2d[all_ids], proj.conics[all_ids], qlims[all_ids],
                                    tx, ty, cam)
        np.testing.assert_array_equal(got, all_ids[meets])  # same depth order, a subset
        yield tx, ty, all_ids, meets


def test_snug_binning_of_splats_with_more_tiles_than_hit_bits():
    # count_tiles hands a splat's tiles to the scatter as 63 bits; splats whose rect has more
    # tiles are tested again there: both kinds must give the numpy twin's lists
    gs, cam = random_scene(200, 9, 0, width=160, height=144)
    gs = gs.replace(scales=gs.scales * np.where(np.arange(len(gs))[:, None] % 5 == 0, 15.0, 1.0))
    proj = project_gaussians(gs, cam)
    r = proj.tile_rects
    tiles = (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])
    assert (tiles > 63).sum() >= 5 and ((tiles <= 63) & (proj.radii > 0)).sum() >= 50
    loose, snug = bin_gaussians(proj, cam), bin_gaussians(proj, cam, gs.opacities)
    for _ in _snug_lists_match_numpy(loose, snug, proj, tile_q_limits(gs.opacities), cam):  # every tile
        pass
    big = np.flatnonzero(tiles > 63)
    assert np.isin(loose.gaussian_ids, big).sum() > np.isin(snug.gaussian_ids, big).sum()


def _tied_depths(case, rng, n):
    """Depths with ties everywhere, and the sort passes the binning should take for them: as
    many 12-bit passes as the spread of their bit patterns (largest - least) needs."""
    if case == "wide":  # 40 distinct depths from 0.02 to 50: three passes
        return rng.choice(rng.uniform(0.02, 50.0, 40), n).astype(np.float32), 3
    if case == "across_half":  # 0.4-0.7 (spread < 2^24): two passes; ties broken by the low
        # 12 bits as well as the next 12 (neighbours a few ulps apart)
        base = rng.uniform(0.4, 0.7, 30).astype(np.float32)
        near = base[:, None].view(np.int32) + rng.integers(0, 5000, (30, 4)).astype(np.int32)
        return rng.choice(near.reshape(-1).view(np.float32), n), 2
    if case == "spread_2_24":  # a spread of exactly 2^24: three passes
        lo = np.float32(2.0).view(np.int32)
        keys = np.array([lo, lo + (1 << 24), lo + 4095, lo + 4096, lo + (1 << 23)], np.int32)
        return rng.choice(keys.view(np.float32), n), 3
    if case == "narrow":  # within 4096 ulps: one pass
        keys = np.float32(0.6).view(np.int32) + rng.integers(0, 4096, 40).astype(np.int32)
        return rng.choice(keys.view(np.float32), n), 1
    return np.full(n, 0.75, np.float32), 1  # one depth


@pytest.mark.parametrize("case", ["wide", "across_half", "spread_2_24", "narrow", "one_depth"])
def test_binning_sorts_tied_depths_stably_over_many_chunks(case):
    # the kernel's radix sort against numpy's stable argsort, through the tile lists: 5000
    # splats (many per sort and bin chunk), ties everywhere, a fifth culled, rects of 1-9
    # tiles; loose binning, so every tile of a rect is listed. One, two or three 12-bit
    # passes, by the keys' spread: each path, and the choice, are checked.
    from avatarkit.render import pipeline

    rng = np.random.default_rng(3)
    n, cam = 5000, Camera(60.0, 60.0, 40.0, 40.0, 83, 61)
    tiles_x, tiles_y = 6, 4
    x0, y0 = rng.integers(0, tiles_x, n), rng.integers(0, tiles_y, n)
    rects = np.stack([x0, y0, np.minimum(x0 + rng.integers(1, 4, n), tiles_x),
                      np.minimum(y0 + rng.integers(1, 4, n), tiles_y)], 1).astype(np.int32)
    radii = np.where(rng.random(n) < 0.2, 0, 5).astype(np.int32)
    rects[radii == 0] = 0
    depths, passes = _tied_depths(case, rng, n)
    depths[radii == 0] = rng.uniform(-5, 100, (radii == 0).sum())  # culled: any depth
    conics = np.tile(np.float32([0.1, 0.0, 0.1]), (n, 1))
    proj = Projection(rng.uniform(0, 80, (n, 2)).astype(np.float32), depths, conics, radii, rects)
    bins = bin_gaussians(proj, cam)
    assert pipeline._scratch.arrays["bin_total"].view(np.int32)[1] == passes
    order = np.flatnonzero(radii > 0)
    assert len(np.unique(depths[order])) < len(order) / 10  # ties
    order = order[np.argsort(depths[order], kind="stable")]
    for t in range(tiles_x * tiles_y):
        ty, tx = divmod(t, tiles_x)
        inside = (rects[order, 0] <= tx) & (tx < rects[order, 2]) & (rects[order, 1] <= ty) & (ty < rects[order, 3])
        got = bins.gaussian_ids[bins.tile_offsets[t]:bins.tile_offsets[t + 1]]
        np.testing.assert_array_equal(got, order[inside])


def test_binning_q_limit_is_the_numpy_twins():
    # the binning kernel's alpha >= 1/255 bound on q (`_kernels.splat_geo`) must be
    # `tile_q_limits` bit for bit: its constants are float64 (a bare Python float in a
    # kernel is a float32 literal, which gave a different float32 limit for ~1 in 4)
    from avatarkit.render import _kernels as k

    ti = k.ti

    @ti.kernel
    def q_limits(means: k.f32_2, conics: k.f32_2, ops: k.f32_1,
                 out: ti.types.ndarray(dtype=ti.f64, ndim=1)):
        for i in range(ops.shape[0]):
            _, _, _, _, _, q = k.splat_geo(means, conics, ops, 1, i)
            out[i] = q

    rng = np.random.default_rng(5)
    ops = np.concatenate([rng.uniform(0, 1, 200_000), rng.uniform(0, 0.01, 20_000),
                          [0.0, 1 / 255, 0.5, 1.0]]).astype(np.float32)
    means, conics = np.zeros((len(ops), 2), np.float32), np.ones((len(ops), 3), np.float32)
    got = np.empty(len(ops), np.float64)
    q_limits(means, conics, ops, got)
    np.testing.assert_array_equal(got, tile_q_limits(ops).astype(np.float64))


@pytest.mark.parametrize("case", ["random", "snug_fallback", "cut_edge"])
def test_binning_slots_are_the_serial_first_sight_order(case):
    # the scatter hands out the packed records' rows in parallel; the serial `first_sight`
    # pass over the lists is the definition. The image is the same either way.
    from avatarkit.render import _kernels as k

    if case == "random":
        gs, cam = random_scene(600, 12, 0, width=96, height=80)
    elif case == "snug_fallback":  # rects of more than 63 tiles: the scatter tests again
        gs, cam = random_scene(200, 9, 0, width=160, height=144)
        gs = gs.replace(scales=gs.scales * np.where(np.arange(len(gs))[:, None] % 5 == 0, 15.0, 1.0))
    else:
        gs, cam = random_scene(400, 13, 0, width=45, height=37)
    proj = project_gaussians(gs, cam)
    bins = bin_gaussians(proj, cam, gs.opacities)
    slot = np.full(len(gs), -1, np.int32)
    sids = np.empty_like(bins.gaussian_ids)
    k.first_sight(bins.gaussian_ids, slot, sids)
    assert (slot >= 0).sum() > 50 and (slot < 0).any()  # listed and unlisted splats
    np.testing.assert_array_equal(bins.slots, slot)
    np.testing.assert_array_equal(bins.slot_ids, sids)
    colors = sh_colors(gs, cam)
    serial = rasterize(proj, colors, gs.opacities, replace(bins, slots=None, slot_ids=None), cam)
    for got, want in zip(rasterize(proj, colors, gs.opacities, bins, cam), serial):
        np.testing.assert_array_equal(got, want)


def test_depth_order_is_a_stable_argsort():
    rng = np.random.default_rng(0)
    d = rng.choice(rng.uniform(0.01, 100, 50).astype(np.float32), 5000)  # many ties
    np.testing.assert_array_equal(depth_order(d), np.argsort(d, kind="stable"))


# --- analytic cases ---------------------------------------------------------------------------

@pytest.mark.parametrize("scale, depth", [(0.02, 1.0), (0.05, 3.0), (0.003, 1.5)])
def test_single_isotropic_gaussian_peak_and_screen_sigma(scale, depth):
    cam = head_on_camera()
    opacity, rgb = 0.8, np.array([0.9, 0.5, 0.2])
    res = render(single([0, 0, depth], scale, opacity, rgb), cam)
    np.testing.assert_allclose(res.rgb[32, 32], opacity * rgb, rtol=1e-5)
    assert res.alpha[32, 32] == pytest.approx(opacity, rel=1e-6)
    assert res.depth[32, 32] == pytest.approx(depth, rel=1e-6)
    sigma = isotropic_screen_sigma(scale, depth, cam.fx)
    assert sigma == pytest.approx(math.sqrt((cam.fx * scale / depth) ** 2 + 0.3))
    # fit the profile along the row and the column through the peak: log alpha vs d^2
    for profile in (res.alpha[32, :], res.alpha[:, 32]):
        d = np.arange(64) - 32.0
        keep = profile > 0
        assert keep.sum() >= 3
        slope = np.polyfit(d[keep] ** 2, np.log(profile[keep] / opacity), 1)[0]
        assert math.sqrt(-0.5 / slope) == pytest.approx(sigma, rel=1e-4)
        # nothing drawn where alpha < 1/255 (beyond ~3.3 sigma here)
        assert (profile[np.abs(d) > sigma * math.sqrt(2 * math.log(255 * opacity)) + 1] == 0).all()


def test_two_opaque_gaussians_composite_in_depth_order():
    cam = head_on_camera()
    near = ([0, 0, 1.0], 0.05, 0.9, [1.0, 0.0, 0.0])
    far = ([0, 0, 2.0], 0.1, 0.9, [0.0, 1.0, 0.0])
    a = GaussianSet.concat([single(*near), single(*far)])
    b = GaussianSet.concat([single(*far), single(*near)])
    ra, rb = render(a, cam, (0, 0, 1)), render(b, cam, (0, 0, 1))
    np.testing.assert_array_equal(ra.rgb, rb.rgb)
    np.testing.assert_array_equal(ra.alpha, rb.alpha)
    # centre: red over green over blue background, alpha 0.9 each
    np.testing.assert_allclose(ra.rgb[32, 32], [0.9, 0.9 * 0.1, 0.01], rtol=1e-5)
    np.testing.assert_allclose(ra.depth[32, 32], (0.9 * 1.0 + 0.09 * 2.0) / 0.99, rtol=1e-5)
    np.testing.assert_allclose(render_reference(b, cam, (0, 0, 1)).rgb, ra.rgb, atol=1e-5)


@pytest.mark.parametrize("opacity", [0.995, 1.0])
def test_alpha_is_clamped_to_0_99(opacity):
    # 3DGS clamps each splat's alpha to 0.99, so one splat never hides what is behind it
    # completely: at the peak, alpha is 0.99 whatever the opacity above it
    cam = head_on_camera()
    front = single([0, 0, 1.0], 0.05, opacity, [1.0, 0.0, 0.0])
    back = single([0, 0, 2.0], 0.1, 0.5, [0.0, 1.0, 0.0])
    for res in (render(front, cam, (0, 0, 1)), render_reference(front, cam, (0, 0, 1))):
        assert res.alpha[32, 32] == pytest.approx(0.99, rel=1e-6)
        np.testing.assert_allclose(res.rgb[32, 32], [0.99, 0.0, 0.01], rtol=1e-5, atol=1e-7)
    both = GaussianSet.concat([front, back])
    for res in (render(both, cam, (0, 0, 1)), render_reference(both, cam, (0, 0, 1))):
        # T is 0.01 after the front splat, 0.005 after the back one (alpha 0.5)
        np.testing.assert_allclose(res.rgb[32, 32], [0.99, 0.005, 0.005], rtol=1e-4, atol=1e-7)
        assert 1 - res.alpha[32, 32] == pytest.approx(0.005, rel=1e-4)


def test_early_termination_stops_before_the_splat_that_would_cross_1e_4():
    # alpha 0.95 each: T = 0.05, 0.0025, 1.25e-4, then 6.25e-6 < 1e-4 -> the 4th is never drawn
    cam = head_on_camera()
    colors = [[1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [0, 0, 1]]
    gs = GaussianSet.concat([single([0, 0, 1.0 + 0.1 * i], 0.05, 0.95, c)
                             for i, c in enumerate(colors)])
    expected = sum(0.95 * 0.05 ** i * np.array(c, float) for i, c in enumerate(colors[:3]))
    for res in (render(gs, cam), render_reference(gs, cam)):
        np.testing.assert_allclose(res.rgb[32, 32], expected, rtol=1e-5, atol=1e-7)
        assert res.rgb[32, 32, 2] < 1e-6  # drawing the 4th (blue) would add 0.95 * 1.25e-4
        assert 1 - res.alpha[32, 32] == pytest.approx(0.05 ** 3, rel=1e-3)


def test_behind_near_plane_and_outside_frustum_contribute_nothing():
    cam = head_on_camera()
    bg = (0.25, 0.5, 0.75)
    culled = GaussianSet.concat([
        single([0, 0, -1.0], 0.5, 1.0, [1, 1, 1]),     # behind the camera
        single([0, 0, 0.005], 0.001, 1.0, [1, 1, 1]),  # in front of the 0.01 near plane
        single([30, 0, 2.0], 0.05, 1.0, [1, 1, 1]),    # far right of the frustum
        single([0, -40, 2.0], 0.05, 1.0, [1, 1, 1]),   # far above
        single([0, 0, 2.0], 0.05, 0.003, [1, 1, 1]),   # opacity < 1/255 can never show
    ])
    res = render(culled, cam, bg)
    assert (res.meta["radii"] == 0).all() and res.meta["n_pairs"] == 0
    np.testing.assert_array_equal(res.rgb, np.broadcast_to(np.float32(bg), res.rgb.shape))
    assert (res.alpha == 0).all() and (res.depth == 0).all()
    # a splat centred just outside the image still draws its visible part
    edge = single([-(32.5 + 3) / cam.fx * 2.0, 0, 2.0], 0.1, 0.9, [1, 1, 1])
    res = render(edge, cam)
    assert res.meta["n_visible"] == 1 and res.alpha[:, 0].max() > 0.5


def test_empty_scene_is_the_background():
    cam = Camera.from_fov(40, 37, 21)
    res = render(GaussianSet.empty(), cam, (0.1, 0.2, 0.3))
    np.testing.assert_allclose(res.rgb, np.broadcast_to([0.1, 0.2, 0.3], (21, 37, 3)), atol=1e-7)
    assert res.alpha.shape == (21, 37) and not res.alpha.any() and not res.depth.any()


# --- spherical harmonics ----------------------------------------------------------------------

def _direct_real_sh(dirs, degree):
    """Real SH from scipy's complex Y_l^m (Condon-Shortley phase), in 3DGS order and signs:
    m < 0: sqrt(2) Im Y_l^|m|, m = 0: Y_l^0, m > 0: sqrt(2) Re Y_l^m."""
    from scipy.special import sph_harm_y

    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    cols = []
    for l in range(degree + 1):
        for m in range(-l, l + 1):
            y = sph_harm_y(l, abs(m), theta, phi)
            cols.append(math.sqrt(2) * y.imag if m < 0 else y.real if m == 0 else math.sqrt(2) * y.real)
    return np.stack(cols, 1)


def test_degree3_sh_matches_direct_formula():
    rng = np.random.default_rng(0)
    n = 200
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    basis = _direct_real_sh(dirs, 3)
    np.testing.assert_allclose(sh_basis(dirs, 3), basis, atol=1e-12)
    # the renderer's kernel: splats on a sphere around the camera, dir = mean - centre
    cam = Camera.orbit((0, 0, 0), 30, 20, 2.0)
    means = cam.camera_center + dirs * rng.uniform(0.5, 3, (n, 1))
    sh = rng.normal(scale=0.3, size=(n, 16, 3))
    gs = GaussianSet(means, np.tile(IDENTITY_QUAT, (n, 1)), np.full((n, 3), 0.01), np.full(n, 0.5), sh)
    expected = np.maximum(np.einsum("nk,nkc->nc", basis, sh) + 0.5, 0)
    assert (expected == 0).any() and (expected > 1).any()  # exercises the clamp, and no top clamp
    np.testing.assert_allclose(sh_colors(gs, cam), expected, atol=2e-6)


def test_view_dependent_colour_changes_with_the_view():
    sh = np.zeros((1, 4, 3))
    sh[0, 0] = rgb_to_dc([0.5, 0.5, 0.5])
    sh[0, 2, 0] = 0.5  # red grows with the z of the view direction (3DGS basis: +C1 z)
    gs = GaussianSet([[0, 0, 0]], [IDENTITY_QUAT], [[0.05] * 3], [0.9], sh)
    front = sh_colors(gs, Camera.orbit((0, 0, 0), 0, 0, 2.0))    # dir = -Z
    back = sh_colors(gs, Camera.orbit((0, 0, 0), 180, 0, 2.0))   # dir = +Z
    c1 = 0.4886025119029199
    np.testing.assert_allclose(front[0], [0.5 - c1 * 0.5, 0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(back[0], [0.5 + c1 * 0.5, 0.5, 0.5], atol=1e-6)


# --- determinism, API, bad input --------------------------------------------------------------

def test_deterministic_and_meta():
    gs, cam = random_scene(800, 9, 2, 130, 90)
    a, b = render(gs, cam), render(gs, cam)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.depth, b.depth)
    m = a.meta
    assert m["means2d"].shape == (800, 2) and m["conics"].shape == (800, 3)
    assert m["tile_counts"].shape == (6, 9) and m["tile_counts"].sum() == m["n_pairs"]
    assert set(m["timings"]) == {"project", "sh", "bin", "rasterize", "total"}


def test_stages_compose_to_render():
    gs, cam = random_scene(200, 12, 1)
    proj = project_gaussians(gs, cam)
    rgb, alpha, depth = rasterize(proj, sh_colors(gs, cam), gs.opacities, bin_gaussians(proj, cam), cam)
    res = render(gs, cam)
    np.testing.assert_array_equal(rgb, res.rgb)
    np.testing.assert_array_equal(alpha, res.alpha)


def test_bad_input():
    gs, cam = random_scene(10, 0)
    with pytest.raises(InputError, match="GaussianSet"):
        render(np.zeros((10, 3)), cam)
    with pytest.raises(InputError, match="Camera"):
        render(gs, "camera.json")
    for bg in [(1, 2), (0, float("nan"), 0), "white"]:
        with pytest.raises(InputError, match="background"):
            render(gs, cam, bg)
    with pytest.raises(InputError, match="near"):
        render(gs, cam, near=0.0)
