"""`KernelCall`: Taichi kernel launches without Taichi's per-call Python work, for kernels
called every frame with new arrays and scalars (the renderer's stages, the hair push-out).

A plain call `kernel(*args)` goes through Taichi's Python launch path: it looks the compiled
instance up from the arguments' types, builds a launch context and hands it each argument
(~0.05 ms of the calling thread per array under load, while the kernel threads wait; a 100k
render's six launches pass ~55 arrays: the calling thread's CPU per frame went 7.3-8.6 ->
4.8-5.0 ms). `KernelCall` looks the instance up once per argument signature (dtypes and
dimensions) and only fills a fresh context per call, as Taichi's `Kernel.launch_kernel` does
for C-contiguous numpy arrays, ints and floats: the same kernel on the same memory, so the
same results (`tests/test_render.py` and `tests/test_sim.py` compare it with the plain call).

A top-level module so that neither user imports the other's package (importing the simulation
package cost ~0.4 s of CPU on a process's first render). It uses Taichi 1.7's Python internals
(the compiled instance, its launch context, `Program.launch_kernel`), which are not public API:
where any of them is missing, or an array is not one Taichi would pass without a copy, the
plain call is used. `avatarkit.sim._launch.BoundLaunch` binds the same buffers once instead.
"""
from __future__ import annotations

import numpy as np


class KernelCall:
    """kernel(*args) through a cached compiled instance (see the module docstring)."""

    def __init__(self, kernel):
        self.kernel = kernel
        self._instances: dict = {}

    def __call__(self, *args) -> None:
        sig = []
        for a in args:
            if isinstance(a, np.ndarray):
                if not a.flags.c_contiguous:
                    self.kernel(*args)
                    return
                sig.append((a.dtype.str, a.ndim))
            else:
                sig.append(type(a))
        key = tuple(sig)
        instance = self._instances.get(key)
        if instance is None:
            try:
                instance = _instance(self.kernel, args)
            except (AttributeError, TypeError, KeyError, IndexError):
                instance = False  # another Taichi: the plain call from now on
            self._instances[key] = instance
        if instance is False:
            self.kernel(*args)
        else:
            instance(args)


def _instance(kernel, args):
    """A launcher of kernel's compiled instance for arguments like args."""
    from taichi.lang import impl
    from taichi.lang.util import cook_dtype
    from taichi.types import primitive_types
    from taichi.types.utils import is_signed

    primal = kernel._primal
    if len(primal.arguments) != len(args):
        raise TypeError(f"kernel takes {len(primal.arguments)} arguments, {len(args)} given")
    key = primal.ensure_compiled(*args)  # compiles on first use, as a plain call would
    kernel_cpp = primal.compiled_kernels[key]
    prog = impl.get_runtime().prog
    compiled = prog.compile_kernel(prog.config(), prog.get_device_caps(), kernel_cpp)
    setters = []
    for arg, a in zip(primal.arguments, args):
        needed = arg.annotation
        if isinstance(a, np.ndarray):
            dtype = needed.dtype
            # Taichi passes an array's shape without the element's own dimensions
            element_dim = 0 if dtype is None or id(dtype) in primitive_types.type_ids else dtype.ndim
            setters.append(("array", element_dim))
        elif id(needed) in primitive_types.integer_type_ids and is_signed(cook_dtype(needed)):
            setters.append(("int", None))
        elif id(needed) in primitive_types.real_type_ids:
            setters.append(("float", None))
        else:
            raise TypeError(f"argument type {needed} is not one KernelCall fills")

    def launch(values):
        ctx = kernel_cpp.make_launch_context()
        for i, ((kind, element_dim), v) in enumerate(zip(setters, values)):
            if kind == "array":
                ctx.set_arg_external_array_with_shape((i,), int(v.ctypes.data), v.nbytes,
                                                      list(v.shape[:v.ndim - element_dim]), 0)
            elif kind == "int":
                ctx.set_arg_int((i,), int(v))
            else:
                ctx.set_arg_float((i,), float(v))
        prog.launch_kernel(compiled, ctx)

    return launch
