"""The simulation on the test avatar made in code: template head (LBS with neck and jaw),
procedural hair grown from its scalp, a real cage with MVC proxies; and the paper's ablation."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.head.model import HeadParams
from avatarkit.motion import make_clip
from avatarkit.sim import SimConfig
from avatarkit.sim.ablation import format_table, run_ablation
from avatarkit.sim.driver import HairDriver, head_joint_of
from avatarkit.synthetic.head_hair import CLEARANCE, make_test_avatar


@pytest.fixture(scope="module")
def avatar():
    return make_test_avatar("long_straight", n_hair=6000, seed=0, cage_vertices=500)


@pytest.fixture(scope="module")
def driver(avatar):
    return HairDriver(avatar.head_model, avatar.hair, avatar.cage, SimConfig(),
                      rest_vertices=avatar.head_vertices, sdf=avatar.sdf)


def random_params(rng, frames=4) -> HeadParams:
    return HeadParams(rotation=rng.normal(scale=0.4, size=(frames, 3)),
                      translation=rng.normal(scale=0.05, size=(frames, 3)),
                      neck=rng.normal(scale=0.3, size=(frames, 3)),
                      jaw=np.abs(rng.normal(scale=0.2, size=(frames, 3))), num_frames=frames)


def test_test_avatar_hair_grows_from_the_scalp_outside_the_head(avatar):
    head = avatar.head_model
    d, _ = avatar.sdf.query(avatar.hair.means)
    assert d.min() > CLEARANCE - 2e-4
    strand = avatar.hair.extras["strand"]
    first = np.r_[True, strand[1:] != strand[:-1]]
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(avatar.head_vertices).query(avatar.hair.means[first])
    assert head.region_mask("scalp")[nearest].all()
    assert d[first].max() < 0.02  # roots sit on the scalp
    assert 300 <= avatar.cage.n_vertices <= 500


def test_roots_follow_the_scalp_exactly_in_any_pose(avatar, driver):
    """The scalp rides the head joint only, so whatever the rotation, neck, jaw and translation,
    every root must move exactly as that joint's skinning transform moves its rest position."""
    model = driver.model
    head = avatar.head_model
    assert driver.head_joint == head_joint_of(head) == 1
    vertices, transforms = head.forward(random_params(np.random.default_rng(5)))
    rest_roots = model.rest_positions[model.roots].astype(np.float64)
    for v, a in zip(vertices, transforms.astype(np.float64)):
        targets = model.root_targets(v)
        np.testing.assert_allclose(targets, rest_roots @ a[1, :3, :3].T + a[1, :3, 3], atol=2e-6)


def test_driver_settles_then_follows_a_whip_without_blowing_up(avatar, driver):
    clip = make_clip("whip", fps=30)
    rest_extent = np.linalg.norm(driver.model.rest_positions, axis=1).max()
    frames = list(driver.simulate_clip(clip, with_hair=False))
    assert len(frames) == clip.n_frames and frames[0].means is None
    cages = np.stack([f.cage for f in frames])
    assert np.isfinite(cages).all()
    m = driver.model
    for f in frames:
        local = (f.cage - f.head_transform[:3, 3]) @ f.head_transform[:3, :3]
        assert np.linalg.norm(local, axis=1).max() < 1.3 * rest_extent
    for f in frames[::15]:
        # roots are exactly on the head in every frame
        np.testing.assert_allclose(f.cage[m.roots], m.rest_positions[m.roots] @ f.head_transform[:3, :3].T
                                   + f.head_transform[:3, 3], atol=5e-6)
        means, quats, scales = driver.hair_arrays(f.cage)
        assert np.isfinite(means).all() and np.isfinite(quats).all() and (scales > 0).all()


def test_warm_start_settles_the_hair(avatar, driver):
    # the default warm-up (SimConfig.warmup_seconds), as bake and preview use it
    x = driver.reset()
    free = driver.model.free
    assert np.allclose(driver.state.velocities, 0)
    lowest = np.argsort(driver.model.rest_positions[:, 1])[:20]
    assert x[lowest, 1].mean() < driver.model.rest_positions[lowest, 1].mean()
    # one more second at rest barely moves it: it had settled (measured 0.3 mm; a 3-step
    # warm-up leaves the hair dropping by ~4 mm in that second, none by more)
    y = x.copy()
    for _ in range(30):
        y = driver.step(avatar.head_vertices, np.eye(4), 1 / 30)
    assert np.abs(y[free] - x[free]).max() < 0.001


def test_static_mode_moves_hair_rigidly_with_the_head(avatar, driver):
    static = HairDriver(avatar.head_model, avatar.hair, avatar.cage, SimConfig(static=True),
                        rest_vertices=avatar.head_vertices, model=driver.model, deformer=driver.deformer)
    clip = make_clip("turn", frames=6, fps=30)
    for f in static.simulate_clip(clip):
        a = f.head_transform
        np.testing.assert_allclose(f.means, avatar.hair.means @ a[:3, :3].T + a[:3, 3], atol=2e-4)


