#!/usr/bin/env python3
"""Benchmark `avatarkit convert`: an SH-degree-3 3DGS PLY -> .usdc, wall time and peak memory.

Each case runs in its own subprocess, so peak memory is that process's `ru_maxrss` (C++
allocations in USD included, which tracemalloc would miss). Reported: wall seconds of the
whole conversion inside the process (PLY read + USD write), peak RSS of the process, and the
part of it above the RSS right after imports. NVIDIA's `usd-convert-gsplat` runs on the same
file when it is installed (by default only at the smallest size: it loops in Python).

Targets (issue 10): <= 1.0 s and <= 0.5 GB at 200k. Figures are noisy on a shared 2-core box.

Usage: benchmarks/convert.py [--sizes 200000 1000000] [--nvidia-sizes 200000] [--keep DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _rss_mb() -> float:
    """Peak RSS of this process so far (Linux reports KiB). A child started by exec inherits its
    parent's peak at fork time, so the parent keeps nothing big (inputs are made in a child too)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _current_rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def child(tool: str, src: str, dst: str) -> None:
    """Run one conversion and print a JSON line with its figures."""
    if tool == "ours":
        from avatarkit.convert import convert
        from avatarkit.gaussians.ply import read_ply
        from avatarkit.gaussians.usd import save_usd
        base = _current_rss_mb()
        t0 = time.perf_counter()
        convert(src, dst)
        total = time.perf_counter() - t0
        peak = _rss_mb()
        # phases, for the notes (a second run: file caches are warm for both)
        t0 = time.perf_counter()
        gs = read_ply(src)
        t1 = time.perf_counter()
        save_usd(dst + ".2.usdc", gs)
        t2 = time.perf_counter()
        os.remove(dst + ".2.usdc")
        print(json.dumps(dict(seconds=total, peak_mb=peak, base_mb=base, read_s=t1 - t0, write_s=t2 - t1)))
    else:
        import usd_convert_gsplat as nv
        base = _current_rss_mb()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            nv.write_gaussian_splat_usd(nv.read_ply(src), dst, source_file=src)
        total = time.perf_counter() - t0
        print(json.dumps(dict(seconds=total, peak_mb=_rss_mb(), base_mb=base)))


def make_ply(n: int, path: Path, seed: int = 0) -> None:
    import numpy as np

    from avatarkit.gaussians import GaussianSet
    from avatarkit.gaussians.ply import write_ply
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    gs = GaussianSet(rng.normal(scale=0.3, size=(n, 3)).astype(np.float32),
                     q / np.linalg.norm(q, axis=1, keepdims=True),
                     np.exp(rng.uniform(-7, -2, size=(n, 3))).astype(np.float32),
                     rng.uniform(0.05, 1, n).astype(np.float32),
                     rng.normal(scale=0.3, size=(n, 16, 3)).astype(np.float32))
    write_ply(path, gs)


def run_case(tool: str, src: Path, dst: Path) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", tool, str(src), str(dst)],
                         capture_output=True, text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["out_mb"] = dst.stat().st_size / 1e6
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[200_000, 1_000_000])
    ap.add_argument("--nvidia-sizes", type=int, nargs="*", default=[200_000])
    ap.add_argument("--keep", type=Path, help="write inputs/outputs here instead of a temp folder")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--quick", action="store_true",
                    help="tiny sizes, one repeat: only checks that the script runs")
    args = ap.parse_args()
    if args.quick:
        args.sizes, args.nvidia_sizes = [5000], [5000]
    if args.child:
        if args.child[0] == "make":
            make_ply(int(args.child[1]), Path(args.child[2]))
        else:
            child(*args.child)
        return
    try:
        import usd_convert_gsplat  # noqa: F401
        have_nv = True
    except ImportError:
        have_nv = False
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        print(f"{'N':>9} {'tool':<22} {'wall s':>8} {'peak MB':>8} {'above import':>13} {'out MB':>7}  notes")
        for n in args.sizes:
            src = folder / f"sh3_{n}.ply"
            subprocess.run([sys.executable, __file__, "--child", "make", str(n), str(src)], check=True)
            ours = run_case("ours", src, folder / f"ours_{n}.usdc")
            target = "  target <= 1.0 s, <= 500 MB" if n == 200_000 else ""
            print(f"{n:>9} {'avatarkit convert':<22} {ours['seconds']:>8.2f} {ours['peak_mb']:>8.0f} "
                  f"{ours['peak_mb'] - ours['base_mb']:>13.0f} {ours['out_mb']:>7.1f}  "
                  f"PLY read {ours['read_s']:.2f} s + USD write {ours['write_s']:.2f} s{target}")
            if have_nv and n in args.nvidia_sizes:
                nv = run_case("nvidia", src, folder / f"nv_{n}.usdc")
                print(f"{n:>9} {'usd-convert-gsplat':<22} {nv['seconds']:>8.2f} {nv['peak_mb']:>8.0f} "
                      f"{nv['peak_mb'] - nv['base_mb']:>13.0f} {nv['out_mb']:>7.1f}  "
                      f"{nv['seconds'] / ours['seconds']:.1f}x our time, "
                      f"{nv['peak_mb'] / ours['peak_mb']:.1f}x our peak")
            elif n in args.nvidia_sizes:
                print(f"{n:>9} {'usd-convert-gsplat':<22} not installed")


if __name__ == "__main__":
    main()
