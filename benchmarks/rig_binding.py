"""Triangle binding speed: nearest-face binding and posing 50k Gaussians on a ~20k-triangle mesh.

Prints seconds for each stage and ratios to simple baselines run in the same process:
brute-force nearest face (every point against every triangle, vectorised numpy) and a
per-Gaussian Python loop for posing, both timed on a subset and scaled up linearly.
Usage: python benchmarks/rig_binding.py [N_GAUSSIANS] [--quick]
"""
from __future__ import annotations

import sys
import time

import numpy as np
import trimesh

from avatarkit.gaussians import GaussianSet
from avatarkit.rig import TriangleBinding, nearest_faces, point_triangle_distance, triangle_frames


def best_of(fn, repeat=3):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def scene(n: int, sh_degree: int):
    m = trimesh.creation.icosphere(subdivisions=5, radius=0.1)  # 20,480 triangles
    rng = np.random.default_rng(0)
    v = m.vertices * (1 + 0.005 * rng.uniform(-1, 1, (len(m.vertices), 1)))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    q = rng.normal(size=(n, 4))
    g = GaussianSet(d * 0.1 + rng.normal(scale=0.003, size=(n, 3)), q / np.linalg.norm(q, axis=1, keepdims=True),
                    np.exp(rng.normal(-6, 0.5, (n, 3))), rng.uniform(0, 1, n),
                    rng.normal(scale=0.3, size=(n, (sh_degree + 1) ** 2, 3)))
    return v, np.asarray(m.faces), g


def brute_nearest(points, v, f):
    tri = v[f]
    out = np.empty(len(points), np.int64)
    for i, p in enumerate(points):  # one point at a time against all triangles (vectorised)
        out[i] = np.argmin(point_triangle_distance(np.broadcast_to(p, (len(f), 3)), tri))
    return out


def loop_to_world(b: TriangleBinding, v, count: int):
    t, r, k = triangle_frames(v, b.faces)
    out = []
    for i in range(count):
        f = b.face_ids[i]
        out.append(k[f] * r[f] @ b.local_means[i] + t[f])
    return out


def main():
    args = [a for a in sys.argv[1:] if a != "--quick"]
    n = 2000 if "--quick" in sys.argv[1:] else int(args[0]) if args else 50_000
    v, f, g0 = scene(n, 0)
    _, _, g3 = scene(n, 3)
    print(f"rig binding benchmark: {n} Gaussians, {len(f)} triangles (noisy shared 2-core box: compare ratios)")

    t_near, _ = best_of(lambda: nearest_faces(g0.means, v, f), 2)
    sub = 200
    t_brute, _ = best_of(lambda: brute_nearest(g0.means[:sub], v, f), 1)
    t_brute *= n / sub
    print(f"  nearest face           {t_near:8.3f} s   brute force (extrapolated) {t_brute:8.1f} s   "
          f"x{t_brute / t_near:.0f}")

    t_bind0, b0 = best_of(lambda: TriangleBinding.bind(g0, v, f), 2)
    t_bind3, b3 = best_of(lambda: TriangleBinding.bind(g3, v, f), 2)
    print(f"  bind (SH degree 0 / 3) {t_bind0:8.3f} s / {t_bind3:.3f} s")

    rng = np.random.default_rng(1)
    pose = v + rng.normal(scale=0.001, size=v.shape)
    t_w0, _ = best_of(lambda: b0.to_world(pose))
    t_w3, _ = best_of(lambda: b3.to_world(pose))
    sub = 2000
    t_loop, _ = best_of(lambda: loop_to_world(b0, pose, sub), 1)
    t_loop *= n / sub
    print(f"  to_world one frame     {t_w0 * 1e3:8.1f} ms (SH 0)  {t_w3 * 1e3:.1f} ms (SH 3)   "
          f"per-Gaussian loop (means only, extrapolated) {t_loop * 1e3:.0f} ms   x{t_loop / t_w0:.0f}")

    frames = pose[None] + rng.normal(scale=0.001, size=(30,) + v.shape)
    t_batch, _ = best_of(lambda: b0.to_world(frames), 1)
    print(f"  to_world batched       {t_batch / 30 * 1e3:8.1f} ms per frame (30 frames, arrays only)")


if __name__ == "__main__":
    main()