def check_ablation(avatar, hair, clips):
    """The paper's ablation: proxy collision keeps hair out of the head (<= 1% of centres
    inside per frame on average) with a smaller scalp gap than vertex collision, and running
    without collision lets more hair into the head than proxy collision does."""
    rows = run_ablation(avatar.head_model, hair, avatar.cage, clips,
                        rest_vertices=avatar.head_vertices, modes=("none", "vertex", "proxy"),
                        sdf=avatar.sdf)
    table = format_table(rows)
    by = {(r.mode, r.clip): r for r in rows}
    for clip in clips:
        assert by["proxy", clip].penetration_mean <= 0.01, table
        assert by["proxy", clip].gap_mm < by["vertex", clip].gap_mm, table
    none = sum(by["none", c].penetration_mean for c in clips)
    proxy = sum(by["proxy", c].penetration_mean for c in clips)
    assert none > proxy, table


def test_ablation_small(avatar):
    """2,000 of the hair Gaussians, the nod and a 1.5 s whip."""
    hair = avatar.hair.subset(np.random.default_rng(0).permutation(len(avatar.hair))[:2000])
    check_ablation(avatar, hair, {"nod": make_clip("nod", frames=30, fps=30),
                                  "whip": make_clip("whip", frames=45, fps=30)})


@pytest.mark.slow
def test_ablation_full(avatar):
    check_ablation(avatar, avatar.hair, {"nod": make_clip("nod", fps=30),
                                         "whip": make_clip("whip", fps=30)})


# --- rest, shape, and hair outside the posed head (issue 18) --------------------------------------
def frame_speeds(cages: np.ndarray, free: np.ndarray, fps: float) -> np.ndarray:
    """(T - 1,) the largest frame-difference speed (m/s) of a free cage vertex per frame."""
    return np.linalg.norm(np.diff(cages, axis=0), axis=2)[:, free].max(axis=1) * fps


def test_hair_comes_to_rest_on_a_still_head(avatar, driver):
    """6 s of a perfectly still head with the default settings: in the last second no free
    cage vertex moves faster than 1 cm/s (the frozen proxy of the old solver kept them at
    0.2-0.38 m/s, alternating by 3 mm a frame)."""
    driver.reset(dt=1 / 30)
    cages = np.stack([driver.step(avatar.head_vertices, np.eye(4), 1 / 30) for _ in range(180)])
    assert frame_speeds(cages, driver.model.free, 30)[-30:].max() < 0.01


@pytest.fixture(scope="module")
def whip_run(avatar, driver):
    """The whip, then 3 s holding its last pose: cages (T, C, 3), hair means (T, N, 3) and the
    skin's joint transforms (T, J, 4, 4) per frame; n: the whip's frame count."""
    clip = make_clip("whip", fps=30)
    n = clip.n_frames
    idx = np.r_[np.arange(n), np.full(90, n - 1)]
    params = HeadParams.from_clip(clip).select(idx)
    cages, means, joints = [], [], []
    for f in driver.simulate_clip(clip.replace(**{k: getattr(clip, k)[idx] for k in
                                                  ("rotation", "translation", "neck", "jaw", "eyes", "expr")})):
        cages.append(f.cage)
        means.append(f.means)
        joints.append(driver.frame.joint_transforms)
    return np.stack(cages), np.stack(means), np.stack(joints), n, params


def test_hair_comes_to_rest_after_the_whip(driver, whip_run):
    cages, _, _, n, _ = whip_run
    assert np.isfinite(cages).all()
    assert frame_speeds(cages[n - 1:], driver.model.free, 30)[-30:].max() < 0.01


def test_whip_keeps_the_cage_in_shape(driver, whip_run):
    """Hard stretch and volume hold at the default settings (measured +-4.2 %, volume 1.000;
    the old 4 substeps x 15 sweeps reached -18 %..+20 % and 0.874). The worst edge of the worst
    frame depends on the CPU's rounding (the whip is chaotic): 4.2 % on AMD EPYC, 5.3 % on Intel
    Xeon (one edge of 1,017 in one frame; the 99.9th percentile 2.9 %), so the bound is on both."""
    m = driver.model
    cages = whip_run[0][:whip_run[3]].astype(np.float64)
    strain = np.abs(np.linalg.norm(cages[:, m.edges[:, 0]] - cages[:, m.edges[:, 1]], axis=2) / m.edge_lengths - 1)
    assert np.percentile(strain, 99.9) < 0.04
    assert strain.max() < 0.08
    a, b, c = (cages[:, m.faces[:, k]] for k in range(3))
    volume = np.einsum("tfi,tfi->t", a, np.cross(b, c)) / 6 / m.rest_volume
    assert volume.min() > 0.97 and volume.max() < 1.03


def test_whip_keeps_hair_gaussians_out_of_the_posed_head(driver, whip_run):
    """Every frame: at most 0.1 % of the hair centres inside the posed head (jaw and neck
    skinned), none deeper than 1 mm."""
    _, means, joints, _, _ = whip_run
    for m, t in zip(means, joints):
        d, _ = driver.skin.query_posed(driver.model.sdf, m, t)
        assert np.mean(d < 0) <= 0.001 and d.min() > -0.001
