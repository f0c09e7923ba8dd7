"""A textured 3-D head scan as the face a landmark animation drives (Brand §4.6: "a 3D animated
head model").

:func:`load_head` reads a textured mesh (Wavefront ``.obj`` with its texture image) and its 68
landmarks in 3-D, in the model's own units (given, or found by dlib on the head drawn from the
front as its axes have it: :func:`detect_points_3d`), and returns a :class:`voicepuppet.render.mesh.FaceMesh`
seen from the front, so ``render`` and ``export`` drive it as they drive a photo's mesh:

* **The frontal view.** x runs from the subject's right outer eye corner to the left one, y from
  the chin up to the eyes (made orthogonal to x), z towards the viewer; the nose tip must lie in
  front of the eyes (else the points are mirrored or the head faces away, and this says so).
  The model is drawn in that frame on a canvas around its landmarks (the face's extent plus
  0.45 of it on each side, as the drawn portrait), ``height`` pixels high, y down as in an image;
  depth is in the same pixels.
* **The mouth is cut.** A closed mouth is one surface across the lips, which an opening would
  stretch. The triangles that cross the inner lip line (the inner lip points, upper and lower
  averaged) between the mouth's corners are split along it; every point where the line crosses
  an edge becomes two vertices, one on each lip, at one place at rest (the surface and its
  texture are unchanged); where the cut ends inside a triangle, that triangle is split at the
  crossing without a gap. Behind the cut lie a membrane (``FaceMesh.mouth``) on copies of its
  vertices, 0.18 inter-ocular distances deep and walled to its edges (of zero area from the
  front at rest), and the photo mesh's tongue and teeth (:func:`voicepuppet.render.interior.mouth_interior`)
  at the lip line's depth across the mouth.
* **Driving.** Landmark displacements in the frontal plane move the vertices by a thin-plate
  spline over the 68 landmarks in 3-D (scipy's ``RBFInterpolator``), evaluated where the lips
  are pushed apart (upper lip up, lower lip down by up to 0.15 of the inter-ocular distance at the
  mouth's centre, nothing at its corners), so each lip follows its own landmarks; the motion
  fades out between 0.25 and 0.75 inter-ocular distances from the nearest landmark, so the
  back of the head, the ears and the neck hold still.

``sample_head()`` fetches a real textured scan with 68 3-D landmarks: ``james`` from the
menpo3d 0.8.6 source archive (BSD-3-Clause), cached like the other real data
(:func:`voicepuppet.data.cache_dir`), never committed.
"""

from __future__ import annotations

import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet.data import cache_dir, fetch_sdist
from voicepuppet.render._backend import import_pyvista
from voicepuppet.render.interior import INTERIOR_DEPTH, mouth_interior, pixel_tones, tone
from voicepuppet.render.mesh import MOUTH_COLOUR, FaceMesh, skin_depth
from voicepuppet.render.video import FaceRenderer
from voicepuppet.tracking import SURE_FACE_SCORE, NoFaceError, auto_init

__all__ = ["HEAD_SUFFIXES", "load_head", "read_points_3d", "detect_points_3d", "frontal_frame", "sample_head"]

#: mesh files :func:`load_head` reads
HEAD_SUFFIXES = (".obj",)

MENPO3D_VERSION = "0.8.6"
_MENPO3D_DATA = f"menpo3d-{MENPO3D_VERSION}/menpo3d/data/"

#: lips pushed apart in the spline's domain at the mouth's centre, inter-ocular distances
LIP_SPLIT_IOD = 0.15
#: the motion is whole within this many inter-ocular distances of the nearest landmark ...
MOVE_IOD = 0.25
#: ... and gone beyond this many
STILL_IOD = 0.75
#: the mouth cut reaches this far from the mouth's centre (inter-ocular distances, in 3-D)
CUT_IOD = 0.6


