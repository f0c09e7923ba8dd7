"""Benchmark suite ``tracker``: the spring-mesh SSD tracker beside OpenCV's pyramidal
Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``) on the same 26 points of the same frames.

The frames are the planted-truth sequence of :func:`planted_face_sequence` (a real face photo,
``skimage.data.astronaut()``, warped over time by a known smooth deformation with noise, a
brightness drift, blur and a sliding occluder), rendered at 640x480 before timing starts, so
the timings exclude decoding. Both trackers see the same frames and start from the same points;
``agree`` is our mean error divided by LK's mean error against the planted truth (below 1: we
are more accurate), and each case carries both errors and frames per second.

Peers and data are benchmark dependencies only: ``pip install opencv-contrib-python-headless
scikit-image``.
"""

from __future__ import annotations

import importlib
import time

import numpy as np

from voicepuppet import _core
from voicepuppet.bench.runner import case, timeit_interleaved
from voicepuppet.synth import face_photo

# 26 landmarks on the astronaut's face (frame coordinates after the 1.25x resize below): dlib's
# 68-point model on that frame, points 0, 4, 8, 12, 16 (jaw), 17, 19, 21, 22, 24, 26 (brows),
# 36, 39, 42, 45 (eye corners), 27, 30, 31, 33, 35 (nose), 48, 51, 54, 57, 62, 66 (mouth).
ASTRONAUT_POINTS = np.array([
    [225, 128], [231, 187], [275, 223], [316, 205], [340, 134],
    [233, 117], [251, 109], [270, 116], [295, 117], [315, 113], [331, 123],
    [244, 126], [266, 130], [297, 131], [319, 130],
    [282, 128], [281, 159], [268, 164], [280, 168], [293, 165],
    [251, 174], [272, 174], [296, 175], [278, 195], [279, 180], [278, 188],
], dtype=np.float64)
MOUTH_POINTS = np.arange(20, 26)  # rows of ASTRONAUT_POINTS that the occluder covers

_FACE_CENTRE = np.array([282.0, 165.0])


def _require(module: str, pip_name: str):
    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(f"the tracker benchmark and tests need {module}: "
                          f"pip install {pip_name}") from exc


def _base_frame() -> np.ndarray:
    cv2 = _require("cv2", "opencv-contrib-python-headless")
    data = _require("skimage.data", "scikit-image")
    grey = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY)
    return cv2.resize(grey, (640, 640), interpolation=cv2.INTER_AREA)[:480].astype(np.float32)


def _motion(t: np.ndarray | float, n_frames: int):
    """Similarity and local-bump parameters of frame t (t = 0: identity)."""
    u = 2 * np.pi * np.asarray(t, dtype=np.float64) / max(n_frames, 2)
    tx = 22 * np.sin(u) + 6 * np.sin(3 * u)
    ty = 10 * np.sin(2 * u)
    theta = np.deg2rad(6) * np.sin(u + 0.3) * np.sin(u)
    scale = 1 + 0.06 * np.sin(2 * u) * np.sin(u)
    jaw = 5 * np.sin(5 * u) ** 2        # mouth opening, px
    brow = 3 * np.sin(3 * u) ** 2       # brow raise, px
    return tx, ty, theta, scale, jaw, brow


def _source_of(x: np.ndarray, y: np.ndarray, t: float, n_frames: int):
    """Where frame t's pixel (x, y) samples the base photo (the inverse deformation)."""
    tx, ty, theta, scale, jaw, brow = _motion(t, n_frames)
    cx, cy = _FACE_CENTRE
    # Local bumps: the jaw region moves down by `jaw`, the brows up by `brow` (smooth Gaussians).
    jaw_w = np.exp(-((x - 280) ** 2 / (2 * 45.0 ** 2) + (y - 205) ** 2 / (2 * 25.0 ** 2)))
    brow_w = np.exp(-((x - 282) ** 2 / (2 * 55.0 ** 2) + (y - 113) ** 2 / (2 * 10.0 ** 2)))
    xb = x
    yb = y - jaw * jaw_w + brow * brow_w
    # Inverse similarity about the face centre.
    dx, dy = xb - cx - tx, yb - cy - ty
    c, s = np.cos(theta), np.sin(theta)
    return cx + (c * dx + s * dy) / scale, cy + (-s * dx + c * dy) / scale


