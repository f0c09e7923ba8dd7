"""Landmark animations: the file format users exchange, validation, the animator's controls.

An animation is ``points`` float64 [T, P, 2] (pixel coordinates x, y), ``fps`` and optional
``names`` [P], ``confidence`` [T, P] and ``neutral`` [P, 2] (the face at rest, which rendering
and export retarget from; a puppet's animation carries the face it makes in silence). On disk
(DESIGN.md, "Files users exchange") it is an ``.npz`` with those arrays, or a ``.csv`` twin with
one row per frame: ``frame,time,x0,y0,x1,y1,...`` (frames only: read back, its rest is its first
frame).

Also here: :func:`exaggerate`, :func:`add_offset` and :func:`apply_controls` (the animator's
controls), and :func:`neutral_landmarks` / :func:`procedural_animation`, a parametric 68-point
face with planted jaw, smile, pucker, brow and blink motion for demos, tests and benchmarks.
"""

from __future__ import annotations

import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet.layout import neutral_landmarks
from voicepuppet._files import atomic_path, read_npz, write_npz
from voicepuppet.limits import check_limit

__all__ = ["Animation", "AnimationWriter", "load_animation", "save_animation", "check_points",
           "neutral_landmarks", "procedural_animation", "exaggerate", "add_offset", "apply_controls"]


def check_points(points, name: str = "points", n_points: Optional[int] = None) -> np.ndarray:
    """Validates landmark frames: float64 [T, P, 2], finite. Returns a C-contiguous copy.

    Raises ``ValueError`` naming ``name``, what was expected and what came.

    Parameters
    ----------
    points : array_like, shape (T, P, 2)
        Landmark frames, pixel coordinates (x, y).
    name : str
        What the points are, for the error messages (default ``"points"``).
    n_points : int, optional
        The number of points P required (default any P >= 1).

    Returns
    -------
    ndarray, shape (T, P, 2)
        A C-contiguous float64 copy of ``points``.

    Raises
    ------
    ValueError
        ``points`` not numbers, not of shape (T, P, 2) with T, P >= 1, more frames or points
        than :data:`voicepuppet.limits.LIMITS` allows, not ``n_points`` points per frame, or
        with NaN or infinite values.
    """
    try:
        arr = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numbers of shape (T, P, 2); could not convert: {exc}") from None
    if arr.ndim != 3 or arr.shape[2] != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{name} must have shape (T, P, 2) with T >= 1 frames of P >= 1 (x, y) points, "
                         f"got {arr.shape}; a single frame of shape (P, 2) needs a leading axis")
    check_limit(arr.shape[0], "frames", f"{name}: frames")
    check_limit(arr.shape[1], "points", f"{name}: points per frame")
    if n_points is not None and arr.shape[1] != n_points:
        raise ValueError(f"{name} must have {n_points} points per frame to match the face mesh, got "
                         f"{arr.shape[1]}; use landmarks in the same layout as the face's points")
    bad = ~np.isfinite(arr)
    if bad.any():
        t, p, _ = np.argwhere(bad)[0]
        raise ValueError(f"{name} must be finite, got {int(bad.sum())} NaN/inf values (first at frame {t}, "
                         f"point {p}); fill lost points (e.g. interpolate) before rendering or exporting")
    return np.ascontiguousarray(arr)


def _check_fps(fps) -> float:
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"fps must be a positive finite number of frames per second, got {value}")
    return check_limit(value, "fps", "animation fps", "give the frame rate the animation was made at")


