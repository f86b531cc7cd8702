"""The Taichi kernel behind `read_ply`'s fast path (imported lazily: importing this starts Taichi).

One parallel pass over the file's rows does what the numpy reference in `ply.py` does in a dozen
passes: copy out positions and SH (transposing `f_rest` from channel-major to coefficient-major),
activate scales and opacity, normalise quaternions and check every value. Each row is read from
memory once, which is what brings a 1M-splat read close to the cost of `np.fromfile`.

The arithmetic mirrors the reference in float64 (`exp`, the sigmoid and the quaternion norm), so
both paths give the same float32 bits; `tests/test_ply_kernel.py` holds them to it.
"""

import numpy as np

from avatarkit._taichi import ensure_taichi

ti = ensure_taichi()

f64 = ti.f64
nd_f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
nd_i64_1 = ti.types.ndarray(dtype=ti.i64, ndim=1)

#: float32 exponent bits: all set means inf or NaN. Tested on the bits because Taichi compiles
#: with fast math, under which LLVM may fold `x != x` and comparisons with inf away.
EXP_MASK = 0x7F800000
#: float32's smallest normal number. Taichi's worker threads, which run this parallel loop,
#: flush subnormals to zero (inputs and results), so rows whose arithmetic meets a float32
#: subnormal are flagged for the numpy reference, which keeps them (real files hold no such
#: values; copies are bit moves and unaffected).
FLT_MIN = float(np.finfo(np.float32).tiny)
#: a quaternion this close to unit norm keeps its bits (as `ply._normalize_quats` does)
UNIT_SLACK = 4 * float(np.finfo(np.float32).eps)


@ti.kernel
def decode_rows(src: nd_f32_1, stride: ti.i32, lo: ti.template(), hi: ti.template(),
                pos: ti.template(), dc: ti.template(), rest: ti.template(),
                opacity: ti.template(), scale: ti.template(), rot: ti.template(), K: ti.template(),
                means: nd_f32_1, quats: nd_f32_1, scales: nd_f32_1, opacities: nd_f32_1,
                sh: nd_f32_1, first_bad: nd_i64_1):
    """src: the vertex rows as float32 words, `stride` words a row; pos/dc/... the word offset
    of each property group within a row, all inside words [lo, hi). Outputs are flat views of
    (N,3) means, (N,4) quats, (N,3) scales, (N,) opacities and (N,K,3) sh. `first_bad[0]`
    (preset to N) drops to the lowest row with a non-finite word in [lo, hi) or a scale that
    float32 cannot hold once exponentiated; the caller then lets the reference path name the
    problem (or, for a NaN normal between the groups or a subnormal (see FLT_MIN), find
    nothing wrong)."""
    for i in range(opacities.shape[0]):
        s = i * stride
        # One plain loop over the row's words: LLVM vectorises it, where a check beside each
        # copy below stayed scalar and cost a quarter of the kernel.
        worst = 0  # the largest exponent field in the row
        for j in range(lo, hi):
            worst = ti.max(worst, ti.bit_cast(src[s + j], ti.i32) & EXP_MASK)
        for j in ti.static(range(3)):
            means[i * 3 + j] = src[s + pos + j]
            sh[i * 3 * K + j] = src[s + dc + j]
        for c in ti.static(range(3)):
            for k in ti.static(range(K - 1)):  # channel-major on disk, coefficient-major here
                sh[i * 3 * K + 3 * (k + 1) + c] = src[s + rest + c * (K - 1) + k]
        o = 1.0 / (1.0 + ti.exp(-ti.cast(src[s + opacity], f64)))
        opacities[i] = ti.cast(o, ti.f32)
        if o != 0.0 and o < FLT_MIN:  # a float32 subnormal, which this kernel would flush
            worst = EXP_MASK
        for j in ti.static(range(3)):
            e = ti.cast(ti.exp(ti.cast(src[s + scale + j], f64)), ti.f32)
            scales[i * 3 + j] = e
            bits = ti.bit_cast(e, ti.i32)
            # exp underflowed to 0 or a subnormal (flushed or not, depending on the thread's
            # FP mode: flag both so the outcome does not) or overflowed to inf
            if bits & EXP_MASK == 0 or bits == EXP_MASK:
                worst = EXP_MASK
        w, x, y, z = src[s + rot], src[s + rot + 1], src[s + rot + 2], src[s + rot + 3]
        for j in ti.static(range(4)):
            bits = ti.bit_cast(src[s + rot + j], ti.i32)
            if bits & EXP_MASK == 0 and bits & 0x7FFFFFFF != 0:  # subnormal: read as zero here
                worst = EXP_MASK
        wd, xd, yd, zd = ti.cast(w, f64), ti.cast(x, f64), ti.cast(y, f64), ti.cast(z, f64)
        norm = ti.sqrt(wd * wd + xd * xd + yd * yd + zd * zd)
        if ti.abs(norm - 1.0) > UNIT_SLACK:
            if norm == 0.0:
                w, x, y, z = 1.0, 0.0, 0.0, 0.0
            else:
                w, x, y, z = (ti.cast(wd / norm, ti.f32), ti.cast(xd / norm, ti.f32),
                              ti.cast(yd / norm, ti.f32), ti.cast(zd / norm, ti.f32))
        quats[i * 4 + 0] = w
        quats[i * 4 + 1] = x
        quats[i * 4 + 2] = y
        quats[i * 4 + 3] = z
        if worst == EXP_MASK:
            ti.atomic_min(first_bad[0], i)


def decode(words: np.ndarray, stride: int, offsets: dict, k: int):
    """words: (N*stride,) float32 rows; offsets: word offset of 'pos', 'dc', 'rest', 'opacity',
    'scale', 'rot' and the span 'lo'..'hi' holding them; k: SH coefficients per channel.
    -> (means, quats, scales, opacities, sh, first_bad), first_bad == N when every row is valid."""
    n = len(words) // stride
    means = np.empty((n, 3), np.float32)
    quats = np.empty((n, 4), np.float32)
    scales = np.empty((n, 3), np.float32)
    opacities = np.empty(n, np.float32)
    sh = np.empty((n, k, 3), np.float32)
    first_bad = np.full(1, n, np.int64)
    if n:
        decode_rows(words, stride, *(offsets[key] for key in ("lo", "hi", "pos", "dc", "rest",
                                                              "opacity", "scale", "rot")), k,
                    means.reshape(-1), quats.reshape(-1), scales.reshape(-1), opacities,
                    sh.reshape(-1), first_bad)
    return means, quats, scales, opacities, sh, int(first_bad[0])
