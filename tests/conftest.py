"""Shared test configuration: fixed seeds, and the bpy marker lane."""

import numpy as np
import pytest


@pytest.fixture
def rng():
    """A fixed-seed generator; tests never use the global RNG."""
    return np.random.default_rng(12345)
