"""The face mesh a landmark animation drives (Brand §4.6): :class:`FaceMesh` and its skin's depth.

A :class:`FaceMesh` is a textured triangle mesh in image coordinates whose first vertices are the
face's landmarks. It comes from a photo (:func:`voicepuppet.render.photo.build_face_mesh`) or a
textured 3-D head scan (:func:`voicepuppet.render.head.load_head`); behind its lips lies the mouth's
interior (:mod:`voicepuppet.render.interior`), placed below the skin's depth surface
(:func:`skin_depth`: an ellipsoidal cap over the landmarks plus a nose bump).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from voicepuppet import layout as face_layout

__all__ = ["FaceMesh", "skin_depth", "MOUTH_COLOUR"]

#: the flat colour of the mouth's cavity (RGB), before it is scaled to a photo's tones
MOUTH_COLOUR = (70, 18, 24)


def skin_depth(xy: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """The skin's depth surface of a photo's face: an ellipsoidal cap over the landmarks' box
    (its radii 0.55 of the box's extents, its height 0.6 of the horizontal radius) plus, with the
    68-point layout, a Gaussian bump at the nose tip (point 30).

    Parameters
    ----------
    xy : ndarray, shape (N, 2)
        points in pixels (x right, y down).
    landmarks : ndarray, shape (P, 2)
        the face's landmarks in pixels.

    Returns
    -------
    ndarray, shape (N,)
        depth in pixels towards the viewer (0 outside the cap).
    """
    lo, hi = landmarks.min(axis=0), landmarks.max(axis=0)
    centre = 0.5 * (lo + hi)
    radii = np.maximum(0.55 * (hi - lo), 1.0)
    r2 = np.sum(((xy - centre) / radii) ** 2, axis=1)
    z = 0.6 * radii[0] * np.sqrt(np.clip(1.0 - r2, 0.0, None))
    if len(landmarks) == face_layout.N_POINTS:
        tip = landmarks[30]
        sigma = 0.12 * radii[0]
        z += 0.25 * radii[0] * np.exp(-np.sum((xy - tip) ** 2, axis=1) / (2 * sigma ** 2))
    return z


@dataclass
class FaceMesh:
    """A textured face mesh in image coordinates.

    Each parameter is kept as the attribute of the same name.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        x, y in pixels (y down, as in the image) and depth z in pixels (towards the viewer).
        The first ``n_landmarks`` vertices are the landmarks, in order.
    faces : ndarray, shape (F, 3), int64
        triangles (counter-clockwise on screen).
    mouth : ndarray, shape (F,), bool
        the mouth cavity's faces (the inner lip polygon, drawn dark, not textured; its wall down
        from the inner lips) and the tongue's (none when the photo's mouth is open: its own
        interior is the texture there).
    uv : ndarray, shape (V, 2)
        texture coordinates (u right, v up) into ``image``.
    image : ndarray, shape (H, W, 3), uint8
        the texture: the face photo (or a 3-D head's texture).
    n_landmarks : int
        how many of the first vertices are the landmarks (P).
    fixed : ndarray, shape (V,), bool
        vertices that never move (the image frame).
    teeth : ndarray, shape (F,), bool, optional
        the teeth's faces (:func:`voicepuppet.render.interior.mouth_interior`), seen through the cavity
        (default: none).
    colours : ndarray, shape (F, 3), uint8, optional
        the flat colour of the mouth's interior's faces (unused for the textured skin); default
        :data:`MOUTH_COLOUR` on the ``mouth`` faces, zero elsewhere.
    carried : ndarray, shape (V, P), optional
        for the vertices that move rigidly with part of the face (the cavity's copies of the
        inner lips, the tongue, the teeth) their rows of :meth:`interpolation_matrix`; zero rows
        elsewhere (default: all zero).
    canvas : (width, height), optional
        the view's size when it is not the image's: a 3-D head (:mod:`voicepuppet.render.head`), whose
        image is its texture.
    _interp : ndarray, optional
        The interpolation matrix, computed on first use (:meth:`interpolation_matrix`); not to be
        given.

    Notes
    -----
    The mouth's interior lies behind the skin, in layers below the skin's depth surface
    (:data:`voicepuppet.render.interior.INTERIOR_DEPTH`), the cavity deepest, so a renderer with a
    depth buffer shows it through the lips' opening only, and one without draws it first in
    :meth:`draw_order`.
    """

    vertices: np.ndarray
    faces: np.ndarray
    mouth: np.ndarray
    uv: np.ndarray
    image: np.ndarray
    n_landmarks: int
    fixed: np.ndarray
    teeth: Optional[np.ndarray] = None
    colours: Optional[np.ndarray] = None
    carried: Optional[np.ndarray] = field(default=None, repr=False)
    canvas: Optional[tuple[int, int]] = None
    _interp: Optional[np.ndarray] = field(default=None, repr=False)

    def __post_init__(self):
        F, V = len(self.faces), len(self.vertices)
        if self.teeth is None:
            self.teeth = np.zeros(F, bool)
        if self.colours is None:
            self.colours = np.zeros((F, 3), np.uint8)
            self.colours[self.mouth] = MOUTH_COLOUR
        if self.carried is None:
            self.carried = np.zeros((V, self.n_landmarks))

    @property
    def flat(self) -> np.ndarray:
        """(F,) bool: the faces drawn in their flat colour (the cavity, the tongue, the teeth), not textured."""
        return self.mouth | self.teeth

    def draw_order(self) -> np.ndarray:
        """Face indices from back to front for a painter's renderer.

        Returns
        -------
        ndarray, shape (F,), int
            the flat faces by their layer (their depth below the skin's surface: the cavity, the
            tongue, the lower teeth, the upper teeth), then the skin.
        """
        below = self.vertices[:, 2] - skin_depth(self.vertices[:, :2], self.landmarks)
        layer = np.round(below[self.faces].mean(axis=1), 6)  # one value per layer, face order within it
        flat = np.flatnonzero(self.flat)
        return np.concatenate([flat[np.argsort(layer[flat], kind="stable")], np.flatnonzero(~self.flat)])

    @property
    def landmarks(self) -> np.ndarray:
        """The neutral landmark positions, (P, 2)."""
        return self.vertices[: self.n_landmarks, :2]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the view: the photo's, or a 3-D head's canvas."""
        if self.canvas is not None:
            return int(self.canvas[0]), int(self.canvas[1])
        return int(self.image.shape[1]), int(self.image.shape[0])

    def interpolation_matrix(self) -> np.ndarray:
        """The linear map from landmark displacements to vertex displacements.

        Returns
        -------
        ndarray, shape (V, P)
            identity on the landmarks, zero on the fixed frame, the carried rows on the mouth's
            interior, a thin-plate spline (scipy's ``RBFInterpolator``) elsewhere; computed once.
        """
        if self._interp is None:
            from scipy.interpolate import RBFInterpolator

            P = self.n_landmarks
            ctrl = np.vstack([self.landmarks, self.vertices[self.fixed, :2]])
            values = np.zeros((len(ctrl), P))
            values[:P] = np.eye(P)
            # points at one place (closed lips' inner points, say) are one control point, their mean
            ctrl, where = np.unique(np.round(ctrl, 9), axis=0, return_inverse=True)
            where = where.ravel()
            merged = np.zeros((len(ctrl), P))
            np.add.at(merged, where, values)
            values = merged / np.bincount(where, minlength=len(ctrl))[:, None]
            rbf = RBFInterpolator(ctrl, values, kernel="thin_plate_spline")
            M = rbf(self.vertices[:, :2])
            M[:P] = np.eye(P)
            M[self.fixed] = 0.0
            rigid = np.any(self.carried != 0, axis=1)
            M[rigid] = self.carried[rigid]
            self._interp = M
        return self._interp
