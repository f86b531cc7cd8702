"""Bake speed and memory: the sample avatar (~50k bald + ~50k hair Gaussians) on a 300-frame clip.

Prints
- frames per second of bake + USD write (no preview), and of the bake alone, with seconds per
  stage (head LBS, bald Gaussians, hair simulation, hair deformation, USD write);
- peak resident memory (ru_maxrss of a fresh subprocess) of 100- and 300-frame bakes, which must
  not grow with the clip length;
- USD bytes per frame for float and half precision;
- the bald Gaussians' fast path (fused Taichi kernel) against the numpy reference
  (`TriangleBinding.to_world`), in this process.
Each bake runs in its own subprocess (so ru_maxrss is that bake's own peak).
Target: >= 20 frames/s end to end on 2 cores.

Usage: python benchmarks/bake.py [N_HAIR N_BALD] [--frames 300]
       python benchmarks/bake.py --child AVATAR_DIR FRAMES OUT {usd,half,none}   (internal)
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


def child(avatar_dir: str, frames: int, out: str, mode: str) -> None:
    from avatarkit.avatar import load_avatar
    from avatarkit.bake import BakeConfig, run_bake

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    avatar = load_avatar(avatar_dir)
    load = time.perf_counter() - t0
    writers = []
    if mode in ("usd", "half"):
        from avatarkit.export.usd_stage import UsdStageWriter, UsdWriteOptions

        writers.append(UsdStageWriter(out, UsdWriteOptions(half=mode == "half")))
    stamps = []
    summary = run_bake(avatar, clip(frames), BakeConfig(), writers,
                       progress=lambda done, total: stamps.append(time.perf_counter()))
    # steady rate: from the end of frame 1 on (frame 0 carries the Taichi JIT and the 1 s pre-roll)
    steady = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 else float("nan")
    size = 0
    if writers:
        p = Path(out)
        clips = p.parent / (p.stem + "_clips")
        size = p.stat().st_size + (sum(f.stat().st_size for f in clips.iterdir()) if clips.is_dir() else 0)
    print(json.dumps({"frames": summary.frames, "seconds": summary.seconds, "fps": summary.fps,
                      "steady_fps": steady, "first_frame_seconds": stamps[0] - t0 - load,
                      "load_seconds": load, "bytes": size, "timings": summary.timings,
                      "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def run_child(avatar_dir: Path, frames: int, out: Path, mode: str) -> dict:
    env = dict(os.environ, TI_SKIP_VERSION_CHECK="ON", ENABLE_TAICHI_HEADER_PRINT="0")
    res = subprocess.run([sys.executable, __file__, "--child", str(avatar_dir), str(frames), str(out), mode],
                         capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise SystemExit(f"child failed:\n{res.stderr}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv: list[str]) -> None:
    frames = 300
    if "--frames" in argv:
        i = argv.index("--frames")
        frames = int(argv[i + 1])
        del argv[i:i + 2]
    n_hair, n_bald = (int(argv[0]), int(argv[1])) if len(argv) >= 2 else (50_000, 50_000)
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    import numpy as np

    from avatarkit.bake import binding_to_world
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
              f"{avatar.cage.n_vertices} vertices), saved in {saved:.1f} s, "
              f"{sum(sizes.values()) / 1e6:.1f} MB (rig.npz {sizes['rig.npz'] / 1e6:.1f} MB)")

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
        for label, n, mode in (("usd", frames, "usd"), ("usd_short", max(frames // 3, 1), "usd"),
                               ("half", max(frames // 3, 1), "half"), ("none", max(frames // 3, 1), "none")):
            runs[label] = run_child(folder, n, tmp / f"{label}.usdc", mode)
            r = runs[label]
            stages = ", ".join(f"{k} {1e3 * s / r['frames']:.1f}" for k, s in r["timings"].items())
            print(f"  {label:<9} {r['frames']:>4} frames: {r['steady_fps']:5.1f} frames/s steady "
                  f"({r['fps']:.1f} overall; first frame {r['first_frame_seconds']:.1f} s), "
                  f"peak RSS {r['maxrss_mb']:5.0f} MB, load {r['load_seconds']:.1f} s; ms/frame: {stages}")

    full, short, half, none = runs["usd"], runs["usd_short"], runs["half"], runs["none"]
    print()
    print(f"bake + USD write (no preview): {full['steady_fps']:.1f} frames/s steady over {full['frames']} "
          f"frames, {full['fps']:.1f} overall incl. JIT and 1 s pre-roll (target >= 20); bake alone "
          f"{none['steady_fps']:.1f} frames/s steady (ratio with USD / without "
          f"{full['steady_fps'] / none['steady_fps']:.2f})")
    print(f"peak memory: {short['maxrss_mb']:.0f} MB for {short['frames']} frames, {full['maxrss_mb']:.0f} MB "
          f"for {full['frames']} frames (ratio {full['maxrss_mb'] / short['maxrss_mb']:.2f}; "
          f"independent of clip length if ~1)")
    print(f"USD bytes per frame: float {full['bytes'] / full['frames'] / 1e6:.2f} MB, "
          f"half {half['bytes'] / half['frames'] / 1e6:.2f} MB "
          f"(ratio {half['bytes'] / half['frames'] / (full['bytes'] / full['frames']):.2f})")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5])
    else:
        main(sys.argv[1:])
