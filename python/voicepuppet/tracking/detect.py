"""Face detection and initialisation: dlib's 68 landmarks on the first frame with a face.

``--init auto`` (:func:`auto_init`) runs dlib's frontal face detector and its 68-point shape
predictor (iBUG 300-W layout) on a frame; :func:`first_face` looks for the first frame of a
video with a face when the first has none. dlib comes with ``pip install`` (the ``dlib-bin`` wheel)
and so does its model (the ``face-recognition-models`` package, :func:`landmark_model`); they are
loaded when a face is looked for.
"""

from __future__ import annotations

import functools
import itertools
import os
import threading
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from voicepuppet.layout import OUTER_EYE_CORNERS, neutral_landmarks
from voicepuppet.tracking import video
from voicepuppet.tracking._checks import as_grey

__all__ = ["NoFaceError", "auto_init", "first_face", "separate_coincident", "landmark_model", "DLIB_MODEL_PATHS",
           "DLIB_MODEL_NAME",
           "AUTO_INIT_STRIDE_S", "AUTO_INIT_SCAN_S", "PROBE_MAX_PIXELS", "SEPARATE_PX", "SURE_FACE_SCORE"]


# Where Debian's libdlib-data puts dlib's 68-point model, looked at after VOICEPUPPET_DLIB_MODEL
# and before the copy the face-recognition-models package installs.
DLIB_MODEL_PATHS = ("/usr/share/dlib/shape_predictor_68_face_landmarks.dat",)
#: The model's file name, in every place it is looked for.
DLIB_MODEL_NAME = "shape_predictor_68_face_landmarks.dat"
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


def landmark_model() -> str | None:
    """The file of dlib's 68-point shape predictor, or None when none is installed.

    Looked for in the environment variable ``VOICEPUPPET_DLIB_MODEL``, then at
    :data:`DLIB_MODEL_PATHS` (Debian's ``libdlib-data``), then in the ``face-recognition-models``
    package that ``pip install voicepuppet`` brings (found without importing it).

    Returns
    -------
    str or None
    """
    import importlib.util

    candidates = [os.environ.get("VOICEPUPPET_DLIB_MODEL", "")] + list(DLIB_MODEL_PATHS)
    spec = importlib.util.find_spec("face_recognition_models")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        candidates.append(os.path.join(folder, "models", DLIB_MODEL_NAME))
    return next((c for c in candidates if c and Path(c).is_file()), None)


def auto_init(frame: np.ndarray, instead: str = "--init points.json",
              max_pixels: int | None = None, min_score: float | None = None) -> np.ndarray:
    """Finds 68 face landmarks on a frame with dlib's shape predictor (iBUG 300-W layout).

    dlib's detector looks at the frame, then (no face found) at it upsampled once and twice, each
    time twice the size on a side for faces half as small; with ``max_pixels`` only the sizes of
    at most that many pixels after the first (see :data:`PROBE_MAX_PIXELS`). Of several faces
    the largest of those the detector is sure of (:data:`SURE_FACE_SCORE`) is taken, else its
    surest: the largest alone took the astronaut's badge (score 0.05) over her face (1.50). With
    ``min_score``, detections scoring less are no face.

    Needs the ``dlib-bin`` (or ``dlib``) wheel and the model file (:func:`landmark_model`), both
    installed with voicepuppet.

    Parameters
    ----------
    frame : ndarray, shape (H, W) or (H, W, 3), uint8
        The frame, grey or BGR.
    instead : str, default "--init points.json"
        The caller's way to give the points by hand, named in the errors.
    max_pixels : int, optional
        Upsample the frame only while it has at most this many pixels (the first size is always
        looked at); default: up to twice.
    min_score : float, optional
        Detections scoring less are no face; default: all the detector reports.

    Returns
    -------
    ndarray, shape (68, 2), float64
        The landmarks (x, y) in the frame's pixels, points on one pixel moved apart
        (:func:`separate_coincident`).

    Raises
    ------
    ValueError
        dlib or its model is not installed (the message says what to install), or the frame is
        not a uint8 image.
    NoFaceError
        No face was found (a ``ValueError``). Both messages name ``instead``.
    """
    try:
        import dlib  # noqa: F401  (here only to say what to install; the detector loads it)
    except ImportError:
        raise ValueError("finding face landmarks automatically needs dlib, which installs with voicepuppet: "
                         "pip install dlib-bin (or reinstall voicepuppet), or pass the points with "
                         f'{instead} ({{"points": [[x, y], ...]}})') from None
    model = landmark_model()
    if model is None:
        raise ValueError("finding face landmarks automatically: dlib is installed but not its 68-point model: "
                         "pip install face-recognition-models (or reinstall voicepuppet), or set "
                         f"VOICEPUPPET_DLIB_MODEL to {DLIB_MODEL_NAME}, or pass the points with {instead}")
    g = as_grey(frame, 0, None)
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
    return separate_coincident(points)


