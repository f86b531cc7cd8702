"""Head model benchmark: template generation and LBS time per frame.

    .venv/bin/python benchmarks/head.py
    .venv/bin/python benchmarks/head.py --frames 200

Figures (wall clock, median of repeats after a warm-up; the machine is shared, so compare the
ratios printed beside each figure, which come from baselines run in the same process):
 - procedural template generation (uncached), split into its stages;
 - `HeadModel.forward` per frame, batched over T frames, on the template and on a FLAME-sized
   random model (5023 vertices, 300 + 100 blendshapes, 36 pose correctives, sparse J_regressor);
   the baselines are `lbs_reference` (plain loops over frames and joints, float64) and the torch
   twin `forward_torch` (CPU).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402
from _timing import median_time  # noqa: E402
import scipy.sparse  # noqa: E402

from avatarkit.head import FLAME_PARENTS, HeadModel, HeadParams  # noqa: E402
from avatarkit.head.lbs import lbs_reference  # noqa: E402



def flame_sized_model(seed: int = 0) -> HeadModel:
    rng = np.random.default_rng(seed)
    V, F = 5023, 9976
    v = rng.normal(scale=0.05, size=(V, 3))
    faces = rng.integers(0, V, size=(F, 3))
    w = rng.random((V, 5)) ** 4
    w /= w.sum(1, keepdims=True)
    jr = scipy.sparse.random(5, V, density=0.01, random_state=seed, format="csr")
    jr = scipy.sparse.diags(1.0 / np.asarray(jr.sum(1)).ravel()) @ jr
    return HeadModel(faces=faces, v_template=v, shapedirs=rng.normal(scale=1e-3, size=(V, 3, 300)),
                     exprdirs=rng.normal(scale=1e-3, size=(V, 3, 100)),
                     posedirs=rng.normal(scale=1e-3, size=(36, V * 3)),
                     J_regressor=jr.tocsr(), kintree_parents=FLAME_PARENTS, weights=w, name="flame-sized")


def random_params(model: HeadModel, T: int, seed: int = 1) -> HeadParams:
    rng = np.random.default_rng(seed)
    return HeadParams(expr=rng.normal(size=(T, model.num_expr)), rotation=rng.normal(scale=0.3, size=(T, 3)),
                      neck=rng.normal(scale=0.3, size=(T, 3)), jaw=rng.normal(scale=0.2, size=(T, 3)),
                      eyes=rng.normal(scale=0.2, size=(T, 6)), translation=rng.normal(scale=0.05, size=(T, 3)),
                      shape=rng.normal(size=model.num_shape))


def bench_generation() -> None:
    from avatarkit.head import template as tm
    from avatarkit.head.model import build_template
    from avatarkit.head.remesh import collapse_short_edges, flip_edges, project_to_sdf, relax

    t0 = time.perf_counter()
    v, f = tm._marching_cubes()
    t1 = time.perf_counter()
    v = project_to_sdf(v, tm.head_sdf, iterations=2)
    v, f = collapse_short_edges(v, f, tm._sizing, tm.head_sdf)
    t2 = time.perf_counter()
    f = flip_edges(v, f)
    v = relax(v, f, tm.head_sdf, iterations=5)
    f = flip_edges(v, f)
    t3 = time.perf_counter()
    total = median_time(build_template, repeats=1, warmup=0)
    print(f"template generation: {total:.2f} s total (marching cubes {t1 - t0:.2f} s, "
          f"decimation {t2 - t1:.2f} s, flips + relaxation {t3 - t2:.2f} s); {len(v)} head vertices")


def bench_lbs(model: HeadModel, T: int) -> None:
    params = random_params(model, T)
    t_np = median_time(lambda: model.forward(params), repeats=5) / T
    Tr = min(T, 10)
    sub = params.select(slice(0, Tr))
    vs = model.shaped_vertices(sub)
    t_ref = median_time(lambda: lbs_reference(vs, model.J_regressor, model.kintree_parents, model.weights,
                                              sub.full_pose, sub.translation, model.posedirs), repeats=3) / Tr
    line = (f"{model.name:12s} V={model.num_vertices:5d}  forward {t_np * 1e3:7.3f} ms/frame (T={T})  "
            f"reference {t_ref * 1e3:7.2f} ms/frame ({t_ref / t_np:5.1f}x slower)")
    try:
        import torch

        with torch.no_grad():
            t_torch = median_time(lambda: model.forward_torch(params), repeats=5) / T
        line += f"  torch {t_torch * 1e3:7.3f} ms/frame ({t_torch / t_np:4.1f}x)"
    except ImportError:
        pass
    print(line)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100, help="frames per batched forward call")
    ap.add_argument("--quick", action="store_true",
                    help="tiny sizes, one repeat: only checks that the script runs")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames = 4
    bench_generation()
    bench_lbs(HeadModel.template(), args.frames)
    bench_lbs(flame_sized_model(), args.frames)


if __name__ == "__main__":
    main()
