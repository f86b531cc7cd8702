"""3DGS PLY I/O speed: write and read N Gaussians with SH degree 3 (default 1M, ~248 MB).

Prints seconds (best of --repeat, page cache warm) for our write and read, `np.fromfile` of the
same bytes (the floor: one copy of the file into memory) and plyfile's read as the INRIA 3DGS
`load_ply` does it (a peer reader), then the ratios. The issue's target: our read within 1.5x of np.fromfile.

    python benchmarks/ply_io.py [--n 1000000] [--repeat 5]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from helpers import random_gaussians  # noqa: E402

from avatarkit.gaussians.ply import read_ply, read_ply_header, write_ply  # noqa: E402


def best_of(repeat: int, fn) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
        del result
    return min(times)


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
    args = ap.parse_args()

    gs = random_gaussians(args.n, 3, seed=0, extras=())
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.ply"
        t_write = best_of(max(1, args.repeat // 2), lambda: write_ply(path, gs))
        size = path.stat().st_size
        offset = read_ply_header(path).data_offset
        read_ply(path)  # warm the page cache
        t_fromfile = best_of(args.repeat, lambda: np.fromfile(path, dtype=np.float32, offset=offset))
        t_read = best_of(args.repeat, lambda: read_ply(path))
        t_plyfile = None
        if not args.no_plyfile:
            t_plyfile = best_of(args.repeat, lambda: plyfile_load_like_3dgs(path))

    print(f"PLY I/O: {args.n:,} Gaussians, SH degree 3, {size / 1e6:.1f} MB, "
          f"best of {args.repeat}, {os.cpu_count()} CPUs")
    print(f"  write_ply           {t_write:8.3f} s")
    print(f"  read_ply            {t_read:8.3f} s")
    print(f"  np.fromfile (floor) {t_fromfile:8.3f} s")
    if t_plyfile is not None:
        print(f"  plyfile read        {t_plyfile:8.3f} s  (as 3DGS load_ply does: arrays, no activation)")
    print(f"  read_ply / np.fromfile = {t_read / t_fromfile:.2f}x  (target <= 1.5x)")
    print(f"  write_ply / np.fromfile = {t_write / t_fromfile:.2f}x")
    if t_plyfile is not None:
        print(f"  plyfile / read_ply = {t_plyfile / t_read:.2f}x")


if __name__ == "__main__":
    main()
