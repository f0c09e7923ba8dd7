"""Tracked landmarks: the tracker's result, its files, and its frame-rate regridding.

:class:`TrackResult` holds what the tracker found; :func:`save_landmarks` writes it as
``.npz`` with a ``.csv`` twin and :func:`load_landmarks` reads it back (DESIGN.md, "Files users
exchange"); :func:`load_init_points` reads the first-frame points of ``track --init``;
:func:`on_uniform_grid` resamples points tracked on a variable-rate video onto the uniform
frame grid of the audio features.
"""

from __future__ import annotations

import json
import os
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from voicepuppet._files import atomic_path, read_npz, write_npz
from voicepuppet.layout import N_POINTS
from voicepuppet.tracking._checks import check_points
from voicepuppet.tracking.detect import SEPARATE_PX, separate_coincident
from voicepuppet.tracking.video import MAX_GRID_SLIP, grid_slip

__all__ = ["TrackResult", "save_landmarks", "load_landmarks", "load_init_points", "on_uniform_grid",
           "MAX_GAP_FRAMES"]


@dataclass
class TrackResult:
    """Landmarks tracked through a sequence (:func:`voicepuppet.tracking.tracker.track_frames`,
    :func:`voicepuppet.tracking.tracker.track_video`); each parameter is kept as the attribute
    of its name.

    Parameters
    ----------
    points : ndarray, shape (T, P, 2), float64
        Positions (x, y) in pixels.
    confidence : ndarray, shape (T, P), float64
        In [0, 1], correlation with the first-frame patch.
    lost : ndarray, shape (T, P), bool
        Outside the image or not matching its first-frame patch.
    fps : float
        Frames per second (of a variable-rate video: its most common rate,
        :func:`voicepuppet.tracking.video.nominal_rate`; ``times`` says when each frame is).
    edges : ndarray, shape (E, 2), int64
        Spring edges.
    rest_length : ndarray, shape (E,)
        The rest lengths (px) of the springs of the last pass.
    stiffness : ndarray, shape (E,)
        The stiffnesses (px^-2) of the springs of the last pass.
    passes : list of dict
        One dict per pass: ``pass``, ``max_rel_length_change`` and ``max_length_change``
        (px; of the springs it re-estimated), ``mean_point_change`` (px, mean displacement from
        the previous pass), ``lost_fraction``, ``reacquired``.
    names : list of str, optional
        (P,) landmark names.
    working_scale : float, default 1.0
        The factor f the frames were resized by for tracking (1: full resolution; see
        :func:`voicepuppet.tracking.scale.working_scale_factor`); points, rest lengths (px) and
        stiffnesses (px^-2) are reported in full-resolution pixels.
    reacquired : list of int
        Frames (indices, last pass) where the face, lost for
        :data:`voicepuppet.tracking.reacquire.REACQUIRE_FRAMES` frames, was found again by the
        whole-frame search and the mesh restarted there (each pass's list is in
        ``passes[k]["reacquired"]``).
    start : int, default 0
        The frame tracking started on (0 unless ``init="auto"`` found no face on the first
        frame: the frames before it are all lost, their points those of ``start``).
    times : ndarray, shape (T,), optional
        Presentation time of each frame in seconds, the first at 0, from the video's container
        (:func:`voicepuppet.tracking.video.frame_times`), or None (frame ``k`` at ``k / fps``):
        with a variable frame rate the two differ, and training resamples the points onto a
        uniform grid by these times (:meth:`on_grid`).
    """

    points: np.ndarray
    confidence: np.ndarray
    lost: np.ndarray
    fps: float
    edges: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    passes: list = field(default_factory=list)
    names: list | None = None
    working_scale: float = 1.0
    reacquired: list = field(default_factory=list)
    start: int = 0
    times: np.ndarray | None = None

    def on_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """The points on the uniform grid ``k / fps`` the audio features are on: as they are for a
        constant frame rate, interpolated by ``times`` for a variable one
        (:func:`on_uniform_grid`); what to give ``Puppet.train`` with the video's audio.

        Returns
        -------
        points : ndarray, shape (T', P, 2), float64
            Positions on the grid.
        lost : ndarray, shape (T', P), bool
            Lost flags on the grid.
        """
        return on_uniform_grid(self.points, self.lost, self.times, self.fps)


#: On the uniform grid of :func:`on_uniform_grid`, a frame between two video frames further apart
#: than this many frame periods (the camera stalled) is lost rather than interpolated.
MAX_GAP_FRAMES = 3.0


