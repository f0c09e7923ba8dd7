"""Short-time spectra and the features built on them: MFCC, RASTA-PLP, band energies, energy.

All analysis windows are centred on video frame times (see ``framing``); power spectra are
``|rfft(window * frame)|^2``. The tables (windows, filterbanks) are used by the C++ front end
(``stream.core_options``); ``spectral_features`` is the numpy reference of its per-frame work
(``extract.reference_extract``, the test oracle).
"""

from __future__ import annotations

import math

import numpy as np

from voicepuppet.audio.framing import centred_window, fast_len, frame_centres, hann, iter_frames
from voicepuppet.audio.lpc import levinson, lpc_to_cepstrum

#: Power floor (amin of librosa.power_to_db): -100 dB.
POWER_FLOOR = 1e-10

#: Bands (Hz) of the sonorant band energies: voice bar and nasal murmur, the F1 region, the F2
#: region and the F3 region (where vowels, nasals, liquids and glides put their energy).
SONORANT_BANDS = ((80.0, 400.0), (400.0, 1000.0), (1000.0, 2500.0), (2500.0, 4000.0))


# --------------------------------------------------------------------------- mel / MFCC
def hz_to_mel(f):
    """Slaney's mel scale (librosa's default, ``htk=False``): linear below 1 kHz, log above.

    Parameters
    ----------
    f : array_like
        Frequencies in Hz.

    Returns
    -------
    ndarray
        Mels, the shape of ``f``.
    """
    f = np.asarray(f, dtype=np.float64)
    f_sp = 200.0 / 3.0
    min_log_mel = 1000.0 / f_sp
    logstep = math.log(6.4) / 27.0
    return np.where(f >= 1000.0, min_log_mel + np.log(np.maximum(f, 1e-300) / 1000.0) / logstep,
                    f / f_sp)


def mel_to_hz(m):
    """Inverse of :func:`hz_to_mel` (Slaney's mel scale).

    Parameters
    ----------
    m : array_like
        Mels.

    Returns
    -------
    ndarray
        Frequencies in Hz, the shape of ``m``.
    """
    m = np.asarray(m, dtype=np.float64)
    f_sp = 200.0 / 3.0
    min_log_mel = 1000.0 / f_sp
    logstep = math.log(6.4) / 27.0
    return np.where(m >= min_log_mel, 1000.0 * np.exp(logstep * (m - min_log_mel)), f_sp * m)


