"""Streaming audio features: the front end fed chunks of any size.

:class:`StreamingFeatures` takes samples in chunks of any size (one sample to many seconds) and
returns the feature frames whose analysis windows are complete. The per-frame work runs in C++
(``voicepuppet::StreamingAudioFeatures``, cpp/include/voicepuppet/audio_features.hpp, the GIL
released); this module builds its analysis tables from the definitions in ``spectral`` and
``lpc`` and checks the input. The offline front end (:func:`voicepuppet.audio.extract`) is the
same C++ code run on the whole (DC-removed) signal in one push, so stream and offline agree by
construction; both are tested to 1e-9 against the numpy reference
(``extract.reference_extract``, the test oracle, on
``prepare(x, rate, target_rate=None, remove_dc=False)``):

- spectral features (``mfcc``, ``bands``, ``log_energy``, ``rasta_plp``) and LPC features are
  per-window computations: frame ``k`` is ready once the sample at the right edge of its window
  has arrived (12.5 ms after its centre with the default 25 ms window);
- RASTA filtering is a recursive filter along time: its state is carried between chunks and it
  starts, like the offline filter, in the steady state of the first frame;
- ``mfcc_deltas`` need ``delta_width`` frames of look-ahead (edges replicated at the end);
- formants are resampled with the offline polyphase filter (``resample_poly``'s taps applied on
  the stream), and their continuity tracker (a Viterbi over candidate triples) runs online: a
  frame's assignment is final when all surviving paths agree on it (exact online Viterbi), and
  frames without formants wait for the next frame with them (linear interpolation). Both make the
  latency of the formant columns data-dependent; ``formant_lag`` bounds it by forcing a decision
  (the current best path, or holding the last value across a gap) after that many frames, at
  the cost of exactness (measured in docs/streaming.md).

F0 and voicing (global Viterbi with interpolation through unvoiced stretches) are not streamed:
asking for them raises ``ValueError``.

>>> s = StreamingFeatures("puppet", fps=29.97)              # doctest: +SKIP
>>> rows = s.push(chunk)              # (K, 24), K >= 0 new frames          # doctest: +SKIP
>>> rest = s.flush()                  # end of stream: the remaining frames  # doctest: +SKIP
"""

from __future__ import annotations

import warnings
from fractions import Fraction

import numpy as np

from voicepuppet import _core
from voicepuppet.audio import lpc as lpc_mod
from voicepuppet.audio import spectral
from voicepuppet.audio.featureset import FeatureSet, analysis_window_s, as_feature_set, check_level_db
from voicepuppet.audio.framing import check_fps, n_frames
from voicepuppet.audio.loading import MIN_RATE, AudioWarning

#: Features the stream can produce.
STREAMABLE = ("lpc", "lpc_cepstra", "rasta_plp", "mfcc", "mfcc_deltas", "formants", "bands",
              "log_energy")

__all__ = ["StreamingFeatures", "BandLimiter", "LevelNormalizer", "StreamResampler", "STREAMABLE",
           "pcm_to_float", "speech_level_db"]


def pcm_to_float(samples) -> np.ndarray:
    """Samples as float64 full scale, shape (n,): integer PCM is scaled by its type's range (as
    :func:`voicepuppet.audio.prepare` does), floats are taken as they are.

    Parameters
    ----------
    samples : array_like, shape (n,) or (n, channels)
        A chunk of samples: floats in full scale or integer PCM; channels are averaged.

    Returns
    -------
    ndarray, shape (n,)
        C-contiguous float64 mono samples.

    Raises
    ------
    ValueError
        Not numbers, not of shape (n,) or (n, channels), or NaN / infinite samples.
    """
    x = np.asarray(samples)
    if x.dtype.kind not in "fiu":
        raise ValueError(f"stream: samples must be numbers, got dtype {x.dtype}")
    if x.dtype.kind == "i":
        x = x.astype(np.float64) / float(2 ** (8 * x.dtype.itemsize - 1))
    elif x.dtype.kind == "u":
        half = float(2 ** (8 * x.dtype.itemsize - 1))
        x = (x.astype(np.float64) - half) / half
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2 and x.shape[1] >= 1:
        x = x.mean(axis=1) if x.shape[1] > 1 else x[:, 0]
    if x.ndim != 1:
        raise ValueError(f"stream: a chunk must have shape (n,) or (n, channels), got {x.shape}")
    if not np.all(np.isfinite(x)):
        bad = int(np.count_nonzero(~np.isfinite(x)))
        raise ValueError(f"stream: {bad} NaN or infinite samples in the chunk; the source is "
                         "corrupt (check the PCM format: e.g. --format s16le)")
    return np.ascontiguousarray(x)