def read_points_3d(path) -> np.ndarray:
    """The 3-D landmarks of a head, (P, 3), in the 68-point iBUG order when they are 68.

    Parameters
    ----------
    path : str or path-like
        JSON ``{"points": [[x, y, z], ...]}`` in the animation's point order, or menpo's
        ``.ljson`` (``groups.LJSON``: labelled groups ``chin``, two eyes, two brows, ``nose``,
        ``mouth`` of 17, 6, 6, 5, 5, 9 and 20 points), whose groups are put in iBUG order (the eye
        and brow of the image's left, the subject's right, first: told apart by the frontal x).

    Returns
    -------
    ndarray, shape (P, 3)

    Raises
    ------
    ValueError
        the file is missing, not JSON, holds no finite [x, y, z] points, or menpo groups of
        other sizes.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"head points {str(p)!r} do not exist; give the head's 68 landmarks in 3-D "
                         'as JSON {"points": [[x, y, z], ...]} or menpo .ljson')
    try:
        doc = json.loads(p.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"head points {str(p)!r} are not JSON ({exc})") from None
    groups = doc.get("groups", {}).get("LJSON") if isinstance(doc, dict) else None
    if isinstance(groups, dict):
        raw = groups.get("landmarks", {}).get("points")
    else:
        raw = doc.get("points") if isinstance(doc, dict) else None
    try:
        pts = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        pts = np.zeros((0,))
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"head points {str(p)!r}: expected a list of [x, y, z] points, got "
                         f"{'nothing' if raw is None else np.shape(raw)}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"head points {str(p)!r} hold NaN or infinite coordinates")
    if isinstance(groups, dict):
        pts = _ibug_order(pts, groups.get("labels", []), p)
    return pts


def _ibug_order(pts: np.ndarray, labels: list, path: Path) -> np.ndarray:
    """menpo's labelled groups of 68 points in iBUG order (see :func:`read_points_3d`)."""
    sizes = {"chin": 17, "nose": 9, "mouth": 20}
    named = {g.get("label"): np.asarray(g.get("mask", []), dtype=np.int64) for g in labels}
    eyes = [m for n, m in named.items() if n in ("leye", "reye")]
    brows = [m for n, m in named.items() if n in ("leyebrow", "reyebrow")]
    ok = (len(pts) == 68 and all(n in named and len(named[n]) == k for n, k in sizes.items())
          and len(eyes) == 2 and all(len(m) == 6 for m in eyes)
          and len(brows) == 2 and all(len(m) == 5 for m in brows))
    if not ok:
        raise ValueError(f"head points {str(path)!r}: menpo's 68-point groups (chin 17, leye/reye 6, "
                         f"leyebrow/reyebrow 5, nose 9, mouth 20) expected, got "
                         f"{ {n: len(m) for n, m in named.items()} } over {len(pts)} points")
    # which side is the image's left: along the jaw from its first point to its last
    jaw = pts[named["chin"]]
    across = jaw[-1] - jaw[0]
    first = lambda pair: sorted(pair, key=lambda m: float(pts[m].mean(axis=0) @ across))  # noqa: E731
    order = np.concatenate([named["chin"], *first(brows), named["nose"], *first(eyes), named["mouth"]])
    return pts[order]


def frontal_frame(points: np.ndarray) -> np.ndarray:
    """The face's frontal frame from its 68 3-D landmarks (iBUG order): x from the subject's right
    outer eye corner to the left one, y up from the chin to the eyes (orthogonal to x),
    z = x × y towards the viewer.

    Parameters
    ----------
    points : ndarray, shape (68, 3)
        the head's landmarks in 3-D.

    Returns
    -------
    ndarray, shape (3, 3)
        the rows x, y, z.

    Raises
    ------
    ValueError
        the eye corners coincide, the chin lies between the eyes, or the nose tip is not in
        front of the eyes (mirrored points, or not in iBUG order).
    """
    L = np.asarray(points, dtype=np.float64)
    right, left = L[face_layout.OUTER_EYE_CORNERS[0]], L[face_layout.OUTER_EYE_CORNERS[1]]
    x = left - right
    eyes = 0.5 * (left + right)
    up = eyes - L[8]
    if np.linalg.norm(x) == 0 or np.linalg.norm(up) == 0:
        raise ValueError("head points: the outer eye corners coincide or the chin is between the eyes; "
                         "give the 68 landmarks in iBUG order")
    x /= np.linalg.norm(x)
    up = up - (up @ x) * x
    up /= np.linalg.norm(up)
    z = np.cross(x, up)
    if (L[30] - eyes) @ z <= 0:
        raise ValueError("head points: the nose tip is not in front of the eyes, so the points are mirrored "
                         "(left and right swapped) or not in iBUG order; give them in the 68-point iBUG order")
    return np.stack([x, up, z])


