"""Video in and out for the tracker: decoding to grey frames and writing overlay videos (OpenCV).

OpenCV (``opencv-contrib-python-headless``) is imported lazily, so the rest of the package works
without it; a missing install raises an ``ImportError`` that says what to install.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from voicepuppet._files import atomic_path

__all__ = ["VideoInfo", "probe_video", "frame_times", "grid_slip", "nominal_rate", "MAX_GRID_SLIP", "iter_frames",
           "frame_at", "read_grey_frames", "downscale", "write_overlay"]


def _cv2():
    try:
        import cv2
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("video decoding needs OpenCV: pip install opencv-contrib-python-headless") from exc
    return cv2


class VideoInfo:
    """What a video holds, as reported by the container (:func:`probe_video`); each parameter is
    kept as the attribute of its name.

    Parameters
    ----------
    path : str
        The video file.
    width : int
        Frame width, px.
    height : int
        Frame height, px.
    fps : float
        Frame rate (0 when unknown).
    frame_count : int
        Number of frames (0 when unknown).
    """

    def __init__(self, path: str, width: int, height: int, fps: float, frame_count: int):
        self.path, self.width, self.height, self.fps, self.frame_count = path, width, height, fps, frame_count

    def __repr__(self) -> str:
        return (f"VideoInfo({self.path!r}, {self.width}x{self.height}, {self.fps:.3f} fps, "
                f"{self.frame_count} frames)")


def _open(path: str | os.PathLike):
    cv2 = _cv2()
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"video {str(p)!r} does not exist or is not a file; pass the path of a video file")
    cap = cv2.VideoCapture(str(p))
    if not cap.isOpened():
        cap.release()
        if _sound_only(p):
            raise ValueError(f"{str(p)!r} is sound without pictures: faces are tracked from video; give a "
                             "video of the face talking (voicepuppet animate is the verb that takes audio)")
        raise ValueError(f"video {str(p)!r} cannot be opened by OpenCV (unknown or corrupt format); "
                         "convert it to mp4 (H.264) or avi first")
    return cap


def _sound_only(path: Path) -> bool:
    """Whether FFmpeg (PyAV) reads ``path`` as audio streams without a video stream."""
    import av
    import av.logging

    try:
        with av.logging.Capture(), av.open(str(path)) as container:  # FFmpeg's own complaints kept quiet
            return bool(container.streams.audio) and not container.streams.video
    except (av.error.FFmpegError, OSError):
        return False


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Opens ``path`` and reports its size, frame rate and frame count.

    Parameters
    ----------
    path : str or os.PathLike
        A video file.

    Returns
    -------
    VideoInfo
        Its size, frame rate and frame count.

    Raises
    ------
    ValueError
        The file does not exist or cannot be decoded.
    """
    cv2 = _cv2()
    cap = _open(path)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or 0.0
        return VideoInfo(str(path), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                         int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), fps,
                         max(0, int(cap.get(cv2.CAP_PROP_FRAME_COUNT))))
    finally:
        cap.release()


#: Frame stamps closer than this share of the median interval are one stamp repeated by a muxer.
TIED_STAMPS = 0.25
#: Frame times further than this many frame periods from ``k / fps`` mean the frame rate varies
#: (or is another than ``fps``): training resamples the tracked points onto the grid.
MAX_GRID_SLIP = 0.25


def frame_times(path: str | os.PathLike) -> np.ndarray | None:
    """Presentation times (s) of a video's frames in display order, the first at 0, read from the
    container's packets (demuxed by PyAV, not decoded: a fraction of a second for an hour).

    A phone's video often has a variable frame rate: frame ``k`` is then not at ``k / fps``, and
    these times are what lines the frames up with the sound. Frames less than
    :data:`TIED_STAMPS` of the median frame interval apart (a muxer's repeated or one-tick-apart
    stamps) are spread evenly up to the next stamp.

    Parameters
    ----------
    path : str or os.PathLike
        A video file.

    Returns
    -------
    ndarray, shape (T,), float64, or None
        The times, s; None when the container gives a frame no time stamp (or PyAV cannot read
        it): frame ``k`` is then at ``k / fps``.
    """
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                return None
            stream = container.streams.video[0]
            pts = [pk.pts for pk in container.demux(stream) if pk.size]
            base = stream.time_base
    except (av.error.FFmpegError, OSError):
        return None
    if not pts or any(p is None for p in pts) or base is None:
        return None
    times = _untie(np.sort(np.asarray(pts, dtype=np.float64)) * float(base))
    return times - times[0]


