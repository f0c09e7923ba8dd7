"""The mouth's interior behind a face mesh's lips: the cavity, the tongue and two arches of teeth.

With the 68-point layout and the face's mouth closed, an opening mouth shows what lies behind its
lips: a dark cavity on its own copies of the inner lip points, a tongue (a dome behind the lower
teeth) and two arches of flat-coloured teeth, each moving rigidly with part of the face (the upper
teeth with the skull, the lower teeth and the tongue with the jaw and the lower lip), laid out in
layers below the skin's depth surface (:func:`voicepuppet.render.mesh.skin_depth`,
:data:`INTERIOR_DEPTH`) and coloured to the photo's lighting (:func:`photo_tones`, :func:`tone`).
:func:`mouth_interior` builds it for a photo's mesh (:func:`voicepuppet.render.photo.build_face_mesh`)
and a 3-D head's (:func:`voicepuppet.render.head.load_head`).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet.render.mesh import MOUTH_COLOUR, skin_depth

__all__ = ["CAVITY", "INTERIOR_DEPTH", "mouth_interior", "photo_tones", "pixel_tones", "tone"]

#: The cavity's triangles inside the inner lip contour (60-67) of the 68-point layout.
CAVITY = ((60, 61, 67), (61, 66, 67), (61, 62, 66), (62, 65, 66), (62, 63, 65), (63, 64, 65))

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
#: Depths below the skin's depth surface (:func:`voicepuppet.render.mesh.skin_depth`) at each
#: vertex, inter-ocular distances: the upper teeth, the lower, the tongue, the cavity. A 3-D
#: viewer sees the teeth a few millimetres behind the lips (on the image plane, 0.5 IOD behind
#: them, they slid away from the mouth at an angle). The first layer lies deeper than the skin's
#: sag between its vertices and its slide over the interior as the lips move (~0.03); the layers
#: apart by more than the depth change of one's slide over the next.
INTERIOR_DEPTH = {"upper": -0.06, "lower": -0.10, "tongue": -0.14, "cavity": -0.18}


def _affine_weights(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(len(targets), len(points)) weights, each row the smallest (in norm) that sums to one and
    reproduces its target from the points (w @ points = target): the row moves its target exactly
    as any affine motion (shift, rotation, scale, shear) of the points moves it, the same weights
    for x and y, and spreads other motions over all the points."""
    A = np.vstack([np.ones(len(points)), points.T])  # (3, n)
    B = np.vstack([np.ones(len(targets)), targets.T])
    return np.linalg.lstsq(A, B, rcond=None)[0].T


def photo_tones(image: np.ndarray, landmarks: np.ndarray) -> tuple[float, bool]:
    """The tones of a photo's face: its pixels' median luma and whether it is grey.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3), uint8
        the photo, RGB.
    landmarks : ndarray, shape (P, 2)
        the face's points in pixels; its pixels are those inside their convex hull.

    Returns
    -------
    luma : float
        the median luma (0-255) of the face's pixels.
    grey : bool
        whether the photo is grey there (its channels equal).
    """
    import cv2

    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(landmarks).astype(np.int32)), 1)
    return pixel_tones(image[mask.astype(bool)])


def pixel_tones(px: np.ndarray) -> tuple[float, bool]:
    """The median luma of RGB pixels and whether they are grey.

    Parameters
    ----------
    px : array_like, shape (N, 3)
        RGB pixels.

    Returns
    -------
    luma : float
        their median luma (0-255).
    grey : bool
        whether they are grey (their channels equal, within 3 levels, as a median).

    Raises
    ------
    ValueError
        there are no pixels.
    """
    px = np.asarray(px, np.float64).reshape(-1, 3)
    if len(px) == 0:
        raise ValueError("no face pixels to take the tones of")
    return float(np.median(px @ [0.299, 0.587, 0.114])), bool(np.median(np.ptp(px, axis=1)) < 3.0)


def tone(colour, luma: Optional[float], grey: bool) -> np.ndarray:
    """A flat colour matched to a photo's lighting.

    Parameters
    ----------
    colour : array_like, shape (3,)
        RGB.
    luma : float or None
        the luma to scale ``colour`` to; None keeps it.
    grey : bool
        make it grey (for a grey photo).

    Returns
    -------
    ndarray, shape (3,), uint8
    """
    c = np.asarray(colour, np.float64)
    if luma is not None:
        c = c * luma / max(float(c @ [0.299, 0.587, 0.114]), 1e-9)
    if grey:
        c = np.full(3, c @ [0.299, 0.587, 0.114])
    return np.clip(np.round(c), 0, 255).astype(np.uint8)


def mouth_interior(lm: np.ndarray, tones: tuple[float, bool], cavity: bool = True):
    """The mouth's interior of a 68-point face at rest (its lips closed): the cavity, on its own
    copies of the inner lip points (carried by them, deepest), the tongue (:data:`_TONGUE`) and
    two arches of teeth (:data:`_TEETH`: hexagons with the biting corners cut, fanned into 4
    triangles each), laid out in the face's frame (x along the eye corners, y below) about the lip
    line and carried by the skull's and the jaw's landmarks (:func:`_affine_weights`), coloured to
    the photo's lighting (``tones``: :func:`photo_tones`).

    Parameters
    ----------
    lm : ndarray, shape (68, 2)
        the face's landmarks at rest, in pixels.
    tones : (float, bool)
        the face's median luma and whether it is grey (:func:`photo_tones`, :func:`pixel_tones`).
    cavity : bool
        build the cavity; False leaves it out (a 3-D head has its own behind its cut lips).

    Returns
    -------
    vertices : ndarray, shape (N, 3)
        x, y in pixels and their depth (below :func:`voicepuppet.render.mesh.skin_depth`).
    faces : ndarray, shape (F, 3), int64
        triangles into ``vertices``.
    teeth : ndarray, shape (F,), bool
        the teeth's faces (the rest are the cavity's and the tongue's).
    colours : ndarray, shape (F, 3), uint8
        each face's flat colour.
    carried : ndarray, shape (N, 68)
        the rows moving each vertex with the landmarks (:attr:`voicepuppet.render.mesh.FaceMesh.carried`).
    """
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
        verts.append(np.column_stack([lm[inner], skin_depth(lm[inner], lm) + INTERIOR_DEPTH["cavity"] * iod]))
        carry.append(np.eye(len(lm))[inner])
        faces.append(np.searchsorted(inner, CAVITY))
        colours.append(np.repeat(tone(MOUTH_COLOUR, None, grey)[None], len(CAVITY), axis=0))
        teeth.append(np.zeros(len(CAVITY), bool))
    n = len(verts[0]) if verts else 0

    def add(xy, depth, fan, colour, part, is_teeth):
        nonlocal n
        verts.append(np.column_stack([xy, skin_depth(xy, lm) + depth * iod]))
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
    add(to_image(u, v), INTERIOR_DEPTH["tongue"], len(u), tone(t["colour"], t["luma"] * skin / 150.0, grey),
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
            add(to_image(u, v), INTERIOR_DEPTH[arch], 6, tone(_TOOTH_COLOUR, enamel * spec["shade"][j], grey),
                arch, True)
    return (np.vstack(verts), np.vstack(faces).astype(np.int64), np.concatenate(teeth), np.vstack(colours),
            np.vstack(carry))
