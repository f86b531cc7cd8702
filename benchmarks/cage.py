"""Cage benchmark: cage build, MVC weights and per-frame deformation on synthetic long hair.

    .venv/bin/python benchmarks/cage.py                 # 50k and 200k Gaussians
    .venv/bin/python benchmarks/cage.py --sizes 50000   # just one size

Figures (wall clock, median of repeats after a warm-up; the machine is shared, so compare the
ratios printed beside each figure, which come from baselines run in the same process):
 - cage build time (~500 vertices);
 - MVC weight time for the principal-axis method (2 points per Gaussian), and the ns per
   point-face pair of a batched PyTorch implementation of the same formula run here on a
   subset (the peer figure in shared/bench/README.md is ~474 ns);
 - per-frame deformation as the bake does it: `deform_batch` with `bake.HAIR_BATCH` (16) frames
   per product, wall and CPU ms per frame, against the single-frame path (`deform_arrays`, one
   product per frame) as the baseline ratio; the product alone, the plain numpy `W @ V` in
   row-major layout, the memory floor bytes(W) / read bandwidth (bandwidth measured with a
   large numpy sum), and top-32/64 sparse weights with their position error.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402
from _timing import median_time  # noqa: E402

from avatarkit.cage import (CageDeformer, build_cage, deformation_points, mvc_weights,  # noqa: E402
                            sparse_apply, sparse_error, sparsify)
from avatarkit.bake import HAIR_BATCH  # noqa: E402
from avatarkit.synthetic import make_hair  # noqa: E402


def median_wall_cpu(fn, repeats: int = 3, warmup: int = 1) -> tuple[float, float]:
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return float(np.median(wall)), float(np.median(cpu))



def read_bandwidth() -> float:
    """Bytes per second of a large streaming read (numpy sum of 512 MB of float32)."""
    a = np.ones(128 * 1024 * 1024, np.float32)
    t = median_time(lambda: a.sum(), repeats=5)
    return a.nbytes / t


def torch_mvc_ns_per_pair(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> float:
    """The peer: Ju et al.'s formula batched over points x faces in PyTorch (float32, 2 threads)."""
    import torch

    torch.set_num_threads(2)
    x = torch.from_numpy(points.astype(np.float32))
    v = torch.from_numpy(vertices.astype(np.float32))
    f = torch.from_numpy(faces.astype(np.int64))

    def run(batch: int = 256):
        out = []
        for s in range(0, len(x), batch):
            xb = x[s:s + batch]
            rel = v[None] - xb[:, None]                              # (B, C, 3)
            d = rel.norm(dim=2)
            u = rel / d[..., None]
            uf = u[:, f]                                             # (B, M, 3, 3)
            df = d[:, f]
            l = torch.stack([(uf[:, :, (i + 1) % 3] - uf[:, :, (i + 2) % 3]).norm(dim=2) for i in range(3)], 2)
            th = 2 * torch.asin(torch.clamp(l / 2, max=1.0))
            h = th.sum(2) / 2
            sin_t = torch.sin(th)
            c = torch.stack([2 * torch.sin(h) * torch.sin(h - th[..., i])
                             / (sin_t[..., (i + 1) % 3] * sin_t[..., (i + 2) % 3]) - 1 for i in range(3)], 2)
            det = torch.linalg.det(uf)
            sgn = torch.sign(det)[..., None]
            sv = sgn * torch.sqrt(torch.clamp(1 - c * c, min=0))
            w = torch.stack([(th[..., i] - c[..., (i + 1) % 3] * th[..., (i + 2) % 3]
                              - c[..., (i + 2) % 3] * th[..., (i + 1) % 3])
                             / (df[..., i] * sin_t[..., (i + 1) % 3] * sv[..., (i + 2) % 3]) for i in range(3)], 2)
            acc = torch.zeros(len(xb), len(v))
            acc.scatter_add_(1, f.reshape(1, -1).expand(len(xb), -1), w.reshape(len(xb), -1))
            out.append(acc / acc.sum(1, keepdim=True))
        return torch.cat(out)

    t = median_time(run, repeats=3)
    return t / (len(points) * len(faces)) * 1e9


