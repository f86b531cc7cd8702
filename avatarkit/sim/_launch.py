"""Taichi kernel launches without Taichi's per-call Python work, for kernels launched every
frame: `BoundLaunch` (the same buffers every time: the XPBD frame kernel) and `KernelCall`
(new arrays and scalars each call: the push-out).

A plain call `kernel(*arrays)` goes through Taichi's Python launch path: it looks the kernel
instance up from the arguments' types, builds a launch context and hands it each array's
address and shape. For the XPBD frame kernel and its 5 arrays that measured ~0.16-0.20 ms of CPU
a launch under load, against ~5 us for the launch itself (`benchmarks/sim.py`'s figures).
Bound here, the context is built once and only the launch runs per call; the kernel writes the
same memory as the plain call, so results are identical (`tests/test_sim.py`). `KernelCall`
fills a fresh context per call from its arguments (a few us), the instance looked up once; it
lives in `avatarkit._kernel_call`, shared with the renderer.

This uses Taichi 1.7's Python internals (the compiled kernel instance, its launch context,
`Program.launch_kernel`), which are not public API: where any of them is missing, or an array
is not one Taichi would pass without a copy (C-contiguous numpy), the plain call is used.
The arrays must keep their memory while bound: the instance holds them, and callers rebind
when they replace one (`XPBDSolver` checks the identity of each per step).
"""
from __future__ import annotations

import numpy as np

from avatarkit._kernel_call import KernelCall  # noqa: F401  (the push-out imports it from here)


class BoundLaunch:
    """kernel(*arrays) as a call without arguments. `fast` tells whether the bound path is
    used (False: Taichi's plain call, for a Taichi without the internals used here, or with
    bind=False: the benchmark's baseline)."""

    def __init__(self, kernel, *arrays: np.ndarray, bind: bool = True):
        self.kernel = kernel
        self.arrays = arrays
        self._launch = None
        if bind and all(isinstance(a, np.ndarray) and a.flags.c_contiguous for a in arrays):
            try:
                self._launch = _bind(kernel, arrays)
            except (AttributeError, TypeError, KeyError, IndexError):
                self._launch = None  # another Taichi: the plain call below

    @property
    def fast(self) -> bool:
        return self._launch is not None

    def __call__(self) -> None:
        if self._launch is None:
            self.kernel(*self.arrays)
        else:
            self._launch()

    def binds(self, *arrays: np.ndarray) -> bool:
        """Are these the very arrays bound (the same objects, in order)?"""
        return len(arrays) == len(self.arrays) and all(a is b for a, b in zip(arrays, self.arrays))


def _bind(kernel, arrays):
    """The launch of Taichi's `Kernel.launch_kernel` with the context filled once: each array's
    address, byte size and shape without the element's own dimensions (as Taichi's
    `set_arg_ext_array` strips them)."""
    from taichi.lang import impl
    from taichi.types import primitive_types

    primal = kernel._primal
    key = primal.ensure_compiled(*arrays)  # compiles on first use, as a plain call would
    kernel_cpp = primal.compiled_kernels[key]
    prog = impl.get_runtime().prog
    compiled = prog.compile_kernel(prog.config(), prog.get_device_caps(), kernel_cpp)
    ctx = kernel_cpp.make_launch_context()
    if len(primal.arguments) != len(arrays):
        raise TypeError(f"kernel takes {len(primal.arguments)} arguments, {len(arrays)} bound")
    for i, (arg, a) in enumerate(zip(primal.arguments, arrays)):
        dtype = arg.annotation.dtype
        element_dim = 0 if dtype is None or id(dtype) in primitive_types.type_ids else dtype.ndim
        shape = a.shape[:a.ndim - element_dim]
        ctx.set_arg_external_array_with_shape((i,), int(a.ctypes.data), a.nbytes, list(shape), 0)

    def launch():
        prog.launch_kernel(compiled, ctx)

    return launch