def _texture(mesh_path: Path) -> np.ndarray:
    """The texture image of an .obj: its material file's ``map_Kd``, else a picture of the same stem."""
    from PIL import Image

    candidates = []
    for line in mesh_path.read_text(errors="replace").splitlines():
        if line.startswith("mtllib "):
            mtl = mesh_path.parent / line.split(None, 1)[1].strip()
            if mtl.is_file():
                for m in mtl.read_text(errors="replace").splitlines():
                    if m.strip().startswith("map_Kd "):
                        candidates.append(mtl.parent / m.strip().split()[-1])
    named = list(dict.fromkeys(candidates))
    if len(named) > 1:
        warnings.warn(f"head mesh {str(mesh_path)!r} has {len(named)} textures ({', '.join(n.name for n in named)}); "
                      f"only one is drawn: {named[0].name} textures every face, so parts made for the others "
                      "show the wrong picture; bake them into one texture", stacklevel=3)
    candidates += [mesh_path.with_suffix(s) for s in (".png", ".jpg", ".jpeg")]
    for c in candidates:
        if c.is_file():
            with Image.open(c) as im:
                return np.asarray(im.convert("RGB"))
    raise ValueError(f"head mesh {str(mesh_path)!r} has no texture: neither a material file with map_Kd "
                     f"nor {mesh_path.stem}.png / .jpg beside it")