def _truth(points0: np.ndarray, t: float, n_frames: int) -> np.ndarray:
    """Frame-t positions of base-photo points: solve source_of(x) = p0 by Newton-like steps."""
    _, _, theta, scale, _, _ = _motion(t, n_frames)
    c, s = np.cos(theta), np.sin(theta)
    jac_inv = scale * np.array([[c, -s], [s, c]])  # inverse of the similarity part's Jacobian
    x = points0.copy()
    for _ in range(100):
        sx, sy = _source_of(x[:, 0], x[:, 1], t, n_frames)
        r = np.stack([sx, sy], axis=1) - points0
        x = x - r @ jac_inv.T
        if np.max(np.abs(r)) < 1e-9:
            break
    return x


def planted_face_sequence(n_frames: int = 120, seed: int = 0, noise: float = 3.0,
                          occlusion: tuple[int, int] | None = (70, 80), blur: tuple[int, int] | None = (45, 55)):
    """A real face photo deformed over time by a known smooth motion, with planted positions.

    Parameters
    ----------
    n_frames : number of frames (>= 2); the motion is periodic over them.
    seed : seed of the noise.
    noise : standard deviation of the additive Gaussian pixel noise (grey levels).
    occlusion : frames [start, stop) during which a textured card slides across the mouth.
    blur : frames [start, stop) blurred with a Gaussian of sigma 1.5 px.

    Returns
    -------
    frames : (n_frames, 480, 640) uint8 grey frames.
    truth : (n_frames, 26, 2) true positions (x, y) of :data:`ASTRONAUT_POINTS`.
    occluded : (n_frames, 26) bool, True where the card covers a point's neighbourhood.
    """
    cv2 = _require("cv2", "opencv-contrib-python-headless")
    if n_frames < 2:
        raise ValueError(f"n_frames must be at least 2, got {n_frames}")
    rng = np.random.default_rng(seed)
    base = _base_frame()
    h, w = base.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    card_src = _base_frame()[300:380, 40:200].copy()  # the astronaut's suit: real texture
    frames = np.empty((n_frames, h, w), dtype=np.uint8)
    truth = np.empty((n_frames, len(ASTRONAUT_POINTS), 2))
    occluded = np.zeros((n_frames, len(ASTRONAUT_POINTS)), dtype=bool)
    for t in range(n_frames):
        sx, sy = _source_of(xs, ys, t, n_frames)
        img = cv2.remap(base, sx.astype(np.float32), sy.astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REFLECT)
        truth[t] = _truth(ASTRONAUT_POINTS, t, n_frames)
        if blur and blur[0] <= t < blur[1]:
            img = cv2.GaussianBlur(img, (0, 0), 1.5)
        if occlusion and occlusion[0] <= t < occlusion[1]:
            # The card slides left to right across the mouth, 8 px per frame.
            k = t - occlusion[0]
            mouth = truth[t, MOUTH_POINTS]
            top = int(mouth[:, 1].min()) - 16
            left = int(mouth[:, 0].mean()) - 80 + 8 * (k - (occlusion[1] - occlusion[0]) // 2)
            bottom = int(mouth[:, 1].max()) + 16
            hh = bottom - top
            img[top:bottom, left:left + 160] = card_src[:hh, :max(0, min(160, w - left))]
            inside = ((truth[t, :, 0] > left - 6) & (truth[t, :, 0] < left + 166)
                      & (truth[t, :, 1] > top - 6) & (truth[t, :, 1] < bottom + 6))
            occluded[t] = inside
        gain = 1.0 - 0.3 * t / (n_frames - 1)
        bias = 25.0 * t / (n_frames - 1)
        img = gain * img + bias + rng.normal(0.0, noise, size=img.shape)
        frames[t] = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return frames, truth, occluded


def track_lk(frames: np.ndarray, points: np.ndarray, *, patch_radius: int = 6,
             levels: int = 3) -> np.ndarray:
    """Pyramidal Lucas-Kanade (OpenCV) from the same points with the same patch and pyramid.

    Parameters
    ----------
    frames : ndarray of uint8, shape (T, H, W)
        Grey frames.
    points : ndarray, shape (P, 2)
        Points (x, y) on frame 0.
    patch_radius : int
        Half the window's side, as the spring-mesh tracker's patch.
    levels : int
        Pyramid levels.

    Returns
    -------
    ndarray, shape (T, P, 2)
        Positions (frame 0 = the given points).
    """
    cv2 = _require("cv2", "opencv-contrib-python-headless")
    win = 2 * patch_radius + 1
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    out = np.empty((len(frames), len(points), 2))
    p = points.astype(np.float32).reshape(-1, 1, 2)
    out[0] = points
    for t in range(1, len(frames)):
        q, _, _ = cv2.calcOpticalFlowPyrLK(frames[t - 1], frames[t], p, None, winSize=(win, win),
                                           maxLevel=levels - 1, criteria=crit)
        p = q
        out[t] = q.reshape(-1, 2)
    return out


def _track_ours(frames: np.ndarray, points: np.ndarray, mesh) -> np.ndarray:
    tracker = _core.SpringMeshTracker(frames[0], points, mesh)
    out = np.empty((len(frames), len(points), 2))
    out[0] = points
    for t in range(1, len(frames)):
        out[t] = tracker.track(frames[t]).points
    return out


def run(quick: bool, repeats: int) -> list[dict]:
    """Frames per second of one spring-mesh pass vs ``calcOpticalFlowPyrLK``, 26 points, 640x480.

    Parameters
    ----------
    quick : bool
        Small sizes, for a smoke run.
    repeats : int
        Timed repeats per case (median).

    Returns
    -------
    list of dict
        Rows made by :func:`voicepuppet.bench.runner.case`.
    """
    cv2 = _require("cv2", "opencv-contrib-python-headless")
    cv2.setNumThreads(1)  # one core for both
    n = 40 if quick else 120
    frames, truth, _ = planted_face_sequence(n)
    mesh = _core.springs_from_points(ASTRONAUT_POINTS, _core.delaunay_edges(ASTRONAUT_POINTS))
    fns = {"ours": lambda: _track_ours(frames, ASTRONAUT_POINTS, mesh),
           "lk": lambda: track_lk(frames, ASTRONAUT_POINTS)}
    med, res = timeit_interleaved(fns, repeats)
    err_ours = float(np.linalg.norm(res["ours"] - truth, axis=2).mean())
    err_lk = float(np.linalg.norm(res["lk"] - truth, axis=2).mean())
    per = n - 1
    # Per-frame compute (one more pass, timed frame by frame) for the streaming percentiles.
    tracker = _core.SpringMeshTracker(frames[0], ASTRONAUT_POINTS, mesh)
    frame_ms = []
    for t in range(1, n):
        t0 = time.perf_counter()
        tracker.track(frames[t])
        frame_ms.append(1e3 * (time.perf_counter() - t0))
    return [case("track_26pts_640x480", f"{per} frames, 26 points, 13x13 patch, 3 levels",
                 med["ours"], "cv2.calcOpticalFlowPyrLK", med["lk"], err_ours / err_lk,
                 frames_per_s=per / med["ours"], peer_frames_per_s=per / med["lk"],
                 mean_error_px=err_ours, peer_mean_error_px=err_lk,
                 realtime_factor=(per / 29.97) / med["ours"],
                 frame_ms_p50=float(np.percentile(frame_ms, 50)),
                 frame_ms_p99=float(np.percentile(frame_ms, 99)),
                 opencv=cv2.__version__)]


def similarity_ramp(n_frames: int, max_angle: float, max_scale: float, min_scale: float, seed: int,
                    noise: float = 2.0, canvas: int = 400):
    """The performer's photo seen through a known similarity ramp, with its exact landmarks.

    The photo (grey, 320x320, reflect-padded to ``canvas``) turns about the face centre from 0 to
    ``max_angle`` degrees and back, scales 1 -> ``max_scale`` -> ``min_scale`` -> 1 and
    translates by up to 20 px, with Gaussian pixel noise; the 68 landmarks move exactly with it.

    Parameters
    ----------
    n_frames : int
        Frames of the ramp.
    max_angle : float
        Largest rotation (degrees), at the middle of the ramp.
    max_scale, min_scale : float
        Largest and smallest scale, at 35 % and 75 % of the ramp.
    seed : int
        Seeds the pixel noise.
    noise : float
        Standard deviation of the pixel noise (grey levels, default 2).
    canvas : int
        Side of the square frames (px, default 400).

    Returns
    -------
    frames : ndarray, shape (T, canvas, canvas), uint8
    truth : ndarray, shape (T, 68, 2)
        The landmarks in each frame (px).
    angle : ndarray, shape (T,)
        Rotation per frame (radians).
    scale : ndarray, shape (T,)
        Scale per frame.
    """
    import cv2

    photo = face_photo((320, 320), fallback=False)
    grey = cv2.cvtColor(photo.image, cv2.COLOR_RGB2GRAY)
    pad = (canvas - 320) // 2
    image = cv2.copyMakeBorder(grey, pad, pad, pad, pad, cv2.BORDER_REFLECT).astype(np.float32)
    points = photo.points + pad
    centre = points.mean(axis=0)
    u = np.linspace(0.0, 1.0, n_frames)
    angle = np.deg2rad(max_angle) * np.sin(np.pi * u)
    scale = np.interp(u, [0.0, 0.35, 0.75, 1.0], [1.0, max_scale, min_scale, 1.0])
    shift = np.stack([20 * np.sin(2 * np.pi * u), 10 * np.sin(4 * np.pi * u)], axis=1)
    rng = np.random.default_rng(seed)
    frames, truth = [], []
    for a, s, b in zip(angle, scale, shift):
        A = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        t = centre - A @ centre + b
        f = cv2.warpAffine(image, np.hstack([A, t[:, None]]), (canvas, canvas), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REFLECT)
        frames.append(np.clip(np.round(f + rng.normal(0.0, noise, f.shape)), 0, 255).astype(np.uint8))
        truth.append(points @ A.T + t)
    return np.stack(frames), np.stack(truth), angle, scale


#: Re-acquisition cases of :func:`planted`: (absent from, absent to, shift x, shift y, cover).
REACQUIRE_CASES = (
    (60, 90, 90, 60, "plain"),
    (60, 90, 90, 60, "card"),
    (100, 120, 60, 0, "plain"),
    (40, 80, 100, 80, "card"),
)
#: Where :func:`planted` puts the clip, and the canvas beyond it (room for the largest shift).
PLANT_START = (20, 20)
PLANT_MARGIN = (110, 90)


def planted(frames: np.ndarray, truth: np.ndarray, absent, shift, cover: str, *, start=PLANT_START,
            margin=PLANT_MARGIN, bg: int | None = None):
    """A clip whose face leaves and comes back elsewhere: planted truth for re-acquisition.

    ``frames`` are placed at ``start`` in a plain canvas ``margin`` px larger than start + frame;
    for the frames ``absent`` = [a, b) the face is gone (``cover="plain"``: the bare canvas;
    ``"card"``: seeded smooth noise where the face was), and from frame b on it is back ``shift``
    px further on.

    Parameters
    ----------
    frames : ndarray, shape (T, h, w), uint8
        The clip's grey frames.
    truth : ndarray, shape (T, P, 2)
        Its landmarks (px).
    absent : (int, int)
        First frame without the face and the frame it is back.
    shift : (int, int)
        Where the face comes back, relative to where it was (px, x and y).
    cover : {"plain", "card"}
        What stands where the face was while it is gone.
    start : (int, int)
        Where the clip's frame is placed in the canvas (px).
    margin : (int, int)
        Canvas beyond the clip's frame (px): room for the largest shift.
    bg : int, optional
        The canvas grey (default the median of the first frame's outer columns).

    Returns
    -------
    canvas_frames : ndarray, shape (T, H, W), uint8
    moved_truth : ndarray, shape (T, P, 2)
        ``truth`` moved with the face.
    """
    import cv2

    n, h, w = frames.shape
    H, W = h + start[1] + margin[1], w + start[0] + margin[0]
    if bg is None:
        bg = int(np.median(np.concatenate([frames[0][:, :4].ravel(), frames[0][:, -4:].ravel()])))
    out = np.full((n, H, W), bg, np.uint8)
    moved = np.empty_like(truth)
    for t in range(n):
        ox, oy = (start[0] + shift[0], start[1] + shift[1]) if t >= absent[1] else start
        if not absent[0] <= t < absent[1]:
            out[t, oy:oy + h, ox:ox + w] = frames[t]
        elif cover == "card":
            noise = np.random.default_rng(t).normal(130.0, 40.0, (h, w))
            out[t, oy:oy + h, ox:ox + w] = np.clip(cv2.GaussianBlur(noise, (0, 0), 3.0), 0, 255).astype(np.uint8)
        moved[t] = truth[t] + [ox, oy]
    return out, moved
