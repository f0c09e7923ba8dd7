"""Error measures between predicted and ground-truth facial motion.

- :func:`err`: Voice Puppetry eq. 7, ``|x − y|² / |x + y|²`` on motion about the ground truth's
  mean face (penalises motion in the wrong direction: 0 is perfect, 1 is what a prediction of no
  motion at all scores, more is worse than no motion). Summed over the whole sequence before the
  ratio, so nearly-neutral frames cannot blow it up.
- :func:`l1`, :func:`rms`, :func:`linf`: Englebienne et al. figure 4 errors (per coordinate).
- :func:`landmark_rmse_iod`: root mean squared landmark distance over the inter-ocular distance
  (outer eye corners 36 and 45 of the 68-point layout, or ``iod`` given).
- :func:`lip_vertex_error`: per frame, the largest squared distance over the mouth points; averaged.
- :func:`closures`: of the stretches where the lips must close (the frames of B, P, M), how many
  the prediction closes (a perceptual measure the errors above do not see: a mouth that never
  quite closes can have a low lip error).
- :func:`summary`: all of them for two landmark sequences.
"""

from __future__ import annotations

import numpy as np

from voicepuppet.layout import LIP_GAP, MOUTH, inter_ocular_distance

#: Mouth points of the 68-point iBUG layout.
IBUG68_MOUTH = tuple(int(i) for i in MOUTH)
#: The middle points of the upper and lower inner lip (68-point layout): the lips' gap.
IBUG68_LIP_GAP = LIP_GAP
#: A gap at most this fraction of the inter-ocular distance is a closed mouth (about 1 px on the
#: synthetic performer, whose closed lips are 0.004 apart; open speech, 0.05-0.3).
CLOSED_GAP_IOD = 0.01