@dataclass
class Animation:
    """A landmark animation.

    The constructor checks and converts its arguments; each is kept as the attribute of the
    same name.

    Parameters
    ----------
    points : array_like, shape (T, P, 2)
        pixel coordinates (x right, y down) per frame.
    fps : float
        frames per second; frame ``t`` is shown at time ``t / fps``.
    names : list of str or None, length P
        a name per point (default None).
    confidence : array_like, shape (T, P), or None
        a tracking confidence per point and frame (default None).
    neutral : array_like, shape (P, 2), or None
        the face at rest that rendering and export retarget displacements from (:attr:`rest`);
        None (the default): the first frame.

    Attributes
    ----------
    rest : ndarray, shape (P, 2)
        :attr:`neutral`, else the first frame.
    n_frames, n_points : int
        T and P.
    duration : float
        Seconds covered by the frames: ``T / fps``.
    times : ndarray, shape (T,)
        Frame times ``t / fps``.

    Raises
    ------
    ValueError
        ``points`` or ``neutral`` not finite or of the wrong shape, ``fps`` outside the range of
        :data:`voicepuppet.limits.LIMITS` (1 to 1000), or ``names`` / ``confidence`` not
        matching P (and T).
    """

    points: np.ndarray
    fps: float
    names: Optional[list] = None
    confidence: Optional[np.ndarray] = None
    neutral: Optional[np.ndarray] = None

    def __post_init__(self):
        self.points = check_points(self.points)
        self.fps = _check_fps(self.fps)
        T, P, _ = self.points.shape
        if self.names is not None:
            self.names = [str(n) for n in self.names]
            if len(self.names) != P:
                raise ValueError(f"names must have one entry per point ({P}), got {len(self.names)}")
        if self.confidence is not None:
            conf = np.asarray(self.confidence, dtype=np.float64)
            if conf.shape != (T, P):
                raise ValueError(f"confidence must have shape ({T}, {P}), got {conf.shape}")
            self.confidence = conf
        if self.neutral is not None:
            if np.shape(self.neutral) != (P, 2):
                raise ValueError(f"neutral must have shape ({P}, 2), the face at rest in the animation's layout; "
                                 f"got {np.shape(self.neutral)}")
            self.neutral = check_points(np.asarray(self.neutral)[None], "neutral")[0]

    @property
    def rest(self) -> np.ndarray:
        """The face at rest, (P, 2): :attr:`neutral`, else the first frame."""
        return self.points[0] if self.neutral is None else self.neutral

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return int(self.points.shape[0])

    @property
    def n_points(self) -> int:
        """Number of points per frame P."""
        return int(self.points.shape[1])

    @property
    def duration(self) -> float:
        """Seconds covered by the frames: ``T / fps``."""
        return self.n_frames / self.fps

    @property
    def times(self) -> np.ndarray:
        """Frame times ``t / fps``, shape (T,)."""
        return np.arange(self.n_frames) / self.fps


def _csv_header(P: int) -> str:
    return "frame,time," + ",".join(f"x{i},y{i}" for i in range(P))


def save_animation(anim: Animation, path) -> Path:
    """Writes ``anim`` as ``.npz`` or ``.csv`` (chosen by the suffix), atomically. A ``.csv``
    holds the frames only (no names, confidence or neutral).

    Parameters
    ----------
    anim : Animation
        The animation.
    path : str or os.PathLike
        Output file, ending in ``.npz`` or ``.csv``.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        Another suffix, an output folder that does not exist or is not writable, or a
        ``path`` that is a folder.
    """
    with atomic_path(path, (".npz", ".csv"), "animation file") as tmp:
        if tmp.suffix == ".npz":
            arrays = {"points": anim.points, "fps": np.float64(anim.fps)}
            if anim.names is not None:
                arrays["names"] = np.asarray(anim.names, dtype=str)
            if anim.confidence is not None:
                arrays["confidence"] = anim.confidence
            if anim.neutral is not None:
                arrays["neutral"] = anim.neutral
            with open(tmp, "wb") as fh:
                write_npz(fh, arrays)
        else:
            T, P, _ = anim.points.shape
            table = np.column_stack([np.arange(T), anim.times, anim.points.reshape(T, -1)])
            np.savetxt(tmp, table, fmt=["%d", "%.9g"] + ["%.9g"] * (2 * P), delimiter=",",
                       header=_csv_header(P), comments="")
    return Path(path)


