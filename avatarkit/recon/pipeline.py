"""`build_avatar`: one portrait -> an `Avatar` (issue 8; paper section 3.2), stage by stage.

Stages (`STAGES`, each timed and reported through the `progress` callback):

    read        the image (EXIF orientation, at most 2048 px)          recon.image_io
    analyse     the one face, landmarks                                 recon.portrait
    segment     background / skin / hair / body (or --hair-mask)        recon.segment
    fit         head pose, shape; the camera                            recon.fit
    views       a video build's keyframes: cameras, segmentations       recon.multiview
    bald        the 2D bald filter, guided by the fitted scalp          recon.bald
    lift        bald + hair Gaussians (built-in, or imported splats)    recon.lift
    segment3d   3D hair segmentation cleans the hair                    recon.labels3d
    rig         bald Gaussians bound to the head's triangles            recon.assemble.rig_bald
    assemble    hair out of the scalp, small head-shape adjustment      recon.assemble.assemble
    colours     uncovered head pixels filled, input-view render matched    recon.coverage, recon.assemble
                to the photo
    hair_rig    cage + weights + roots, or rigid scalp binding          recon.hair_rig
    previews    front / three-quarter / profile renders                 render

A video build (`track.video_build`) passes `views` (a `multiview.VideoViews`): the fit stage
fits the reference keyframe as a single-frame build would (shape included); the views
stage registers the keyframes to the fitted camera and segments them; segment3d lifts the hair
labels from every keyframe (votes), removes hair outside any keyframe's silhouette and grows the
shell where a keyframe shows hair beyond it (`recon.hair_hull`); colours turns the hair strands to
the directions the keyframes' hair flow gives (`recon.hair_directions`) and blends every
keyframe's samples before matching the reference photo (`recon.multiview`). Without
`views` the views stage does nothing.

A portrait without hair (a bald person: no hair pixels, or none left after the 3D hair
segmentation) builds a hairless avatar (no cage, no rig; `Avatar.has_hair` False) with the
warning `NO_HAIR_WARNING` in the build report; the hair_rig stage then does nothing.

`save_avatar` writes the folder atomically (a temp folder beside the target, renamed into
place): a failed build never leaves a partial avatar folder.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from avatarkit.errors import InputError
from avatarkit.fileio import atomic_folder

STAGES = ("read", "analyse", "segment", "fit", "views", "bald", "lift", "segment3d", "rig", "assemble",
          "colours", "hair_rig", "previews")
#: preview views: file name -> azimuth (degrees; 0 = the front)
PREVIEW_VIEWS = {"preview.png": 0.0, "preview_three_quarter.png": 45.0, "preview_profile.png": 90.0}
#: grid spacing (metres) of the head SDF the hair is grown on
LIFT_SDF_SPACING = 0.004
#: the build report's warning when the portrait has no hair
NO_HAIR_WARNING = "no hair found: building a bald avatar"
#: a video build also matches colours against every keyframe (`multiview.refine_colours_views`)
#: before the reference photo. Off: measured on the synthetic turning video (gain over the
#: single-frame build, front / +-45 / +-90 degrees), the sampled blend alone gives +0.19 /
#: +1.63, -0.33 / +3.77, +3.11 dB; with this step +0.24 / +1.62, -0.02 / +2.98, +3.18 dB; with
#: it and no final reference matching -3.39 / +3.22, +1.78 / +4.26, +4.65 dB (the keyframes'
#: registration error blurs the face)
MULTIVIEW_REFINE = False
#: a video build turns hair strand directions to what the keyframes' hair flow shows
#: (`recon.hair_directions`) and grows the hair shell where keyframes show more hair
#: (`recon.hair_hull`); measured in docs/video-build.md
MULTIVIEW_HAIR_DIRECTIONS = True
#: a video build keeps the colours of the Gaussians only the other keyframes saw after the
#: reference photo's colour matching (`multiview.VideoViews.keep_view_colours`)
KEEP_VIEW_COLOURS = True
GROW_HAIR_HULL = True
#: the lifter's hidden strands reach down as low as the turned keyframes show hair on the back
#: of the head (`recon.hair_end`). Off: over three lifter seeds the profile gains +0.35 / +1.21
#: dB (+90 / -90) on the sample avatar and +0.84 / +0.58 on the mesh subject, every seed
#: positive, but the held-out bob does not move (its photo already shows lower hair) and the
#: other views are flat within the seed noise (docs/video-build.md, "The hair's end, made
#: robust", session 13)
HAIR_END_FROM_VIEWS = False
#: a video build moves its outermost hair out to where the keyframes' silhouettes show the
#: person's hair beyond the avatar's outline (`recon.hair_outline`; the tracking's edge frames
#: do not count), each turned keyframe seen at its pose registered against the draft build, twice
#: (`track.video_build.OUTLINE_POSES`, `SECOND_ROUND`). On since session 14 (later): with the
#: joint fit's poses it cost the 32-frame whip clip's sample avatar 0.98 dB at +45 (turn-end
#: frames read short without the face being lost); with the registered poses the whip's worst
#: view is -0.04 (two seeds, both tuning subjects), and the eased clip keeps its profile gains
#: (sample avatar +1.27 / +2.11 dB at +90 / -90, mesh subject +0.10 / +0.12, the held-out bob
#: -0.11 / +0.24; docs/video-build.md, "Keyframe poses the outline can trust"). A video with one
#: keyframe (the real clips) never runs it
FIT_HAIR_OUTLINE = True
#: a video build (several keyframes) then matches its colours to every keyframe at once, each
#: Gaussian's update led by the keyframes that face it best (`recon.facing_refine`). Off:
#: measured on the synthetic turning videos (eased clip, gain front / +-45 / +-90 degrees) the
#: sample avatar -0.03 / +0.07 / +0.04 / +0.10 / +0.10 dB, the mesh subject -0.22 / +0.26 /
#: +0.39 / +0.07 / +0.18; in the whole build the held-out bob lost 1.17 dB at the front
#: (docs/video-build.md, session 12)
FACING_REFINE = False
#: Gaussians on the photo's head pixels the assembled avatar leaves uncovered in the input view
#: (`recon.coverage`), before the colour matching
COVER_SILHOUETTE = True
#: teeth and a mouth cavity behind the lips, and lips that part instead of stretching across the
#: opening (`recon.mouth`; docs/building.md "The open mouth", session 14). The video build can
#: open it just before its frame-colours stage instead (`track.video_build.OPEN_MOUTH`)
OPEN_MOUTH = False
#: label images for the 3D segmentation are at most this large (pixels)
LABEL_SIDE = 512

Progress = Callable[[str, int, int, "float | None"], None]


@dataclass
class BuildOptions:
    """Everything `avatarkit build` can be told (paths may be str or Path).

    hair_mask: PNG whose non-zero pixels are hair (replaces the built-in hair segmentation).
    head_splats / bald_splats: 3DGS PLYs from an image-to-3D lifter (both or neither).
    head_model: a FLAME .pkl (or avatarkit .npz) to use instead of the built-in template.
    flame_params: a tracker's FLAME fit (.npz): its identity shape is used, not fitted.
    face_index: which face when the photo has several (left to right, from 0).
    face_detector: "auto" (MediaPipe's face models when installed, else the cascades with a
    warning), "mediapipe" or "cascade". landmark_embedding: a FLAME
    `mediapipe_landmark_embedding.npz` putting face-mesh points on --head-model's triangles
    (the template's ships with avatarkit).
    n_bald / n_hair: built-in lifter's Gaussian counts (hair: at most).
    hair_mode: "auto" (short hair rigid, long hair simulated), "cage" or "rigid".
    clean_hair: run the 3D hair segmentation on the hair (always on for imported splats).
    refine_iterations: rounds of colour matching against the photo (0 = off).
    preview: render the preview images. name: the avatar's name (default: the photo's stem).
    focal_mm: the camera's lens, 35 mm-equivalent across the image's longer side (None: the
    assumed 50 mm portrait lens, `recon.fit.portrait_focal`); a video build tracks with it too.
    """

    hair_mask: str | os.PathLike | None = None
    head_splats: str | os.PathLike | None = None
    bald_splats: str | os.PathLike | None = None
    head_model: str | os.PathLike | None = None
    flame_params: str | os.PathLike | None = None
    face_index: int | None = None
    face_detector: str = "auto"
    landmark_embedding: str | os.PathLike | None = None
    n_bald: int = 40_000
    n_hair: int = 40_000
    cage_vertices: int = 500
    hair_mode: str = "auto"
    clean_hair: bool = True
    refine_iterations: int = 6
    preview: bool = True
    preview_size: int = 512
    seed: int = 0
    name: str | None = None
    focal_mm: float | None = None

    def check(self) -> None:
        if (self.head_splats is None) != (self.bald_splats is None):
            raise InputError("--head-splats and --bald-splats go together: give both or neither")
        from avatarkit.recon.portrait import FACE_DETECTORS

        if self.face_detector not in FACE_DETECTORS:
            raise InputError(f"face detector must be one of {', '.join(FACE_DETECTORS)}, got {self.face_detector!r}")
        if self.hair_mode not in ("auto", "cage", "rigid"):
            raise InputError(f"hair mode must be auto, cage or rigid, got {self.hair_mode!r}")
        for name in ("n_bald", "cage_vertices", "preview_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        if isinstance(self.n_hair, bool) or int(self.n_hair) != self.n_hair or self.n_hair < 0:
            raise InputError(f"n_hair must be a non-negative integer, got {self.n_hair!r}")
        if self.focal_mm is not None and not (isinstance(self.focal_mm, (int, float)) and not isinstance(self.focal_mm, bool)
                                              and math.isfinite(self.focal_mm) and self.focal_mm > 0):
            raise InputError(f"focal length (mm) must be a positive number, got {self.focal_mm!r}")
        if self.face_index is not None and (int(self.face_index) != self.face_index or self.face_index < 0):
            raise InputError(f"face index must be a non-negative integer, got {self.face_index!r}")
        for name in ("hair_mask", "head_splats", "bald_splats", "head_model", "flame_params", "landmark_embedding"):
            value = getattr(self, name)
            if value is not None and not Path(value).is_file():
                what = name.replace("_", " ")
                raise InputError(f"{what} file not found" if not Path(value).exists()
                                 else f"{what} is not a file", value)


@dataclass(eq=False)
class BuildReport:
    """What a build did: seconds per stage, counts, fit residuals, warnings."""

    timings: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def to_json(self) -> dict:
        return {"timings_s": {k: round(v, 3) for k, v in self.timings.items()},
                "total_s": round(sum(self.timings.values()), 3), **self.info,
                "warnings": list(self.warnings)}


class _Stages:
    """Times the stages and tells `progress` about each (start: seconds None; end: seconds)."""

    def __init__(self, progress: Progress | None, report: BuildReport):
        self.progress = progress
        self.report = report

    def __call__(self, name: str):
        return _Stage(self, name)


class _Stage:
    def __init__(self, owner: _Stages, name: str):
        self.owner, self.name = owner, name

    def __enter__(self):
        self.t0 = time.perf_counter()
        if self.owner.progress:
            self.owner.progress(self.name, STAGES.index(self.name) + 1, len(STAGES), None)
        return self

    def __exit__(self, exc_type, exc, tb):
        dt = time.perf_counter() - self.t0
        self.owner.report.timings[self.name] = dt
        if exc_type is None and self.owner.progress:
            self.owner.progress(self.name, STAGES.index(self.name) + 1, len(STAGES), dt)
        return False


def _labels_for(labels: np.ndarray, camera, side: int | None = None):
    """Labels (H, W) and the camera shrunk (nearest neighbour) so the longer side is <= side."""
    side = LABEL_SIDE if side is None else side
    import cv2

    h, w = labels.shape
    k = min(1.0, side / max(h, w))
    if k >= 1:
        return labels, camera
    size = (max(1, round(w * k)), max(1, round(h * k)))
    small = cv2.resize(labels.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    return small, camera.with_size(*size)


def clean_hair(bald, hair, camera, labels: np.ndarray, surface_distance=None, clear: bool = True):
    """The 3D hair segmentation (item 6, `recon.labels3d.split_hair`) of the hair, from the
    photo's label image seen by `camera`, over bald + hair together: labels lifted from the
    view, then the boundary-aware reassignment; hair candidates that end up labelled anything
    but hair are dropped. Returns (hair kept, summary dict). camera and labels may also be
    lists (a video build's keyframes): the lifting sums every view's votes.

    surface_distance: a callable (P, 3) points -> (P,) signed distance to the fitted head
    (e.g. `HeadSDF.query(...)[0]`), or None. With one labelled view it is what keeps the hidden
    hair (behind the visible hair, at the back) as hair and the scalp seen through the hair's
    gaps out of it (`reassign_boundary`). clear: `reassign_boundary`'s (the views' clear votes
    may take hair out, `hair_reassign.CLEAR_SHARE`)."""
    from avatarkit.gaussians.gaussian_set import GaussianSet
    from avatarkit.recon.labels3d import split_hair

    if len(hair) == 0:
        return hair, {"hair_in": 0, "hair_kept": 0}
    cams, labs = (camera, labels) if isinstance(camera, (list, tuple)) else ([camera], [labels])
    views = [_labels_for(np.asarray(lab), cam) for cam, lab in zip(cams, labs)]
    union = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    sd = None if surface_distance is None else np.asarray(surface_distance(union.means), np.float64)
    _, _, report = split_hair(union, [c for _, c in views], [lab.astype(np.int32) for lab, _ in views],
                              surface_distance=sd, clear=clear)
    is_hair = np.zeros(len(union), bool)
    is_hair[report.hair_index] = True
    keep = is_hair[len(bald):]
    extra = {f"split_{k}": v for k, v in report.summary().items()}
    extra["unseen_hair_kept"] = int((keep & ~report.lift.seen[len(bald):]).sum())
    return hair.subset(keep), {"hair_in": len(hair), "hair_kept": int(keep.sum()),
                               "surface_distance": sd is not None, **extra}


def head_mask(segmentation) -> np.ndarray:
    """(H, W) bool: the pixels of the head in the photo (skin + hair labels): where colours
    are matched and where the benchmark's PSNR is measured."""
    from avatarkit.recon.segment import HAIR, SKIN

    return np.isin(segmentation.labels, (SKIN, HAIR))


