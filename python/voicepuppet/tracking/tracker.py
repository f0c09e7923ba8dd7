"""Facial landmark tracking: the spring-mesh SSD tracker of Voice Puppetry §4.1.

A mesh of sub-pixel SSD trackers (one per landmark) coupled by springs, relaxed jointly in each
frame by the C++ kernel (``cpp/include/voicepuppet/tracker.hpp``). Spring lengths and
stiffnesses are re-estimated from the mean and variance of the tracked distances, and the
sequence is tracked again, ``passes`` times in all (the paper's "few repetitions").

Command line: ``voicepuppet track VIDEO -o landmarks.npz [--init points.json|auto]
[--overlay out.mp4]``. File formats are those of DESIGN.md ("Files users exchange").
"""

from __future__ import annotations

import functools
import itertools
import json
import os
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from voicepuppet import _core
from voicepuppet._files import atomic_path, write_npz
from voicepuppet.layout import N_POINTS, OUTER_EYE_CORNERS, RIGID

__all__ = [
    "TrackResult", "track_frames", "track_video", "delaunay_edges", "load_init_points",
    "auto_init", "first_face", "NoFaceError", "VariableFrameRateWarning", "on_uniform_grid", "save_landmarks",
    "load_landmarks", "lip_patch_sides", "eye_corner_sides", "DLIB_MODEL_PATHS",
    "face_size", "working_scale_factor", "points_to_working", "points_to_full",
    "LARGE_FACE_IOD", "WORKING_IOD", "LARGE_FACE_RMS_RADIUS", "WORKING_RMS_RADIUS",
]

# Where Debian's libdlib-data puts dlib's 68-point model (override with VOICEPUPPET_DLIB_MODEL).
DLIB_MODEL_PATHS = ("/usr/share/dlib/shape_predictor_68_face_landmarks.dat",)
# With init="auto" and no face on the first frame (a title card, a fade-in, someone stepping into
# view), the detector looks at one frame every AUTO_INIT_STRIDE_S seconds of the first
# AUTO_INIT_SCAN_S seconds; tracking starts on the earliest frame with a face (those between the
# last faceless probe and the first with a face are looked at one by one). Those looks upsample
# the frame (dlib's way to find faces under its 80 px window) only while the upsampled frame
# has at most PROBE_MAX_PIXELS: a faceless 1920x1080 frame costs dlib 0.11 s as it is and
# 1.9 s upsampled twice, so 120 looks stay seconds; the smallest face they find is ~20 px on a
# 320x320 frame, ~40 px on 640x480 and ~80 px from 1280x720 up (the first frame: any size).
AUTO_INIT_STRIDE_S = 0.5
AUTO_INIT_SCAN_S = 60.0
PROBE_MAX_PIXELS = 1 << 21
# How far apart (px) auto_init sets landmarks the detector put on one pixel (a closed mouth's
# inner lips): the spring mesh's triangulation needs distinct points.
SEPARATE_PX = 0.5


class NoFaceError(ValueError):
    """The landmark detector found no face (``--init auto``)."""


class VariableFrameRateWarning(UserWarning):
    """:func:`track_video` found a video whose frames are not at ``k / fps`` (their time stamps
    are kept in ``TrackResult.times``)."""


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

# Re-acquisition: when more than REACQUIRE_LOST_SHARE of the points have been lost for
# REACQUIRE_FRAMES frames in a row (the face left the frame or was covered), every following
# frame is searched for the first frame's face region (the bounding box of the first-frame
# points, REACQUIRE_MARGIN of its size added on each side), seen through 25 in-plane rotations
# and scales (REACQUIRE_ANGLES x REACQUIRE_SCALES about the points' centroid), by normalised
# cross-correlation (cv2.matchTemplate, TM_CCOEFF_NORMED) at pyramid level REACQUIRE_LEVEL
# (1/4 size), the best peak refined at full size within one coarse step; a peak of at least
# REACQUIRE_NCC restarts the mesh there (the first-frame points through the found similarity,
# SpringMeshTracker.relocate) and the frame is tracked again from it. Until then every point of
# the frames in the run is lost. The share is above puppet_cli's training cut (0.3): a partial
# occlusion that leaves most points found never searches (the performer's clips and carphone:
# at most 0.12 and 0.37 of a frame's points lost). REACQUIRE_NCC lies between the highest
# peak on faceless images (0.48 over 14 scikit-image pictures, 0.39 on a card of smooth noise,
# 0.38 on another face, carphone's) and the lowest of the performer's face back in the frame
# (0.84 over rotations to 20 degrees and scales 0.85-1.3; upright 0.905): docs/tracking.md,
# "Re-acquiring a lost face".
REACQUIRE_LOST_SHARE = 0.5
REACQUIRE_FRAMES = 3
REACQUIRE_NCC = 0.65
REACQUIRE_LEVEL = 2
REACQUIRE_MARGIN = 0.1
REACQUIRE_ANGLES = (0.0, -10.0, 10.0, -20.0, 20.0)
REACQUIRE_SCALES = (1.0, 0.89, 1.12, 0.8, 1.25)

_OPTION_NAMES = ("patch_radius", "levels", "max_iterations", "tolerance", "intensity_sigma",
                 "spring_weight", "ncc_floor", "ncc_full", "lost_confidence", "drift_tolerance",
                 "damping", "patch_sides", "search_radius", "frame_points", "spring_outlier", "outlier_edges",
                 "search_groups", "group_search_radius", "reference_points", "reference_sides",
                 "reference_search_radius", "reference_search_ncc")


@dataclass
class TrackResult:
    """Landmarks tracked through a sequence.

    Attributes
    ----------
    points : (T, P, 2) float64 positions (x, y) in pixels
    confidence : (T, P) float64 in [0, 1], correlation with the first-frame patch
    lost : (T, P) bool, outside the image or not matching its first-frame patch
    fps : frames per second (of a variable-rate video: its most common rate,
        :func:`voicepuppet.tracking.video.nominal_rate`; ``times`` says when each frame is)
    edges : (E, 2) int64 spring edges
    rest_length, stiffness : (E,) the springs of the last pass
    passes : one dict per pass: ``pass``, ``max_rel_length_change`` and ``max_length_change``
        (px; of the springs it re-estimated), ``mean_point_change`` (px, mean displacement from
        the previous pass), ``lost_fraction``
    names : optional (P,) landmark names
    working_scale : the factor f the frames were resized by for tracking (1: full resolution;
        see :func:`working_scale_factor`); points, rest lengths (px) and stiffnesses (px^-2)
        are reported in full-resolution pixels
    reacquired : frames (indices, last pass) where the face, lost for
        :data:`REACQUIRE_FRAMES` frames, was found again by the whole-frame search and the mesh
        restarted there (each pass's list is in ``passes[k]["reacquired"]``)
    start : the frame tracking started on (0 unless ``init="auto"`` found no face on the first
        frame: the frames before it are all lost, their points those of ``start``)
    times : (T,) presentation time of each frame in seconds, the first at 0, from the video's
        container (:func:`voicepuppet.tracking.video.frame_times`), or None (frame ``k`` at ``k / fps``):
        with a variable frame rate the two differ, and training resamples the points onto a
        uniform grid by these times (:meth:`on_grid`)
    """

    points: np.ndarray
    confidence: np.ndarray
    lost: np.ndarray
    fps: float
    edges: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    passes: list = field(default_factory=list)
    names: list | None = None
    working_scale: float = 1.0
    reacquired: list = field(default_factory=list)
    start: int = 0
    times: np.ndarray | None = None

    def on_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """``(points, lost)`` on the uniform grid ``k / fps`` the audio features are on: as they
        are for a constant frame rate, interpolated by ``times`` for a variable one
        (:func:`on_uniform_grid`); what to give ``Puppet.train`` with the video's audio."""
        return on_uniform_grid(self.points, self.lost, self.times, self.fps)