def resample_taps(up: int, down: int) -> np.ndarray:
    """The filter of ``scipy.signal.resample_poly(x, up, down)`` (Kaiser(5)-windowed sinc,
    ``half_len = 10 max(up, down)``, times ``up``).

    Parameters
    ----------
    up, down : int
        Up- and down-sampling factors.

    Returns
    -------
    ndarray, shape (2 half_len + 1,)
        The filter taps.
    """
    from scipy.signal import firwin

    half_len = 10 * max(up, down)
    return firwin(2 * half_len + 1, 1.0 / max(up, down), window=("kaiser", 5.0)) * up


class StreamResampler:
    """``scipy.signal.resample_poly(x, up, down)`` computed chunk by chunk (in C++).

    The offline taps are applied to the stream; output samples are released once every input
    sample under their filter has arrived, and ``flush`` finishes the stream with the zero
    padding of the offline call, so the concatenated output equals ``resample_poly`` on the
    concatenated input (to rounding; same length ``ceil(n up / down)``).

    Parameters
    ----------
    rate_in, rate_out : int
        Sample rates in Hz.

    Attributes
    ----------
    up, down : int
        The resampling ratio ``rate_out / rate_in`` in lowest terms.
    identity : bool
        Whether the two rates are equal.

    Raises
    ------
    ValueError
        A rate that is not a whole number of Hz >= 1.
    """

    def __init__(self, rate_in: int, rate_out: int):
        for name, v in (("rate_in", rate_in), ("rate_out", rate_out)):
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"resampler: {name} must be a whole number of Hz >= 1, got {v!r}")
        frac = Fraction(int(rate_out), int(rate_in))
        self.up, self.down = frac.numerator, frac.denominator
        self.identity = self.up == self.down == 1
        taps = np.zeros(0) if self.identity else resample_taps(self.up, self.down)
        self._core = _core.PolyphaseResampler(self.up, self.down, taps)

    def push(self, x) -> np.ndarray:
        """Feed input samples.

        Parameters
        ----------
        x : array_like, shape (n,)
            The next input samples.

        Returns
        -------
        ndarray, shape (m,)
            The output samples completed by them (m >= 0).

        Raises
        ------
        ValueError
            ``x`` is not one-dimensional.
        """
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.ndim != 1:
            raise ValueError(f"resampler: x must have shape (n,), got {x.shape}")
        return self._core.push(x)

    def flush(self) -> np.ndarray:
        """End of input: the remaining outputs (``ceil(n up / down)`` in total); then reset.

        Returns
        -------
        ndarray, shape (m,)
            The output samples not yet returned.
        """
        return self._core.flush()