def _read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (V, 3), triangles (F, 3), uv (V, 2)) of a textured mesh file, one vertex per
    distinct position and texture coordinate."""
    pv = import_pyvista()
    try:
        poly = pv.read(str(path))
    except Exception as exc:  # VTK's readers raise many kinds
        raise ValueError(f"cannot read the head mesh {str(path)!r}: {exc}") from None
    if poly.n_cells == 0:
        raise ValueError(f"head mesh {str(path)!r} has no faces")
    poly = poly.triangulate()
    tc = poly.active_texture_coordinates
    if tc is None:
        raise ValueError(f"head mesh {str(path)!r} has no texture coordinates (vt lines); give a textured mesh")
    tri = poly.faces.reshape(-1, 4)[:, 1:]
    key = np.round(np.hstack([np.asarray(poly.points, np.float64), np.asarray(tc, np.float64)]), 9)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    faces = inverse.ravel()[tri]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    return uniq[:, :3], faces.astype(np.int64), uniq[:, 3:5]


def _cut_mouth(verts, faces, uv, f, cut):
    """Splits the triangles ``cut`` (F,) bool whose vertices lie on both sides of the lip line
    (``f`` (V,): < 0 above it, >= 0 below) along it. Returns (vertices, uv, faces, segments
    (K, 4): each cut's upper and lower copies of its two ends (u1, l1, u2, l2), side (V',): +1
    above the line (and the upper copies), -1 below)."""
    lower = f >= 0
    V = len(verts)
    new_v, new_uv = [], []
    split: dict[tuple[int, int], tuple[int, int]] = {}

    def crossing(i, j):
        k = (min(i, j), max(i, j))
        if k not in split:
            t = f[k[0]] / (f[k[0]] - f[k[1]])
            new_v.append(verts[k[0]] + t * (verts[k[1]] - verts[k[0]]))
            new_uv.append(uv[k[0]] + t * (uv[k[1]] - uv[k[0]]))
            up = V + len(new_v) * 2 - 2
            split[k] = (up, up + 1)
        return split[k]

    kept, added, segments = [], [], []
    for n, (a, b, c) in enumerate(faces):
        s = lower[[a, b, c]]
        if not cut[n] or s.all() or not s.any():
            kept.append(n)
            continue
        # rotate so that the lone vertex comes first (orientation kept)
        if s[1] != s[0] and s[1] != s[2]:
            a, b, c = b, c, a
        elif s[2] != s[0] and s[2] != s[1]:
            a, b, c = c, a, b
        ab, ac = crossing(a, b), crossing(a, c)
        mine, theirs = (1, 0) if lower[a] else (0, 1)  # index into (upper copy, lower copy)
        added += [(a, ab[mine], ac[mine]), (ab[theirs], b, c), (ab[theirs], c, ac[theirs])]
        segments.append((ab[0], ab[1], ac[0], ac[1]))
    # where the cut ends inside a triangle left whole (past the corners), its crossing is one
    # vertex: that triangle is split there without a gap (no T-junction to open a crack)
    close = {}
    for n in list(kept):
        a, b, c = faces[n]
        for i, j, k in ((a, b, c), (b, c, a), (c, a, b)):
            key = (min(i, j), max(i, j))
            if key in split:
                up, low = split[key]
                close[low] = up
                kept.remove(n)
                added += [(i, up, k), (up, j, k)]
                break
    if close:
        remap = np.arange(V + 2 * len(new_v))
        remap[list(close)] = list(close.values())
        added = [tuple(remap[list(t)]) for t in added]
        segments = [tuple(remap[list(t)]) for t in segments]
    extra_v = np.repeat(np.asarray(new_v).reshape(-1, 3), 2, axis=0)
    extra_uv = np.repeat(np.asarray(new_uv).reshape(-1, 2), 2, axis=0)
    side = np.concatenate([np.where(lower, -1.0, 1.0), np.tile([1.0, -1.0], len(new_v))])
    all_faces = np.vstack([faces[kept], np.asarray(added, np.int64).reshape(-1, 3)])
    return (np.vstack([verts, extra_v]), np.vstack([uv, extra_uv]), all_faces,
            np.asarray(segments, np.int64).reshape(-1, 4), side)


def load_head(mesh_path, points_path=None, *, height: int = 720, progress: bool = False) -> FaceMesh:
    """A :class:`voicepuppet.render.mesh.FaceMesh` of a textured 3-D head scan, seen from the front.

    Parameters
    ----------
    mesh_path : str or path-like
        a textured ``.obj`` (its texture from the material file's ``map_Kd``, else
        ``STEM.png`` / ``.jpg`` beside it).
    points_path : str or path-like, optional
        the head's 68 landmarks in 3-D, in the mesh's units (:func:`read_points_3d`); None:
        found on the head's front view (:func:`detect_points_3d`).
    height : int
        the canvas height in pixels (its width follows the face's proportions).
    progress : bool
        say on stderr what is being done (finding the points takes a few seconds).

    Returns
    -------
    FaceMesh
        its first 68 vertices the landmarks (in no face), ``canvas`` the frontal view's size,
        ``mouth`` the cut's cavity (a membrane deep behind it, walled to its edges) and the
        tongue, ``teeth`` the teeth (both as the photo mesh's,
        :func:`voicepuppet.render.interior.mouth_interior`, at the lip line's depth), and its
        interpolation matrix (module docstring).

    Raises
    ------
    ValueError
        the mesh is missing, unreadable, untextured or not an ``.obj``; the points are not 68,
        not on the mesh, mirrored, or cannot be found.
    """
    from scipy.interpolate import RBFInterpolator
    from scipy.spatial import cKDTree

    mp = Path(mesh_path)
    if not mp.is_file():
        raise ValueError(f"head mesh {str(mp)!r} does not exist")
    if mp.suffix.lower() not in HEAD_SUFFIXES:
        raise ValueError(f"head mesh {str(mp)!r}: unknown format {mp.suffix!r}; give a textured "
                         f"{' or '.join(HEAD_SUFFIXES)}")
    verts3, faces, uv = _read_mesh(mp)
    image = _texture(mp)
    if points_path is None:
        if progress:
            print(f"finding the 68 landmarks of {mp.name} on its front view (dlib; --face-points to give them)",
                  file=sys.stderr, flush=True)
        L3 = detect_points_3d(verts3, faces, uv, image, name=str(mp))
        points_path = "(detected)"
    else:
        L3 = read_points_3d(points_path)
    if len(L3) != face_layout.N_POINTS:
        raise ValueError(f"head points {str(points_path)!r} hold {len(L3)} points; a 3-D head needs the "
                         f"{face_layout.N_POINTS}-point iBUG layout")
    R = frontal_frame(L3)

    # the frontal canvas: the landmarks' extent plus 0.45 of it on each side, ``height`` pixels high
    lf, vf = L3 @ R.T, verts3 @ R.T
    lo, hi = lf[:, :2].min(axis=0), lf[:, :2].max(axis=0)
    extent = float((hi - lo).max())
    w, h = hi - lo + 0.9 * extent
    scale = height / h
    width = int(round(w * scale)) + int(round(w * scale)) % 2
    centre = 0.5 * (lo + hi)

    def canvas(p):
        return np.column_stack([(p[:, 0] - centre[0]) * scale + width / 2.0,
                                -(p[:, 1] - centre[1]) * scale + height / 2.0,
                                (p[:, 2] - lf[:, 2].mean()) * scale])

    L, V = canvas(lf), canvas(vf)
    iod = float(face_layout.inter_ocular_distance(L[:, :2]))
    off = float(np.median(cKDTree(V).query(L)[0])) / iod
    if off > 0.1:
        raise ValueError(f"head points {str(points_path)!r} are not on the mesh {str(mp)!r} (a landmark's nearest "
                         f"vertex is {off:.2f} inter-ocular distances away, as a median); give this mesh's "
                         "points, in its units")

    # the inner lip line (upper and lower averaged) from corner 60 to corner 64, by x
    line = np.vstack([L[60], 0.5 * (L[61:64] + L[[67, 66, 65]]), L[64]])
    line = line[np.argsort(line[:, 0], kind="stable")]
    mouth_centre = line.mean(axis=0)
    corner_x = line[[0, -1], 0]
    if corner_x[1] - corner_x[0] < 1e-6 * iod:
        raise ValueError("head points: the mouth's corners (points 60 and 64) coincide in the frontal view")
    cen = V[faces].mean(axis=1)
    cut = ((cen[:, 0] > corner_x[0]) & (cen[:, 0] < corner_x[1])
           & (np.linalg.norm(cen - mouth_centre, axis=1) < CUT_IOD * iod))
    below_line = V[:, 1] - np.interp(V[:, 0], line[:, 0], line[:, 1])
    V, uv, faces, segments, side = _cut_mouth(V, faces, uv, below_line, cut)

    # the spline's domain: the lips pushed apart, most at the centre, nothing at the corners
    half = 0.5 * (corner_x[1] - corner_x[0])

    def apart(p, s):
        across = np.clip(1.0 - ((p[:, 0] - mouth_centre[0]) / half) ** 2, 0.0, None)
        near = np.clip(1.0 - np.linalg.norm(p - mouth_centre, axis=1) / (CUT_IOD * iod), 0.0, None)
        q = p.copy()
        q[:, 1] -= s * LIP_SPLIT_IOD * iod * across * near
        return q

    lm_side = np.zeros(face_layout.N_POINTS)
    lm_side[[49, 50, 51, 52, 53, 61, 62, 63]] = 1.0
    lm_side[[55, 56, 57, 58, 59, 65, 66, 67]] = -1.0
    P = face_layout.N_POINTS
    rbf = RBFInterpolator(apart(L, lm_side), np.eye(P), kernel="thin_plate_spline")
    M = rbf(apart(V, side))
    d = cKDTree(L).query(V)[0] / iod
    fade = np.clip((STILL_IOD - d) / (STILL_IOD - MOVE_IOD), 0.0, 1.0)
    M *= (fade * fade * (3.0 - 2.0 * fade))[:, None]  # smoothstep

    # the mouth's interior: a membrane deep behind the cut (its own copies of the cut's vertices,
    # walled to them, edge-on from the front), and the photo mesh's tongue and teeth
    # (mouth_interior) at the lip line's depth across the mouth
    tones = _texture_tones(image, uv[d < 0.1])
    ends = np.unique(segments)
    deep = np.searchsorted(ends, segments) + len(V)
    u1, l1, u2, l2 = segments.T
    du1, dl1, du2, dl2 = deep.T
    cavity = np.vstack([np.column_stack(c) for c in (
        (du1, dl1, dl2), (du1, dl2, du2),            # the membrane
        (u1, u2, du2), (u1, du2, du1), (l1, dl2, l2), (l1, dl1, dl2))])  # the walls
    deep_v = V[ends] + [0.0, 0.0, INTERIOR_DEPTH["cavity"] * iod]
    iv, ifaces, iteeth, icolours, icarry = mouth_interior(L[:, :2], tones, cavity=False)  # the membrane is ours
    iv[:, 2] += np.interp(iv[:, 0], line[:, 0], line[:, 2]) - skin_depth(iv[:, :2], L[:, :2])

    n_skin, n_deep = len(V), len(ends)
    vertices = np.vstack([L, V, deep_v, iv])
    all_faces = np.vstack([faces, cavity, ifaces + n_skin + n_deep]) + P
    F_skin, F_cav = len(faces), len(cavity)
    mouth = np.r_[np.zeros(F_skin, bool), np.ones(F_cav, bool), ~iteeth]
    teeth = np.r_[np.zeros(F_skin + F_cav, bool), iteeth]
    colours = np.zeros((len(all_faces), 3), np.uint8)
    colours[F_skin:F_skin + F_cav] = tone(MOUTH_COLOUR, None, tones[1])
    colours[F_skin + F_cav:] = icolours
    carried = np.zeros((len(vertices), P))
    carried[P + n_skin + n_deep:] = icarry
    interp = np.vstack([np.eye(P), M, M[ends], icarry])
    return FaceMesh(vertices=vertices, faces=all_faces, mouth=mouth,
                    uv=np.vstack([np.zeros((P, 2)), uv, uv[ends], np.zeros((len(iv), 2))]),
                    image=image, n_landmarks=P, teeth=teeth, colours=colours, carried=carried,
                    fixed=np.r_[np.zeros(P, bool), fade == 0.0, np.zeros(n_deep + len(iv), bool)],
                    canvas=(width, int(height)), _interp=interp)


def _texture_tones(image: np.ndarray, uv: np.ndarray) -> tuple[float, bool]:
    """The tones (:func:`voicepuppet.render.interior.pixel_tones`) of the texture at ``uv`` (the face's
    vertices), as :func:`voicepuppet.render.interior.photo_tones` gives a photo's."""
    H, W = image.shape[:2]
    cols = np.clip(np.round(uv[:, 0] * (W - 1)), 0, W - 1).astype(int)
    rows = np.clip(np.round((1.0 - uv[:, 1]) * (H - 1)), 0, H - 1).astype(int)
    return pixel_tones(image[rows, cols])


#: the height in pixels of the front view the landmarks are detected on
DETECT_HEIGHT = 800


#: the views the points are looked for in, in turn: degrees about the model's y axis from the
#: face towards +z (scans, most tools) to towards -z (Blender's OBJ export of a head facing its
#: -Y), then +x and -x
DETECT_TURNS = (0.0, 180.0, 90.0, -90.0)


def detect_points_3d(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, image: np.ndarray,
                     name: str = "the head") -> np.ndarray:
    """The 68 landmarks (iBUG order) of a textured head found without being given: dlib's
    detector and shape predictor (:func:`voicepuppet.tracking.detect.auto_init`) on the head drawn with
    its y axis up, from +z, else -z, +x or -x (:data:`DETECT_TURNS`), unlit,
    :data:`DETECT_HEIGHT` px high, until it is sure of a face (:data:`voicepuppet.tracking.detect.SURE_FACE_SCORE`)
    that is not mirrored (a face mask seen from behind: :func:`frontal_frame`
    refuses its points); each point is lifted to the surface it
    lies on (the nearest in front along the view), and an inner lip pair with the surface
    between them at their depth (a closed mouth) becomes one point, their middle.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        the head's vertices in the model's units.
    faces : ndarray, shape (F, 3), int
        its triangles.
    uv : ndarray, shape (V, 2)
        texture coordinates into ``image``.
    image : ndarray, shape (H, W, 3), uint8
        the texture.
    name : str
        the head's name in the error message.

    Returns
    -------
    ndarray, shape (68, 3)
        the landmarks in the model's units.

    Raises
    ------
    ValueError
        naming ``name``, when no view shows a face.
    """
    for turn in DETECT_TURNS:
        a = np.radians(turn)
        Ry = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
        found = _detect_facing(vertices @ Ry.T, faces, uv, image)
        if found is None:
            continue
        try:
            frontal_frame(found)  # a face mask seen from behind shows its face mirrored
        except ValueError:
            continue
        return found @ Ry
    raise ValueError(f"no face found on {name} with its y axis up, seen from +z, -z, +x or -x; give its 68 "
                     "landmarks in 3-D with --face-points head.json")


def _detect_facing(vertices, faces, uv, image) -> np.ndarray | None:
    """:func:`detect_points_3d` on the head as seen from +z (y up), or None without a face there."""
    import cv2

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    scale = DETECT_HEIGHT / max(float(hi[1] - lo[1]), 1e-12)
    width = int(np.ceil((hi[0] - lo[0]) * scale)) + 2
    front = np.column_stack([(vertices[:, 0] - lo[0]) * scale + 1.0, (hi[1] - vertices[:, 1]) * scale + 1.0,
                             (vertices[:, 2] - hi[2]) * scale])
    view = FaceMesh(front, faces, np.zeros(len(faces), bool), uv, image, 0, np.zeros(len(front), bool),
                    canvas=(width, DETECT_HEIGHT + 2))
    with FaceRenderer(view, size=view.size) as r:
        picture = r.frame(front)
    try:
        xy = auto_init(cv2.cvtColor(picture, cv2.COLOR_RGB2GRAY), instead="--face-points head.json",
                       min_score=SURE_FACE_SCORE)
    except NoFaceError:
        return None
    surface = import_pyvista().PolyData(front, np.hstack([np.full((len(faces), 1), 3), faces]))

    def lift(x, y):
        hits, _ = surface.ray_trace([x, y, 1.0], [x, y, -(hi[2] - lo[2]) * scale - 1.0], first_point=True)
        if len(hits) == 0:  # on the silhouette: the nearest vertex in the view instead
            return front[np.argmin(np.sum((front[:, :2] - [x, y]) ** 2, axis=1))]
        return np.asarray(hits, np.float64).reshape(3)

    p = np.array([lift(x, y) for x, y in xy])
    # dlib parts the inner lips of a closed mouth (by 0.14 IOD on james): where the surface runs
    # between a pair at the lips' depth (within 0.05 IOD; an open mouth's inside lies deeper),
    # the mouth is closed there and both points are the surface at their middle
    iod = float(face_layout.inter_ocular_distance(xy))
    for up, low in ((61, 67), (62, 66), (63, 65)):
        mid = lift(*(0.5 * (xy[up] + xy[low])))
        if abs(mid[2] - 0.5 * (p[up, 2] + p[low, 2])) < 0.05 * iod:
            p[up] = p[low] = mid
    return np.column_stack([(p[:, 0] - 1.0) / scale + lo[0], hi[1] - (p[:, 1] - 1.0) / scale, p[:, 2] / scale + hi[2]])


def sample_head() -> tuple[Path, Path]:
    """(mesh, points) of a real textured head scan with 68 3-D landmarks: ``james.obj`` (+ its
    material and ``james.jpg``) and ``james.ljson`` from the menpo3d 0.8.6 source archive,
    fetched once from PyPI into the cache folder.

    Returns
    -------
    mesh : Path
        ``james.obj``.
    points : Path
        ``james.ljson``.
    """
    dest = os.path.join(cache_dir(), f"menpo3d-{MENPO3D_VERSION}")
    names = ["james.obj", "james.obj.mtl", "james.jpg", "james.ljson"]
    if not all(os.path.exists(os.path.join(dest, n)) for n in names):
        fetch_sdist("menpo3d", MENPO3D_VERSION, _MENPO3D_DATA, names, dest)
    return Path(dest, "james.obj"), Path(dest, "james.ljson")