def delaunay_edges(points: np.ndarray) -> np.ndarray:
    """Edges (i < j) of the Delaunay triangulation of (P, 2) points, as an (E, 2) int64 array."""
    pts = _check_points(points, "points")
    return np.asarray(_core.delaunay_edges(pts), dtype=np.int64)


def lip_patch_sides(points: np.ndarray) -> np.ndarray:
    """Half-patch directions for the lip points of a 68-point (iBUG 300-W) layout.

    The inner upper lip (61-63) is tracked on the half of its patches above it and the lower lip
    (55-59, 65-67) on the half below it (in the face frame given by the outer eye corners): the
    side away from the mouth opening, whose texture moves with the lip while the other half
    turns from closed lips into the mouth cavity and back.

    Parameters
    ----------
    points : (68, 2) first-frame positions (x, y)

    Returns
    -------
    (68, 2) float64: unit directions for points 55-59, 61-63 and 65-67, zero rows (whole
    patches) for the others; pass as the ``patch_sides`` tracker option.
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
    points : (68, 2) first-frame positions (x, y)

    Returns
    -------
    (68, 2) float64: unit directions for the four eye corners, zero rows (whole patches) for the
    others; add to :func:`lip_patch_sides` (the rows do not overlap) for the ``patch_sides``
    tracker option.
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


def _checked_lip_edges(edges: np.ndarray) -> np.ndarray:
    """Indices of the springs of a 68-point mesh that check the lip points' data
    (``outlier_edges``): those within one lip, and those from a mouth corner to the lower lip."""
    return np.flatnonzero(_same_lip(edges) | _corner_to_lower(edges))


def _lip_springs(init: np.ndarray, edges: np.ndarray, mesh, relative_sigma: float, min_sigma: float,
                 floor: float):
    """The initial springs of a 68-point face with offset springs on the edges that touch a lip.

    A lip spring's offset is free to change by ``floor`` px (std) along the face's vertical axis,
    where the mouth opens, but only by a length spring's std (``relative_sigma`` of its length,
    at least ``min_sigma``) along the horizontal one, so lip points do not slide along the lip
    contours (the aperture problem: a horizontal lip edge says nothing about x). Those edges'
    length springs are off: the offset spring holds the length too.
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


def _soften_opening(mesh, edges: np.ndarray, floor: float):
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


def face_size(points: np.ndarray) -> tuple[float, float, float]:
    """The size of the face marked by first-frame points, the size above which it is tracked at
    a working scale, and the size it is then tracked at.

    A 68-point (iBUG 300-W) face: the distance between the outer eye corners (36, 45), against
    ``LARGE_FACE_IOD`` and ``WORKING_IOD``; any other layout: the RMS distance of the points
    from their centroid, against ``LARGE_FACE_RMS_RADIUS`` and ``WORKING_RMS_RADIUS``.

    Parameters
    ----------
    points : (P, 2) first-frame positions (x, y), P >= 3

    Returns
    -------
    (size, large, working) in pixels
    """
    p = _check_points(points, "points")
    if len(p) == 68:
        return float(np.linalg.norm(p[45] - p[36])), LARGE_FACE_IOD, WORKING_IOD
    c = p - p.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum(c * c, axis=1)))), LARGE_FACE_RMS_RADIUS, WORKING_RMS_RADIUS


