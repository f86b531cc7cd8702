#!/usr/bin/env python3
"""Write the standard renderer benchmark scene as a 3DGS PLY plus its camera as JSON.

The scene: N Gaussians (seed 0) filling a 60-degree frustum at depth 2..4 in front of a
pinhole camera at the origin, OpenCV camera axes (x right, y down, z forward), so the
world-to-camera matrix is the identity. Log-normal scales (median 0.01, sigma 0.5), random
unit quaternions, opacity uniform in [0.3, 1], random RGB (SH degree 0).

The same definition as the scene the peer renderers were timed on (the project's bench notes),
kept here so the benchmarks run in a clone with nothing beside it; `render.py` and
`labels3d.py` import it.

Usage: make_scene.py N OUT.ply [--width 512 --height 512]
Writes OUT.ply and OUT.camera.json (fx, fy, cx, cy, width, height, world_to_camera 4x4).
Needs only numpy.
"""
import argparse
import json
import math

import numpy as np

SH_C0 = 0.28209479177387814


def make_scene(n, width, height, seed=0):
    rng = np.random.default_rng(seed)
    fov = math.radians(60.0)
    t = math.tan(fov / 2)
    z = 2.0 + 2.0 * rng.random(n)
    x = (rng.random(n) * 2 - 1) * z * t
    y = (rng.random(n) * 2 - 1) * z * t
    means = np.stack([x, y, z], -1).astype(np.float32)
    scales = (0.01 * np.exp(0.5 * rng.standard_normal((n, 3)))).astype(np.float32)
    q = rng.standard_normal((n, 4))
    quats = (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)  # w x y z
    opacity = (0.3 + 0.7 * rng.random(n)).astype(np.float32)
    rgb = rng.random((n, 3)).astype(np.float32)
    fx = fy = 0.5 * width / t
    camera = dict(fx=fx, fy=fy, cx=width / 2, cy=height / 2, width=width, height=height,
                  world_to_camera=np.eye(4).tolist(), convention="opencv")
    return means, scales, quats, opacity, rgb, camera


def write_ply(path, means, scales, quats, opacity, rgb):
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    n = len(means)
    data = np.zeros((n, len(names)), dtype="<f4")
    data[:, 0:3] = means
    data[:, 6:9] = (rgb - 0.5) / SH_C0
    data[:, 9] = np.log(opacity / (1 - opacity + 1e-7))
    data[:, 10:13] = np.log(scales)
    data[:, 13:17] = quats
    header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % n
    header += "".join("property float %s\n" % name for name in names) + "end_header\n"
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(data.tobytes())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("n", type=int)
    ap.add_argument("out")
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--height", type=int, default=512)
    a = ap.parse_args()
    means, scales, quats, opacity, rgb, camera = make_scene(a.n, a.width, a.height)
    write_ply(a.out, means, scales, quats, opacity, rgb)
    stem = a.out[:-4] if a.out.endswith(".ply") else a.out
    with open(stem + ".camera.json", "w") as f:
        json.dump(camera, f, indent=1)


if __name__ == "__main__":
    main()
