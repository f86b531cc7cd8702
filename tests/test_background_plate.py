"""The wall plate of a video (`track.background_plate`) and the segmentation that takes it
(`recon.segment`, `plate=`): cases whose answer is known."""
import cv2
import numpy as np
import pytest

from avatarkit.recon.portrait import analysis_from_box
from avatarkit.recon.segment import BACKGROUND, HAIR, segment_portrait
from avatarkit.recon.synthetic import synthetic_portrait
from avatarkit.synthetic.walls import wall_image
from avatarkit.track import background_plate as BP
from avatarkit.track.background_plate import Plate, person_zone, plate_from_frames


def iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def textured_wall(h=64, w=96, seed=0):
    """(h, w, 3) uint8: a wall with a texture and hard-edged clutter (no two neighbours alike)."""
    rng = np.random.default_rng(seed)
    wall = rng.integers(40, 216, (h, w, 3)).astype(np.uint8)
    wall[10:30, 60:80] = (200, 30, 20)     # a poster
    return wall


def blob_video(wall, xs, r=12, cy=32):
    """Frames (T, h, w, 3) of a disc of its own colour moving over `wall` to the centres xs, and
    each frame's zone (the disc dilated by 2 px, as a tracked head's zone would be)."""
    h, w = wall.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    frames, zones, discs = [], [], []
    for x in xs:
        disc = (yy - cy) ** 2 + (xx - x) ** 2 <= r * r
        frames.append(np.where(disc[..., None], np.array([90, 60, 40], np.uint8), wall))
        zones.append((yy - cy) ** 2 + (xx - x) ** 2 <= (r + 2) ** 2)
        discs.append(disc)
    return np.stack(frames), np.stack(zones), np.stack(discs)


