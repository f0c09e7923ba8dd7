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

from fractions import Fraction

import numpy as np
from tqdm import tqdm

__all__ = ["LONG_AUDIO_S", "WINDOW_S", "MARGIN_S", "frame_period", "plan_windows", "animate_windows"]

#: Audio longer than this (seconds; 5 min) is animated in windows (``Puppet.animate(chunked=None)``).
LONG_AUDIO_S = 300.0
#: Seconds of each window that are kept (its centre).
WINDOW_S = 120.0
#: Seconds of audio on each side of a window's centre that the window also analyses.
MARGIN_S = 10.0


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
