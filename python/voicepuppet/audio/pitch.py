"""F0 and voicing: the autocorrelation method of Boersma (1993), as in Praat's "To Pitch (ac)".

Per video frame: a Hann window of ``periods / floor`` seconds centred on the frame time, its
normalised autocorrelation divided by the window's own autocorrelation (which undoes the taper),
peaks between ``1 / ceiling`` and ``1 / floor`` refined by parabolic interpolation, strengths
``r - octave_cost * log2(floor * lag)``; an unvoiced candidate with Praat's strength
``voicing_threshold + max(0, 2 - (local_peak / global_peak) / (silence_threshold / (1 +
voicing_threshold)))``; then the cheapest path (Viterbi) with octave-jump and voiced/unvoiced
transition costs, scaled by ``0.01 / frame_step`` as Praat does.
"""

from __future__ import annotations

import math

import numpy as np

from voicepuppet.audio.framing import frame_centres, hann, iter_frames
from voicepuppet.audio.loading import resample

#: Analysis rate for F0 (Hz): ample for a 600 Hz ceiling, half the samples of 16 kHz.
PITCH_RATE = 8000


def voicing_probability(best_voiced: np.ndarray, unvoiced: np.ndarray, scale: float = 0.1
                        ) -> np.ndarray:
    """Soft voicing score in (0, 1): a logistic of how much the best voiced candidate beats the
    unvoiced one (0.5 where Praat's frame-wise decision would flip).

    Parameters
    ----------
    best_voiced : ndarray, shape (T,)
        Strength of each frame's best voiced candidate.
    unvoiced : ndarray, shape (T,)
        Strength of each frame's unvoiced candidate.
    scale : float
        Strength difference that moves the logistic by one unit (default 0.1).

    Returns
    -------
    ndarray, shape (T,)
        ``1 / (1 + exp(-(best_voiced - unvoiced) / scale))`` (argument clipped to +/-50).
    """
    z = np.clip((best_voiced - unvoiced) / scale, -50.0, 50.0)
    return 1.0 / (1.0 + np.exp(-z))


