"""The tracked head motion carried by the neck joint (`track.neck`): the head lands exactly where
the global pose put it, the body keeps the reference rotation and only translates."""
import numpy as np

from avatarkit.head.model import HeadParams, load_template
from avatarkit.rotations import axis_angle_to_matrix
from avatarkit.track.neck import head_on_neck, head_rotation, median_rotation


def _random_clip(rng, model, T=12, neck=False):
    return dict(rotation=rng.normal(scale=0.4, size=(T, 3)), translation=rng.normal(scale=0.05, size=(T, 3)),
                neck=rng.normal(scale=0.2, size=(T, 3)) if neck else np.zeros((T, 3)),
                jaw=rng.normal(scale=0.1, size=(T, 3)), eyes=rng.normal(scale=0.1, size=(T, 6)),
                expr=rng.normal(scale=1.0, size=(T, model.num_expr)),
                shape=rng.normal(scale=1.0, size=model.num_shape))


def _pose(model, c):
    p = HeadParams(**{k: np.asarray(v, np.float32) for k, v in c.items()})
    return model.forward(p)[0].astype(np.float64), model.shaped_vertices(p).astype(np.float64)


def _joints(model, c):
    """(T, J, 3) rest joints of clip dict c (its shape, each frame's expression)."""
    return model.rest_joints(HeadParams(shape=c["shape"].astype(np.float32),
                                        expr=c["expr"].astype(np.float32))).astype(np.float64)


def test_head_lands_where_the_global_pose_put_it_and_the_body_only_translates():
    model = load_template()
    w = model.weights
    head = w[:, 0] == 0           # every vertex on the neck, jaw and eyes only
    body = w[:, 0] == 1           # the neck's base ring: root only
    assert head.sum() > 1000 and body.sum() > 50
    for seed, with_neck in ((0, False), (1, False), (2, True)):
        rng = np.random.default_rng(seed)
        c = _random_clip(rng, model, neck=with_neck)
        before, shaped = _pose(model, c)
        joints = _joints(model, c)
        ref = rng.normal(scale=0.3, size=3)
        rot, neck, tau = head_on_neck(c["rotation"], c["translation"], c["neck"], joints, ref)
        after, _ = _pose(model, {**c, "rotation": rot, "neck": neck, "translation": tau})
        # float32 posing of ~0.2 m coordinates: ~1e-7 m apart
        np.testing.assert_allclose(after[:, head], before[:, head], atol=2e-6)
        np.testing.assert_allclose(rot, np.broadcast_to(ref, rot.shape), atol=1e-12)
        np.testing.assert_allclose(head_rotation(rot, neck), head_rotation(c["rotation"], c["neck"]), atol=1e-9)
        R0 = axis_angle_to_matrix(ref).astype(np.float64)
        offset = after[:, body] - shaped[:, body] @ R0.T             # (T, n, 3): one translation per frame
        np.testing.assert_allclose(offset, np.broadcast_to(offset[:, :1], offset.shape), atol=2e-6)
        # and before, the body turned with the head (what this change removes)
        assert np.abs(before[:, body] - after[:, body]).max() > 0.01


def test_body_follows_the_neck_joint_and_the_reference_frame_is_unchanged():
    model = load_template()
    rng = np.random.default_rng(3)
    c = _random_clip(rng, model)
    joints = _joints(model, c)
    row = 4
    rot, neck, tau = head_on_neck(c["rotation"], c["translation"], None, joints, c["rotation"][row])
    np.testing.assert_allclose(neck[row], 0, atol=1e-9)
    np.testing.assert_allclose(tau[row], c["translation"][row], atol=1e-12)
    _, A_before = model.forward(HeadParams(**{k: np.asarray(v, np.float32) for k, v in c.items()}))
    _, A_after = model.forward(HeadParams(**{k: np.asarray(v, np.float32) for k, v in
                                             {**c, "rotation": rot, "neck": neck, "translation": tau}.items()}))
    J1 = joints[:, 1]
    p_before = np.einsum("tab,tb->ta", A_before[:, 1, :3, :3], J1) + A_before[:, 1, :3, 3]
    p_root = np.einsum("tab,tb->ta", A_after[:, 0, :3, :3], J1) + A_after[:, 0, :3, 3]
    # the neck joint sits where the tracked head put it, and the root carries it there
    np.testing.assert_allclose(p_root, p_before, atol=1e-5)


def test_median_rotation_is_the_middle_of_a_spread_about_any_centre():
    rng = np.random.default_rng(5)
    centre = np.array([0.2, -0.5, 0.1])
    C = axis_angle_to_matrix(centre).astype(np.float64)
    from avatarkit.rotations import matrix_to_axis_angle

    offs = rng.normal(scale=0.15, size=(41, 3))
    offs -= np.median(offs, axis=0)                         # the spread's median is exactly zero
    rots = matrix_to_axis_angle(C @ axis_angle_to_matrix(offs).astype(np.float64)).astype(np.float64)
    got = axis_angle_to_matrix(median_rotation(rots)).astype(np.float64)
    angle = np.degrees(np.arccos(np.clip((np.trace(got.T @ C) - 1) / 2, -1, 1)))
    assert angle < 0.5
    # frames without a face are left out
    junk = np.vstack([rots, np.tile([2.0, 0.0, 0.0], (60, 1))])
    keep = np.r_[np.ones(41), np.zeros(60)]
    np.testing.assert_allclose(median_rotation(junk, keep), median_rotation(rots), atol=1e-12)


