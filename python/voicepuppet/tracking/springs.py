"""The spring mesh's layout: its edges, and the lip and eye-corner handling of a 68-point face.

The mesh's edges are the Delaunay triangulation of the first-frame points. On a 68-point (iBUG
300-W) face the lips and eye corners are tracked on half patches (:func:`lip_patch_sides`,
:func:`eye_corner_sides`), the edges that touch a lip carry offset springs (:func:`lip_springs`),
re-estimated springs across the mouth opening are softened (:func:`soften_opening`), and the
springs within a lip check the lip points' data (:func:`checked_lip_edges`). The constants below
are the tracker's lip settings, in inter-ocular distances (IOD) where they are lengths.
"""

from __future__ import annotations

import numpy as np

from voicepuppet import _core
from voicepuppet.layout import RIGID
from voicepuppet.tracking._checks import check_points

__all__ = ["delaunay_edges", "lip_patch_sides", "eye_corner_sides", "checked_lip_edges", "lip_springs",
           "soften_opening", "LIP_SEARCH_IOD", "LIP_SPRING_FLOOR_IOD", "LOWER_LIP", "LIP_GROUP_SEARCH_IOD",
           "LIP_SPRING_OUTLIER", "FACE_FRAME_POINTS", "MOUTH_CORNERS", "OUTER_MOUTH_CORNERS", "OUTER_UPPER_LIP"]


# Lip tracking on a 68-point (iBUG 300-W) layout, in inter-ocular distances (IOD): the
# exhaustive search radius for the lip points (a lower lip moves up to ~0.07 IOD between frames
# at 30 fps) and the floor on the initial springs' standard deviation (the mouth opens by up
# to ~0.25 IOD; first-frame springs of 5 % of a 3 px lip gap would hold the lips shut).
LIP_SEARCH_IOD = 0.065
LIP_SPRING_FLOOR_IOD = 0.025
# The lower lip is searched for as one (a jaw drop moves it by more than a point's search
# radius within a few frames, and its points' contours are faint) within 0.15 IOD; from the
# second pass a lip point further than 6 standard deviations of its within-lip springs from
# where they put it is handed to the springs for the frame (3, 4, 5, 6 measured: 3 mutes lips
# that really moved, 5-6 best; the re-estimated variances are smaller than the true ones).
LOWER_LIP = (55, 56, 57, 58, 59, 65, 66, 67)
LIP_GROUP_SEARCH_IOD = 0.15
LIP_SPRING_OUTLIER = 6.0
# The face frame of a 68-point layout: points that move rigidly with the head (nose, eye
# corners); the lip springs' offsets are measured in it.
FACE_FRAME_POINTS = RIGID
# The mouth corners (outer 48, 54; inner 60, 64): where the two lip contours meet. In a wide
# opening their patches match about equally well anywhere along the lip edge beside them, so
# their springs to the lower lip stay stiff across the opening and check their data.
MOUTH_CORNERS = (48, 54, 60, 64)
# The outer corners are also searched for against their first-frame patches within the lip
# search radius after stage A: over that window the first-frame patch still peaks at the
# corner of an open mouth (180 s video, openings above 18 px: within 2 px in 98 % of frames),
# where the gradient steps leave it on the upper lip's edge. The inner corners are not: their
# first-frame patches turn into teeth and cavity (a search moved 60 outwards, worse). The outer
# upper lip (49-53) is searched for with the half of its first-frame patch above it (its lower
# half turns into teeth) along the face's vertical only (along the lip edge the half patch
# matches about equally well everywhere); it is still tracked on whole patches.
OUTER_MOUTH_CORNERS = (48, 54)
OUTER_UPPER_LIP = (49, 50, 51, 52, 53)
# The eye corners (36, 39 of the subject's right eye, 42, 45 of the left) are tracked on the half
# of their patches away from their eye, along the eye's axis (``eye_corner_sides``). In a blink
# the lids sweep across the eye side of a corner's patch, and a whole patch follows them into the
# eye (the performer's inner corner 42: 9.5 px off on the 60 s clip, carried over into pass 2 by
# the re-estimated springs); the half away from the eye barely changes (correlation of the
# first-frame half with the lids shut 0.98-0.99 at the truth, whole patches 0.51-0.76).


def delaunay_edges(points: np.ndarray) -> np.ndarray:
    """Edges (i < j) of the Delaunay triangulation of points: the spring mesh's default edges.

    Parameters
    ----------
    points : ndarray, shape (P, 2)
        Positions (x, y), P >= 3, finite.

    Returns
    -------
    ndarray, shape (E, 2), int64
        The edges as point index pairs (i < j).

    Raises
    ------
    ValueError
        The points are not a (P, 2) array of at least 3 finite positions.
    """
    pts = check_points(points, "points")
    return np.asarray(_core.delaunay_edges(pts), dtype=np.int64)