def render_previews(avatar, size: int = 512, background=(1.0, 1.0, 1.0)) -> dict[str, np.ndarray]:
    """File name -> (size, size, 3) uint8 view of the avatar at rest (PREVIEW_VIEWS), all framed
    on the same bounds."""
    from avatarkit.export.images import to_uint8
    from avatarkit.render import render
    from avatarkit.render.views import frame_camera, scene_bounds

    gs = avatar.rest_gaussians()
    bounds = scene_bounds(gs)
    return {name: to_uint8(render(gs, frame_camera(bounds, azimuth, 0.0, width=size, height=size),
                                  background).rgb)
            for name, azimuth in PREVIEW_VIEWS.items()}


def attach_previews(avatar, size: int = 512) -> dict[str, np.ndarray]:
    """Render the avatar's previews (`render_previews`) and attach them (`preview`,
    `extra_previews`, `build_previews`, which `save_avatar` writes); returns them. A stage that
    changes the avatar after the build (the video build's frame_colours) calls it again, so the
    saved previews show what was saved."""
    previews = render_previews(avatar, size)
    avatar.preview = previews["preview.png"]
    avatar.extra_previews = {k: v for k, v in previews.items() if k != "preview.png"}
    avatar.build_previews = previews
    return previews


def _preload() -> None:
    """Import torch and Taichi (`build_avatar` runs this beside its first stages). Only a head
    start: a failure here is left for the stage that needs the module to report."""
    from avatarkit._taichi import import_taichi

    try:
        import torch  # noqa: F401

        import_taichi()
    except Exception:  # noqa: BLE001 - the fit / lift's own import raises it where it belongs
        pass


