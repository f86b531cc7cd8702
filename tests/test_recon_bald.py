"""The 2D bald filter (recon/bald.py) and the harmonic fill behind it (recon/fill.py)."""
from pathlib import Path

import cv2
import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.recon.bald import head_region, make_bald_image
from avatarkit.recon.fill import harmonic_fill, harmonic_fill_fast
from avatarkit.recon.image_io import read_image
from avatarkit.recon.portrait import analysis_from_box, analyze_portrait
from avatarkit.recon.segment import BACKGROUND, HAIR, MATCH_D2, SKIN, rgb_to_lab, segment_portrait
from avatarkit.recon.synthetic import synthetic_portrait

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg"


def jacobi_reference(values, region, known, iterations=20000):
    """The slow, obvious harmonic fill: repeat "each region pixel = mean of its usable neighbours"."""
    v = np.asarray(values, dtype=np.float64).copy()
    if v.ndim == 2:
        v = v[:, :, None]
    usable = region | known
    v[region] = 0.0
    H, W = region.shape
    for _ in range(iterations):
        acc = np.zeros_like(v)
        cnt = np.zeros((H, W, 1))
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            shifted = np.zeros_like(v)
            ok = np.zeros((H, W), bool)
            ys = slice(max(dy, 0), H + min(dy, 0))
            yd = slice(max(-dy, 0), H + min(-dy, 0))
            xs = slice(max(dx, 0), W + min(dx, 0))
            xd = slice(max(-dx, 0), W + min(-dx, 0))
            shifted[yd, xd] = v[ys, xs]
            ok[yd, xd] = usable[ys, xs]
            acc += shifted * ok[:, :, None]
            cnt += ok[:, :, None]
        v[region] = (acc / np.maximum(cnt, 1))[region]
    return v


# ---------------------------------------------------------------------------------- fill

def test_harmonic_fill_matches_jacobi_reference():
    rng = np.random.default_rng(0)
    H, W = 24, 30
    values = rng.uniform(0, 255, (H, W, 3))
    y, x = np.mgrid[0:H, 0:W]
    region = ((x - 14) / 10.0) ** 2 + ((y - 11) / 8.0) ** 2 <= 1.0
    known = ~region & (x < 22)  # the right side is neither: a no-flux (Neumann) border
    fast = harmonic_fill(values, region, known)
    slow = jacobi_reference(values, region, known, iterations=6000)
    np.testing.assert_allclose(fast[region], slow[region], atol=1e-3)
    assert (fast[~region] == values[~region]).all()


def test_harmonic_fill_reproduces_linear_functions():
    # A linear function is discrete-harmonic: filled from its own boundary it comes back exactly.
    H, W = 40, 50
    y, x = np.mgrid[0:H, 0:W].astype(float)
    lin = 3.0 + 0.7 * x - 1.3 * y
    region = np.zeros((H, W), bool)
    region[5:35, 8:44] = True
    out = harmonic_fill(np.where(region, 999.0, lin), region, ~region)
    np.testing.assert_allclose(out[:, :, 0], lin, atol=1e-9)


def test_unreachable_components_get_the_fallback():
    region = np.zeros((20, 20), bool)
    region[5:10, 5:10] = True
    known = np.zeros((20, 20), bool)  # nothing known anywhere
    out = harmonic_fill(np.zeros((20, 20, 3)), region, known, fallback=np.array([1.0, 2.0, 3.0]))
    assert (out[region] == [1.0, 2.0, 3.0]).all()


def test_two_level_fill_is_close_to_direct_solve():
    H, W = 360, 400
    y, x = np.mgrid[0:H, 0:W].astype(float)
    values = np.stack([128 + 60 * np.sin(x / 40) * np.cos(y / 55), 0.4 * x, 0.5 * y + 15 * np.sin(x / 11)], axis=2)
    region = ((x - 200) / 150) ** 2 + ((y - 170) / 110) ** 2 <= 1
    known = ~region & (x < 330)
    direct = harmonic_fill(values, region, known)
    fast = harmonic_fill_fast(values, region, known, work_size=128)
    err = np.abs(direct - fast)[region]
    assert err.mean() < 0.5 and err.max() < 4.0
    assert (fast[~region] == values[~region]).all()


# ---------------------------------------------------------------------------------- bald

@pytest.fixture(scope="module", params=[dict(blur=1.0, noise=4), dict(blur=1.5, noise=4, hair_rgb=(196, 164, 108), seed=2)],
                ids=["brown", "blond"])
def synthetic_case(request):
    sp = synthetic_portrait(**request.param)
    a = analysis_from_box(sp.image.shape[1::-1], sp.face_box)
    seg = segment_portrait(sp.image, a)
    return sp, a, seg, make_bald_image(sp.image, seg, a)


