"""Bake speed and memory: the sample avatar (~50k bald + ~50k hair Gaussians) on a 300-frame clip.

Prints
- the avatar folder: its size, and the load time (wall and CPU) of the folder as saved (rig
  format 2: MVC weights recomputed on load) and of the same avatar with the dense weights stored
  (rig format 1, the old layout) as the baseline;
- rig storage options measured on the whip clip: top-k sparse weights (with linear precision)
  against the dense weights, max / mean distance of the deformed hair points, and their size;
- frames per second of bake + USD write (no preview), and of the bake alone, with ms per frame
  per stage (head LBS, bald Gaussians, hair simulation, hair deformation, USD write) and CPU ms
  per frame; the bake alone with `hair_batch=1` (one product per frame, the reference path) is
  the baseline the batched hair deformation (16 frames per product) is compared with;
- peak resident memory (ru_maxrss of a fresh subprocess) of 100- and 300-frame bakes, which must
  not grow with the clip length;
- USD bytes per frame for float and half precision;
- the bald Gaussians' fast path (fused Taichi kernel) against the numpy reference
  (`TriangleBinding.to_world`), in this process.
Each bake runs in its own subprocess (so ru_maxrss is that bake's own peak).
Target: >= 20 frames/s end to end on 2 cores.

Usage: python benchmarks/bake.py [N_HAIR N_BALD] [--frames 300] [--no-storage] [--quick]
       python benchmarks/bake.py --child AVATAR_DIR FRAMES OUT {usd,half,none} HAIR_BATCH  (internal)
       python benchmarks/bake.py --load AVATAR_DIR                                     (internal)
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path


def clip(frames: int):
    from avatarkit.motion import make_clip

    # talking with head motion: jaw, expressions and a moving head, at 30 fps
    return make_clip("talk", frames=frames, fps=30.0, expr_dims=9)


def cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def load_child(avatar_dir: str) -> None:
    """Time one load_avatar in a fresh process, and the load with the hair's MVC weights ready
    (format 2 computes them on first use; Taichi's import and start included)."""
    from avatarkit.avatar import load_avatar

    warnings.simplefilter("ignore")
    t0, c0 = time.perf_counter(), cpu_seconds()
    avatar = load_avatar(avatar_dir)
    t1, c1 = time.perf_counter(), cpu_seconds()
    avatar.rig.deformer.weights_t  # noqa: B018 -- computes deferred weights
    print(json.dumps({"load": t1 - t0, "load_cpu": c1 - c0, "seconds": time.perf_counter() - t0,
                      "cpu": cpu_seconds() - c0}))


def child(avatar_dir: str, frames: int, out: str, mode: str, hair_batch: int) -> None:
    from avatarkit.avatar import load_avatar
    from avatarkit.bake import BakeConfig, run_bake

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    avatar = load_avatar(avatar_dir)
    load = time.perf_counter() - t0
    # the hair's MVC weights (computed on first use): timed apart from the bake's stages
    t1 = time.perf_counter()
    avatar.rig.deformer.weights_t  # noqa: B018
    weights = time.perf_counter() - t1
    t0 += weights
    writers = []
    if mode in ("usd", "half"):
        from avatarkit.export.usd_stage import UsdStageWriter, UsdWriteOptions

        writers.append(UsdStageWriter(out, UsdWriteOptions(half=mode == "half")))
    stamps, cpus = [], []

    def progress(done, total):
        stamps.append(time.perf_counter())
        cpus.append(cpu_seconds())

    summary = run_bake(avatar, clip(frames), BakeConfig(hair_batch=hair_batch), writers, progress=progress)
    # steady rate: after the first chunk of `hair_batch` frames (it carries the Taichi JIT and the
    # 1 s pre-roll; every frame after its last one is computed after that frame's stamp)
    b = hair_batch if len(stamps) > hair_batch else 1
    steady = (len(stamps) - b) / (stamps[-1] - stamps[b - 1]) if len(stamps) > b else float("nan")
    size = 0
    if writers:
        p = Path(out)
        clips = p.parent / (p.stem + "_clips")
        size = p.stat().st_size + (sum(f.stat().st_size for f in clips.iterdir()) if clips.is_dir() else 0)
    print(json.dumps({"frames": summary.frames, "seconds": summary.seconds, "fps": summary.fps,
                      "steady_fps": steady,
                      "steady_cpu_ms": 1e3 * (cpus[-1] - cpus[b - 1]) / max(len(cpus) - b, 1),
                      "first_frame_seconds": stamps[0] - t0 - load,
                      "load_seconds": load, "weights_seconds": weights, "bytes": size, "timings": summary.timings,
                      "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def run_child(*args) -> dict:
    env = dict(os.environ, TI_SKIP_VERSION_CHECK="ON", ENABLE_TAICHI_HEADER_PRINT="0")
    res = subprocess.run([sys.executable, __file__, *map(str, args)], capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise SystemExit(f"child failed:\n{res.stderr}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def as_format_1(folder: Path, target: Path) -> None:
    """A copy of an avatar folder whose rig.npz stores the dense MVC weights (rig format 1)."""
    import shutil

    import numpy as np

    from avatarkit.avatar import load_avatar

    shutil.copytree(folder, target)
    weights_t = load_avatar(folder).rig.deformer.weights_t
    with np.load(target / "rig.npz") as z:
        data = {k: z[k] for k in z.files}
    data.update(format=np.array("avatarkit.rig/1"), deform_weights_t=weights_t)
    with open(target / "rig.npz", "wb") as fh:
        np.savez(fh, **data)


def storage_options(avatar) -> None:
    """Dense weights (stored or recomputed: the same numbers) against top-k sparse weights with
    linear precision, on the cage of the whip clip (every 3rd frame)."""
    import numpy as np

    from avatarkit.cage.mvc import sparse_apply, sparsify
    from avatarkit.cage.points import deformation_points
    from avatarkit.motion import make_clip

    d = avatar.rig.deformer
    cages = np.stack([f.cage for f in avatar.hair_driver().simulate_clip(make_clip("whip", fps=30),
                                                                         with_hair=False)])[::3]
    points = deformation_points(avatar.hair, d.method, d.axis_sigma)
    dense = [d.deformed_points(c).T for c in cages]
    print(f"rig storage options on the whip clip ({len(cages)} frames, {len(points):,} hair points, "
          f"{d.cage.n_vertices}-vertex cage); distance of the deformed points from the dense result:")
    print(f"  dense float32 stored (rig format 1): {d.weights_t.nbytes / 1e6:.0f} MB, exact")
    print("  dense recomputed on load (rig format 2, the product's choice): 0 MB, exact")
    for k in (32, 64):
        idx, w = sparsify(d.weights, k, points=points, cage_vertices=d.cage.vertices)
        err = np.concatenate([np.linalg.norm(sparse_apply(idx, w, c) - x, axis=1) for c, x in zip(cages, dense)])
        print(f"  top-{k} sparse + linear precision: {len(points) * k * 6 / 1e6:.0f} MB (uint16 index + "
              f"float32 weight), max {err.max() * 1e3:.2f} mm, mean {err.mean() * 1e3:.3f} mm, "
              f"99th percentile {np.percentile(err, 99) * 1e3:.2f} mm")


def main(argv: list[str]) -> None:
    frames = 300
    quick = "--quick" in argv  # tiny sizes: only checks that the script runs (tests, make bench-quick)
    storage = "--no-storage" not in argv and not quick
    argv = [a for a in argv if a not in ("--no-storage", "--quick")]
    if "--frames" in argv:
        i = argv.index("--frames")
        frames = int(argv[i + 1])
        del argv[i:i + 2]
    n_hair, n_bald = (int(argv[0]), int(argv[1])) if len(argv) >= 2 else (50_000, 50_000)
    if quick:
        frames, n_hair, n_bald = 12, 3000, 3000
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    import numpy as np

    from avatarkit.rig.binding_kernel import binding_to_world
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    print(f"bake benchmark: sample avatar {n_bald:,} bald + {n_hair:,} hair Gaussians, {frames}-frame "
          f"talk clip at 30 fps, default simulation (4 substeps x 15 iterations, proxy collision)")
    print(f"(cpu cores: {os.cpu_count()}; timings on a shared machine are noisy)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        avatar = make_sample_avatar(n_hair=n_hair, n_bald=n_bald)
        made = time.perf_counter() - t
        t = time.perf_counter()
        folder = avatar.save(tmp / "avatar", preview=False)
        saved = time.perf_counter() - t
        sizes = {p.name: p.stat().st_size for p in folder.iterdir()}
        print(f"sample avatar: made in {made:.1f} s ({len(avatar.hair):,} hair, cage "
              f"{avatar.cage.n_vertices} vertices), saved in {saved:.1f} s, folder "
              f"{sum(sizes.values()) / 1e6:.1f} MB (goal < 40): " + ", ".join(
                  f"{k} {v / 1e6:.1f} MB" for k, v in sorted(sizes.items())))
        old = tmp / "avatar_format1"
        as_format_1(folder, old)
        old_size = sum(p.stat().st_size for p in old.iterdir())
        tries = 1 if quick else 2
        new_load = [run_child("--load", folder) for _ in range(tries)]
        old_load = [run_child("--load", old) for _ in range(tries)]
        best = {k: min(r["seconds"] for r in v) for k, v in (("new", new_load), ("old", old_load))}
        cpu = {k: min(r["cpu"] for r in v) for k, v in (("new", new_load), ("old", old_load))}
        print(f"load + hair weights ready (fresh process, best of {tries}): {best['new']:.1f} s wall / "
              f"{cpu['new']:.1f} s CPU with the weights recomputed (goal < ~5 s on 2 cores; the load "
              f"alone {min(r['load'] for r in new_load):.1f} s wall / {min(r['load_cpu'] for r in new_load):.1f} s "
              f"CPU); baseline with dense weights stored (rig format 1, {old_size / 1e6:.0f} MB folder): "
              f"{best['old']:.1f} s wall / {cpu['old']:.1f} s CPU")
        if storage:
            storage_options(avatar)

        # fast path vs reference for the bald Gaussians, in this process
        rng = np.random.default_rng(0)
        v = avatar.rest_head_vertices + rng.normal(0, 1e-3, avatar.rest_head_vertices.shape).astype(np.float32)
        binding = avatar.binding
        binding_to_world(binding, v)  # compile
        reps = 20
        t = time.perf_counter()
        for _ in range(reps):
            binding_to_world(binding, v)
        fast = (time.perf_counter() - t) / reps
        t = time.perf_counter()
        for _ in range(3):
            binding.to_world(v)
        ref = (time.perf_counter() - t) / 3
        print(f"bald Gaussians to world: fused kernel {fast * 1e3:.2f} ms/frame, numpy reference "
              f"{ref * 1e3:.1f} ms/frame ({ref / fast:.1f}x)")
        del avatar, binding

        runs = {}
        from avatarkit.bake import HAIR_BATCH

        short_n = max(frames // 3, 1)
        for label, n, mode, batch in (("usd", frames, "usd", HAIR_BATCH), ("usd_short", short_n, "usd", HAIR_BATCH),
                                      ("half", short_n, "half", HAIR_BATCH), ("none", short_n, "none", HAIR_BATCH),
                                      ("none_ref", short_n, "none", 1)):
            runs[label] = run_child("--child", folder, n, tmp / f"{label}.usdc", mode, batch)
            r = runs[label]
            stages = ", ".join(f"{k} {1e3 * s / r['frames']:.1f}" for k, s in r["timings"].items())
            print(f"  {label:<9} {r['frames']:>4} frames, hair_batch {batch:>2}: {r['steady_fps']:5.1f} "
                  f"frames/s steady ({r['steady_cpu_ms']:.0f} CPU ms/frame; {r['fps']:.1f} overall; first "
                  f"frame {r['first_frame_seconds']:.1f} s), peak RSS {r['maxrss_mb']:5.0f} MB, load "
                  f"{r['load_seconds']:.1f} s + weights {r['weights_seconds']:.1f} s; ms/frame: {stages}")

    full, short, half, none, ref = runs["usd"], runs["usd_short"], runs["half"], runs["none"], runs["none_ref"]
    print()
    print(f"bake + USD write (no preview): {full['steady_fps']:.1f} frames/s steady over {full['frames']} "
          f"frames, {full['fps']:.1f} overall incl. JIT and 1 s pre-roll (target >= 20); bake alone "
          f"{none['steady_fps']:.1f} frames/s steady (ratio with USD / without "
          f"{full['steady_fps'] / none['steady_fps']:.2f})")
    hair_ms = {k: 1e3 * r["timings"]["hair"] / r["frames"] for k, r in (("new", none), ("ref", ref))}
    print(f"hair deformation in the bake: {hair_ms['new']:.1f} ms/frame batched ({HAIR_BATCH} frames per "
          f"product) vs {hair_ms['ref']:.1f} ms/frame one product per frame (reference path): "
          f"{hair_ms['ref'] / hair_ms['new']:.1f}x; bake alone {none['steady_fps']:.1f} vs "
          f"{ref['steady_fps']:.1f} frames/s, {none['steady_cpu_ms']:.0f} vs {ref['steady_cpu_ms']:.0f} CPU ms/frame")
    print(f"peak memory: {short['maxrss_mb']:.0f} MB for {short['frames']} frames, {full['maxrss_mb']:.0f} MB "
          f"for {full['frames']} frames (ratio {full['maxrss_mb'] / short['maxrss_mb']:.2f}; "
          f"independent of clip length if ~1)")
    print(f"USD bytes per frame: float {full['bytes'] / full['frames'] / 1e6:.2f} MB, "
          f"half {half['bytes'] / half['frames'] / 1e6:.2f} MB "
          f"(ratio {half['bytes'] / half['frames'] / (full['bytes'] / full['frames']):.2f})")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5], int(sys.argv[6]))
    elif len(sys.argv) > 1 and sys.argv[1] == "--load":
        load_child(sys.argv[2])
    else:
        main(sys.argv[1:])
