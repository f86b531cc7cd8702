"""3DGS PLY I/O speed: write and read N Gaussians with SH degree 3 (default 1M, ~248 MB).

Prints seconds (best of --repeat, and the median, page cache warm) for our write, our read with
each decoder (the Taichi kernel once loaded, and the numpy reference), `np.fromfile` of the same
bytes (the floor: one copy of the file into memory) and plyfile's read as the INRIA 3DGS
`load_ply` does it (a peer reader), then the ratios. The issue's target: our read within 1.5x of
np.fromfile. Then one read in a fresh process each way, start-up included: what a one-shot
command such as `avatarkit inspect` pays (`read_ply`'s "auto" weighs exactly this).

    python benchmarks/ply_io.py [--n 1000000] [--repeat 5] [--no-plyfile] [--no-cold]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from helpers import random_gaussians  # noqa: E402

from avatarkit.gaussians.ply import read_ply, write_ply  # noqa: E402
from avatarkit.gaussians.ply_header import read_ply_header  # noqa: E402


def timings(repeat: int, fn) -> tuple[float, float]:
    """(best, median) seconds of `repeat` calls."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
        del result
    return min(times), statistics.median(times)


def best_of(repeat: int, fn) -> float:
    return timings(repeat, fn)[0]


COLD = """
import sys, time
t = time.perf_counter()
from avatarkit.gaussians.ply import read_ply
read_ply(sys.argv[1], decoder=sys.argv[2])
print(time.perf_counter() - t)
"""


def cold_read(path: Path, decoder: str) -> float:
    """Seconds for one read in a fresh Python process, imports and Taichi start included."""
    out = subprocess.run([sys.executable, "-c", COLD, str(path), decoder], check=True,
                         capture_output=True, text=True).stdout
    return float(out.split()[-1])


def plyfile_load_like_3dgs(path: Path):
    """plyfile as the INRIA 3DGS `load_ply` uses it: default (memory-mapped) read, then one
    array per property group (raw values: no activation, no validation)."""
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"]
    xyz = np.stack([np.asarray(v[c]) for c in ("x", "y", "z")], axis=1)
    opacity = np.asarray(v["opacity"])[:, None]
    dc = np.stack([np.asarray(v[f"f_dc_{i}"]) for i in range(3)], axis=1)
    rest_names = sorted((p.name for p in v.properties if p.name.startswith("f_rest_")),
                        key=lambda s: int(s.split("_")[-1]))
    rest = np.zeros((len(xyz), len(rest_names)), np.float32)
    for i, name in enumerate(rest_names):
        rest[:, i] = np.asarray(v[name])
    rest = rest.reshape(len(xyz), 3, -1)
    scales = np.stack([np.asarray(v[f"scale_{i}"]) for i in range(3)], axis=1)
    rots = np.stack([np.asarray(v[f"rot_{i}"]) for i in range(4)], axis=1)
    return xyz, opacity, dc, rest, scales, rots


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-plyfile", action="store_true", help="skip the (slow) plyfile read")
    ap.add_argument("--no-cold", action="store_true", help="skip the fresh-process reads")
    ap.add_argument("--quick", action="store_true",
                    help="tiny sizes, one repeat: only checks that the script runs")
    args = ap.parse_args()
    cold_repeats = 3
    if args.quick:
        args.n, args.repeat, cold_repeats = 5000, 1, 1

    gs = random_gaussians(args.n, 3, seed=0, extras=())
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.ply"
        t_write = best_of(max(1, args.repeat // 2), lambda: write_ply(path, gs))
        size = path.stat().st_size
        offset = read_ply_header(path).data_offset
        read_ply(path, decoder="kernel")  # warm the page cache, start Taichi, load the kernel
        fromfile = timings(args.repeat, lambda: np.fromfile(path, dtype=np.float32, offset=offset))
        kernel = timings(args.repeat, lambda: read_ply(path, decoder="kernel"))
        reference = timings(args.repeat, lambda: read_ply(path, decoder="numpy"))
        t_plyfile = None
        if not args.no_plyfile:
            t_plyfile = best_of(args.repeat, lambda: plyfile_load_like_3dgs(path))
        cold = {} if args.no_cold else {d: min(cold_read(path, d) for _ in range(cold_repeats))
                                        for d in ("auto", "numpy", "kernel")}

    t_fromfile, t_read = fromfile[0], kernel[0]
    print(f"PLY I/O: {args.n:,} Gaussians, SH degree 3, {size / 1e6:.1f} MB, "
          f"best of {args.repeat} (median), {os.cpu_count()} CPUs")
    print(f"  write_ply                 {t_write:8.3f} s")
    print(f"  read_ply, Taichi kernel   {kernel[0]:8.3f} s  ({kernel[1]:.3f})")
    print(f"  read_ply, numpy reference {reference[0]:8.3f} s  ({reference[1]:.3f})")
    print(f"  np.fromfile (floor)       {fromfile[0]:8.3f} s  ({fromfile[1]:.3f})")
    if t_plyfile is not None:
        print(f"  plyfile read              {t_plyfile:8.3f} s  (as 3DGS load_ply does: arrays, no activation)")
    print(f"  read_ply (kernel) / np.fromfile = {t_read / t_fromfile:.2f}x  (target <= 1.5x)")
    print(f"  read_ply (numpy) / np.fromfile = {reference[0] / t_fromfile:.2f}x")
    print(f"  write_ply / np.fromfile = {t_write / t_fromfile:.2f}x")
    if t_plyfile is not None:
        print(f"  plyfile / read_ply (kernel) = {t_plyfile / t_read:.2f}x")
    if cold:
        print("  one read in a fresh process (best of 3), imports and Taichi start-up included:")
        for decoder, seconds in cold.items():
            print(f"    decoder={decoder:7s} {seconds:6.3f} s")


if __name__ == "__main__":
    main()