class AnimationWriter:
    """An animation written frame block by frame block, in bounded memory: the file
    :func:`save_animation` writes for the same frames (``.npz``: ``points`` [T, P, 2] float64,
    ``fps``, optional ``names`` and ``neutral``; ``.csv``: ``frame,time,x0,y0,...``), atomically:
    the file appears when the context ends after all ``n_frames`` frames were written, and not
    at all on an error or Ctrl-C.

    >>> with AnimationWriter("long.npz", n_frames=T, n_points=68, fps=29.97) as w:  # doctest: +SKIP
    ...     for block in blocks:
    ...         w.write(block)

    Parameters
    ----------
    path : str or os.PathLike
        Output file, ending in ``.npz`` or ``.csv``.
    n_frames, n_points : int
        T and P.
    fps : float
        Frame rate.
    names : list of str, optional
        A name per point (``.npz`` only).
    neutral : array_like, shape (P, 2), optional
        The face at rest (``.npz`` only).

    Raises
    ------
    ValueError
        As :func:`save_animation`; a block of the wrong shape, non-finite points, more frames
        than ``n_frames``, or fewer when the context ends.
    """

    def __init__(self, path, n_frames: int, n_points: int, fps: float, names=None, neutral=None):
        self.path, self.n_frames, self.n_points = Path(path), int(n_frames), int(n_points)
        self.fps = _check_fps(fps)
        if self.n_frames < 1 or self.n_points < 1:
            raise ValueError(f"an animation needs frames and points, got {n_frames} frames of {n_points} points")
        self.names = None if names is None else [str(n) for n in names]
        self.neutral = None if neutral is None else check_points(np.asarray(neutral)[None], "neutral",
                                                                 self.n_points)[0]
        self._done = 0

    def __enter__(self) -> "AnimationWriter":
        self._atomic = atomic_path(self.path, (".npz", ".csv"), "animation file")
        tmp = self._atomic.__enter__()
        self._npz = tmp.suffix == ".npz"
        try:
            self._fh = open(tmp, "wb" if self._npz else "w")
            if self._npz:
                self._zip = zipfile.ZipFile(self._fh, "w", compression=zipfile.ZIP_DEFLATED)
                info = zipfile.ZipInfo("points.npy", date_time=(1980, 1, 1, 0, 0, 0))  # as write_npz
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                self._member = self._zip.open(info, "w", force_zip64=True)
                header = {"descr": np.lib.format.dtype_to_descr(np.dtype(np.float64)), "fortran_order": False,
                          "shape": (self.n_frames, self.n_points, 2)}
                try:
                    np.lib.format.write_array_header_1_0(self._member, header)
                except ValueError:  # a header too long for format 1.0, as write_array falls back
                    np.lib.format.write_array_header_2_0(self._member, header)
            else:
                self._fh.write(_csv_header(self.n_points) + "\n")
        except BaseException:
            self._atomic.__exit__(*sys.exc_info())
            raise
        return self

    def write(self, points) -> None:
        """Append frames.

        Parameters
        ----------
        points : array_like, shape (n, P, 2)
            The next ``n`` frames.
        """
        pts = check_points(points, "points", self.n_points)
        n = len(pts)
        if self._done + n > self.n_frames:
            raise ValueError(f"animation writer: {self._done + n} frames written, more than the {self.n_frames} "
                             "announced")
        if self._npz:
            self._member.write(np.ascontiguousarray(pts, dtype="<f8").tobytes("C"))
        else:
            k = np.arange(self._done, self._done + n)
            table = np.column_stack([k, k / self.fps, pts.reshape(n, -1)])
            np.savetxt(self._fh, table, fmt=["%d", "%.9g"] + ["%.9g"] * (2 * self.n_points), delimiter=",")
        self._done += n

    def __exit__(self, kind, value, tb):
        error = None
        if kind is None and self._done != self.n_frames:
            error = ValueError(f"animation writer: {self._done} frames written of the {self.n_frames} announced")
        try:
            if self._npz:
                self._member.close()
                if kind is None and error is None:
                    arrays = {"fps": np.float64(self.fps)}  # save_animation's members, in its order
                    if self.names is not None:
                        arrays["names"] = np.asarray(self.names, dtype=str)
                    if self.neutral is not None:
                        arrays["neutral"] = self.neutral
                    for name, a in arrays.items():
                        info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                        info.compress_type = zipfile.ZIP_DEFLATED
                        info.external_attr = 0o644 << 16
                        with self._zip.open(info, "w", force_zip64=True) as member:
                            np.lib.format.write_array(member, np.asanyarray(a), allow_pickle=False)
                self._zip.close()
            self._fh.close()
        except Exception as exc:  # noqa: BLE001 - reported below, after the temporary is removed
            error = error or exc
        if kind is None and error is not None:
            self._atomic.__exit__(type(error), error, error.__traceback__)  # removes the temporary
            raise error
        self._atomic.__exit__(kind, value, tb)  # publishes the file, or removes it on an error
        return False


