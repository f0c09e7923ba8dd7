"""A textured low-polygon face driven by landmark animations, rendered off screen (Brand §4.6).

The face mesh comes from a photo and its landmarks: the landmarks, two rings of border points
around them and a frame on the image edge are triangulated (scipy's Delaunay, about 200
triangles), lifted to 3-D with a smooth depth profile (an ellipsoidal cap plus a nose bump)
and texture-mapped with the photo; with the 68-point layout and the photo's mouth closed, the
mouth's interior (the cavity, the tongue and two arches of teeth, flat-coloured) lies behind the
lips. Any face whose points correspond to the animation's (a cartoon, an animal) works the same
way (§6, figure 7).

Driving, two ways:

- ``mode="vertex"``: landmark displacements move the landmark vertices; every other vertex
  moves by a thin-plate-spline interpolation (scipy's ``RBFInterpolator``) of them, with the
  image frame held still.
- ``mode="au"``: an action-unit basis on the mesh (:data:`ACTION_UNITS`: jaw open, lip corner
  pulls, pucker, lip press, upper lip raise, brow raise, blinks) with per-frame least-squares
  activations; the landmark motion outside the basis span is dropped (reported by
  :func:`fit_activations`).

The animation is retargeted first: its displacements from its rest face
(:attr:`voicepuppet.animation.Animation.rest`: the face its puppet makes in silence, else its
first frame) are mapped onto the photo's landmarks through the similarity transform (scale,
rotation) between the two neutral shapes.

Rendering uses pyvista off screen (headless EGL with Mesa: ``VTK_DEFAULT_OPENGL_WINDOW=
vtkEGLRenderWindow``, set here unless already set) with a parallel camera over the image, so
the neutral frame reproduces the photo. Outputs: ``.mp4`` (H.264 through imageio-ffmpeg, the
audio muxed in from the start, cut to the animation's duration), ``.gif``, a folder of
``.png`` frames; a side-by-side comparison (prediction | ground truth); a fast 2-D landmark
drawing instead of the mesh (``renderer="2d"``).
"""

from __future__ import annotations

import itertools
import os
import shutil
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Optional, Sequence

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet.face import shape_distance
from voicepuppet.animation import Animation, check_points
from voicepuppet._files import atomic_path, check_output_path, publish

__all__ = ["FaceMesh", "build_face_mesh", "portrait_image", "ACTION_UNITS", "action_unit_basis",
           "fit_activations", "retarget", "mesh_animation", "FaceRenderer", "draw_landmarks_2d",
           "render_frames", "write_video", "render", "VIDEO_SUFFIXES", "expression_offset"]

VIDEO_SUFFIXES = (".mp4", ".gif")

#: action units of the basis, in column order; activation 1 is a full expression
ACTION_UNITS = ("jaw_open", "smile_right", "smile_left", "pucker", "lip_press", "upper_lip_raise",
                "brow_raise", "blink_right", "blink_left")

_MOUTH_COLOUR = (70, 18, 24)
_FRAME_CHUNK = 512  # frames of vertices computed at once while rendering


# ------------------------------------------------------------------------------ the mesh

@dataclass
class FaceMesh:
    """A textured face mesh in image coordinates.

    Attributes
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
    n_landmarks : int
    fixed : ndarray, shape (V,), bool
        vertices that never move (the image frame).
    teeth : ndarray, shape (F,), bool
        the teeth's faces (:func:`_interior`), seen through the cavity.
    colours : ndarray, shape (F, 3), uint8
        the flat colour of the mouth's interior's faces (unused for the textured skin).
    carried : ndarray, shape (V, P)
        for the vertices that move rigidly with part of the face (the cavity's copies of the
        inner lips, the tongue, the teeth) their rows of :meth:`interpolation_matrix`; zero rows
        elsewhere.
    canvas : (width, height), optional
        the view's size when it is not the image's: a 3-D head (:mod:`voicepuppet.render.head`), whose
        image is its texture.

    The mouth's interior lies behind the skin, in layers below the skin's depth surface
    (:data:`_INTERIOR_DEPTH`), the cavity deepest, so a renderer with a depth buffer shows it
    through the lips' opening only, and one without draws it first in :meth:`draw_order`.
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
            self.colours[self.mouth] = _MOUTH_COLOUR
        if self.carried is None:
            self.carried = np.zeros((V, self.n_landmarks))

    @property
    def flat(self) -> np.ndarray:
        """(F,) bool: the faces drawn in their flat colour (the cavity, the tongue, the teeth), not textured."""
        return self.mouth | self.teeth

    def draw_order(self) -> np.ndarray:
        """Face indices from back to front for a painter's renderer: the flat faces by their
        layer (their depth below the skin's surface: the cavity, the tongue, the lower teeth, the
        upper teeth), then the skin."""
        below = self.vertices[:, 2] - _depth(self.vertices[:, :2], self.landmarks)
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
        """(V, P) linear map from landmark displacements to vertex displacements: identity on
        the landmarks, zero on the fixed frame, a thin-plate spline elsewhere."""
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


def _ellipse(centre, radii, n, phase=0.0):
    a = phase + np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([centre[0] + radii[0] * np.cos(a), centre[1] + radii[1] * np.sin(a)])


def _frame_points(width, height, per_side=4):
    s = np.linspace(0.0, 1.0, per_side + 1)[:-1]
    w, h = width - 1.0, height - 1.0
    top = np.column_stack([s * w, np.zeros_like(s)])
    right = np.column_stack([np.full_like(s, w), s * h])
    bottom = np.column_stack([w - s * w, np.full_like(s, h)])
    left = np.column_stack([np.zeros_like(s), h - s * h])
    return np.vstack([top, right, bottom, left])


#: The lips' triangles of the 68-point layout, fixed: the ring from the outer contour (48-59) to
#: the inner one (60-67), and the cavity inside the inner contour (drawn dark, or with a photo's
#: open mouth its own teeth and tongue).
_LIP_RING = ((48, 49, 60), (49, 61, 60), (49, 50, 61), (50, 51, 61), (51, 62, 61), (51, 63, 62),
             (51, 52, 63), (52, 53, 63), (53, 64, 63), (53, 54, 64), (54, 55, 64), (55, 65, 64),
             (55, 56, 65), (56, 57, 65), (57, 66, 65), (57, 67, 66), (57, 58, 67), (58, 59, 67),
             (59, 67, 60), (59, 48, 60))
_CAVITY = ((60, 61, 67), (61, 66, 67), (61, 62, 66), (62, 65, 66), (62, 63, 65), (63, 64, 65))
#: The lips are opened this much (vertically, about the corners' line) in the topology shape, so
#: the mouth corners are not so acute that the triangulation skips an outer-lip edge.
_TOPOLOGY_LIP_OPENING = 1.3


def _topology_shape(landmarks: np.ndarray) -> np.ndarray:
    """The landmarks the triangulation is made on (68-point layout): the lips opened
    (:data:`_TOPOLOGY_LIP_OPENING`) and the inner lips pulled apart, halfway to the outer ones,
    whether the photo's mouth is open or closed."""
    topo = landmarks.copy()
    if len(landmarks) != face_layout.N_POINTS:
        return topo
    cy = 0.5 * (landmarks[48, 1] + landmarks[54, 1])
    topo[48:68, 1] = cy + _TOPOLOGY_LIP_OPENING * (landmarks[48:68, 1] - cy)
    mid = 0.5 * (topo[[61, 62, 63]] + topo[[67, 66, 65]])
    topo[[61, 62, 63]] = mid + 0.5 * (topo[[50, 51, 52]] - mid)
    topo[[67, 66, 65]] = mid + 0.5 * (topo[[58, 57, 56]] - mid)
    return topo