def _pair(pred, truth, what="pred and truth"):
    x = np.asarray(pred, dtype=np.float64)
    y = np.asarray(truth, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError(f"{what} must have the same shape; got {x.shape} and {y.shape} (resample the "
                         "prediction to the ground truth's frame rate and length first)")
    if x.size == 0:
        raise ValueError(f"{what} are empty")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError(f"{what} must be finite (no NaN or inf)")
    return x.reshape(len(x), -1), y.reshape(len(y), -1)


def err(pred, truth) -> float:
    """Voice Puppetry eq. 7 on motion about the ground truth's mean (see the module notes).

    Parameters
    ----------
    pred, truth : array (T, ...)
        Frames of face vectors or landmarks, same shape.

    Returns
    -------
    float
        ``|x − y|² / |x + y|²`` over the whole sequence, x and y the prediction and the truth
        minus the truth's mean frame: 0 is perfect, 1 is no motion.

    Raises
    ------
    ValueError
        ``pred`` and ``truth`` of different shapes, empty or not finite, or neither with any
        motion (the ratio is undefined).
    """
    x, y = _pair(pred, truth)
    mean = y.mean(axis=0)
    x, y = x - mean, y - mean
    den = float(np.sum((x + y) ** 2))
    if den <= 0:
        raise ValueError("err: the ground truth has no motion and the prediction none either; the "
                         "ratio is undefined")
    return float(np.sum((x - y) ** 2)) / den


def l1(pred, truth) -> float:
    """Mean absolute error per coordinate.

    Parameters
    ----------
    pred, truth : array_like, shape (T, ...)
        Frames of face vectors or landmarks, same shape (finite, not empty).

    Returns
    -------
    float
        The mean of ``|pred − truth|`` over all frames and coordinates.

    Raises
    ------
    ValueError
        ``pred`` and ``truth`` of different shapes, empty, or not finite.
    """
    x, y = _pair(pred, truth)
    return float(np.mean(np.abs(x - y)))


def rms(pred, truth) -> float:
    """Root mean squared error per coordinate.

    Parameters
    ----------
    pred, truth : array_like, shape (T, ...)
        Frames of face vectors or landmarks, same shape (finite, not empty).

    Returns
    -------
    float
        The square root of the mean of ``(pred − truth)²`` over all frames and coordinates.

    Raises
    ------
    ValueError
        ``pred`` and ``truth`` of different shapes, empty, or not finite.
    """
    x, y = _pair(pred, truth)
    return float(np.sqrt(np.mean((x - y) ** 2)))


def linf(pred, truth) -> float:
    """Largest absolute error of any coordinate in any frame.

    Parameters
    ----------
    pred, truth : array_like, shape (T, ...)
        Frames of face vectors or landmarks, same shape (finite, not empty).

    Returns
    -------
    float
        The maximum of ``|pred − truth|``.

    Raises
    ------
    ValueError
        ``pred`` and ``truth`` of different shapes, empty, or not finite.
    """
    x, y = _pair(pred, truth)
    return float(np.max(np.abs(x - y)))


def _landmarks(pred_pts, true_pts):
    x = np.asarray(pred_pts, dtype=np.float64)
    y = np.asarray(true_pts, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 2 or x.shape != y.shape:
        raise ValueError(f"landmarks must both have shape (frames, points, 2); got {x.shape} and {y.shape}")
    _pair(x, y, "predicted and true landmarks")
    return x, y


def inter_ocular(true_pts) -> np.ndarray:
    """Per-frame distance between the outer eye corners (:func:`voicepuppet.layout.inter_ocular_distance`).

    Parameters
    ----------
    true_pts : array_like, shape (T, 68, 2)

    Returns
    -------
    ndarray, shape (T,)
        The distance of points 36 and 45 in each frame.

    Raises
    ------
    ValueError
        The eye corners coincide in some frame.
    """
    d = inter_ocular_distance(true_pts)
    if np.any(d <= 0):
        raise ValueError("the eye corners coincide in some frame; the inter-ocular distance is zero")
    return d


def landmark_rmse_iod(pred_pts, true_pts, iod=None) -> float:
    """RMS point-to-point distance divided by the inter-ocular distance (per frame, then averaged).

    Parameters
    ----------
    pred_pts, true_pts : array_like, shape (T, P, 2)
        Predicted and true landmarks of the same frames (finite).
    iod : float or array_like, shape (T,), optional
        Inter-ocular distance to divide by (default: :func:`inter_ocular` of ``true_pts``,
        which needs the 68-point layout).

    Returns
    -------
    float
        The mean over frames of the RMS landmark distance over the inter-ocular distance.

    Raises
    ------
    ValueError
        Landmarks not of one shape (T, P, 2), empty, or not finite, or (without ``iod``) coinciding
        eye corners.
    """
    x, y = _landmarks(pred_pts, true_pts)
    d = inter_ocular(y) if iod is None else np.broadcast_to(np.asarray(iod, dtype=np.float64), (len(y),))
    per_frame = np.sqrt(np.mean(np.sum((x - y) ** 2, axis=2), axis=1)) / d
    return float(per_frame.mean())


def lip_vertex_error(pred_pts, true_pts, mouth=IBUG68_MOUTH) -> float:
    """Lip vertex error: per frame the maximum squared distance over the mouth points, averaged
    over frames (pixels²).

    Parameters
    ----------
    pred_pts, true_pts : array_like, shape (T, P, 2)
        Predicted and true landmarks of the same frames (finite).
    mouth : sequence of int
        Indices of the mouth points (default :data:`IBUG68_MOUTH`, the 68-point layout's).

    Returns
    -------
    float
        The lip vertex error in squared landmark units (pixels²).

    Raises
    ------
    ValueError
        Landmarks not of one shape (T, P, 2), empty, or not finite, or too few points for ``mouth``.
    """
    x, y = _landmarks(pred_pts, true_pts)
    mouth = list(mouth)
    if x.shape[1] <= max(mouth):
        raise ValueError(f"lip vertex error needs the mouth points {mouth[0]}..{mouth[-1]}; these "
                         f"landmarks have {x.shape[1]} points: give mouth= indices")
    return float(np.mean(np.max(np.sum((x[:, mouth] - y[:, mouth]) ** 2, axis=2), axis=1)))


def closures(pred_pts, true_pts, must_close, closed_iod: float = CLOSED_GAP_IOD,
             gap=IBUG68_LIP_GAP) -> tuple[int, int]:
    """Lip closures: of the runs of frames where ``must_close`` (T,) is set (the frames of the
    bilabials B, P, M, say), how many the prediction closes, i.e. in at least one of the run's
    frames its lips' gap (the distance of points ``gap``) is at most ``closed_iod`` of the true
    face's inter-ocular distance. Pool the counts over sequences.

    Parameters
    ----------
    pred_pts, true_pts : array_like, shape (T, P, 2)
        Predicted and true landmarks of the same frames (finite).
    must_close : array_like of bool, shape (T,)
        The frames where the lips must close.
    closed_iod : float
        Largest lip gap that counts as closed, as a fraction of the true inter-ocular distance
        (default :data:`CLOSED_GAP_IOD`).
    gap : pair of int
        The two points whose distance is the lips' gap (default :data:`IBUG68_LIP_GAP`).

    Returns
    -------
    closed : int
        Runs of ``must_close`` the prediction closes.
    runs : int
        Runs of ``must_close`` in all.

    Raises
    ------
    ValueError
        Landmarks not of one shape (T, P, 2), empty, or not finite, ``must_close`` without one
        entry per frame, too few points for ``gap``, or coinciding eye corners.
    """
    x, y = _landmarks(pred_pts, true_pts)
    m = np.asarray(must_close, dtype=bool)
    if m.shape != (len(x),):
        raise ValueError(f"must_close must have one entry per frame ({len(x)}), got shape {m.shape}")
    if x.shape[1] <= max(gap):
        raise ValueError(f"the lips' gap needs points {gap}; these landmarks have {x.shape[1]} points: give gap=")
    shut = np.linalg.norm(x[:, gap[0]] - x[:, gap[1]], axis=1) <= closed_iod * inter_ocular(y)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], m.astype(np.int8), [0]])))
    runs = list(zip(edges[::2], edges[1::2]))
    return int(sum(bool(shut[a:b].any()) for a, b in runs)), len(runs)


