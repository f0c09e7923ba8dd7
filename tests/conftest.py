import os
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture
def rng(request):
    """A seeded generator; the seed is printed so a failure can be replayed."""
    seed = int(os.environ.get("VOICEPUPPET_TEST_SEED", "20261123"))
    print(f"seed={seed}")
    return np.random.default_rng(seed)


@pytest.fixture(scope="session")
def write_avi():
    """``write_avi(path, frames, fps=25.0)``: (T, H, W) uint8 grey frames as an MJPG .avi (the
    folder created if missing); returns the path."""
    import cv2

    def write(path, frames, fps: float = 25.0) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        frames = np.asarray(frames)
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), float(fps),
                            (frames.shape[2], frames.shape[1]), False)
        for f in frames:
            w.write(f)
        w.release()
        return path

    return write