def lip_patch_sides(points: np.ndarray) -> np.ndarray:
    """Half-patch directions for the lip points of a 68-point (iBUG 300-W) layout.

    The inner upper lip (61-63) is tracked on the half of its patches above it and the lower lip
    (55-59, 65-67) on the half below it (in the face frame given by the outer eye corners): the
    side away from the mouth opening, whose texture moves with the lip while the other half
    turns from closed lips into the mouth cavity and back.

    Parameters
    ----------
    points : ndarray, shape (68, 2)
        First-frame positions (x, y).

    Returns
    -------
    ndarray, shape (68, 2), float64
        Unit directions for points 55-59, 61-63 and 65-67, zero rows (whole patches) for the
        others; pass as the ``patch_sides`` tracker option.

    Raises
    ------
    ValueError
        The points are not 68, or the outer eye corners (36, 45) coincide.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.shape != (68, 2):
        raise ValueError(f"lip_patch_sides needs the 68 points of the iBUG 300-W layout, got shape {p.shape}")
    u = p[45] - p[36]
    n = np.linalg.norm(u)
    if not np.isfinite(n) or n == 0:
        raise ValueError("points 36 and 45 (outer eye corners) coincide; give a 68-point iBUG face")
    u = u / n
    down = np.array([-u[1], u[0]])  # image y grows downwards: (-uy, ux) points down the face
    sides = np.zeros((68, 2))
    sides[[61, 62, 63]] = -down
    sides[[55, 56, 57, 58, 59, 65, 66, 67]] = down
    return sides


def eye_corner_sides(points: np.ndarray) -> np.ndarray:
    """Half-patch directions for the eye corners of a 68-point (iBUG 300-W) layout.

    Each corner (36, 39, 42, 45) looks away from its own eye along the eye's axis: 36 away from
    39 and 39 away from 36, 42 away from 45 and 45 away from 42. The lids, which sweep across the
    eye side of a corner's patch in a blink, stay out of its templates.

    Parameters
    ----------
    points : ndarray, shape (68, 2)
        First-frame positions (x, y).

    Returns
    -------
    ndarray, shape (68, 2), float64
        Unit directions for the four eye corners, zero rows (whole patches) for the others; add
        to :func:`lip_patch_sides` (the rows do not overlap) for the ``patch_sides`` tracker
        option.

    Raises
    ------
    ValueError
        The points are not 68, or the two corners of an eye coincide.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.shape != (68, 2):
        raise ValueError(f"eye_corner_sides needs the 68 points of the iBUG 300-W layout, got shape {p.shape}")
    sides = np.zeros((68, 2))
    for a, b in ((36, 39), (42, 45)):
        u = p[a] - p[b]
        n = np.linalg.norm(u)
        if not np.isfinite(n) or n == 0:
            raise ValueError(f"eye corners {a} and {b} coincide; give a 68-point iBUG face")
        sides[a] = u / n
        sides[b] = -u / n
    return sides


_IS_LOWER_LIP = np.isin(np.arange(68), LOWER_LIP)


def _same_lip(edges: np.ndarray) -> np.ndarray:
    """(E,) bool: edges of a 68-point mesh with both ends on the upper lip and corners (48-54,
    60-64) or both on the lower lip (55-59, 65-67): they keep their shape when the mouth opens."""
    return np.all(edges >= 48, axis=1) & (_IS_LOWER_LIP[edges[:, 0]] == _IS_LOWER_LIP[edges[:, 1]])