def _untie(times: np.ndarray) -> np.ndarray:
    """Sorted stamps with each run closer than :data:`TIED_STAMPS` of the median interval (a
    muxer's repeated or one-tick-apart stamp) spread evenly up to the stamp after it."""
    times = np.array(times, dtype=np.float64)
    gaps = np.diff(times)
    if not len(gaps) or not np.any(gaps < TIED_STAMPS * np.median(gaps)):
        return times
    step = np.median(gaps)
    first = np.flatnonzero(np.concatenate([[True], gaps >= TIED_STAMPS * step]))
    count = np.diff(np.append(first, len(times)))
    following = np.append(times[first[1:]], times[first[-1]] + step * count[-1])
    for k, m, nxt in zip(first[count > 1], count[count > 1], following[count > 1]):
        times[k:k + m] = times[k] + (nxt - times[k]) * np.arange(m) / m
    return times


def grid_slip(times: np.ndarray, fps: float) -> float:
    """The largest distance of frame times from the grid ``k / fps``, in frame periods: about 0
    for a constant frame rate, growing along a video whose rate varies.

    Parameters
    ----------
    times : array_like, shape (T,)
        Frame times, s (measured from the first).
    fps : float
        The grid's frame rate.

    Returns
    -------
    float
        The largest distance, in frame periods (0 for no frames).
    """
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    return float(np.max(np.abs(times - times[0] - np.arange(len(times)) / fps)) * fps) if len(times) else 0.0


#: Frame rates a camera records at; a rate measured within 1 % of one is taken to be it.
COMMON_RATES = (24000 / 1001, 24.0, 25.0, 30000 / 1001, 30.0, 48.0, 50.0, 60000 / 1001, 60.0, 120.0)


def nominal_rate(times: np.ndarray) -> float:
    """The frame rate of a video's most common frame interval (the mean of the intervals within
    25 % of the median: stamps rounded to milliseconds average out), snapped to a
    :data:`COMMON_RATES` rate within 1 %: what a variable-rate video runs at most of the time (a
    phone's 30 fps with drops: 30, where OpenCV reports the average rate, e.g. 27.4).

    Parameters
    ----------
    times : array_like, shape (T,)
        Frame times, s, increasing, T >= 2.

    Returns
    -------
    float
        The frame rate, frames per second.

    Raises
    ------
    ValueError
        Fewer than two increasing times.
    """
    gaps = np.diff(np.asarray(times, dtype=np.float64).reshape(-1))
    if not len(gaps) or not np.median(gaps) > 0:
        raise ValueError("nominal_rate needs at least two increasing frame times")
    mid = float(np.median(gaps))
    rate = 1.0 / float(np.mean(gaps[np.abs(gaps - mid) <= 0.25 * mid]))
    near = min(COMMON_RATES, key=lambda r: abs(r - rate))
    return near if abs(near - rate) <= 0.01 * rate else rate


def downscale(frame: np.ndarray, scale: float) -> np.ndarray:
    """``frame`` resized by ``scale`` (0 < scale <= 1) with area averaging (``cv2.INTER_AREA``).

    The output is ``round(W * scale)`` by ``round(H * scale)`` pixels, and a point (x, y) of
    ``frame`` (pixel centres at integers) is at ``((x + 0.5) * scale - 0.5, (y + 0.5) * scale
    - 0.5)`` in it, in both axes with the same ``scale`` (OpenCV's own factor, not the rounded
    size's).

    Parameters
    ----------
    frame : ndarray, shape (H, W) or (H, W, 3)
        The frame.
    scale : float
        The factor, in (0, 1].

    Returns
    -------
    ndarray
        The resized frame; ``frame`` itself, untouched, when ``scale == 1``.

    Raises
    ------
    ValueError
        ``scale`` is not in (0, 1].
    """
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"scale must be in (0, 1] (a downscale factor), got {scale!r}")
    if scale == 1.0:
        return frame
    cv2 = _cv2()
    return cv2.resize(frame, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def iter_frames(path: str | os.PathLike, grey: bool = True, scale: float = 1.0) -> Iterator[np.ndarray]:
    """Yields the frames of a video in order, decoded by OpenCV.

    Parameters
    ----------
    path : str or os.PathLike
        A video file.
    grey : bool, default True
        Yield grey frames (else BGR).
    scale : float, default 1.0
        Resize the frames by this factor in (0, 1] (see :func:`downscale`).

    Yields
    ------
    ndarray, shape (H, W) or (H, W, 3), uint8
        The next frame: grey, or BGR if not ``grey``.

    Raises
    ------
    ValueError
        The file does not exist or cannot be decoded, or ``scale`` is not in (0, 1].
    """
    cv2 = _cv2()
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"scale must be in (0, 1] (a downscale factor), got {scale!r}")
    cap = _open(path)
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if grey:
                frame = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            yield np.ascontiguousarray(downscale(frame, scale))
    finally:
        cap.release()


