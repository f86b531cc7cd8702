"""avatarkit._taichi: kernels decorated while a module imports do not walk `sys.modules`."""
import importlib
import inspect
import sys

import numpy as np


def test_kernel_decoration_during_import_reads_no_module_list(tmp_path, monkeypatch):
    """Taichi's `_inside_class` asks inspect for the source line of importlib's frame; once
    `ensure_taichi` has told inspect which module "<frozen importlib._bootstrap>" is, that costs
    no walk over sys.modules (the walk was ~20-30 ms a kernel with torch loaded), and kernels
    decorated at a module's top level and inside a class still work as before."""
    from avatarkit._taichi import ensure_taichi

    ti = ensure_taichi()
    walked = []
    real_ismodule = inspect.ismodule
    monkeypatch.setattr(inspect, "ismodule", lambda obj: walked.append(1) or real_ismodule(obj))
    top = "".join(f"@ti.kernel\ndef times{k}(a: ti.types.ndarray(dtype=ti.f32, ndim=1)):\n"
                  f"    for i in a:\n        a[i] = {k} * a[i]\n" for k in range(2, 8))
    (tmp_path / "ak_kernels_probe.py").write_text(
        "import taichi as ti\n" + top +
        "@ti.data_oriented\n"
        "class Scaled:\n"
        "    def __init__(self, k):\n"
        "        self.k = k\n"
        "    @ti.kernel\n"
        "    def apply(self, a: ti.types.ndarray(dtype=ti.f32, ndim=1)):\n"
        "        for i in a:\n"
        "            a[i] = self.k * a[i]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    probe = importlib.import_module("ak_kernels_probe")
    try:
        # a walk is one call per loaded module: two for the new file's own class body (as
        # before), and without the fix two more per top-level kernel (importlib's frame, not
        # found, twice): 19 walks here without it (measured), 2 with it
        assert len(walked) <= 4 * len(sys.modules), (len(walked), len(sys.modules))
        monkeypatch.setattr(inspect, "ismodule", real_ismodule)
        a = np.arange(4, dtype=np.float32)
        probe.times2(a)
        probe.Scaled(3.0).apply(a)
        np.testing.assert_array_equal(a, [0, 6, 12, 18])
    finally:
        sys.modules.pop("ak_kernels_probe", None)
