"""Linear prediction: autocorrelation method, Levinson-Durbin, LPC cepstra and formants.

These numpy functions define the LPC and formant features; the front end computes them in C++
(``cpp/include/voicepuppet/audio_features.hpp``, through ``stream.StreamingFeatures``), and
``lpc_frames`` / ``formant_frames`` are its reference (``extract.reference_extract``, the
test oracle) and the benchmark peers' counterparts.

Conventions: the inverse filter is ``A(z) = 1 + a_1 z^-1 + ... + a_p z^-p`` (the coefficient
vector starts with 1, as ``librosa.lpc`` returns it) and the model spectrum is ``err / |A|^2``
with ``err`` the prediction-error power.

The autocorrelation method (windowed frame, Toeplitz normal equations solved by Levinson-Durbin)
always gives a stable, minimum-phase filter; ``librosa.lpc`` uses Burg's method instead, which
minimises forward and backward errors on the unwindowed samples. The two agree closely on long
stationary frames and differ on short windowed speech frames by the window's smoothing; see
docs/audio.md.
"""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np

from voicepuppet.audio.framing import fast_len, frame_centres, hamming, iter_frames
from voicepuppet.audio.loading import resample

#: Relative white-noise correction added to lag 0 (-90 dB): keeps Levinson-Durbin well posed.
WHITE_NOISE_CORRECTION = 1e-9
#: Absolute floor on lag 0 (silence): a flat model spectrum at -100 dB full scale.
ENERGY_FLOOR = 1e-10