def frame_at(path: str | os.PathLike, index: int, grey: bool = True) -> np.ndarray | None:
    """Frame ``index`` of a video as :func:`iter_frames` yields it (decoded in order up to it).

    Parameters
    ----------
    path : str or os.PathLike
        A video file.
    index : int
        The frame's index, from 0.
    grey : bool, default True
        Return it grey (else BGR).

    Returns
    -------
    ndarray, shape (H, W) or (H, W, 3), uint8, or None
        The frame, or None if the video has no such frame.
    """
    frames = iter_frames(path, grey=grey)
    try:
        return next(itertools.islice(frames, int(index), None), None)
    finally:
        frames.close()


def read_grey_frames(path: str | os.PathLike) -> tuple[np.ndarray, float]:
    """Decodes a whole video to grey frames.

    Parameters
    ----------
    path : str or os.PathLike
        A video file.

    Returns
    -------
    frames : ndarray, shape (T, H, W), uint8
        The frames.
    fps : float
        Frames per second (29.97 assumed, with a warning-free fallback, if the container has
        none).

    Raises
    ------
    ValueError
        The video cannot be opened or holds no frames.
    """
    info = probe_video(path)
    frames = list(iter_frames(path))
    if not frames:
        raise ValueError(f"video {str(path)!r} holds no decodable frames; check the file")
    return np.stack(frames), (info.fps if info.fps > 0 else 29.97)


def write_overlay(path: str | os.PathLike, frames_bgr, points: np.ndarray, lost: np.ndarray,
                  fps: float, edges: np.ndarray | None = None, progress=None) -> None:
    """Writes an inspection video: the mesh edges and points drawn over each frame (green:
    tracked, red: lost). Written to a temporary file and renamed, so never half-written.

    Parameters
    ----------
    path : str or os.PathLike
        Output video (.mp4, .m4v, .mov or .avi).
    frames_bgr : iterable of ndarray
        (H, W, 3) uint8 BGR (or (H, W) grey) frames, at least T of them.
    points : ndarray, shape (T, P, 2)
        Positions (x, y).
    lost : ndarray, shape (T, P), bool
        Lost flags.
    fps : float
        Frame rate of the output.
    edges : ndarray, shape (E, 2), optional
        Point index pairs to draw.
    progress : callable, optional
        Called with 1 after each frame.

    Raises
    ------
    ValueError
        A path of another extension or in a directory that does not exist, a codec that cannot
        write, or fewer frames than points.
    """
    cv2 = _cv2()
    path = Path(path)
    ext = path.suffix.lower()
    fourcc = {".mp4": "mp4v", ".m4v": "mp4v", ".mov": "mp4v", ".avi": "MJPG"}.get(ext)
    if fourcc is None:
        raise ValueError(f"overlay path {str(path)!r} must end in .mp4, .mov or .avi, got {ext or 'no extension'!r}")
    if not path.parent.exists():
        raise ValueError(f"overlay directory {str(path.parent)!r} does not exist; create it first")
    writer = None
    t = 0
    with atomic_path(path, what="overlay") as tmp:
        try:
            for frame in frames_bgr:
                if t >= len(points):
                    break
                img = frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
                img = img.copy()
                if writer is None:
                    h, w = img.shape[:2]
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), float(fps), (w, h))
                    if not writer.isOpened():
                        raise ValueError(f"cannot write overlay video {str(path)!r} with codec {fourcc}; "
                                         "try an .avi path")
                p = points[t]
                if edges is not None:
                    for a, b in edges:
                        cv2.line(img, tuple(int(round(v)) for v in p[a]), tuple(int(round(v)) for v in p[b]),
                                 (200, 160, 0), 1, cv2.LINE_AA)
                for i, (x, y) in enumerate(p):
                    colour = (0, 0, 255) if lost[t, i] else (0, 255, 0)
                    cv2.circle(img, (int(round(x)), int(round(y))), 2, colour, -1, cv2.LINE_AA)
                writer.write(img)
                t += 1
                if progress is not None:
                    progress(1)
            if writer is None or t < len(points):
                raise ValueError(f"overlay needs {len(points)} frames but the video gave {t}")
            writer.release()
            writer = None
        finally:
            if writer is not None:
                writer.release()
