"""Package-private: the input checks the tracking modules share (first-frame points, frames).

Not part of the API; imported only by the modules of :mod:`voicepuppet.tracking`.
"""

from __future__ import annotations

import numpy as np


def check_inside(init: np.ndarray, shape) -> None:
    """Raises ``ValueError`` naming the first of the (P, 2) points ``init`` outside an image of
    ``shape`` (H, W)."""
    h, w = shape
    outside = ~((init[:, 0] >= 0) & (init[:, 0] <= w - 1) & (init[:, 1] >= 0) & (init[:, 1] <= h - 1))
    if np.any(outside):
        i = int(np.flatnonzero(outside)[0])
        raise ValueError(f"initial point {i} = ({init[i, 0]:g}, {init[i, 1]:g}) is outside the "
                         f"{w}x{h} first frame; initial points must lie inside the image")


def check_points(points, name: str) -> np.ndarray:
    """``points`` as a contiguous (P, 2) float64 array, P >= 3, all finite; else ``ValueError``
    naming them ``name``."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{name} must have shape (P, 2) (x, y per row), got {pts.shape}")
    if len(pts) < 3:
        raise ValueError(f"{name} must hold at least 3 landmarks for a spring mesh, got {len(pts)}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{name} contains NaN or infinite values; give finite pixel coordinates")
    return pts


def as_grey(frame: np.ndarray, t: int, shape) -> np.ndarray:
    """Frame ``t`` as (H, W) uint8 grey (a (H, W, 3) BGR frame converted with OpenCV); else
    ``ValueError``, also when its shape is not ``shape`` (frame 0's; None: any)."""
    f = np.asarray(frame)
    if f.ndim == 3 and f.shape[2] == 3:
        import cv2  # colour frames come from OpenCV callers

        f = cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
    if f.dtype != np.uint8 or f.ndim != 2:
        raise ValueError(f"frame {t} must be a (H, W) uint8 grey or (H, W, 3) uint8 BGR image, "
                         f"got dtype {f.dtype} and shape {f.shape}")
    if shape is not None and f.shape != shape:
        raise ValueError(f"frame {t} has shape {f.shape} but frame 0 has {shape}; "
                         "all frames of a sequence must have one size")
    return f