def core_options(fset: FeatureSet, fps: float, rate: int, formant_lag: int | None):
    """The ``_core.AudioFeatureOptions`` of a feature set: the analysis tables of the offline
    definitions (``spectral.analysis_window``, the filterbanks, ``lpc.lpc_window``,
    ``gaussian_window``, ``resample_poly``'s taps, ``reference_formants``).

    Parameters
    ----------
    fset : FeatureSet
        A streamable feature set.
    fps : float
        Output frame rate.
    rate : int
        Sample rate in Hz.
    formant_lag : int or None
        Bound (frames) on a formant decision's wait; None: exact.

    Returns
    -------
    voicepuppet._core.AudioFeatureOptions
        The options of the C++ front end.
    """
    from scipy.signal import lfilter_zi

    opt = fset.settings()
    want = set(fset.features)
    window_s = analysis_window_s(opt, fps)
    o = _core.AudioFeatureOptions()
    o.rate = float(rate)
    o.fps = float(fps)
    o.features = list(fset.features)
    if want & {"mfcc", "mfcc_deltas", "rasta_plp", "bands", "log_energy"}:
        n_fft, win, freqs, parseval = spectral.analysis_window(window_s, rate, opt["n_fft"] or None)
        o.n_fft, o.spectral_window, o.parseval = int(n_fft), win, parseval
        m = max(1, int(round(100.0 / fps))) if "rasta_plp" in want else 1
        o.fine = m
        if want & {"mfcc", "mfcc_deltas"}:
            n_mels, n_mfcc = int(opt["n_mels"]), int(opt["n_mfcc"])
            o.mel_filters = spectral.mel_filterbank(rate, n_fft, n_mels)
            o.dct = np.ascontiguousarray(spectral.dct_ortho(np.eye(n_mels), n_mfcc).T)
            o.delta_width = int(opt["delta_width"])
        if "bands" in want:
            o.band_weights = spectral.band_weights(freqs, parseval)
        if "rasta_plp" in want:
            barkfb, centres = spectral.bark_filterbank(rate, n_fft)
            o.bark_filters = barkfb
            o.loudness = spectral.equal_loudness(centres)
            b, a = spectral.rasta_coefficients(fps * m)  # at the fine frame rate
            o.rasta_b, o.rasta_pole = b, float(-a[1])
            o.rasta_zi = lfilter_zi(b, a)
            o.rasta_order, o.n_rasta = int(opt["rasta_order"]), int(opt["n_rasta"])
            o.rasta_first = 0 if opt["rasta_c0"] else 1
    if want & {"lpc", "lpc_cepstra"}:
        order = int(opt["lpc_order"])
        o.lpc_window, o.lpc_order = lpc_mod.lpc_window(order, window_s, rate), order
        o.lpc_preemph = float(opt["lpc_preemph"])
        o.n_lpc_cepstra = int(opt["n_lpc_cepstra"])
    if "formants" in want:
        fs, order, preemph = lpc_mod.formant_analysis(rate, float(opt["formant_ceiling"]))
        frac = Fraction(fs, rate)
        o.resample_up, o.resample_down = frac.numerator, frac.denominator
        if fs != rate:
            o.resample_taps = resample_taps(frac.numerator, frac.denominator)
        o.formant_rate = float(fs)
        o.formant_window = lpc_mod.lpc_window(order, 0.05, fs, "gaussian")  # formant_frames'
        o.formant_order = order
        o.formant_preemph = preemph
        o.formant_max_bandwidth = float(opt["formant_max_bandwidth"])
        o.formant_reference = lpc_mod.reference_formants(fs / 2.0, 3)
        o.formant_lag = -1 if formant_lag is None else int(formant_lag)
    return o


def column_names(fset: FeatureSet) -> tuple:
    """Column names of a streamable feature set, in ``extract``'s order.

    Parameters
    ----------
    fset : FeatureSet
        A streamable feature set.

    Returns
    -------
    tuple of str
        The column names.
    """
    opt = fset.settings()
    first = 0 if opt["rasta_c0"] else 1
    cols = {"mfcc": [f"mfcc{i}" for i in range(opt["n_mfcc"])],
            "mfcc_deltas": [f"dmfcc{i}" for i in range(opt["n_mfcc"])],
            "rasta_plp": [f"rplp{i}" for i in range(first, opt["n_rasta"])],
            "bands": [f"band{i}" for i in range(4)],
            "log_energy": ["log_energy"],
            "lpc": [f"lpc{i}" for i in range(1, int(opt["lpc_order"]) + 1)],
            "lpc_cepstra": [f"lpcc{i}" for i in range(1, int(opt["n_lpc_cepstra"]) + 1)],
            "formants": ["f1", "f2", "f3"]}
    names = []
    for f in fset.features:
        names += cols[f]
    return tuple(names)


