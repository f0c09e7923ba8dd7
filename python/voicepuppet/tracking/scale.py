"""The working scale: a large face is tracked on frames resized down, one factor per video.

The tracker's patches, pyramid levels and pixel floors suit a face of about the synthetic
performer's size; a larger first-frame face (:func:`face_size`) is tracked on frames resized by
:func:`working_scale_factor`, and its points are mapped between the two pixel grids by
:func:`points_to_working` and :func:`points_to_full`.
"""

from __future__ import annotations

import numpy as np

from voicepuppet.tracking._checks import check_points

__all__ = ["face_size", "working_scale_factor", "points_to_working", "points_to_full", "LARGE_FACE_IOD",
           "WORKING_IOD", "LARGE_FACE_RMS_RADIUS", "WORKING_RMS_RADIUS"]


# The working scale: a first-frame face larger than LARGE_FACE_IOD is tracked on frames resized
# down (one factor for the whole video) so that it is WORKING_IOD in size; the tracker's 13x13
# patches, 3 levels and pixel floors were tuned on the synthetic performer, whose outer eye
# corners are 123 px apart. Sizes: the distance between the outer eye corners (36, 45) of a
# 68-point face. LARGE_FACE_IOD is the performer's plus a 4 % margin, so that it (and a
# detector's init on it) stays at full resolution, bit for bit as before; WORKING_IOD = 112
# tracked the performer's clips planted 1.5-2.8x larger better than 128 (lips, rest of the face
# and lost points on 11-12 of 12 clips) and than 96 (lips; docs/tracking.md, "Large faces").
# Other layouts: the RMS distance of the init points from their centroid, the performer's 68
# points' ratio to their IOD (78.25 / 123.29 = 0.635) times those; a layout that covers less of
# the face than the 68 points gives a smaller radius, so it is resized less (never more).
LARGE_FACE_IOD = 128.0
WORKING_IOD = 112.0
LARGE_FACE_RMS_RADIUS = 0.635 * LARGE_FACE_IOD
WORKING_RMS_RADIUS = 0.635 * WORKING_IOD


def face_size(points: np.ndarray) -> tuple[float, float, float]:
    """The size of the face marked by first-frame points, the size above which it is tracked at
    a working scale, and the size it is then tracked at.

    A 68-point (iBUG 300-W) face: the distance between the outer eye corners (36, 45), against
    ``LARGE_FACE_IOD`` and ``WORKING_IOD``; any other layout: the RMS distance of the points
    from their centroid, against ``LARGE_FACE_RMS_RADIUS`` and ``WORKING_RMS_RADIUS``.

    Parameters
    ----------
    points : ndarray, shape (P, 2)
        First-frame positions (x, y), P >= 3.

    Returns
    -------
    size : float
        The face's size, px.
    large : float
        The size above which the face is tracked at a working scale, px.
    working : float
        The size it is then tracked at, px.

    Raises
    ------
    ValueError
        The points are not a (P, 2) array of at least 3 finite positions.
    """
    p = check_points(points, "points")
    if len(p) == 68:
        return float(np.linalg.norm(p[45] - p[36])), LARGE_FACE_IOD, WORKING_IOD
    c = p - p.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum(c * c, axis=1)))), LARGE_FACE_RMS_RADIUS, WORKING_RMS_RADIUS


def working_scale_factor(points: np.ndarray, working_scale="auto") -> float:
    """The factor f by which the frames are resized for tracking.

    Parameters
    ----------
    points : ndarray, shape (P, 2)
        First-frame positions (x, y) in full-resolution pixels.
    working_scale : {"auto"} or float, default "auto"
        ``"auto"``: ``working / size`` of :func:`face_size` when the face is larger than
        ``large`` (a 68-point face: outer eye corners more than 128 px apart, resized so that
        they are 112 px apart), else 1 (faces at or below it are tracked at full resolution,
        exactly as without a working scale); or a number in (0, 1]: that factor (1: always
        full resolution).

    Returns
    -------
    float
        The factor, in (0, 1].

    Raises
    ------
    ValueError
        ``working_scale`` is neither ``"auto"`` nor a number in (0, 1], or (with ``"auto"``) the
        points are not a (P, 2) array of at least 3 finite positions.
    """
    if isinstance(working_scale, str):
        if working_scale != "auto":
            raise ValueError(f"working_scale must be 'auto' or a number in (0, 1] (the factor the frames "
                             f"are resized by; 1 tracks at full resolution), got {working_scale!r}")
        size, large, working = face_size(points)
        return working / size if size > large else 1.0
    if isinstance(working_scale, (bool, np.bool_)) or not isinstance(working_scale, (int, float, np.integer,
                                                                                     np.floating)):
        raise ValueError(f"working_scale must be 'auto' or a number in (0, 1], got {working_scale!r} "
                         f"of type {type(working_scale).__name__}")
    f = float(working_scale)
    if not 0.0 < f <= 1.0:
        raise ValueError(f"working_scale must be 'auto' or a number in (0, 1] (a downscale factor; faces "
                         f"are not upscaled), got {working_scale!r}")
    return f


def points_to_working(points: np.ndarray, f: float) -> np.ndarray:
    """Full-resolution pixel positions in frames resized by ``f`` (pixel centres at integers in
    both): ``(x + 0.5) * f - 0.5``.

    Parameters
    ----------
    points : ndarray, shape (..., 2)
        Positions (x, y) in full-resolution pixels.
    f : float
        The factor the frames are resized by.

    Returns
    -------
    ndarray, shape (..., 2), float64
        The positions in pixels of the resized frames.
    """
    return (np.asarray(points, dtype=np.float64) + 0.5) * f - 0.5


def points_to_full(points: np.ndarray, f: float) -> np.ndarray:
    """The inverse of :func:`points_to_working`: ``(x + 0.5) / f - 0.5``.

    Parameters
    ----------
    points : ndarray, shape (..., 2)
        Positions (x, y) in pixels of frames resized by ``f``.
    f : float
        The factor the frames were resized by.

    Returns
    -------
    ndarray, shape (..., 2), float64
        The positions in full-resolution pixels.
    """
    return (np.asarray(points, dtype=np.float64) + 0.5) / f - 0.5