def _triangulate(topo: np.ndarray, P: int) -> np.ndarray:
    """Triangles of the mesh on the topology shape: Delaunay, and with the 68-point layout the
    lips by hand (:data:`_LIP_RING`, :data:`_CAVITY`) in the hole the outer lip contour cuts
    out of a Delaunay triangulation without the inner lips, so the cavity is always the inner
    contour's six triangles (Delaunay alone skipped a corner of it on most real faces: 240 of
    274 of the performer's). Falls back to Delaunay of all points should that hole not be the
    outer contour's."""
    import cv2
    from scipy.spatial import Delaunay

    if P != face_layout.N_POINTS:
        return Delaunay(topo).simplices.astype(np.int64)
    keep = np.array([i for i in range(len(topo)) if not 60 <= i < 68])
    faces = keep[Delaunay(topo[keep]).simplices].astype(np.int64)
    outer = np.arange(48, 60)
    contour = topo[outer].astype(np.float32).reshape(-1, 1, 2)
    hole = np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), False) > 0
                     for x, y in topo[faces].mean(axis=1)])
    edges = {frozenset(e) for f in faces.tolist() for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    if np.isin(faces[hole], outer).all() and all(frozenset((int(outer[i]), int(outer[(i + 1) % 12]))) in edges
                                                 for i in range(12)):
        return np.vstack([faces[~hole], np.array(_LIP_RING + _CAVITY, dtype=np.int64)])
    return Delaunay(topo).simplices.astype(np.int64)


def _depth(xy: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
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


#: Inner-lip gap (inter-ocular distances) above which a face's mouth counts as open: a photo's
#: own cavity then textures the mouth, and a photo that open is not at rest (:func:`resolve_face`).
OPEN_MOUTH_IOD = 0.04


def lip_gap_iod(landmarks) -> float:
    """The inner lips' mean gap (pairs 61-67, 62-66, 63-65) of a 68-point face, in inter-ocular
    distances (outer eye corners 36, 45)."""
    lm = np.asarray(landmarks, dtype=np.float64)
    gap = np.mean(np.linalg.norm(lm[[61, 62, 63]] - lm[[67, 66, 65]], axis=1))
    return float(gap / max(float(face_layout.inter_ocular_distance(lm)), 1e-12))


# ------------------------------------------------------------------------------ the mouth's interior

#: The teeth seen through an opened mouth, per arch: the visible teeth's relative widths from one
#: mouth corner to the other, their span (a share of the mouth's width at rest), and in
#: inter-ocular distances below the lip line (the inner lips' mean at rest) the biting edge in the
#: middle, its curve (the edge at the span's ends is this much further below) and the root; the
#: shade of each tooth (the arch turns back into the mouth's shadow; neighbours differ, so they
#: part without a gap, which a renderer without anti-aliasing drew as a broken dark line). The
#: upper edge sits just below the lip line, so an opening shows it, the lower one below that (the
#: teeth apart at rest); both roots lie under the lips at rest. With the upper edge 0.012 below,
#: the sub-pixel slit of closed lips showed teeth as a broken light line (12 of its 18 pixels at the
#: demo's closures; now 4).
_TEETH = {
    "upper": {"widths": (0.55, 0.7, 0.8, 1.0, 1.0, 0.8, 0.7, 0.55), "span": 0.8, "edge": 0.006,
              "curve": -0.035, "root": -0.16, "shade": (0.6, 0.78, 0.9, 1.0, 0.95, 0.88, 0.76, 0.58)},
    "lower": {"widths": (0.6, 0.75, 0.8, 0.85, 0.85, 0.8, 0.75, 0.6), "span": 0.68, "edge": 0.012,
              "curve": 0.03, "root": 0.16, "shade": (0.48, 0.6, 0.7, 0.78, 0.74, 0.68, 0.58, 0.46)},
}
_TOOTH_COLOUR = (232, 226, 208)  # enamel, scaled to the photo's lighting
#: Landmarks the arches move with (68-point layout): the upper teeth with the skull (the nose and
#: the eye corners), the lower with the jaw (its contour from cheek to cheek round the chin) and
#: this share of the lower lip's inner edge's motion beyond the jaw's, as the lip rests on them:
#: the tracked chin moves less than the opening at the lips, and with the jaw alone an opened mouth
#: bared the whole height of the lower teeth. A motion of the whole face moves both arches with it.
_SKULL = face_layout.RIGID
_JAW = (4, 5, 6, 7, 8, 9, 10, 11, 12)
_LOWER_LIP = (65, 66, 67)
_LOWER_LIP_SHARE = 0.6
#: The tongue, a dome behind the lower teeth moving with them: its base and crown below the lip
#: line and its half width (a share of the mouth's), in inter-ocular distances; its colour, scaled
#: to ``luma`` for a photo whose face has luma 150, and the points of its arch.
_TONGUE = {"base": 0.16, "crown": -0.03, "span": 0.62, "colour": (175, 62, 70), "luma": 62.0, "points": 9}
#: Depths below the skin's depth surface (:func:`_depth`) at each vertex, inter-ocular distances:
#: the upper teeth, the lower, the tongue, the cavity. A 3-D viewer sees the teeth a few
#: millimetres behind the lips (on the image plane, 0.5 IOD behind them, they slid away from the
#: mouth at an angle). The first layer lies deeper than the skin's sag between its vertices and
#: its slide over the interior as the lips move (~0.03); the layers apart by more than the depth
#: change of one's slide over the next.
_INTERIOR_DEPTH = {"upper": -0.06, "lower": -0.10, "tongue": -0.14, "cavity": -0.18}


def _affine_weights(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(len(targets), len(points)) weights, each row the smallest (in norm) that sums to one and
    reproduces its target from the points (w @ points = target): the row moves its target exactly
    as any affine motion (shift, rotation, scale, shear) of the points moves it, the same weights
    for x and y, and spreads other motions over all the points."""
    A = np.vstack([np.ones(len(points)), points.T])  # (3, n)
    B = np.vstack([np.ones(len(targets)), targets.T])
    return np.linalg.lstsq(A, B, rcond=None)[0].T


def _photo_tones(image: np.ndarray, landmarks: np.ndarray) -> tuple[float, bool]:
    """The median luma of the face's pixels (inside the landmarks' convex hull) and whether the
    photo is grey (its channels equal there)."""
    import cv2

    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(landmarks).astype(np.int32)), 1)
    return _pixel_tones(image[mask.astype(bool)])


def _pixel_tones(px: np.ndarray) -> tuple[float, bool]:
    """The median luma of the RGB pixels ``px`` (N, 3) and whether they are grey (channels equal)."""
    px = np.asarray(px, np.float64).reshape(-1, 3)
    if len(px) == 0:
        raise ValueError("no face pixels to take the tones of")
    return float(np.median(px @ [0.299, 0.587, 0.114])), bool(np.median(np.ptp(px, axis=1)) < 3.0)


def _tone(colour, luma: Optional[float], grey: bool) -> np.ndarray:
    """``colour`` scaled to the luma ``luma`` (None: kept), grey for a grey photo, as uint8."""
    c = np.asarray(colour, np.float64)
    if luma is not None:
        c = c * luma / max(float(c @ [0.299, 0.587, 0.114]), 1e-9)
    if grey:
        c = np.full(3, c @ [0.299, 0.587, 0.114])
    return np.clip(np.round(c), 0, 255).astype(np.uint8)


def _interior(lm: np.ndarray, tones: tuple[float, bool], cavity: bool = True):
    """The mouth's interior of a 68-point face at rest (its lips closed): the cavity, on its own
    copies of the inner lip points (carried by them, deepest), the tongue (:data:`_TONGUE`) and
    two arches of teeth (:data:`_TEETH`: hexagons with the biting corners cut, fanned into 4
    triangles each), laid out in the face's frame (x along the eye corners, y below) about the lip
    line and carried by the skull's and the jaw's landmarks (:func:`_affine_weights`), coloured to
    the photo's lighting (``tones``: :func:`_photo_tones`). ``cavity=False`` leaves the cavity
    out (a 3-D head has its own behind its cut lips).

    Returns vertices (N, 3) with their depth, faces (F, 3) into them, the teeth's faces (F,) bool
    (the rest are the cavity's and the tongue's), colours (F, 3) uint8 and the carry rows (N, 68)."""
    iod = float(face_layout.inter_ocular_distance(lm))
    ex = (lm[45] - lm[36]) / iod
    ey = np.array([-ex[1], ex[0]])  # below, in image coordinates
    centre = lm[60:68].mean(axis=0)
    half_mouth = 0.5 * abs(float((lm[54] - lm[48]) @ ex)) / iod
    skin, grey = tones
    to_image = lambda u, v: centre + iod * (np.outer(u, ex) + np.outer(v, ey))  # noqa: E731

    def carried_by(part: str, xy: np.ndarray) -> np.ndarray:
        """Rows moving ``xy`` with the skull ("upper") or the jaw and the lower lip ("lower")."""
        group = list(_SKULL if part == "upper" else _JAW)
        rows = np.zeros((len(xy), len(lm)))
        rows[:, group] = _affine_weights(lm[group], xy)
        if part == "lower":  # and a share of the lip's motion beyond the jaw's there
            lip = list(_LOWER_LIP)
            rows[:, group] -= _LOWER_LIP_SHARE * _affine_weights(lm[group], lm[lip].mean(axis=0)[None])
            rows[:, lip] += _LOWER_LIP_SHARE / len(lip)
        return rows

    verts, carry, faces, colours, teeth = [], [], [], [], []
    if cavity:
        inner = list(range(60, 68))
        verts.append(np.column_stack([lm[inner], _depth(lm[inner], lm) + _INTERIOR_DEPTH["cavity"] * iod]))
        carry.append(np.eye(len(lm))[inner])
        faces.append(np.searchsorted(inner, _CAVITY))
        colours.append(np.repeat(_tone(_MOUTH_COLOUR, None, grey)[None], len(_CAVITY), axis=0))
        teeth.append(np.zeros(len(_CAVITY), bool))
    n = len(verts[0]) if verts else 0

    def add(xy, depth, fan, colour, part, is_teeth):
        nonlocal n
        verts.append(np.column_stack([xy, _depth(xy, lm) + depth * iod]))
        carry.append(carried_by(part, xy))
        faces.append(n + np.array([[0, k, k + 1] for k in range(1, fan - 1)]))
        colours.append(np.repeat(colour[None], fan - 2, axis=0))
        teeth.append(np.full(fan - 2, is_teeth))
        n += len(xy)

    # the tongue: a dome behind the lower teeth, its crown just above their edge
    t = _TONGUE
    arc = np.linspace(0.0, np.pi, t["points"])
    u = np.r_[0.0, t["span"] * half_mouth * np.cos(arc)]
    v = np.r_[t["base"], t["base"] + (t["crown"] - t["base"]) * np.sin(arc)]
    add(to_image(u, v), _INTERIOR_DEPTH["tongue"], len(u), _tone(t["colour"], t["luma"] * skin / 150.0, grey),
        "lower", False)
    enamel = min(235.0, 1.6 * skin)
    for arch, spec in _TEETH.items():
        w = np.asarray(spec["widths"], np.float64)
        half = spec["span"] * half_mouth
        bounds = np.concatenate([[0.0], np.cumsum(w)]) / w.sum() * 2 * half - half
        edge = lambda u: spec["edge"] + spec["curve"] * (u / half) ** 2  # noqa: E731
        back = np.sign(spec["root"] - spec["edge"])  # from the biting edge towards the root
        for j in range(len(w)):
            a, b = bounds[j], bounds[j + 1]
            cut = 0.2 * (b - a)
            u = np.array([a, b, b, b - cut, a + cut, a])
            v = np.array([spec["root"], spec["root"], edge(b) + back * cut, edge(b - cut), edge(a + cut),
                          edge(a) + back * cut])
            add(to_image(u, v), _INTERIOR_DEPTH[arch], 6, _tone(_TOOTH_COLOUR, enamel * spec["shade"][j], grey),
                arch, True)
    return (np.vstack(verts), np.vstack(faces).astype(np.int64), np.concatenate(teeth), np.vstack(colours),
            np.vstack(carry))


def build_face_mesh(image: np.ndarray, landmarks, *, rings: Sequence[tuple[float, int]] = ((1.2, 12), (1.5, 16)),
                    frame_per_side: int = 4) -> FaceMesh:
    """Builds the textured face mesh of a photo.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W), uint8 (or float in [0, 1])
    landmarks : ndarray, shape (P, 2)
        the face's points in pixels; with the 68-point layout the mouth cavity and the nose
        bump are known.
    rings : sequence of (scale, count)
        border rings: ellipses around the landmarks' box, scaled from its half extents.
    frame_per_side : int
        fixed points per image edge.

    With 68 landmarks the defaults give 112 vertices and 198-200 triangles of skin, and with the
    mouth closed in the photo the interior's 114 vertices and 94 triangles (the cavity's 6 and its
    wall's 16, the tongue's 8, the teeth's 64).
    """

    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or min(img.shape[:2]) < 8:
        raise ValueError(f"image must be an (H, W, 3) RGB picture of at least 8x8 pixels, got shape {img.shape}")
    if img.dtype != np.uint8:
        img = np.clip(np.asarray(img, dtype=np.float64) * 255.0, 0, 255).astype(np.uint8)
    img = np.ascontiguousarray(img[:, :, :3])
    H, W = img.shape[:2]
    lm = check_points(np.asarray(landmarks, dtype=np.float64)[None], "face landmarks")[0]
    if len(lm) < 3:
        raise ValueError(f"face landmarks must have at least 3 points, got {len(lm)}")
    inside = (lm[:, 0] >= 0) & (lm[:, 0] <= W - 1) & (lm[:, 1] >= 0) & (lm[:, 1] <= H - 1)
    if not inside.all():
        raise ValueError(f"face landmarks must lie inside the {W}x{H} image; {int((~inside).sum())} "
                         f"points are outside (first: {lm[~inside][0]}); were they made for another image?")
    lo, hi = lm.min(axis=0), lm.max(axis=0)
    if np.any(hi - lo < 4.0):
        raise ValueError(f"face landmarks span {hi - lo} pixels; they must outline a face (spread in x and y)")
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    border = []
    for scale, count in rings:
        ring = _ellipse(centre, scale * half, count, phase=np.pi / count)
        ring = np.clip(ring, 2.0, [W - 3.0, H - 3.0])
        border.append(ring)
    frame = _frame_points(W, H, frame_per_side)
    pts = np.vstack([lm] + border + [frame])
    # drop border points that collapsed onto another point (clipped rings in tight crops)
    keep = np.ones(len(pts), bool)
    P = len(lm)
    for i in range(P, len(pts)):
        d = np.linalg.norm(pts[:i][keep[:i]] - pts[i], axis=1)
        if d.size and d.min() < 2.0:
            keep[i] = False
    keep[-len(frame):] = True
    pts = pts[keep]
    fixed = np.zeros(len(pts), bool)
    fixed[-len(frame):] = True
    topo = pts.copy()
    topo[:P] = _topology_shape(lm)
    faces = _triangulate(topo, P)
    z = _depth(pts, lm)
    z[fixed] = 0.0
    vertices = np.column_stack([pts, z])
    V = len(vertices)
    mouth = teeth = np.zeros(len(faces), bool)
    colours = np.zeros((len(faces), 3), np.uint8)
    carried = np.zeros((V, P))
    if P == face_layout.N_POINTS:
        inner = set(range(60, 68))
        cavity = np.array([set(f.tolist()) <= inner for f in faces])
        # a photo with the mouth open shows its own teeth and tongue: its texture is the cavity;
        # a closed one's cavity and teeth are the interior's, behind the lips (laid out in
        # inter-ocular distances: none for eyes closer than 2 px)
        if lip_gap_iod(lm) <= OPEN_MOUTH_IOD and face_layout.inter_ocular_distance(lm) >= 2.0:
            iv, ifaces, iteeth, icolours, icarry = _interior(lm, _photo_tones(img, lm))
            # the cavity's wall from the inner lips down to its copies: edge-on in a frontal view
            # (the copies move with the lips), it closes the mouth's corners in a 3-D viewer
            ring = np.arange(60, 68)
            copy, nxt = V + ring - 60, np.roll(ring, -1)
            wall = np.vstack([np.column_stack([ring, nxt, V + nxt - 60]), np.column_stack([ring, V + nxt - 60, copy])])
            faces = np.vstack([faces[~cavity], V + ifaces, wall])
            n_skin = int((~cavity).sum())
            teeth = np.r_[np.zeros(n_skin, bool), iteeth, np.zeros(len(wall), bool)]
            mouth = np.r_[np.zeros(n_skin, bool), ~iteeth, np.ones(len(wall), bool)]
            colours = np.vstack([np.zeros((n_skin, 3), np.uint8), icolours, np.repeat(icolours[:1], len(wall), axis=0)])
            itopo = iv[:, :2].copy()
            itopo[:8] = topo[60:68]  # the cavity's copies of the inner lips, pulled apart as theirs
            topo = np.vstack([topo, itopo])
            vertices = np.vstack([vertices, iv])
            carried = np.vstack([carried, icarry])
            fixed = np.r_[fixed, np.zeros(len(iv), bool)]
    # counter-clockwise on screen (y up): flip where the image-space (y down) area is positive
    ta, tb, tc = (topo[faces[:, k]] for k in range(3))
    tarea = (tb[:, 0] - ta[:, 0]) * (tc[:, 1] - ta[:, 1]) - (tb[:, 1] - ta[:, 1]) * (tc[:, 0] - ta[:, 0])
    flip = tarea > 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    uv = np.column_stack([vertices[:, 0] / (W - 1), 1.0 - vertices[:, 1] / (H - 1)])
    return FaceMesh(vertices, faces, mouth, uv, img, P, fixed, teeth=teeth, colours=colours, carried=carried)


def portrait_image(landmarks, width: int, height: int) -> np.ndarray:
    """A drawn face for the 68-point layout (skin, brows, eyes, nose, lips) to texture the mesh
    when no photo is given. Returns (height, width, 3) uint8."""
    from PIL import Image, ImageDraw

    lm = check_points(np.asarray(landmarks, dtype=np.float64)[None], "landmarks", face_layout.N_POINTS)[0]
    im = Image.new("RGB", (int(width), int(height)), (92, 110, 136))
    d = ImageDraw.Draw(im)
    jaw = lm[0:17]
    top = lm[17:27, 1].min()
    centre_x = 0.5 * (jaw[0, 0] + jaw[16, 0])
    rx = 0.5 * (jaw[16, 0] - jaw[0, 0])
    ry = jaw[0, 1] - top + 0.35 * rx
    a = np.linspace(0.0, np.pi, 24)
    forehead = np.column_stack([centre_x + rx * np.cos(a), jaw[0, 1] - ry * np.sin(a)])
    outline = np.vstack([jaw, forehead[1:-1]])
    d.polygon([tuple(p) for p in outline], fill=(226, 180, 150))
    tup = lambda idx: [tuple(p) for p in lm[idx]]  # noqa: E731
    lw = max(2, int(rx / 30))
    for g in ("right_brow", "left_brow"):
        d.line(tup(list(face_layout.GROUPS[g])), fill=(80, 52, 38), width=2 * lw)
    for g in ("right_eye", "left_eye"):
        idx = list(face_layout.GROUPS[g])
        d.polygon(tup(idx), fill=(245, 245, 245), outline=(60, 40, 30))
        c = lm[idx].mean(axis=0)
        r = 0.3 * np.ptp(lm[idx][:, 1]) + 1.0
        d.ellipse([c[0] - r, c[1] - r, c[0] + r, c[1] + r], fill=(50, 70, 100))
    d.line(tup(list(range(27, 31))), fill=(170, 120, 100), width=lw)
    d.line(tup(list(range(31, 36))), fill=(150, 100, 85), width=lw)
    d.polygon(tup(list(range(48, 60))), fill=(190, 80, 90))
    d.line(tup(list(range(60, 65))), fill=(120, 40, 50), width=max(1, lw // 2))
    return np.asarray(im)


# ---------------------------------------------------------------- retargeting and AU basis

def similarity(reference: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``s R`` (2, 2): the similarity (scale, rotation) that best maps ``reference`` onto
    ``target`` (orthogonal Procrustes; row vectors, ``x_ref @ sR ~ x_tgt`` about their centroids).
    Shapes: reference and target (P, 2)."""
    ref_c = reference - reference.mean(axis=0)
    tgt_c = target - target.mean(axis=0)
    u, sv, vt = np.linalg.svd(ref_c.T @ tgt_c)
    d = np.sign(np.linalg.det(u @ vt))
    D = np.diag([1.0, d])
    s = float(np.sum(sv * np.diag(D)) / max(np.sum(ref_c ** 2), 1e-300))
    return s * (u @ D @ vt)


def retarget(points: np.ndarray, reference: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Maps landmark motion onto another face: ``target + s R (points - reference)``, ``s R`` of
    :func:`similarity`. Shapes: points (T, P, 2), reference and target (P, 2).
    Returns the displacements (T, P, 2) to add to ``target``.
    """
    return (points - reference) @ similarity(reference, target)


def action_unit_basis(landmarks) -> np.ndarray:
    """The action-unit displacement fields on a 68-point face.

    Parameters
    ----------
    landmarks : ndarray, shape (68, 2)
        the neutral face (pixels); displacements scale with its inter-ocular distance.

    Returns
    -------
    ndarray, shape (K, 68, 3)
        per unit of :data:`ACTION_UNITS`: displacement of every landmark (x, y down, depth z).
    """
    lm = check_points(np.asarray(landmarks, dtype=np.float64)[None], "landmarks", face_layout.N_POINTS)[0]
    iod = float(face_layout.inter_ocular_distance(lm))
    B = np.zeros((len(ACTION_UNITS), 68, 3))
    k = {name: i for i, name in enumerate(ACTION_UNITS)}
    # jaw open: lower lip and chin down, corners half way, the jaw line by its distance from the temples
    jaw = B[k["jaw_open"]]
    w = np.zeros(68)
    w[np.r_[55:60, 65:68]] = 1.0
    w[[48, 54, 60, 64]] = 0.5
    w[0:17] = np.sin(np.linspace(0.0, np.pi, 17)) ** 2
    jaw[:, 1] = 0.35 * iod * w
    # lip corner pulls (subject's right = image left: 48, 60; left: 54, 64): out and up
    for name, corners, halves, sign in (("smile_right", [48, 60], [49, 59], -1.0),
                                        ("smile_left", [54, 64], [53, 55], 1.0)):
        S = B[k[name]]
        S[corners, 0] = sign * 0.15 * iod
        S[corners, 1] = -0.15 * iod
        S[halves, 0] = sign * 0.06 * iod
        S[halves, 1] = -0.06 * iod
    # pucker: lips narrow towards the mouth centre and push forward
    lips = np.r_[48:68]
    mc = lm[lips].mean(axis=0)
    B[k["pucker"], lips, 0] = -0.35 * (lm[lips, 0] - mc[0])
    B[k["pucker"], lips, 2] = 0.12 * iod
    # lip press: lips pressed together and thinned
    B[k["lip_press"], [61, 62, 63], 1] = 0.05 * iod
    B[k["lip_press"], [65, 66, 67], 1] = -0.05 * iod
    B[k["lip_press"], [50, 51, 52], 1] = 0.04 * iod
    B[k["lip_press"], [56, 57, 58], 1] = -0.04 * iod
    # upper lip raise
    B[k["upper_lip_raise"], np.r_[49:54, 61:64], 1] = -0.1 * iod
    B[k["upper_lip_raise"], [48, 54, 60, 64], 1] = -0.04 * iod
    # brow raise (negative activations lower the brows)
    B[k["brow_raise"], 17:27, 1] = -0.12 * iod
    # blinks: upper lids onto the lower lids
    for name, upper, lower in (("blink_right", [37, 38], [41, 40]), ("blink_left", [43, 44], [47, 46])):
        B[k[name], upper, 1] = lm[lower, 1] - lm[upper, 1]
    return B


def fit_activations(displacements, basis, *, bounds: Optional[tuple] = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame least-squares activations of an action-unit basis.

    Parameters
    ----------
    displacements : ndarray, shape (T, P, 2)
        landmark motion from the neutral face (x, y).
    basis : ndarray, shape (K, P, 2) or (K, P, 3)
        (depth ignored: it is not observed).
    bounds : (lower, upper) arrays of shape (K,), optional
        box constraints (scipy ``lsq_linear``); unconstrained otherwise (one QR solve for all
        frames).

    Returns
    -------
    activations : ndarray, shape (T, K)
    rms_error : ndarray, shape (T,)
        root-mean-square residual per landmark coordinate, in the displacement's units.
    """
    d = check_points(displacements, "displacements")
    B = np.asarray(basis, dtype=np.float64)[..., :2]
    T, P, _ = d.shape
    if B.ndim != 3 or B.shape[1] != P:
        raise ValueError(f"basis must have shape (K, {P}, 2|3) to match the displacements, got {B.shape}")
    A = B.reshape(len(B), -1).T  # (2P, K)
    Y = d.reshape(T, -1).T  # (2P, T)
    if bounds is None:
        X, *_ = np.linalg.lstsq(A, Y, rcond=None)
        act = X.T
    else:
        from scipy.optimize import lsq_linear

        lo, hi = (np.broadcast_to(np.asarray(b, float), (len(B),)) for b in bounds)
        act = np.stack([lsq_linear(A, Y[:, t], bounds=(lo, hi), method="bvls").x for t in range(T)])
    resid = Y - A @ act.T
    return act, np.sqrt(np.mean(resid ** 2, axis=0))


def expression_offset(neutral, weights) -> np.ndarray:
    """A whole-face expression as landmark displacements: ``sum_k w_k B_k`` over the action-unit
    basis of the 68-point ``neutral`` face (x, y only).

    ``weights``: a dict ``{unit: weight}`` or a string ``"smile_left=1,smile_right=1"``; units from
    :data:`ACTION_UNITS`. Returns (68, 2). Use with :func:`voicepuppet.animation.add_offset`.
    """
    if isinstance(weights, str):
        parsed = {}
        for item in filter(None, (w.strip() for w in weights.split(","))):
            name, _, value = item.partition("=")
            try:
                parsed[name.strip()] = float(value) if value else 1.0
            except ValueError:
                raise ValueError(f"expression item {item!r} must be UNIT or UNIT=WEIGHT, e.g. smile_left=0.8") from None
        weights = parsed
    B = action_unit_basis(neutral)
    out = np.zeros((face_layout.N_POINTS, 2))
    for name, w in weights.items():
        if name not in ACTION_UNITS:
            raise ValueError(f"unknown action unit {name!r} in the expression; use {', '.join(ACTION_UNITS)}")
        out += float(w) * B[ACTION_UNITS.index(name), :, :2]
    return out


def mesh_animation(anim: Animation, mesh: FaceMesh, *, mode: str = "vertex",
                   neutral: Optional[np.ndarray] = None) -> dict:
    """Vertex positions of the mesh for every frame of ``anim``.

    Parameters
    ----------
    anim : Animation with P points (the mesh's landmark count)
    mesh : FaceMesh
    mode : "vertex" or "au"
    neutral : ndarray, shape (P, 2), optional
        the animation's rest shape (default: :attr:`Animation.rest`, its neutral or first frame).

    Returns
    -------
    dict with ``vertices`` (T, V, 3) in image coordinates (x, y down, z), and for ``"au"``
    ``activations`` (T, K), ``targets`` (K, V, 3) (vertex displacement per unit activation)
    and ``rms_error`` (T,) in pixels of the photo.
    """
    if anim.n_points != mesh.n_landmarks:
        raise ValueError(f"the animation has {anim.n_points} points per frame but the face mesh has "
                         f"{mesh.n_landmarks} landmarks; give the face's points in the animation's layout")
    ref = anim.rest if neutral is None else check_points(np.asarray(neutral)[None], "neutral", anim.n_points)[0]
    disp = retarget(anim.points, ref, mesh.landmarks)
    M = mesh.interpolation_matrix()
    base = mesh.vertices
    if mode == "vertex":
        dv = np.einsum("vp,tpc->tvc", M, disp)
        verts = np.repeat(base[None], anim.n_frames, axis=0)
        verts[:, :, :2] += dv
        return {"vertices": verts}
    if mode == "au":
        if mesh.n_landmarks != face_layout.N_POINTS:
            raise ValueError(f"mode 'au' needs the 68-point layout, the mesh has {mesh.n_landmarks} landmarks; "
                             "use mode 'vertex'")
        B = action_unit_basis(mesh.landmarks)  # (K, 68, 3)
        act, err = fit_activations(disp, B)
        targets = np.einsum("vp,kpc->kvc", M, B)
        verts = base[None] + np.einsum("tk,kvc->tvc", act, targets)
        return {"vertices": verts, "activations": act, "targets": targets, "rms_error": err}
    raise ValueError(f"mode must be 'vertex' or 'au', got {mode!r}")


# ------------------------------------------------------------------------------ rendering

def _pyvista():
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        import pyvista
    except ImportError:
        raise ValueError("mesh rendering needs pyvista: pip install pyvista (and Mesa's EGL: "
                         "apt-get install libegl1 libgl1-mesa-dri), or use renderer='2d'") from None
    return pyvista


def _even(n: int) -> int:
    return int(n) + (int(n) % 2)


#: Without ``size``, a face image larger than this (long side, short side) renders scaled down to
#: fit it, its aspect kept: a 12-megapixel phone photo (4000x3000) renders at 1440x1080 instead of
#: 4000x3000 (a 3000x3000 photo rendered 4.9 frames/s, at 1080x1080 22.5 on the 2-core machine).
DEFAULT_MAX_SIZE = (1920, 1080)


def default_size(width: int, height: int) -> tuple[int, int]:
    """The output size for a ``width`` x ``height`` face image when none is given: the image's,
    scaled down (never up) to fit :data:`DEFAULT_MAX_SIZE` in its orientation, even numbers."""
    long_side, short_side = DEFAULT_MAX_SIZE
    f = min(1.0, long_side / max(width, height), short_side / min(width, height))
    return _even(int(round(width * f))), _even(int(round(height * f)))


class FaceRenderer:
    """Off-screen pyvista renderer of a :class:`FaceMesh`; ``frame(vertices)`` returns RGB.

    Parameters
    ----------
    mesh : FaceMesh
    size : (width, height), optional
        output size in pixels (default: the photo's, scaled down to fit
        :data:`DEFAULT_MAX_SIZE` by :func:`default_size`; even numbers for H.264).
    shading : bool
        light the mesh (shows the depth); off by default so the neutral frame is the photo.
    turn : (yaw, pitch), optional
        degrees to turn the face from the front: yaw about its vertical axis (positive: to its
        left, the nose towards the viewer's right, its right cheek showing), then pitch about the
        horizontal (positive: the chin up); the camera orbits the view's centre at the depth of
        the face's landmarks, its projection still parallel.
    """

    def __init__(self, mesh: FaceMesh, size: Optional[tuple[int, int]] = None, shading: bool = False,
                 turn: Optional[tuple[float, float]] = None):
        pv = _pyvista()
        W, H = mesh.size
        self.size = default_size(W, H) if size is None else (_even(size[0]), _even(size[1]))
        self.mesh = mesh
        # no multisampling: llvmpipe renders 8x MSAA (pyvista's default) at a third of the speed,
        # and the texture already carries the photo's own anti-aliasing
        theme = pv.themes.DocumentTheme()
        theme.multi_samples = 0
        theme.anti_aliasing = None
        self._plotter = pv.Plotter(off_screen=True, window_size=list(self.size), theme=theme)
        self._plotter.set_background((0.0, 0.0, 0.0))
        skin_faces = mesh.faces[~mesh.flat]
        self._skin = pv.PolyData(self._world(mesh.vertices), np.hstack([np.full((len(skin_faces), 1), 3), skin_faces]))
        self._skin.active_texture_coordinates = mesh.uv.astype(np.float32)
        texture = pv.Texture(mesh.image)
        kw = {} if shading else {"ambient": 1.0, "diffuse": 0.0, "specular": 0.0}
        self._plotter.add_mesh(self._skin, texture=texture, lighting=shading, **kw)
        self._interior = None
        if mesh.flat.any():  # the mouth's interior, behind the skin: the depth buffer shows it
            flat_faces = mesh.faces[mesh.flat]
            self._interior = pv.PolyData(self._world(mesh.vertices),
                                         np.hstack([np.full((len(flat_faces), 1), 3), flat_faces]))
            self._interior.cell_data["colour"] = mesh.colours[mesh.flat]
            self._plotter.add_mesh(self._interior, scalars="colour", rgb=True, lighting=False)
        cam = self._plotter.camera
        cam.parallel_projection = True
        cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
        cam.focal_point = (cx, -cy, 0.0)
        cam.position = (cx, -cy, 10.0 * max(W, H))
        cam.up = (0.0, 1.0, 0.0)
        # fit the photo in the window keeping its aspect ratio
        aspect_win = self.size[0] / self.size[1]
        cam.parallel_scale = max(H / 2.0, W / 2.0 / aspect_win)
        cam.clipping_range = (1.0, 20.0 * max(W, H))
        if turn is not None:
            yaw, pitch = (float(a) for a in turn)
            if not (np.isfinite(yaw) and np.isfinite(pitch) and abs(yaw) <= 90 and abs(pitch) <= 90):
                raise ValueError(f"turn must be yaw, pitch in degrees within [-90, 90], got {turn!r}")
            # the face turning one way is the camera orbiting the other way round its centre
            depth = float(np.mean(mesh.vertices[: mesh.n_landmarks, 2])) if mesh.n_landmarks else 0.0
            cam.focal_point = (cx, -cy, depth)
            cam.Azimuth(-yaw)
            cam.Elevation(-pitch)
            cam.OrthogonalizeViewUp()
            cam.clipping_range = (1.0, 20.0 * max(W, H))

    @staticmethod
    def _world(vertices: np.ndarray) -> np.ndarray:
        v = np.asarray(vertices, dtype=np.float64).copy()
        v[:, 1] = -v[:, 1]
        return v

    def frame(self, vertices: np.ndarray) -> np.ndarray:
        """Renders one frame of vertex positions (V, 3); returns (height, width, 3) uint8."""
        world = self._world(vertices)
        self._skin.points = world
        if self._interior is not None:
            self._interior.points = world
        self._plotter.render()
        return np.asarray(self._plotter.screenshot(return_img=True))[:, :, :3]

    def close(self) -> None:
        self._plotter.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def draw_landmarks_2d(points: np.ndarray, size: tuple[int, int], background=(255, 255, 255)) -> np.ndarray:
    """The fast fallback: one frame of landmarks drawn as contours (68-point layout) or dots.
    ``points`` (P, 2) in pixels; returns (height, width, 3) uint8."""
    from PIL import Image, ImageDraw

    im = Image.new("RGB", (int(size[0]), int(size[1])), tuple(background))
    d = ImageDraw.Draw(im)
    pts = np.asarray(points, dtype=np.float64)
    r = max(1.5, size[0] / 200.0)
    if len(pts) == face_layout.N_POINTS:
        closed = {"right_eye", "left_eye", "outer_lip", "inner_lip"}
        for g, idx in face_layout.GROUPS.items():
            seg = [tuple(p) for p in pts[list(idx)]]
            if g in closed:
                seg.append(seg[0])
            d.line(seg, fill=(200, 40, 60) if "lip" in g else (40, 60, 90), width=max(1, int(r)))
    for x, y in pts:
        d.ellipse([x - r, y - r, x + r, y + r], fill=(20, 20, 20))
    return np.asarray(im)


def _label(img: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    ImageDraw.Draw(im).text((6, 4), text, fill=(255, 255, 0))
    return np.asarray(im)


def render_frames(anim: Animation, *, face: Optional[FaceMesh] = None, mode: str = "vertex",
                  truth: Optional[Animation] = None, renderer: str = "mesh",
                  size: Optional[tuple[int, int]] = None, shading: bool = False,
                  turn: Optional[tuple[float, float]] = None,
                  neutral: Optional[np.ndarray] = None, progress: bool = False) -> Iterator[np.ndarray]:
    """Yields the frames (H, W, 3) uint8 of ``anim``; with ``truth``, side by side
    (prediction left, ground truth right, same face and frame count).

    ``face`` defaults to a drawn portrait (:func:`portrait_image`) on the animation's rest face
    (``neutral``, else :attr:`Animation.rest`; 68-point layout). Both sides move from
    ``neutral`` when it is given, else each from its own rest, a truth without a ``neutral``
    from its frame nearest the animation's (:func:`voicepuppet.face.shape_distance`).
    ``renderer="2d"`` draws the landmarks instead of the mesh; ``turn`` (yaw, pitch) views the
    mesh from an angle (:class:`FaceRenderer`).
    """
    if truth is not None:
        if truth.n_points != anim.n_points:
            raise ValueError(f"ground truth has {truth.n_points} points per frame, the prediction {anim.n_points}; "
                             "compare animations in the same layout")
        if truth.n_frames != anim.n_frames:
            raise ValueError(f"ground truth has {truth.n_frames} frames, the prediction {anim.n_frames}; "
                             "resample one of them to the other's frame rate and length")
    tqdm = None
    if progress:
        from tqdm import tqdm
    frames = range(anim.n_frames)
    if tqdm is not None:
        frames = tqdm(frames, desc="render", unit="frame")
    if renderer == "2d":
        pts = anim.points
        lo, hi = pts.reshape(-1, 2).min(axis=0), pts.reshape(-1, 2).max(axis=0)
        if truth is not None:
            tp = truth.points.reshape(-1, 2)
            lo, hi = np.minimum(lo, tp.min(axis=0)), np.maximum(hi, tp.max(axis=0))
        margin = 0.1 * (hi - lo).max() + 4.0
        box = (_even(int(np.ceil(hi[0] - lo[0] + 2 * margin))), _even(int(np.ceil(hi[1] - lo[1] + 2 * margin))))
        if size is not None:
            box = (_even(size[0]), _even(size[1]))
        shift = lo - margin
        for t in frames:
            img = draw_landmarks_2d(pts[t] - shift, box)
            if truth is not None:
                img = np.hstack([_label(img, "prediction"),
                                 _label(draw_landmarks_2d(truth.points[t] - shift, box), "ground truth")])
            yield img
        return
    if renderer != "mesh":
        raise ValueError(f"renderer must be 'mesh' or '2d', got {renderer!r}")
    ref = None if neutral is None else np.asarray(neutral, dtype=np.float64)
    pred_ref = anim.rest if ref is None else ref
    truth_ref = None if truth is None else (truth.rest if ref is None else ref)
    if ref is None and truth is not None and truth.neutral is None and anim.neutral is not None:
        # a truth of frames only (tracked, say) rests where it is nearest the prediction's rest,
        # not on its first frame, which may be mid-word
        truth_ref = truth.points[int(np.argmin(shape_distance(truth.points, anim.neutral)))]
    if face is None:
        if anim.n_points != face_layout.N_POINTS:
            raise ValueError(f"without a face photo the animation must use the 68-point layout "
                             f"(a drawn portrait is used), got {anim.n_points} points; "
                             "pass a face image and its points")
        lo, hi = pred_ref.min(axis=0), pred_ref.max(axis=0)
        margin = 0.45 * (hi - lo).max()
        shift = lo - margin
        W, H = _even(int(hi[0] - lo[0] + 2 * margin)), _even(int(hi[1] - lo[1] + 2 * margin))
        face = build_face_mesh(portrait_image(pred_ref - shift, W, H), pred_ref - shift)
    # vertices in chunks of frames: memory stays bounded for hour-long animations
    chunk = _FRAME_CHUNK
    pred = gt = None
    with FaceRenderer(face, size=size, shading=shading, turn=turn) as r:
        for t in frames:
            if t % chunk == 0:
                part = slice(t, t + chunk)
                pred = mesh_animation(Animation(anim.points[part], anim.fps), face, mode=mode,
                                      neutral=pred_ref)["vertices"]
                if truth is not None:
                    gt = mesh_animation(Animation(truth.points[part], truth.fps), face, mode=mode,
                                        neutral=truth_ref)["vertices"]
            img = r.frame(pred[t % chunk])
            if gt is not None:
                img = np.hstack([_label(img, "prediction"), _label(r.frame(gt[t % chunk]), "ground truth")])
            yield img


def write_video(frames: Iterable[np.ndarray], path, fps: float, *, audio=None, n_frames: Optional[int] = None) -> Path:
    """Writes frames (H, W, 3) uint8 to ``.mp4`` (H.264, yuv420p, audio muxed as AAC and cut to
    the video's duration ``n_frames / fps``), ``.gif`` or a folder of ``frame_000000.png``
    (any other path without a suffix), atomically: nothing appears at ``path`` unless all frames
    were written.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if audio is not None:
        audio = Path(audio)
        if not audio.is_file():
            raise ValueError(f"audio file {str(audio)!r} does not exist")
        if suffix != ".mp4":
            raise ValueError(f"audio can only be muxed into .mp4, not {suffix or 'a folder of frames'}; drop the audio "
                             "or write an .mp4")
    if suffix == "":
        parent = p.parent if str(p.parent) else Path(".")
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            raise ValueError(f"output folder {str(parent)!r} must exist and be writable")
        if p.exists() and (not p.is_dir() or any(p.iterdir())):
            raise ValueError(f"output {str(p)!r} already exists and is not an empty folder; choose a new folder name")
        tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".partial", dir=parent))
        try:
            from PIL import Image

            for t, img in enumerate(frames):
                Image.fromarray(img).save(tmp / f"frame_{t:06d}.png")
            if p.exists():
                p.rmdir()
            publish(tmp, p)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp)
        return p
    check_output_path(p, VIDEO_SUFFIXES + ("",), "video")
    with atomic_path(p, VIDEO_SUFFIXES, "video") as tmp:
        if suffix == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in frames]
            if not images:
                raise ValueError("no frames to write")
            images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                           duration=max(20, int(round(1000.0 / fps / 10.0)) * 10), loop=0)
        else:
            _write_mp4(frames, tmp, fps, audio, n_frames)
    return p


def _write_mp4(frames, path: Path, fps: float, audio: Optional[Path], n_frames: Optional[int]) -> None:
    try:
        import imageio_ffmpeg
    except ImportError:
        raise ValueError("writing .mp4 needs imageio-ffmpeg: pip install imageio-ffmpeg") from None
    from fractions import Fraction

    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        raise ValueError("no frames to write") from None
    h, w = first.shape[:2]
    rate = Fraction(30000, 1001) if abs(fps - 30000 / 1001) < 1e-3 else Fraction(fps).limit_denominator(1001)
    # the same frames give the same bytes: one encoder thread (x264's automatic count follows
    # the CPUs the process may use: 3 frame threads on 2 cores, 1 under taskset) and no B-frames
    # (with them x264's macroblock tree reads heap memory it has not written; see synth.video)
    out_params = ["-movflags", "+faststart", "-preset", "veryfast", "-threads", "1", "-bf", "0"]
    if audio is not None and n_frames is not None:
        out_params += ["-t", f"{n_frames / float(rate):.6f}"]
    writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=rate, codec="libx264", quality=7,
                                         macro_block_size=2, ffmpeg_log_level="error", output_params=out_params,
                                         audio_path=None if audio is None else str(audio),
                                         audio_codec=None if audio is None else "aac")
    writer.send(None)
    try:
        writer.send(np.ascontiguousarray(first))
        for img in it:
            writer.send(np.ascontiguousarray(img))
    finally:
        writer.close()


def render(anim: Animation, path, *, audio=None, face: Optional[FaceMesh] = None, mode: str = "vertex",
           truth: Optional[Animation] = None, renderer: str = "mesh", size: Optional[tuple[int, int]] = None,
           shading: bool = False, neutral: Optional[np.ndarray] = None, progress: bool = False,
           turn: Optional[tuple[float, float]] = None) -> Path:
    """Renders ``anim`` to ``path`` (``.mp4``, ``.gif`` or a folder of ``.png`` frames),
    with ``audio`` muxed into an ``.mp4``. See :func:`render_frames` for the options."""
    p = Path(path)
    if p.suffix.lower() not in VIDEO_SUFFIXES + ("",):
        raise ValueError(f"render output {str(p)!r} has an unknown format {p.suffix!r}; use .mp4, .gif, or a folder "
                         "name for .png frames (meshes and other formats: voicepuppet export)")
    if p.suffix:
        check_output_path(p, VIDEO_SUFFIXES, "render output")
    frames = render_frames(anim, face=face, mode=mode, truth=truth, renderer=renderer, size=size,
                           shading=shading, neutral=neutral, progress=progress, turn=turn)
    return write_video(frames, p, anim.fps, audio=audio, n_frames=anim.n_frames)


# ------------------------------------------------------------------------------ CLI

#: ``--face VIDEO`` with the animation's rest face: the video's frames looked at for the face
#: at rest, one every REST_STRIDE_S seconds over its first REST_SCAN_S (dlib on each: ~10 ms a
#: 320x320 frame).
REST_STRIDE_S = 0.5
REST_SCAN_S = 30.0


def load_face(image_path, points_path=None, rest=None, progress: bool = False) -> FaceMesh:
    """A face mesh from a photo file, or a video (the puppet's own, say), and its points: JSON
    ``{"points": [[x, y], ...]}``, CSV ``x,y`` rows, or an animation or landmarks ``.npz`` (its
    first frame; for a video, its frames). Without points, the 68 landmarks are detected (dlib,
    see :func:`voicepuppet.tracking.tracker.auto_init`) on the photo.

    A video gives one of its frames. With ``rest`` (P, 2), the rest face the animation moves
    from (:attr:`voicepuppet.animation.Animation.rest`), it is the frame whose face is nearest
    it (:func:`voicepuppet.face.shape_distance`), so the photo is the face at rest whatever the
    video begins with: among the frames of a landmarks ``.npz``, or without points among those
    dlib finds a face on, one every :data:`REST_STRIDE_S` s over the first :data:`REST_SCAN_S`
    s. Without ``rest``: the first frame with a face (:func:`voicepuppet.tracking.tracker.first_face`),
    or with points the first frame.

    A textured 3-D head (``.obj``), with its 68 points in 3-D or without (detected on its front
    view), gives :func:`voicepuppet.render.head.load_head`."""
    from PIL import Image, UnidentifiedImageError

    from voicepuppet.render.head import HEAD_SUFFIXES, load_head

    ip = Path(image_path)
    if not ip.is_file():
        raise ValueError(f"face image {str(ip)!r} does not exist")
    if ip.suffix.lower() in HEAD_SUFFIXES:
        return load_head(ip, points_path, progress=progress)
    given = None if points_path is None else _face_points(points_path)
    try:
        with Image.open(ip) as im:
            img = np.asarray(im.convert("RGB"))
    except (UnidentifiedImageError, OSError) as exc:
        img, pts = _video_face(ip, given, rest, why=exc, progress=progress)
        return build_face_mesh(img, pts)
    if given is None:
        import cv2

        from voicepuppet.tracking.detect import NoFaceError, auto_init

        try:
            return build_face_mesh(img, auto_init(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY),
                                                  instead="--face-points points.json"))
        except NoFaceError:
            raise ValueError(f"no face found in the photo {str(ip)!r} (dlib's detector: a frontal, upright, "
                             "lit face); pass its 68 landmarks with --face-points points.json") from None
    return build_face_mesh(img, given[0])


def _face_points(path) -> np.ndarray:
    """The points of ``--face-points``: (N, P, 2), the frames of an ``.npz``, else one frame."""
    pp = Path(path)
    if pp.suffix.lower() == ".npz":
        from voicepuppet.animation import load_animation

        return load_animation(pp).points
    from voicepuppet.tracking.landmarks import load_init_points

    return load_init_points(pp)[0][None]


def _video_face(path: Path, given: np.ndarray | None, rest, why: Exception,
                progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(RGB frame, its points) of the video ``path`` for :func:`load_face`: ``given`` points
    (N, P, 2) or dlib's, the frame nearest ``rest`` or the first (with a face). ``why`` is the
    picture reader's refusal, reported when ``path`` is no video either."""
    import cv2

    from voicepuppet.tracking import video
    from voicepuppet.tracking.detect import NoFaceError, first_face

    try:
        info = video.probe_video(path)
        first = video.frame_at(path, 0, grey=False)
    except ValueError:
        raise ValueError(f"face image {str(path)!r} is neither a readable picture ({why}) nor a video "
                         "OpenCV can open; give a .png / .jpg photo or an .mp4 video of the face") from None
    if first is None:
        raise ValueError(f"face video {str(path)!r} holds no decodable frames; give a photo or another video")
    fps = info.fps or 29.97
    if given is not None:
        k = 0
        if rest is not None and len(given) > 1 and given.shape[1] == len(rest):
            k = int(np.argmin(shape_distance(given, rest)))
        frame = first if k == 0 else video.frame_at(path, k, grey=False)
        if frame is None:
            raise ValueError(f"face video {str(path)!r} has fewer frames than its --face-points ({k + 1} needed); "
                             "give the video's own landmarks")
        return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), given[k]
    try:
        t, frame, pts = first_face(path, first, fps, grey=False)
    except NoFaceError as exc:
        raise ValueError(f"face video: {exc}; pass a photo with --face, or the first frame's 68 landmarks "
                         "with --face-points") from None
    if rest is not None and len(rest) == len(pts):
        frame, pts = _rest_frame(path, fps, rest, (frame, pts), start=t, progress=progress)
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), pts


def _rest_frame(path: Path, fps: float, rest, found, start: int, progress: bool = False):
    """The (BGR frame, dlib points) nearest ``rest`` among ``found`` (the first face, at frame
    ``start``) and the probes after it, one every :data:`REST_STRIDE_S` s up to
    :data:`REST_SCAN_S` s."""
    import cv2
    from tqdm.auto import tqdm

    from voicepuppet.tracking import video
    from voicepuppet.tracking.detect import PROBE_MAX_PIXELS, NoFaceError, auto_init

    stride = max(1, int(round(REST_STRIDE_S * fps)))
    last = int(REST_SCAN_S * fps)
    best, best_d = found, float(shape_distance(found[1][None], rest)[0])
    frames = video.iter_frames(path, grey=False)
    try:
        probes = itertools.islice(frames, start + stride, last + 1, stride)
        for frame in tqdm(probes, total=max(0, (last - start) // stride), desc="looking for the face at rest",
                          unit="frame", disable=not progress, leave=False):
            try:
                pts = auto_init(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), max_pixels=PROBE_MAX_PIXELS)
            except NoFaceError:
                continue
            d = float(shape_distance(pts[None], rest)[0])
            if d < best_d:
                best, best_d = (frame, pts), d
    finally:
        frames.close()
    return best


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
_POINT_SUFFIXES = (".json", ".csv", ".npz")


def face_palette(folder) -> dict:
    """The faces of a palette folder (Brand §6: the animator picks a face by name).

    Every picture ``NAME.png`` (or .jpg, ...) is a face; its points are ``NAME.json`` / ``.csv`` /
    ``.npz`` beside it (without them the 68 landmarks are detected). Returns
    ``{name: (image_path, points_path or None)}`` sorted by name.
    """
    d = Path(folder)
    if not d.is_dir():
        raise ValueError(f"face palette {str(d)!r} is not a folder; give a folder of NAME.png + NAME.json faces")
    faces = {}
    for img in sorted(d.iterdir()):
        if img.suffix.lower() in _IMAGE_SUFFIXES and not img.name.startswith("."):
            pts = next((img.with_suffix(s) for s in _POINT_SUFFIXES if img.with_suffix(s).is_file()), None)
            faces[img.stem] = (img, pts)
    if not faces:
        raise ValueError(f"face palette {str(d)!r} holds no pictures ({', '.join(_IMAGE_SUFFIXES)})")
    return faces


def resolve_face(face: str, points=None, palette=None, rest=None, progress: bool = False) -> FaceMesh:
    """A face mesh from ``face``: a picture or video file (with ``points`` or detected landmarks;
    a video's frame nearest ``rest``, see :func:`load_face`) or, with a ``palette`` folder, a
    face name in it. With ``rest``, a 68-point face whose lips are more than
    :data:`OPEN_MOUTH_IOD` further apart than the rest face's is warned about (it is not at rest:
    every frame would show the mouth that much more open)."""
    if palette is not None and not Path(face).is_file():
        faces = face_palette(palette)
        if face not in faces:
            raise ValueError(f"face {face!r} is not in the palette {str(palette)!r}; choose one of "
                             f"{', '.join(faces)}")
        image, pts = faces[face]
        mesh = load_face(image, points if points is not None else pts, rest, progress)
    else:
        mesh = load_face(face, points, rest, progress)
    if rest is not None and mesh.n_landmarks == len(rest) == face_layout.N_POINTS:
        photo, still = lip_gap_iod(mesh.landmarks), lip_gap_iod(rest)
        if photo - still > OPEN_MOUTH_IOD:
            warnings.warn(f"the face {str(face)!r} has its lips {photo:.2f} inter-ocular distances apart and the "
                          f"animation's rest face {still:.2f}: every frame shows the mouth that much more open "
                          "and closures do not close; give a photo with the mouth closed at rest (or a video: "
                          "its frame nearest the rest face is taken)", stacklevel=2)
    return mesh


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must look like 640x480, got {text!r}") from None
    if w < 16 or h < 16:
        raise ValueError(f"--size must be at least 16x16, got {text!r}")
    return w, h


def _turn(text: str) -> tuple[float, float]:
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2):
        raise ValueError(f"--turn must look like 30 or 30,-10 (yaw[,pitch] in degrees), got {text!r}")
    return parts[0], parts[1] if len(parts) == 2 else 0.0


def apply_controls(anim: Animation, args) -> Animation:
    """The animator controls of the command line: ``--exaggerate`` then ``--expression`` over
    ``--expression-time START:END`` (seconds) with ``--fade``. The result carries the rest face
    its outputs move from (:attr:`Animation.rest` before the controls, scaled by the
    exaggeration, not moved by the expression, which so shows in every output)."""
    from voicepuppet.animation import add_offset, exaggerate

    if anim.neutral is None:
        anim = Animation(anim.points, anim.fps, anim.names, anim.confidence, anim.rest)

    if getattr(args, "exaggerate", None) is not None:
        anim = exaggerate(anim, args.exaggerate)
    if getattr(args, "expression", None):
        start, end = 0.0, None
        if args.expression_time:
            a, _, b = args.expression_time.partition(":")
            try:
                start = float(a) if a else 0.0
                end = float(b) if b else None
            except ValueError:
                raise ValueError(f"--expression-time must be START:END in seconds, "
                                 f"got {args.expression_time!r}") from None
        anim = add_offset(anim, expression_offset(anim.rest, args.expression), start, end, args.fade)
    return anim


def add_control_arguments(p) -> None:
    """``--exaggerate``, ``--expression``, ``--expression-time``, ``--fade`` (Brand §6)."""
    p.add_argument("--exaggerate", type=float, help="scale deviations from the mean shape (1: as is)")
    p.add_argument("--expression", help=f"whole-face offset, e.g. smile_left=1,smile_right=1 (units: "
                                        f"{', '.join(ACTION_UNITS)})")
    p.add_argument("--expression-time", help="START:END seconds of the expression (default: all)")
    p.add_argument("--fade", type=float, default=0.0, help="seconds of ramp at each end of the expression")


def _cli(args) -> int:
    import time

    from voicepuppet.animation import load_animation

    original = load_animation(args.animation)
    anim = apply_controls(original, args)
    truth = load_animation(args.truth) if args.truth else None
    face = resolve_face(args.face, args.face_points, args.palette, original.rest, not args.quiet) \
        if args.face else None
    suffix = Path(args.output).suffix.lower()
    t0 = time.perf_counter()
    if suffix in (".pvd", ".glb"):
        from voicepuppet.render.export import export

        from voicepuppet.render.export import _print_summary

        export(anim, args.output, face=face, mode=args.mode, report=_print_summary)
    else:
        if face is not None and args.size is None and args.renderer == "mesh":
            (W, H), (w, h) = face.size, default_size(*face.size)
            if (w, h) != (_even(W), _even(H)):
                print(f"rendering the {W}x{H} face image at {w}x{h} (--size WxH for another size)")
        render(anim, args.output, audio=args.audio, face=face, mode=args.mode or "vertex", truth=truth,
               renderer=args.renderer, size=_size(args.size) if args.size else None, shading=args.shading,
               progress=not args.quiet, turn=_turn(args.turn) if args.turn else None)
    dt = time.perf_counter() - t0
    print(f"{args.animation}: {anim.n_frames} frames at {anim.fps:g} fps -> {args.output} "
          f"({dt:.1f} s, {anim.n_frames / max(dt, 1e-9):.1f} frames/s)")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="render a landmark animation (mp4 with audio, gif, png frames)",
                       description="Render a landmark animation on a textured face mesh off screen: .mp4 "
                                   "(with --audio muxed in sync), .gif, a folder of .png frames (an output "
                                   "name without suffix), or the mesh as .pvd / .glb.")
    p.add_argument("animation", help="landmark animation (.npz or .csv)")
    p.add_argument("-o", "--output", required=True, help="out.mp4, out.gif, a new folder, out.pvd or out.glb")
    p.add_argument("--audio", help="sound to mux into the .mp4 (wav, flac, mp3, or a video's audio)")
    p.add_argument("--face", help="face photo at rest (mouth closed), a video (e.g. the puppet's training "
                                  "video: its frame nearest the animation's rest face), a textured 3-D head (.obj; "
                                  "its 68 points in 3-D with --face-points), or a face name with "
                                  "--palette (default: a drawn portrait on the animation's rest face)")
    p.add_argument("--palette", help="folder of faces (NAME.png + NAME.json points) to pick --face from")
    p.add_argument("--face-points", help="the photo's points: JSON {\"points\": [[x, y], ...]}, CSV, or .npz "
                                         "(a video's: its frames', e.g. track's landmarks; default: "
                                         "detect 68 landmarks with dlib); for an .obj head, JSON "
                                         "{\"points\": [[x, y, z], ...]} or menpo .ljson (default: "
                                         "detected on its front view)")
    p.add_argument("--truth", help="ground-truth animation: render side by side (prediction | truth)")
    p.add_argument("--mode", choices=["vertex", "au"], default=None,
                   help="drive vertices directly (default) or through the action-unit basis")
    p.add_argument("--renderer", choices=["mesh", "2d"], default="mesh",
                   help="textured mesh (default) or a fast 2-D landmark drawing")
    p.add_argument("--size", help="output size WxH (default: the face image's, scaled down to fit 1920x1080, "
                                  "or 1080x1920 for a portrait image)")
    p.add_argument("--shading", action="store_true", help="light the mesh to show its depth")
    p.add_argument("--turn", metavar="YAW[,PITCH]",
                   help="degrees to turn the face from the front (positive yaw turns it to its left, "
                        "positive pitch lifts the chin), e.g. 30 for a three-quarter view of a 3-D head")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_control_arguments(p)
    p.set_defaults(func=_cli)
