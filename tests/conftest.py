"""Shared test configuration: fixed seeds, the NumPy-only lane (``--numpy-only``) and the
compiled passes' preparation state (``no_compile``, ``slow_compile``)."""

import os
import sys
import threading
import time

import numpy as np
import pytest

# The numba passes' background compile (sss_addon.precompile.start_background) is off
# in every test and in the processes they start, unless a test turns it on: when the
# cache is not stamped complete yet, a job would otherwise start one and log two more
# lines depending on which tests ran before it.
os.environ["CVSSS_BACKGROUND_COMPILE"] = "0"


def pytest_addoption(parser):
    parser.addoption(
        "--numpy-only",
        action="store_true",
        help="run as where numba has no wheel (Windows on ARM): numba and llvmlite cannot "
        "be imported, so the core runs on NumPy and tests that need numba skip",
    )


class _NoNumba:
    """An import hook that refuses numba and llvmlite, as a platform without their wheels."""

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("numba", "llvmlite"):
            raise ModuleNotFoundError(f"No module named {name!r} (--numpy-only)", name=name)
        return None


def pytest_configure(config):
    if config.getoption("--numpy-only"):
        if any(name.split(".")[0] in ("numba", "llvmlite") for name in sys.modules):
            raise pytest.UsageError("--numpy-only: numba was imported before the tests")
        sys.meta_path.insert(0, _NoNumba())


@pytest.fixture
def rng():
    """A fixed-seed generator; tests never use the global RNG."""
    return np.random.default_rng(12345)


# -- the numba passes' preparation (sss_addon.precompile) ---------------------------
@pytest.fixture
def no_compile():
    """No kernels prepared in this process yet, no background compile started (the module's
    state is per process)."""
    from cvsss.sss_addon import precompile

    saved, background = dict(precompile._state), dict(precompile._background)
    precompile._state.clear()
    precompile._background.clear()
    yield precompile._state
    precompile.stop_background()
    precompile._state.clear()
    precompile._state.update(saved)
    precompile._background.clear()
    precompile._background.update(background)


@pytest.fixture
def slow_compile(monkeypatch):
    """``slow_compile(seconds, error=None)``: compiling the passes becomes a sleep (then
    raises ``error``); returns the list of its calls, (pixels, thread name) each."""
    from cvsss.sss_addon import precompile

    def make(seconds: float, error: Exception | None = None) -> list:
        calls = []

        def compile_all(pixels=None):
            calls.append((pixels, threading.current_thread().name))
            time.sleep(seconds)
            if error is not None:
                raise error
            return seconds

        monkeypatch.setattr(precompile, "compile_all", compile_all)
        return calls

    return make
