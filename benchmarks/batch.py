"""Batch bakes: 8 jobs (2 sample avatars x 4 clips) on 2 workers, local process pool vs Ray.

Prints, for each way of running the same 8 jobs (USD output only), the wall time from a fresh
process (process start, imports, Taichi start and avatar loads included):
- sequential: the jobs one after another in one process (`run_batch(engine="inline")`): the
  baseline of the ratios;
- 8 x `avatarkit bake`: one CLI process per job (what a shell loop does);
- local: `bake-batch --engine local --workers 2` (spawned process pool);
- ray: `bake-batch --engine ray --workers 2`, Ray's own start-up shown apart;
and for the parallel ones the speed-up (sequential / parallel) and the scaling efficiency
(speed-up / 2 workers). On a 2-core machine shared with other work the wall times are noisy,
so the CPU seconds of the sequential run and of the local pool (its workers included) are
printed too: what the pool costs beyond the work itself (one interpreter, Taichi start and
kernel compile per worker; each avatar is loaded by one worker when the affinity works).

Usage: python benchmarks/batch.py [--hair N] [--bald N] [--frames F] [--keep DIR]
       python benchmarks/batch.py --child ENGINE BATCH OUT   (internal)
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CLIPS = ("nod", "shake", "talk", "turn")
WORKERS = 2


def make_inputs(root: Path, n_hair: int, n_bald: int, frames: int) -> Path:
    from avatarkit.motion import make_clip, save_clip
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    for style, seed in (("long_straight", 0), ("bob", 1)):
        folder = root / "avatars" / style
        if not (folder / "avatar.json").is_file():
            folder.parent.mkdir(parents=True, exist_ok=True)
            make_sample_avatar(n_hair=n_hair, n_bald=n_bald, style=style, seed=seed).save(folder, preview=False)
    (root / "clips").mkdir(exist_ok=True)
    for kind in CLIPS:
        save_clip(root / "clips" / f"{kind}.npz", make_clip(kind, frames=frames, fps=30.0))
    doc = {"format": "avatarkit.batch", "version": 1,
           "jobs": [{"avatar": ["avatars/long_straight", "avatars/bob"], "clips": "clips"}]}
    (root / "batch.json").write_text(json.dumps(doc))
    return root / "batch.json"


def child(engine: str, batch: str, out: str) -> None:
    """One run from a fresh process; prints JSON."""
    import warnings

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    from avatarkit.batch import load_batch, run_batch

    ray_start = 0.0
    if engine == "ray":
        import logging

        import ray

        t1 = time.perf_counter()
        ray.init(num_cpus=WORKERS, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
        ray_start = time.perf_counter() - t1
    report = run_batch(load_batch(batch), out, engine=engine, workers=WORKERS if engine != "inline" else None)
    seconds = time.perf_counter() - t0
    if engine == "ray":
        import ray

        ray.shutdown()
    assert report.ok, [j.error for j in report.failed]
    import resource

    # this process and its (joined) pool workers; Ray's workers are not our children
    cpu = sum(getattr(resource.getrusage(who), f) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
              for f in ("ru_utime", "ru_stime"))
    print(json.dumps({"seconds": seconds, "ray_start": ray_start, "done": report.count("done"), "cpu": cpu,
                      "frames": sum(j.frames for j in report.jobs),
                      "bake_seconds": sum(j.seconds for j in report.jobs)}))


def run_child(engine: str, batch: Path, out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", TI_SKIP_VERSION_CHECK="ON", ENABLE_TAICHI_HEADER_PRINT="0")
    p = subprocess.run([sys.executable, __file__, "--child", engine, str(batch), str(out)], env=env,
                       capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{engine} run failed:\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def cli_loop(batch: Path, out: Path) -> float:
    """Each job as its own `avatarkit bake` process."""
    from avatarkit.batch import load_batch

    shutil.rmtree(out, ignore_errors=True)
    exe = Path(sys.executable).with_name("avatarkit")
    t0 = time.perf_counter()
    for job in load_batch(batch).jobs:
        target = out / f"{job.name}.usdc"
        target.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run([str(exe), "bake", str(job.avatar), str(job.clip), "-o", str(target), "-q"], check=True,
                       capture_output=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hair", type=int, default=5000)
    ap.add_argument("--bald", type=int, default=5000)
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--keep", type=Path, default=None, help="Keep (and reuse) the inputs in this folder.")
    ap.add_argument("--quick", action="store_true",
                    help="tiny sizes, one repeat: only checks that the script runs")
    args = ap.parse_args()
    if args.quick:
        args.hair, args.bald, args.frames = 1500, 1500, 8

    work = Path(tempfile.mkdtemp(prefix="avatarkit_batch_bench_"))
    inputs = args.keep or work / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    try:
        t0 = time.perf_counter()
        batch = make_inputs(inputs, args.hair, args.bald, args.frames)
        print(f"inputs: 2 sample avatars ({args.hair} hair + {args.bald} bald Gaussians) x {len(CLIPS)} clips "
              f"of {args.frames} frames = 8 jobs, USD output ({time.perf_counter() - t0:.1f} s to make)")
        print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start "
              "(figures are noisy on a shared machine)")
        seq = run_child("inline", batch, work / "seq")
        print(f"  sequential (one process)   {seq['seconds']:7.1f} s   {seq['frames']} frames, "
              f"{seq['frames'] / seq['seconds']:.1f} frames/s, {seq['cpu']:.1f} CPU s   [baseline]")
        loop = cli_loop(batch, work / "loop")
        print(f"  8 x avatarkit bake         {loop:7.1f} s   x{seq['seconds'] / loop:.2f} of sequential")
        for engine in ("local", "ray"):
            try:
                r = run_child(engine, batch, work / engine)
            except (SystemExit, FileNotFoundError) as e:
                print(f"  {engine:<26} skipped: {e}")
                continue
            speedup = seq["seconds"] / r["seconds"]
            extra = f"  (Ray start {r['ray_start']:.1f} s included)" if engine == "ray" else ""
            print(f"  {engine + ', 2 workers':<26} {r['seconds']:7.1f} s   speed-up x{speedup:.2f}, "
                  f"scaling efficiency {100 * speedup / WORKERS:.0f}%{extra}")
            if engine == "local":
                # load-independent: does the pool add work? (the sequential run is multi-threaded
                # too, so this is not a bound on the speed-up)
                print(f"  {'':<26} {r['cpu']:7.1f} CPU s, x{r['cpu'] / seq['cpu']:.2f} the sequential run's")
            if engine == "ray":
                net = r["seconds"] - r["ray_start"]
                s2 = seq["seconds"] / net
                print(f"  {'ray, without its start':<26} {net:7.1f} s   speed-up x{s2:.2f}, "
                      f"scaling efficiency {100 * s2 / WORKERS:.0f}%")
        print(f"load average at the end: {os.getloadavg()[0]:.1f}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":  # required: the local engine spawns workers that import this file
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(*sys.argv[2:5])
    else:
        main()
