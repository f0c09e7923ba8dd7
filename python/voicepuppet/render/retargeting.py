"""Retargeting and action units: landmark motion carried onto a face mesh.

The animation is retargeted first: its displacements from its rest face
(:attr:`voicepuppet.animation.Animation.rest`: the face its puppet makes in silence, else its
first frame) are mapped onto the face's landmarks through the similarity transform (scale,
rotation) between the two neutral shapes (:func:`similarity`, :func:`retarget`).

Driving the mesh (:func:`mesh_animation`), two ways:

- ``mode="vertex"``: landmark displacements move the landmark vertices; every other vertex
  moves by a thin-plate-spline interpolation (scipy's ``RBFInterpolator``) of them, with the
  image frame held still (:meth:`voicepuppet.render.mesh.FaceMesh.interpolation_matrix`).
- ``mode="au"``: an action-unit basis on the mesh (:data:`ACTION_UNITS`: jaw open, lip corner
  pulls, pucker, lip press, upper lip raise, brow raise, blinks) with per-frame least-squares
  activations; the landmark motion outside the basis span is dropped (reported by
  :func:`fit_activations`).

:func:`expression_offset` turns action-unit weights into a whole-face expression for the
animator's controls (:func:`voicepuppet.animation.apply_controls`).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet.animation import Animation, check_points
from voicepuppet.render.mesh import FaceMesh

__all__ = ["ACTION_UNITS", "similarity", "retarget", "action_unit_basis", "fit_activations",
           "expression_offset", "mesh_animation"]

#: action units of the basis, in column order; activation 1 is a full expression
ACTION_UNITS = ("jaw_open", "smile_right", "smile_left", "pucker", "lip_press", "upper_lip_raise",
                "brow_raise", "blink_right", "blink_left")


def similarity(reference: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The similarity (scale, rotation) that best maps ``reference`` onto ``target``
    (orthogonal Procrustes; row vectors, ``x_ref @ sR ~ x_tgt`` about their centroids).

    Parameters
    ----------
    reference, target : ndarray, shape (P, 2)
        two shapes with corresponding points.

    Returns
    -------
    ndarray, shape (2, 2)
        ``s R``, to multiply row vectors on the right.
    """
    ref_c = reference - reference.mean(axis=0)
    tgt_c = target - target.mean(axis=0)
    u, sv, vt = np.linalg.svd(ref_c.T @ tgt_c)
    d = np.sign(np.linalg.det(u @ vt))
    D = np.diag([1.0, d])
    s = float(np.sum(sv * np.diag(D)) / max(np.sum(ref_c ** 2), 1e-300))
    return s * (u @ D @ vt)


def retarget(points: np.ndarray, reference: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Maps landmark motion onto another face: ``target + s R (points - reference)``, ``s R`` of
    :func:`similarity`.

    Parameters
    ----------
    points : ndarray, shape (T, P, 2)
        the animation's frames.
    reference : ndarray, shape (P, 2)
        the animation's rest face.
    target : ndarray, shape (P, 2)
        the face to carry the motion onto, at rest.

    Returns
    -------
    ndarray, shape (T, P, 2)
        the displacements to add to ``target``.
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

    Raises
    ------
    ValueError
        ``landmarks`` are not 68 finite points.
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

    Raises
    ------
    ValueError
        the displacements are not finite (T, P, 2) frames, or the basis does not match them.
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

    Parameters
    ----------
    neutral : array_like, shape (68, 2)
        the face the expression is made on, at rest.
    weights : dict or str
        ``{unit: weight}`` or a string ``"smile_left=1,smile_right=1"`` (a unit alone weighs 1);
        units from :data:`ACTION_UNITS`.

    Returns
    -------
    ndarray, shape (68, 2)
        the offset; use with :func:`voicepuppet.animation.add_offset` or
        :func:`voicepuppet.animation.apply_controls`.

    Raises
    ------
    ValueError
        an item of the string is not UNIT or UNIT=WEIGHT, a unit is unknown, or ``neutral`` is
        not 68 finite points.
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
    anim : Animation
        with P points per frame (the mesh's landmark count).
    mesh : FaceMesh
        the face to drive.
    mode : {"vertex", "au"}
    neutral : ndarray, shape (P, 2), optional
        the animation's rest shape (default: :attr:`Animation.rest`, its neutral or first frame).

    Returns
    -------
    dict
        ``vertices`` (T, V, 3) in image coordinates (x, y down, z), and for ``"au"``
        ``activations`` (T, K), ``targets`` (K, V, 3) (vertex displacement per unit activation)
        and ``rms_error`` (T,) in pixels of the photo.

    Raises
    ------
    ValueError
        the animation's points are not the mesh's landmarks, ``mode="au"`` without the 68-point
        layout, or an unknown ``mode``.
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