def pitch_frames(x: np.ndarray, rate: float, fps: float, n_out: int, *, floor: float = 75.0,
                 ceiling: float = 600.0, periods: float = 3.0, voicing_threshold: float = 0.45,
                 silence_threshold: float = 0.03, octave_cost: float = 0.01,
                 octave_jump_cost: float = 0.35, voiced_unvoiced_cost: float = 0.14,
                 n_candidates: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """F0 (Hz, NaN where unvoiced) and voicing probability at video frame times.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Mono samples.
    rate : float
        Sample rate of ``x`` in Hz (resampled to ``PITCH_RATE``, 8 kHz, if higher).
    fps : float
        Output frame rate; frame ``k`` is centred at ``k / fps``.
    n_out : int
        Number of output frames.
    floor, ceiling : float
        Pitch search range in Hz (Praat's defaults 75 and 600).
    periods : float
        Window length in periods of ``floor`` (default 3).
    voicing_threshold : float
        Praat's voicing threshold (default 0.45): the base strength of the unvoiced candidate.
    silence_threshold : float
        Praat's silence threshold (default 0.03), relative to the global peak amplitude.
    octave_cost : float
        Per-octave bonus for higher-frequency candidates (default 0.01).
    octave_jump_cost : float
        Cost of an octave jump between voiced frames (default 0.35).
    voiced_unvoiced_cost : float
        Cost of a voiced/unvoiced transition (default 0.14).
    n_candidates : int
        Voiced candidates kept per frame (default 4).

    Returns
    -------
    f0 : ndarray, shape (n_out,)
        Fundamental frequency in Hz on voiced frames, NaN on unvoiced ones.
    voicing : ndarray, shape (n_out,)
        Voicing probability in [0, 1] (see ``voicing_probability``).

    Raises
    ------
    ValueError
        Not ``0 < floor < ceiling``, or a ``ceiling`` not below half the analysis rate
        (``PITCH_RATE``, 8 kHz, or ``rate`` if lower).
    """
    if not 0 < floor < ceiling:
        raise ValueError(f"pitch: need 0 < floor < ceiling, got floor={floor}, ceiling={ceiling}")
    fs = PITCH_RATE if rate >= PITCH_RATE else int(rate)
    if ceiling >= fs / 2:
        raise ValueError(f"pitch: ceiling {ceiling} Hz must be below half the analysis rate "
                         f"{fs / 2} Hz")
    y = resample(np.asarray(x, dtype=np.float64), int(rate), fs) if fs != rate else \
        np.asarray(x, dtype=np.float64)
    global_peak = float(np.max(np.abs(y))) if y.size else 0.0
    length = int(round(periods / floor * fs))
    length += length % 2
    min_lag = max(2, int(math.floor(fs / ceiling)))
    max_lag = min(int(math.ceil(fs / floor)), length // 2)
    n_fft = 1 << int(math.ceil(math.log2(length + max_lag + 2)))
    w = hann(length)
    wspec = np.fft.rfft(w, n_fft)
    rw = np.fft.irfft(np.abs(wspec) ** 2, n_fft)[:max_lag + 2]
    rw = rw / rw[0]
    centres = frame_centres(n_out, fs, fps)

    K = n_candidates
    cand_f = np.full((n_out, K), np.nan)
    cand_s = np.full((n_out, K), -np.inf)
    unv = np.empty(n_out)
    lags = np.arange(max_lag + 2)
    for sl, frames in iter_frames(y, centres, length):
        local_peak = np.max(np.abs(frames - frames.mean(axis=1, keepdims=True)), axis=1)
        frames = (frames - frames.mean(axis=1, keepdims=True)) * w
        spec = np.fft.rfft(frames, n_fft, axis=1)
        ra = np.fft.irfft(spec.real ** 2 + spec.imag ** 2, n_fft, axis=1)[:, :max_lag + 2]
        r0 = ra[:, :1]
        silent = r0[:, 0] <= 1e-20
        r = np.where(silent[:, None], 0.0, ra / np.where(silent[:, None], 1.0, r0)) / rw
        mid = r[:, min_lag:max_lag + 1]
        left = r[:, min_lag - 1:max_lag]
        right = r[:, min_lag + 1:max_lag + 2]
        is_peak = (mid > left) & (mid >= right) & (mid > 0)
        denom = left - 2.0 * mid + right
        delta = np.where(denom < 0, 0.5 * (left - right) / np.where(denom < 0, denom, -1.0), 0.0)
        delta = np.clip(delta, -0.5, 0.5)
        peak = np.minimum(mid - 0.25 * (left - right) * delta, 1.0)
        lag = lags[min_lag:max_lag + 1][None, :] + delta
        strength = np.where(is_peak, peak - octave_cost * np.log2(floor * lag / fs), -np.inf)
        kk = min(K, strength.shape[1])
        top = np.argsort(-strength, axis=1)[:, :kk]
        s_top = np.take_along_axis(strength, top, axis=1)
        f_top = fs / np.take_along_axis(lag, top, axis=1)
        cand_s[sl, :kk] = s_top
        cand_f[sl, :kk] = np.where(np.isfinite(s_top), f_top, np.nan)
        ratio = local_peak / global_peak if global_peak > 0 else np.zeros(local_peak.shape[0])
        unv[sl] = voicing_threshold + np.maximum(
            0.0, 2.0 - ratio / (silence_threshold / (1.0 + voicing_threshold)))

    best_voiced = np.max(cand_s, axis=1)
    voicing = voicing_probability(np.where(np.isfinite(best_voiced), best_voiced, -1e3), unv)

    # Viterbi: states 0..K-1 voiced candidates, K unvoiced; maximise strength minus costs.
    step_corr = 0.01 * fps
    S = K + 1
    gain = np.concatenate([np.where(np.isfinite(cand_s), cand_s, -1e6), unv[:, None]], axis=1)
    logf = np.log2(np.where(np.isfinite(cand_f), cand_f, 1.0))
    back = np.zeros((n_out, S), dtype=np.int64)
    score = gain[0].copy()
    voiced_mask = np.zeros(S, dtype=bool)
    voiced_mask[:K] = True
    vu = voiced_unvoiced_cost * step_corr * (voiced_mask[:, None] != voiced_mask[None, :])
    block = 4096
    for b0 in range(1, n_out, block):
        b1 = min(n_out, b0 + block)
        jump = octave_jump_cost * step_corr * np.abs(
            logf[b0 - 1:b1 - 1, :, None] - logf[b0:b1, None, :])  # (B, K, K)
        cost = np.broadcast_to(vu, (b1 - b0, S, S)).copy()
        cost[:, :K, :K] += jump
        for t in range(b0, b1):
            tot = score[:, None] - cost[t - b0]
            arg = np.argmax(tot, axis=0)
            back[t] = arg
            score = tot[arg, np.arange(S)] + gain[t]
    path = np.empty(n_out, dtype=np.int64)
    path[-1] = int(np.argmax(score))
    for t in range(n_out - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    f0 = np.full(n_out, np.nan)
    voiced = path < K
    idx = np.nonzero(voiced)[0]
    f0[idx] = cand_f[idx, path[idx]]
    f0[~np.isfinite(f0)] = np.nan
    return f0, voicing


def fill_unvoiced(f0: np.ndarray, default: float = 150.0) -> np.ndarray:
    """Interpolate ``log f0`` through unvoiced (NaN) frames, holding the ends; ``default`` Hz
    everywhere if no frame is voiced. Makes F0 a finite, continuous feature (pair it with the
    voicing probability).

    Parameters
    ----------
    f0 : array_like, shape (T,)
        F0 in Hz, NaN (or <= 0) on unvoiced frames.
    default : float
        F0 (Hz) returned everywhere when no frame is voiced (default 150).

    Returns
    -------
    ndarray, shape (T,)
        Finite, positive F0 in Hz.
    """
    f0 = np.asarray(f0, dtype=np.float64)
    good = np.isfinite(f0) & (f0 > 0)
    if not np.any(good):
        return np.full(f0.shape, float(default))
    t = np.arange(f0.shape[0])
    return np.exp(np.interp(t, t[good], np.log(f0[good])))