def test_plate_is_the_wall_where_the_blob_left_and_unknown_where_it_never_did():
    wall = textured_wall()
    frames, zones, discs = blob_video(wall, np.linspace(38, 58, 10), r=14)
    # one frame's zone misses the blob's rim (a tracking error): the median keeps the wall
    zones[0] = cv2.erode(discs[0].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    plate = plate_from_frames(frames, zones)
    always = zones.all(axis=0)                    # the blob's zone in every frame
    assert always.sum() > 50 and (~always).sum() > 1000
    known = plate.known
    assert not (known & always).any()             # never uncovered: no plate
    # uncovered in enough frames that agree: the plate is the wall there, to the level
    enough = (~zones).sum(axis=0) >= BP.MIN_FRAMES
    assert not (known & ~enough).any() and known.sum() > 0.95 * enough.sum()
    assert (plate.colour[known] == wall[known]).all()
    # a frame matches the plate where it shows the wall the plate knows, and nowhere on the blob
    m = plate.matches(frames[-1])
    assert m[known & ~zones[-1]].all() and not m[discs[-1]].any()


def test_person_zone_covers_the_head_its_margin_and_a_torso_widening_below():
    h, w = 120, 120
    t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    pts = np.stack([60 + 20 * np.cos(t), 45 + 25 * np.sin(t)], 1)      # a head 40 x 50 px
    zone = person_zone(pts, (h, w))
    size = np.sqrt(np.pi * 20 * 25)
    r = BP.ZONE_MARGIN * size
    assert zone[45, int(60 + 20 + r - 1)] and not zone[45, int(60 + 20 + r + 2)]   # the margin
    assert not zone[2, 2] and not zone[2, 117]                                       # the top corners
    # below the jaw the torso widens by ZONE_SLOPE a row: wider at the bottom than at the jaw
    assert zone[119].sum() > zone[70].sum() + BP.ZONE_SLOPE * 40
    assert person_zone(np.full((10, 2), np.nan), (h, w)).all()      # nothing projects: no plate


def clutter_portrait(n=160):
    """The synthetic portrait's central n px (the head fills the frame: no "far" zone) on the
    cluttered wall (`synthetic.walls`: a poster and a post touching the head), its truth labels,
    the wall, and the portrait analysis."""
    sp = synthetic_portrait(size=256, noise=0, background_rgb=(255, 255, 255))
    y0, x0 = 40, 48
    truth = sp.labels[y0:y0 + n, x0:x0 + n]
    wall = np.round(wall_image("clutter", n) * 255).astype(np.uint8)
    img = np.where((truth == BACKGROUND)[..., None], wall, sp.image[y0:y0 + n, x0:x0 + n]).astype(np.uint8)
    x, y, w, h = sp.face_box
    return np.ascontiguousarray(img), truth, wall, analysis_from_box((n, n), (x - x0, y - y0, w, h))


def test_a_plate_keeps_clutter_touching_the_head_out_of_the_person(monkeypatch):
    from avatarkit.recon import segment as S

    img, truth, wall, a = clutter_portrait()
    n = len(img)
    full = np.full((n, n), 10, np.int32)
    plate = Plate(wall, full, full, 10)             # the wall, known everywhere
    without = segment_portrait(img, a)
    withp = segment_portrait(img, a, plate=plate)
    wall_px = truth == BACKGROUND
    assert (without.person & wall_px).sum() > 1000   # the poster and the post taken for the person
    assert (withp.person & wall_px).sum() < 50
    assert iou(withp.person, ~wall_px) > 0.98
    assert iou(withp.hair, truth == HAIR) > 0.95 > iou(without.hair, truth == HAIR)
    # the wall seen through a gap inside the hair (a hole the person encloses) stays the wall's
    hole = np.zeros(truth.shape, bool)
    ys, xs = np.nonzero(truth == HAIR)
    cy, cx = int(np.median(ys)), int(np.median(xs))
    hole[cy - 4:cy + 4, cx - 4:cx + 4] = True
    holed = np.where(hole[..., None], wall, img).astype(np.uint8)
    assert not segment_portrait(holed, a, plate=plate).person[hole].any()
    monkeypatch.setattr(S, "PLATE_SURE", False)     # the switch off: the plate is ignored
    assert (segment_portrait(img, a, plate=plate).labels == without.labels).all()


def test_a_still_video_has_no_plate_where_the_head_is_and_segments_no_worse():
    """A head that never moves: its zone is the same in every frame, the plate is unknown there;
    with the plate known nowhere the segmentation is the plate-less one to the pixel."""
    img, truth, wall, a = clutter_portrait()
    zone = cv2.dilate((truth != BACKGROUND).astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    still = plate_from_frames(np.repeat(img[None], 8, 0), np.repeat(zone[None], 8, 0))
    assert not (still.known & zone).any() and still.known[~zone].all()
    without = segment_portrait(img, a)
    withp = segment_portrait(img, a, plate=still)
    wall_px = truth == BACKGROUND
    assert (withp.person & wall_px).sum() <= (without.person & wall_px).sum()
    assert iou(withp.person, ~wall_px) >= iou(without.person, ~wall_px)
    nowhere = plate_from_frames(np.repeat(img[None], 8, 0), np.ones((8,) + zone.shape, bool))
    assert not nowhere.known.any()
    assert (segment_portrait(img, a, plate=nowhere).labels == without.labels).all()


@pytest.mark.parametrize("shape", [(160, 160), (320, 320)])
def test_plate_at_an_image_size(shape):
    wall = textured_wall(80, 80)
    full = np.full((80, 80), 10, np.int32)
    known = full.copy()
    known[:, :40] = 0
    plate = Plate(wall, known, full, 10)
    colour, k = plate.at(shape)
    assert colour.shape == shape + (3,) and k.shape == shape
    s = shape[1] // 80
    assert not k[:, :40 * s].any() and k[:, 41 * s + 1:].mean() > 0.9


def test_the_gaps_between_strands_stay_grabcuts_to_decide(monkeypatch):
    """`segment.PLATE_OPEN`: hair with one-pixel gaps that show the wall (strands). Every gap
    matches the plate; taken for sure background one by one they cut the hair to pieces and
    GrabCut dropped all of it; opened away, the hair is the plate-less segmentation's."""
    from avatarkit.recon import segment as S

    sp = synthetic_portrait(size=256, noise=0, background_rgb=(255, 255, 255))
    y0, x0, n = 40, 48, 160
    truth = sp.labels[y0:y0 + n, x0:x0 + n]
    img = sp.image[y0:y0 + n, x0:x0 + n].copy()
    gaps = (truth == HAIR) & (np.arange(n)[None] % 4 == 0)
    img[gaps] = 255
    x, y, w, h = sp.face_box
    a = analysis_from_box((n, n), (x - x0, y - y0, w, h))
    full = np.full((n, n), 10, np.int32)
    plate = Plate(np.full((n, n, 3), 255, np.uint8), full, full, 10)    # the white wall
    without = segment_portrait(img, a)
    assert without.hair.sum() > 0.5 * (truth == HAIR).sum()
    # the portrait holds none of the wall the opened plate shows (`PLATE_TAKEN`): kept as it was
    assert (segment_portrait(img, a, plate=plate).labels == without.labels).all()
    monkeypatch.setattr(S, "PLATE_OPEN", 0.0)
    assert segment_portrait(img, a, plate=plate).hair.sum() < 0.2 * without.hair.sum()


def test_a_plate_leaves_a_portrait_that_kept_the_wall_out_as_it_was(monkeypatch):
    """`segment.PLATE_TAKEN`: on a plain wall the portrait's own segmentation holds none of the
    wall the plate shows; it is kept to the pixel (the plate as sure background would still
    change GrabCut's colour models)."""
    from avatarkit.recon import segment as S

    sp = synthetic_portrait(size=256, noise=0, background_rgb=(200, 200, 200))
    y0, x0, n = 40, 48, 160
    img = np.ascontiguousarray(sp.image[y0:y0 + n, x0:x0 + n])
    truth = sp.labels[y0:y0 + n, x0:x0 + n]
    x, y, w, h = sp.face_box
    a = analysis_from_box((n, n), (x - x0, y - y0, w, h))
    full = np.full((n, n), 10, np.int32)
    plate = Plate(np.where((truth == BACKGROUND)[..., None], img, 0).astype(np.uint8), full, full, 10)
    without = segment_portrait(img, a)
    assert (without.person & (truth == BACKGROUND)).sum() < 0.005 * (truth == BACKGROUND).sum()
    assert (segment_portrait(img, a, plate=plate).labels == without.labels).all()


def test_relabel_head_leaves_the_wall_a_plate_shows_to_the_wall(monkeypatch):
    """`multiview.RELABEL_PLATE`: a turned keyframe with no face (labels all background) on the
    cluttered wall. `relabel_head` takes what by the head is not the one-colour wall model's
    colour for the person: the poster and the post. With the plate's wall (`plate_wall`) they
    stay the wall's; the head's own pixels are the person's either way."""
    from avatarkit.recon import multiview as MV
    from avatarkit.recon.segment import ColourModel, rgb_to_lab

    n = 160
    wall = np.round(wall_image("clutter", n) * 255).astype(np.uint8)
    yy, xx = np.mgrid[0:n, 0:n]
    head = (yy - 70) ** 2 + (xx - 80) ** 2 <= 40 ** 2
    img = np.where(head[..., None], np.array([200, 150, 120], np.uint8), wall).astype(np.uint8)
    skin = ColourModel.fit(rgb_to_lab(np.array([[200, 150, 120]] * 8, np.uint8)))
    hair = ColourModel.fit(rgb_to_lab(np.array([[60, 40, 30]] * 8, np.uint8)))
    full = np.full((n, n), 10, np.int32)
    plate = Plate(wall, full, full, 10)
    labels = np.zeros((n, n), np.int32)
    plain = MV.relabel_head(labels, img, head, (hair, skin))
    withp = MV.relabel_head(labels, img, head, (hair, skin), wall=MV.plate_wall(plate, img))
    assert (plain[~head] != BACKGROUND).sum() > 300          # clutter by the head: the person's
    assert (withp[~head] != BACKGROUND).sum() < 10
    assert (withp[head] != BACKGROUND).all() and (plain[head] != BACKGROUND).all()
    monkeypatch.setattr(MV, "RELABEL_PLATE", None)
    assert MV.plate_wall(plate, img) is None



def haired_video(wall, xs, model_r=10, hair_r=14, cy=32, model_xs=None):
    """Frames (T, h, w, 3) of a head whose model (the tracked outline) is a disc of model_r and
    whose hair reaches hair_r (beyond the tighter zone), moving over `wall` to the centres xs
    (the model tracked at model_xs: None, there); the frames' zones (`person_zone` of the model
    disc: the wide one and the pass test's at 0.14) and where the person is (T, h, w)."""
    h, w = wall.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    frames, zones, tight, person = [], [], [], []
    for x, mx in zip(xs, xs if model_xs is None else model_xs):
        pts = np.stack([mx + model_r * np.cos(t), cy + model_r * np.sin(t)], 1)
        zones.append(person_zone(pts, (h, w)))
        tight.append(person_zone(pts, (h, w), 0.14))          # `PASS_MARGIN` as measured (off)
        p = (yy - cy) ** 2 + (xx - x) ** 2 <= hair_r ** 2
        frames.append(np.where(p[..., None], np.array([60, 40, 30], np.uint8), wall))
        person.append(p)
    return np.stack(frames), np.stack(zones), np.stack(tight), np.stack(person)


def test_the_tighter_zone_takes_the_wall_the_head_passed_over_and_never_still_hair():
    wall = textured_wall(64, 128)
    # a head that never moves (a talking head): its hair lies outside the tighter zone in every
    # frame and is all those frames show there; alone (no pass test) that zone's plate is hair
    frames, zones, tight, person = haired_video(wall, [64] * 12)
    assert (~tight[0] & person[0]).sum() > 20 and not (~zones[0] & person[0]).any()
    assert (plate_from_frames(frames, tight).known & person[0]).sum() > 20
    still = plate_from_frames(frames, zones, tight)
    assert not (still.known & person[0]).any()
    assert (still.known == plate_from_frames(frames, zones).known).all()
    # the same still head tracked 2 px to and fro (the tracking's jitter) and the camera's
    # exposure up 30 levels in 4 of the 48 frames the tighter zone was over the hair's rim: the
    # rim differs in too few of them, the head did not pass (`PASS_SHARE`): the test adds no hair
    frames, zones, tight, person = haired_video(wall, [64] * 96, model_xs=[64, 66] * 48)
    frames[[1, 3, 5, 7]] = np.clip(frames[[1, 3, 5, 7]].astype(int) + 30, 0, 255).astype(np.uint8)
    rim = person[0] & ~tight[0] & tight[1]
    assert rim.sum() > 5
    jitter = plate_from_frames(frames, zones, tight)
    assert not (jitter.known & ~plate_from_frames(frames, zones).known & person[0]).any()
    # a head that moves to and fro: the wall it uncovers beside itself within the wide zone is
    # known (the wall's colour, to the level), more of it than the wide zone alone knows
    xs = 64 + 10 * np.sin(np.linspace(0, 4 * np.pi, 24))
    frames, zones, tight, person = haired_video(wall, xs)
    wide = plate_from_frames(frames, zones)
    moved = plate_from_frames(frames, zones, tight)
    gained = moved.known & ~wide.known
    assert (moved.known >= wide.known).all() and gained.sum() > 30
    assert (moved.colour[moved.known] == wall[moved.known]).all()
    assert not (moved.matches(frames[0]) & person[0]).any()


def still_head_video(hair_r=None, tuft=0, n=12, size=128, cx=64, cy=22, model_r=16):
    """Frames (n, size, size, 3) of a still head (the model: a skin disc of model_r whose top is
    near the frame's top, as a 192 px video's head) on the cluttered wall, with hair of its own
    colour to hair_r (None: bald) and a tuft `tuft` px beyond the wide zone above its top (a
    flyaway the wide zone leaves out); the frames' zones (wide: `ZONE_MARGIN`; near: the
    continued wall's 0.14) and where the person is (size, size) bool."""
    wall = np.round(wall_image("clutter", size) * 255).astype(np.uint8)
    yy, xx = np.mgrid[0:size, 0:size]
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    pts = np.stack([cx + model_r * np.cos(t), cy + model_r * np.sin(t)], 1)
    zone = person_zone(pts, (size, size))
    near = person_zone(pts, (size, size), 0.14)
    d2 = (yy - cy) ** 2 + (xx - cx) ** 2
    img = wall.copy()
    hair = np.zeros((size, size), bool)
    if hair_r is not None:
        hair = d2 <= hair_r ** 2
        if tuft:
            right = np.nonzero(zone[cy])[0][-1]      # the wide zone's side beside the head
            hair |= (np.abs(yy - cy) <= 3) & (xx >= cx) & (xx <= right + tuft)
    img[hair] = (150, 100, 80)
    img[d2 <= model_r ** 2] = (220, 170, 140)
    frames = np.repeat(img[None], n, axis=0)
    return frames, np.repeat(zone[None], n, 0), np.repeat(near[None], n, 0), hair | (d2 <= model_r ** 2), wall


def test_the_continued_wall_takes_the_wall_above_a_still_head_and_not_its_hair(monkeypatch):
    # a bald head that never moves (the top of a turning head, which the zone always covers): the
    # wall between the tight and the wide zone is never seen outside the wide one: no plate
    frames, zones, near, person, wall = still_head_video()
    band = zones[0] & ~near[0] & ~person
    assert band.sum() > 100
    wide = plate_from_frames(frames, zones)
    assert not (wide.known & band).any()
    # ...and the wall beside it continues into it: known, the wall's colour there (to the level:
    # every frame shows it), nothing of the head
    cont = plate_from_frames(frames, zones, near=near)
    assert (cont.known & band).sum() > 0.75 * band.sum()
    assert (cont.colour[cont.known] == wall[cont.known]).all()
    assert not (cont.known & person).any() and (cont.known >= wide.known).all()
    assert not (cont.matches(frames[0]) & person).any()
    # a still head whose hair reaches past the tight zone: that zone's plate alone is hair there;
    # the hair does not continue the wall beside it: none of it known
    frames, zones, near, person, wall = still_head_video(hair_r=22)
    assert (plate_from_frames(frames, near).known & person).sum() > 50
    cont = plate_from_frames(frames, zones, near=near)
    assert not (cont.known & person).any()
    assert (cont.known & zones[0] & ~person).sum() > 0.6 * (zones[0] & ~near[0] & ~person).sum()
    # a flyaway tuft beyond the wide zone: the wide plate knows it (hair as wall, the grey clip's
    # top); the continued wall is grown only in the colours of the wall far from the unknown
    # (`CONTINUE_DEEP`), so the tuft neither seeds it nor lets it into the hair below
    frames, zones, near, person, wall = still_head_video(hair_r=22, tuft=2)
    wide = plate_from_frames(frames, zones)
    assert (wide.known & person).sum() >= 10
    cont = plate_from_frames(frames, zones, near=near)
    assert not (cont.known & ~wide.known & person).any()
    monkeypatch.setattr(BP, "CONTINUE_DEEP", 0.0)
    flooded = plate_from_frames(frames, zones, near=near)
    assert (flooded.known & ~wide.known & person).sum() > 20


def test_without_the_near_zones_the_plate_is_the_wide_zones_alone():
    frames, zones, near, person, wall = still_head_video()
    band = zones[0] & ~near[0] & ~person
    # `video_plate` asks for the near zones only when the margin is on; `plate_from_frames`
    # without them is the plate as before, to the pixel
    a, b = plate_from_frames(frames, zones), plate_from_frames(frames, zones, near=None)
    assert (a.known == b.known).all() and (a.colour == b.colour).all() and not (a.known & band).any()


def test_relabel_head_leaves_the_wall_continuing_past_the_known_plate_to_the_wall(monkeypatch):
    """`multiview.RELABEL_PLATE_NEAR`: the plate knows the cluttered wall only beyond a band by the
    head (the tracked head's zone covers the band in every frame). Without the rule the poster and
    the post in the band are taken for the person (not the one-colour wall model's colour); with
    it, where their colour continues the known plate beside them, they stay the wall's. The head,
    a colour no wall pixel near it has, is the person's either way."""
    from avatarkit.recon import multiview as MV
    from avatarkit.recon.segment import ColourModel, rgb_to_lab

    n = 160
    wall = np.round(wall_image("clutter", n) * 255).astype(np.uint8)
    yy, xx = np.mgrid[0:n, 0:n]
    d2 = (yy - 70) ** 2 + (xx - 80) ** 2
    head = d2 <= 40 ** 2
    img = np.where(head[..., None], np.array([200, 150, 120], np.uint8), wall).astype(np.uint8)
    skin = ColourModel.fit(rgb_to_lab(np.array([[200, 150, 120]] * 8, np.uint8)))
    hair = ColourModel.fit(rgb_to_lab(np.array([[60, 40, 30]] * 8, np.uint8)))
    known = np.where(d2 > 44 ** 2, 10, 0).astype(np.int32)     # a 4 px band by the head unknown
    plate = Plate(wall, known, np.full((n, n), 10, np.int32), 10)
    band = ~head & ~plate.known
    labels = np.zeros((n, n), np.int32)
    monkeypatch.setattr(MV, "RELABEL_PLATE_NEAR", None)
    before = MV.relabel_head(labels, img, head, (hair, skin), wall=MV.plate_wall(plate, img))
    assert (before[band] != BACKGROUND).sum() > 150          # the band's poster and post: person
    monkeypatch.setattr(MV, "RELABEL_PLATE_NEAR", 0.03)
    after = MV.relabel_head(labels, img, head, (hair, skin), wall=MV.plate_wall(plate, img))
    assert (after[band] != BACKGROUND).sum() < 0.1 * (before[band] != BACKGROUND).sum()
    assert (after[head] != BACKGROUND).all() and (after[~band & ~head] == before[~band & ~head]).all()


def test_continuing_counts_what_a_pixel_by_pixel_count_does():
    """`continuing` (which skips the pixels with no known pixel inside their disc) against the
    obvious count: for each region pixel, the known pixels within the disc (the same elliptic
    element) agreeing with its colour within `AGREE` in every channel. Random walls with a large
    unknown zone, so that most of the region lies farther than r from any known pixel."""
    rng = np.random.default_rng(5)
    for _ in range(6):
        h, w, r = 40, 52, int(rng.integers(2, 7))
        colour = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
        colour[rng.random((h, w)) < 0.5] = (200, 190, 170)                 # a wall colour repeated
        image = colour.copy()
        image[rng.random((h, w)) < 0.3] = (205, 185, 175)                  # within AGREE of it
        known = np.ones((h, w), bool)
        known[5:35, 8:45] = False                                          # the head's zone
        region = rng.random((h, w)) < 0.7
        got = BP.continuing(known, colour, image, region, r)
        want = _obvious_count(known, colour, image, region, r)
        np.testing.assert_array_equal(got, want)
        assert (want[region] == 0).any() and (want[region] > 0).any()


def _obvious_count(known, colour, image, region, r):
    """The pixel-by-pixel count `continuing` makes: for each region pixel, the known pixels
    within the elliptic disc agreeing with its colour within `AGREE` in every channel."""
    h, w = known.shape
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2).astype(bool)
    want = np.zeros((h, w), np.int32)
    for y, x in zip(*np.nonzero(region)):
        for dy, dx in zip(*np.nonzero(disc)):
            yy, xx = y + dy - r, x + dx - r
            if 0 <= yy < h and 0 <= xx < w and known[yy, xx]:
                d = np.abs(colour[yy, xx].astype(int) - image[y, x].astype(int)).max()
                want[y, x] += d <= BP.AGREE
    return want


@pytest.mark.parametrize("chunk", [256, 5])
def test_continues_decides_what_the_full_count_does(monkeypatch, chunk):
    """`continues` (a summed-area bound per colour bin, then counting only up to the threshold)
    against the obvious count's decision, count >= enough, for thresholds from 1 to past every
    count: random walls of a repeated colour with pixels within `AGREE` of it, colours one bin
    off and one just past `AGREE` (the bins' edges), a large unknown zone. Chunks of 5 offsets:
    the pixels that reached the threshold are dropped while others still count."""
    monkeypatch.setattr(BP, "AGREEING_CHUNK", chunk)
    rng = np.random.default_rng(11)
    for _ in range(5):
        h, w, r = 36, 44, int(rng.integers(1, 7))
        colour = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
        colour[rng.random((h, w)) < 0.5] = (200, 190, 170)                 # the wall's colour
        image = colour.copy()
        image[rng.random((h, w)) < 0.25] = (212, 178, 182)                 # within AGREE (12)
        image[rng.random((h, w)) < 0.15] = (213, 190, 170)                 # 13 off: never agrees
        image[rng.random((h, w)) < 0.1] = (188, 202, 158)                  # 12 off the other way
        known = np.ones((h, w), bool)
        known[4:30, 7:38] = False
        region = rng.random((h, w)) < 0.8
        want = _obvious_count(known, colour, image, region, r)
        assert (want[region] == 0).any() and (want[region] >= 3).any()
        for enough in (1, 2, 3, 4, 9, int(want.max()), int(want.max()) + 1):
            got = BP.continues(known, colour, image, region, r, enough)
            np.testing.assert_array_equal(got, region & (want >= enough))


def test_agreeing_stops_at_enough_and_square_bound_bounds_the_count(monkeypatch):
    """`agreeing(enough=)` returns min(count, enough) (the nearest offsets first, pixels dropped
    as they reach it); `square_bound` is at least the count everywhere and 0 where no known
    colour of a neighbouring bin lies in the square (a white wall beside skin)."""
    rng = np.random.default_rng(3)
    h, w, r = 30, 34, 4
    colour = np.full((h, w, 3), 250, np.uint8)                             # a white wall...
    colour[rng.random((h, w)) < 0.4] = (120, 90, 200)                      # ...with a violet pattern
    image = colour.copy()
    image[8:22, 9:25] = (210, 160, 130)                                    # skin: no wall colour near
    image[rng.random((h, w)) < 0.2] = (245, 255, 240)                      # wall-white specks
    known = np.ones((h, w), bool)
    known[6:24, 7:27] = False
    region = np.ones((h, w), bool)
    want = _obvious_count(known, colour, image, region, r)
    ys, xs = np.nonzero(region)
    c = image[ys, xs].astype(np.int16)
    bound = BP.square_bound(known, colour, ys, xs, c, r)
    assert (bound >= want[ys, xs]).all()
    skin = (image[ys, xs] == (210, 160, 130)).all(axis=1)
    assert skin.any() and (bound[skin] == 0).all()
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
    pad_k = np.pad(known, r)
    pad_c = np.pad(colour.astype(np.int16), ((r, r), (r, r), (0, 0)))
    np.testing.assert_array_equal(BP.agreeing(pad_k, pad_c, ys, xs, c, disc), want[ys, xs])
    monkeypatch.setattr(BP, "AGREEING_CHUNK", 4)            # pixels dropped between chunks
    for enough in (1, 3, 7):
        np.testing.assert_array_equal(BP.agreeing(pad_k, pad_c, ys, xs, c, disc, enough),
                                      np.minimum(want[ys, xs], enough))


def test_disc_bound_is_a_lower_bound_that_the_wall_beside_the_wall_reaches():
    """`disc_bound` (the known pixels of a pixel's own colour bin in rectangles inside its disc)
    never exceeds the count (`agreeing`, checked above against the pixel-by-pixel one), with
    discs wider than its bands (r 13 and 21: each band as wide as its narrowest row) and with
    known pixels crowding the disc's rim; the wall's own pixels beside the known wall reach 3."""
    rng = np.random.default_rng(8)
    for r in (13, 21):
        h, w = 70, 90
        colour = np.full((h, w, 3), (200, 190, 170), np.uint8)
        colour[rng.random((h, w)) < 0.3] = (60, 70, 80)
        image = colour.copy()
        image[rng.random((h, w)) < 0.3] = (205, 185, 175)                  # the wall's bin
        image[rng.random((h, w)) < 0.2] = (190, 195, 160)                  # agrees, another bin
        known = rng.random((h, w)) < 0.5
        known[20:50, 25:65] = False
        ys, xs = np.nonzero(np.ones((h, w), bool))
        c = image[ys, xs].astype(np.int16)
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
        count = BP.agreeing(np.pad(known, r), np.pad(colour.astype(np.int16), ((r, r), (r, r), (0, 0))),
                            ys, xs, c, disc)
        for strips in (1, 3, 8, 64):
            low = BP.disc_bound(known, colour, ys, xs, c, disc, strips)
            assert (low <= count).all()
        wall = (image[ys, xs] == (205, 185, 175)).all(axis=1) & (count >= 3)
        assert (BP.disc_bound(known, colour, ys, xs, c, disc)[wall] >= 3).mean() > 0.9