def load_animation(path, fps: Optional[float] = None) -> Animation:
    """Reads an animation from ``.npz`` (``points``, ``fps``, optional ``names``,
    ``confidence``, ``neutral``) or ``.csv`` (``frame,time,x0,y0,...``; fps from the time column unless
    given).

    Parameters
    ----------
    path : str or os.PathLike
        An ``.npz`` or ``.csv`` animation file.
    fps : float, optional
        Frame rate; overrides the file's (default: the file's ``fps``, or for a ``.csv`` the
        inverse of the median step of its time column).

    Returns
    -------
    Animation
        The animation in the file.

    Raises
    ------
    ValueError
        No such file, an unknown suffix, an unreadable file or one without ``points``, no
        frame rate (an ``.npz`` without ``fps`` or a one-frame ``.csv``, and no ``fps``
        given), or invalid contents (see :class:`Animation`).
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"animation file {str(p)!r} does not exist")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        data = read_npz(p, "animation file")
        if "points" not in data:
            raise ValueError(f"animation file {str(p)!r} has no 'points' array (T, P, 2); found "
                             f"{sorted(data)}")
        if fps is None:
            if "fps" not in data:
                raise ValueError(f"animation file {str(p)!r} has no 'fps'; pass the frame rate")
            fps = float(np.asarray(data["fps"]).reshape(-1)[0])
        names = [str(n) for n in data["names"]] if "names" in data else None
        points = check_points(data["points"], f"points in {str(p)!r}")
        try:
            return Animation(points, fps, names, data.get("confidence"), data.get("neutral"))
        except ValueError as exc:
            raise ValueError(f"animation file {str(p)!r}: {exc}") from None
    if suffix == ".csv":
        try:
            table = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"animation file {str(p)!r} is not a 'frame,time,x0,y0,...' CSV: {exc}") from None
        if table.shape[1] < 4 or (table.shape[1] - 2) % 2:
            raise ValueError(f"animation file {str(p)!r} must have columns frame,time,x0,y0,...; got "
                             f"{table.shape[1]} columns")
        if fps is None:
            if table.shape[0] < 2:
                raise ValueError(f"animation file {str(p)!r} has one frame; pass fps explicitly")
            fps = 1.0 / float(np.median(np.diff(table[:, 1])))
        points = table[:, 2:].reshape(table.shape[0], -1, 2)
        return Animation(check_points(points, f"points in {str(p)!r}"), fps)
    raise ValueError(f"animation file {str(p)!r} has an unknown format {p.suffix!r}; use .npz or .csv")


# ------------------------------------------------------------------ animator controls (Brand §6)

def exaggerate(anim: Animation, factor: float, mean=None) -> Animation:
    """Scales every frame's deviation from the mean shape: ``mean + factor (x_t - mean)``.

    ``mean`` (P, 2) defaults to the time average of the animation; ``factor`` 1 is the identity,
    above 1 exaggerates, between 0 and 1 calms the performance. The ``neutral`` (the rest face)
    is scaled alike, so a frame at rest stays at rest and the motion from it is scaled.

    Parameters
    ----------
    anim : Animation
        The animation.
    factor : float
        Scale of the deviations (>= 0).
    mean : array_like, shape (P, 2), optional
        The shape scaled about (default the time average of ``anim.points``).

    Returns
    -------
    Animation
        A new animation (same fps, names and confidence).

    Raises
    ------
    ValueError
        ``factor`` negative or not finite, or ``mean`` not finite points of shape (P, 2).
    """
    f = float(factor)
    if not np.isfinite(f) or f < 0:
        raise ValueError(f"exaggeration factor must be a finite number >= 0, got {factor!r}")
    mu = anim.points.mean(axis=0) if mean is None else check_points(np.asarray(mean)[None], "mean",
                                                                     anim.n_points)[0]
    neutral = None if anim.neutral is None else mu + f * (anim.neutral - mu)
    return Animation(mu + f * (anim.points - mu), anim.fps, anim.names, anim.confidence, neutral)


def add_offset(anim: Animation, offset, start: float = 0.0, end: Optional[float] = None,
               fade: float = 0.0) -> Animation:
    """Adds a whole-face expression offset (e.g. a grin) over a time range.

    Parameters
    ----------
    anim : Animation
        The animation.
    offset : ndarray, shape (P, 2)
        displacement of every point at full strength.
    start, end : float
        seconds; frames with ``start <= t / fps <= end`` get the offset (``start`` default 0,
        ``end`` default: the end).
    fade : float
        seconds of linear ramp inside the range at each end (0, the default: a hard switch).

    Returns
    -------
    Animation
        A new animation (same fps, names, confidence and neutral).

    Raises
    ------
    ValueError
        ``offset`` not finite points of shape (P, 2), ``end < start`` or a bound not finite,
        or ``fade`` negative or not finite.
    """
    off = check_points(np.asarray(offset)[None], "offset", anim.n_points)[0]
    end = anim.duration if end is None else float(end)
    start, fade = float(start), float(fade)
    if not (np.isfinite(start) and np.isfinite(end)) or end < start:
        raise ValueError(f"expression time range must have start <= end, got {start}..{end} s")
    if fade < 0 or not np.isfinite(fade):
        raise ValueError(f"fade must be >= 0 seconds, got {fade}")
    t = anim.times
    w = ((t >= start - 1e-9) & (t <= end + 1e-9)).astype(np.float64)
    if fade > 0:
        w *= np.clip(np.minimum(t - start, end - t) / fade, 0.0, 1.0)
    return Animation(anim.points + w[:, None, None] * off, anim.fps, anim.names, anim.confidence, anim.neutral)


def apply_controls(anim: Animation, *, exaggeration: Optional[float] = None, offset=None, start: float = 0.0,
                   end: Optional[float] = None, fade: float = 0.0) -> Animation:
    """The animator's controls (Brand §6): :func:`exaggerate`, then :func:`add_offset`.

    The result carries the rest face its outputs move from (:attr:`Animation.rest` before the
    controls, scaled by the exaggeration, not moved by the offset, which so shows in every
    output).

    Parameters
    ----------
    anim : Animation
        the animation to control.
    exaggeration : float, optional
        the factor of :func:`exaggerate` (1: as is); None leaves the motion alone.
    offset : ndarray, shape (P, 2), optional
        a whole-face expression at full strength (e.g.
        :func:`voicepuppet.render.retargeting.expression_offset` of the rest face), added after
        the exaggeration; None adds nothing. An offset made on the exaggerated rest face, as the
        command line's ``--expression`` is, needs two calls: the exaggeration first, then the
        offset made on the result's :attr:`Animation.rest`.
    start, end : float
        seconds of the offset (``end`` default: the end).
    fade : float
        seconds of linear ramp inside the range at each end.

    Returns
    -------
    Animation
        with ``neutral`` set.

    Raises
    ------
    ValueError
        a negative or non-finite exaggeration, an offset of another shape, ``end < start`` or a
        negative fade.
    """
    if anim.neutral is None:
        anim = Animation(anim.points, anim.fps, anim.names, anim.confidence, anim.rest)
    if exaggeration is not None:
        anim = exaggerate(anim, exaggeration)
    if offset is not None:
        anim = add_offset(anim, offset, start, end, fade)
    return anim


# ------------------------------------------------------------------ a parametric 68-point face

def procedural_animation(n_frames: int = 60, fps: float = 30.0, *, width: int = 320,
                         height: int = 320, jaw=None, smile=None, seed: Optional[int] = None) -> Animation:
    """A neutral face (:func:`neutral_landmarks`) with planted mouth motion.

    ``jaw`` and ``smile`` are per-frame amounts in [0, 1] (default: a jaw opening at about
    2.5 Hz and a slow smile). Jaw 1 lowers the lower lip and chin by 0.35 inter-ocular
    distances; smile 1 pulls the lip corners out and up by 0.15. ``seed`` adds small seeded
    landmark noise (0.2 px). Returns an :class:`Animation` with ``names`` from the layout.

    Parameters
    ----------
    n_frames : int
        Number of frames T (default 60).
    fps : float
        Frame rate (default 30).
    width, height : int
        Image size in pixels (default 320 x 320).
    jaw, smile : array_like, shape (T,) or scalar, optional
        Per-frame amounts in [0, 1] (broadcast to T frames).
    seed : int, optional
        Seed of the landmark noise (default None: no noise).

    Returns
    -------
    Animation
        T frames of 68 points, ``names`` from :data:`voicepuppet.layout.NAMES`.

    Raises
    ------
    ValueError
        ``n_frames`` below 1, or ``fps`` not positive and finite.
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    t = np.arange(n_frames) / float(fps)
    jaw = (0.5 - 0.5 * np.cos(2 * np.pi * 2.5 * t) if jaw is None
           else np.broadcast_to(np.asarray(jaw, float), (n_frames,)))
    smile = (0.5 - 0.5 * np.cos(2 * np.pi * 0.5 * t) if smile is None
             else np.broadcast_to(np.asarray(smile, float), (n_frames,)))
    base = neutral_landmarks(width, height)
    iod = float(face_layout.inter_ocular_distance(base))
    pts = np.repeat(base[None], n_frames, axis=0)
    # jaw: lower lip, inner lower lip and chin move down; jaw sides follow partially
    lower = np.r_[55:60, 65:68]
    weights = np.zeros(68)
    weights[lower] = 1.0
    weights[[54, 48, 60, 64]] = 0.5
    weights[0:17] = np.sin(np.linspace(0.0, np.pi, 17)) ** 2
    pts[:, :, 1] += jaw[:, None] * weights[None, :] * 0.35 * iod
    # smile: corners out and up
    for idx, sign in (([48, 60], -1.0), ([54, 64], 1.0)):
        pts[:, idx, 0] += sign * smile[:, None] * 0.15 * iod
        pts[:, idx, 1] -= smile[:, None] * 0.15 * iod
    if seed is not None:
        pts += np.random.default_rng(seed).normal(scale=0.2, size=pts.shape)
    return Animation(pts, fps, list(face_layout.NAMES))