def levinson(r: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Levinson-Durbin recursion on many autocorrelation sequences at once.

    Parameters
    ----------
    r : ndarray, shape (T, >= order + 1)
        Autocorrelations ``r[:, 0 .. order]`` (lag 0 first); one row per frame.
    order : int
        Prediction order p.

    Returns
    -------
    a : ndarray, shape (T, order + 1)
        ``[1, a_1, ..., a_p]`` per frame.
    err : ndarray, shape (T,)
        Prediction-error power (> 0).

    Raises
    ------
    ValueError
        ``r`` is not 2-D with at least ``order + 1`` lags.

    Notes
    -----
    Lag 0 gets the white-noise correction ``WHITE_NOISE_CORRECTION`` and the floor
    ``ENERGY_FLOOR`` added, so silent frames give a flat model.
    """
    r = np.asarray(r, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] < order + 1:
        raise ValueError(f"levinson: r must have shape (T, >= {order + 1}), got {r.shape}")
    r0 = r[:, 0] * (1.0 + WHITE_NOISE_CORRECTION) + ENERGY_FLOOR
    T = r.shape[0]
    a = np.zeros((T, order + 1))
    a[:, 0] = 1.0
    err = r0.copy()
    for i in range(1, order + 1):
        acc = r[:, i].copy()
        if i > 1:
            acc += np.einsum("tj,tj->t", a[:, 1:i], r[:, i - 1:0:-1])
        k = -acc / err
        if i > 1:
            a[:, 1:i] = a[:, 1:i] + k[:, None] * a[:, i - 1:0:-1]
        a[:, i] = k
        err = err * (1.0 - k * k)
    return a, np.maximum(err, ENERGY_FLOOR * 1e-3)


def autocorrelation(frames: np.ndarray, max_lag: int) -> np.ndarray:
    """Autocorrelation of each row up to lag ``max_lag`` (zero-padded FFT, no wrap-around).

    Parameters
    ----------
    frames : ndarray, shape (T, n)
        One frame per row.
    max_lag : int
        Highest lag computed.

    Returns
    -------
    ndarray, shape (T, max_lag + 1)
        ``r[:, k] = sum_n frames[:, n] frames[:, n + k]``, lag 0 first.
    """
    from scipy.fft import irfft, rfft

    n_fft = fast_len(frames.shape[1] + max_lag + 1)
    spec = rfft(frames, n_fft, axis=1)
    return irfft(spec.real ** 2 + spec.imag ** 2, n_fft, axis=1)[:, :max_lag + 1]


def pre_emphasis(x: np.ndarray, coef: float) -> np.ndarray:
    """Pre-emphasis filter ``y[n] = x[n] - coef * x[n - 1]`` (first sample kept).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Samples.
    coef : float
        Pre-emphasis coefficient (e.g. 0.97).

    Returns
    -------
    ndarray, shape (n,)
        The filtered samples (a new float64 array).
    """
    y = np.array(x, dtype=np.float64, copy=True)
    y[1:] -= coef * x[:-1]
    return y


def lpc_frames(x: np.ndarray, rate: float, fps: float, n_out: int, *, order: int = 12,
               window_s: float = 0.025, preemph: float = 0.97, window: str = "hamming"
               ) -> tuple[np.ndarray, np.ndarray]:
    """LPC coefficients of windows centred on video frame times.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Mono samples at ``rate``.
    rate : float
        Sample rate of ``x`` in Hz.
    fps : float
        Output frame rate.
    n_out : int
        Number of output frames (frame ``k`` centred at ``k / fps``).
    order : int
        Prediction order (default 12).
    window_s : float
        Window length in seconds (default 0.025; see :func:`lpc_window`).
    preemph : float
        Pre-emphasis coefficient (default 0.97; 0 disables).
    window : {"hamming", "gaussian"}
        Window shape (Praat's Gaussian for formants); default ``"hamming"``.

    Returns
    -------
    a : ndarray, shape (n_out, order + 1)
        ``[1, a_1, ..., a_p]`` per frame (:func:`levinson`).
    err : ndarray, shape (n_out,)
        Prediction-error power per frame.

    Raises
    ------
    ValueError
        ``order`` below 1, or ``fps`` not positive and finite.
    """
    if order < 1:
        raise ValueError(f"lpc: order must be >= 1, got {order}")
    w = lpc_window(order, window_s, rate, window)
    length = w.shape[0]
    centres = frame_centres(n_out, rate, fps)
    a = np.empty((n_out, order + 1))
    err = np.empty(n_out)
    for sl, frames in iter_frames(x, centres, length, w, preemph=preemph):
        a[sl], err[sl] = levinson(autocorrelation(frames, order), order)
    return a, err


def lpc_window(order: int, window_s: float, rate: float, window: str = "hamming") -> np.ndarray:
    """The LPC analysis window: ``max(order + 1, round(window_s rate))`` samples, Hamming or
    (``"gaussian"``) Praat's Gaussian.

    Parameters
    ----------
    order : int
        Prediction order (the window has at least ``order + 1`` samples).
    window_s : float
        Window length in seconds.
    rate : float
        Sample rate in Hz.
    window : {"hamming", "gaussian"}
        Window shape (default ``"hamming"``; any other value gives the Gaussian).

    Returns
    -------
    ndarray, shape (n,)
        The window (:func:`~voicepuppet.audio.framing.hamming` or :func:`gaussian_window`).
    """
    length = max(order + 1, int(round(window_s * rate)))
    return hamming(length) if window == "hamming" else gaussian_window(length)


def formant_analysis(rate: int, ceiling: float, n_formants: int = 3):
    """The formant analysis settings: ``(fs, order, preemph)``, the rate the signal is resampled
    to (``2 ceiling``, at most ``rate``), the LPC order ``2 (n_formants + 2)`` and the
    pre-emphasis from 50 Hz.

    Parameters
    ----------
    rate : int
        Sample rate of the signal in Hz.
    ceiling : float
        Formant ceiling in Hz (e.g. 5500).
    n_formants : int
        Number of formants sought (default 3).

    Returns
    -------
    fs : int
        Analysis rate in Hz: ``round(2 ceiling)``, at most ``rate``.
    order : int
        LPC order ``2 (n_formants + 2)``.
    preemph : float
        Pre-emphasis coefficient ``exp(-2 pi 50 / fs)``.
    """
    fs = int(round(2 * ceiling))
    if fs > rate:
        fs = int(rate)
    return fs, 2 * (n_formants + 2), math.exp(-2.0 * math.pi * 50.0 / fs)


def gaussian_window(n: int) -> np.ndarray:
    """Praat's Gaussian window (``exp(-12 (t - 1/2)^2)`` rescaled to zero at the edges).

    Parameters
    ----------
    n : int
        Window length in samples.

    Returns
    -------
    ndarray, shape (n,)
        The window, 1 at the centre.
    """
    t = (np.arange(n) + 0.5) / n - 0.5
    e12 = math.exp(-12.0)
    return (np.exp(-48.0 * t * t) - e12) / (1.0 - e12)


def lpc_to_cepstrum(a: np.ndarray, err: np.ndarray, n_ceps: int) -> np.ndarray:
    """Cepstrum of the all-pole model ``err / |A|^2``.

    ``c_0 = log(err)``; ``c_n = -a_n - sum_{k=1}^{n-1} (k / n) c_k a_{n-k}`` (``a_n = 0`` for
    ``n > p``). Equals the real cepstrum of ``log(err / |A(e^jw)|^2)``.

    Parameters
    ----------
    a : ndarray, shape (T, p + 1)
        ``[1, a_1, ..., a_p]`` per frame.
    err : ndarray, shape (T,)
        Prediction-error power per frame.
    n_ceps : int
        Number of coefficients returned, ``c_0 .. c_{n_ceps - 1}``.

    Returns
    -------
    ndarray, shape (T, n_ceps)
    """
    a = np.asarray(a, dtype=np.float64)
    T, p1 = a.shape
    p = p1 - 1
    c = np.zeros((T, n_ceps))
    c[:, 0] = np.log(err)
    for n in range(1, n_ceps):
        acc = -a[:, n] if n <= p else np.zeros(T)
        for k in range(max(1, n - p), n):
            acc = acc - (k / n) * c[:, k] * a[:, n - k]
        c[:, n] = acc
    return c


def lpc_roots(a: np.ndarray) -> np.ndarray:
    """Roots of ``A(z)`` per frame via the companion-matrix eigenvalues.

    Parameters
    ----------
    a : ndarray, shape (T, p + 1)
        ``[1, a_1, ..., a_p]`` per frame.

    Returns
    -------
    ndarray of complex, shape (T, p)
        The p roots of each frame's ``A(z)``.
    """
    a = np.asarray(a, dtype=np.float64)
    T, p1 = a.shape
    p = p1 - 1
    comp = np.zeros((T, p, p))
    comp[:, 0, :] = -a[:, 1:]
    if p > 1:
        comp[:, np.arange(1, p), np.arange(p - 1)] = 1.0
    return np.linalg.eigvals(comp)


def reference_formants(ceiling: float, n: int = 3) -> np.ndarray:
    """Reference frequencies of F1..Fn for a formant ceiling (Praat's Formant Track:
    ``(2i - 1) ceiling / 10``, e.g. 550, 1650, 2750 Hz for 5500 Hz).

    Parameters
    ----------
    ceiling : float
        Formant ceiling in Hz.
    n : int
        Number of formants (default 3).

    Returns
    -------
    ndarray, shape (n,)
        Reference frequencies in Hz.
    """
    return np.array([(2 * i - 1) * ceiling / 10.0 for i in range(1, n + 1)])


def formant_candidates(a: np.ndarray, rate: float, *, min_freq: float = 90.0,
                       max_bandwidth: float = 1000.0, margin: float = 50.0, n_max: int | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Formant candidates (frequency, bandwidth) from LPC roots, sorted by frequency.

    A root ``r = |r| e^{j theta}`` in the upper half plane gives ``F = theta rate / (2 pi)`` and
    ``B = -log|r| rate / pi``. Candidates below ``min_freq``, within ``margin`` of Nyquist or
    wider than ``max_bandwidth`` are dropped (NaN).

    Parameters
    ----------
    a : ndarray, shape (T, p + 1)
        LPC coefficients ``[1, a_1, ..., a_p]`` per frame.
    rate : float
        Sample rate (Hz) the coefficients were computed at.
    min_freq : float
        Lowest candidate frequency in Hz (default 90).
    max_bandwidth : float
        Widest candidate bandwidth in Hz (default 1000).
    margin : float
        Candidates within this many Hz of Nyquist are dropped (default 50).
    n_max : int, optional
        Candidates kept per frame (default ``(p + 1) // 2``).

    Returns
    -------
    freqs, bands : ndarray, shape (T, n_max)
        Frequencies and bandwidths in Hz, NaN-padded, ascending in frequency.
    """
    roots = lpc_roots(a)
    T, p = roots.shape
    n_max = n_max or (p + 1) // 2
    freq = np.angle(roots) * (rate / (2.0 * np.pi))
    mag = np.maximum(np.abs(roots), 1e-300)
    bw = -np.log(mag) * (rate / np.pi)
    ok = (roots.imag > 0) & (freq >= min_freq) & (freq <= rate / 2.0 - margin) & \
         (bw > 0) & (bw <= max_bandwidth)
    freq = np.where(ok, freq, np.inf)
    order = np.argsort(freq, axis=1)[:, :n_max]
    f = np.take_along_axis(freq, order, axis=1)
    b = np.take_along_axis(np.where(ok, bw, np.inf), order, axis=1)
    bad = ~np.isfinite(f)
    f[bad] = np.nan
    b[bad] = np.nan
    if f.shape[1] < n_max:
        pad = np.full((T, n_max - f.shape[1]), np.nan)
        f, b = np.hstack([f, pad]), np.hstack([b, pad])
    return f, b


def track_formants(freqs: np.ndarray, bands: np.ndarray, *, n_formants: int = 3,
                   ceiling: float = 5500.0, freq_cost: float = 1.0, bandwidth_cost: float = 1.0,
                   transition_cost: float = 1.0) -> np.ndarray:
    """Assign candidates to F1..Fn with continuity (Viterbi over ordered candidate triples).

    Each frame's state is an increasing choice of ``n_formants`` candidates. Local cost (as in
    Praat's Formant Track): ``freq_cost * sum |F_i - ref_i| / ref_i + bandwidth_cost * sum B_i /
    F_i``; transition cost ``transition_cost * sum |log(F_i(t) / F_i(t-1))|``. Frames with too
    few candidates take the values of their neighbours (linear interpolation in time); if no
    frame has formants, the reference values are returned.

    Parameters
    ----------
    freqs, bands : ndarray, shape (T, K)
        Candidate frequencies and bandwidths in Hz per frame, NaN where missing (as
        :func:`formant_candidates` gives them).
    n_formants : int
        Number of formants assigned (default 3).
    ceiling : float
        Formant ceiling in Hz that sets the reference frequencies (default 5500; see
        :func:`reference_formants`).
    freq_cost, bandwidth_cost, transition_cost : float
        Weights of the three cost terms (default 1 each).

    Returns
    -------
    ndarray, shape (T, n_formants)
        Finite formant frequencies in Hz.
    """
    T, K = freqs.shape
    ref = reference_formants(ceiling, n_formants)
    combos = np.array(list(combinations(range(K), n_formants)), dtype=np.int64)  # (S, n)
    F = freqs[:, combos]  # (T, S, n)
    B = bands[:, combos]
    valid = np.all(np.isfinite(F), axis=2)  # (T, S)
    BIG = 1e6
    with np.errstate(invalid="ignore"):
        local = freq_cost * np.sum(np.abs(F - ref) / ref, axis=2) + \
            bandwidth_cost * np.sum(B / F, axis=2)
    local = np.where(valid, local, BIG)
    logF = np.log(np.where(np.isfinite(F), F, 1.0))
    S = combos.shape[0]
    back = np.zeros((T, S), dtype=np.int64)
    score = local[0].copy()
    block = 4096
    for b0 in range(1, T, block):
        b1 = min(T, b0 + block)
        trans = transition_cost * np.sum(
            np.abs(logF[b0:b1, None, :, :] - logF[b0 - 1:b1 - 1, :, None, :]), axis=3)
        both = valid[b0 - 1:b1 - 1, :, None] & valid[b0:b1, None, :]
        trans = np.where(both, trans, 0.0)  # no continuity cost across gaps
        for t in range(b0, b1):
            tot = score[:, None] + trans[t - b0]
            arg = np.argmin(tot, axis=0)
            back[t] = arg
            score = tot[arg, np.arange(S)] + local[t]
    path = np.empty(T, dtype=np.int64)
    path[-1] = int(np.argmin(score))
    for t in range(T - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    out = F[np.arange(T), path]  # (T, n)
    good = valid[np.arange(T), path]
    times = np.arange(T)
    if not np.any(good):
        return np.tile(ref, (T, 1))
    for i in range(n_formants):
        out[:, i] = np.interp(times, times[good], out[good, i])
    return out


def formant_frames(x: np.ndarray, rate: float, fps: float, n_out: int, *, n_formants: int = 3,
                   ceiling: float = 5500.0, window_s: float = 0.05, max_bandwidth: float = 1000.0,
                   track: bool = True) -> np.ndarray:
    """Formants F1..Fn (Hz) at video frame times, Praat-style analysis.

    The signal is resampled to ``2 * ceiling`` Hz, pre-emphasised from 50 Hz, cut with a
    ``window_s`` Gaussian window and modelled with ``2 * (n_formants + 2)`` LPC poles
    (autocorrelation method); candidates come from the roots (``formant_candidates``) and are
    assigned with continuity (``track_formants``) or, if ``track`` is False, taken in order of
    frequency (NaN where missing).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Mono samples at ``rate``.
    rate : float
        Sample rate of ``x`` in Hz.
    fps : float
        Output frame rate; frame ``k`` is centred at ``k / fps``.
    n_out : int
        Number of output frames.
    n_formants : int
        Number of formants (default 3).
    ceiling : float
        Formant ceiling in Hz (default 5500); if ``rate`` is below ``2 * ceiling`` the signal
        is analysed at ``rate`` and the tracker's references follow its Nyquist frequency.
    window_s : float
        Gaussian window length in seconds (default 0.05).
    max_bandwidth : float
        Widest candidate bandwidth in Hz (default 1000).
    track : bool
        Assign with continuity (default True) or take the lowest candidates.

    Returns
    -------
    ndarray, shape (n_out, n_formants)
        Formant frequencies in Hz (finite when ``track``).
    """
    fs, order, preemph = formant_analysis(int(rate), ceiling, n_formants)
    y = resample(np.asarray(x, dtype=np.float64), int(rate), fs) if fs != rate else x
    a, _ = lpc_frames(y, fs, fps, n_out, order=order, window_s=window_s, preemph=preemph,
                      window="gaussian")
    f, b = formant_candidates(a, fs, max_bandwidth=max_bandwidth)
    if not track:
        return f[:, :n_formants]
    return track_formants(f, b, n_formants=n_formants, ceiling=fs / 2.0)
