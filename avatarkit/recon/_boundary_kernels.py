"""Taichi CPU kernel of `recon.boundary`: the nearest interior colour of each band pixel.

Imported lazily (after `ensure_taichi()`). Whole-number colours only (the band test's uint8
pixels as float32): every squared distance is then an integer below 2^24, exact in float32
whatever the order or fusing of the arithmetic, so the kernel's minimum is
`boundary._nearest_interior_colour2_loop`'s bit for bit.
"""

import os

from avatarkit._taichi import ensure_taichi

os.environ.setdefault("TI_ENABLE_PYBUF", "0")  # see avatarkit/render/_kernels.py
ti = ensure_taichi()

f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
f32_3 = ti.types.ndarray(dtype=ti.f32, ndim=3)
i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
u8_2 = ti.types.ndarray(dtype=ti.u8, ndim=2)

#: what a pixel with no interior pixel in reach gets (the caller makes it inf)
NONE = 1e30


@ti.kernel
def nearest_interior(ys: i32_1, xs: i32_1, f: f32_3, interior: u8_2, reach: ti.i32, best: f32_1):
    """best[i] = min |f[ys[i], xs[i]] - f[y, x]|^2 over the interior (non-zero) pixels (y, x)
    with (y - ys[i])^2 + (x - xs[i])^2 <= reach^2; NONE where there is none."""
    h = interior.shape[0]
    w = interior.shape[1]
    for i in range(ys.shape[0]):
        y = ys[i]
        x = xs[i]
        c0 = f[y, x, 0]
        c1 = f[y, x, 1]
        c2 = f[y, x, 2]
        b = ti.cast(NONE, ti.f32)
        for j in range(2 * reach + 1):
            dy = j - reach
            y2 = y + dy
            if 0 <= y2 < h:
                for k in range(2 * reach + 1):
                    dx = k - reach
                    x2 = x + dx
                    if dx * dx + dy * dy <= reach * reach and 0 <= x2 < w:
                        if interior[y2, x2] != 0:
                            e0 = c0 - f[y2, x2, 0]
                            e1 = c1 - f[y2, x2, 1]
                            e2 = c2 - f[y2, x2, 2]
                            b = ti.min(b, e0 * e0 + e1 * e1 + e2 * e2)
        best[i] = b