def _across_opening(edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(E,) bool masks: edges with both ends on the lips, and those of them that span the mouth
    opening (a lower-lip point to an upper-lip point or a corner)."""
    on_lips = np.all(edges >= 48, axis=1)
    return on_lips, on_lips & ~_same_lip(edges)


def _corner_to_lower(edges: np.ndarray) -> np.ndarray:
    """(E,) bool: edges of a 68-point mesh from a mouth corner (48, 54, 60, 64) across the
    opening to the lower lip: the springs that say where along the lip edge a corner is."""
    return _across_opening(edges)[1] & np.any(np.isin(edges, MOUTH_CORNERS), axis=1)


def checked_lip_edges(edges: np.ndarray) -> np.ndarray:
    """Indices of the springs of a 68-point mesh that check the lip points' data
    (``outlier_edges``): those within one lip, and those from a mouth corner to the lower lip.

    Parameters
    ----------
    edges : ndarray, shape (E, 2), int
        The mesh's edges, point index pairs of a 68-point face.

    Returns
    -------
    ndarray, shape (K,), int64
        Indices into ``edges``, ascending.
    """
    return np.flatnonzero(_same_lip(edges) | _corner_to_lower(edges))


def lip_springs(init: np.ndarray, edges: np.ndarray, mesh, relative_sigma: float, min_sigma: float,
                floor: float):
    """The initial springs of a 68-point face with offset springs on the edges that touch a lip.

    A lip spring's offset is free to change by ``floor`` px (std) along the face's vertical axis,
    where the mouth opens, but only by a length spring's std (``relative_sigma`` of its length,
    at least ``min_sigma``) along the horizontal one, so lip points do not slide along the lip
    contours (the aperture problem: a horizontal lip edge says nothing about x). Those edges'
    length springs are off: the offset spring holds the length too.

    Parameters
    ----------
    init : ndarray, shape (68, 2)
        First-frame positions (x, y) in the pixels the tracker works in.
    edges : ndarray, shape (E, 2), int64
        The mesh's edges.
    mesh : voicepuppet._core.SpringMesh
        The length springs of the first frame (``_core.springs_from_points``).
    relative_sigma : float
        A length spring's std as a fraction of its length.
    min_sigma : float
        Floor of a length spring's std, px.
    floor : float
        Std of a spring across the mouth opening along the face's vertical, px.

    Returns
    -------
    voicepuppet._core.SpringMesh
        ``mesh`` with offset springs on the lip edges and the springs that touch a lip no stiffer
        than ``floor``.
    """
    touches = np.any(edges >= 48, axis=1)
    on_lips, across = _across_opening(edges)
    u = init[45] - init[36]
    u = u / np.linalg.norm(u)
    v = np.array([-u[1], u[0]])
    d = init[edges[:, 1]] - init[edges[:, 0]]
    length = np.linalg.norm(d, axis=1)
    sig_u = np.maximum(relative_sigma * length, min_sigma)
    # Only an edge across the mouth opening (a lower-lip point to an upper-lip point or a
    # corner) changes by the opening; edges within one lip keep a length spring's std.
    sig_v = np.maximum(relative_sigma * length, min_sigma)
    sig_v = np.where(across, np.maximum(sig_v, floor), sig_v)
    prec = (np.einsum("i,j->ij", u, u)[None] / sig_u[:, None, None] ** 2
            + np.einsum("i,j->ij", v, v)[None] / sig_v[:, None, None] ** 2)
    prec[~on_lips] = 0.0
    k = np.asarray(mesh.stiffness).copy()
    k[touches] = np.minimum(k[touches], 1.0 / floor**2)
    k[on_lips] = 0.0
    mean = np.where(on_lips[:, None], d, 0.0)
    return _core.SpringMesh(edges, np.asarray(mesh.rest_length), k,
                            np.ascontiguousarray(prec.reshape(-1, 4)), np.ascontiguousarray(mean))


def soften_opening(mesh, edges: np.ndarray, floor: float):
    """``mesh`` with the springs that span the mouth opening no stiffer than ``floor`` px (std)
    along the opening.

    Re-estimated springs record the previous pass's tracks, and those hold the lower lip too high
    in wide openings; springs across the opening (lower lip to upper lip or corners, offset
    springs; lower lip to the rest of the face, length springs) learned from them pull the lip
    back to that bias. The offsets' covariance keeps its eigenvectors with eigenvalues floored
    at floor^2, the length springs' stiffness is capped at 1/floor^2. A spring from a mouth
    corner to the lower lip has only its softest direction (the opening) floored: across it, it
    holds the corner where the lower lip says (a corner slides along the lip edge beside it,
    where its own patch matches about equally well).

    Parameters
    ----------
    mesh : voicepuppet._core.SpringMesh
        Springs re-estimated from a pass (``_core.estimate_springs``).
    edges : ndarray, shape (E, 2), int64
        The mesh's edges, point index pairs of a 68-point face.
    floor : float
        The std (px) below which a spring across the opening may not hold it.

    Returns
    -------
    voicepuppet._core.SpringMesh
        The softened springs.
    """
    on_lips, across = _across_opening(edges)
    corner = _corner_to_lower(edges)
    to_lower = np.any(_IS_LOWER_LIP[edges], axis=1) & ~on_lips
    prec = np.asarray(mesh.offset_precision).reshape(-1, 2, 2).copy()
    for e in np.flatnonzero(across):
        w, v = np.linalg.eigh(prec[e])  # ascending precisions: w[0] is the softest direction
        w = np.minimum(w, 1.0 / floor**2) if not corner[e] else np.r_[min(w[0], 1.0 / floor**2), w[1]]
        prec[e] = (v * w) @ v.T
    k = np.asarray(mesh.stiffness).copy()
    k[to_lower] = np.minimum(k[to_lower], 1.0 / floor**2)
    return _core.SpringMesh(edges, np.asarray(mesh.rest_length), k,
                            np.ascontiguousarray(prec.reshape(-1, 4)), np.asarray(mesh.offset_mean))