def build_avatar(portrait_path: str | os.PathLike, options: BuildOptions | None = None,
                 progress: Progress | None = None, views=None, plate=None):
    """Build an `Avatar` from a portrait (module docstring). progress(stage, index, total,
    seconds): called when each stage starts (seconds None) and ends. The `BuildReport` is in
    `avatar.provenance["build"]`; the previews (if rendered) in `avatar.build_previews`.
    views: a `recon.multiview.VideoViews` (a video build: the portrait is its reference
    keyframe), or None. plate: the wall plate of the video the portrait is a frame of
    (`track.background_plate`), given to its segmentation, or None."""
    from avatarkit.avatar import Avatar, _now, _tool_version
    from avatarkit.head.ref import HeadRef
    from avatarkit.face.correspondence import read_embedding
    from avatarkit.head.io import load_head_model
    from avatarkit.recon.assemble import assemble, refine_colours, rig_bald
    from avatarkit.recon.bald import make_bald_image
    from avatarkit.recon import outline_trim
    from avatarkit.recon.fit import fit_head, fit_with_params, load_flame_params, portrait_focal, scalp_hint
    from avatarkit.recon.hair_rig import detect_hair_mode, rig_hair, rig_sdf
    from avatarkit.recon.image_io import load_image
    from avatarkit.recon.import_lifter import ImportLifter
    from avatarkit.recon.lift import BuiltinLifter
    from avatarkit.recon.portrait import analyze_portrait
    from avatarkit.recon.segment import segment_portrait
    from avatarkit.head.sdf_grid import HeadSDF
    from avatarkit.recon.background import Background

    options = options or BuildOptions()
    options.check()
    # torch (the fit) and Taichi (the lift's renders) take ~2 CPU s of Python to import. Loaded
    # on a second thread while this one reads, analyses and segments the photo (OpenCV, LiteRT:
    # mostly off the GIL), they cost the build little wall time. Those stages import none of
    # the modules these two load, so the threads never wait on each other's import locks.
    Background(_preload, name="avatarkit-preload")
    report = BuildReport()
    stage = _Stages(progress, report)
    path = Path(portrait_path)

    with stage("read"):
        loaded = load_image(path)
        image = loaded.rgb
        head_model = load_head_model(options.head_model)
        head_ref = HeadRef.for_file(options.head_model) if options.head_model else HeadRef()
        flame = load_flame_params(options.flame_params) if options.flame_params else None
        embedding = (read_embedding(options.landmark_embedding, head_model.num_faces)
                     if options.landmark_embedding else None)
        lifter = (ImportLifter(options.head_splats, options.bald_splats) if options.head_splats
                  else BuiltinLifter(options.n_bald, options.n_hair, options.seed))
    with stage("analyse"):
        analysis = analyze_portrait(image, options.face_index, path=path, detector=options.face_detector)
        report.warnings.extend(analysis.warnings)
        report.info["face"] = {"detector": analysis.detector, "faces": len(analysis.faces),
                               "face_mesh": analysis.mesh is not None}
    with stage("segment"):
        segmentation = segment_portrait(image, analysis, options.hair_mask, path=path, plate=plate)
    with stage("fit"):
        # the lens the user gave (None: `recon.fit.portrait_focal`'s assumed one)
        focal = None if options.focal_mm is None else portrait_focal(image.shape[1], image.shape[0], options.focal_mm)
        if flame is not None and views is None:
            fit = fit_with_params(analysis, segmentation, head_model, flame, embedding=embedding, focal=focal)
        else:
            # a video build fits its reference keyframe as the single-frame build does (shape
            # included): with the joint identity fixed, the pose-only fit matched the reference
            # worse and cost the front view 1.3-2 dB on the synthetic turning videos
            # (docs/video-build.md); the joint fit's poses still register the keyframes
            fit = fit_head(analysis, segmentation, head_model, embedding=embedding, focal=focal)
        report.info["fit"] = fit.summary()
        report.info["camera"] = fit.camera.to_dict()
        # a coarse SDF is enough to grow hair on; the rig gets a fine one of the final head.
        # Computed on the other core (its kd-tree query is off the GIL) while the bald head is
        # lifted (Taichi's start and kernel compiles: one thread of Python); the hair lift is
        # the first to need it
        pending_sdf = Background(HeadSDF.build, fit.rest_vertices, head_model.faces, spacing=LIFT_SDF_SPACING,
                                 name="avatarkit-lift-sdf")
    with stage("views"):
        keyviews = []
        if views is not None:
            keyviews = views.register(fit, image, segmentation.labels, options)
            report.info["video"] = views.summary(keyviews)
            report.warnings.extend(w for v in keyviews for w in v.info.get("warnings", []))
    with stage("bald"):
        bald_image = make_bald_image(image, segmentation, analysis, scalp_hint(fit))
    with stage("lift"):
        if isinstance(lifter, BuiltinLifter):
            lifter.sdf = pending_sdf
            lifter.hair_end = None
            if keyviews and HAIR_END_FROM_VIEWS:
                from avatarkit.recon.hair_end import back_of_head, hair_end_from_views

                lifter.hair_end = hair_end_from_views(fit.rest_vertices, head_model.faces, keyviews,
                                                      back_of_head(fit.rest_vertices, head_model.regions))
                report.info["hair_end_from_views"] = lifter.hair_end
        lifted = lifter.lift(image, analysis, segmentation, bald_image, fit)
        sdf = pending_sdf.result()
        report.info["lift"] = dict(lifted.info)
    with stage("segment3d"):
        hair = lifted.hair
        if options.clean_hair or isinstance(lifter, ImportLifter):
            labelled = [v for v in keyviews if v.labels is not None] or None
            hair, summary = clean_hair(lifted.bald, hair,
                                       [v.camera for v in labelled] if labelled else fit.camera,
                                       [v.labels for v in labelled] if labelled else segmentation.labels,
                                       lambda p: sdf.query(p)[0],
                                       clear=views is None or views.clears_hair())
            report.info["segment3d"] = summary
        if keyviews and len(hair):
            from avatarkit.recon.multiview import silhouette_outside

            inside = silhouette_outside(hair.means, keyviews) == 0
            report.info.setdefault("segment3d", {})["outside_silhouettes"] = int((~inside).sum())
            hair = hair.subset(inside)
        if keyviews and len(hair) and GROW_HAIR_HULL:
            from avatarkit.gaussians.gaussian_set import GaussianSet
            from avatarkit.recon.hair_hull import grow_hull

            grown, report.info["segment3d"]["hull"] = grow_hull(lifted.bald, hair, keyviews, sdf)
            hair = GaussianSet.concat([hair, grown]) if len(grown) else hair
        if keyviews and len(hair) and FIT_HAIR_OUTLINE and views.info.get("fit_outline", True):
            from avatarkit.recon.hair_outline import fit_outline

            edge = frozenset(views.info.get("tracking_edge", [])) | frozenset(views.info.get("untrusted_poses", []))
            # the keyframes' poses registered against the draft build where the video build did so
            # (`track.video_build.refine_keyframes`): a turn's end read short asks for pushes
            hair, report.info.setdefault("segment3d", {})["outline"] = fit_outline(
                lifted.bald, hair, views.outline_views(fit, keyviews), sdf, edge,
                draft=bool(views.info.get("draft", False)))
        if len(hair) == 0:
            report.warnings.append(NO_HAIR_WARNING)
    with stage("rig"):
        binding = rig_bald(lifted.bald, fit)
    with stage("assemble"):
        assembled = assemble(fit, binding, hair, analysis, screen=sdf)
        report.info["assemble"] = assembled.report
        fit = assembled.fit
        # the rig's fine head SDF needs only the final head: made on the other core while the
        # colours are matched (mostly one thread), the hair_rig stage only collects it
        pending_rig_sdf = (Background(rig_sdf, fit.rest_vertices, fit.model.faces, name="avatarkit-rig-sdf")
                           if len(assembled.hair) else None)
    with stage("colours"):
        bald, hair = assembled.bald, assembled.hair
        # where the photo's colours are matched: the head's pixels but the neck's the coverage
        # leaves without a disc (`coverage.COVER_NECK` off)
        matched = head_mask(segmentation)
        if keyviews and MULTIVIEW_HAIR_DIRECTIONS:
            from avatarkit.recon.hair_directions import orient_from_views

            hair, report.info["hair_directions"] = orient_from_views(bald, hair, keyviews, sdf, analysis.eye_distance)
        if keyviews:
            bald, hair, figures = views.colour(bald, hair, keyviews, fit, sdf)
            report.info["multiview_colours"] = figures
        if keyviews and options.refine_iterations > 0 and MULTIVIEW_REFINE:
            from avatarkit.gaussians.gaussian_set import GaussianSet
            from avatarkit.recon.multiview import refine_colours_views

            both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
            both, figures = refine_colours_views(both, sdf.query(both.means)[1], keyviews,
                                                 options.refine_iterations)
            bald = bald.replace(sh=both.sh[:len(bald)])
            hair = hair.replace(sh=both.sh[len(bald):])
            report.info["colours_views"] = figures
        if COVER_SILHOUETTE:
            from avatarkit.recon.coverage import cover_silhouette

            neck = np.zeros(matched.shape, bool)
            bald, hair, report.info["coverage"] = cover_silhouette(bald, hair, fit, image, segmentation.labels,
                                                                   neck_out=neck, views=bool(keyviews),
                                                                   plate=plate if keyviews and views.covers_plate() else None)
            matched &= ~neck
        if outline_trim.SHARPEN_OUTLINE:
            # before the colours are matched: the outline discs narrowed, not recoloured to hide on the wall
            bald, hair, report.info["outline_sharpen"] = outline_trim.sharpen_outline(bald, hair, fit,
                                                                                      segmentation.person)
        elif outline_trim.TRIM_OUTLINE:
            # before the colours are matched: the discs moved in, not recoloured to hide on the wall
            bald, hair, report.info["outline_trim"] = outline_trim.trim_outline(bald, hair, fit, segmentation.person)
        if options.refine_iterations > 0:
            # the reference photo last: the keyframes' residual misregistration must not blur
            # the face the build is made from
            from avatarkit.gaussians.gaussian_set import GaussianSet

            both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
            both, figures = refine_colours(both, fit.camera, image, matched,
                                           options.refine_iterations)
            bald = bald.replace(sh=both.sh[:len(bald)])
            hair = hair.replace(sh=both.sh[len(bald):])
            report.info["colours"] = figures
        if keyviews and KEEP_VIEW_COLOURS:
            # what only the other keyframes saw keeps their colours (`VideoViews.keep_view_colours`)
            bald, hair, report.info["multiview_colours"]["kept_after_refine"] = views.keep_view_colours(bald, hair)
        if len(keyviews) > 1 and FACING_REFINE and options.refine_iterations > 0:
            # the render matched to every keyframe, each Gaussian led by the view facing it best
            from avatarkit.recon.facing_refine import refine_facing

            t0 = time.perf_counter()
            keep = views.neck_rows(bald, hair, fit)
            bald, hair, figures = refine_facing(bald, hair, keyviews,
                                                sdf.query(np.concatenate([bald.means, hair.means]))[1], keep)
            report.info["facing_refine"] = {**figures, "seconds": round(time.perf_counter() - t0, 3)}
        if keyviews and plate is not None and not views.info.get("draft", False):
            # after every colour: the hair coloured more by the wall between the strands than by
            # the strands is cleared (`hair_fringe.WALL_SHARE`); not in a registration draft (the
            # turned frames are registered against the drafts as they were)
            from avatarkit.recon import hair_fringe

            hair, report.info["hair_fringe"] = hair_fringe.clear_wall_hair(hair, fit.camera, plate,
                                                                           np.asarray(image).shape[:2])
        if OPEN_MOUTH:
            # after the colour matching: hidden at rest, the teeth would only soak up the
            # residual of the lips in front of them
            from avatarkit.recon.mouth import inner_lips, open_mouth, photo_teeth_colour

            teeth_rgb = photo_teeth_colour(image, inner_lips(analysis.mesh))
            bald, report.info["mouth"] = open_mouth(fit.model, fit.rest_vertices, fit.shape, bald,
                                                    teeth_rgb=teeth_rgb)
    with stage("hair_rig"):
        if len(hair) == 0:  # a bald person: nothing to cage or rig
            mode = "none"
            hair_out, cage, rig = hair.replace(extras={}), None, None
            report.info["hair"] = {"mode": mode, "requested": options.hair_mode}
        else:
            mode, why = detect_hair_mode(segmentation, analysis)
            if options.hair_mode != "auto":
                mode = options.hair_mode
            rigged = rig_hair(fit, hair, mode, cage_vertices=options.cage_vertices, sdf=pending_rig_sdf)
            report.info["hair"] = {"mode": mode, "requested": options.hair_mode, **why, **rigged.info}
            hair_out = rigged.hair.replace(extras={k: v for k, v in rigged.hair.extras.items()
                                                   if k == "binding"})
            cage, rig = rigged.cage, rigged.rig
    bald_out = bald.replace(extras={"binding": bald.extras["binding"].astype(np.int32)})
    provenance = {"tool": "avatarkit", "version": _tool_version(), "created": _now(),
                  "source_image": str(path), "generator": _generator(path, options),
                  "hair_mode": mode}
    avatar = Avatar(head_model, bald_out, hair_out, cage, rig, fit.shape, head_ref,
                    options.name or path.stem, "local", provenance)
    previews = {}
    with stage("previews"):
        if options.preview:
            previews = attach_previews(avatar, options.preview_size)
    report.info["counts"] = {"bald": len(bald_out), "hair": len(hair_out),
                             "cage_vertices": int(cage.n_vertices) if cage is not None else 0}
    avatar.provenance["build"] = report.to_json()
    avatar.build_previews = previews
    return avatar


