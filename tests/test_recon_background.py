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
