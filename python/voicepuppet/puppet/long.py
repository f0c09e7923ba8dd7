"""Long audio in bounded memory: the puppet's analysis and synthesis in overlapping windows.

:meth:`voicepuppet.puppet.Puppet.animate` runs the C++ core (``Puppet::animate``) on the whole
utterance at once: its memory (the features, the Viterbi log densities and back-pointers T × N,
the trajectory's blocks, the landmarks) grows with the length, and Ctrl-C waits for the call to
return. Above :data:`LONG_AUDIO_S` it runs the same core on windows of :data:`WINDOW_S` seconds
with :data:`MARGIN_S` seconds of the neighbouring audio on each side, and keeps each window's
centre: the Viterbi paths of a window and of the whole utterance coalesce within the margin, and
the trajectory's dependence on frames further away decays geometrically, so the centres are the
whole-utterance solve (measured in docs/benchmarks.md, "Long audio": the largest difference over
a 30-minute recording, and the fraction of frames beyond 1e-6).

Window edges fall on frames where the analysis rate and the output rate meet (a multiple of
``p`` analysis frames when ``out_fps / fps = q / p`` in lowest terms), so a window's output frames
are the whole utterance's output frames ``[a q / p, b q / p)``.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
from tqdm import tqdm

from voicepuppet import audio as vaudio
from voicepuppet._files import check_output_path
from voicepuppet.animation import Animation, AnimationWriter, save_animation
from voicepuppet.animation import exaggerate as scale
from voicepuppet.audio import AudioWarning
from voicepuppet.audio.extract import extract_file
from voicepuppet.audio.loading import AudioReader
from voicepuppet.audio.stream import STREAMABLE
from voicepuppet.layout import N_POINTS, close_crossed_lips

__all__ = ["LONG_AUDIO_S", "WINDOW_S", "MARGIN_S", "DECODE_ROWS", "AnimatedFiles", "frame_period", "plan_windows",
           "animate_windows", "should_chunk", "long_features", "points_of", "all_points", "write_blocks", "animate_to"]

#: Audio longer than this (seconds; 5 min) is animated in windows (``Puppet.animate(chunked=None)``).
LONG_AUDIO_S = 300.0
#: Seconds of each window that are kept (its centre).
WINDOW_S = 120.0
#: Seconds of audio on each side of a window's centre that the window also analyses.
MARGIN_S = 10.0
#: Frames of landmarks decoded (and written) at a time.
DECODE_ROWS = 5_000


@dataclass
class AnimatedFiles:
    """What :meth:`Puppet.animate_to` returns: :class:`Animated` without the landmarks, which
    went to the files.

    Each parameter is kept as the attribute of the same name.

    Parameters
    ----------
    paths : list of pathlib.Path
        The files written.
    n_frames : int
        Frames T' of the animation.
    fps : float
        Its frame rate.
    neutral : ndarray (P, 2) or None
        The face at rest written with it (scaled as the motion with ``exaggerate``).
    face, states, states_fps, log_likelihood, transforms
        As in :class:`Animated`.

    Attributes
    ----------
    duration : float
        Seconds covered: ``n_frames / fps``.
    """

    paths: list
    n_frames: int
    fps: float
    neutral: np.ndarray | None
    face: np.ndarray
    states: np.ndarray
    states_fps: float
    log_likelihood: float
    transforms: list = field(default_factory=list)

    @property
    def duration(self) -> float:
        """Seconds covered: ``n_frames / fps``."""
        return self.n_frames / self.fps


def frame_period(fps: float, out_fps: float) -> tuple[int, int]:
    """The smallest whole numbers ``p``, ``q`` with ``out_fps / fps = q / p`` (to 1e-12): every
    ``p`` analysis frames are ``q`` output frames.

    Parameters
    ----------
    fps : float
        Analysis (the puppet's) frame rate.
    out_fps : float
        Output frame rate.

    Returns
    -------
    p, q : int
        Analysis frames and output frames per period ((0, 0) when the ratio is not a fraction
        with a denominator up to 10^5).
    """
    ratio = out_fps / fps
    r = Fraction(ratio).limit_denominator(100_000)
    if abs(float(r) - ratio) > 1e-12 * ratio:
        return 0, 0
    return r.denominator, r.numerator


def plan_windows(n: int, window: int, margin: int, period: int = 1) -> list[tuple[int, int, int, int]]:
    """The windows covering ``n`` analysis frames.

    Parameters
    ----------
    n : int
        Frames in all.
    window : int
        Frames kept per window (rounded up to a multiple of ``period``).
    margin : int
        Frames analysed on each side of the kept ones (rounded up to a multiple of ``period``).
    period : int
        Window edges fall on multiples of it (default 1).

    Returns
    -------
    list of (lo, a, b, hi)
        Per window, the frames analysed ``[lo, hi)`` and kept ``[a, b)``; the kept ones tile
        ``[0, n)``.
    """
    up = lambda v: max(period, -(-int(v) // period) * period)  # noqa: E731
    window, margin = up(window), up(margin) if margin > 0 else 0
    out = []
    a = 0
    while a < n:
        b = min(n, a + window)
        if n - b < window // 4:  # no sliver of a window at the end
            b = n
        out.append((max(0, a - margin), a, b, min(n, b + margin)))
        a = b
    return out


def animate_windows(core, features: np.ndarray, fps: float, out_fps: float, posterior: bool, lam: float, *,
                    window_s: float | None = None, margin_s: float | None = None, progress: bool = False) -> dict:
    """``core.animate`` on overlapping windows of ``features``, the centres joined.

    Parameters
    ----------
    core : voicepuppet._core.Puppet
        The puppet's C++ core.
    features : ndarray, shape (T, A)
        Raw features at ``fps``.
    fps, out_fps : float
        The puppet's rate and the output rate.
    posterior : bool
        Posterior-weighted synthesis.
    lam : float
        The guide weight as the core takes it (negative: the file's).
    window_s, margin_s : float
        Seconds kept per window and analysed on each side (default :data:`WINDOW_S`,
        :data:`MARGIN_S` as they are when called).
    progress : bool
        Show a progress bar over the windows.

    Returns
    -------
    dict
        ``face`` (T', K) at ``out_fps``, ``states`` (T, parts) and ``windows`` (the plan,
        :func:`plan_windows`). Ctrl-C is answered between windows.

    Raises
    ------
    ValueError
        An output rate that meets the analysis rate only every more than 10^5 frames (use the
        whole-utterance path), and what ``core.animate`` raises.
    """
    window_s = WINDOW_S if window_s is None else window_s
    margin_s = MARGIN_S if margin_s is None else margin_s
    T = len(features)
    p, q = (1, 1) if out_fps == fps else frame_period(fps, out_fps)
    if p == 0:
        raise ValueError(f"the output rate {out_fps:g} fps and the puppet's {fps:g} fps have no common period of "
                         "at most 10^5 frames, so the animation cannot be cut into windows; animate it whole "
                         "(chunked=False) or choose another --fps")
    plan = plan_windows(T, int(round(window_s * fps)), int(round(margin_s * fps)), p)
    faces, states = [], []
    for lo, a, b, hi in tqdm(plan, desc="animate", unit="window", disable=not progress or len(plan) < 2,
                             leave=False):
        r = core.animate(np.ascontiguousarray(features[lo:hi]), out_fps, posterior, "none", 30.0, 1, lam)
        if p == q:
            i, j = a - lo, b - lo
        else:  # the window's output frame k is the whole's k + lo q / p
            i, j = (a - lo) // p * q, len(r["face"]) if b == T else (b - lo) // p * q
        faces.append(r["face"][i:j])
        states.append(r["states"][a - lo:b - lo])
    return {"face": np.vstack(faces), "states": np.vstack(states), "windows": plan}


def should_chunk(puppet, chunked, audio, features, states, adapt) -> bool:
    """Whether ``Puppet.animate`` works in windows.

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    chunked : bool or None
        ``animate``'s ``chunked``: None decides by the length (:data:`LONG_AUDIO_S`).
    audio, features, states, adapt
        As given to ``animate``.

    Returns
    -------
    bool
        Whether to animate in windows.

    Raises
    ------
    ValueError
        ``chunked`` not None or a bool, or True with ``states`` or ``adapt``.
    """
    if chunked is not None and not isinstance(chunked, (bool, np.bool_)):
        raise ValueError(f"chunked must be None, True or False, got {chunked!r}")
    if states is not None or adapt is not None:
        if chunked:
            raise ValueError("chunked animation decodes the audio window by window: given states and adapt "
                             "(which fits one transform to all of the audio) are whole-utterance only; drop "
                             "chunked=True")
        return False
    if chunked is not None:
        return bool(chunked)
    if features is not None:
        return len(features) / puppet.fps > LONG_AUDIO_S
    if isinstance(audio, vaudio.Audio):
        return audio.duration > LONG_AUDIO_S
    duration = AudioReader(audio).duration
    return duration is None or duration > LONG_AUDIO_S


def long_features(puppet, audio, progress: bool) -> np.ndarray:
    """Raw features of long audio, read from a file in blocks when the puppet's feature set
    streams (else loaded whole, with a warning).

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    audio : path or voicepuppet.audio.Audio
        The audio.
    progress : bool
        Show a progress bar.

    Returns
    -------
    ndarray, shape (T, A)
        The raw features at the puppet's rate.
    """
    streams = all(f in STREAMABLE for f in puppet.feature_set.features)
    if isinstance(audio, vaudio.Audio) or not streams:
        if not streams and not isinstance(audio, vaudio.Audio):
            warnings.warn(f"this puppet's features {', '.join(f for f in puppet.feature_set.features if f not in STREAMABLE)} "
                          "need the whole recording at once: the audio is loaded whole (its memory grows with "
                          "its length: about 0.5 GB per hour at 16 kHz)", AudioWarning, stacklevel=4)
        return puppet.extract(audio, progress=progress, stacklevel=5).values
    reader = AudioReader(audio)
    puppet.check_band(reader.source_rate, f"audio {reader.path!r}", stacklevel=4)
    return extract_file(audio, fps=puppet.fps, features=puppet.feature_set, progress=progress).values


def write_blocks(puppet, paths, face: np.ndarray, widened: bool, fps: float, neutral, factor) -> np.ndarray | None:
    """The landmarks of ``face`` written to ``paths`` :data:`DECODE_ROWS` frames at a time
    (``Puppet.animate_to`` when chunked), scaled about their mean shape by ``factor`` if given.

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    paths : list of pathlib.Path
        ``.npz`` or ``.csv`` files.
    face : ndarray, shape (T', K)
        Face coordinates at ``fps``.
    widened : bool
        Whether ``face`` was widened (its landmarks decoded in Python, lips closed).
    fps : float
        Frame rate.
    neutral : ndarray (P, 2) or None
        The face at rest.
    factor : float or None
        :func:`voicepuppet.animation.exaggerate`'s factor.

    Returns
    -------
    ndarray (P, 2) or None
        The face at rest as written (scaled with the motion).
    """
    def blocks():
        for i in range(0, len(face), DECODE_ROWS):
            yield points_of(puppet, face[i:i + DECODE_ROWS], widened)

    mean = None
    if factor is not None:  # exaggerate's mean shape, over all frames
        mean = sum(b.sum(axis=0) for b in blocks()) / len(face)
        if neutral is not None:
            neutral = scale(Animation(neutral[None], 30.0, neutral=neutral), factor, mean).neutral
    with contextlib.ExitStack() as stack:
        writers = [stack.enter_context(AnimationWriter(p, len(face), puppet.n_points, fps, neutral=neutral))
                   for p in paths]
        for b in blocks():
            if mean is not None:
                b = scale(Animation(b, fps), factor, mean).points
            for w in writers:
                w.write(b)
    return neutral


def points_of(puppet, face: np.ndarray, widened: bool) -> np.ndarray:
    """Landmarks of face coordinates as ``Puppet.animate`` makes them: C++ ``to_points``, or
    for a widened trajectory the face space's decoding with crossed lips closed.

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    face : ndarray, shape (T, K)
        Face coordinates.
    widened : bool
        Whether they were widened (``widen_motion``).

    Returns
    -------
    ndarray, shape (T, P, 2)
        The landmarks.
    """
    if not widened:
        return puppet._core.to_points(np.ascontiguousarray(face)).reshape(len(face), -1, 2)
    pts = puppet.face_space.decode(face)
    return close_crossed_lips(pts) if pts.shape[1] == N_POINTS else pts


def all_points(puppet, r: dict) -> np.ndarray:
    """The landmarks of an animation's result: its own, or (chunked) decoded
    :data:`DECODE_ROWS` frames at a time into one array.

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    r : dict
        ``Puppet._animate``'s result (its ``points`` are taken out).

    Returns
    -------
    ndarray, shape (T', P, 2)
        The landmarks.
    """
    pts = r.pop("points")
    if pts is None:
        face = r["face"]
        pts = np.empty((len(face), puppet.n_points, 2))
        for i in range(0, len(face), DECODE_ROWS):
            pts[i:i + DECODE_ROWS] = points_of(puppet, face[i:i + DECODE_ROWS], r["widened"])
    return pts


def animate_to(puppet, path, audio=None, *, features=None, fps=None, posterior=False, adapt=None, adapt_tau=30.0,
               adapt_iter=1, guide_weight=None, full_motion=True, exaggerate=None, progress=False,
               chunked=None) -> AnimatedFiles:
    """``Puppet.animate_to``: the animation of ``audio`` written to ``path`` (one or a list of
    ``.npz`` / ``.csv`` files). Whole-utterance: :func:`voicepuppet.animation.save_animation` of
    ``Puppet.animate``'s animation (scaled by :func:`voicepuppet.animation.exaggerate`);
    chunked: the same files written :data:`DECODE_ROWS` frames at a time (:func:`write_blocks`),
    the landmarks never held.

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    path : str or os.PathLike, or a list of them
        The files; checked before any work.
    audio, features, fps, posterior, adapt, adapt_tau, adapt_iter, guide_weight, full_motion, progress, chunked
        As for ``Puppet.animate``.
    exaggerate : float, optional
        Scale the motion about the animation's mean shape (default: as is).

    Returns
    -------
    AnimatedFiles
        The files, the frame count and rate, face coordinates, states and log-likelihood.
    """
    paths = [path] if isinstance(path, (str, os.PathLike)) else list(path)
    paths = [check_output_path(p, (".npz", ".csv"), "animation file") for p in paths]
    if exaggerate is not None:
        scale(Animation(np.zeros((1, 1, 2)), 30.0), exaggerate)  # the factor checked before the work
    r = puppet._animate(audio, fps, posterior, features, None, None, adapt, adapt_tau, adapt_iter, guide_weight,
                        full_motion, progress, chunked)
    face, neutral = r["face"], puppet.rest_face()
    if r["points"] is not None:  # whole-utterance: as animate + save_animation
        anim = Animation(r["points"], r["out_fps"], neutral=neutral)
        if exaggerate is not None:
            anim = scale(anim, exaggerate)
        for p in paths:
            save_animation(anim, p)
        neutral = anim.neutral
    else:
        neutral = write_blocks(puppet, paths, face, r["widened"], r["out_fps"], neutral, exaggerate)
    return AnimatedFiles([Path(p) for p in paths], len(face), r["out_fps"], neutral, face, r["states"],
                         r["states_fps"], r["log_likelihood"], r["transforms"])
