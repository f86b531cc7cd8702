"""The wall seen between the strands (`recon.hair_fringe`): hair Gaussians whose colour is more
the wall's than the hair's are cleared, read against the wall plate behind each."""
import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon import hair_fringe
from avatarkit.render.camera import Camera
from avatarkit.track.background_plate import Plate

H = W = 64
DARK = np.array([0.25, 0.20, 0.15])
WHITE = np.ones(3)
BLUE = np.array([0.55, 0.75, 1.00])


def _plate(left=WHITE, right=BLUE, hole=16):
    """A plate white on the left half, blue on the right, unknown in the central square (the
    head the frames never left)."""
    colour = np.zeros((H, W, 3), np.uint8)
    colour[:, : W // 2] = np.round(left * 255)
    colour[:, W // 2:] = np.round(right * 255)
    support = np.full((H, W), 10, np.int32)
    c = H // 2
    support[c - hole:c + hole, c - hole:c + hole] = 0
    return Plate(colour, support, np.full((H, W), 10, np.int32), 10)


CAM = Camera(fx=64.0, fy=64.0, cx=W / 2, cy=H / 2, width=W, height=H)


def _hair(colours, xs):
    """Hair Gaussians at 1 m in front of CAM, at image columns xs (row the middle), coloured."""
    n = len(colours)
    x = (np.asarray(xs, np.float64) + 0.5 - W / 2) / 64.0
    means = np.stack([x, np.zeros(n), np.ones(n)], axis=1).astype(np.float32)
    g = GaussianSet(means, np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32),
                    np.full((n, 3), 0.002, np.float32), np.ones(n, np.float32),
                    np.zeros((n, 1, 3), np.float32), extras={"tag": np.arange(n)})
    return g.with_colors(np.clip(np.asarray(colours, np.float32), 0, 1))


def test_wall_shares_reads_a_mix_of_the_hair_and_the_wall():
    a = np.array([1.0, 0.8, 0.5, 0.3, 0.0])
    mixes = a[:, None] * DARK + (1 - a[:, None]) * WHITE
    got = hair_fringe.wall_shares(mixes, DARK, np.tile(WHITE, (5, 1)))
    assert np.allclose(got, a, atol=1e-6)
    # darker than the hair: all hair; off the segment (a red highlight): not a mix, all hair
    assert hair_fringe.wall_shares([DARK * 0.5], DARK, [WHITE])[0] == 1.0
    assert hair_fringe.wall_shares([DARK + [0.4, 0, 0]], DARK, [WHITE])[0] == 1.0
    # a wall like the hair: unreadable
    assert hair_fringe.wall_shares([DARK + 0.05], DARK, [DARK + 0.1])[0] == 1.0


def test_plate_walls_the_wall_at_the_pixel_or_the_nearest_known():
    plate = _plate()
    xs = [2, 60, 20, 40]                     # known white, known blue, hole's left, hole's right
    walls = hair_fringe.plate_walls(_hair(np.tile(DARK, (4, 1)), xs).means, CAM, plate, (H, W))
    assert np.allclose(walls[0], WHITE, atol=1 / 255) and np.allclose(walls[2], WHITE, atol=1 / 255)
    assert np.allclose(walls[1], BLUE, atol=1 / 255) and np.allclose(walls[3], BLUE, atol=1 / 255)


def test_the_hair_more_wall_than_hair_is_cleared_against_the_wall_behind_it():
    rng = np.random.default_rng(0)
    n = 30
    colours = [DARK + rng.normal(0, 0.02, 3) for _ in range(n)]
    xs = list(rng.integers(17, 47, n))
    mix = lambda a, w: a * DARK + (1 - a) * w
    # on the white side: 0.3 of hair cleared, 0.7 kept; on the blue side the same against blue,
    # and a white mix there (not the wall behind it) kept
    extra = [(mix(0.3, WHITE), 20), (mix(0.3, WHITE), 22), (mix(0.7, WHITE), 21),
             (mix(0.3, BLUE), 42), (mix(0.7, BLUE), 43), (mix(0.3, WHITE), 44),
             (DARK + [0.4, 0.0, 0.0], 24)]                     # a red highlight: off the segment
    hair = _hair(colours + [c for c, _ in extra], xs + [x for _, x in extra])
    out, info = hair_fringe.clear_wall_hair(hair, CAM, _plate(), (H, W))
    assert info["cleared"] == 3
    gone = set(range(len(hair))) - set(out.extras["tag"].tolist())
    assert gone == {n + 0, n + 1, n + 3}


def test_blond_hair_on_a_white_wall_keeps_its_own_shades():
    blond = np.array([0.72, 0.55, 0.42])
    rng = np.random.default_rng(1)
    colours = [np.clip(blond + rng.normal(0, 0.04, 3), 0, 1) for _ in range(40)]
    hair = _hair(colours + [0.3 * blond + 0.7 * WHITE], list(rng.integers(17, 47, 41)))
    out, info = hair_fringe.clear_wall_hair(hair, CAM, _plate(right=WHITE), (H, W))
    assert info["cleared"] == 1 and len(out) == 40


def test_off_without_a_plate_or_with_the_switch(monkeypatch):
    hair = _hair([0.3 * DARK + 0.7 * WHITE, DARK, DARK], [20, 21, 22])
    assert len(hair_fringe.clear_wall_hair(hair, CAM, None, (H, W))[0]) == 3
    assert len(hair_fringe.clear_wall_hair(hair, CAM, _plate(), (H, W))[0]) == 2
    monkeypatch.setattr(hair_fringe, "WALL_SHARE", None)
    assert len(hair_fringe.clear_wall_hair(hair, CAM, _plate(), (H, W))[0]) == 3
