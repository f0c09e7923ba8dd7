"""The audio-video offset of a recording: how late its sound runs against its face.

Real recordings are often out of sync by a few frames (a separately stored sound track muxed
back, a capture pipeline's buffering). A puppet trained on them learns each face a few frames
away from the sound that made it. :func:`estimate_av_offset` finds the offset as the lag that
best correlates the mouth's opening with the loudness of the speech: the mouth opens where the
voice is loud and closes in the pauses, so the two envelopes line up at the true offset.

- Opening: the gap between the inner lips' middle points over the inter-ocular distance, per
  frame (68-point layout, :data:`voicepuppet.layout.LIP_GAP`).
- Loudness: the frame-centred log energy of the speech in 40 ms windows (dB), its floor raised
  to 45 dB under its 95th percentile, so that room noise in the pauses does not count.
- Offset: the lag (within +-:data:`MAX_OFFSET_S`) of the highest Pearson correlation of the two
  over the frames both cover, refined between frames by a parabola through the peak and its
  neighbours. Positive: the sound is late.

An estimate is *reliable* when the recording is at least :data:`MIN_SECONDS` long (a few
syllables give chance peaks), the peak lies inside the search range (not at its edge) and its
correlation reaches :data:`MIN_CORRELATION`; training corrects only reliable offsets of a frame
or more (:func:`voicepuppet.puppet.sources.training_sequences`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from voicepuppet.audio.loading import Audio
from voicepuppet.layout import LIP_GAP, N_POINTS, inter_ocular_distance

__all__ = ["MAX_OFFSET_S", "MIN_SECONDS", "MIN_CORRELATION", "AvOffset", "mouth_opening", "speech_loudness",
           "estimate_av_offset", "shift_audio"]

#: The largest offset looked for (s), either way.
MAX_OFFSET_S = 0.3
#: Shorter recordings give no reliable estimate.
MIN_SECONDS = 5.0
#: The least correlation of opening and loudness at the offset for a reliable estimate.
MIN_CORRELATION = 0.15
#: Length of the loudness windows (s) and how far under its 95th percentile its floor lies (dB).
LOUDNESS_WINDOW_S = 0.04
LOUDNESS_RANGE_DB = 45.0


@dataclass(frozen=True)
class AvOffset:
    """An estimated audio-video offset.

    Parameters
    ----------
    seconds : float
        How late the sound runs against the face (s; negative: early).
    correlation : float
        Pearson correlation of mouth opening and speech loudness at that offset.
    correlation_in_sync : float
        The same with no offset.
    reliable : bool
        Whether the estimate may be acted on.
    reason : str
        Why it is not reliable (empty when it is).
    """

    seconds: float
    correlation: float
    correlation_in_sync: float
    reliable: bool
    reason: str = ""

    def describe(self, fps: float) -> str:
        """A sentence for the user, e.g. ``"the sound is 167 ms (5.0 frames) late"``.

        Parameters
        ----------
        fps : float
            The video's frame rate, to give the offset in frames too.

        Returns
        -------
        str
        """
        ms, frames = 1000.0 * self.seconds, self.seconds * fps
        where = "in sync" if abs(frames) < 1.0 else (
            f"the sound is {abs(ms):.0f} ms ({abs(frames):.1f} frames) {'late' if ms > 0 else 'early'}")
        return (f"{where} (opening and loudness correlate {self.correlation:.2f} there, "
                f"{self.correlation_in_sync:.2f} in sync)")


def mouth_opening(points) -> np.ndarray:
    """The inner lips' gap over the inter-ocular distance, per frame (NaN where a point is).

    Parameters
    ----------
    points : array_like, shape (T, 68, 2)
        Landmarks in the 68-point layout.

    Returns
    -------
    ndarray, shape (T,)

    Raises
    ------
    ValueError
        The landmarks are not of the 68-point layout.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (N_POINTS, 2):
        raise ValueError(f"the mouth's opening needs 68-point landmarks of shape (T, 68, 2), got {p.shape}")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.linalg.norm(p[:, LIP_GAP[0]] - p[:, LIP_GAP[1]], axis=1) / inter_ocular_distance(p)