def front_view_metrics(avatar, image: np.ndarray, segmentation, camera=None) -> dict:
    """Quality of a built avatar seen from the photo's camera (the `camera` the build stored in
    its provenance unless given): PSNR (dB) and SSIM (skimage) of the render (on white) against
    the photo inside the head mask (`head_mask`); the PSNR over the whole frame of the render
    composited over the photo (`psnr_frame_db`: the head mask ends on the photo's outline, so
    it cannot see a render that stands past it over the wall, nor a soft edge's cost outside);
    the share of hair Gaussian centres inside the rest head (exact signed distance); and
    hair/skin label agreement: over the head mask, the share of pixels where the render's hair
    label (hair Gaussians dominate the pixel) equals the 2D segmentation's, and the IoU of the
    two hair masks."""
    from skimage.metrics import structural_similarity

    from avatarkit.recon.assemble import psnr
    from avatarkit.recon.label_lifting import render_label_images
    from avatarkit.recon.mesh_distance import signed_distance
    from avatarkit.recon.segment import HAIR, SKIN
    from avatarkit.render import render
    from avatarkit.render.camera import Camera

    if camera is None:
        camera = Camera.from_dict(avatar.provenance["build"]["camera"])
    gs = avatar.rest_gaussians()
    target = np.asarray(image, np.float32) / 255.0
    rgb = np.clip(render(gs, camera, background=(1.0, 1.0, 1.0)).rgb, 0, 1)
    mask = head_mask(segmentation)
    over = render(gs, camera, background=(0.0, 0.0, 0.0))
    frame = np.clip(over.rgb + (1.0 - np.asarray(over.alpha))[..., None] * target, 0, 1)   # (H, W, 3)
    _, ssim_map = structural_similarity(target, rgb, channel_axis=2, data_range=1.0, full=True)
    sd = signed_distance(avatar.hair.means, avatar.rest_head_vertices, avatar.head_model.faces)
    part = np.where(gs.extras["part"] == 1, HAIR, SKIN).astype(np.int32)
    rendered = render_label_images(gs, part, [camera], n_labels=4)[0]
    hair2d = segmentation.labels == HAIR
    hair3d = rendered == HAIR
    inter = (hair2d & hair3d & mask).sum()
    union = ((hair2d | hair3d) & mask).sum()
    return {"psnr_db": round(psnr(rgb, target, mask), 3),
            "ssim": round(float(ssim_map[mask].mean()), 4),
            "psnr_frame_db": round(psnr(frame, target, np.ones(mask.shape, bool)), 3),
            "hair_inside_share": float((sd < 0).mean()) if len(sd) else 0.0,
            "label_agreement": round(float((hair2d == hair3d)[mask].mean()), 4),
            "hair_iou": round(float(inter / max(union, 1)), 4),
            "render": rgb}


def _generator(path: Path, options: BuildOptions) -> str:
    defaults = BuildOptions()
    args = [f"{k}={v!r}" for k, v in asdict(options).items() if v != getattr(defaults, k)]
    return f"avatarkit build {path.name}" + (f" ({', '.join(args)})" if args else "")


def save_avatar(avatar, folder: str | os.PathLike) -> Path:
    """Write the avatar folder (Avatar.save) plus the extra preview renders, atomically: all of
    it is written into a temp folder beside the target, then renamed into place (an existing
    avatar folder there is replaced; anything else is refused)."""
    from avatarkit.avatar import check_avatar_target
    from avatarkit.export.images import write_png

    target = check_avatar_target(folder)
    with atomic_folder(target, tag="build") as staged:
        avatar.save(staged, preview=avatar.preview is not None)
        for name, image in (getattr(avatar, "build_previews", None) or {}).items():
            if name != "preview.png":
                write_png(staged / name, image)
    return target


__all__ = ["NO_HAIR_WARNING", "BuildOptions", "BuildReport", "PREVIEW_VIEWS", "STAGES", "attach_previews", "build_avatar", "clean_hair",
           "front_view_metrics", "head_mask", "render_previews", "save_avatar"]
