"""`binding_to_world(binding, vertices)`: the bald Gaussians' triangle-local values -> world for
one mesh pose, as one fused Taichi kernel (float64 inside). The slow, obvious reference is
`TriangleBinding.to_world` (rig.binding); tests/test_bake.py compares them.
"""
# no `from __future__ import annotations`: Taichi evaluates the kernel's annotations
import functools

import numpy as np

from avatarkit.errors import InputError


@functools.cache
def _binding_kernel():
    """A fused Taichi kernel of `TriangleBinding.to_world` (means, quats, scales only)."""
    from avatarkit._taichi import ensure_taichi
    from avatarkit.rig.frames import MIN_EDGE, MIN_RELATIVE_HEIGHT

    ti = ensure_taichi()
    f64 = ti.f64

    @ti.kernel
    def to_world(verts: ti.types.ndarray(dtype=ti.f32, ndim=2), faces: ti.types.ndarray(dtype=ti.i32, ndim=2),
                 face_ids: ti.types.ndarray(dtype=ti.i32, ndim=1),
                 local_means: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 local_quats: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 local_scales: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 means: ti.types.ndarray(dtype=ti.f32, ndim=2), quats: ti.types.ndarray(dtype=ti.f32, ndim=2),
                 scales: ti.types.ndarray(dtype=ti.f32, ndim=2), bad: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        # float64 inside, like the reference (rig.frames / rig.binding)
        for i in range(face_ids.shape[0]):
            f = face_ids[i]
            a = ti.Vector([verts[faces[f, 0], 0], verts[faces[f, 0], 1], verts[faces[f, 0], 2]], dt=f64)
            b = ti.Vector([verts[faces[f, 1], 0], verts[faces[f, 1], 1], verts[faces[f, 1], 2]], dt=f64)
            c = ti.Vector([verts[faces[f, 2], 0], verts[faces[f, 2], 1], verts[faces[f, 2], 2]], dt=f64)
            d1 = b - a
            d2 = c - a
            len0 = d1.norm()
            e0 = d1 / ti.max(len0, MIN_EDGE)
            nraw = e0.cross(d2)
            height = nraw.norm()
            if len0 <= MIN_EDGE or height <= MIN_RELATIVE_HEIGHT * len0:
                bad[0] = f + 1
            n = nraw / ti.max(height, 1e-300)
            bb = e0.cross(n)
            k = 0.5 * (len0 + height)
            t = (a + b + c) / 3.0
            lm = ti.Vector([local_means[i, 0], local_means[i, 1], local_means[i, 2]], dt=f64)
            mu = k * (e0 * lm[0] + n * lm[1] + bb * lm[2]) + t
            # R = [e0 | n | bb] (columns) -> quaternion, Shepperd's method as rotations.matrix_to_quat
            m00, m01, m02 = e0[0], n[0], bb[0]
            m10, m11, m12 = e0[1], n[1], bb[1]
            m20, m21, m22 = e0[2], n[2], bb[2]
            tr = m00 + m11 + m22
            qw, qx, qy, qz = ti.f64(1.0), ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
            if tr >= m00 and tr >= m11 and tr >= m22:
                r = ti.sqrt(1.0 + tr) * 2.0
                qw, qx, qy, qz = 0.25 * r, (m21 - m12) / r, (m02 - m20) / r, (m10 - m01) / r
            elif m00 >= m11 and m00 >= m22:
                r = ti.sqrt(1.0 + m00 - m11 - m22) * 2.0
                qw, qx, qy, qz = (m21 - m12) / r, 0.25 * r, (m01 + m10) / r, (m02 + m20) / r
            elif m11 >= m22:
                r = ti.sqrt(1.0 + m11 - m00 - m22) * 2.0
                qw, qx, qy, qz = (m02 - m20) / r, (m01 + m10) / r, 0.25 * r, (m12 + m21) / r
            else:
                r = ti.sqrt(1.0 + m22 - m00 - m11) * 2.0
                qw, qx, qy, qz = (m10 - m01) / r, (m02 + m20) / r, (m12 + m21) / r, 0.25 * r
            if qw < 0:
                qw, qx, qy, qz = -qw, -qx, -qy, -qz
            lw, lx, ly, lz = (ti.cast(local_quats[i, 0], f64), ti.cast(local_quats[i, 1], f64),
                              ti.cast(local_quats[i, 2], f64), ti.cast(local_quats[i, 3], f64))
            w = qw * lw - qx * lx - qy * ly - qz * lz
            x = qw * lx + qx * lw + qy * lz - qz * ly
            y = qw * ly - qx * lz + qy * lw + qz * lx
            z = qw * lz + qx * ly - qy * lx + qz * lw
            norm = ti.sqrt(w * w + x * x + y * y + z * z)
            for j in ti.static(range(3)):
                means[i, j] = ti.cast(mu[j], ti.f32)
                scales[i, j] = ti.cast(k * local_scales[i, j], ti.f32)
            quats[i, 0] = ti.cast(w / norm, ti.f32)
            quats[i, 1] = ti.cast(x / norm, ti.f32)
            quats[i, 2] = ti.cast(y / norm, ti.f32)
            quats[i, 3] = ti.cast(z / norm, ti.f32)

    return to_world


def binding_to_world(binding, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fast `TriangleBinding.to_world` for one mesh pose: vertices (V, 3) -> means (N, 3),
    quats (N, 4) wxyz, scales (N, 3), float32. InputError if a host triangle collapsed."""
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"vertices must have shape (V, 3), got {v.shape}")
    if not np.isfinite(v).all():
        raise InputError("vertices contain non-finite values")
    n = len(binding)
    means = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    scales = np.empty((n, 3), np.float32)
    bad = np.zeros(1, np.int32)
    if n:
        local = binding.local
        _binding_kernel()(v, binding.faces, binding.face_ids, local.means, local.quats, local.scales,
                          means, quats, scales, bad)
    if bad[0]:
        raise InputError(f"triangle {int(bad[0]) - 1} collapsed (zero area); its Gaussians have no frame")
    return means, quats, scales


__all__ = ["binding_to_world"]