class BandLimiter:
    """The ``band_hz`` feature option: the audio resampled to ``2 band_hz`` and back, on a
    stream (two :class:`StreamResampler`), so a 16 kHz recording reaches the analysis as the
    same sound sampled at ``2 band_hz`` would (an 8 kHz telephone recording at ``band_hz =
    4000``), and audio already of that band passes nearly unchanged. The output equals
    ``resample_poly(resample_poly(x, m, r), r, m)`` (``m / r`` the ratio of the two rates) cut
    to the input's length, whole or chunk by chunk.

    Parameters
    ----------
    band_hz : float
        The band's edge (Hz), below ``rate / 2``, with ``2 band_hz`` a whole number of Hz.
    rate : int
        Sample rate (Hz) of the samples filtered.

    Attributes
    ----------
    band_hz : float
        The band's edge (Hz).
    rate : int
        Sample rate (Hz).
    delay_s : float
        Delay (s) of the two resamplers' half filters: how long a pushed sample may wait.

    Raises
    ------
    ValueError
        ``band_hz`` not between 0 and ``rate / 2``, or ``2 band_hz`` not a whole number.
    """

    def __init__(self, band_hz: float, rate: int):
        try:
            band = float(band_hz)
        except (TypeError, ValueError):
            band = float("nan")
        if not (0.0 < band < 0.5 * rate and float(2 * band).is_integer()):
            raise ValueError(f"features: band_hz must be a frequency between 0 and half the analysis rate "
                             f"({0.5 * rate:g} Hz), twice it a whole number of Hz, got {band_hz!r}; e.g. "
                             "4000 for telephone audio")
        self.band_hz, self.rate = band, int(rate)
        self._down = StreamResampler(self.rate, int(2 * band))
        self._up = StreamResampler(int(2 * band), self.rate)
        self.delay_s = sum((len(resample_taps(r.up, r.down)) // 2) / (rate_in * r.up)
                           for r, rate_in in ((self._down, self.rate), (self._up, int(2 * band))))
        self.reset()

    def push(self, x: np.ndarray) -> np.ndarray:
        """Feed the next chunk of the stream.

        Parameters
        ----------
        x : array_like, shape (n,)
            The next samples.

        Returns
        -------
        ndarray, shape (m,)
            The band-limited samples completed so far (fewer than pushed while the filters wait
            for the samples after them: :attr:`delay_s`).
        """
        x = np.ascontiguousarray(x, dtype=np.float64)
        self._n_in += x.size
        return self._release(self._up.push(self._down.push(x)))

    def flush(self) -> np.ndarray:
        """End of the stream: the remaining samples (as many in all as were pushed); then reset.

        Returns
        -------
        ndarray, shape (m,)
            The band-limited samples not yet returned.
        """
        tail = np.concatenate([self._up.push(self._down.flush()), self._up.flush()])
        out = self._release(tail)
        self.reset()
        return out

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Band-limit a whole recording (resets the stream first).

        Parameters
        ----------
        x : array_like, shape (n,)
            The recording.

        Returns
        -------
        ndarray, shape (n,)
            The band-limited recording, length n.
        """
        self.reset()
        return np.concatenate([self.push(x), self.flush()])

    def reset(self) -> None:
        """Forget the stream (a new one starts at time 0)."""
        self._down.flush()
        self._up.flush()
        self._n_in = self._n_out = 0

    def _release(self, y: np.ndarray) -> np.ndarray:
        y = y[:max(0, self._n_in - self._n_out)]  # the up-sampler's last sample can be one past the input
        self._n_out += y.size
        return y


#: The ``level_db`` feature option. A recording's speech level is the LEVEL_PERCENTILE-th
#: percentile (inverted CDF) of its power in LEVEL_FRAME_S frames (dBFS; pauses, however long,
#: fall below it); the recording is scaled to put it at ``level_db`` (by at most MAX_GAIN_DB up),
#: and every GATE_FRAME_S frame whose power is then more than GATE_BELOW_DB under ``level_db``
#: becomes white dither DITHER_BELOW_DB under it (seeded: the same input gives the same
#: samples). A pause is then the dither whether the recording had digital silence or a noise
#: floor up to GATE_BELOW_DB under its speech, and speech frames are left as they are (dither
#: added to every frame cost Err +0.01 to +0.02 on the espeak-ng and real-speech CV by masking
#: their weak high bands). Without it a puppet trained on digital silence (espeak-ng) opened its
#: mouth 10-12 px in pauses with any noise floor above -80 dBFS, and a recording 20 dB quieter
#: cost Err +0.07 (docs/puppet.md, "The recording's level and noise floor").
LEVEL_FRAME_S = 0.032
LEVEL_PERCENTILE = 95.0
MAX_GAIN_DB = 30.0
GATE_FRAME_S = 0.010
GATE_BELOW_DB = 35.0
DITHER_BELOW_DB = 45.0
#: A stream's level is estimated from what it has heard: until LEVEL_SETTLE_S of it, the level is
#: taken to be ``level_db`` already (gain 1).
LEVEL_SETTLE_S = 1.0
_LEVEL_SEED = 20261204
_HIST_LO, _HIST_STEP, _HIST_N = -160.0, 0.25, 800  # frame powers, dBFS: -160 .. +40


def _frame_power(x: np.ndarray, n: int) -> np.ndarray:
    """Mean square of each n-sample frame of ``x`` (a whole number of frames), without a
    temporary the size of ``x`` (which cost 40 times the arithmetic on an hour of audio)."""
    v = x.reshape(-1, n)
    return np.einsum("ij,ij->i", v, v) / n


def speech_level_db(x: np.ndarray, rate: int) -> float:
    """The speech level (dBFS) of samples ``x`` (n,): the :data:`LEVEL_PERCENTILE`-th percentile
    (inverted CDF: one frame's power) of the power of its :data:`LEVEL_FRAME_S` frames (one
    short frame for a shorter input); -inf for digital silence.

    Parameters
    ----------
    x : array_like, shape (n,)
        Samples in full scale.
    rate : int
        Sample rate in Hz.

    Returns
    -------
    float
        The speech level in dBFS, or -inf.
    """
    x = np.asarray(x, dtype=np.float64)
    n = max(1, int(round(LEVEL_FRAME_S * rate)))
    if x.size < n:
        power = np.array([np.mean(x ** 2)]) if x.size else np.zeros(1)
    else:
        power = _frame_power(x[: x.size // n * n], n)
    level = float(np.percentile(power, LEVEL_PERCENTILE, method="inverted_cdf"))
    return 10.0 * np.log10(level) if level > 0 else -np.inf


class LevelNormalizer:
    """The ``level_db`` feature option on a recording (:meth:`apply`) or a stream (:meth:`push`,
    :meth:`flush`): scale to the speech level ``level_db`` dBFS, and turn the frames more than
    :data:`GATE_BELOW_DB` under it into white dither :data:`DITHER_BELOW_DB` under it.

    Parameters
    ----------
    level_db : float
        The speech level (dBFS) every recording is brought to (e.g. -20).
    rate : int
        Sample rate (Hz).
    input_level_db : float, optional
        A stream's speech level, if known: the stream is scaled by the gain it implies from the
        first sample, as :meth:`apply` scales a recording of that level (the same samples, for
        any chunking). Without it the stream's level is estimated from the frames heard so far
        (the gain changes chunk by chunk; 1 until :data:`LEVEL_SETTLE_S` s have been heard).

    Attributes
    ----------
    level_db : float
        The target speech level (dBFS).
    rate : int
        Sample rate (Hz).
    input_level_db : float or None
        The given stream level.
    delay_s : float
        The most a pushed sample waits for the rest of its gate frame.

    Raises
    ------
    ValueError
        ``level_db`` not a level in [-100, 0] dBFS, or ``input_level_db`` not finite.
    """

    def __init__(self, level_db: float, rate: int, input_level_db: float | None = None):
        level = check_level_db(level_db)
        if input_level_db is not None and not np.isfinite(float(input_level_db)):
            raise ValueError(f"input_level_db must be a level in dBFS, got {input_level_db!r}")
        self.level_db, self.rate = level, int(rate)
        self.input_level_db = None if input_level_db is None else float(input_level_db)
        self._frame = max(1, int(round(LEVEL_FRAME_S * self.rate)))
        self._gate = max(1, int(round(GATE_FRAME_S * self.rate)))
        self.delay_s = (self._gate - 1) / self.rate
        self.reset()

    def gain(self, level_db: float) -> float:
        """The factor that brings speech at ``level_db`` dBFS to :attr:`level_db`.

        Parameters
        ----------
        level_db : float
            A speech level in dBFS (-inf for digital silence).

        Returns
        -------
        float
            The amplitude gain (at most :data:`MAX_GAIN_DB` up; 1 for digital silence).
        """
        if not np.isfinite(level_db):
            return 1.0
        return float(10.0 ** (min(self.level_db - level_db, MAX_GAIN_DB) / 20.0))

    def apply(self, x: np.ndarray) -> np.ndarray:
        """A whole recording (n,): scaled by the gain of its own speech level (or of the given
        ``input_level_db``), its quiet frames turned into dither; length n. Resets the stream
        first.

        Parameters
        ----------
        x : array_like, shape (n,)
            The recording.

        Returns
        -------
        ndarray, shape (n,)
            The scaled and gated recording.

        Warns
        -----
        AudioWarning
            The speech level is more than :data:`MAX_GAIN_DB` under :attr:`level_db` (raised by
            that much and still quiet).
        """
        self.reset()
        x = np.asarray(x, dtype=np.float64)
        level = self.input_level_db if self.input_level_db is not None else speech_level_db(x, self.rate)
        if np.isfinite(level) and self.level_db - level > MAX_GAIN_DB:
            warnings.warn(f"audio: the speech level is {level:.0f} dBFS, {self.level_db - level:.0f} dB under the "
                          f"puppet's {self.level_db:g}: raised by {MAX_GAIN_DB:g} dB, the most, and still quiet "
                          "(a recording of almost nothing? check the file or the microphone's gain)",
                          AudioWarning, stacklevel=2)
        return self._release(x * self.gain(level), last=True)

    def push(self, x: np.ndarray) -> np.ndarray:
        """Feed the next chunk of a stream.

        Parameters
        ----------
        x : array_like, shape (n,)
            The next samples.

        Returns
        -------
        ndarray, shape (m,)
            The samples of the gate frames completed so far, scaled and gated (fewer than
            pushed while a frame waits for its end: :attr:`delay_s`).
        """
        x = np.asarray(x, dtype=np.float64)
        if self.input_level_db is not None:
            g = self.gain(self.input_level_db)
        else:
            g = self.gain(self._estimate()) if self._heard >= LEVEL_SETTLE_S * self.rate else 1.0
            self._count(x)
        return self._release(x * g, last=False)

    def flush(self) -> np.ndarray:
        """End of the stream: the last (partial) gate frame; then reset.

        Returns
        -------
        ndarray, shape (m,)
            The samples not yet returned, scaled and gated.
        """
        out = self._release(np.zeros(0), last=True)
        self.reset()
        return out

    def reset(self) -> None:
        """Forget the stream (and restart the dither)."""
        self._rng = np.random.default_rng(_LEVEL_SEED)
        self._hist = np.zeros(_HIST_N, dtype=np.int64)
        self._partial = np.zeros(0)
        self._pending = np.zeros(0)
        self._heard = 0

    def _release(self, y: np.ndarray, last: bool) -> np.ndarray:
        """The complete gate frames of the pending samples and ``y`` (scaled samples, ours to
        change), the quiet ones turned into dither; the rest waits (all of it when ``last``)."""
        buf = y if not self._pending.size else np.concatenate([self._pending, y])
        m = self._gate
        done = buf.size if last else buf.size // m * m
        out, self._pending = buf[:done], buf[done:].copy()
        if done:
            k = done // m
            power = _frame_power(out[:k * m], m)
            sizes = np.full(k, m)
            if done > k * m:  # the last, partial frame of a recording
                power = np.append(power, np.mean(out[k * m:] ** 2))
                sizes = np.append(sizes, done - k * m)
            mask = np.repeat(power < 10.0 ** ((self.level_db - GATE_BELOW_DB) / 10.0), sizes)
            # drawn for the gated samples in time order: a recording and a stream of it alike
            out[mask] = (10.0 ** ((self.level_db - DITHER_BELOW_DB) / 20.0)
                         * self._rng.standard_normal(int(np.count_nonzero(mask))))
        return out

    def _count(self, x: np.ndarray) -> None:
        buf = np.concatenate([self._partial, x])
        k = buf.size // self._frame
        if k:
            power = _frame_power(buf[: k * self._frame], self._frame)
            db = 10.0 * np.log10(np.maximum(power, 1e-16))
            bins = np.clip(((db - _HIST_LO) / _HIST_STEP).astype(np.int64), 0, _HIST_N - 1)
            self._hist += np.bincount(bins, minlength=_HIST_N)
        self._partial = buf[k * self._frame:]
        self._heard += x.size

    def _estimate(self) -> float:
        total = int(self._hist.sum())
        if total == 0:
            return -np.inf
        k = int(np.searchsorted(np.cumsum(self._hist), LEVEL_PERCENTILE / 100.0 * total))
        db = _HIST_LO + (k + 0.5) * _HIST_STEP
        return db if db > -150.0 else -np.inf


class StreamingFeatures:
    """The audio front end on a stream: push chunks, get the finished feature frames.

    Parameters
    ----------
    features : FeatureSet, str or list of str
        The feature set (default ``"puppet"``); every feature must be in ``STREAMABLE``.
    fps : float
        Output frame rate; frame ``k`` is centred at ``k / fps`` (time 0 = the first sample).
    rate : int
        Sample rate of the pushed samples (the analysis rate; 16000 for puppets trained on
        loaded audio). Use :class:`StreamResampler` in front for other rates.
    formant_lag : int or None
        Bound (frames) on how long a formant decision may wait; None: exact (offline) formants
        with data-dependent latency.
    input_level_db : float or None
        With the ``level_db`` option: the stream's speech level if known (dBFS;
        :func:`speech_level_db`), so it is scaled as :meth:`process` scales a recording of that
        level; None: estimated from what has been heard (:class:`LevelNormalizer`).
    **options
        Overrides of ``DEFAULT_OPTIONS``, as for :func:`voicepuppet.audio.extract`.

    Attributes
    ----------
    names : tuple of str
        Column names (those of ``extract`` for the same set).
    frames_out : int
        Frames emitted so far.
    fset : FeatureSet
        The feature set, with ``options`` applied.
    fps : float
        Output frame rate.
    rate : int
        Sample rate (Hz).
    formant_lag : int or None
        As given.
    opt : dict
        All options in force (:meth:`FeatureSet.settings`).
    want : set of str
        The features computed.

    Raises
    ------
    ValueError
        A feature that is not streamable, an unknown feature or option, ``fps`` not positive
        and finite, ``rate`` not a whole number of Hz >= ``MIN_RATE``, or ``formant_lag`` not
        None or a whole number >= 0.
    """

    def __init__(self, features="puppet", fps: float = 29.97, rate: int = 16000,
                 formant_lag: int | None = None, input_level_db: float | None = None, **options):
        fps = check_fps(fps)
        fset = as_feature_set(features)
        if options:
            fset = FeatureSet(fset.features, {**fset.options, **options}, fset.name)
        bad = [f for f in fset.features if f not in STREAMABLE]
        if bad:
            raise ValueError(f"stream: feature(s) {', '.join(bad)} cannot be computed on a stream "
                             f"(they need the whole recording); streamable features are "
                             f"{', '.join(STREAMABLE)}. Train the puppet with a set of those "
                             "(e.g. 'puppet' or 'mfcc')")
        try:
            rate_i = int(rate)
        except (TypeError, ValueError):
            raise ValueError(f"stream: rate must be a whole number of Hz, got {rate!r}") from None
        if rate_i != rate or rate_i < MIN_RATE:
            raise ValueError(f"stream: rate must be a whole number of Hz >= {MIN_RATE}, got "
                             f"{rate!r}")
        if formant_lag is not None and (not isinstance(formant_lag, (int, np.integer))
                                        or isinstance(formant_lag, bool) or formant_lag < 0):
            raise ValueError(f"stream: formant_lag must be None or a whole number of frames >= 0,"
                             f" got {formant_lag!r}")
        self.fset, self.fps, self.rate = fset, fps, rate_i
        self.formant_lag = None if formant_lag is None else int(formant_lag)
        self.opt = fset.settings()
        self.want = set(fset.features)
        self._options = core_options(fset, fps, rate_i, self.formant_lag)
        self._core = _core.StreamingAudioFeatures(self._options)
        self._level = (None if self.opt["level_db"] is None
                       else LevelNormalizer(self.opt["level_db"], rate_i, input_level_db))
        self._band = None if self.opt["band_hz"] is None else BandLimiter(self.opt["band_hz"], rate_i)
        self._names = column_names(fset)
        if len(self._names) != self._core.n_features:  # a bug: the two lists must agree
            raise AssertionError("stream: column names and core features disagree")

    @property
    def names(self) -> tuple:
        """Column names (those of ``extract`` for the same set)."""
        return self._names

    @property
    def n_features(self) -> int:
        """Number of columns D."""
        return len(self._names)

    @property
    def samples_in(self) -> int:
        """Samples pushed so far."""
        return int(self._core.samples_in)

    @property
    def frames_out(self) -> int:
        """Frames emitted so far."""
        return int(self._core.frames_out)

    @property
    def formants_forced(self) -> int:
        """Frames whose formants were forced by ``formant_lag`` (0 in exact mode)."""
        return int(self._core.formants_forced)

    def lookahead_s(self) -> float:
        """Seconds of audio after a frame's centre needed before the frame can be computed
        (the right half of the longest analysis window; formants add their tracker's wait,
        bounded by ``formant_lag`` frames when that is set; ``band_hz`` adds its resamplers'
        half filters, :attr:`BandLimiter.delay_s`, and ``level_db`` its gate frame,
        :attr:`LevelNormalizer.delay_s`).

        Returns
        -------
        float
            The look-ahead in seconds.
        """
        o, la = self._options, 0.0
        if self.want & {"mfcc", "mfcc_deltas", "rasta_plp", "bands", "log_energy"}:
            la = max(la, (o.n_fft - o.n_fft // 2) / self.rate)
            if "mfcc_deltas" in self.want:
                la += self.opt["delta_width"] / self.fps
        if self.want & {"lpc", "lpc_cepstra"}:
            n = o.lpc_window.shape[0]
            la = max(la, (n - n // 2) / self.rate)
        if "formants" in self.want:
            n = o.formant_window.shape[0]
            fl = (n - n // 2) / o.formant_rate + 0.002  # + resampler taps
            if self.formant_lag is not None:
                fl += self.formant_lag / self.fps
            la = max(la, fl)
        return (la + (0.0 if self._band is None else self._band.delay_s)
                + (0.0 if self._level is None else self._level.delay_s))

    def push(self, samples) -> np.ndarray:
        """Feed a chunk of samples (any length, including 0).

        Parameters
        ----------
        samples : array_like, shape (n,) or (n, channels)
            Float samples in full scale, or integer PCM (scaled by its type's range).

        Returns
        -------
        ndarray, shape (K, D)
            The frames completed by this chunk (K >= 0), in order.

        Raises
        ------
        ValueError
            Samples that are not numbers, not of shape (n,) or (n, channels), or not finite.
        """
        x = pcm_to_float(samples)
        if self._level is not None:
            x = self._level.push(x)
        return self._core.push(x if self._band is None else self._band.push(x))

    def flush(self) -> np.ndarray:
        """End of the stream: the remaining frames, up to ``ceil(n_samples * fps / rate)`` in
        total (windows past the end see zeros, as offline). Then the object is reset.

        Returns
        -------
        ndarray, shape (K, D)
            The frames not yet returned, in order.
        """
        rows = []
        if self._level is not None:
            tail = self._level.flush()
            rows.append(self._core.push(tail if self._band is None else self._band.push(tail)))
        if self._band is not None:
            rows.append(self._core.push(self._band.flush()))
        rows.append(self._core.flush())
        return np.vstack(rows) if len(rows) > 1 else rows[0]

    def process(self, samples, n_out: int | None = None) -> np.ndarray:
        """A whole recording in one call (the offline front end). Resets the stream before and
        after.

        Parameters
        ----------
        samples : array_like, shape (n,) or (n, channels)
            The recording: float samples in full scale, or integer PCM.
        n_out : int, optional
            Number of frames (default ``ceil(n * fps / rate)``; frames past the end see
            silence).

        Returns
        -------
        ndarray, shape (n_out, D)
            The feature frames.

        Raises
        ------
        ValueError
            Samples that are not numbers, not of shape (n,) or (n, channels), or not finite.
        """
        x = pcm_to_float(samples)
        T = n_frames(x.shape[0], self.rate, self.fps) if n_out is None else int(n_out)
        if self._level is not None:
            x = self._level.apply(x)
        return self._core.process(x if self._band is None else self._band.apply(x), T)

    def reset(self) -> None:
        """Forget the stream (a new stream starts at time 0)."""
        self._core.reset()
        if self._level is not None:
            self._level.reset()
        if self._band is not None:
            self._band.reset()
