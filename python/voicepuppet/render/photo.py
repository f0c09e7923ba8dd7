"""A textured low-polygon face mesh from a photo and its landmarks (Brand §4.6).

The landmarks, two rings of border points around them and a frame on the image edge are
triangulated (scipy's Delaunay, about 200 triangles; the lips by hand with the 68-point layout),
lifted to 3-D with a smooth depth profile (:func:`voicepuppet.render.mesh.skin_depth`: an
ellipsoidal cap plus a nose bump) and texture-mapped with the photo; with the 68-point layout and
the photo's mouth closed, the mouth's interior (:mod:`voicepuppet.render.interior`: the cavity,
the tongue and two arches of teeth, flat-coloured) lies behind the lips. Any face whose points
correspond to the animation's (a cartoon, an animal) works the same way (§6, figure 7).
Without a photo, :func:`portrait_image` draws a face to texture the mesh.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet.animation import check_points
from voicepuppet.render.interior import CAVITY, mouth_interior, photo_tones
from voicepuppet.render.mesh import FaceMesh, skin_depth

__all__ = ["build_face_mesh", "portrait_image", "lip_gap_iod", "OPEN_MOUTH_IOD"]

#: Inner-lip gap (inter-ocular distances) above which a face's mouth counts as open: a photo's
#: own cavity then textures the mouth, and a photo that open is not at rest
#: (:func:`voicepuppet.render.faces.resolve_face`).
OPEN_MOUTH_IOD = 0.04


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
#: the inner one (60-67); with the cavity inside the inner contour
#: (:data:`voicepuppet.render.interior.CAVITY`: drawn dark, or with a photo's open mouth its own
#: teeth and tongue).
_LIP_RING = ((48, 49, 60), (49, 61, 60), (49, 50, 61), (50, 51, 61), (51, 62, 61), (51, 63, 62),
             (51, 52, 63), (52, 53, 63), (53, 64, 63), (53, 54, 64), (54, 55, 64), (55, 65, 64),
             (55, 56, 65), (56, 57, 65), (57, 66, 65), (57, 67, 66), (57, 58, 67), (58, 59, 67),
             (59, 67, 60), (59, 48, 60))
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
    lips by hand (:data:`_LIP_RING`, :data:`CAVITY`) in the hole the outer lip contour cuts
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
        return np.vstack([faces[~hole], np.array(_LIP_RING + CAVITY, dtype=np.int64)])
    return Delaunay(topo).simplices.astype(np.int64)


def lip_gap_iod(landmarks) -> float:
    """The inner lips' mean gap (pairs 61-67, 62-66, 63-65) of a 68-point face.

    Parameters
    ----------
    landmarks : array_like, shape (68, 2)
        the face's points.

    Returns
    -------
    float
        the gap in inter-ocular distances (outer eye corners 36, 45).
    """
    lm = np.asarray(landmarks, dtype=np.float64)
    gap = np.mean(np.linalg.norm(lm[[61, 62, 63]] - lm[[67, 66, 65]], axis=1))
    return float(gap / max(float(face_layout.inter_ocular_distance(lm)), 1e-12))


def build_face_mesh(image: np.ndarray, landmarks, *, rings: Sequence[tuple[float, int]] = ((1.2, 12), (1.5, 16)),
                    frame_per_side: int = 4) -> FaceMesh:
    """Builds the textured face mesh of a photo.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W), uint8 (or float in [0, 1])
        the photo (RGB, or grey).
    landmarks : ndarray, shape (P, 2)
        the face's points in pixels; with the 68-point layout the mouth cavity and the nose
        bump are known.
    rings : sequence of (scale, count)
        border rings: ellipses around the landmarks' box, scaled from its half extents.
    frame_per_side : int
        fixed points per image edge.

    Returns
    -------
    FaceMesh
        the photo's mesh, its first P vertices the landmarks.

    Raises
    ------
    ValueError
        the image is not an RGB (or grey) picture of at least 8x8 pixels, or the landmarks are
        fewer than 3, not finite, outside the image or all on a line.

    Notes
    -----
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
    z = skin_depth(pts, lm)
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
            iv, ifaces, iteeth, icolours, icarry = mouth_interior(lm, photo_tones(img, lm))
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
    when no photo is given.

    Parameters
    ----------
    landmarks : array_like, shape (68, 2)
        the face's points in pixels of the picture.
    width, height : int
        the picture's size in pixels.

    Returns
    -------
    ndarray, shape (height, width, 3), uint8

    Raises
    ------
    ValueError
        the landmarks are not 68 finite points.
    """
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

