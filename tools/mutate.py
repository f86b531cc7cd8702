"""Mutation testing on our own list of edits: does the fast suite notice when the code is wrong?

Each mutation is a small deliberate bug (file, old text, new text) with the test files (or test
ids) that should catch it. For each one the script applies the edit, runs those tests of the
default (fast) suite, puts the file back byte for byte, and reports the mutation "killed" (the
tests failed) or "survived" (they still passed: a gap in the tests). The score is killed /
total, per package and overall.

    .venv/bin/python tools/mutate.py                 # every mutation (tens of minutes on 2 cores)
    .venv/bin/python tools/mutate.py cage render     # the mutations of some packages
    .venv/bin/python tools/mutate.py --id render.alpha_clamp --id cage.shallow_half
    .venv/bin/python tools/mutate.py --list          # what there is, without running anything
    .venv/bin/python tools/mutate.py --check         # every `old` text still matches exactly once

It never edits the working tree: the mutations are applied to a scratch copy of it (the files
git tracks or would track, uncommitted edits included, with `../shared` linked beside it) and the
tests run there, so a build or a test run in the working tree meanwhile never imports a mutant.
Exit status: 0 when every mutation run was killed, 1 when some survived, 2 for bad
arguments or a mutation whose `old` text no longer matches (the code moved: update the list).

Why our own list and not mutmut: mutmut generates hundreds of mutants per module and runs the
suite against each; with Taichi kernels, ~10 s of start-up per pytest process and a shared
2-core machine that does not fit in a working session. A curated list of edits, each a bug
someone could plausibly write, keeps a full run under an hour and every result readable.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutation:
    id: str                          # "<package>.<name>"
    edits: tuple                     # ((file, old, new), ...): all applied together
    tests: tuple                     # pytest arguments: files, file::test ids, or "-k", "expr"
    why: str                         # the bug, in words

    @property
    def package(self) -> str:
        return self.id.split(".")[0]


def M(id, file, old, new, tests, why, more=()):
    return Mutation(id, ((file, old, new), *more), tuple(tests), why)


MUTATIONS = [
    # --- sim ------------------------------------------------------------------------------------
    M("sim.warmup_3_steps", "avatarkit/sim/config.py", "warmup_seconds: float = 1.0",
      "warmup_seconds: float = 0.1", ["tests/test_sim_avatar.py"],
      "the default warm-up cut from 1 s to 3 steps at 30 fps"),
    M("sim.no_collision_margin", "avatarkit/sim/config.py", "collision_margin: float = 0.002",
      "collision_margin: float = 0.0", ["tests/test_sim.py", "-k", "collision or defaults"],
      "default collision margin 2 mm -> 0"),
    M("sim.no_damping", "avatarkit/sim/solver.py", "np.exp(-config.damping * h)", "1.0",
      ["tests/test_sim.py", "-k", "kernel_matches or settles"], "the kernel ignores damping"),
    M("sim.gravity_halved", "avatarkit/sim/solver.py", "*config.gravity, config.max_speed",
      "*(0.5 * g for g in config.gravity), config.max_speed",
      ["tests/test_sim.py", "-k", "kernel_matches or settles"],
      "the kernel applies half the gravity"),
    M("sim.contact_pulls", "avatarkit/sim/_kernels.py", "new = ti.max(lam + dl, 0.0)  # contact only pushes",
      "new = lam + dl", ["tests/test_sim.py", "-k", "kernel_matches or collision"],
      "a collision contact may pull a vertex into the head"),
    # --- cage -----------------------------------------------------------------------------------
    M("cage.manifold_unreported", "avatarkit/cage/mesh.py",
      '        problems.append("not manifold: some vertex joins two separate fans of faces")',
      "        pass", ["tests/test_cage.py", "-k", "check"],
      "a non-manifold vertex is no longer reported as a problem"),
    M("cage.unused_unreported", "avatarkit/cage/mesh.py",
      '        problems.append(f"{unused} vertices are not used by any face")', "        pass",
      ["tests/test_cage.py", "-k", "check"], "unused vertices are no longer reported"),
    M("cage.shallow_half", "avatarkit/cage/mesh.py", "((depth > 0) & (depth < margin))",
      "((depth > 0) & (depth < margin / 2))", ["tests/test_cage.py", "-k", "check or shallow"],
      "the shallow-point threshold halved"),
    M("cage.depth_search_radius", "avatarkit/cage/inside.py",
      "hits = tree.query_ball_point(centroid, circum + radius, workers=-1, return_sorted=False)",
      "hits = tree.query_ball_point(centroid, circum, workers=-1, return_sorted=False)",
      ["tests/test_cage.py", "-k", "clipped_depth or check"],
      "the depth search misses triangles whose circumsphere the point lies outside"),
    M("cage.mvc_unnormalised", "avatarkit/cage/mvc.py",
      "kept = kept / np.where(np.abs(total) > 1e-12, total, 1.0)", "kept = kept",
      ["tests/test_mvc.py"], "sparse top-k weights no longer renormalised to sum 1"),
    # --- render ---------------------------------------------------------------------------------
    M("render.alpha_clamp", "avatarkit/render/pipeline.py", "ALPHA_MAX = 0.99", "ALPHA_MAX = 1.0",
      ["tests/test_render.py"], "the 0.99 alpha clamp removed (fast and reference renderer)",
      more=(("avatarkit/render/_kernels.py", "ALPHA_MAX = 0.99", "ALPHA_MAX = 1.0"),)),
    M("render.alpha_min", "avatarkit/render/pipeline.py", "ALPHA_MIN = 1.0 / 255.0", "ALPHA_MIN = 0.1 / 255.0",
      ["tests/test_render.py"], "splats below 1/255 alpha drawn (both renderers)",
      more=(("avatarkit/render/_kernels.py", "ALPHA_MIN = 1.0 / 255.0", "ALPHA_MIN = 0.1 / 255.0"),)),
    M("render.no_early_stop", "avatarkit/render/pipeline.py", "TRANSMITTANCE_MIN = 1e-4",
      "TRANSMITTANCE_MIN = 0.0", ["tests/test_render.py"],
      "no early termination at T < 1e-4 (both renderers)",
      more=(("avatarkit/render/_kernels.py", "T_MIN = 1e-4", "T_MIN = 0.0"),)),
    M("render.no_dilation", "avatarkit/render/_kernels.py", "DILATION = 0.3", "DILATION = 0.0",
      ["tests/test_render.py"], "the fast renderer forgets the 0.3 px low-pass dilation"),
    M("render.reference_near_frozen", "avatarkit/render/reference.py",
      "def project_reference(gaussians: GaussianSet, camera: Camera, near: float | None = None) -> Projection:",
      "def project_reference(gaussians: GaussianSet, camera: Camera, near: float = _pipeline.NEAR_PLANE) -> Projection:",
      ["tests/test_call_time_defaults.py"],
      "the reference renderer's near plane frozen at import (setting pipeline.NEAR_PLANE leaves it behind)"),
    # --- export ---------------------------------------------------------------------------------
    M("export.manifest_unlinked", "avatarkit/export/usd_stage.py",
      '                clips.SetClipManifestAssetPath(Sdf.AssetPath(f"./{self._clips_name}/{manifest_name}"))',
      "                pass", ["tests/test_usd_stage.py", "-k", "manifest"],
      "the stage no longer links its value-clip manifest"),
    M("export.fps_unset", "avatarkit/export/usd_stage.py",
      "        stage.SetTimeCodesPerSecond(float(self._static.fps))", "        pass",
      ["tests/test_usd_stage.py", "-k", "layout or manifest"], "clip layers without timeCodesPerSecond"),
    M("export.tmp_mkdtemp_unguarded", "avatarkit/fileio.py",
      "    except OSError as e:\n        raise OutputError(f\"output folder is not writable",
      "    except ValueError as e:\n        raise OutputError(f\"output folder is not writable",
      ["tests/test_usd_stage.py", "-k", "unwritable"],
      "an unwritable folder escapes as a raw PermissionError"),
    M("export.sequence_fps", "avatarkit/export/ply_sequence.py", '"fps": float(s.fps), "frame_count"',
      '"fps": 30.0, "frame_count"', ["tests/test_ply_sequence.py"],
      "sequence.json always says 30 fps"),
    # --- gaussians ------------------------------------------------------------------------------
    M("gaussians.spz_ratio_check", "avatarkit/gaussians/spz.py",
      "        if need > len(data) * _MAX_RATIO:", "        if False:",
      ["tests/test_spz.py"], "SPZ v2/v3: a point count no file of this size could hold is not refused"),
    M("gaussians.spz_count_low", "avatarkit/gaussians/spz.py",
      "        if trailing and not flags & FLAG_EXTENSIONS:", "        if False:",
      ["tests/test_spz.py"], "SPZ v2/v3: a point count below the data's is read shifted"),
    M("gaussians.spz_stream_size", "avatarkit/gaussians/spz.py", "        if usize != want:",
      "        if usize < want:", ["tests/test_spz.py"],
      "SPZ v4: a stream larger than the header's count needs is accepted"),
    M("gaussians.ply_kernel_never", "avatarkit/gaussians/ply.py",
      "    offsets = _kernel_offsets(table, rest_names) if colour is DC and decoder != \"numpy\" else None",
      "    offsets = None", ["tests/test_ply.py", "-k", "round_trip"], "read_ply never takes the kernel"),
    M("gaussians.ply_rest_order", "avatarkit/gaussians/ply.py",
      "rest_cm = [rest_names[c * (k - 1) + j] for j in range(k - 1) for c in range(3)]",
      "rest_cm = [rest_names[j * 3 + c] for j in range(k - 1) for c in range(3)]",
      ["tests/test_ply.py", "-k", "numpy and round_trip"], "f_rest read coefficient-major (the numpy decoder)"),
    M("gaussians.sh_c1_sign", "avatarkit/gaussians/sh.py", "cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]",
      "cols += [SH_C1 * y, SH_C1 * z, -SH_C1 * x]", ["tests/test_rotations_sh.py"],
      "band-1 SH basis with the wrong sign on y"),
    # --- batch ----------------------------------------------------------------------------------
    M("batch.retries_off_by_one", "avatarkit/batch/runner.py",
      "if r.status == \"failed\" and r.transient and item.attempts <= retries:",
      "if r.status == \"failed\" and r.transient and item.attempts < retries:",
      ["tests/test_batch.py", "-k", "retr or transient"], "--retries 1 never retries"),
    M("batch.retries_one_more", "avatarkit/batch/runner.py",
      "if r.status == \"failed\" and r.transient and item.attempts <= retries:",
      "if r.status == \"failed\" and r.transient and item.attempts <= retries + 1:",
      ["tests/test_batch.py", "-k", "retr or transient"], "one retry more than asked"),
    M("batch.all_transient", "avatarkit/batch/worker.py",
      "result.transient = isinstance(error, OSError)", "result.transient = True",
      ["tests/test_batch.py", "-k", "retr or transient"], "every failure is retried, bugs included"),
    # --- bake and its CLI -----------------------------------------------------------------------
    M("bake.preroll_ignored", "avatarkit/bake.py", "warmup=cfg.preroll, dt=dt", "warmup=None, dt=dt",
      ["tests/test_cli_bake.py", "-k", "flags"], "bake ignores its preroll"),
    M("cli.preroll_ignored", "cli/bake_cmd.py", "sim=SimConfig(**sim), preroll=preroll)",
      "sim=SimConfig(**sim), preroll=None)", ["tests/test_cli_bake.py", "-k", "flags"],
      "`bake --preroll` ignored"),
    M("cli.collision_ignored", "cli/bake_cmd.py", '        sim["collision"] = collision', "        pass",
      ["tests/test_cli_bake.py", "-k", "flags"], "`bake --collision` ignored"),
    M("cli.half_ignored", "cli/bake_cmd.py", '{"half": half, "usd_points"', '{"half": False, "usd_points"',
      ["tests/test_cli_bake.py", "-k", "flags"], "`bake --half` ignored"),
    M("cli.usd_points_ignored", "cli/bake_cmd.py", '"usd_points": usd_points, "chunk_frames"',
      '"usd_points": False, "chunk_frames"', ["tests/test_cli_bake.py", "-k", "flags"],
      "`bake --usd-points` ignored"),
    # --- recon (thresholds set from what the code reaches) --------------------------------------
    M("recon.refine_one_round", "avatarkit/recon/assemble.py", "    for it in range(iterations + 1):",
      "    iterations = min(iterations, 1)\n    for it in range(iterations + 1):",
      ["tests/test_recon_pipeline.py", "-k", "refine_colours"], "colour refinement stops after one round"),
    M("recon.build_one_round", "avatarkit/recon/pipeline.py", "    refine_iterations: int = 6",
      "    refine_iterations: int = 1", ["tests/test_recon_pipeline.py", "-k", "fast_end_to_end_build"],
      "the build's colour matching does one round instead of six"),
    M("recon.lift_half_pixel", "avatarkit/recon/image_sampling.py",
      "    p = np.asarray(px, np.float32).reshape(-1, 2) - 0.5",
      "    p = np.asarray(px, np.float32).reshape(-1, 2)", ["tests/test_recon_lift.py", "-k", "bald_lifting"],
      "photo colours sampled half a pixel off"),
    M("recon.outline_trim_never_called", "avatarkit/recon/pipeline.py", "        elif outline_trim.TRIM_OUTLINE:",
      "        elif False:", ["tests/test_recon_pipeline.py", "-k", "trims_its_outline"],
      "the pipeline never trims the outline, even with outline_trim.TRIM_OUTLINE on"),
    M("recon.outline_trim_hair_kept", "avatarkit/recon/outline_trim.py", "HAIR = True",
      "HAIR = False", ["tests/test_outline_trim.py", "-k", "hair"],
      "the hair over the wall is kept: the crown and temples still overshoot"),
    M("recon.outline_trim_outward", "avatarkit/recon/outline_trim.py",
      "        offsets[move] += step * normals[move]", "        offsets[move] -= step * normals[move]",
      ["tests/test_outline_trim.py", "-k", "outline_comes_onto"],
      "the outline discs move outward (the normal's sign flipped)"),
    M("recon.outline_sharpen_never_called", "avatarkit/recon/pipeline.py",
      "        if outline_trim.SHARPEN_OUTLINE:", "        if False:",
      ["tests/test_recon_pipeline.py", "-k", "sharpens_its_outline"],
      "the pipeline never sharpens the outline, even with outline_trim.SHARPEN_OUTLINE on"),
    M("recon.outline_sharpen_centre_kept", "avatarkit/recon/outline_trim.py",
      "    means[ok] += shift[ok] @ w", "    means[ok] += 0.0 * shift[ok] @ w",
      ["tests/test_outline_trim.py", "-k", "sharpen or narrow"],
      "the narrowed discs keep their centres: the inner edge comes out, the outer stays past the outline"),
    M("recon.outline_sharpen_no_dilation", "avatarkit/recon/outline_trim.py",
      "    sig = np.sqrt(var + DILATION)", "    sig = np.sqrt(var)",
      ["tests/test_outline_trim.py", "-k", "sharpen or narrow"],
      "the renderer's 0.3 px^2 dilation is left out of a disc's projected width"),
    M("recon.outline_sharpen_hair_rounds_ignored", "avatarkit/recon/outline_trim.py",
      "    if hair_rounds <= 0 or len(hair) == 0:", "    if True:",
      ["tests/test_outline_trim.py", "-k", "sharpening_drops_the_hair"],
      "the sharpening's hair rounds are never run: the crown and temples still overshoot"),
    M("recon.outline_sharpen_hair_into_head", "avatarkit/recon/outline_trim.py",
      "        ok = signed_distance(trial, fit.rest_vertices, fit.model.faces) >= HAIR_MARGIN",
      "        ok = signed_distance(trial, fit.rest_vertices, fit.model.faces) >= -1.0",
      ["tests/test_outline_trim.py", "-k", "narrowed_hair"],
      "the narrowed hair moves its full way in, past assemble.HAIR_MARGIN (into the head)"),
    M("recon.outline_sharpen_hair_not_narrowed", "avatarkit/recon/outline_trim.py",
      "    if NARROW_HAIR and len(hair):", "    if False:",
      ["tests/test_outline_trim.py", "-k", "narrowed_hair"],
      "NARROW_HAIR does nothing: the hair's outline is left as it was"),
    M("recon.front_frame_over_white", "avatarkit/recon/pipeline.py",
      "    frame = np.clip(over.rgb + (1.0 - np.asarray(over.alpha))[..., None] * target, 0, 1)",
      "    frame = np.clip(over.rgb + (1.0 - np.asarray(over.alpha))[..., None], 0, 1)",
      ["tests/test_recon_pipeline.py", "-k", "fast_end_to_end"],
      "the whole-frame PSNR composites the render over white, not over the photo"),
    M("recon.segment_dark_wall_kept_flat", "avatarkit/recon/segment.py", "RENOISE_DARK_WALL = True",
      "RENOISE_DARK_WALL = False", ["tests/test_recon_segment.py", "-k", "dark_plain_background"],
      "a flat dark wall's pixels are not re-noised for GrabCut: 8-9 px of wall stay in the person"),
    M("recon.segment_wall_taken_never", "avatarkit/recon/segment.py", "WALL_TAKEN = 0.98",
      "WALL_TAKEN = None", ["tests/test_recon_segment.py", "-k", "head_filling_the_frame"],
      "a head filling the frame on a flat dark wall: GrabCut's person is the whole frame"),
    M("recon.segment_plate_holes_filled", "avatarkit/recon/segment.py",
      "    person = ndimage.binary_fill_holes(person) & ~walled",
      "    person = ndimage.binary_fill_holes(person)", ["tests/test_background_plate.py", "-k", "clutter_touching"],
      "the wall a video's plate shows inside the person's outline is filled back into the person"),
    M("recon.segment_plate_not_opened", "avatarkit/recon/segment.py", "PLATE_OPEN = 0.05",
      "PLATE_OPEN = 0.0", ["tests/test_background_plate.py", "-k", "gaps_between_strands"],
      "every pixel that matches a video's plate is sure background, the gaps between strands too"),
    M("recon.segment_plate_unguarded", "avatarkit/recon/segment.py", "PLATE_TAKEN = 0.02",
      "PLATE_TAKEN = 0.0", ["tests/test_background_plate.py", "-k", "gaps_between_strands"],
      "a video's plate is sure background even where the portrait's segmentation kept the wall out"),
    M("recon.multiview_relabel_plate_ignored", "avatarkit/recon/multiview.py",
      "            lost &= ~wall\n        if connected is not None:",
      "            pass\n        if connected is not None:", ["tests/test_background_plate.py", "-k", "relabel"],
      "a turned keyframe's relabelling takes the clutter the video's plate shows for the person"),
    M("track.plate_mean_not_median", "avatarkit/track/background_plate.py",
      "        med = np.nanmedian(x, axis=0)                        # (h, w, 3)",
      "        med = np.nanmean(x, axis=0)                          # (h, w, 3)", ["tests/test_background_plate.py"],
      "the plate is the mean of the frames outside the zone: a head's colours crossing it blend in"),
    M("track.plate_pass_untested", "avatarkit/track/background_plate.py",
      "    take = t_plate.known & ~plate.known & (passed >= PASS_FRAMES) & (passed >= PASS_SHARE * over)",
      "    take = t_plate.known & ~plate.known", ["tests/test_background_plate.py", "-k", "tighter_zone"],
      "the tighter zone's plate is taken where the head never passed: a still head's hair is wall"),
    M("track.plate_pass_share_dropped", "avatarkit/track/background_plate.py",
      "    take = t_plate.known & ~plate.known & (passed >= PASS_FRAMES) & (passed >= PASS_SHARE * over)",
      "    take = t_plate.known & ~plate.known & (passed >= PASS_FRAMES)", ["tests/test_background_plate.py", "-k", "tighter_zone"],
      "the tighter zone's plate is taken where a few of many frames with the head over it differ"),
    M("track.plate_continue_never", "avatarkit/track/background_plate.py",
      "        take = _continued(known, plate.colour, n_plate.known & ~known, n_colour)",
      "        take = np.zeros_like(known)", ["tests/test_background_plate.py", "-k", "continued_wall_takes"],
      "the wall above a still head's top stays unknown: the continued wall is never taken"),
    M("track.plate_continue_palette_everywhere", "avatarkit/track/background_plate.py",
      "    deep = cv2.distanceTransform(known.astype(np.uint8), cv2.DIST_L2, 3) > d",
      "    deep = known", ["tests/test_background_plate.py", "-k", "continued_wall_takes"],
      "the continued wall's palette holds the known pixels by the unknown: a known flyaway seeds the hair"),
    M("recon.multiview_relabel_plate_near_ignored", "avatarkit/recon/multiview.py",
      "        wall = wall | cont\n",
      "        wall = wall\n", ["tests/test_background_plate.py", "-k", "continuing_past"],
      "a turned keyframe's relabelling takes the wall continuing past the known plate for the person"),
    M("recon.multiview_body_wall_ignored", "avatarkit/recon/multiview.py",
      "        seen &= ~on[ix[:, 1], ix[:, 0]]\n",
      "        seen &= seen\n", ["tests/test_multiview.py", "-k", "known_walls"],
      "a turned keyframe's body pixels in the known wall's colours are sampled (the poster on the head)"),
    M("recon.multiview_body_wall_in_the_reference", "avatarkit/recon/multiview.py",
      "view.labels is not None and not view.reference:\n",
      "view.labels is not None:\n", ["tests/test_multiview.py", "-k", "known_walls"],
      "the reference view's body pixels in the wall's colours give no sample either"),
    M("recon.multiview_body_wall_fringe_ignored", "avatarkit/recon/multiview.py",
      "            on = body_px & (cv2.dilate(on.astype(np.uint8), disc) > 0)\n",
      "            on = on & body_px\n", ["tests/test_multiview.py", "-k", "beside_the_wall"],
      "the body pixels beside the wall a turned keyframe shows are sampled (the red at the back of the crown)"),
    M("recon.multiview_body_wall_fringe_any_label", "avatarkit/recon/multiview.py",
      "            on = body_px & (cv2.dilate(on.astype(np.uint8), disc) > 0)\n",
      "            on = cv2.dilate(on.astype(np.uint8), disc) > 0\n", ["tests/test_multiview.py", "-k", "beside_the_wall"],
      "the skin and hair pixels beside the wall a turned keyframe shows give no sample either"),
    M("recon.multiview_body_wall_fringe_not_scaled", "avatarkit/recon/multiview.py",
      "            r = max(1, int(round(float(fringe) * max(on.shape))))\n",
      "            r = 1\n", ["tests/test_multiview.py", "-k", "beside_the_wall"],
      "the fringe is one pixel wide whatever its share of the frame"),
    M("recon.multiview_body_wall_fringe_in_drafts", "avatarkit/recon/multiview.py",
      "(BODY_WALL_FRINGE_IN_DRAFTS or not self.info.get(\"draft\", False))",
      "True", ["tests/test_multiview.py", "-k", "beside_the_wall"],
      "the registration drafts leave out the body pixels beside the wall too"),
    M("recon.multiview_body_wall_fringe_flag_ignored", "avatarkit/recon/multiview.py",
      "        if fringe is not None and on.any() and view.info.get(\"wall_fringe\", True):\n",
      "        if fringe is not None and on.any():\n", ["tests/test_multiview.py", "-k", "beside_the_wall"],
      "a view the video build marks (a draft's) leaves out the body pixels beside the wall all the same"),
    M("recon.multiview_hidden_bald_never_filled", "avatarkit/recon/multiview.py",
      "        colours, bald_filled = fill_hidden_hair(both.means, colours, rows & seen, target)\n",
      "        bald_filled = 0\n", ["tests/test_multiview.py", "-k", "bald_layer_no_view_saw"],
      "the bald layer no keyframe saw keeps the portrait's fill (HIDDEN_BALD_FILL does nothing)"),
    M("recon.multiview_hidden_bald_shown_filled", "avatarkit/recon/multiview.py",
      "            target &= footprint_visibility(both, views[0].camera) < float(HIDDEN_BALD_SHOWN)\n",
      "            target &= target\n", ["tests/test_multiview.py", "-k", "bald_layer_no_view_saw"],
      "the bald rows the reference photo shows at its outline are filled too"),
    M("recon.multiview_hidden_bald_refills_the_scalp", "avatarkit/recon/multiview.py",
      "        done = (np.asarray(scalp, bool) & ~seen & away) if scalp is not None else np.zeros(len(both), bool)\n",
      "        done = np.zeros(len(both), bool)\n", ["tests/test_multiview.py", "-k", "bald_layer_no_view_saw"],
      "the hidden bald fill fills again the scalp rows the scalp fill took"),
    M("recon.multiview_hidden_bald_in_drafts", "avatarkit/recon/multiview.py",
      "        return bool(HIDDEN_BALD_FILL and not self.info.get(\"draft\", False))\n",
      "        return bool(HIDDEN_BALD_FILL)\n", ["tests/test_multiview.py", "-k", "hidden_bald"],
      "the registration drafts fill the hidden bald layer too"),
    M("track.keyframe_pose_raw_ignored", "avatarkit/track/keyframes.py",
      "    if KEYFRAME_POSE == \"raw\" and getattr(result, \"raw\", None) is not None and \"rotation\" in result.raw:\n",
      "    if False:\n", ["tests/test_keyframes.py", "-k", "raw_keyframe_pose"],
      "the keyframe choice measures the smoothed pose whatever KEYFRAME_POSE says"),
    M("track.keyframe_pose_raw_nan_kept", "avatarkit/track/keyframes.py",
      "        ok = np.isfinite(raw).all(axis=1) & np.asarray(result.found, bool)\n",
      "        ok = np.ones(len(raw), bool)\n", ["tests/test_keyframes.py", "-k", "raw_keyframe_pose"],
      "a frame without its own fit lends the choice a NaN pose"),
    M("recon.segment_wall_bins_exact", "avatarkit/recon/segment.py",
      "    table = ndimage.binary_dilation(table.reshape(n, n, n), np.ones((3, 3, 3), bool)).ravel()",
      "    table = table.ravel()", ["tests/test_recon_segment.py", "-k", "wall_colours"],
      "only the wall's exact colour bins count as the wall's (no neighbouring bin)"),
    M("recon.segment_wall_any_stray", "avatarkit/recon/segment.py", "WALL_MIN_SHARE = 0.002",
      "WALL_MIN_SHARE = 0.0", ["tests/test_recon_segment.py", "-k", "wall_colours"],
      "a single stray flat pixel in the wall zone makes its colour the wall's"),
    # --- face, track (session 10) ---------------------------------------------------------------
    M("face.lower_lip_not_carried", "avatarkit/face/correspondence.py",
      "    rows = [k for k in rows if bary_w[k] < min_weight]", "    rows = []",
      ["tests/test_face_lower_lip.py"], "the lower inner lip left on the upper lip, where the jaw does not reach"),
    M("face.overlay_plain_embedding", "avatarkit/face/overlay.py",
      "embedding_for(model, mirror=True, carry_jaw=False)", "embedding_for(model, carry_jaw=False)",
      ["tests/test_face_front_end.py", "-k", "mirror_averaged"],
      "`avatarkit face` fits the mirror-averaged mesh on the plain mesh's embedding"),
    M("face.portrait_fit_carries_jaw", "avatarkit/recon/fit.py",
      "embedding_for(model, carry_jaw=False)", "embedding_for(model)",
      ["tests/test_face_lower_lip.py", "-k", "portrait"],
      "the build's portrait fit (no jaw) takes the lower lip's re-hosting meant for the tracker"),
    M("track.edge_walks_on", "avatarkit/track/keyframes.py",
      "                if abs(yaw[i]) < peak - EDGE_MARGIN:", "                if False:",
      ["tests/test_keyframes.py", "-k", "edge"], "the tracking's edge takes every eligible frame on the turned side"),
    # --- face, track (session 11) ---------------------------------------------------------------
    M("face.overlay_not_augmented", "avatarkit/face/overlay.py", "AUGMENT = True", "AUGMENT = False",
      ["tests/test_face_augment.py"], "`avatarkit face` fits the face mesh read in one region, not the nine"),
    M("track.neck_no_translation_fix", "avatarkit/track/neck.py",
      "    tau = np.asarray(translation, np.float64).reshape(T, 3) + np.einsum(\"tij,tj->ti\", R_old - R0, rel)",
      "    tau = np.asarray(translation, np.float64).reshape(T, 3)",
      ["tests/test_track_neck.py"], "the head moved onto the neck without moving the translation: the head lands off the fit"),
    M("track.neck_composed_backwards", "avatarkit/track/neck.py",
      "    return matrix_to_axis_angle(_matrices(rot) @ _matrices(neck))",
      "    return matrix_to_axis_angle(_matrices(neck) @ _matrices(rot))",
      ["tests/test_track_neck.py"], "the head's rotation read as neck then global"),
    M("track.calibration_centred_crop", "avatarkit/face/view_correction.py",
      "    c = np.asarray(data[\"principal\"], np.float64) if \"principal\" in data else np.array([size / 2, size / 2])",
      "    c = np.array([size / 2, size / 2])",
      ["tests/test_track_subject_calibration.py"], "the subject calibration's crops read as if centred on the head"),
    M("track.rigid_turn_backwards", "avatarkit/face/view_correction.py",
      "    L[:, 0, 1], L[:, 0, 2] = q[:, 2], -q[:, 1]",
      "    L[:, 0, 1], L[:, 0, 2] = -q[:, 2], q[:, 1]",
      ["tests/test_track_subject_calibration.py"], "the rigid part's turn about y and z read backwards in x"),
    M("track.nonrigid_added", "avatarkit/track/subject_calibration.py",
      "    return ViewCorrection(full.mesh_index, full.coef - rigid.coef, full.static - rigid.static), \\",
      "    return ViewCorrection(full.mesh_index, full.coef + rigid.coef, full.static - rigid.static), \\",
      ["tests/test_track_subject_calibration.py"], "the non-rigid part made by adding the rigid part instead of removing it"),
    M("track.jaw_guard_inverted", "avatarkit/track/jaw_corrective.py",
      "            if stat[k] <= threshold:", "            if stat[k] > threshold:",
      ["tests/test_jaw_corrective.py"], "the jaw corrective's guard zeroes the slopes the frames support and keeps the others"),
    M("track.jaw_pose_ignored_by_fit", "avatarkit/face/fit.py",
      "        if r is not None and self.jaw_pose is not None:", "        if False:",
      ["tests/test_jaw_corrective.py"], "the landmark fit does not pose a model's jaw correctives"),
    M("track.jaw_corrective_not_loaded", "avatarkit/avatar.py",
      '    if "jaw_corrective" in ref_json:', '    if False:',
      ["tests/test_jaw_corrective.py"], "an avatar folder's jaw corrective is not added to its head on load"),
    M("recon.hair_end_top_percentile", "avatarkit/recon/hair_end.py",
      "    return float(np.percentile(heights, PERCENTILE))", "    return float(np.percentile(heights, 100 - PERCENTILE))",
      ["tests/test_hair_end.py"], "the hair's end read from the top of the hair the turned views show"),
    M("recon.hair_end_every_speck", "avatarkit/recon/hair_end.py",
      "        hair = connected_hair(np.asarray(view.labels) == HAIR)", "        hair = np.asarray(view.labels) == HAIR",
      ["tests/test_hair_end.py"], "the hair's end read from hair specks apart from the body of the hair"),
    M("recon.hair_end_face_counts", "avatarkit/recon/hair_end.py",
      "        keep &= v[:, 2] < v[face, 2].min()", "        pass",
      ["tests/test_hair_end.py"], "the face's vertices under hair count for the end of the hair at the back"),
    M("recon.hair_outline_counts_edge", "avatarkit/recon/hair_outline.py",
      "    labelled = [v for v in views if v.labels is not None and v.frame not in skip]",
      "    labelled = [v for v in views if v.labels is not None]",
      ["tests/test_hair_outline.py"], "the hair's outline fitted to the tracking's edge frames too"),
    M("recon.hair_outline_no_margin", "avatarkit/recon/hair_outline.py",
      "    gap = np.maximum(gap - GAP_MARGIN, 0.0)", "    gap = np.maximum(gap, 0.0)",
      ["tests/test_hair_outline.py"], "the hair's outline gap read without the pixel of margin"),
    M("recon.hair_outline_direction_veto_as_band", "avatarkit/recon/hair_outline.py",
      "            on = on & ~held", "            pass",
      ["tests/test_hair_outline.py"], "VETO \"direction\": a view with no gap still holds every push near its outline"),
    M("recon.hair_outline_hold_ignores_direction", "avatarkit/recon/hair_outline.py",
      "    a = np.einsum(\"ij,ij->i\", p1 - p0, outward)", "    a = np.linalg.norm(p1 - p0, axis=1)",
      ["tests/test_hair_outline.py"], "the holding view cuts a push along its ray or inward too"),
    M("recon.hair_outline_contour_holds_nothing_whole", "avatarkit/recon/hair_outline.py",
      "            push[held & (asker >= 0) & same] = 0.0", "            pass",
      ["tests/test_hair_outline.py"], "VETO \"contour\": a view of the same contour holds only its side, as \"direction\""),
    M("recon.hair_outline_contour_one_way_round", "avatarkit/recon/hair_outline.py",
      "np.abs(sight[np.maximum(asker, 0)] @ sight[vi])", "(sight[np.maximum(asker, 0)] @ sight[vi])",
      ["tests/test_hair_outline.py"], "VETO \"contour\": a view from behind counted as another contour"),
    M("recon.hair_outline_hold_to_the_exact_pixel", "avatarkit/recon/hair_outline.py",
      "HOLD_TOLERANCE = 1.0", "HOLD_TOLERANCE = 0.0",
      ["tests/test_hair_outline.py"], "a holding view's outline read as exact: no pixel of tolerance"),
    M("recon.hair_outline_contour_in_the_drafts", "avatarkit/recon/hair_outline.py",
      "    veto = DRAFT_VETO if draft else VETO", "    veto = VETO",
      ["tests/test_hair_outline.py"], "the registration drafts fit the outline with the final build's veto"),
    M("usd.probe_ignores_crashes", "avatarkit/gaussians/usd_probe.py",
      "    if done.returncode < 0:", "    if done.returncode < -99:",
      ["tests/test_usd_probe.py"], "a USD reader crash in the probe's child process let through"),
    M("usd.stale_layer_kept", "avatarkit/gaussians/usd_read.py",
      "            held.Reload(force=True)", "            pass",
      ["tests/test_usd_probe.py"], "a stage reopened over a layer USD still holds as first read"),
    M("track.refine_jaw_dropped", "avatarkit/track/tracker.py",
      'REFINE_SETTINGS = {"photometric": dict(jaw=True, render_depth=True, iterations=3), "photometric-pose": {},',
      'REFINE_SETTINGS = {"photometric": dict(render_depth=True, iterations=3), "photometric-pose": {},',
      ["tests/test_cli_track.py"], "--refine photometric leaving the jaw's opening the landmark fit's"),
    M("recon.reassign_stray_reference", "avatarkit/recon/hair_reassign.py",
      "    if hair_ref.sum() < _reference_minimum(hair_member, cfg):", "    if not hair_ref.any():",
      ["tests/test_recon_labels3d.py"], "three stray confident splats standing for the whole hair class"),
    M("recon.bald_layer_uncapped", "avatarkit/recon/hair_reassign.py",
      "        layer = min(layer, max(cfg.min_layer, 0.5 * float(np.median(surface_distance[hair_ref]))))",
      "        pass",
      ["tests/test_recon_labels3d.py"], "hair labelled skin widening the bald layer over a thin hair shell"),
    M("recon.reassign_clear_votes_with_the_band", "avatarkit/recon/hair_reassign.py",
      "        lab = np.where(band, n_labels, np.asarray(img, np.int32)).astype(np.int32)",
      "        lab = np.asarray(img, np.int32)",
      ["tests/test_recon_labels3d.py"], "the clear votes counting the edge band's pixels too"),
    M("recon.reassign_clear_votes_ignored", "avatarkit/recon/hair_reassign.py",
      "        to_hair &= ~((total >= CLEAR_MIN) & (other > CLEAR_SHARE * total))",
      "        pass",
      ["tests/test_recon_labels3d.py"], "the views' clear skin votes never taking the temple's shell out of the hair"),
    M("recon.reassign_clear_votes_single_view", "avatarkit/recon/hair_reassign.py",
      "    if clear and CLEAR_SHARE is not None and len(cameras) >= 2 and (cand & to_hair).any():",
      "    if clear and CLEAR_SHARE is not None and (cand & to_hair).any():",
      ["tests/test_recon_labels3d.py"], "the clear votes reaching a single-frame build's one view"),
    M("recon.reassign_clear_votes_veto_ignored", "avatarkit/recon/hair_reassign.py",
      "            to_hair_kept = (each[:, :, cfg.hair_label] >= CLEAR_VETO).any(axis=0)",
      "            to_hair_kept = np.zeros(n, bool)",
      ["tests/test_recon_labels3d.py"], "a view seeing hair clear of every edge not keeping it"),
    M("recon.reassign_clear_votes_in_the_drafts", "avatarkit/recon/multiview.py",
      '        return bool(hair_reassign.CLEAR_IN_DRAFTS or not self.info.get("draft", False))',
      "        return True",
      ["tests/test_multiview.py"], "the registration drafts losing the hair the clear votes take out"),
    M("track.refined_eyes_kept", "avatarkit/track/tracker.py",
      '            raw["eyes"][row] = ft.eyes(seen[row], raw["rotation"][row], raw["translation"][row])',
      '            pass',
      ["tests/test_track_refined_gaze.py"], "the refined frames keeping the eyes read at the landmark fit's pose"),
    M("track.refine_keyframes_no_bound", "avatarkit/track/video_build.py",
      "        bounded = at_bound(found, min(near, far), max(near, far), side) is not None", "        bounded = False",
      ["tests/test_keyframe_refine.py"], "a keyframe registered at its search's end trusted by the hair's outline"),
    M("track.register_hair_never_discounted", "avatarkit/track/register.py",
      "    hair = hair_marker(gaussians) if discount_hair else None", "    hair = None",
      ["tests/test_register.py", "-k", "hair"], "register_frame(discount_hair=True) counting the draft's hair as every pixel"),
    M("track.register_hair_weight_inverted", "avatarkit/track/register.py",
      "    w = 1.0 - hair_share(hair, camera)[:rows]", "    w = hair_share(hair, camera)[:rows]",
      ["tests/test_register.py", "-k", "hair"], "the hair-discounted error weighing the hair's pixels, not the rest"),
    M("track.register_hair_pose_not_searched_again", "avatarkit/track/register.py",
      "    if hair is not None:\n        # the yaw is the hair-discounted", "    if False:\n        # the yaw is the hair-discounted",
      ["tests/test_register.py", "-k", "hair"], "the hair-discounted registration keeping its own pitch and position (and error)"),
    M("track.register_hair_gate_ignored", "avatarkit/track/register.py",
      "            if gate is not None and abs(yaw - r0) <= abs(plain[0] - r0) + gate:",
      "            if False:",
      ["tests/test_register.py", "-k", "gate"], "the hair-discounted yaw replacing the plain pose however near it"),
    M("track.hair_discount_stages_swapped", "avatarkit/track/video_build.py",
      '                             discount_hair="refine" in HAIR_DISCOUNT or split', '                             discount_hair="turned" in HAIR_DISCOUNT or split',
      ["tests/test_keyframe_refine.py", "-k", "hair_discount"], "refine_keyframes reading the turned frames' hair-discount stage"),
    M("track.register_split_without_plain", "avatarkit/track/register.py",
      "        if gate is not None or keep_plain:", "        if gate is not None:",
      ["tests/test_register.py", "-k", "split"], "register_frame(keep_plain=True) running no plain search without a gate"),
    M("track.skin_pose_plain_pose_dropped", "avatarkit/track/video_build.py",
      "    return reg.plain_pose, (reg.pose if reg.discounted else None)", "    return reg.pose, (reg.pose if reg.discounted else None)",
      ["tests/test_keyframe_refine.py", "-k", "skin_pose"], "SKIN_POSE's keyframes taking the gated pose for the hair too"),
    M("track.skin_pose_kept_from_an_earlier_round", "avatarkit/track/video_build.py",
      "        if split:\n            # this round's registration decides", "        if split and skin is not None:\n            # this round's registration decides",
      ["tests/test_keyframe_refine.py", "-k", "skin_pose"], "a refine round whose gate keeps the plain pose leaving the skin pose of an earlier round"),
    M("track.register_plate_ignored", "avatarkit/track/register.py",
      "    bg = plate_background(plate, np.asarray(image).shape[:2], target.shape[:2], background_colour(target))",
      "    bg = plate_background(None, np.asarray(image).shape[:2], target.shape[:2], background_colour(target))",
      ["tests/test_register.py", "-k", "plate"], "register_frame compositing over the border colour whatever plate it is given"),
    M("track.register_plate_everywhere", "avatarkit/track/register.py",
      "    differs = known & (np.abs(colour - flat).max(axis=-1) > background_plate.AGREE / 255.0)",
      "    differs = np.ones_like(known)",
      ["tests/test_register.py", "-k", "plate"], "the plate's colour taken where it is not known, and a plain wall's plate moving the registration"),
    M("track.register_plate_scaled_bilinear", "avatarkit/track/register.py",
      "        colour = cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA)",
      "        colour = cv2.resize(colour, (w, h), interpolation=cv2.INTER_NEAREST)",
      ["tests/test_register.py", "-k", "plate"], "the plate scaled otherwise than the frame (a textured wall no longer matches it)"),
    M("track.register_plate_stages_swapped", "avatarkit/track/video_build.py",
      '                             plate=views.plate if "refine" in REGISTER_PLATE else None)',
      '                             plate=views.plate if "turned" in REGISTER_PLATE else None)',
      ["tests/test_keyframe_refine.py", "-k", "plate_switch"], "refine_keyframes reading the turned frames' plate stage"),
    M("track.turned_at_bound_kept", "avatarkit/track/video_build.py",
      'if (end is not None and TURNED_AT_BOUND in ("drop", "beyond"))',
      'if (end is not None and TURNED_AT_BOUND in ("drop",))',
      ["tests/test_keyframe_refine.py", "-k", "no_minimum"], "a turn end still at a bound after the search beyond kept as a keyframe"),
    M("track.turned_at_bound_near_far_swapped", "avatarkit/track/video_build.py",
      "    near, far = (lo, hi) if side > 0 else (hi, lo)",
      "    near, far = (hi, lo) if side > 0 else (lo, hi)",
      ["tests/test_keyframe_refine.py", "-k", "no_minimum"], "the turn's near and far ends swapped: a far end dropped instead of searched beyond"),
    M("track.turned_at_bound_far_drops_near_too", "avatarkit/track/video_build.py",
      '(end == "far" and TURNED_AT_BOUND == "far")', '(end is not None and TURNED_AT_BOUND == "far")',
      ["tests/test_keyframe_refine.py", "-k", "no_minimum"], "\"far\" dropping a turn end at its near end too (the whip's -46 end)"),
    M("track.turned_beyond_not_searched", "avatarkit/track/video_build.py",
      '        if end == "far" and TURNED_AT_BOUND == "beyond" and REGISTER_MODE == "plain":',
      '        if False:',
      ["tests/test_keyframe_refine.py", "-k", "no_minimum"], "\"beyond\" never searching past the far end"),
    M("recon.skin_views_never", "avatarkit/recon/multiview.py",
      "        if not which or not self.uses_skin_poses():", "        if True:",
      ["tests/test_keyframe_refine.py", "-k", "skin"], "VideoViews.skin_views handing back the plain views"),
    M("recon.skin_views_not_to_the_bald_rows", "avatarkit/recon/multiview.py",
      "        if b is not views[i]:\n            # the bald rows", "        if False:\n            # the bald rows",
      ["tests/test_register.py", "-k", "bald_layer"], "colour_from_views sampling the bald rows from the plain views whatever bald_views says"),
    M("recon.skin_views_hair_rows_too", "avatarkit/recon/multiview.py",
      "            samples[i] = Samples(np.where(is_hair, s.seen, t.seen), np.where(is_hair, s.weight, t.weight),\n                                 np.where(is_hair[:, None], s.colour, t.colour))",
      "            samples[i] = t",
      ["tests/test_register.py", "-k", "bald_layer"], "the skin views' samples taken for the hair rows too"),
    M("recon.skin_views_not_passed", "avatarkit/recon/multiview.py",
      "                                                bald_views=skin, hidden_bald=hidden_bald,",
      "                                                bald_views=None, hidden_bald=hidden_bald,",
      ["tests/test_keyframe_refine.py", "-k", "colour_stage"], "VideoViews.colour not handing the skin views to the colour blend"),
    M("recon.skin_pose_recede_ignored", "avatarkit/recon/multiview.py",
      "            if SKIN_POSE_RECEDE:", "            if False:",
      ["tests/test_keyframe_refine.py", "-k", "colour_stage"], "the bald outline's recession voting with the plain poses whatever SKIN_POSE_RECEDE says"),
    M("track.outline_views_keep_tracked_camera", "avatarkit/recon/multiview.py",
      "            out[i] = dataclasses.replace(v, camera=cam, head=head)", "            out[i] = dataclasses.replace(v, head=head)",
      ["tests/test_keyframe_refine.py"], "the hair's outline measured with the joint fit's camera, not the registered"),
    M("track.outline_views_keep_tracked_head", "avatarkit/recon/multiview.py",
      "            out[i] = dataclasses.replace(v, camera=cam, head=head)", "            out[i] = dataclasses.replace(v, camera=cam)",
      ["tests/test_keyframe_refine.py"], "the hair's outline's hull check holding hair by the head at the joint fit's pose"),
    M("track.refine_everywhere_other_frames", "avatarkit/track/video_build.py",
      "        if everywhere is True or (everywhere is not False and k.frame in everywhere):",
      "        if everywhere is True or (everywhere is not False and k.frame not in everywhere):",
      ["tests/test_keyframe_refine.py"], "the registered pose given to every stage for the keyframes not at the tracking's edge"),
    M("track.colour_stage_unregistered", "avatarkit/track/evaluate.py",
      "                                colour_refine=options.refine)", "                                colour_refine=None)",
      ["tests/test_evaluate.py", "-k", "colour_frames_too"],
      "evaluate --refine scores a video build whose frame colours were fused on the landmark poses"),
    M("track.colour_stage_selection_fixed", "avatarkit/track/frame_colours.py",
      "    registered = refine is not None", "    registered = False",
      ["tests/test_frame_colours.py", "-k", "registered"],
      "the frame-colours stage fuses only its regions even when its frames are registered"),
    M("track.frame_hull_one_frame_clears", "avatarkit/track/frame_hull.py",
      "        new = allowed & ~cleared & _voted(seen, out, min_frames, quorum)",
      "        new = allowed & ~cleared & (out >= 1)",
      ["tests/test_frame_hull.py"],
      "one colour frame that shows a Gaussian over the wall clears it (no quorum, no minimum of frames)"),
    M("track.stage_refine_none_is_default", "avatarkit/track/frame_colours.py",
      '    return None if refine == "none" else refine', "    return refine",
      ["tests/test_frame_colours.py"], "`--frame-refine none` handed to the tracker as a setting's name, not as no refinement"),
    M("cli.build_drops_frame_switches", "cli/build_cmd.py",
      "                                        frame_colours=frame_colours, colour_refine=frame_refine,",
      "                                        frame_colours=None, colour_refine=frame_refine,",
      ["tests/test_video_build.py"], "`build VIDEO --no-frame-colours` not reaching the video build"),
    M("track.frame_hull_clears_bald", "avatarkit/track/frame_colours.py",
      "    allowed = None if frame_hull.BALD else np.arange(nb + len(avatar.hair)) >= nb",
      "    allowed = None",
      ["tests/test_frame_hull.py"], "the frame hull clearing the bald head's one layer of discs (holes seen from the side)"),
    M("track.frame_hull_one_round", "avatarkit/track/frame_hull.py",
      "        g = v.gaussians\n        if cleared is not None and cleared.any():",
      "        g = v.gaussians\n        if False:",
      ["tests/test_frame_hull.py"],
      "the bound's later rounds vote with the cleared Gaussians still drawn (what they hid stays hidden)"),
    M("track.frame_hull_recede_unposed", "avatarkit/track/frame_hull.py",
      "        views = pose(offsets)",
      "        views = pose(0 * offsets)",
      ["tests/test_frame_hull.py"],
      "the recession's later rounds vote on the frames posed without the moves so far (discs keep sinking)"),
    M("track.frame_hull_recede_not_returned", "avatarkit/track/frame_colours.py",
      "    _set_bald_means(avatar, mine + receded.offsets)", "    _set_bald_means(avatar, mine)",
      ["tests/test_frame_hull.py"], "the recession moving the posed avatar's bald discs but not the built one's"),
    M("track.frame_hull_neck_ignores_clothes", "avatarkit/track/frame_hull.py",
      "        if other is not None and other.any():", "        if False:",
      ["tests/test_frame_hull.py"], "the neck's discs voting with the person's wall, not their own (the clothes ignored)"),
    M("track.frame_hull_recede_regions_ignored", "avatarkit/track/frame_colours.py",
      "    movable = np.ones(nb, bool) if regions is None else fusion_selection(saved, tuple(regions))[:nb]",
      "    movable = np.ones(nb, bool)",
      ["tests/test_frame_hull.py"], "every bald disc receding whatever RECEDE_REGIONS asks"),
    M("track.fusion_regions_default_none", "avatarkit/track/frame_colours.py",
      "def fusion_selection(avatar, regions=_UNSET, hair: bool = False) -> np.ndarray:",
      "def fusion_selection(avatar, regions=None, hair: bool = False) -> np.ndarray:",
      ["tests/test_call_time_defaults.py"],
      "fusion_selection's default made None, which means every bald Gaussian, not REGIONS"),
    M("track.frame_hull_min_frames_hard_coded", "avatarkit/track/frame_hull.py",
      "    rounds = ROUNDS if rounds is None else rounds\n    share = SHARE if share is None else share\n"
      "    quorum = QUORUM if quorum is None else quorum\n    min_frames = MIN_FRAMES if min_frames is None else min_frames\n"
      "    if len(views) != len(walls):",
      "    rounds = ROUNDS if rounds is None else rounds\n    share = SHARE if share is None else share\n"
      "    quorum = QUORUM if quorum is None else quorum\n    min_frames = 3 if min_frames is None else min_frames\n"
      "    if len(views) != len(walls):",
      ["tests/test_call_time_defaults.py"],
      "carve's minimum of frames written as its value, not read from frame_hull.MIN_FRAMES"),
    M("track.eval_head_on_frozen", "avatarkit/track/evaluate.py",
      "    head_on: str = field(default_factory=lambda: _neck.DEFAULT_HEAD_ON)",
      "    head_on: str = \"neck\"",
      ["tests/test_call_time_defaults.py", "-k", "option_fields"],
      "EvalOptions.head_on written as its value, not read from neck.DEFAULT_HEAD_ON when made"),
    M("track.frame_colours_hidden_unweighted", "avatarkit/track/frame_colours.py",
      "                delta = delta * p[\"damp\"]",
      "                pass",
      ["tests/test_frame_colours.py"], "the frames' colour updates not weighted by what of a Gaussian shows (HIDDEN_WEIGHT ignored)"),
    M("track.frame_colours_hidden_depth_ignored", "avatarkit/track/frame_colours.py",
      "                delta = delta * p[\"scale\"][:, None]",
      "                pass",
      ["tests/test_frame_colours.py"], "a frame updating the Gaussians it shows behind its surface (HIDDEN_DEPTH ignored)"),
    M("track.frame_colours_hidden_frames_counted", "avatarkit/track/frame_colours.py",
      "            den[sh] += p[\"scale\"] if p[\"scale\"] is not None and HIDDEN_COUNT else 1.0",
      "            den[sh] += 1.0",
      ["tests/test_frame_colours.py"], "the frames that hide a Gaussian counted in its mean update (HIDDEN_COUNT ignored)"),
    M("track.unregistered_turned_trusted", "avatarkit/track/video_build.py",
      "            if k.outline_pose is None and abs(params_from_pose(k.pose)[0] - ref) >= REFINE_MIN_YAW]",
      "            if k.outline_pose is None and abs(params_from_pose(k.pose)[0] - ref) >= 10.0]",
      ["tests/test_keyframe_refine.py"], "a video with no draft trusting its turned keyframes' joint-fit poses for the outline"),
    M("track.register_shift_ignored", "avatarkit/track/register.py",
      "    if shift_steps is not None and len(start) >= 5:", "    if False:",
      ["tests/test_register.py", "-k", "shifted"],
      "the shifted registration's second grid (each yaw's head moved to fit) never searched"),
    M("track.register_turned_shift_dropped", "avatarkit/track/video_build.py",
      "                                  shifted=REGISTER_SHIFTED, discount_hair=", "                                  shifted=False, discount_hair=",
      ["tests/test_keyframe_refine.py", "-k", "shifted"],
      "the turned frames registered without the shifted grid whatever REGISTER_SHIFTED says"),
    M("recon.hair_hull_turned_margin_ignored", "avatarkit/recon/hair_hull.py",
      "        turned_end = TURNED_MARGIN is not None and v.info.get(\"turned_end\", False)",
      "        turned_end = False",
      ["tests/test_hair_hull.py", "-k", "turned_end"],
      "the frames registered at the turns' ends grow hull hair with EDGE_MARGIN whatever TURNED_MARGIN says"),
    M("recon.hair_hull_turned_covered_margin_thinned", "avatarkit/recon/hair_hull.py",
      "            covered_margin = _multiview.EDGE_MARGIN if TURNED_COVERED_MARGIN is None else TURNED_COVERED_MARGIN",
      "            covered_margin = TURNED_MARGIN",
      ["tests/test_hair_hull.py", "-k", "turned_end"],
      "the turned-end frames' covered pixels dilated by TURNED_MARGIN, not TURNED_COVERED_MARGIN / EDGE_MARGIN (a rim grows)"),
    M("recon.multiview_turned_end_unmarked", "avatarkit/recon/multiview.py",
      "            if k.frame in turned_end:", "            if False:",
      ["tests/test_keyframe_refine.py", "-k", "marked"],
      "the views of the frames registered at the turns' ends not marked (hair_hull.TURNED_MARGIN never applies)"),
    M("track.register_shift_not_kept", "avatarkit/track/register.py",
      "    best, err = min(ends, key=lambda m: m[1])", "    best, err = ends[0]",
      ["tests/test_register.py", "-k", "shifted"],
      "the shifted grid's refinement run but the plain grid's end kept whatever its error"),
    M("recon.facing_weight_unpowered", "avatarkit/recon/facing_refine.py",
      "    facing = np.clip(cos, 0.0, 1.0) ** power", "    facing = np.clip(cos, 0.0, 1.0)",
      ["tests/test_facing_refine.py"], "the facing refine's weights not sharpened by the power of the cosine"),
    M("recon.nape_stops_at_photo_end", "avatarkit/recon/hair_strands.py",
      "            end[nape] = self.hairline.at(p[nape])", "            pass",
      ["tests/test_recon_lift.py"], "a nape strand stopping at the photo's lowest hair instead of the hairline"),
    M("recon.sclera_fixed_white", "avatarkit/recon/bald_discs.py",
      "    if len(seen) < least:", "    if True:",
      ["tests/test_recon_lift.py"], "the eyes' unseen sclera the fixed bright white, not the photo's sclera"),
    M("recon.hairline_highest_edge", "avatarkit/recon/hair_strands.py",
      "        np.minimum.at(low, b, v[:, 1])", "        np.maximum.at(low, b, v[:, 1])",
      ["tests/test_recon_lift.py"], "the hairline read from the scalp's top instead of its lower edge"),
    M("recon.neck_kept_unseen_too", "avatarkit/recon/multiview.py",
      "    return neck & (footprint_visibility(gaussians, reference) >= float(shown))", "    return neck.copy()",
      ["tests/test_multiview.py"], "NECK_SHOWN keeping the whole neck's portrait colours, the sides the photo never shows too"),
    M("recon.scalp_body_off_the_head", "avatarkit/recon/multiview.py",
      "            wide = region | ((np.asarray(view.labels) == BODY) & np.asarray(view.head, bool))",
      "            wide = region | (np.asarray(view.labels) == BODY)",
      ["tests/test_multiview.py"], "SCALP_BODY sampling body pixels anywhere in the keyframe (the clothes), not only on its head"),
    M("recon.scalp_fill_faces_reference", "avatarkit/recon/multiview.py",
      "        hidden = scalp & ~seen & away", "        hidden = scalp & ~seen",
      ["tests/test_multiview.py"], "SCALP_FILL filling the scalp the reference faces but does not see (hidden), not only what it looks away from"),
    M("recon.scalp_fill_every_bald_row", "avatarkit/recon/multiview.py",
      "        scalp = np.asarray(scalp, bool) & ~is_hair", "        scalp = np.ones(len(both), bool) & ~is_hair",
      ["tests/test_multiview.py"], "SCALP_FILL filling every unseen bald Gaussian, not the scalp's alone"),
    M("recon.scalp_fill_in_the_drafts", "avatarkit/recon/multiview.py",
      '(DRAFT_SCALP_FILL or not self.info.get("draft", False))', "(DRAFT_SCALP_FILL or True)",
      ["tests/test_multiview.py"], "SCALP_FILL in the registration drafts too, whatever DRAFT_SCALP_FILL says"),
    M("recon.neck_fill_the_underside", "avatarkit/recon/multiview.py",
      "        side = np.asarray(normals, np.float64)[:, 1] > -np.sin(np.radians(float(NECK_FILL_DOWN)))",
      "        side = np.ones(len(both), bool)",
      ["tests/test_multiview.py", "-k", "neck"], "NECK_FILL filling the neck's cut end (facing down) too"),
    M("recon.neck_fill_not_from_the_kept", "avatarkit/recon/multiview.py",
      "neck & (seen | kept),", "neck & seen,",
      ["tests/test_multiview.py", "-k", "neck"], "NECK_FILL filling only from the neck the views blended, not from the kept neck the photo shows"),
    M("recon.neck_fill_in_the_drafts", "avatarkit/recon/multiview.py",
      'return bool(NECK_FILL and not self.info.get("draft", False))', "return bool(NECK_FILL)",
      ["tests/test_multiview.py", "-k", "neck"], "NECK_FILL in the registration drafts too"),
    M("recon.hair_facing_ignored", "avatarkit/recon/multiview.py",
      "        if hair_facing is not None:\n            # a view along the shell",
      "        if False:\n            # a view along the shell",
      ["tests/test_multiview.py", "-k", "facing"], "the hair's samples weighted by visibility alone whatever hair_facing says"),
    M("recon.hair_facing_without_its_floor", "avatarkit/recon/multiview.py",
      "np.clip(cos / float(hair_facing), float(HAIR_FACING_FLOOR), 1.0) ** COS_POWER",
      "np.clip(cos / float(hair_facing), 0.0, 1.0) ** COS_POWER",
      ["tests/test_multiview.py", "-k", "facing"], "HAIR_FACING_FLOOR ignored (cos clipped at 0)"),
    M("recon.hair_facing_without_its_knee", "avatarkit/recon/multiview.py",
      "np.clip(cos / float(hair_facing), float(HAIR_FACING_FLOOR), 1.0) ** COS_POWER",
      "np.clip(cos, float(HAIR_FACING_FLOOR), 1.0) ** COS_POWER",
      ["tests/test_multiview.py", "-k", "facing"], "HAIR_FACING's knee ignored (every view below cos 1 weighed down)"),
    M("recon.hair_facing_not_passed_to_the_views", "avatarkit/recon/multiview.py",
      "    samples = [view_samples(both, normals, v, hair=is_hair, body=body, hair_facing=hair_facing) for v in views]",
      "    samples = [view_samples(both, normals, v, hair=is_hair, body=body) for v in views]",
      ["tests/test_multiview.py", "-k", "along_the_shell"], "colour_from_views drops hair_facing"),
    M("recon.hair_facing_in_drafts", "avatarkit/recon/multiview.py",
      'return None if HAIR_FACING is None or self.info.get("draft", False) else float(HAIR_FACING)',
      "return None if HAIR_FACING is None else float(HAIR_FACING)",
      ["tests/test_multiview.py", "-k", "weigh_the_hairs"], "HAIR_FACING in the registration drafts too"),
    M("recon.hair_facing_keeps_no_grazed_hair", "avatarkit/recon/multiview.py",
      "        only_others |= grazed\n", "        only_others = only_others\n",
      ["tests/test_multiview.py", "-k", "little_of_it_shown"], "the grazed hair the reference shows little of left to the photo's matching"),
    M("recon.hair_facing_shown_ignored", "avatarkit/recon/multiview.py",
      "            grazed &= footprint_visibility(both, views[0].camera) < float(HAIR_FACING_SHOWN)",
      "            pass",
      ["tests/test_multiview.py", "-k", "little_of_it_shown"], "HAIR_FACING_SHOWN ignored: every grazed hair row keeps the blend"),
    M("recon.recede_keyframes_in_the_drafts", "avatarkit/recon/multiview.py",
      'return bool(RECEDE_KEYFRAMES and not self.info.get("draft", False))', "return bool(RECEDE_KEYFRAMES)",
      ["tests/test_recede_keyframes.py"], "RECEDE_KEYFRAMES in the registration drafts too"),
    M("recon.recede_keyframes_outward", "avatarkit/recon/multiview.py",
      "    normals = frame_hull.inward_normals(fit.rest_vertices, fit.model.faces, bald.extras[\"binding\"])",
      "    normals = -frame_hull.inward_normals(fit.rest_vertices, fit.model.faces, bald.extras[\"binding\"])",
      ["tests/test_recede_keyframes.py"], "the keyframes' recede moving the discs outward"),
    M("recon.recede_keyframes_joint_fit_poses", "avatarkit/recon/multiview.py",
      "return self.outline_views(fit, views) if RECEDE_OUTLINE_POSES else views", "return views",
      ["tests/test_recede_keyframes.py"], "the keyframes' recede voting at the joint fit's poses, not the outline stage's"),
    M("recon.recede_keyframes_the_scalp_too", "avatarkit/recon/multiview.py",
      "    movable = np.ones(nb, bool) if RECEDE_SCALP else", "    movable = np.ones(nb, bool) if True else",
      ["tests/test_recede_keyframes.py"], "the keyframes' recede setting in the scalp's discs under the hair"),
    M("recon.recede_keyframes_frame_hull_margin", "avatarkit/recon/multiview.py",
      "frame_hull.wall_image(v.labels != BACKGROUND, RECEDE_MARGIN)",
      "frame_hull.wall_image(v.labels != BACKGROUND, frame_hull.MARGIN)",
      ["tests/test_recede_keyframes.py"], "the keyframes' person masks dilated by the frame hull's 1 px (the overshoot hidden)"),
    M("recon.recede_edge_ignored", "avatarkit/recon/multiview.py",
      "                                near=edge)", "                                near=None)",
      ["tests/test_recede_keyframes.py"], "RECEDE_EDGE set but every keyframe that shows a disc counting in its quorum"),
    M("recon.recede_edge_min_frames_kept", "avatarkit/recon/multiview.py",
      "min_frames=RECEDE_MIN_FRAMES if edge is None else RECEDE_EDGE_FRAMES,", "min_frames=RECEDE_MIN_FRAMES,",
      ["tests/test_recede_keyframes.py"], "RECEDE_EDGE asking RECEDE_MIN_FRAMES keyframes at a disc's outline, not RECEDE_EDGE_FRAMES"),
    M("recon.recede_edge_share_ignored", "avatarkit/recon/multiview.py",
      "share=RECEDE_SHARE if edge is None else RECEDE_EDGE_SHARE,", "share=RECEDE_SHARE,",
      ["tests/test_recede_keyframes.py"], "RECEDE_EDGE voting at RECEDE_SHARE, not RECEDE_EDGE_SHARE"),
    M("track.near_outline_far", "avatarkit/track/frame_hull.py",
      "return ok & (dist[ix[:, 1], ix[:, 0]] <= pixels)", "return ok & (dist[ix[:, 1], ix[:, 0]] >= pixels)",
      ["tests/test_recede_keyframes.py"], "near_outline taking the Gaussians far from the render's outline"),
    M("recon.recede_edge_turn_ignored", "avatarkit/recon/multiview.py",
      "lead=[bool(t >= turn) for t in turns],", "lead=[True for t in turns],",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "RECEDE_EDGE_TURN set but every keyframe leading the edge rule"),
    M("recon.turned_yaws_from_the_first_view", "avatarkit/recon/multiview.py",
      "    y0 = yaw(ref)", "    y0 = yaw(views[0].camera)",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "turned_yaws measured from the first view, not the marked reference"),
    M("track.recede_lead_vote_unrequired", "avatarkit/track/frame_hull.py",
      "| ((led >= 1) & _voted(seen_near,", "| ((led >= 0) & _voted(seen_near,",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "recede(lead=) moving a disc no lead frame votes out"),
    M("track.recede_lead_quorum_dropped", "avatarkit/track/frame_hull.py",
      "            new = movable & (quorum_moves", "            new = movable & (False",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "recede(lead=) dropping session 23's quorum over every frame that shows a disc"),
    M("track.continuing_skips_too_near", "avatarkit/track/background_plate.py",
      "near = cv2.dilate(np.asarray(known, np.uint8), disc,", "near = cv2.dilate(np.asarray(known, np.uint8), disc[1:-1, 1:-1],",
      ["tests/test_background_plate.py", "-k", "continuing_counts"], "continuing skipping pixels whose disc's rim holds a known pixel"),
    M("track.recede_lead_share_ignored", "avatarkit/track/frame_hull.py",
      "share, share if near_share is None else near_share, near, lead", "share, share, near, lead",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "recede(lead=) voting at share, not near_share"),
    M("recon.recede_edge_agree_ignored", "avatarkit/recon/multiview.py",
      "or deep_disagreement(p.gaussians, p.camera, w) <= agree", "or True",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "RECEDE_EDGE_AGREE set but a turned keyframe whose silhouette is off leading"),
    M("recon.deep_disagreement_at_the_outline", "avatarkit/recon/multiview.py",
      "deep = (np.asarray(wall) == 1) & (inside > float(RECEDE_EDGE_DEEP))", "deep = (np.asarray(wall) == 1) & (inside > 0)",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "deep_disagreement counting the outline's band (the overshoot the recession mends)"),
    M("track.recede_lead_rounds_ignored", "avatarkit/track/frame_hull.py",
      "lead_rounds = rounds if lead is None or lead_rounds is None else max(int(lead_rounds), rounds)",
      "lead_rounds = rounds",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "recede(lead_rounds=) stopping at rounds"),
    M("track.recede_lead_rounds_move_the_quorums_too", "avatarkit/track/frame_hull.py",
      "quorum_moves = _voted(seen, out, min_frames, quorum) if r < rounds else np.zeros(m, bool)",
      "quorum_moves = _voted(seen, out, min_frames, quorum)",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "recede(lead_rounds=) moving the quorum's Gaussians past rounds too"),
    M("recon.recede_edge_like_ignored", "avatarkit/recon/multiview.py",
      "walls = [sure_wall(w, v.image, v.labels != BACKGROUND, RECEDE_EDGE_LIKE) if", "walls = [w if",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "RECEDE_EDGE_LIKE set but the leading keyframes voting over the wall that looks like the person"),
    M("recon.sure_wall_at_the_persons_edge", "avatarkit/recon/multiview.py",
      "levels: float, inset: int = 3) -> np.ndarray:", "levels: float, inset: int = 0) -> np.ndarray:",
      ["tests/test_recede_keyframes.py", "-k", "turned or deep or unlike or sure_wall or own_rounds"], "sure_wall comparing with the person's blended edge pixels, not its inside"),
    M("recon.hair_fringe_wall_from_the_median", "avatarkit/recon/hair_fringe.py",
      "    return np.asarray(colour, np.float64)[ny, nx] / 255.0",
      "    return np.tile(np.median(np.asarray(colour, np.float64)[known], axis=0) / 255.0, (len(xi), 1))",
      ["tests/test_hair_fringe.py"], "the wall behind every hair Gaussian read as the plate's median, not the wall behind it"),
    M("recon.hair_fringe_off_line_ignored", "avatarkit/recon/hair_fringe.py",
      "    readable = (off <= OFF_LINE) & (l2 >= MIN_CONTRAST ** 2)", "    readable = l2 >= MIN_CONTRAST ** 2",
      ["tests/test_hair_fringe.py"], "a colour off the hair-wall segment (a highlight, another wall) read as their mix"),
    M("recon.hair_fringe_share_unclipped", "avatarkit/recon/hair_fringe.py",
      "    s = np.clip(s, 0.0, 1.0)\n", "",
      ["tests/test_hair_fringe.py"], "the share not clipped: a colour darker than the hair read past it"),
    M("recon.cover_head_colour_past_the_head", "avatarkit/recon/coverage.py",
      "    if inside is not None and flat.any() and (covered & inside).any():", "    if False:",
      ["tests/test_recon_coverage.py"],
      "coverage reading the head's colour at any covered pixel, the wall the overshoot covers included"),
    M("recon.cover_plate_ignored", "avatarkit/recon/coverage.py",
      "    if views and plate is not None and COVER_PLATE is not None:\n", "    if False:\n",
      ["tests/test_recon_coverage.py", "-k", "continues_the_plate"],
      "a video build's coverage giving discs to the wall the segmentation took in beside the jaw"),
    M("recon.cover_plate_matching_kept", "avatarkit/recon/coverage.py",
      "            neck_out[wall] = True\n", "            pass\n",
      ["tests/test_recon_coverage.py", "-k", "continues_the_plate"],
      "the wall taken in beside the jaw left in the photo's colour matching (the rim's discs take it)"),
    M("recon.cover_plate_single_frame_too", "avatarkit/recon/coverage.py",
      "    if views and plate is not None and COVER_PLATE is not None:\n",
      "    if plate is not None and COVER_PLATE is not None:\n",
      ["tests/test_recon_coverage.py", "-k", "continues_the_plate"],
      "the wall-plate test reaching the single-frame builds (the shared real clips)"),
    M("recon.cover_plate_any_channel", "avatarkit/recon/coverage.py",
      "    return region & (count >= COVER_PLATE_MATCHES)\n", "    return region & (count >= 0)\n",
      ["tests/test_recon_coverage.py", "-k", "continues_the_plate"],
      "every head pixel near the known wall taken for the wall, whatever its colour"),
    M("recon.cover_plate_background_share_ignored", "avatarkit/recon/coverage.py",
      "            wall[wy[a < COVER_MIN_SHARE], wx[a < COVER_MIN_SHARE]] = False\n", "            pass\n",
      ["tests/test_recon_coverage.py", "-k", "continues_the_plate"],
      "the wall-coloured skin pixels next to the same wall (background already) left out of the matching too"),
    M("recon.cover_plate_spares_the_unreadable", "avatarkit/recon/coverage.py",
      "            wall[wy[a < COVER_MIN_SHARE], wx[a < COVER_MIN_SHARE]] = False\n",
      "            wall[wy[(a < COVER_MIN_SHARE) | (a >= 1.0)], wx[(a < COVER_MIN_SHARE) | (a >= 1.0)]] = False\n",
      ["tests/test_recon_coverage.py", "-k", "one_case"],
      "the wall-plate test sparing the pixels the unmixing reads as all head (the wall past the overshoot: white or plaster)"),
    M("recon.cover_plate_in_drafts_too", "avatarkit/recon/multiview.py",
      "        return not self.info.get(\"draft\", False)\n\n    def fills_neck", "        return True\n\n    def fills_neck",
      ["tests/test_multiview.py", "-k", "wall_coloured_skin"],
      "the registration drafts' coverage leaving the wall-coloured skin uncovered too (the mesh subject's poses move)"),
    M("recon.cover_neck_ignored", "avatarkit/recon/coverage.py",
      "        if not (COVER_NECK_VIDEO if views else COVER_NECK):\n", "        if False:\n",
      ["tests/test_recon_coverage.py"],
      "COVER_NECK off still giving the neck's skin pixels beyond the fitted head their discs"),
    M("recon.cover_neck_video_builds_too", "avatarkit/recon/coverage.py",
      "        if not (COVER_NECK_VIDEO if views else COVER_NECK):\n", "        if not COVER_NECK:\n",
      ["tests/test_recon_coverage.py"],
      "the video builds dropping the neck's coverage too (the mesh subject's video build on the dark wall)"),
    M("recon.under_jaw_sideways_too", "avatarkit/recon/coverage.py",
      "off[:, 1] < -0.5 * np.linalg.norm(off, axis=1)", "off[:, 1] <= np.linalg.norm(off, axis=1)",
      ["tests/test_recon_coverage.py"],
      "under_jaw taking a disc beside (or above) a jaw triangle for one under the jaw: the face's side"),
    M("recon.under_jaw_no_jaw_weight", "avatarkit/recon/coverage.py",
      "        jaw = w[faces, JAW_JOINT].mean(axis=1) >= UNDER_JAW_WEIGHT\n",
      "        jaw = w[faces, JAW_JOINT].mean(axis=1) >= 0.0\n",
      ["tests/test_recon_coverage.py"],
      "under_jaw counting a disc below any triangle (an ear lobe's, the brow's) as under the jaw"),
    M("recon.cover_neck_rim_dropped_too", "avatarkit/recon/coverage.py",
      "| (gap[ys[sel], xs[sel]] <= NECK_RIM_PX)", "| (gap[ys[sel], xs[sel]] < 0.0)",
      ["tests/test_recon_coverage.py"],
      "COVER_NECK dropping the render's own rim under the jaw too (the sample portrait's jaw showed the white wall)"),
    M("recon.cover_neck_not_reported", "avatarkit/recon/coverage.py",
      "                neck_out[ys[sel[~keep]], xs[sel[~keep]]] = True\n", "                pass\n",
      ["tests/test_recon_coverage.py"],
      "COVER_NECK's dropped pixels not reported: the colour matching pulls the neck's edge discs to them"),
    M("recon.neck_out_still_matched", "avatarkit/recon/pipeline.py",
      "            matched &= ~neck\n", "            pass\n",
      ["tests/test_recon_pipeline.py", "-k", "neck_pixels"],
      "the neck pixels the coverage left without a disc kept in the colour matching (an orange streak at 45)"),
    M("recon.edge_hair_on_skin_every_hair", "avatarkit/recon/multiview.py",
      "        on_skin = is_hair & away & (skin_w", "        on_skin = is_hair & (skin_w",
      ["tests/test_multiview.py", "-k", "skin_is_dropped"],
      "EDGE_HAIR_ON_SKIN dropping hair the reference faces, not only what it shows edge-on"),
    M("recon.edge_hair_on_skin_counts_the_reference", "avatarkit/recon/multiview.py",
      "        if v.reference or v.labels is None:", "        if v.labels is None:",
      ["tests/test_multiview.py", "-k", "skin_is_dropped"],
      "EDGE_HAIR_ON_SKIN counting the reference's own labels (hair at its silhouette) with the keyframes'"),
    M("recon.edge_hair_on_skin_in_the_drafts", "avatarkit/recon/multiview.py",
      'EDGE_HAIR_ON_SKIN is not None and not self.info.get("draft", False))', "EDGE_HAIR_ON_SKIN is not None)",
      ["tests/test_multiview.py", "-k", "skin_is_dropped"],
      "EDGE_HAIR_ON_SKIN in the registration drafts too"),
    M("recon.relabel_connected_dropped", "avatarkit/recon/multiview.py",
      "            lost |= _connected_lost(labels, full, head, near, zone | lost, model, connected, wall)", "            pass",
      ["tests/test_multiview.py", "-k", "connected"],
      "RELABEL_CONNECTED handed over but the strands beyond RELABEL_REACH never relabelled"),
    M("recon.relabel_connected_unconnected", "avatarkit/recon/multiview.py",
      "    return out & np.isin(comp, keep[keep > 0])", "    return out",
      ["tests/test_multiview.py", "-k", "connected"],
      "RELABEL_CONNECTED taking every non-background-coloured pixel within its reach, connected to the head or not"),
    M("recon.relabel_connected_every_keyframe", "avatarkit/recon/multiview.py",
      '            connected = RELABEL_CONNECTED if (RELABEL_CONNECTED_IN == "all" or k.frame in turned_end) else None',
      "            connected = RELABEL_CONNECTED",
      ["tests/test_keyframe_refine.py", "-k", "relabel"],
      "RELABEL_CONNECTED applied to every keyframe whatever RELABEL_CONNECTED_IN says"),
    M("recon.bald_inset_never", "avatarkit/recon/bald_discs.py",
      "    if INSET is None:\n        return discs\n", "    if True:\n        return discs\n",
      ["tests/test_bald_inset.py"], "INSET set but sample_bald leaving its discs on the surface: the outline stands 1-2 px out"),
    M("recon.bald_inset_keeps_nothing", "avatarkit/recon/bald_discs.py",
      "    depth_of = np.where(_inset_kept(fit.model, v), 0.0, inset_depth(sigma_of, pixel))",
      "    depth_of = inset_depth(sigma_of, pixel)",
      ["tests/test_bald_inset.py"], "the lips and lids set in with the rest: the closed lips part, the eyes' inside shows"),
    M("recon.bald_inset_no_pixel", "avatarkit/recon/bald_discs.py",
      "    return INSET * sigma + np.minimum(INSET_PIXEL * p * p / np.maximum(sigma + 0.5 * p, 1e-12), p)",
      "    return INSET * sigma",
      ["tests/test_bald_inset.py"], "the inset without the dilation's part: at the input's pixels the outline still stands out"),
    M("recon.bald_inset_along_the_face_normal_of_another", "avatarkit/recon/bald_discs.py",
      "    depth = np.asarray(depth_of, np.float64)[np.asarray(ids)]",
      "    depth = np.asarray(depth_of, np.float64)[np.asarray(ids)[::-1]]",
      ["tests/test_bald_inset.py"], "each disc set in by another face's depth"),
    M("recon.bald_holes_never_filled", "avatarkit/recon/bald_discs.py",
      "    if threshold is None or rounds <= 0 or len(points) == 0:", "    if True:",
      ["tests/test_bald_holes.py"], "HOLE_ALPHA set but fill_holes adding no disc: the face's holes stay open"),
    M("recon.bald_holes_other_side", "avatarkit/recon/bald_discs.py",
      "        a = np.where(valid & same & (q <= 9.0),", "        a = np.where(valid & (q <= 9.0),",
      ["tests/test_bald_holes.py"], "surface_coverage counting the discs of the surface's other side (an ear's back) as cover"),
    M("recon.bald_holes_from_the_callers_stream", "avatarkit/recon/bald_discs.py",
      "                          rng.spawn(1)[0])", "                          rng)",
      ["tests/test_bald_holes.py"], "fill_holes' probes drawn from the caller's stream: the hair drawn next changes with them"),
    M("recon.bald_holes_first_pass_as_coverage", "avatarkit/recon/bald_discs.py",
      "    cov = surface_coverage(points[maybe], normals[maybe], means, rot, sc, opacity=opacity, k=k, chunk=chunk,\n"
      "                           tree=tree)\n",
      "    cov = bound[maybe]\n", ["tests/test_bald_holes.py", "-k", "bit_for_bit or fast_path"],
      "thin_coverage taking its first pass's bound (the nearest discs alone) for the coverage"),
    M("recon.bald_holes_first_pass_drops_the_near_thin", "avatarkit/recon/bald_discs.py",
      "    maybe = np.flatnonzero(bound < threshold + HOLE_MARGIN)", "    maybe = np.flatnonzero(bound < threshold - 0.02)",
      ["tests/test_bald_holes.py", "-k", "bit_for_bit or fast_path"],
      "thin_coverage's first pass calling covered the probes its bound leaves just under the threshold"),
    M("recon.bald_holes_first_pass_other_side", "avatarkit/recon/bald_discs.py",
      "        hit = valid & facing & (q <= 9.0 - HOLE_MARGIN)", "        hit = valid & (q <= 9.0 - HOLE_MARGIN)",
      ["tests/test_bald_holes.py", "-k", "bit_for_bit"],
      "thin_coverage's first pass counting the discs of the other side: its bound no longer one"),
    M("recon.bald_spread_any_earlier_neighbour", "avatarkit/recon/bald_discs.py",
      "            if kept[j]:", "            if True:", ["tests/test_bald_holes.py", "-k", "spread"],
      "the fast _spread dropping a point near an earlier one the greedy thinning had dropped itself"),
    # --- the camera's lens (session 28) ----------------------------------------------------------
    M("recon.lens_ignored", "avatarkit/recon/fit.py",
      "    mm = FOCAL_35MM if focal_mm is None else float(focal_mm)", "    mm = FOCAL_35MM",
      ["tests/test_lens.py", "-k", "given_lens or tracker_takes or phone_lens"], "portrait_focal ignoring the lens the user gave (the assumed 50 mm always)"),
    M("recon.lens_not_passed_to_the_fit", "avatarkit/recon/pipeline.py",
      "            fit = fit_head(analysis, segmentation, head_model, embedding=embedding, focal=focal)",
      "            fit = fit_head(analysis, segmentation, head_model, embedding=embedding)",
      ["tests/test_lens.py", "-k", "fits_the_head"], "the build fitting the head with the assumed lens although told another"),
    M("track.lens_not_tracked", "avatarkit/track/video_build.py",
      "TrackOptions(face_index=options.face_index or 0, focal_mm=options.focal_mm)",
      "TrackOptions(face_index=options.face_index or 0)",
      ["tests/test_lens.py", "-k", "tracks_with"], "the video build tracking with the assumed lens although told another"),
    M("track.lens_pixels_overridden", "avatarkit/track/tracker.py",
      "    return float(options.focal) if options.focal else portrait_focal(*size, options.focal_mm)",
      "    return portrait_focal(*size, options.focal_mm)",
      ["tests/test_lens.py", "-k", "pixels_win or frame_colours"],
      "the tracker's focal in pixels (a saved tracking's camera) overridden by the lens"),
    M("track.lens_frame_colours_assumed", "avatarkit/track/frame_colours.py",
      "refine_every=stage_spacing(refine), focal=float(tracking.camera.fx))",
      "refine_every=stage_spacing(refine))",
      ["tests/test_lens.py", "-k", "frame_colours"], "the frame-colours stage re-tracking with the assumed lens, not the build's"),
]


def _apply(m: Mutation, root: Path | None = None) -> tuple[dict[Path, bytes], dict[Path, str]]:
    """The edits of `m` worked out in memory (nothing is written) on the tree at `root`: the
    original bytes and the mutated text of each file it touches. `root` defaults to this tree."""
    root = ROOT if root is None else root
    originals: dict[Path, bytes] = {}
    texts: dict[Path, str] = {}
    for file, old, new in m.edits:
        path = root / file
        if path not in texts:
            originals[path] = path.read_bytes()
            texts[path] = originals[path].decode("utf-8")
        count = texts[path].count(old)
        if count != 1:
            raise LookupError(f"{m.id}: {file}: the text to mutate occurs {count} times (expected once):\n{old}")
        texts[path] = texts[path].replace(old, new)
    return originals, texts


def scratch_copy(into: Path, root: Path | None = None) -> Path:
    """A copy of the working tree at `root` under `into` (same folder name, so tests that find
    `../shared` or the repo by path behave as in the tree): every file git tracks or would
    track (`git ls-files --cached --others --exclude-standard`), uncommitted edits included;
    ignored outputs (.venv, build folders) are left out. `../shared` is linked beside it when
    the tree has one. Returns the copy's root."""
    root = ROOT if root is None else root
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            cwd=root, capture_output=True, check=True).stdout.decode().split("\0")
    copy = into / root.name
    for rel in filter(None, listed):
        src = root / rel
        if not src.is_file():  # deleted in the tree but still in the index
            continue
        dst = copy / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
    shared = root.parent / "shared"
    if shared.exists():
        (into / "shared").symlink_to(shared.resolve())
    return copy


