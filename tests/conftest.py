import os

import numpy as np
import pytest


@pytest.fixture
def rng(request):
    """A seeded generator; the seed is printed so a failure can be replayed."""
    seed = int(os.environ.get("VOICEPUPPET_TEST_SEED", "20261123"))
    print(f"seed={seed}")
    return np.random.default_rng(seed)
