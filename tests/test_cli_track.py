"""`avatarkit track` from the command line: a small rendered video end to end, and bad input."""
import numpy as np
import pytest
from helpers import one_error_line

from avatarkit.cli.main import main


@pytest.fixture(scope="module")
def head_mp4(tmp_path_factory):
    from avatarkit.export.video import write_video
    from avatarkit.motion.clip import MotionClip
    from avatarkit.synthetic.head_video import HeadVideo, head_video_camera

    T = 6
    rot = np.stack([np.zeros(T), np.linspace(-0.2, 0.2, T), np.zeros(T)], axis=1)
    clip = MotionClip(fps=24, rotation=rot, translation=np.zeros((T, 3)), neck=np.zeros((T, 3)),
                      jaw=np.zeros((T, 3)), eyes=np.zeros((T, 6)), expr=np.zeros((T, 9)))
    hv = HeadVideo(clip, head_video_camera(192, distance=0.45), n_gaussians=12000)
    path = tmp_path_factory.mktemp("v") / "head.mp4"
    write_video(path, [f.rgb for f in hv.frames()], fps=24)
    return path


def run(capsys, *args):
    code = main(list(args))
    return code, capsys.readouterr()


def test_track_writes_a_clip_bake_reads_and_a_preview(tmp_path, capsys, head_mp4):
    from avatarkit.motion.io import load_clip
    from avatarkit.track import load_tracking
    from avatarkit.video import open_video

    out, prev = tmp_path / "clip.npz", tmp_path / "overlay.mp4"
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(out), "--preview", str(prev), "--start", "1")
    assert code == 0, cap.err
    r = load_tracking(out)
    assert r.num_frames == 5 and r.found.all() and list(r.frame_index) == [1, 2, 3, 4, 5]
    assert r.camera.width == 192 and r.clip.fps == pytest.approx(24.0)
    # yaw increases over the clip as the rendered head turns; the head turns on the neck, the
    # body keeps the clip's median pose (`track --head-on neck`, the default)
    from avatarkit.track.neck import head_rotation, median_rotation

    head = head_rotation(r.clip.rotation, r.clip.neck)
    assert np.all(np.diff(head[:, 1]) > 0)
    np.testing.assert_allclose(r.clip.rotation, np.broadcast_to(median_rotation(head), (5, 3)), atol=1e-6)
    assert np.abs(r.clip.neck[[0, -1], 1]).min() > 0.05
    assert "head on the neck (the body held at the clip's median pose)" in cap.err
    assert load_clip(out).n_frames == 5
    with open_video(prev) as v:
        assert v.info.frame_count == 5 and v.info.codec == "h264"
    assert "tracked 5 frames" in cap.err



def test_not_a_video(tmp_path, capsys):
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    code, cap = run(capsys, "track", str(bad), "-o", str(tmp_path / "c.npz"))
    assert code == 2 and str(bad) in one_error_line(cap)
    assert not (tmp_path / "c.npz").exists()


def test_video_without_faces(tmp_path, capsys):
    from avatarkit.export.video import write_video

    path = tmp_path / "grey.mp4"
    write_video(path, [np.full((64, 64, 3), 100, np.uint8)] * 3, fps=10)
    code, cap = run(capsys, "track", str(path), "-o", str(tmp_path / "c.npz"), "-q")
    line = one_error_line(cap)
    assert code == 2 and "no face found in the video (3 frames looked at" in line and str(path) in line
    assert not (tmp_path / "c.npz").exists()


def test_frame_range_outside_the_video(tmp_path, capsys, head_mp4):
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "c.npz"), "--start", "40")
    assert code == 2 and "outside the video" in one_error_line(cap)


def test_unwritable_output_is_refused_before_any_work(tmp_path, capsys, head_mp4):
    blocker = tmp_path / "file"
    blocker.write_text("x")          # a path under a regular file: unwritable even as root
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(blocker / "c.npz"))
    assert code == 2 and "output folder" in one_error_line(cap)


def test_wrong_output_extension(tmp_path, capsys, head_mp4):
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "c.json"))
    assert code == 2 and ".npz" in one_error_line(cap)


def test_missing_video(tmp_path, capsys):
    code, cap = run(capsys, "track", str(tmp_path / "none.mp4"), "-o", str(tmp_path / "c.npz"))
    assert code == 2 and "not found" in one_error_line(cap)


def test_subject_calibration_needs_an_avatar(tmp_path, capsys, head_mp4):
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "c.npz"), "--subject-calibration")
    assert code == 2 and "--avatar" in cap.err and not (tmp_path / "c.npz").exists()


def test_subject_part_needs_the_subject_calibration(tmp_path, capsys, head_mp4):
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "c.npz"), "--subject-part", "rigid")
    assert code == 2 and "--subject-calibration" in cap.err and not (tmp_path / "c.npz").exists()


def test_photometric_refinement_needs_an_avatar(tmp_path, capsys, head_mp4):
    for how in ("photometric", "photometric-pose"):
        code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "c.npz"), "--refine", how)
        assert code == 2 and "--avatar" in cap.err and not (tmp_path / "c.npz").exists()
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "c.npz"), "--refine-every", "3")
    assert code == 2 and "--refine" in cap.err and not (tmp_path / "c.npz").exists()


def test_a_refined_track_says_its_landmark_error_is_against_landmarks_it_no_longer_follows(
        tmp_path, capsys, head_mp4, tmp_path_factory):
    """With --refine the pose follows the frames' pixels, so the landmark error it prints rises
    while the pose gets better (docs/tracking.md): the summary says what the figure measures."""
    from test_avatar import saved_avatar

    avatar = saved_avatar(tmp_path_factory)
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "r.npz"), "--avatar", str(avatar),
                    "--refine", "photometric-pose")
    assert code == 0, cap.err
    assert "landmark error" in cap.err and "no longer follows" in cap.err
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "p.npz"), "--avatar", str(avatar))
    assert code == 0, cap.err
    assert "landmark error" in cap.err and "no longer follows" not in cap.err
    # photometric: the jaw's opening moves too (the pose-only refinement leaves the fit's)
    code, cap = run(capsys, "track", str(head_mp4), "-o", str(tmp_path / "j.npz"), "--avatar", str(avatar),
                    "--refine", "photometric")
    assert code == 0, cap.err
    assert "no longer follows" in cap.err
    from avatarkit.track.io import load_tracking

    plain, pose, jaw = (load_tracking(tmp_path / f"{n}.npz").clip for n in ("p", "r", "j"))
    np.testing.assert_allclose(pose.jaw, plain.jaw, atol=1e-6)
    assert np.abs(jaw.jaw[:, 0] - plain.jaw[:, 0]).max() > 1e-3
    np.testing.assert_allclose(jaw.jaw[:, 1:], plain.jaw[:, 1:], atol=1e-6)


def test_the_refine_choices_are_the_trackers():
    """The CLI lists its --refine choices without importing the tracker (start-up time); they
    must stay `tracker.REFINE_SETTINGS`' names."""
    import click

    from avatarkit.cli.evaluate_cmd import evaluate_cmd
    from avatarkit.cli.track_cmd import track_cmd
    from avatarkit.track.tracker import REFINE_SETTINGS

    # evaluate refines by default, so it also names the landmark fit's pose ("none")
    for cmd, extra in ((track_cmd, []), (evaluate_cmd, ["none"])):
        (opt,) = [p for p in cmd.params if p.name == "refine"]
        assert isinstance(opt.type, click.Choice) and list(opt.type.choices) == extra + list(REFINE_SETTINGS)