def working_scale_factor(points: np.ndarray, working_scale="auto") -> float:
    """The factor f by which the frames are resized for tracking.

    Parameters
    ----------
    points : (P, 2) first-frame positions (x, y) in full-resolution pixels
    working_scale : ``"auto"`` (default): ``working / size`` of :func:`face_size` when the
        face is larger than ``large`` (a 68-point face: outer eye corners more than 128 px
        apart, resized so that they are 112 px apart), else 1 (faces at or below it are tracked
        at full resolution, exactly as without a working scale); or a number in (0, 1]: that
        factor (1: always full resolution)

    Returns
    -------
    float in (0, 1]
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
    """Full-resolution pixel positions (..., 2) in frames resized by ``f`` (pixel centres at
    integers in both): ``(x + 0.5) * f - 0.5``."""
    return (np.asarray(points, dtype=np.float64) + 0.5) * f - 0.5


def points_to_full(points: np.ndarray, f: float) -> np.ndarray:
    """The inverse of :func:`points_to_working`: ``(x + 0.5) / f - 0.5``."""
    return (np.asarray(points, dtype=np.float64) + 0.5) / f - 0.5


def _check_inside(init: np.ndarray, shape) -> None:
    h, w = shape
    outside = ~((init[:, 0] >= 0) & (init[:, 0] <= w - 1) & (init[:, 1] >= 0) & (init[:, 1] <= h - 1))
    if np.any(outside):
        i = int(np.flatnonzero(outside)[0])
        raise ValueError(f"initial point {i} = ({init[i, 0]:g}, {init[i, 1]:g}) is outside the "
                         f"{w}x{h} first frame; initial points must lie inside the image")


def _check_points(points, name: str) -> np.ndarray:
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{name} must have shape (P, 2) (x, y per row), got {pts.shape}")
    if len(pts) < 3:
        raise ValueError(f"{name} must hold at least 3 landmarks for a spring mesh, got {len(pts)}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{name} contains NaN or infinite values; give finite pixel coordinates")
    return pts


def _options(opts: dict) -> "_core.TrackerOptions":
    o = _core.TrackerOptions()
    for k, v in opts.items():
        if k not in _OPTION_NAMES:
            raise ValueError(f"unknown tracker option {k!r}; choose from {', '.join(_OPTION_NAMES)}")
        setattr(o, k, v)
    return o


def _grey(frame: np.ndarray, t: int, shape) -> np.ndarray:
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


class _FaceSearch:
    """The whole-frame search for a lost face: the first frame's face region (bounding box of
    the first-frame points plus :data:`REACQUIRE_MARGIN`), seen through each in-plane rotation
    of :data:`REACQUIRE_ANGLES` and scale of :data:`REACQUIRE_SCALES` about the points' centroid,
    matched by normalised cross-correlation over the frame at pyramid level
    :data:`REACQUIRE_LEVEL`; the best peak is refined at full size within one coarse step.
    ``find`` returns the first-frame points mapped to where the face is, and the full-size
    correlation, or None when the best coarse peak is below :data:`REACQUIRE_NCC`."""

    def __init__(self, first: np.ndarray, init: np.ndarray):
        import cv2

        self._cv2 = cv2
        h, w = first.shape
        centre = init.mean(axis=0)
        self.hypotheses = []  # (2x3 map of the first frame, template, coarse template, origin)
        for scale in REACQUIRE_SCALES:
            for angle in REACQUIRE_ANGLES:
                M = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), float(angle), float(scale))
                seen = first if angle == 0 and scale == 1 else cv2.warpAffine(
                    first, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                pts = init @ M[:, :2].T + M[:, 2]
                lo, hi = pts.min(axis=0), pts.max(axis=0)
                pad = REACQUIRE_MARGIN * (hi - lo)
                x0, y0 = np.floor(np.maximum(lo - pad, 0)).astype(int)
                x1, y1 = np.ceil(np.minimum(hi + pad, [w - 1, h - 1])).astype(int)
                template = np.ascontiguousarray(seen[y0:y1 + 1, x0:x1 + 1])
                self.hypotheses.append((M, template, self._down(template), np.array([x0, y0])))

    def _down(self, image: np.ndarray) -> np.ndarray:
        for _ in range(REACQUIRE_LEVEL):
            image = self._cv2.pyrDown(image)
        return image

    def peak(self, frame: np.ndarray) -> tuple[float, int, np.ndarray] | None:
        """The best coarse correlation peak: (value, hypothesis, top-left corner in level-0
        pixels), or None when the frame is smaller than every template."""
        small = self._down(frame)
        best = None
        for k, (_, _, coarse, _) in enumerate(self.hypotheses):
            th, tw = coarse.shape
            if small.shape[0] < th or small.shape[1] < tw or min(th, tw) < 4:
                continue
            score = self._cv2.matchTemplate(small, coarse, self._cv2.TM_CCOEFF_NORMED)
            _, value, _, (bx, by) = self._cv2.minMaxLoc(score)
            if best is None or value > best[0]:
                best = (float(value), k, np.array([bx, by]) * (1 << REACQUIRE_LEVEL))
        return best

    def find(self, frame: np.ndarray, init: np.ndarray) -> tuple[np.ndarray, float] | None:
        found = self.peak(frame)
        if found is None or not found[0] >= REACQUIRE_NCC:
            return None
        M, template, _, origin = self.hypotheses[found[1]]
        step = 1 << REACQUIRE_LEVEL
        th, tw = template.shape
        h, w = frame.shape
        x0, y0 = np.clip(found[2] - step, 0, [w - tw, h - th])
        x1, y1 = np.clip(found[2] + step, 0, [w - tw, h - th])
        window = frame[y0:y1 + th, x0:x1 + tw]
        score = self._cv2.matchTemplate(window, template, self._cv2.TM_CCOEFF_NORMED)
        _, value, _, (bx, by) = self._cv2.minMaxLoc(score)
        shift = np.array([x0 + bx, y0 + by], dtype=np.float64) - origin
        return init @ M[:, :2].T + M[:, 2] + shift, float(value)


def _one_pass(frames: Callable[[], Iterable[np.ndarray]], init: np.ndarray, mesh, options,
              n_hint: int | None, progress: bool, desc: str, reacquire: bool = True):
    from tqdm.auto import tqdm

    pts, conf, lost = [], [], []
    reacquired = []
    tracker = search = first = None
    shape = None
    streak = 0  # frames in a row with more than REACQUIRE_LOST_SHARE of the points lost
    with tqdm(total=n_hint, desc=desc, unit="frame", disable=not progress, leave=False) as bar:
        for t, frame in enumerate(frames()):
            g = _grey(frame, t, shape)
            if tracker is None:
                shape = g.shape
                _check_inside(init, shape)
                tracker = _core.SpringMeshTracker(g, init, mesh, options)
                first = g
                pts.append(init.copy())
                conf.append(np.ones(len(init)))
                lost.append(np.zeros(len(init), dtype=bool))
            else:
                r = tracker.track(g)
                if reacquire and streak >= REACQUIRE_FRAMES:
                    # Lost for long enough: look for the face over the whole frame, restart the
                    # mesh where it is found and track this frame again from there (the search's
                    # templates are cut from the first frame when it is first needed).
                    search = search or _FaceSearch(first, init)
                    found = search.find(g, init)
                    if found is not None:
                        tracker.relocate(found[0])
                        r = tracker.track(g)
                        if np.mean(r.lost) <= REACQUIRE_LOST_SHARE:
                            reacquired.append(t)
                streak = streak + 1 if np.mean(r.lost) > REACQUIRE_LOST_SHARE else 0
                pts.append(np.asarray(r.points))
                conf.append(np.asarray(r.confidence))
                lost.append(np.asarray(r.lost, dtype=bool))
                if reacquire and streak >= REACQUIRE_FRAMES:
                    # The face is gone: the few points that still match something (a hand's
                    # texture, the background) are not on it, so every point of these frames is
                    # lost (and the springs re-estimated from the pass do not learn from them):
                    # the run's first frames when it is recognised, then each frame of it.
                    for q in range(1, (REACQUIRE_FRAMES if streak == REACQUIRE_FRAMES else 1) + 1):
                        lost[-q] = np.ones(len(init), dtype=bool)
            bar.update(1)
    if tracker is None:
        raise ValueError("the sequence holds no frames; nothing to track")
    return np.stack(pts), np.stack(conf), np.stack(lost), reacquired


def _track(frames: Callable[[], Iterable[np.ndarray]], init_points, *, fps: float, edges=None,
           passes: int = 2, relative_sigma: float = 0.05, min_sigma: float = 0.5,
           initial_min_sigma: float | None = None, lips: bool | None = None, eyes: bool | None = None,
           n_hint: int | None = None, progress: bool = True, names=None, scale: float = 1.0,
           work_shape=None, reacquire: bool = True, **options) -> TrackResult:
    """Tracks ``frames`` (already resized by ``scale``, of shape ``work_shape``) from the
    full-resolution ``init_points``; the tracker runs in the resized frames, the result is
    mapped back to full-resolution pixels."""
    init = _check_points(init_points, "init_points")
    if scale != 1.0:
        # A point on the last full-resolution pixel can map past the last resized one (the
        # resized size is rounded): clamp into the resized image.
        h, w = work_shape
        init = np.clip(points_to_working(init, scale), 0.0, [w - 1.0, h - 1.0])
    if lips is None:
        lips = len(init) == 68
    if eyes is None:
        eyes = len(init) == 68
    for flag, on in (("lips", lips), ("eyes", eyes)):
        if on and len(init) != 68:
            raise ValueError(f"{flag}=True needs the 68 points of the iBUG 300-W layout, got {len(init)} points; "
                             f"pass {flag}=False (or patch_sides and search_radius yourself)")
    if lips or eyes:
        # Half patches: the lips on the side away from the mouth opening, the eye corners on the
        # side away from their eye.
        options.setdefault("patch_sides", (lip_patch_sides(init) if lips else 0.0)
                           + (eye_corner_sides(init) if eyes else 0.0))
    if lips:
        iod = float(np.linalg.norm(init[45] - init[36]))
        options.setdefault("search_radius", LIP_SEARCH_IOD * iod)
        groups = np.where(_IS_LOWER_LIP, 0, -1).astype(np.int64)
        options.setdefault("search_groups", groups)
        options.setdefault("group_search_radius", LIP_GROUP_SEARCH_IOD * iod)
        options.setdefault("spring_outlier", LIP_SPRING_OUTLIER)
        options.setdefault("reference_points", np.asarray(OUTER_MOUTH_CORNERS + OUTER_UPPER_LIP, dtype=np.int64))
        reference_sides = np.zeros((68, 2))
        reference_sides[list(OUTER_UPPER_LIP)] = lip_patch_sides(init)[62]  # up the face
        options.setdefault("reference_sides", reference_sides)
        options.setdefault("reference_search_radius", LIP_SEARCH_IOD * iod)
        lip_floor = LIP_SPRING_FLOOR_IOD * iod
    if passes < 1:
        raise ValueError(f"passes must be >= 1 (tracking passes with spring re-estimation), got {passes}")
    if edges is None:
        edges = delaunay_edges(init)
    edges = np.ascontiguousarray(edges, dtype=np.int64)
    if edges.ndim != 2 or edges.shape[1] != 2 or len(edges) == 0:
        raise ValueError(f"edges must have shape (E, 2) with E >= 1, got {edges.shape}")
    mesh = _core.springs_from_points(init, edges, relative_sigma,
                                     0.0 if initial_min_sigma is None else initial_min_sigma)
    if lips:
        mesh = _lip_springs(init, edges, mesh, relative_sigma, min_sigma, lip_floor)
        options.setdefault("outlier_edges", _checked_lip_edges(edges))
    # The head pose the templates, half patches and springs follow: the nose and eye corners of
    # a 68-point face, otherwise all points (frame_points=() for the image frame).
    options.setdefault("frame_points", np.asarray(FACE_FRAME_POINTS if len(init) == 68 else range(len(init)),
                                                  dtype=np.int64))
    opts = _options(options)
    # The first pass's lip springs are guesses: their check on the data (spring_outlier) waits
    # for the springs re-estimated from a pass.
    first_opts = _options({**options, "spring_outlier": 0.0}) if lips else opts
    frame_points = np.asarray(options.get("frame_points", np.zeros(0)), dtype=np.int64)
    history = []
    prev = None
    for k in range(passes):
        pts, conf, lost, reacquired = _one_pass(frames, init, mesh, first_opts if k == 0 else opts, n_hint,
                                                progress, f"tracking pass {k + 1}/{passes}", reacquire)
        row = {"pass": k + 1, "lost_fraction": float(lost.mean()), "reacquired": reacquired,
               "mean_point_change": None if prev is None else float(np.linalg.norm(pts - prev, axis=2).mean()),
               "max_rel_length_change": None, "max_length_change": None}
        if k + 1 < passes:
            new = _core.estimate_springs(pts.reshape(len(pts), -1), lost, mesh, min_sigma, frame_points)
            old_len = np.asarray(mesh.rest_length)
            change = np.abs(np.asarray(new.rest_length) - old_len)
            row["max_rel_length_change"] = float(np.max(change / old_len))
            row["max_length_change"] = float(np.max(change))
            mesh = _soften_opening(new, edges, lip_floor) if lips else new
        history.append(row)
        prev = pts
    rest_length, stiffness = np.asarray(mesh.rest_length), np.asarray(mesh.stiffness)
    if scale != 1.0:  # back to full-resolution pixels
        pts = points_to_full(pts, scale)
        rest_length, stiffness = rest_length / scale, stiffness * scale**2
        for row in history:
            for key in ("mean_point_change", "max_length_change"):
                if row[key] is not None:
                    row[key] /= scale
    return TrackResult(points=pts, confidence=conf, lost=lost, fps=float(fps), edges=edges,
                       rest_length=rest_length, stiffness=stiffness,
                       passes=history, names=list(names) if names is not None else None, working_scale=scale,
                       reacquired=list(reacquired))


def track_frames(frames: Sequence[np.ndarray] | np.ndarray, init_points, *, fps: float = 29.97,
                 edges=None, passes: int = 2, progress: bool = False, working_scale="auto",
                 **options) -> TrackResult:
    """Tracks landmarks through frames held in memory.

    Parameters
    ----------
    frames : (T, H, W) uint8 grey frames (or a sequence of (H, W) uint8 / (H, W, 3) BGR frames)
    init_points : (P, 2) positions (x, y) on frame 0, P >= 3, inside the image
    fps : frame rate recorded in the result
    edges : (E, 2) spring edges; default: the Delaunay triangulation of ``init_points``
    passes : tracking passes; after each but the last, spring lengths and stiffnesses are
        re-estimated from the tracked distances (mean and variance), as in the paper
    progress : show a tqdm progress bar
    working_scale : ``"auto"`` (default) or a factor in (0, 1]: a face larger than the one the
        tracker was tuned on (outer eye corners more than ``LARGE_FACE_IOD`` = 128 px apart;
        other layouts: see :func:`face_size`) is tracked on frames resized down by one factor
        for the whole sequence (area averaging), so that they are ``WORKING_IOD`` = 112 px
        apart; faces at or below 128 px are tracked at full resolution, as before. The points are returned in full-resolution pixels and the
        factor as ``TrackResult.working_scale``; pixel-valued options (``patch_radius``,
        ``search_radius``, ``min_sigma``, ...) are pixels of the resized frames.
        See :func:`working_scale_factor`
    **options : fields of the C++ ``TrackerOptions`` (patch_radius, levels, ncc_floor, ...,
        ``patch_sides`` (P, 2) half-patch directions, ``search_radius`` px, ``frame_points``:
        the points whose similarity to frame 0 is the head pose that the first-frame templates,
        half patches, search radii and spring lengths follow through in-plane rotation and
        scale; default the nose and eye corners of a 68-point face (``FACE_FRAME_POINTS``),
        all points otherwise; ``()`` for the image frame) and
        ``relative_sigma`` (initial spring std as a fraction of length), ``min_sigma`` (px floor
        of re-estimated spring std), ``initial_min_sigma`` (px floor of the initial spring std;
        default none), ``lips`` (lip tracking for a 68-point iBUG layout:
        :func:`lip_patch_sides` half patches, a search radius of 0.065 inter-ocular distances,
        initial springs from the lips to the face no stiffer than a std of 0.025 inter-ocular
        distances, offset springs between lip points (a Gaussian on the face-frame vector
        between them: stiff along the lip contours, soft along the face's vertical axis across
        the mouth opening; ``frame_points`` the nose and eye corners), the lower lip searched
        for as one group within 0.15 inter-ocular distances (``search_groups``,
        ``group_search_radius``) and, from the second pass, a lip point further than 6
        standard deviations of its within-lip springs (and a mouth corner's springs to the
        lower lip) from where they put it handed to them for the frame (``spring_outlier``,
        ``outlier_edges``), the outer mouth corners searched for against their first-frame
        patches within the lip search radius and the outer upper lip against the upper half of
        theirs along the face's vertical (``reference_points``, ``reference_sides``,
        ``reference_search_radius``, ``reference_search_ncc``); default: on when there are 68
        points; explicit options win), ``eyes`` (the eye corners 36, 39, 42, 45 of a 68-point
        layout tracked on the half of their patches away from their eye, so the lids do not
        drag them in blinks: :func:`eye_corner_sides`; default: on when there are 68 points),
        ``reacquire`` (default True: a face lost for :data:`REACQUIRE_FRAMES` frames, more than
        :data:`REACQUIRE_LOST_SHARE` of its points lost, is searched for over the whole frame
        each frame until found, the mesh restarted where it is (``TrackResult.reacquired``), and
        the frames it is gone have every point lost; False: points stay where they were lost)

    Returns
    -------
    TrackResult
    """
    if len(frames) == 0:
        raise ValueError("frames is empty: the sequence holds no frames; nothing to track")
    scale = working_scale_factor(init_points, working_scale)
    work_shape = None
    if scale != 1.0:
        from voicepuppet.tracking import video

        first = _grey(frames[0], 0, None)
        _check_inside(_check_points(init_points, "init_points"), first.shape)
        frames = [video.downscale(_grey(f, t, first.shape), scale) for t, f in enumerate(frames)]
        work_shape = frames[0].shape
    return _track(lambda: iter(frames), init_points, fps=fps, edges=edges, passes=passes,
                  n_hint=len(frames), progress=progress, scale=scale, work_shape=work_shape, **options)


def track_video(path: str | os.PathLike, init: str | os.PathLike | np.ndarray = "auto", *,
                names=None, edges=None, passes: int = 2, progress: bool = True, cache_bytes: int = 1 << 30,
                working_scale="auto", **options) -> TrackResult:
    """Tracks landmarks through a video file.

    Parameters
    ----------
    path : a video OpenCV can decode
    init : (P, 2) points on the first frame, a JSON/CSV file of them (see
        :func:`load_init_points`), or ``"auto"`` for a landmark detector (:func:`auto_init`);
        with ``"auto"`` and no face on the first frame, one frame every
        :data:`AUTO_INIT_STRIDE_S` s of the first :data:`AUTO_INIT_SCAN_S` s is looked at
        (:func:`first_face`), and tracking starts on the earliest frame with a face (a warning
        says where; the frames before it are lost, ``TrackResult.start``)
    edges, passes, progress, working_scale, **options : as in :func:`track_frames`
    cache_bytes : decoded grey frames (at the working scale: resized ones when the face is
        large) are kept in memory up to this size when ``passes > 1``; longer videos are
        decoded again for each pass

    Raises ``ValueError`` for a video that cannot be opened or holds no frames, bad points, or
    (with ``init="auto"``) no detector or no face.
    """
    from voicepuppet.tracking import video

    info = video.probe_video(path)
    fps = info.fps if info.fps > 0 else 29.97
    if names is not None and (isinstance(init, (str, os.PathLike))):
        raise ValueError("names go with init points given as an array, not with a points file (which "
                         "carries its own) or 'auto'")
    frames_iter = video.iter_frames(path)
    first = next(frames_iter, None)
    frames_iter.close()  # releases the decoder now rather than at garbage collection
    if first is None:
        raise ValueError(f"video {str(path)!r} holds no decodable frames; check the file")
    times = video.frame_times(path)
    start = 0
    if isinstance(init, str) and init == "auto":
        try:
            start, first, points = first_face(path, first, fps, progress)
        except NoFaceError as exc:
            raise NoFaceError(f"--init auto: {exc}; pass the first-frame points with --init points.json") from None
        if start:
            when = times[start] if times is not None and start < len(times) else start / fps
            warnings.warn(f"--init auto: no face on the first frame of {str(path)!r}; found one at "
                          f"frame {start} ({when:.2f} s), where tracking starts (the {start} frames "
                          "before it are lost)", stacklevel=2)
    elif isinstance(init, (str, os.PathLike)):
        points, names = load_init_points(init)
    else:
        points = init
    scale = working_scale_factor(points, working_scale)
    work_shape = None
    if scale != 1.0:
        _check_inside(_check_points(points, "init_points"), first.shape)
        first = video.downscale(first, scale)
        work_shape = first.shape

    def decode():
        return itertools.islice(video.iter_frames(path, scale=scale), start, None)

    need = max(info.frame_count - start, 0) * first.size
    if passes > 1 and 0 < need <= cache_bytes:
        frames = np.stack(list(decode()))
        source = lambda: iter(frames)  # noqa: E731
        n_hint = len(frames)
    else:
        source = decode
        n_hint = (info.frame_count - start) or None
    result = _track(source, points, fps=fps, edges=edges, passes=passes, n_hint=n_hint,
                    progress=progress, names=names, scale=scale, work_shape=work_shape, **options)
    if start:
        result = _lost_before(result, start)
    if times is not None and len(times) == len(result.points):  # else OpenCV decoded others
        result.times = times
        slip = video.grid_slip(times, fps)
        if slip > video.MAX_GRID_SLIP:
            # The rate it runs at most of the time, not OpenCV's average: the grid train resamples onto.
            result.fps = video.nominal_rate(times)
            step = np.diff(times) * 1e3
            warnings.warn(f"{str(path)!r} has a variable frame rate (frames {step.min():.1f}-{step.max():.1f} ms "
                          f"apart: at OpenCV's average of {fps:g} fps a frame's index would put it up to "
                          f"{slip:.1f} frames off its time); each frame's time is kept (the landmarks' times "
                          f"and the .csv's time column), the frame rate is its most common, {result.fps:g} "
                          "fps, and train resamples onto it", VariableFrameRateWarning, stacklevel=2)
    return result


def first_face(path, first: np.ndarray, fps: float, progress: bool = False,
               grey: bool = True) -> tuple[int, np.ndarray, np.ndarray]:
    """``(frame index, frame, 68 points)`` of the first frame of the video ``path`` that
    :func:`auto_init` finds a face on: ``first`` (its first frame, as decoded), else the first
    probe (one frame every :data:`AUTO_INIT_STRIDE_S` s up to :data:`AUTO_INIT_SCAN_S` s at
    ``fps``) with a face, or the earliest of the frames since the probe before it that has one;
    after the first frame the detector upsamples only up to :data:`PROBE_MAX_PIXELS`. The frame
    is returned as decoded: grey, or BGR without ``grey``. Raises :class:`NoFaceError` if none
    has a face."""
    from tqdm.auto import tqdm

    from voicepuppet.tracking import video

    try:
        return 0, first, auto_init(first)
    except NoFaceError:
        pass
    stride = max(1, int(round(AUTO_INIT_STRIDE_S * fps)))
    last = int(AUTO_INIT_SCAN_S * fps)
    frames = video.iter_frames(path, grey=grey)
    seen = 0
    try:
        with tqdm(total=last // stride, desc="looking for a face", unit="frame", disable=not progress,
                  leave=False) as bar:
            since = []  # the frames after the last probe: the face may have come in among them
            for t, frame in enumerate(itertools.islice(frames, last + 1)):
                seen = t + 1
                if t == 0:
                    continue
                if t % stride:
                    since.append((t, frame))
                    continue
                bar.update(1)
                try:
                    points = auto_init(frame, max_pixels=PROBE_MAX_PIXELS)
                except NoFaceError:
                    since = []
                    continue
                for u, earlier in since:
                    try:
                        found = auto_init(earlier, max_pixels=PROBE_MAX_PIXELS)
                    except NoFaceError:
                        continue
                    t, frame, points = u, earlier, found
                    break
                return t, frame, points
    finally:
        frames.close()
    cut = (f"; if it comes in later, cut the video to start there (ffmpeg -ss SECONDS -i {Path(path).name} "
           "start.mp4)") if seen > last else ""
    raise NoFaceError(f"no face in the first {seen / fps:.1f} s of {str(path)!r} (the first frame, then one "
                      f"every {AUTO_INIT_STRIDE_S:g} s); check that the face is in view, upright and lit{cut}")


def _lost_before(result: TrackResult, start: int) -> TrackResult:
    """``result`` (tracked from frame ``start``) with the ``start`` frames before it prepended as
    lost, their points those of its first frame; frame indices and lost shares of the whole video."""
    from dataclasses import replace

    T, P = result.lost.shape
    passes = [{**row, "lost_fraction": (row["lost_fraction"] * T + start) / (T + start),
               "reacquired": [t + start for t in row["reacquired"]]} for row in result.passes]
    return replace(result,
                   points=np.concatenate([np.repeat(result.points[:1], start, axis=0), result.points]),
                   confidence=np.concatenate([np.zeros((start, P)), result.confidence]),
                   lost=np.concatenate([np.ones((start, P), dtype=bool), result.lost]),
                   passes=passes, reacquired=[t + start for t in result.reacquired], start=start)


#: On the uniform grid of :func:`on_uniform_grid`, a frame between two video frames further apart
#: than this many frame periods (the camera stalled) is lost rather than interpolated.
MAX_GAP_FRAMES = 3.0


def on_uniform_grid(points, lost, times, fps: float, where: str = ""):
    """Tracked points on the frame grid ``k / fps`` of the audio features; returns ``(points, lost)``.

    ``times`` are the frames' time stamps (s, the first at 0: ``TrackResult.times``, or the
    ``times`` of a landmarks file), None for frame ``k`` at ``k / fps``. Within
    :data:`voicepuppet.tracking.video.MAX_GRID_SLIP` frame periods of that everywhere, the points are
    returned as they are; otherwise (a variable frame rate, or another video's rate) they are
    interpolated linearly in time onto the grid, with a warning: a grid frame is lost if either
    video frame around it is, or if they are more than :data:`MAX_GAP_FRAMES` periods apart.
    """
    from voicepuppet.tracking.video import MAX_GRID_SLIP, grid_slip

    points = np.asarray(points, dtype=np.float64)
    T = len(points)
    lost = np.zeros(points.shape[:2], dtype=bool) if lost is None else np.asarray(lost, dtype=bool).reshape(T, -1)
    if times is None:
        return points, lost
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    if len(times) != T:
        raise ValueError(f"{where}{len(times)} frame times for {T} frames; track the video again")
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError(f"{where}frame times must be finite and increasing; track the video again")
    if T < 2 or grid_slip(times, fps) <= MAX_GRID_SLIP:
        return points, lost
    times = times - times[0]
    grid = np.arange(int(np.floor(times[-1] * fps + 1e-9)) + 1) / fps
    i = np.clip(np.searchsorted(times, grid, side="right") - 1, 0, T - 2)
    w = np.clip((grid - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
    out = (1.0 - w)[:, None, None] * points[i] + w[:, None, None] * points[i + 1]
    # inside a stall (not on the frames around it)
    gap = ((times[i + 1] - times[i]) > MAX_GAP_FRAMES / fps) & (w > 1e-6) & (w < 1.0 - 1e-6)
    out_lost = lost[i] | (lost[i + 1] & (w > 0)[:, None]) | gap[:, None]
    step = np.diff(times) * 1e3
    warnings.warn(f"{where}the video's frames are not on the training's {fps:g} fps grid (they are "
                  f"{step.min():.1f}-{step.max():.1f} ms apart); its {T} tracked frames are resampled to "
                  f"{len(grid)} on the grid, to line up with the audio"
                  + (f" ({int(gap.sum())} in gaps longer than {MAX_GAP_FRAMES:g} frames are lost)" if gap.any() else ""),
                  stacklevel=2)
    return out, out_lost


def load_init_points(path: str | os.PathLike) -> tuple[np.ndarray, list | None]:
    """Reads first-frame points: JSON ``{"points": [[x, y], ...], "names": [...]}`` (names
    optional) or CSV with one ``x,y`` row per point (an optional header row is skipped).

    Points of the 68-point layout that share a position (a closed mouth in whole pixels) are
    moved :data:`SEPARATE_PX` apart as :func:`auto_init` moves dlib's, with a warning; other
    layouts keep them (the spring mesh then refuses the pair, naming it).

    Returns ``(points (P, 2), names or None)``.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"init points file {str(p)!r} does not exist; pass a JSON or CSV file, or --init auto")
    text = p.read_text(encoding="utf-8")
    names = None
    if p.suffix.lower() == ".json":
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"init points file {str(p)!r} is not valid JSON: {exc}") from exc
        if not isinstance(doc, dict) or "points" not in doc:
            raise ValueError(f'init points file {str(p)!r} must hold {{"points": [[x, y], ...]}}')
        try:
            pts = np.asarray(doc["points"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"init points in {str(p)!r} must be a list of [x, y] numbers") from exc
        names = doc.get("names")
        if names is not None and len(names) != len(pts):
            raise ValueError(f"init points file {str(p)!r} has {len(pts)} points but {len(names)} names")
    else:
        rows = []
        for k, line in enumerate(text.splitlines()):
            cells = [c.strip() for c in line.split(",") if c.strip()]
            if not cells:
                continue
            try:
                rows.append([float(cells[0]), float(cells[1])])
            except (ValueError, IndexError):
                if k == 0:
                    continue  # header
                raise ValueError(f"init points file {str(p)!r} line {k + 1} is not 'x,y': {line!r}") from None
        pts = np.asarray(rows, dtype=np.float64).reshape(-1, 2)
    pts = _check_points(pts, f"points in {str(p)!r}")
    if len(pts) == N_POINTS:
        separated = _separate_coincident(pts)
        moved = np.flatnonzero(np.any(separated != pts, axis=1))
        if len(moved):
            warnings.warn(f"points {', '.join(map(str, moved))} in {str(p)!r} share positions (a closed mouth "
                          f"given in whole pixels?); moved {SEPARATE_PX:g} px apart as --init auto does",
                          stacklevel=2)
        pts = separated
    return pts, names


def auto_init(frame: np.ndarray, instead: str = "--init points.json",
              max_pixels: int | None = None, min_score: float | None = None) -> np.ndarray:
    """Finds 68 face landmarks on a frame with dlib's shape predictor (iBUG 300-W layout).

    dlib's detector looks at the frame, then (no face found) at it upsampled once and twice, each
    time twice the size on a side for faces half as small; with ``max_pixels`` only the sizes of
    at most that many pixels after the first (see :data:`PROBE_MAX_PIXELS`). Of several faces
    the largest of those the detector is sure of (:data:`SURE_FACE_SCORE`) is taken, else its
    surest: the largest alone took the astronaut's badge (score 0.05) over her face (1.50). With
    ``min_score``, detections scoring less are no face.

    Needs the ``dlib-bin`` (or ``dlib``) wheel and the model file from Debian's ``libdlib-data``
    (``/usr/share/dlib/shape_predictor_68_face_landmarks.dat``) or the path in the environment
    variable ``VOICEPUPPET_DLIB_MODEL``. Raises ``ValueError`` saying what to install, or
    :class:`NoFaceError` (a ``ValueError``) when no face is found; both name ``instead``, the
    caller's way to give the points by hand. Returns (68, 2) float64.
    """
    try:
        import dlib
    except ImportError:
        raise ValueError("finding face landmarks automatically needs a detector: pip install dlib-bin and "
                         "apt-get install libdlib-data (dlib's 68-point model), or pass the points with "
                         f'{instead} ({{"points": [[x, y], ...]}})') from None
    candidates = [os.environ.get("VOICEPUPPET_DLIB_MODEL", "")] + list(DLIB_MODEL_PATHS)
    model = next((c for c in candidates if c and Path(c).is_file()), None)
    if model is None:
        raise ValueError("finding face landmarks automatically: dlib is installed but not its 68-point model: "
                         "apt-get install libdlib-data, or set VOICEPUPPET_DLIB_MODEL to "
                         f"shape_predictor_68_face_landmarks.dat, or pass the points with {instead}")
    g = _grey(frame, 0, None)
    faces = []
    with _DLIB_LOCK:
        for upsample in (0, 1, 2):
            if upsample and max_pixels is not None and g.size * 4 ** upsample > max_pixels:
                break
            faces, scores, _ = _dlib_detector().run(g, upsample, 0.0)
            if min_score is not None:
                faces, scores = [f for f, s in zip(faces, scores) if s >= min_score], \
                    [s for s in scores if s >= min_score]
            if len(faces):
                break
        if not len(faces):
            raise NoFaceError(f"dlib's detector found no face on the frame; pass the points with {instead}")
        sure = [f for f, s in zip(faces, scores) if s >= SURE_FACE_SCORE]
        face = max(sure, key=lambda r: r.width() * r.height()) if sure else faces[int(np.argmax(scores))]
        shape = _dlib_predictor(model)(g, face)
    points = np.array([[shape.part(i).x, shape.part(i).y] for i in range(shape.num_parts)], dtype=np.float64)
    return _separate_coincident(points)


#: dlib detection score (its SVM margin; 0 is its default threshold) above which a detection is
#: taken for a face: of those the largest is the subject; below, clutter scores (a badge: 0.05).
SURE_FACE_SCORE = 0.5

# dlib's detector takes 0.26 s to build and its 68-point model 0.5 s to load, more than a look
# at a frame: built once per process (a face search looks at up to 120 frames), used one thread
# at a time.
_DLIB_LOCK = threading.Lock()


@functools.lru_cache(maxsize=1)
def _dlib_detector():
    import dlib

    return dlib.get_frontal_face_detector()


@functools.lru_cache(maxsize=2)
def _dlib_predictor(model: str):
    import dlib

    return dlib.shape_predictor(model)


def _separate_coincident(points: np.ndarray) -> np.ndarray:
    """``points`` (68, 2) with the points that share a position moved :data:`SEPARATE_PX` apart.

    dlib gives whole pixels, so on a closed mouth the upper and lower inner lip (61-63 and 67-65)
    land on one pixel, as may a lip corner's outer and inner point; the spring mesh needs distinct
    points. Each point of a shared position moves half the distance away from the others, in the
    direction it lies from them on the neutral face (:func:`voicepuppet.animation.neutral_landmarks`)
    turned by the head's roll (the outer eye corners' line): upper lip up, lower lip down.
    """
    from voicepuppet.animation import neutral_landmarks

    _, index, counts = np.unique(points, axis=0, return_inverse=True, return_counts=True)
    index = index.reshape(-1)
    if counts.max() == 1:
        return points
    ref = neutral_landmarks()
    a, b = OUTER_EYE_CORNERS
    eyes, ref_eyes = points[b] - points[a], ref[b] - ref[a]
    roll = np.arctan2(eyes[1], eyes[0]) - np.arctan2(ref_eyes[1], ref_eyes[0])
    turn = np.array([[np.cos(roll), -np.sin(roll)], [np.sin(roll), np.cos(roll)]])
    out = points.copy()
    for k in np.flatnonzero(counts > 1):
        members = np.flatnonzero(index == k)
        away = (ref[members] - ref[members].mean(axis=0)) @ turn.T
        out[members] += 0.5 * SEPARATE_PX * away / np.linalg.norm(away, axis=1, keepdims=True)
    return out


def save_landmarks(path: str | os.PathLike, result: TrackResult, csv: bool = True) -> list[Path]:
    """Writes ``result`` as ``.npz`` (``points`` [T, P, 2], ``fps``, ``confidence`` [T, P],
    ``lost`` [T, P], ``edges``, ``reacquired`` [R] (frames where a lost face was found again and
    the mesh restarted), ``working_scale``, optional ``names`` and ``times`` [T] (each frame's
    time stamp in the video, s)) and a ``.csv`` twin (``frame, time, x0, y0, ...``; ``time`` the
    time stamp, else frame / fps), each through a temporary file and a rename. Returns the paths
    written."""
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise ValueError(f"landmarks path must end in .npz, got {str(path)!r}")
    if not path.parent.exists():
        raise ValueError(f"output directory {str(path.parent)!r} does not exist; create it first")
    arrays = {"points": result.points.astype(np.float64), "fps": np.float64(result.fps),
              "confidence": result.confidence.astype(np.float64), "lost": result.lost.astype(bool),
              "edges": result.edges.astype(np.int64),
              "reacquired": np.asarray(result.reacquired, dtype=np.int64).reshape(-1),
              "working_scale": np.float64(result.working_scale)}
    if result.names is not None:
        arrays["names"] = np.asarray(result.names, dtype=str)
    if result.times is not None:
        arrays["times"] = np.asarray(result.times, dtype=np.float64)

    with atomic_path(path, (".npz",), "landmarks") as tmp, open(tmp, "wb") as fh:
        write_npz(fh, arrays)  # fixed zip timestamps: equal tracks are equal bytes
    written = [path]
    if csv:
        T, P, _ = result.points.shape
        header = "frame,time," + ",".join(f"x{i},y{i}" for i in range(P))
        times = np.arange(T) / result.fps if result.times is None else result.times
        table = np.column_stack([np.arange(T), times, result.points.reshape(T, -1)])
        csv_path = path.with_suffix(".csv")

        with atomic_path(csv_path, (".csv",), "landmarks") as tmp:
            np.savetxt(tmp, table, fmt=["%d", "%.6f"] + ["%.4f"] * (2 * P), delimiter=",", header=header,
                       comments="")
        written.append(csv_path)
    return written


def load_landmarks(path: str | os.PathLike) -> dict:
    """Reads a landmarks ``.npz`` back as a dict of arrays (``points``, ``fps``, ...).

    Raises ``FileNotFoundError`` for a missing file, ``ValueError`` for the ``.csv`` twin (it
    lacks the frame rate and the lost flags: the ``.npz`` beside it is the one to read) or
    anything that is not an ``.npz`` archive."""
    import zipfile

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"landmarks file {str(p)!r} does not exist; make one with voicepuppet track")
    if p.suffix.lower() == ".csv":
        raise ValueError(f"{str(p)!r} is the .csv twin of a landmarks file: it has no frame rate or lost "
                         f"flags; pass the .npz that voicepuppet track wrote beside it ({p.with_suffix('.npz').name})")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"landmarks file {str(p)!r} is not an .npz archive (truncated or another format); "
                         "make one with voicepuppet track")
    with np.load(p, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


# ----------------------------------------------------------------------------------- CLI

def _cli(args) -> int:
    from tqdm.auto import tqdm

    from voicepuppet.tracking import video

    init = args.init
    if init != "auto" and not Path(init).is_file():
        raise ValueError(f"--init {init!r} is neither 'auto' nor an existing points file")
    out = Path(args.output)
    if out.suffix.lower() != ".npz":
        raise ValueError(f"-o must name a .npz file, got {str(out)!r}")
    working_scale = args.working_scale
    if working_scale != "auto":
        try:
            working_scale = float(working_scale)
        except ValueError:
            working_scale = float("nan")
        if not 0.0 < working_scale <= 1.0:
            raise ValueError(f"--working-scale must be 'auto' or a number in (0, 1] (the factor the frames are "
                             f"resized by; 1 tracks at full resolution), got {args.working_scale!r}")
    result = track_video(args.video, init, passes=args.passes, progress=not args.quiet,
                         patch_radius=args.patch_radius, levels=args.levels, working_scale=working_scale,
                         reacquire=not args.no_reacquire)
    written = save_landmarks(out, result)
    if args.overlay:
        # Every frame once, at the video's average rate: as long as the video (a variable-rate
        # video's nominal fps would play it faster).
        T = len(result.points)
        rate = result.fps if result.times is None or T < 2 else (T - 1) / float(result.times[-1])
        with tqdm(total=T, desc="overlay", unit="frame", disable=args.quiet, leave=False) as bar:
            video.write_overlay(args.overlay, video.iter_frames(args.video, grey=False), result.points,
                                result.lost, rate, result.edges, progress=bar.update)
        written.append(Path(args.overlay))
    T, P, _ = result.points.shape
    for row in result.passes:
        change = row["max_length_change"]
        moved = row["mean_point_change"]
        print(f"pass {row['pass']}: lost {100 * row['lost_fraction']:.1f}% of point-frames"
              + (f", points moved {moved:.3f} px on average from the previous pass" if moved is not None else "")
              + (f", spring lengths re-estimated (largest change {change:.2f} px)" if change is not None else ""))
    if result.reacquired:
        print(f"face lost and found again (mesh restarted) at frame{'s' if len(result.reacquired) > 1 else ''} "
              + ", ".join(f"{t} ({t / result.fps:.2f} s)" for t in result.reacquired))
    if result.working_scale != 1.0:
        print(f"large face: tracked on frames resized by {result.working_scale:.4f} "
              f"(--working-scale; points written in full-resolution pixels)")
    print(f"tracked {P} points through {T} frames; wrote {', '.join(str(w) for w in written)}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("track", help="track facial landmarks through a video (spring-mesh SSD tracker)",
                       description="Track facial landmarks through a video with the spring-mesh SSD "
                                   "tracker of Voice Puppetry §4.1; writes landmarks.npz and a .csv twin.")
    p.add_argument("video", help="input video (anything OpenCV decodes)")
    p.add_argument("-o", "--output", required=True, metavar="LANDMARKS.npz", help="output landmarks (.npz; a .csv twin is written beside it)")
    p.add_argument("--init", default="auto", metavar="POINTS.json|auto",
                   help='first-frame points: JSON {"points": [[x, y], ...]} or CSV x,y rows, or "auto" '
                        "(dlib 68-point detector on the first frame with a face, looked for in the first "
                        f"{AUTO_INIT_SCAN_S:g} s; needs dlib-bin and libdlib-data). Default: auto")
    p.add_argument("--overlay", metavar="OUT.mp4", help="also write a video with the tracked mesh drawn on it")
    p.add_argument("--passes", type=int, default=2, help="tracking passes with spring re-estimation between them (default 2)")
    p.add_argument("--patch-radius", type=int, default=6, help="SSD patch radius in pixels (default 6: 13x13)")
    p.add_argument("--levels", type=int, default=3, help="image pyramid levels (default 3)")
    p.add_argument("--working-scale", default="auto", metavar="auto|F",
                   help="track a large face on frames resized down by F in (0, 1]; auto (default): a face "
                        f"with outer eye corners more than {LARGE_FACE_IOD:g} px apart is resized so that they "
                        f"are {WORKING_IOD:g} px apart (other layouts: the RMS radius of the init points, "
                        f"{LARGE_FACE_RMS_RADIUS:.1f} and {WORKING_RMS_RADIUS:.1f} px), smaller faces are tracked "
                        "at full resolution. Points are written in full-resolution pixels; --patch-radius is "
                        "in pixels of the resized frames")
    p.add_argument("--no-reacquire", action="store_true",
                   help="do not search the whole frame for a face lost for a few frames (by default the "
                        "mesh is restarted where the face is found again)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cli)