def bench(n: int, bandwidth: float, peer_points: int) -> None:
    print(f"\n== {n} Gaussians (synthetic long_straight hair)")
    hair = make_hair("long_straight", n=n, seed=0)
    t = time.perf_counter()
    cage = build_cage(hair)
    t_cage = time.perf_counter() - t
    print(f"cage build: {t_cage:.2f} s -> {cage.n_vertices} vertices, {len(cage.faces)} faces "
          f"(attempt {cage.info['attempt']}, cell {cage.info['cell_size'] * 100:.1f} cm)")

    points = deformation_points(hair, "principal_axis")
    mvc_weights(points[:64], cage.vertices, cage.faces)  # compile / load the kernel
    t, cpu = time.perf_counter(), time.process_time()
    deformer = CageDeformer.build(hair, cage)
    t_mvc, cpu_mvc = time.perf_counter() - t, time.process_time() - cpu
    pairs = len(points) * len(cage.faces)
    ours = t_mvc / pairs * 1e9
    print(f"MVC weights (principal axis, {len(points)} points x {len(cage.faces)} faces): {t_mvc:.2f} s "
          f"= {ours:.1f} ns per point-face pair (target <= 5 s for 50k Gaussians); CPU time "
          f"{cpu_mvc:.2f} s = {cpu_mvc / pairs * 1e9:.1f} ns per pair per core "
          f"(so {cpu_mvc / 2:.2f} s on 2 idle cores)")
    if peer_points:
        rng = np.random.default_rng(0)
        subset = points[rng.choice(len(points), min(peer_points, len(points)), replace=False)]
        peer = torch_mvc_ns_per_pair(subset, cage.vertices, cage.faces)
        print(f"  peer (batched PyTorch, same formula, {len(subset)} points): {peer:.0f} ns per pair "
              f"-> ours is {peer / ours:.1f}x faster; peer for all points: {peer * pairs / 1e9:.1f} s")

    v = cage.vertices + np.float32(0.01) * np.sin(cage.vertices * 9).astype(np.float32)
    w_bytes = deformer.weights_t.nbytes
    floor = w_bytes / bandwidth
    t_prod = median_time(lambda: deformer.deformed_points(v), repeats=15)
    t_arrays = median_time(lambda: deformer.deform_arrays(v), repeats=15)
    t_set = median_time(lambda: deformer.deform(v), repeats=7)
    w_rowmajor = np.ascontiguousarray(deformer.weights)
    t_base = median_time(lambda: w_rowmajor @ v, repeats=7)
    del w_rowmajor
    frames = np.stack([v + np.float32(0.001 * i) for i in range(2 * HAIR_BATCH)])
    b_wall, b_cpu = median_wall_cpu(lambda: list(deformer.deform_batch(frames, chunk=HAIR_BATCH)))
    s_wall, s_cpu = median_wall_cpu(lambda: [deformer.deform_arrays(f) for f in frames])
    b_wall, b_cpu, s_wall, s_cpu = (x / len(frames) for x in (b_wall, b_cpu, s_wall, s_cpu))
    print(f"per frame, the bake's path (deform_batch, {HAIR_BATCH} frames per product): {b_wall * 1e3:.1f} ms "
          f"wall / {b_cpu * 1e3:.1f} ms CPU (target <= 10 ms for 50k); baseline one product per frame "
          f"(deform_arrays): {s_wall * 1e3:.1f} ms wall / {s_cpu * 1e3:.1f} ms CPU "
          f"({s_wall / b_wall:.1f}x wall, {s_cpu / b_cpu:.1f}x CPU)")
    print(f"  single frame: product {t_prod * 1e3:.1f} ms, deform_arrays {t_arrays * 1e3:.1f} ms, "
          f"deform -> GaussianSet {t_set * 1e3:.1f} ms")
    print(f"  memory floor bytes(W) / bandwidth = {w_bytes / 1e6:.0f} MB / {bandwidth / 1e9:.1f} GB/s "
          f"= {floor * 1e3:.1f} ms (product at {floor / t_prod:.0%} of the floor's speed)")
    print(f"  baseline numpy W @ V, row-major W: {t_base * 1e3:.1f} ms "
          f"(our layout {t_base / t_prod:.2f}x faster)")
    if n > 100_000:  # the top-k selection needs several P x C temporaries: skip when huge
        return
    dense = deformer.deformed_points(v).T.astype(np.float64)
    for k in (32, 64):
        plain = sparsify(deformer.weights, k)
        exact = sparsify(deformer.weights, k, points=points, cage_vertices=cage.vertices)
        t_sparse = median_time(lambda: sparse_apply(*exact, v), repeats=3)
        e_rest = sparse_error(*plain, cage.vertices, points)
        e_plain = sparse_error(*plain, v, dense)
        e_exact = sparse_error(*exact, v, dense)
        print(f"  top-{k} sparse weights ({sparse_apply.__name__}, numpy gather: {t_sparse * 1e3:.0f} ms): "
              f"renormalised: rest error mean {e_rest.mean_error * 1e3:.2f} mm; vs dense on a bent cage "
              f"mean {e_plain.mean_error * 1e3:.2f} / max {e_plain.max_error * 1e3:.2f} mm; "
              f"with linear precision: mean {e_exact.mean_error * 1e3:.3f} / max {e_exact.max_error * 1e3:.3f} mm")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[50_000, 200_000])
    parser.add_argument("--peer-points", type=int, default=1000,
                        help="points for the PyTorch peer timing (0: skip)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes, one repeat: only checks that the script runs")
    args = parser.parse_args()
    if args.quick:
        args.sizes, args.peer_points = [2000], 50
    bandwidth = read_bandwidth()
    print(f"read bandwidth (numpy sum of 512 MB): {bandwidth / 1e9:.1f} GB/s; cores: {os.cpu_count()}")
    for n in args.sizes:
        bench(n, bandwidth, args.peer_points)


if __name__ == "__main__":
    main()
