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

from fractions import Fraction

import numpy as np

from voicepuppet import _core
from voicepuppet.audio import lpc as lpc_mod
from voicepuppet.audio import spectral
from voicepuppet.audio.featureset import FeatureSet, analysis_window_s, as_feature_set
from voicepuppet.audio.framing import check_fps, n_frames
from voicepuppet.audio.conditioning import BandLimiter, LevelNormalizer, pcm_to_float, resample_taps
from voicepuppet.audio.loading import MIN_RATE

#: Features the stream can produce.
STREAMABLE = ("lpc", "lpc_cepstra", "rasta_plp", "mfcc", "mfcc_deltas", "formants", "bands",
              "log_energy")

__all__ = ["StreamingFeatures", "STREAMABLE", "core_options", "column_names"]


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