def check(mutations) -> list[str]:
    problems = []
    for m in mutations:
        try:
            _apply(m)
        except LookupError as e:
            problems.append(str(e))
    return problems


def run_one(m: Mutation, timeout: float, root: Path) -> tuple[str, float, str]:
    """Apply to the copy at `root`, test there, restore. Returns (outcome, seconds, last line of
    the test output)."""
    originals, texts = _apply(m, root)
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-m", "not slow", *m.tests]
    # the copy first on the path: the venv's editable install points at the working tree
    env = dict(os.environ, TI_SKIP_VERSION_CHECK="ON", ENABLE_TAICHI_HEADER_PRINT="0",
               PYTHONPATH=os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])]))
    t0 = time.perf_counter()
    try:
        for path, text in texts.items():
            path.write_text(text, encoding="utf-8")
        try:
            proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return "killed (timeout)", time.perf_counter() - t0, f"no result within {timeout:.0f} s"
    finally:
        for path, data in originals.items():
            path.write_bytes(data)
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    last = lines[-1] if lines else ""
    if proc.returncode == 0:
        return "survived", time.perf_counter() - t0, last
    if proc.returncode == 5:  # no tests collected: the test selection is wrong, not a kill
        return "no tests", time.perf_counter() - t0, last
    return "killed", time.perf_counter() - t0, last


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("packages", nargs="*", help="packages to mutate (default: all): "
                    + ", ".join(sorted({m.package for m in MUTATIONS})))
    ap.add_argument("--id", action="append", default=[], help="run only this mutation (repeatable)")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    ap.add_argument("--check", action="store_true", help="check that every edit still applies, and exit")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per mutation's test run")
    args = ap.parse_args(argv)

    chosen = [m for m in MUTATIONS if (not args.packages or m.package in args.packages)
              and (not args.id or m.id in args.id)]
    unknown = set(args.id) - {m.id for m in MUTATIONS}
    unknown |= set(args.packages) - {m.package for m in MUTATIONS}
    if unknown or not chosen:
        print(f"error: unknown or empty selection: {', '.join(sorted(unknown)) or '(none chosen)'}", file=sys.stderr)
        return 2
    if args.list:
        for m in chosen:
            print(f"{m.id:32} {m.why}  [{' '.join(m.tests)}]")
        return 0
    problems = check(chosen)
    if problems:
        for p in problems:
            print(f"error: {p}", file=sys.stderr)
        return 2
    if args.check:
        print(f"{len(chosen)} mutations apply cleanly")
        return 0

    # SIGTERM as Ctrl-C: stop, and remove the scratch copy
    signal.signal(signal.SIGTERM, lambda *a: (_ for _ in ()).throw(KeyboardInterrupt()))
    results = []
    scratch = Path(tempfile.mkdtemp(prefix="avatarkit-mutate-"))
    try:
        copy = scratch_copy(scratch)
        for m in chosen:
            outcome, seconds, last = run_one(m, args.timeout, copy)
            results.append((m, outcome))
            print(f"{outcome:17} {m.id:32} {seconds:6.1f} s  {m.why}", flush=True)
            if outcome != "killed":
                print(f"{'':17} {last}", flush=True)
    except KeyboardInterrupt:
        print("interrupted (the working tree was never touched)", file=sys.stderr)
        return 130
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    print()
    by_pkg: dict[str, list[int]] = {}
    for m, outcome in results:
        k = by_pkg.setdefault(m.package, [0, 0])
        k[0] += outcome.startswith("killed")
        k[1] += 1
    for pkg, (killed, total) in by_pkg.items():
        print(f"{pkg:10} {killed}/{total} killed")
    killed = sum(k for k, _ in by_pkg.values())
    total = sum(t for _, t in by_pkg.values())
    print(f"{'score':10} {killed}/{total} killed ({100 * killed / total:.0f} %)")
    return 0 if killed == total else 1


if __name__ == "__main__":
    sys.exit(main())