def speech_loudness(audio: Audio, fps: float, n_frames: int) -> np.ndarray:
    """The speech's log energy (dB) in windows centred on each video frame, floor raised.

    Parameters
    ----------
    audio : voicepuppet.audio.Audio
        The recording's sound, starting at frame 0.
    fps : float
        The video's frame rate.
    n_frames : int
        Frames to give (past the end of the sound: the floor).

    Returns
    -------
    ndarray, shape (n_frames,)
    """
    x, rate = np.asarray(audio.samples, dtype=np.float64), int(audio.rate)
    half = max(int(round(0.5 * LOUDNESS_WINDOW_S * rate)), 1)
    c = np.cumsum(np.concatenate([[0.0], x * x]))
    centre = np.round(np.arange(n_frames) / fps * rate).astype(np.int64)
    lo, hi = np.clip(centre - half, 0, len(x)), np.clip(centre + half, 0, len(x))
    n = np.maximum(hi - lo, 1)
    db = 10.0 * np.log10((c[hi] - c[lo]) / n + 1e-12)
    db[hi <= lo] = -np.inf
    top = np.percentile(db[np.isfinite(db)], 95) if np.isfinite(db).any() else 0.0
    return np.maximum(db, top - LOUDNESS_RANGE_DB)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 10:
        return np.nan
    a, b = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
    d = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / d) if d > 0 else np.nan


def estimate_av_offset(points, audio: Audio, fps: float, *, max_offset_s: float = MAX_OFFSET_S) -> AvOffset:
    """How late a recording's sound runs against its face (see the module's description).

    Parameters
    ----------
    points : array_like, shape (T, 68, 2)
        The face's landmarks per video frame (NaN where lost).
    audio : voicepuppet.audio.Audio
        Its sound, starting with frame 0.
    fps : float
        The video's frame rate.
    max_offset_s : float
        The largest offset looked for, either way (s).

    Returns
    -------
    AvOffset

    Raises
    ------
    ValueError
        The landmarks are not of the 68-point layout, or ``fps`` or ``max_offset_s`` is not
        positive.
    """
    if not (fps > 0 and np.isfinite(fps)):
        raise ValueError(f"fps must be positive, got {fps!r}")
    if not (max_offset_s > 0 and np.isfinite(max_offset_s)):
        raise ValueError(f"max_offset_s must be positive, got {max_offset_s!r}")
    opening = mouth_opening(points)
    T = len(opening)
    loud = speech_loudness(audio, fps, T)
    K = max(int(np.ceil(max_offset_s * fps)), 1)
    lags = np.arange(-K, K + 1)
    # r(k): the face at frame t against the sound at frame t + k (k > 0: the sound is late)
    r = np.array([_correlation(opening[max(0, -k):T - max(0, k)], loud[max(0, k):T - max(0, -k)])
                  for k in lags])
    in_sync = float(r[K]) if np.isfinite(r[K]) else 0.0
    if not np.isfinite(r).any():
        return AvOffset(0.0, 0.0, in_sync, False, "too few frames with a face and sound to compare")
    i = int(np.nanargmax(r))
    shift = 0.0
    if 0 < i < len(r) - 1 and np.isfinite(r[i - 1]) and np.isfinite(r[i + 1]):
        den = r[i - 1] - 2 * r[i] + r[i + 1]
        if den < 0:
            shift = float(np.clip(0.5 * (r[i - 1] - r[i + 1]) / den, -0.5, 0.5))
    seconds, best = (lags[i] + shift) / fps, float(r[i])
    reason = ""
    if T / fps < MIN_SECONDS:
        reason = f"the recording is {T / fps:.1f} s long, under {MIN_SECONDS:g} s"
    elif i in (0, len(r) - 1):
        reason = f"the best match lies at the edge of the +-{1000 * max_offset_s:.0f} ms searched"
    elif best < MIN_CORRELATION:
        reason = f"the mouth's opening follows the loudness too weakly (correlation {best:.2f})"
    return AvOffset(float(seconds), best, in_sync, not reason, reason)


def shift_audio(audio: Audio, seconds: float) -> Audio:
    """The sound moved ``seconds`` earlier, so that a sound that ran that late is in sync.

    Positive ``seconds`` drops the sound's first ``seconds`` and pads its end with silence;
    negative prepends silence and drops as much from its end. The length stays the same.

    Parameters
    ----------
    audio : voicepuppet.audio.Audio
    seconds : float
        How late the sound ran (s).

    Returns
    -------
    voicepuppet.audio.Audio
    """
    x = np.asarray(audio.samples)
    n = int(round(float(seconds) * audio.rate))
    if n == 0 or not len(x):
        return audio
    out = np.zeros_like(x)
    if abs(n) < len(x):
        if n > 0:
            out[:len(x) - n] = x[n:]
        else:
            out[-n:] = x[:len(x) + n]
    return replace(audio, samples=out)
