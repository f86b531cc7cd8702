"""recon.background.Background: a function on a second thread, its value or its exception."""
import threading

import pytest

from avatarkit.recon.background import Background


def test_background_returns_the_value_computed_on_another_thread():
    seen = {}

    def work(a, b=0):
        seen["thread"] = threading.current_thread()
        return a * 10 + b

    job = Background(work, 4, b=2)
    assert job.result() == 42 and job.result() == 42
    assert seen["thread"] is not threading.current_thread() and seen["thread"].daemon


def test_background_raises_the_exception_in_the_caller():
    def broken():
        raise ValueError("spacing must be > 0")

    job = Background(broken)
    with pytest.raises(ValueError, match="spacing"):
        job.result()


def test_closest_points_split_over_two_threads_is_the_one_thread_answer():
    import numpy as np

    from avatarkit.head.io import load_head_model
    from avatarkit.recon import mesh_distance

    model = load_head_model(None)
    v = model.v_template.astype(np.float64)
    rng = np.random.default_rng(3)
    # points on, inside and 2 cm off the head (the hair's range), more than PARALLEL_POINTS
    n = mesh_distance.PARALLEL_POINTS + 901
    p = v[rng.integers(0, len(v), n)] + rng.normal(0.0, 0.01, (n, 3))
    one = mesh_distance.closest_points(p, v, model.faces, threads=1)
    two = mesh_distance.closest_points(p, v, model.faces)
    for a, b in zip(one, two):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    # fewer points than that stay on one thread and still answer; none gives empty arrays
    few = mesh_distance.closest_points(p[:10], v, model.faces)
    np.testing.assert_array_equal(few[0], one[0][:10])
    assert [len(x) for x in mesh_distance.closest_points(p[:0], v, model.faces)] == [0, 0, 0, 0]


def test_build_preload_imports_torch_and_taichi_off_the_main_thread():
    """The build's head start (`pipeline._preload`) in a fresh process: run on a second thread
    it leaves torch and Taichi imported (Taichi not started, our interrupt-safe `_inside_class`
    in place) and prints nothing."""
    import subprocess
    import sys

    code = (
        "import sys, threading\n"
        "from avatarkit.recon.pipeline import _preload\n"
        "t = threading.Thread(target=_preload); t.start(); t.join()\n"
        "import avatarkit._taichi as at\n"
        "from taichi.lang import kernel_impl\n"
        "print('torch' in sys.modules, at.taichi_running(), getattr(kernel_impl._inside_class, '_avatarkit', False))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "True False True\n"
