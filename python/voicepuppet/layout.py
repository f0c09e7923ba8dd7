"""The facial landmark layout shared by the synthetic performer, tracking, training and
rendering: the 68-point iBUG / Multi-PIE markup (dlib's and menpo's), image coordinates (x, y).

Groups index into the 68 points; :func:`neutral_landmarks` draws a frontal neutral face in
the layout (for the drawn performer, tests and demos). ``MOUTH`` (outer + inner lip) is what the lip vertex error is
measured on; the inter-ocular distance (outer eye corners) normalises landmark errors.
"""

from __future__ import annotations

import numpy as np

__all__ = ["N_POINTS", "GROUPS", "NAMES", "MOUTH", "UPPER_FACE", "LOWER_FACE", "OUTER_EYE_CORNERS",
           "EYE_CORNERS", "RIGID", "LIP_GAP", "INNER_LIP_PAIRS", "inter_ocular_distance", "inner_lip_gaps",
           "crossed_lips", "CROSSED_IOD", "close_crossed_lips", "neutral_landmarks"]

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
#: the inner lips' facing points, (upper, lower): the lower never lies above the upper
INNER_LIP_PAIRS = ((61, 67), LIP_GAP, (63, 65))


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


def _faces(points, what: str) -> np.ndarray:
    p = np.array(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (N_POINTS, 2):
        raise ValueError(f"{what} needs 68-point faces of shape (T, {N_POINTS}, 2), got {p.shape}")
    return p


def _face_down(p: np.ndarray) -> np.ndarray:
    """Each face's own vertical, a unit vector from the eyes' outer corners' midpoint to the lower
    lip's middle (point 57)."""
    a, b = OUTER_EYE_CORNERS
    down = p[:, 57] - 0.5 * (p[:, a] + p[:, b])
    return down / np.maximum(np.linalg.norm(down, axis=1, keepdims=True), 1e-12)


def inner_lip_gaps(points: np.ndarray) -> np.ndarray:
    """How far each lower inner-lip point lies below its upper partner (``INNER_LIP_PAIRS``),
    along each face's own vertical (from the eyes' outer corners' midpoint to the lower lip's
    middle, point 57): negative where the lips cross.

    Parameters
    ----------
    points : array_like, shape (T, 68, 2)
        Faces, pixel coordinates (x, y).

    Returns
    -------
    ndarray, shape (T, 3)
        The gaps in pixels, one column per pair.

    Raises
    ------
    ValueError
        The points are not 68-point faces.
    """
    p = _faces(points, "the inner lips' gaps")
    down = _face_down(p)
    return np.stack([np.einsum("ij,ij->i", p[:, lo] - p[:, up], down) for up, lo in INNER_LIP_PAIRS], axis=1)


#: An overlap of the inner lips beyond this (inter-ocular distances) counts as crossed.
CROSSED_IOD = 0.01


def crossed_lips(points) -> np.ndarray:
    """Per frame, whether the inner lips cross: an upper inner-lip point more than
    :data:`CROSSED_IOD` inter-ocular distances below its lower partner, along the face's own
    vertical (from the eyes' midpoint to the lower lip).

    Parameters
    ----------
    points : array_like, shape (T, 68, 2)
        Landmarks in the 68-point layout.

    Returns
    -------
    ndarray of bool, shape (T,)
    """
    p = np.asarray(points, dtype=np.float64)
    return (inner_lip_gaps(p) < -CROSSED_IOD * inter_ocular_distance(p)[:, None]).any(axis=1)


def close_crossed_lips(points: np.ndarray) -> np.ndarray:
    """68-point faces whose inner lips do not pass each other: a pair whose gap
    (:func:`inner_lip_gaps`) is negative is moved to the middle of the two along the face's
    vertical, so the lips meet, closed, instead of crossing.

    Parameters
    ----------
    points : array_like, shape (T, 68, 2)
        Faces, pixel coordinates (x, y).

    Returns
    -------
    ndarray, shape (T, 68, 2)
        A copy, the crossed pairs closed.

    Raises
    ------
    ValueError
        The points are not 68-point faces.
    """
    p = _faces(points, "closing crossed lips")
    down = _face_down(p)
    gaps = inner_lip_gaps(p)
    for k, (up, lo) in enumerate(INNER_LIP_PAIRS):
        shut = np.minimum(gaps[:, k], 0.0)[:, None] * down  # zero where the pair is in order
        p[:, up] += 0.5 * shut
        p[:, lo] -= 0.5 * shut
    return p


def _arc(cx, cy, rx, ry, a0, a1, n):
    a = np.linspace(a0, a1, n)
    return np.column_stack([cx + rx * np.cos(a), cy + ry * np.sin(a)])


def neutral_landmarks(width: int = 320, height: int = 320) -> np.ndarray:
    """A frontal neutral face in the 68-point layout of :mod:`voicepuppet.layout`,
    centred in a ``width`` x ``height`` image, mouth closed. Returns (68, 2) float64.

    Parameters
    ----------
    width, height : int
        Image size in pixels (default 320 x 320); the face scales with the smaller.

    Returns
    -------
    ndarray, shape (68, 2)
        Pixel coordinates (x, y), float64.
    """
    s = min(width, height) / 440.0
    cx, cy = width / 2.0, height / 2.0
    pts = np.zeros((68, 2))
    # jaw 0..16: from the subject's right temple (image left) under the chin to the left temple
    theta = np.linspace(0.0, np.pi, 17)
    pts[0:17] = np.column_stack([cx - 105 * s * np.cos(theta), cy - 10 * s + 130 * s * np.sin(theta)])
    # brows 17..26 (arched upwards: y smaller in the middle)
    pts[17:22] = _arc(cx - 52 * s, cy - 58 * s, 34 * s, 10 * s, np.pi, 2 * np.pi, 5)
    pts[22:27] = _arc(cx + 52 * s, cy - 58 * s, 34 * s, 10 * s, np.pi, 2 * np.pi, 5)
    # nose bridge 27..30, nose base 31..35
    pts[27:31] = np.column_stack([np.full(4, cx), cy + np.linspace(-42, 8, 4) * s])
    pts[31:36] = np.column_stack([cx + np.linspace(-20, 20, 5) * s,
                                  cy + (18 - 4 * np.cos(np.linspace(-1.2, 1.2, 5))) * s])
    # eyes 36..47: corner, two upper lid points, corner, two lower lid points
    for start, ex in ((36, cx - 45 * s), (42, cx + 45 * s)):
        a = np.array([np.pi, 4 * np.pi / 3, 5 * np.pi / 3, 0.0, np.pi / 3, 2 * np.pi / 3])
        pts[start:start + 6] = np.column_stack([ex + 20 * s * np.cos(a), cy - 30 * s + 9 * s * np.sin(a)])
    # outer lip 48..59: corner (48), upper lip to the other corner (54), lower lip back
    my = cy + 62 * s
    a = np.linspace(np.pi, 2 * np.pi, 7)
    upper = np.column_stack([cx + 42 * s * np.cos(a), my + 14 * s * np.sin(a)])
    upper[3, 1] += 4 * s  # the Cupid's bow dip
    b = np.linspace(0.0, np.pi, 7)[1:-1]
    lower = np.column_stack([cx + 42 * s * np.cos(b), my + 16 * s * np.sin(b)])
    pts[48:55] = upper
    pts[55:60] = lower
    # inner lip 60..67: corner, three upper, corner, three lower; closed mouth: lips touch
    ai = np.linspace(np.pi, 2 * np.pi, 5)
    pts[60:65] = np.column_stack([cx + 30 * s * np.cos(ai), my + 1.5 * s * np.sin(ai)])
    bi = np.linspace(0.0, np.pi, 5)[1:-1]
    pts[65:68] = np.column_stack([cx + 30 * s * np.cos(bi), my + 1.5 * s * np.sin(bi)])
    return pts
