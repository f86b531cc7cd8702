"""The person outline's boundary step (recon/boundary.py) on drawn shapes with known edges."""
import cv2
import numpy as np
import pytest
from scipy import ndimage

from avatarkit.recon.boundary import (MIN_CONTRAST, _cores, _nearest_interior_colour2,
                                      _nearest_interior_colour2_loop, _peel, drop_mask, drop_mask_reference, person_share, refine_person)


def disc_image(size=96, radius=28.0, fg=(120, 80, 60), bg=(245, 243, 240), blur=1.5, noise=2.0, seed=0):
    """(image (H, W, 3) uint8, true disc (H, W) bool): a soft-edged disc on a plain wall."""
    y, x = np.mgrid[0:size, 0:size] + 0.5
    disc = np.hypot(x - size / 2, y - size / 2) <= radius
    img = np.where(disc[..., None], np.float32(fg), np.float32(bg))
    img = cv2.GaussianBlur(img, (0, 0), blur) + np.random.default_rng(seed).normal(0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), disc


def test_outline_moves_back_onto_the_edge():
    img, disc = disc_image()
    grown = ndimage.binary_dilation(disc, iterations=3)       # GrabCut's halo: 3 px of wall
    out = refine_person(img, grown, band=4)
    y, x = np.mgrid[0:96, 0:96] + 0.5
    d = np.hypot(x - 48, y - 48) - 28.0   # signed distance to the drawn edge
    far = grown & (d > 1.0)               # wall, not the edge's mixed pixels
    assert (out & far).sum() <= 0.02 * far.sum()
    assert (disc & ~out).sum() <= 0.05 * (grown & ~disc).sum()
    # the mixing estimate itself: about 0.5 on the true outline, about 0 two pixels further out
    ring, alpha, contrast, _, _ = person_share(img, grown, band=4)
    assert np.median(alpha[ring & (np.abs(d) < 0.5)]) == pytest.approx(0.5, abs=0.2)
    assert np.median(alpha[ring & (d > 2.5)]) < 0.1
    assert contrast[ring].min() > MIN_CONTRAST


def test_low_contrast_edge_keeps_its_outline():
    # dark hair on a dark wall: the mix says nothing, the outline stays where GrabCut put it
    img, disc = disc_image(fg=(40, 32, 28), bg=(30, 28, 26))
    grown = ndimage.binary_dilation(disc, iterations=3)
    assert (refine_person(img, grown, band=4) == grown).all()


def test_only_peels_from_the_outside_and_keeps_sure_pixels():
    # the peel: of the wall-like pixels, those reached from the background through other
    # wall-like pixels go; an enclosed patch of them (a grey shirt on a grey wall) stays
    person = np.zeros((20, 20), bool)
    person[4:16, 4:16] = True
    drop = np.zeros_like(person)
    drop[4:6, 4:16] = True        # a band at the top, touching the background
    drop[9:11, 9:11] = True       # a patch inside
    out = _peel(person, drop, np.zeros_like(person))
    assert not out[4:6].any() and out[9:11, 9:11].all() and out[6:16, 4:16].all()
    # pixels marked `keep` are never removed, whatever their colour
    img, disc = disc_image()
    grown = ndimage.binary_dilation(disc, iterations=3)
    x = np.mgrid[0:96, 0:96][1] + 0.5
    keep = grown & (x < 30)
    assert (refine_person(img, grown, band=4, keep=keep)[keep]).all()
    assert not refine_person(img, grown, band=4)[keep & ~disc].all()


@pytest.mark.parametrize("seed", [0, 1])
def test_fast_matches_reference(seed):
    img, disc = disc_image(size=48, radius=14.0, seed=seed)
    rng = np.random.default_rng(seed)
    grown = ndimage.binary_dilation(disc, iterations=2) | (rng.random(disc.shape) < 0.02)
    grown = ndimage.binary_fill_holes(grown)
    fast = drop_mask(img, grown, band=3)
    ref, tied = drop_mask_reference(img, grown, band=3)
    assert fast.sum() > 20 and tied.sum() < 0.1 * fast.sum()   # the case does drop pixels; few ties
    assert (fast == ref)[~tied].all()


@pytest.mark.parametrize("seed", [0, 1])
def test_nearest_interior_colour_kernel_matches_the_loop(seed):
    """The Taichi kernel gives the offset loop's array bit for bit on uint8 colours (exact
    integer distances), inf where no interior pixel is in reach included; a frame with an
    image's edge near the disc's ring and a blob with no interior pixel in reach."""
    rng = np.random.default_rng(seed)
    img, disc = disc_image(size=64, radius=20.0, seed=seed)
    img = np.clip(img.astype(np.int16) + rng.integers(-40, 40, img.shape), 0, 255).astype(np.uint8)
    person = disc.copy()
    person[2:7, 56:61] = True                     # a blob all ring, no interior pixel in reach
    interior, _, ring = _cores(person, 3)
    f = img.astype(np.float32)
    fast = _nearest_interior_colour2(f, interior, ring, 6)
    slow = _nearest_interior_colour2_loop(f, interior, ring, 6)
    assert np.isinf(slow).any() and np.isfinite(slow[ring]).sum() > 100
    assert fast.dtype == slow.dtype and np.array_equal(fast, slow)
    # colours that are not whole numbers take the loop itself
    g = f + np.float32(0.25)
    assert np.array_equal(_nearest_interior_colour2(g, interior, ring, 6), _nearest_interior_colour2_loop(g, interior, ring, 6))
