"""Video -> FLAME-style motion on the CPU (`avatarkit track`).

    track_video(path, ...) -> TrackResult      video.py: open, track, name
    track_frames(frames, model, shape, ...)    tracker.py: the per-frame loop and smoothing
    save_tracking / load_tracking              io.py: the clip .npz with camera and confidence
    whittaker                                  smooth.py: zero-lag smoothing
    eyes_pose                                  gaze.py: eye rotations from the iris
    choose_keyframes                           keyframes.py: a video build's keyframes by head pose
    fit_joint_identity                         joint_identity.py: one shape over several views
    build_video_avatar                         video_build.py: `avatarkit build VIDEO`
"""
from avatarkit.track.io import load_tracking, save_tracking
from avatarkit.track.smooth import whittaker
from avatarkit.track.tracker import TrackOptions, TrackResult, track_frames

__all__ = ["TrackOptions", "TrackResult", "load_tracking", "save_tracking", "track_frames", "whittaker"]