def on_uniform_grid(points, lost, times, fps: float, where: str = ""):
    """Tracked points on the frame grid ``k / fps`` of the audio features.

    ``times`` are the frames' time stamps (s, the first at 0: ``TrackResult.times``, or the
    ``times`` of a landmarks file), None for frame ``k`` at ``k / fps``. Within
    :data:`voicepuppet.tracking.video.MAX_GRID_SLIP` frame periods of that everywhere, the points are
    returned as they are; otherwise (a variable frame rate, or another video's rate) they are
    interpolated linearly in time onto the grid, with a warning: a grid frame is lost if either
    video frame around it is, or if they are more than :data:`MAX_GAP_FRAMES` periods apart.

    Parameters
    ----------
    points : array_like, shape (T, P, 2)
        Tracked positions (x, y).
    lost : array_like, shape (T, P), bool, or None
        Lost flags; None: none lost.
    times : array_like, shape (T,), or None
        The frames' time stamps, s.
    fps : float
        The grid's frame rate.
    where : str, default ""
        A prefix for the warning and error messages (which sequence they are about).

    Returns
    -------
    points : ndarray, shape (T', P, 2), float64
        The positions on the grid (``T' = T`` when no resampling was needed).
    lost : ndarray, shape (T', P), bool
        The lost flags on the grid.

    Raises
    ------
    ValueError
        ``times`` do not match the frames or are not finite and increasing.
    """
    points = np.asarray(points, dtype=np.float64)
    T = len(points)
    lost = np.zeros(points.shape[:2], dtype=bool) if lost is None else np.asarray(lost, dtype=bool).reshape(T, -1)
    if times is None:
        return points, lost
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    if len(times) != T:
        raise ValueError(f"{where}{len(times)} frame times for {T} frames; track the video again")
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError(f"{where}frame times must be finite and increasing; track the video again")
    if T < 2 or grid_slip(times, fps) <= MAX_GRID_SLIP:
        return points, lost
    times = times - times[0]
    grid = np.arange(int(np.floor(times[-1] * fps + 1e-9)) + 1) / fps
    i = np.clip(np.searchsorted(times, grid, side="right") - 1, 0, T - 2)
    w = np.clip((grid - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
    out = (1.0 - w)[:, None, None] * points[i] + w[:, None, None] * points[i + 1]
    # inside a stall (not on the frames around it)
    gap = ((times[i + 1] - times[i]) > MAX_GAP_FRAMES / fps) & (w > 1e-6) & (w < 1.0 - 1e-6)
    out_lost = lost[i] | (lost[i + 1] & (w > 0)[:, None]) | gap[:, None]
    step = np.diff(times) * 1e3
    warnings.warn(f"{where}the video's frames are not on the training's {fps:g} fps grid (they are "
                  f"{step.min():.1f}-{step.max():.1f} ms apart); its {T} tracked frames are resampled to "
                  f"{len(grid)} on the grid, to line up with the audio"
                  + (f" ({int(gap.sum())} in gaps longer than {MAX_GAP_FRAMES:g} frames are lost)" if gap.any() else ""),
                  stacklevel=2)
    return out, out_lost


def load_init_points(path: str | os.PathLike) -> tuple[np.ndarray, list | None]:
    """Reads first-frame points: JSON ``{"points": [[x, y], ...], "names": [...]}`` (names
    optional) or CSV with one ``x,y`` row per point (an optional header row is skipped).

    Points of the 68-point layout that share a position (a closed mouth in whole pixels) are
    moved :data:`voicepuppet.tracking.detect.SEPARATE_PX` apart as
    :func:`voicepuppet.tracking.detect.auto_init` moves dlib's, with a warning; other layouts keep
    them (the spring mesh then refuses the pair, naming it).

    Parameters
    ----------
    path : str or os.PathLike
        A ``.json`` file, or any other name for CSV.

    Returns
    -------
    points : ndarray, shape (P, 2), float64
        The points (x, y), P >= 3.
    names : list of str or None
        Their names, if the JSON file gives them.

    Raises
    ------
    ValueError
        The file does not exist, cannot be parsed, or holds fewer than 3 finite points (or as
        many names as points).
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"init points file {str(p)!r} does not exist; pass a JSON or CSV file, or --init auto")
    text = p.read_text(encoding="utf-8")
    names = None
    if p.suffix.lower() == ".json":
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"init points file {str(p)!r} is not valid JSON: {exc}") from exc
        if not isinstance(doc, dict) or "points" not in doc:
            raise ValueError(f'init points file {str(p)!r} must hold {{"points": [[x, y], ...]}}')
        try:
            pts = np.asarray(doc["points"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"init points in {str(p)!r} must be a list of [x, y] numbers") from exc
        names = doc.get("names")
        if names is not None and len(names) != len(pts):
            raise ValueError(f"init points file {str(p)!r} has {len(pts)} points but {len(names)} names")
    else:
        rows = []
        for k, line in enumerate(text.splitlines()):
            cells = [c.strip() for c in line.split(",") if c.strip()]
            if not cells:
                continue
            try:
                rows.append([float(cells[0]), float(cells[1])])
            except (ValueError, IndexError):
                if k == 0:
                    continue  # header
                raise ValueError(f"init points file {str(p)!r} line {k + 1} is not 'x,y': {line!r}") from None
        pts = np.asarray(rows, dtype=np.float64).reshape(-1, 2)
    pts = check_points(pts, f"points in {str(p)!r}")
    if len(pts) == N_POINTS:
        separated = separate_coincident(pts)
        moved = np.flatnonzero(np.any(separated != pts, axis=1))
        if len(moved):
            warnings.warn(f"points {', '.join(map(str, moved))} in {str(p)!r} share positions (a closed mouth "
                          f"given in whole pixels?); moved {SEPARATE_PX:g} px apart as --init auto does",
                          stacklevel=2)
        pts = separated
    return pts, names


def save_landmarks(path: str | os.PathLike, result: TrackResult, csv: bool = True) -> list[Path]:
    """Writes ``result`` as ``.npz`` (``points`` [T, P, 2], ``fps``, ``confidence`` [T, P],
    ``lost`` [T, P], ``edges``, ``reacquired`` [R] (frames where a lost face was found again and
    the mesh restarted), ``working_scale``, optional ``names`` and ``times`` [T] (each frame's
    time stamp in the video, s)) and a ``.csv`` twin (``frame, time, x0, y0, ...``; ``time`` the
    time stamp, else frame / fps), each through a temporary file and a rename.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.npz`` to write; the ``.csv`` twin goes beside it.
    result : TrackResult
        What the tracker found.
    csv : bool, default True
        Also write the ``.csv`` twin.

    Returns
    -------
    list of pathlib.Path
        The paths written.

    Raises
    ------
    ValueError
        ``path`` does not end in ``.npz`` or its directory does not exist.
    """
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise ValueError(f"landmarks path must end in .npz, got {str(path)!r}")
    if not path.parent.exists():
        raise ValueError(f"output directory {str(path.parent)!r} does not exist; create it first")
    arrays = {"points": result.points.astype(np.float64), "fps": np.float64(result.fps),
              "confidence": result.confidence.astype(np.float64), "lost": result.lost.astype(bool),
              "edges": result.edges.astype(np.int64),
              "reacquired": np.asarray(result.reacquired, dtype=np.int64).reshape(-1),
              "working_scale": np.float64(result.working_scale)}
    if result.names is not None:
        arrays["names"] = np.asarray(result.names, dtype=str)
    if result.times is not None:
        arrays["times"] = np.asarray(result.times, dtype=np.float64)

    with atomic_path(path, (".npz",), "landmarks") as tmp, open(tmp, "wb") as fh:
        write_npz(fh, arrays)  # fixed zip timestamps: equal tracks are equal bytes
    written = [path]
    if csv:
        T, P, _ = result.points.shape
        header = "frame,time," + ",".join(f"x{i},y{i}" for i in range(P))
        times = np.arange(T) / result.fps if result.times is None else result.times
        table = np.column_stack([np.arange(T), times, result.points.reshape(T, -1)])
        csv_path = path.with_suffix(".csv")

        with atomic_path(csv_path, (".csv",), "landmarks") as tmp:
            np.savetxt(tmp, table, fmt=["%d", "%.6f"] + ["%.4f"] * (2 * P), delimiter=",", header=header,
                       comments="")
        written.append(csv_path)
    return written


def load_landmarks(path: str | os.PathLike) -> dict:
    """Reads a landmarks ``.npz`` back as a dict of arrays (``points``, ``fps``, ...).

    Parameters
    ----------
    path : str or os.PathLike
        A landmarks file written by :func:`save_landmarks`.

    Returns
    -------
    dict of str to ndarray
        The file's arrays by name.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        The path is the ``.csv`` twin (it lacks the frame rate and the lost flags: the ``.npz``
        beside it is the one to read) or anything that is not an ``.npz`` archive.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"landmarks file {str(p)!r} does not exist; make one with voicepuppet track")
    if p.suffix.lower() == ".csv":
        raise ValueError(f"{str(p)!r} is the .csv twin of a landmarks file: it has no frame rate or lost "
                         f"flags; pass the .npz that voicepuppet track wrote beside it ({p.with_suffix('.npz').name})")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"landmarks file {str(p)!r} is not an .npz archive (truncated or another format); "
                         "make one with voicepuppet track")
    return read_npz(p, "landmarks file")
