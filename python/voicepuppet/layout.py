"""The facial landmark layout shared by the synthetic performer, tracking, training and
rendering: the 68-point iBUG / Multi-PIE markup (dlib's and menpo's), image coordinates (x, y).

Groups index into the 68 points. ``MOUTH`` (outer + inner lip) is what the lip vertex error is
measured on; the inter-ocular distance (outer eye corners) normalises landmark errors.
"""

from __future__ import annotations

import numpy as np

__all__ = ["N_POINTS", "GROUPS", "NAMES", "MOUTH", "UPPER_FACE", "LOWER_FACE", "OUTER_EYE_CORNERS",
           "EYE_CORNERS", "RIGID", "LIP_GAP", "inter_ocular_distance"]

N_POINTS = 68

GROUPS: dict[str, range] = {
    "jaw": range(0, 17),
    "right_brow": range(17, 22),
    "left_brow": range(22, 27),
    "nose_bridge": range(27, 31),
    "nose_base": range(31, 36),
    "right_eye": range(36, 42),
    "left_eye": range(42, 48),
    "outer_lip": range(48, 60),
    "inner_lip": range(60, 68),
}

NAMES: list[str] = [f"{group}_{i - r.start}" for group, r in GROUPS.items() for i in r]

MOUTH = np.arange(48, 68)
#: brows, eyes and nose bridge: the upper-face model of Brand §5.1
UPPER_FACE = np.r_[17:31, 36:48]
#: jaw line, nose base and lips: the lower-face model
LOWER_FACE = np.r_[0:17, 31:36, 48:68]
#: the subject's right eye outer corner (36) and left eye outer corner (45)
OUTER_EYE_CORNERS = (36, 45)
#: the four eye corners: outer and inner of the right eye, inner and outer of the left
EYE_CORNERS = (36, 39, 42, 45)
#: points that speech does not move: the nose (bridge and base) and the eye corners; head pose
#: is fitted to them, and the tracker's face frame and the mouth's upper teeth follow them
RIGID = (27, 28, 29, 30, 31, 32, 33, 34, 35) + EYE_CORNERS
#: the middle points of the upper and lower inner lip: the lips' gap
LIP_GAP = (62, 66)


def inter_ocular_distance(points: np.ndarray) -> np.ndarray:
    """Distance between the outer eye corners.

    Parameters
    ----------
    points : ndarray, shape (..., 68, 2)
        68-point faces, pixel coordinates (x, y).

    Returns
    -------
    ndarray, shape (...)
        Distance between points 36 and 45 (``OUTER_EYE_CORNERS``) of each face, in pixels.

    Raises
    ------
    ValueError
        The points are not a 68-point face.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.shape[-2:] != (N_POINTS, 2):
        raise ValueError(f"inter-ocular distance needs 68-point faces (outer eye corners {OUTER_EYE_CORNERS}): "
                         f"points must have shape (..., {N_POINTS}, 2), got {points.shape}; give the "
                         "distance explicitly for other layouts")
    a, b = OUTER_EYE_CORNERS
    return np.linalg.norm(points[..., a, :] - points[..., b, :], axis=-1)
