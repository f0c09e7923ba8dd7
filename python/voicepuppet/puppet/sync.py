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

Recordings too short to be judged alone (sentence cuts of a few seconds) are judged together
when they come from one source and so share its offset (:func:`estimate_shared_av_offset`): the
correlation at each lag pools every recording's products of opening and loudness (each about
its own means), as if they were one long recording, and the same rules decide whether it is
reliable.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from voicepuppet.audio.loading import Audio
from voicepuppet.layout import LIP_GAP, N_POINTS, inter_ocular_distance

__all__ = ["MAX_OFFSET_S", "MIN_SECONDS", "MIN_CORRELATION", "AvOffset", "mouth_opening", "speech_loudness",
           "estimate_av_offset", "estimate_shared_av_offset", "shift_audio"]

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


def speech_loudness(audio: Audio, fps: float, n_frames: int, *, shift_s: float = 0.0) -> np.ndarray:
    """The speech's log energy (dB) in windows centred on each video frame, floor raised.

    Parameters
    ----------
    audio : voicepuppet.audio.Audio
        The recording's sound, starting at frame 0.
    fps : float
        The video's frame rate.
    n_frames : int
        Frames to give (past the end of the sound: the floor).
    shift_s : float
        Centre the windows this much later than the frames (s; default 0).

    Returns
    -------
    ndarray, shape (n_frames,)
    """
    x, rate = np.asarray(audio.samples, dtype=np.float64), int(audio.rate)
    half = max(int(round(0.5 * LOUDNESS_WINDOW_S * rate)), 1)
    c = np.cumsum(np.concatenate([[0.0], x * x]))
    centre = np.round((np.arange(n_frames) / fps + shift_s) * rate).astype(np.int64)
    lo, hi = np.clip(centre - half, 0, len(x)), np.clip(centre + half, 0, len(x))
    n = np.maximum(hi - lo, 1)
    db = 10.0 * np.log10((c[hi] - c[lo]) / n + 1e-12)
    db[hi <= lo] = -np.inf
    top = np.percentile(db[np.isfinite(db)], 95) if np.isfinite(db).any() else 0.0
    return np.maximum(db, top - LOUDNESS_RANGE_DB)


def _check_rate(fps, name: str = "fps") -> None:
    if not (fps > 0 and np.isfinite(fps)):
        raise ValueError(f"{name} must be positive, got {fps!r}")


def _lag_sums(points, audio: Audio, fps: float, lags_s: np.ndarray) -> np.ndarray:
    """Per lag s: the sums (Σxy, Σxx, Σyy) of the opening x at frame t and the loudness y at
    t/fps + s, each about its mean, over the frames whose shifted time lies on the recording."""
    opening = mouth_opening(points)
    T = len(opening)
    t = np.arange(T)
    sums = np.zeros((len(lags_s), 3))
    for j, s in enumerate(lags_s):
        loud = speech_loudness(audio, fps, T, shift_s=float(s))
        moved = t + s * fps
        ok = np.isfinite(opening) & np.isfinite(loud) & (moved > -0.5) & (moved < T - 0.5)
        if ok.sum() < 10:
            continue
        a, b = opening[ok] - opening[ok].mean(), loud[ok] - loud[ok].mean()
        sums[j] = (a * b).sum(), (a * a).sum(), (b * b).sum()
    return sums


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
    return estimate_shared_av_offset([(points, audio, fps)], max_offset_s=max_offset_s)


def estimate_shared_av_offset(recordings, *, max_offset_s: float = MAX_OFFSET_S) -> AvOffset:
    """The one offset of recordings from one source, judged together (see the module's
    description): lags on the first recording's frame grid, correlation pooled over all.

    Parameters
    ----------
    recordings : sequence of (points, audio, fps)
        Each recording's landmarks (T_i, 68, 2), its sound (:class:`voicepuppet.audio.Audio`,
        starting with frame 0) and its frame rate.
    max_offset_s : float
        The largest offset looked for, either way (s).

    Returns
    -------
    AvOffset
        The offset, reliable by the rules of :func:`estimate_av_offset` applied to the pooled
        correlation and the recordings' total duration.

    Raises
    ------
    ValueError
        No recordings, landmarks not of the 68-point layout, or an ``fps`` or ``max_offset_s``
        that is not positive.
    """
    recordings = list(recordings)
    if not recordings:
        raise ValueError("no recordings to estimate an audio-video offset from")
    _check_rate(max_offset_s, "max_offset_s")
    for _, _, fps in recordings:
        _check_rate(fps)
    fps0 = float(recordings[0][2])
    K = max(int(np.ceil(max_offset_s * fps0)), 1)
    lags = np.arange(-K, K + 1)
    # r(k): the face at frame t against the sound at time t + k frames (k > 0: the sound is late)
    sums = sum(_lag_sums(p, a, float(f), lags / fps0) for p, a, f in recordings)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(sums[:, 1] * sums[:, 2] > 0, sums[:, 0] / np.sqrt(sums[:, 1] * sums[:, 2]), np.nan)
    in_sync = float(r[K]) if np.isfinite(r[K]) else 0.0
    if not np.isfinite(r).any():
        return AvOffset(0.0, 0.0, in_sync, False, "too few frames with a face and sound to compare")
    i = int(np.nanargmax(r))
    shift = 0.0
    if 0 < i < len(r) - 1 and np.isfinite(r[i - 1]) and np.isfinite(r[i + 1]):
        den = r[i - 1] - 2 * r[i] + r[i + 1]
        if den < 0:
            shift = float(np.clip(0.5 * (r[i - 1] - r[i + 1]) / den, -0.5, 0.5))
    seconds, best = (lags[i] + shift) / fps0, float(r[i])
    duration = sum(len(p) / float(f) for p, _, f in recordings)
    what = "the recording is" if len(recordings) == 1 else f"the {len(recordings)} recordings are"
    reason = ""
    if duration < MIN_SECONDS:
        reason = f"{what} {duration:.1f} s long, under {MIN_SECONDS:g} s"
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