def mel_filterbank(rate: float, n_fft: int, n_mels: int = 40, fmin: float = 0.0,
                   fmax: float | None = None) -> np.ndarray:
    """Triangular mel filters, area-normalised (Slaney).

    Parameters
    ----------
    rate : float
        Sample rate in Hz.
    n_fft : int
        FFT length.
    n_mels : int
        Number of filters (default 40).
    fmin : float
        Lowest edge in Hz (default 0).
    fmax : float, optional
        Highest edge in Hz (default ``rate / 2``).

    Returns
    -------
    ndarray, shape (n_mels, n_fft // 2 + 1)
        Filter weights on the one-sided FFT bins.

    Raises
    ------
    ValueError
        Not ``0 <= fmin < fmax <= rate / 2``.
    """
    fmax = rate / 2.0 if fmax is None else float(fmax)
    if not 0 <= fmin < fmax <= rate / 2.0:
        raise ValueError(f"mel: need 0 <= fmin < fmax <= rate/2, got fmin={fmin}, fmax={fmax}, "
                         f"rate={rate}")
    fft_f = np.linspace(0.0, rate / 2.0, n_fft // 2 + 1)
    mel_f = mel_to_hz(np.linspace(hz_to_mel(fmin), hz_to_mel(fmax), n_mels + 2))
    fdiff = np.diff(mel_f)
    ramps = mel_f[:, None] - fft_f[None, :]
    lower = -ramps[:-2] / fdiff[:-1, None]
    upper = ramps[2:] / fdiff[1:, None]
    w = np.maximum(0.0, np.minimum(lower, upper))
    w *= (2.0 / (mel_f[2:] - mel_f[:-2]))[:, None]
    return w


def dct_ortho(x: np.ndarray, n: int) -> np.ndarray:
    """First ``n`` orthonormal DCT-II coefficients along the last axis.

    Parameters
    ----------
    x : ndarray, shape (..., m)
        Input.
    n : int
        Number of coefficients kept.

    Returns
    -------
    ndarray, shape (..., n)
        ``scipy.fft.dct(x, type=2, norm="ortho")`` cut to ``n`` coefficients.
    """
    from scipy.fft import dct

    return dct(x, type=2, norm="ortho", axis=-1)[..., :n]


def deltas(x: np.ndarray, width: int = 2) -> np.ndarray:
    """Regression deltas (HTK): ``d_t = sum_n n (x_{t+n} - x_{t-n}) / (2 sum n^2)``, edges
    replicated. Equals ``librosa.feature.delta(x.T, width=2 * width + 1, mode="nearest").T``.

    Parameters
    ----------
    x : array_like, shape (T, d)
        Features, one row per frame.
    width : int
        Frames on each side in the regression (default 2).

    Returns
    -------
    ndarray, shape (T, d)
        The deltas.
    """
    x = np.asarray(x, dtype=np.float64)
    T = x.shape[0]
    xp = np.concatenate([np.repeat(x[:1], width, axis=0), x, np.repeat(x[-1:], width, axis=0)])
    num = np.zeros_like(x)
    for n in range(1, width + 1):
        num += n * (xp[width + n:width + n + T] - xp[width - n:width - n + T])
    return num / (2.0 * sum(n * n for n in range(1, width + 1)))


# --------------------------------------------------------------------------- bark / RASTA-PLP
def hz_to_bark(f):
    """Schroeder's Bark scale ``6 asinh(f / 600)`` (the one of PLP).

    Parameters
    ----------
    f : array_like
        Frequencies in Hz.

    Returns
    -------
    ndarray
        Barks, the shape of ``f``.
    """
    return 6.0 * np.arcsinh(np.asarray(f, dtype=np.float64) / 600.0)


def bark_to_hz(z):
    """Inverse of :func:`hz_to_bark`: ``600 sinh(z / 6)``.

    Parameters
    ----------
    z : array_like
        Barks.

    Returns
    -------
    ndarray
        Frequencies in Hz, the shape of ``z``.
    """
    return 600.0 * np.sinh(np.asarray(z, dtype=np.float64) / 6.0)


def bark_filterbank(rate: float, n_fft: int) -> tuple[np.ndarray, np.ndarray]:
    """PLP critical-band filters (Hermansky 1990), one per Bark from 0 to Nyquist.

    The masking curve is flat within +/-0.5 Bark, rises 25 dB/Bark below and falls 10 dB/Bark
    above.

    Parameters
    ----------
    rate : float
        Sample rate in Hz.
    n_fft : int
        FFT length.

    Returns
    -------
    weights : ndarray, shape (n_bands, n_fft // 2 + 1)
        Filter weights on the one-sided FFT bins.
    centres_hz : ndarray, shape (n_bands,)
        Filter centres in Hz, evenly spaced in Bark from 0 to Nyquist.
    """
    nyq_bark = float(hz_to_bark(rate / 2.0))
    n_bands = int(math.ceil(nyq_bark)) + 1
    step = nyq_bark / (n_bands - 1)
    bins = hz_to_bark(np.linspace(0.0, rate / 2.0, n_fft // 2 + 1))
    mids = np.arange(n_bands) * step
    lof = bins[None, :] - mids[:, None] - 0.5
    hif = bins[None, :] - mids[:, None] + 0.5
    w = 10.0 ** np.minimum(0.0, np.minimum(hif, -2.5 * lof))
    return w, bark_to_hz(mids)


def equal_loudness(f_hz: np.ndarray) -> np.ndarray:
    """Equal-loudness weighting of PLP (Hermansky 1990) in Hz, as in rastamat's ``postaud``:
    ``E(f) = (f^2 / (f^2 + 400^2))^2 (f^2 + 1200^2) / (f^2 + 3100^2)``.

    Parameters
    ----------
    f_hz : array_like
        Frequencies in Hz.

    Returns
    -------
    ndarray
        ``E(f)``, the shape of ``f_hz``.
    """
    fsq = np.asarray(f_hz, dtype=np.float64) ** 2
    ftmp = fsq + 1.6e5
    return (fsq / ftmp) ** 2 * ((fsq + 1.44e6) / (fsq + 9.61e6))


def rasta_coefficients(frame_rate: float, pole: float = 0.94) -> tuple[np.ndarray, np.ndarray]:
    """``(b, a)`` of the RASTA filter at ``frame_rate`` frames/s (pole ``pole^(100 / rate)``).

    Parameters
    ----------
    frame_rate : float
        Frames per second of the filtered sequence.
    pole : float
        Pole at 100 frames/s (default 0.94).

    Returns
    -------
    b : ndarray, shape (5,)
        Numerator ``[0.2, 0.1, 0, -0.1, -0.2]``.
    a : ndarray, shape (2,)
        Denominator ``[1, -pole^(100 / frame_rate)]``.
    """
    b = np.array([0.2, 0.1, 0.0, -0.1, -0.2])
    return b, np.array([1.0, -(pole ** (100.0 / frame_rate))])


def rasta_filter(log_bands: np.ndarray, frame_rate: float, pole: float = 0.94) -> np.ndarray:
    """RASTA band-pass filter along time (Hermansky & Morgan 1994).

    ``H(z) = 0.1 (2 + z^-1 - z^-3 - 2 z^-4) / (1 - p z^-1)`` at 100 frames/s; at another frame
    rate the pole is rescaled to keep its time constant (``p^(100 / frame_rate)``). The filter
    starts in the steady state of the first frame, so a constant (a fixed channel gain or
    spectral tilt) gives exactly zero output from the first frame on.

    Parameters
    ----------
    log_bands : ndarray, shape (T, n_bands)
        Log band energies, one row per frame.
    frame_rate : float
        Frames per second of the rows.
    pole : float
        Pole at 100 frames/s (default 0.94).

    Returns
    -------
    ndarray, shape (T, n_bands)
        The filtered log band energies.
    """
    from scipy.signal import lfilter, lfilter_zi

    b, a = rasta_coefficients(frame_rate, pole)
    zi = lfilter_zi(b, a)[:, None] * log_bands[:1, :]
    y, _ = lfilter(b, a, log_bands, axis=0, zi=zi)
    return y


def plp_from_bands(bands: np.ndarray, centres_hz: np.ndarray, order: int, n_ceps: int
                   ) -> np.ndarray:
    """Equal loudness, cube-root compression and an all-pole fit -> cepstra (T, n_ceps).

    Parameters
    ----------
    bands : ndarray, shape (T, n_bands)
        Critical-band powers (:func:`bark_filterbank` applied to power spectra).
    centres_hz : ndarray, shape (n_bands,)
        Band centres in Hz.
    order : int
        All-pole model order.
    n_ceps : int
        Number of cepstra returned, ``c_0 .. c_{n_ceps - 1}``.

    Returns
    -------
    ndarray, shape (T, n_ceps)
        PLP cepstra (:func:`~voicepuppet.audio.lpc.lpc_to_cepstrum` of the model).
    """
    z = bands * equal_loudness(centres_hz)[None, :]
    z = np.cbrt(np.maximum(z, 0.0))
    z[:, 0] = z[:, 1]
    z[:, -1] = z[:, -2]
    # The auditory spectrum is a power spectrum sampled from 0 to Nyquist: its inverse DFT
    # (mirrored, real) is an autocorrelation sequence.
    full = np.concatenate([z, z[:, -2:0:-1]], axis=1)
    r = np.fft.ifft(full, axis=1).real[:, :order + 1]
    a, err = levinson(r, order)
    return lpc_to_cepstrum(a, err, n_ceps)


# --------------------------------------------------------------------------- one analysis pass
def analysis_window(window_s: float, rate: float, n_fft: int | None = None):
    """The spectral analysis window: ``(n_fft, window [n_fft], freqs [n_fft//2+1], parseval)``.

    A Hann window of ``round(window_s * rate)`` samples centred in ``n_fft`` (default the next
    fast length); ``parseval`` weights turn one-sided power into the mean square of the windowed
    frame over the window energy. Shared by the C++ front end (``stream.core_options``) and the
    numpy reference.

    Parameters
    ----------
    window_s : float
        Window length in seconds.
    rate : float
        Sample rate in Hz.
    n_fft : int, optional
        FFT length (default the next fast length >= the window, at least 2).

    Returns
    -------
    n_fft : int
        The FFT length.
    window : ndarray, shape (n_fft,)
        The centred Hann window.
    freqs : ndarray, shape (n_fft // 2 + 1,)
        Frequencies (Hz) of the one-sided bins.
    parseval : ndarray, shape (n_fft // 2 + 1,)
        Parseval weights of the bins.

    Raises
    ------
    ValueError
        The window is longer than ``n_fft``.
    """
    length = int(round(window_s * rate))
    if n_fft is None:
        n_fft = fast_len(max(length, 2))
    if length > n_fft:
        raise ValueError(f"window of {length} samples exceeds n_fft={n_fft}")
    win = centred_window(hann(length), n_fft)
    win_energy = float(np.sum(win * win))
    freqs = np.fft.rfftfreq(n_fft, 1.0 / rate)
    parseval = np.full(freqs.shape[0], 2.0)
    parseval[0] = 1.0
    if n_fft % 2 == 0:
        parseval[-1] = 1.0
    parseval /= n_fft * win_energy
    return n_fft, win, freqs, parseval


def band_weights(freqs: np.ndarray, parseval: np.ndarray, bands=SONORANT_BANDS) -> np.ndarray:
    """Weights turning a one-sided power spectrum into band energies: each band's indicator
    ``low <= f < high`` times the Parseval weights.

    Parameters
    ----------
    freqs : ndarray, shape (n_bins,)
        Frequencies (Hz) of the bins.
    parseval : ndarray, shape (n_bins,)
        Parseval weights of the bins (:func:`analysis_window`).
    bands : sequence of (float, float)
        ``(low, high)`` edges in Hz (default ``SONORANT_BANDS``).

    Returns
    -------
    ndarray, shape (len(bands), n_bins)
        One row of weights per band.

    Raises
    ------
    ValueError
        A band that is not ``0 <= low < high``.
    """
    w = np.zeros((len(bands), freqs.shape[0]))
    for i, (lo, hi) in enumerate(bands):
        if not 0 <= lo < hi:
            raise ValueError(f"bands must be (low, high) with 0 <= low < high, got {(lo, hi)}")
        w[i] = ((freqs >= lo) & (freqs < hi)) * parseval
    return w


def spectral_features(x: np.ndarray, rate: float, fps: float, n_out: int, *,
                      want: set, window_s: float = 0.025, n_fft: int | None = None,
                      n_mfcc: int = 13, n_mels: int = 40, fmin: float = 0.0,
                      fmax: float | None = None, rasta_order: int = 8, rasta_ceps: int = 9,
                      rasta_rate: float = 100.0, bands=SONORANT_BANDS) -> dict:
    """One STFT pass for the spectral features requested in ``want``.

    ``want`` is a subset of ``{"mfcc", "rasta_plp", "bands", "log_energy"}``. RASTA filtering
    needs a frame rate near 100/s: its spectra are computed on a grid ``m`` times finer than the
    video frames (``m = round(rasta_rate / fps)``, at least 1) whose every ``m``-th frame is a
    video frame time, and subsampled after filtering.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Mono samples at ``rate``.
    rate : float
        Sample rate in Hz.
    fps : float
        Output frame rate; frame ``k`` is centred at ``k / fps``.
    n_out : int
        Number of output frames.
    want : set of str
        The features computed.
    window_s : float
        Analysis window length in seconds (default 0.025).
    n_fft : int, optional
        FFT length (default the next fast length >= the window).
    n_mfcc, n_mels : int
        MFCCs kept (default 13) and mel filters (default 40).
    fmin, fmax : float
        Mel filterbank range in Hz (default 0 to ``rate / 2``).
    rasta_order, rasta_ceps : int
        RASTA-PLP all-pole order (default 8) and cepstra kept (default 9).
    rasta_rate : float
        Frame rate (frames/s) RASTA filtering runs near (default 100).
    bands : sequence of (float, float)
        Band edges in Hz of the band energies (default ``SONORANT_BANDS``).

    Returns
    -------
    dict
        ``mfcc`` (n_out, n_mfcc) cepstra of the log (dB) mel power; ``rasta_plp``
        (n_out, rasta_ceps); ``bands`` (n_out, len(bands)) in dB; ``log_energy`` (n_out,) in dB.
    """
    from scipy.fft import rfft

    n_fft, win, freqs, parseval = analysis_window(window_s, rate, n_fft)

    m = max(1, int(round(rasta_rate / fps))) if "rasta_plp" in want else 1
    fine = frame_centres(n_out * m, rate, fps * m)
    out: dict = {}
    if "mfcc" in want:
        melfb = mel_filterbank(rate, n_fft, n_mels, fmin, fmax)
        mel = np.empty((n_out, n_mels))
    if "bands" in want:
        band_w = band_weights(freqs, parseval, bands)
        bandE = np.empty((n_out, len(bands)))
    if "log_energy" in want:
        energy = np.empty(n_out)
    if "rasta_plp" in want:
        barkfb, centres_hz = bark_filterbank(rate, n_fft)
        bark = np.empty((n_out * m, barkfb.shape[0]))
    block = 2048 * m
    for sl, frames in iter_frames(x, fine, n_fft, win, block=block):
        spec = rfft(frames, axis=1)
        P = spec.real ** 2 + spec.imag ** 2
        if "rasta_plp" in want:
            bark[sl] = P @ barkfb.T
        # video-frame rows of this block (block is a multiple of m, so rows 0, m, 2m, ...)
        Pv = P[::m]
        osl = slice(sl.start // m, sl.start // m + Pv.shape[0])
        if "mfcc" in want:
            mel[osl] = Pv @ melfb.T
        if "bands" in want:
            bandE[osl] = Pv @ band_w.T
        if "log_energy" in want:
            energy[osl] = Pv @ parseval
    if "mfcc" in want:
        out["mfcc"] = dct_ortho(10.0 * np.log10(np.maximum(mel, POWER_FLOOR)), n_mfcc)
    if "bands" in want:
        out["bands"] = 10.0 * np.log10(bandE + POWER_FLOOR)
    if "log_energy" in want:
        out["log_energy"] = 10.0 * np.log10(energy + POWER_FLOOR)
    if "rasta_plp" in want:
        logb = np.log(bark + POWER_FLOOR)
        filt = rasta_filter(logb, fps * m)[::m]
        out["rasta_plp"] = plp_from_bands(np.exp(filt), centres_hz, rasta_order, rasta_ceps)
    return out
