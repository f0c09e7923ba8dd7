"""Signal conditioning for the audio front end, offline and streamed: PCM to float, polyphase
resampling on a stream (:class:`StreamResampler`), band limiting (:class:`BandLimiter`) and the
speech-level normalisation and pause gate every recording a puppet hears goes through
(:class:`LevelNormalizer`, :func:`speech_level_db`).
"""

from __future__ import annotations

import warnings
from fractions import Fraction

import numpy as np

from voicepuppet import _core
from voicepuppet.audio.featureset import check_level_db
from voicepuppet.audio.loading import AudioWarning, resample_taps

__all__ = ["pcm_to_float", "resample_taps", "StreamResampler", "BandLimiter", "speech_level_db", "LevelNormalizer",
           "LEVEL_FRAME_S", "LEVEL_PERCENTILE", "MAX_GAIN_DB", "GATE_FRAME_S", "GATE_BELOW_DB", "DITHER_BELOW_DB",
           "LEVEL_SETTLE_S"]

_HIST_LO, _HIST_STEP, _HIST_N = -160.0, 0.25, 800  # frame powers, dBFS: -160 .. +40


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
