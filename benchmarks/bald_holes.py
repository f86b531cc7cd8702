"""`bald_discs.fill_holes`' fast path against its slow reference, in one process.

On the synthetic head (`synthetic_head_view`'s truth fit), `sample_bald` at n = 8,000 and 40,000
(the CLI's size), seeds 0-2, with `HOLE_REFERENCE` False (the fast path: `thin_coverage`'s first
pass over the `HOLE_FIRST` nearest discs, the vectorised `_spread`) and True (`surface_coverage`
over every probe, `_spread_reference`) and without the fill (`HOLE_ALPHA` None): prints the
median seconds of each (wall, and the process's CPU), their ratio ("ratio": sample_bald's; "fill
ratio": the fill's own, sample_bald's less the draw without it) and whether the five outputs are
bit for bit the same (they must be). Times on a shared machine are noisy; the ratios (same
process, interleaved; the CPU seconds steadier) are the figures to read.

    .venv/bin/python benchmarks/bald_holes.py [--repeats 3] [--quick]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _timing import cpu_model  # noqa: E402

from avatarkit.recon import bald_discs  # noqa: E402
from avatarkit.recon.fit import synthetic_head_view  # noqa: E402


def _build(fit, n: int, seed: int, reference: bool | None):
    """sample_bald with the fast path (False), the reference (True) or no fill (None)."""
    saved = bald_discs.HOLE_REFERENCE, bald_discs.HOLE_ALPHA
    try:
        if reference is None:
            bald_discs.HOLE_ALPHA = None
        else:
            bald_discs.HOLE_REFERENCE = reference
        return bald_discs.sample_bald(fit, n, np.random.default_rng(seed))
    finally:
        bald_discs.HOLE_REFERENCE, bald_discs.HOLE_ALPHA = saved


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="tiny sizes (n 2,000, seed 0, once): the script runs")
    args = ap.parse_args()
    sizes, seeds = ((2000,), (0,)) if args.quick else ((8000, 40000), (0, 1, 2))
    repeats = 1 if args.quick else args.repeats
    fit = synthetic_head_view((0.0, 0.15, 0.0), distance=0.6, size=64, n_gaussians=500).truth
    print(f"cpu: {cpu_model()}  cores: {os.cpu_count()}  load: {os.getloadavg()[0]:.2f}")
    print(f"{'n':>6} {'seed':>4} {'discs':>6} {'time':>4} {'no fill s':>9} {'reference s':>11} {'fast s':>7} "
          f"{'ratio':>6} {'fill ratio':>10} same")
    for n in sizes:
        for seed in seeds:
            ref = _build(fit, n, seed, True)
            fast = _build(fit, n, seed, False)
            same = all(a.dtype == b.dtype and np.array_equal(a, b) for a, b in zip(ref, fast))
            # interleaved, so that the machine's load falls on the three alike; the process's CPU
            # seconds beside the wall's (steadier on a shared machine: all of it runs on one thread)
            wall = {None: [], True: [], False: []}
            cpu = {None: [], True: [], False: []}
            for _ in range(repeats):
                for kind in wall:
                    t, c = time.perf_counter(), time.process_time()
                    _build(fit, n, seed, kind)
                    wall[kind].append(time.perf_counter() - t)
                    cpu[kind].append(time.process_time() - c)
            for name, times in (("wall", wall), ("cpu", cpu)):
                t_none, t_ref, t_fast = (float(np.median(times[kind])) for kind in (None, True, False))
                # the fill's own seconds: sample_bald's less the draw without it
                fill = (t_ref - t_none) / max(t_fast - t_none, 1e-9)
                print(f"{n:>6} {seed:>4} {len(fast[0]):>6} {name:>4} {t_none:>9.3f} {t_ref:>11.3f} {t_fast:>7.3f} "
                      f"{t_ref / t_fast:>6.2f} {fill:>10.2f} {'yes' if same else 'NO'}", flush=True)


if __name__ == "__main__":
    main()