def test_scalp_has_no_hair_colour_left_and_looks_like_skin(synthetic_case):
    sp, a, seg, bald = synthetic_case
    assert bald.scalp_mask.sum() > 0.5 * ((sp.labels == HAIR) & head_region(a)).sum()
    lab = rgb_to_lab(bald.image[bald.scalp_mask])
    # (a pixel or two where the segmentation called the blurred tip of the hair skin may stay tinted)
    assert (seg.hair_model.distance2(lab) > MATCH_D2).mean() > 0.995
    assert (seg.skin_model.log_likelihood(lab) > seg.hair_model.log_likelihood(lab)).all()
    # colour of the face's skin: chroma of the skin model, lightness within the face's own range
    assert np.abs(lab[:, 1:] - seg.skin_model.mean[1:]).max() < 10
    face_l = rgb_to_lab(sp.image[(sp.labels == SKIN)])[:, 0]
    lo, hi = np.percentile(face_l, [5, 100])
    assert lo - 3 < lab[:, 0].min() and lab[:, 0].max() < hi + 3
    # smooth: no hair texture, no seams (neighbouring filled pixels differ little)
    g = np.abs(np.diff(bald.image.astype(int), axis=0))[bald.scalp_mask[1:] & bald.scalp_mask[:-1]]
    assert np.percentile(g, 99) < 8


def test_background_fill_and_untouched_pixels(synthetic_case):
    sp, a, seg, bald = synthetic_case
    outside = ~bald.filled_mask
    assert (bald.image[outside] == sp.image[outside]).all()
    to_bg = bald.filled_mask & ~bald.scalp_mask
    assert to_bg.any()
    bg_colour = np.median(sp.image[sp.labels == BACKGROUND], axis=0)
    assert np.abs(bald.image[to_bg].astype(float) - bg_colour).mean() < 4
    assert not (bald.labels == HAIR).any()
    assert (bald.labels[bald.scalp_mask] == SKIN).all() and (bald.labels[to_bg] == BACKGROUND).all()


def test_grow_zero_changes_exactly_the_hair_and_grow_stays_in_background(synthetic_case):
    sp, a, seg, _ = synthetic_case
    exact = make_bald_image(sp.image, seg, a, grow=0)
    assert (exact.filled_mask == seg.hair).all()
    grown = make_bald_image(sp.image, seg, a, grow=3)
    extra = grown.filled_mask & ~seg.hair
    # growth goes into the background around the hair and into the skin along the hairline only
    assert (seg.labels[extra & ~grown.scalp_mask] == BACKGROUND).all()
    assert (seg.labels[extra & grown.scalp_mask] == SKIN).all()
    ring = cv2.dilate(seg.hair.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    assert not (extra & ~ring).any()


def test_scalp_hint_replaces_the_head_ellipse(synthetic_case):
    sp, a, seg, _ = synthetic_case
    hint = np.zeros(seg.labels.shape, np.uint8)
    hint[:, : seg.labels.shape[1] // 2] = 1  # only the left half of the picture is "head"
    bald = make_bald_image(sp.image, seg, a, scalp_hint=hint, grow=0)
    assert (bald.scalp_mask == (seg.hair & (hint > 0))).all()
    grown = make_bald_image(sp.image, seg, a, scalp_hint=hint, grow=2)
    extra = grown.scalp_mask & ~bald.scalp_mask
    assert extra.any() and (seg.labels[extra] == SKIN).all()  # the hairline's blended skin pixels
    with pytest.raises(InputError, match="scalp hint"):
        make_bald_image(sp.image, seg, a, scalp_hint=hint[:-1])


def test_no_hair_means_no_change():
    sp = synthetic_portrait(hair=False, blur=1.0)
    a = analysis_from_box(sp.image.shape[1::-1], sp.face_box)
    seg = segment_portrait(sp.image, a)
    bald = make_bald_image(sp.image, seg, a)
    assert (bald.image == sp.image).all() and not bald.filled_mask.any()


def test_sample_portrait_bald():
    image = read_image(SAMPLE)
    a = analyze_portrait(image)
    seg = segment_portrait(image, a)
    bald = make_bald_image(image, seg, a)
    assert bald.image.shape == image.shape and bald.image.dtype == np.uint8
    assert (bald.image[~bald.filled_mask] == image[~bald.filled_mask]).all()
    assert bald.scalp_mask.sum() > 0.3 * seg.hair.sum()
    lab = rgb_to_lab(bald.image[bald.scalp_mask])
    before = rgb_to_lab(image[bald.scalp_mask])
    # before: hair; after: skin, by the segmentation's own colour models
    more_skin = seg.skin_model.log_likelihood(lab) > seg.hair_model.log_likelihood(lab)
    was_skin = seg.skin_model.log_likelihood(before) > seg.hair_model.log_likelihood(before)
    assert more_skin.mean() > 0.9 and was_skin.mean() < 0.3
    assert np.median(seg.skin_model.distance2(lab)) < MATCH_D2


def test_mismatched_inputs_are_refused(synthetic_case):
    sp, a, seg, _ = synthetic_case
    with pytest.raises(InputError, match="segmentation"):
        make_bald_image(sp.image[:-2], seg, a)
    with pytest.raises(InputError, match="uint8"):
        make_bald_image(sp.image.astype(np.float32), seg, a)
