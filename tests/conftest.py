"""Shared test configuration: fixed seeds, the bpy marker lane, and the kernels' preparation
state (``no_compile``, ``slow_compile``)."""

import os
import threading
import time

import numpy as np
import pytest

# The numba kernels' background compile (sss_addon.precompile.start_background) is off
# in every test and in the processes they start, unless a test turns it on: when the
# cache is not stamped complete yet, a job would otherwise start one and log two more
# lines depending on which tests ran before it.
os.environ["CVSSS_BACKGROUND_COMPILE"] = "0"


@pytest.fixture
def rng():
    """A fixed-seed generator; tests never use the global RNG."""
    return np.random.default_rng(12345)


# -- the numba kernels' preparation (sss_addon.precompile) ---------------------------
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
    """``slow_compile(seconds, error=None)``: the kernels' warm-up becomes a sleep (then
    raises ``error``); returns the list of its calls, (pixels, thread name) each."""
    from cvsss.core.mc import backend as mc_backend

    def make(seconds: float, error: Exception | None = None) -> list:
        calls = []

        def warm_up(pixels=None):
            calls.append((pixels, threading.current_thread().name))
            time.sleep(seconds)
            if error is not None:
                raise error
            return seconds

        monkeypatch.setattr(mc_backend, "warm_up", warm_up)
        return calls

    return make