def summary(pred_pts, true_pts, face_space=None) -> dict:
    """All measures for two landmark sequences [T, P, 2].

    With a :class:`~voicepuppet.face.FaceSpace`, ``err`` and the per-coordinate errors are
    computed on pose-free face coordinates (the model's own space, as in the papers); without one,
    on the pixel landmarks.

    Parameters
    ----------
    pred_pts, true_pts : array_like, shape (T, P, 2)
        Predicted and true landmarks of the same frames (finite).
    face_space : voicepuppet.face.FaceSpace, optional
        The face space of ``err``, ``l1``, ``rms`` and ``linf`` (default: none, pixel landmarks).

    Returns
    -------
    dict
        ``frames``, ``err``, ``l1``, ``rms``, ``linf``, and with 68 points ``rmse_iod`` and ``lve``.

    Raises
    ------
    ValueError
        Landmarks not of one shape (T, P, 2), empty, or not finite.
    """
    x, y = _landmarks(pred_pts, true_pts)
    if face_space is not None:
        fx, _ = face_space.encode(x)
        fy, _ = face_space.encode(y)
    else:
        fx, fy = x, y
    out = {"frames": int(len(x)), "err": err(fx, fy), "l1": l1(fx, fy), "rms": rms(fx, fy),
           "linf": linf(fx, fy)}
    if x.shape[1] == 68:
        out["rmse_iod"] = landmark_rmse_iod(x, y)
        out["lve"] = lip_vertex_error(x, y)
    return out
