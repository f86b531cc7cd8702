"""The camera's lens (session 28): the build and the tracker assume a 50 mm-equivalent portrait
lens (`recon.fit.portrait_focal`) unless told another (`BuildOptions.focal_mm`,
`TrackOptions.focal_mm`, `--focal-mm`). Known answers: the focal length of a given lens, a head
rendered through a phone-like 26 mm lens fitted at its true distance only when the fit is told
the lens, and the lens reaching the fit, the tracker and the CLI."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.recon.fit import FOCAL_35MM, SENSOR_WIDTH_MM, fit_head, portrait_focal, synthetic_head_view
from avatarkit.track.tracker import TrackOptions, tracking_focal

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg"


def test_focal_of_a_given_lens_across_the_longer_side():
    # a phone's 1080x1920 portrait video through its ~26 mm-equivalent main camera
    assert portrait_focal(1080, 1920, 26.0) == pytest.approx(26.0 / 36.0 * 1920)
    assert portrait_focal(1920, 1080, 26.0) == pytest.approx(26.0 / 36.0 * 1920)
    # no lens given: the assumed one, unchanged
    assert portrait_focal(480, 480) == pytest.approx(FOCAL_35MM / SENSOR_WIDTH_MM * 480)
    assert portrait_focal(480, 480, None) == portrait_focal(480, 480)


def test_the_tracker_takes_the_lens_and_pixels_win():
    assert tracking_focal(TrackOptions(focal_mm=26.0), (1080, 1920)) == pytest.approx(26.0 / 36.0 * 1920)
    assert tracking_focal(TrackOptions(), (192, 192)) == pytest.approx(portrait_focal(192, 192))
    # an explicit focal in pixels (e.g. a saved tracking's camera) is used as is
    assert tracking_focal(TrackOptions(focal=300.0, focal_mm=26.0), (192, 192)) == 300.0


def test_a_head_through_a_phone_lens_is_placed_right_only_when_the_fit_knows_the_lens():
    # a 26 mm lens at 0.31 m shows the head as large as the assumed 50 mm lens at 0.6 m, with the
    # stronger perspective of the nearer camera
    size, distance = 256, 0.31
    f = portrait_focal(size, size, 26.0)
    view = synthetic_head_view((0.0, 0.2, 0.0), distance=distance, focal=f)
    told = fit_head(view.analysis, view.segmentation, focal=f)
    assumed = fit_head(view.analysis, view.segmentation)
    depth = -view.truth.translation[2]
    assert -told.translation[2] == pytest.approx(depth, rel=0.05)
    # the assumed (longer) lens puts the same picture much further away
    assert -assumed.translation[2] > 1.5 * depth
    assert told.camera.fx == pytest.approx(f)


def test_build_options_refuse_a_bad_lens():
    from avatarkit.recon.pipeline import BuildOptions

    for bad in (0.0, -26.0, float("nan"), float("inf"), True, "26"):
        with pytest.raises(InputError, match="focal length"):
            BuildOptions(focal_mm=bad).check()
    BuildOptions(focal_mm=26).check()
    BuildOptions(focal_mm=26.0).check()


class _Stop(Exception):
    pass


def test_the_build_fits_the_head_with_the_given_lens(monkeypatch):
    from avatarkit.recon import fit as fit_module
    from avatarkit.recon.pipeline import BuildOptions, build_avatar

    seen = {}

    def fake_fit(analysis, segmentation, *args, focal=None, **kwargs):
        seen["focal"], seen["size"] = focal, segmentation.labels.shape[:2]
        raise _Stop

    monkeypatch.setattr(fit_module, "fit_head", fake_fit)
    with pytest.raises(_Stop):
        build_avatar(SAMPLE, BuildOptions(focal_mm=26.0, preview=False, n_bald=1000, n_hair=500))
    assert seen["focal"] == pytest.approx(26.0 / 36.0 * max(seen["size"]))


def test_the_video_build_tracks_with_the_given_lens(monkeypatch):
    from avatarkit.recon.pipeline import BuildOptions
    from avatarkit.track import video as track_video_module
    from avatarkit.track.video_build import build_tracking

    seen = {}
    monkeypatch.setattr(track_video_module, "track_video", lambda video, **k: seen.update(k))
    build_tracking("clip.mp4", BuildOptions(focal_mm=24.0))
    assert seen["options"].focal_mm == 24.0
    assert tracking_focal(seen["options"], (1080, 1920)) == pytest.approx(24.0 / 36.0 * 1920)


def test_the_cli_passes_the_lens(monkeypatch, tmp_path):
    from click.testing import CliRunner

    from avatarkit.cli.main import cli
    from avatarkit.recon import pipeline

    seen = {}

    def fake_build(path, options, *a, **k):
        seen["focal_mm"] = options.focal_mm
        raise _Stop

    monkeypatch.setattr(pipeline, "build_avatar", fake_build)
    result = CliRunner().invoke(cli, ["build", str(SAMPLE), "-o", str(tmp_path / "out"), "--focal-mm", "26"])
    assert isinstance(result.exception, _Stop), result.output
    assert seen["focal_mm"] == 26.0
    result = CliRunner().invoke(cli, ["build", str(SAMPLE), "-o", str(tmp_path / "out"), "--focal-mm", "0"])
    assert result.exit_code != 0 and "focal-mm" in result.output


def test_the_frame_colours_stage_tracks_with_the_builds_lens(monkeypatch):
    from types import SimpleNamespace

    from avatarkit.track import frame_colours
    from avatarkit.track import video as track_video_module

    seen = {}

    def fake_tracked(avatar, video, meshes, options):
        seen["focal"] = tracking_focal(options, (1080, 1920))
        raise _Stop

    monkeypatch.setattr(track_video_module, "tracked_with_built_avatar", fake_tracked)
    tracking = SimpleNamespace(meshes=None, camera=SimpleNamespace(fx=portrait_focal(1080, 1920, 26.0)))
    with pytest.raises(_Stop):
        frame_colours.fuse_frame_colours(None, "clip.mp4", tracking, 0)
    # the build's tracking's focal, not the assumed lens's
    assert seen["focal"] == pytest.approx(26.0 / 36.0 * 1920)