def test_per_frame_reference_puts_the_head_back_on_the_global_rotation():
    model = load_template()
    rng = np.random.default_rng(7)
    c = _random_clip(rng, model)
    joints = _joints(model, c)
    rot, neck, tau = head_on_neck(c["rotation"], c["translation"], None, joints, np.array([0.1, -0.2, 0.05]))
    back = head_on_neck(rot, tau, neck, joints, head_rotation(rot, neck))
    np.testing.assert_allclose(back[0], c["rotation"], atol=1e-9)
    np.testing.assert_allclose(back[1], 0.0, atol=1e-9)
    np.testing.assert_allclose(back[2], c["translation"], atol=1e-9)


def test_holding_the_base_keeps_the_head_and_puts_the_neck_base_on_the_segment():
    """`hold_base`: the head where it was; the root joint posed on the line from `base` to the
    neck joint, one rest neck length from the neck joint (so at `base` when the neck joint is
    that far from it)."""
    from avatarkit.track.neck import hold_base

    model = load_template()
    rng = np.random.default_rng(11)
    c = _random_clip(rng, model)
    head = model.weights[:, 0] == 0
    before, _ = _pose(model, c)
    joints = _joints(model, c)
    rot, neck, tau = head_on_neck(c["rotation"], c["translation"], None, joints, np.zeros(3))
    base = joints[3, 0] + tau[3]
    rot, neck, tau = hold_base(rot, tau, neck, joints, base)
    after, _ = _pose(model, {**c, "rotation": rot, "neck": neck, "translation": tau})
    np.testing.assert_allclose(after[:, head], before[:, head], atol=2e-6)
    _, A = model.forward(HeadParams(**{k: np.asarray(v, np.float32) for k, v in
                                       {**c, "rotation": rot, "neck": neck, "translation": tau}.items()}))
    A = A.astype(np.float64)
    root = np.einsum("tab,tb->ta", A[:, 0, :3, :3], joints[:, 0]) + A[:, 0, :3, 3]
    nk = np.einsum("tab,tb->ta", A[:, 1, :3, :3], joints[:, 1]) + A[:, 1, :3, 3]
    length = np.linalg.norm(joints[:, 1] - joints[:, 0], axis=1)
    np.testing.assert_allclose(np.linalg.norm(nk - root, axis=1), length, atol=1e-5)
    u, v = root - base, nk - base
    np.testing.assert_allclose(np.cross(u, v), 0.0, atol=1e-5)
    np.testing.assert_allclose(root[3], base, atol=1e-5)
    # the random clips move the neck joint by centimetres: the base moves by less than it
    assert np.linalg.norm(root - base, axis=1).max() < np.linalg.norm(nk - nk[3], axis=1).max()


def test_what_reads_the_head_pose_reads_it_the_same_with_the_head_on_the_neck():
    """The build frame's choice, the keyframes and the frames the colours are fused from read the
    head's rotation (global then neck): a clip carrying the head on the neck chooses the same
    frames as the same motion written globally."""
    from types import SimpleNamespace

    from avatarkit.motion.clip import MotionClip
    from avatarkit.track.build_frame import frame_costs
    from avatarkit.track.frame_colours import colour_frames
    from avatarkit.track.keyframes import choose_keyframes

    T = 40
    t = np.linspace(0, 1, T)
    rot = np.stack([0.15 * np.sin(6 * t), 1.2 * np.sin(3 * t), 0.05 * t], axis=1)   # turns to 69 deg
    z = np.zeros((T, 3))
    marks = np.zeros((T, 468, 2))
    marks[:, [33, 133, 362, 263], 0] = [-40, -20, 20, 40]
    marks[:, 61, 0], marks[:, 291, 0] = -24, 24
    marks[:, 13, 1], marks[:, 14, 1] = 50, 50

    def result(rotation, neck):
        clip = MotionClip(fps=30, rotation=rotation, translation=z, neck=neck, jaw=z, eyes=np.zeros((T, 6)),
                          expr=np.zeros((T, 4)))
        return SimpleNamespace(clip=clip, confidence=np.linspace(0.9, 1.0, T), found=np.ones(T, bool),
                               frame_index=np.arange(T), landmarks=marks, raw={"rotation": rot}, num_frames=T)

    model = load_template()
    glob = result(rot, z)
    r, n, _ = head_on_neck(rot, z, None, model.rest_joints()[0], np.array([0.0, 0.6, 0.0]))
    on_neck = result(r, n)
    np.testing.assert_allclose(frame_costs(on_neck), frame_costs(glob), atol=1e-5)
    np.testing.assert_array_equal(colour_frames(on_neck, count=8, reference=5), colour_frames(glob, count=8, reference=5))
    a, b = choose_keyframes(on_neck), choose_keyframes(glob)
    assert len(b.frame_index) > 1
    np.testing.assert_array_equal(a.frame_index, b.frame_index)