#: dlib's detection box around its own 68 points, measured on the shared real clips (188 faces):
#: the box's centre lies BOX_DROP_IOD inter-ocular distances above the points' centroid (up the
#: face) and its side is BOX_SIDE_IOD of them (spread 0.07 and 0.13).
BOX_DROP_IOD = 0.128
BOX_SIDE_IOD = 1.73


def landmarks_near(frame: np.ndarray, points: np.ndarray, model: str | None = None) -> np.ndarray | None:
    """dlib's 68 points on ``frame`` for the face where ``points`` (a 68-point face, e.g. the
    previous frame's) put it: its shape predictor run in the box dlib's detector would draw around
    those points (:data:`BOX_DROP_IOD`, :data:`BOX_SIDE_IOD`), without the detector.

    Parameters
    ----------
    frame : ndarray, shape (H, W), uint8
        The grey frame.
    points : ndarray, shape (68, 2)
        Where the face is (iBUG 300-W layout), in the frame's pixels.
    model : str, optional
        dlib's 68-point model file; default :func:`landmark_model` (looked up on every call: a
        caller asking frame after frame looks it up once and passes it).

    Returns
    -------
    ndarray, shape (68, 2), float64, or None
        The points, or None when dlib or its model is not installed or the box is degenerate.
    """
    model = model or landmark_model()
    if model is None or not np.all(np.isfinite(points)):
        return None
    try:
        import dlib
    except ImportError:
        return None
    eyes = points[45] - points[36]
    iod = float(np.hypot(*eyes))
    if not iod > 1.0:
        return None
    up = np.array([eyes[1], -eyes[0]]) / iod  # the face's up, turned with its roll
    centre = points.mean(axis=0) + BOX_DROP_IOD * iod * up
    half = 0.5 * BOX_SIDE_IOD * iod
    box = dlib.rectangle(int(round(centre[0] - half)), int(round(centre[1] - half)),
                         int(round(centre[0] + half)), int(round(centre[1] + half)))
    with _DLIB_LOCK:
        shape = _dlib_predictor(model)(np.ascontiguousarray(frame), box)
    return np.array([[shape.part(i).x, shape.part(i).y] for i in range(shape.num_parts)], dtype=np.float64)


def separate_coincident(points: np.ndarray) -> np.ndarray:
    """``points`` with the points that share a position moved :data:`SEPARATE_PX` apart.

    dlib gives whole pixels, so on a closed mouth the upper and lower inner lip (61-63 and 67-65)
    land on one pixel, as may a lip corner's outer and inner point; the spring mesh needs distinct
    points. Each point of a shared position moves half the distance away from the others, in the
    direction it lies from them on the neutral face (:func:`voicepuppet.animation.neutral_landmarks`)
    turned by the head's roll (the outer eye corners' line): upper lip up, lower lip down.

    Parameters
    ----------
    points : ndarray, shape (68, 2), float64
        Landmarks (x, y) of the 68-point layout.

    Returns
    -------
    ndarray, shape (68, 2), float64
        ``points`` itself when no two share a position, else a moved copy.
    """
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


def first_face(path, first: np.ndarray, fps: float, progress: bool = False,
               grey: bool = True) -> tuple[int, np.ndarray, np.ndarray]:
    """The first frame of a video that :func:`auto_init` finds a face on, and the face's points.

    That is ``first`` (the video's first frame, as decoded), else the first probe (one frame
    every :data:`AUTO_INIT_STRIDE_S` s up to :data:`AUTO_INIT_SCAN_S` s at ``fps``) with a face,
    or the earliest of the frames since the probe before it that has one; after the first frame
    the detector upsamples only up to :data:`PROBE_MAX_PIXELS`.

    Parameters
    ----------
    path : str or os.PathLike
        The video.
    first : ndarray, shape (H, W) or (H, W, 3), uint8
        Its first frame, as decoded.
    fps : float
        Its frame rate (sets the probes' spacing).
    progress : bool, default False
        Show a progress bar over the probes.
    grey : bool, default True
        Decode the probed frames grey (else BGR).

    Returns
    -------
    index : int
        The frame's index in the video.
    frame : ndarray, shape (H, W) or (H, W, 3), uint8
        The frame as decoded: grey, or BGR without ``grey``.
    points : ndarray, shape (68, 2), float64
        The face's landmarks on it.

    Raises
    ------
    NoFaceError
        No frame looked at has a face.
    ValueError
        dlib or its model is not installed, or the video cannot be opened.
    """
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
