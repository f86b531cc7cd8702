"""What a user's video may hold that our turning clips do not (session 28): a second, smaller face
beside the person's, a clip that opens on the empty wall, no face at all, and an error about the
reference keyframe that names the video rather than a temporary file."""
import cv2
import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.head.model import HeadModel
from avatarkit.motion.clip import MotionClip
from avatarkit.synthetic.head_video import HeadVideo, SyntheticFrame, head_video_camera

SIZE = 224
FPS = 4.0
SMALL = 72   # the second face's square: its detector box ~0.3 of the person's


@pytest.fixture(scope="module")
def heads():
    """(4, SIZE, SIZE, 3) uint8: the template head turning to 0.2 rad over a plain wall."""
    T = 4
    t = np.linspace(0, 1, T)
    rot = np.stack([np.zeros(T), 0.2 * np.sin(np.pi * t), np.zeros(T)], axis=1)
    clip = MotionClip(fps=FPS, rotation=rot, translation=np.zeros((T, 3)), neck=np.zeros((T, 3)),
                      jaw=np.zeros((T, 3)), eyes=np.zeros((T, 6)), expr=np.zeros((T, 9)))
    hv = HeadVideo(clip, head_video_camera(SIZE, distance=0.45), n_gaussians=15000)
    return np.stack([f.rgb for f in hv.frames()])


def _with_small_face(frame, small):
    out = frame.copy()
    out[:SMALL, :SMALL] = cv2.resize(small, (SMALL, SMALL), interpolation=cv2.INTER_AREA)
    return out


def test_the_tracker_follows_the_person_not_a_smaller_face_beside_them(heads):
    from avatarkit.face import detect_faces
    from avatarkit.track import TrackOptions, track_frames

    wall = np.broadcast_to(heads[0][0, -1], heads[0].shape).copy()   # the top right corner's colour
    # a small face (the head again, 0.3 of its size) top left in every frame, left of the person;
    # in frame 2 the person is gone (a profile the detector misses), only the small face is left
    rgb = [_with_small_face(f, heads[2]) for f in (heads[0], heads[1], wall, heads[2], heads[3])]
    faces = detect_faces(rgb[0])
    assert len(faces) == 2 and faces[0].center[0] < 60 < faces[1].center[0]   # the small one is first
    assert faces[0].width < 0.4 * faces[1].width
    frames = [SyntheticFrame(i, i / FPS, f) for i, f in enumerate(rgb)]
    model = HeadModel.template()
    r = track_frames(frames, model, np.zeros(model.num_shape), (SIZE, SIZE), FPS, TrackOptions())
    # the person's face in every frame that shows it, none where only the small face is left
    assert r.found.tolist() == [True, True, False, True, True]
    centres = np.nanmean(r.landmarks[r.found], axis=1)            # (4, 2) pixels
    assert (centres[:, 0] > 90).all() and (centres[:, 1] > 90).all(), centres


def test_pick_face_keeps_the_index_among_the_faces_of_the_persons_size():
    from avatarkit.face.detect import Face
    from avatarkit.track.tracker import _pick_face

    def face(x, w):
        return Face(np.array([x, 50, x + w, 50 + w], np.float32), np.zeros((6, 2), np.float32), 0.9, "short")

    small, left, right = face(0, 30), face(40, 100), face(160, 90)
    assert _pick_face([small, left, right], 0, None) is left
    assert _pick_face([small, left, right], 1, None) is right
    assert _pick_face([small, left, right], 2, None) is None
    # re-detection: the nearest face of the followed face's size; a smaller one is not taken
    assert _pick_face([small], 0, np.array([90.0, 100.0]), 100.0) is None
    assert _pick_face([small, right], 0, np.array([10.0, 60.0]), 100.0) is right


def _write(path, frames, fps):
    from avatarkit.export.video import VideoWriter

    with VideoWriter(path, fps=fps, crf=12) as w:
        for f in frames:
            w.append(f)


def test_a_clip_that_opens_on_the_empty_wall_for_longer_than_the_identity_window(heads, tmp_path):
    from avatarkit.track.video import IDENTITY_SECONDS, track_video

    wall = np.broadcast_to(heads[0][0, 0], heads[0].shape).copy()
    empty = int(IDENTITY_SECONDS * FPS) + 4                         # 4 s of wall, then the person
    path = tmp_path / "steps_in.mp4"
    _write(path, [wall] * empty + list(heads), FPS)
    r = track_video(path)
    assert r.found.tolist() == [False] * empty + [True] * len(heads)


def test_a_video_without_a_face_fails_clearly_and_writes_nothing(heads, tmp_path, capsys):
    from avatarkit.cli.main import main

    wall = np.broadcast_to(heads[0][0, 0], heads[0].shape).copy()
    path = tmp_path / "wall.mp4"
    _write(path, [wall] * 20, FPS)                                   # 5 s: two identity windows
    out = tmp_path / "avatar"
    code = main(["build", str(path), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"error: {path}: no face found in the video"), line
    assert "5.0 s" in line
    assert not out.exists() and list(tmp_path.iterdir()) == [path]


def test_an_error_about_the_reference_keyframe_names_the_video_and_the_frame(tmp_path):
    from avatarkit.track.video_build import _frame_errors

    folder = tmp_path / "avatarkit-frame-x"
    folder.mkdir()
    with pytest.raises(InputError) as e:
        with _frame_errors(str(folder), "/videos/me.mp4", 50):
            raise InputError("face is too small: 30x30 px", folder / "frame50.png")
    assert str(e.value) == "/videos/me.mp4 (frame 50): face is too small: 30x30 px"
    # an error about another file is left as it is
    with pytest.raises(InputError, match=r"^/models/head.pkl: bad"):
        with _frame_errors(str(folder), "/videos/me.mp4", 50):
            raise InputError("bad", "/models/head.pkl")
