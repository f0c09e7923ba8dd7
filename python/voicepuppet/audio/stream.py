"""Streaming audio features: the front end fed chunks of any size.

:class:`StreamingFeatures` takes samples in chunks of any size (one sample to many seconds) and
returns the feature frames whose analysis windows are complete. The frames are those of the
offline front end (:func:`voicepuppet.audio.extract` on the concatenated samples, without its
DC removal: ``extract(prepare(x, rate, target_rate=None, remove_dc=False))``), computed by the
same code on the same windows, so they agree to rounding (tested to 1e-9; the formant tracker's
decisions are the offline ones exactly):

- spectral features (``mfcc``, ``bands``, ``log_energy``, ``rasta_plp``) and LPC features are
  per-window computations: frame ``k`` is ready once the sample at the right edge of its window
  has arrived (12.5 ms after its centre with the default 25 ms window);
- RASTA filtering is a recursive filter along time: its state is carried between chunks and it
  starts, like the offline filter, in the steady state of the first frame;
- ``mfcc_deltas`` need ``delta_width`` frames of look-ahead (edges replicated at the end);
- formants are resampled with the offline polyphase filter (a streaming ``upfirdn`` with the
  same taps), and their continuity tracker (a Viterbi over candidate triples) runs online: a
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

import math
from fractions import Fraction

import numpy as np

from .featureset import FeatureSet, as_feature_set
from .framing import check_fps, hamming, n_frames
from .loading import MIN_RATE

#: Features the stream can produce.
STREAMABLE = ("lpc", "lpc_cepstra", "rasta_plp", "mfcc", "mfcc_deltas", "formants", "bands",
              "log_energy")

__all__ = ["StreamingFeatures", "StreamResampler", "STREAMABLE", "pcm_to_float"]


def pcm_to_float(samples) -> np.ndarray:
    """Samples as float64 full scale, shape (n,): integer PCM is scaled by its type's range (as
    :func:`voicepuppet.audio.prepare` does), floats are taken as they are.

    Raises
    ------
    ValueError
        Not numbers, not one-dimensional, or NaN / infinite samples.
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
    return x


def _levinson(r: np.ndarray, order: int):
    """``lpc.levinson`` (same operations, same order) for a few frames: a scalar loop per row
    is ~10x faster than the vectorised recursion on 1-3 rows."""
    from .lpc import ENERGY_FLOOR, WHITE_NOISE_CORRECTION, levinson

    if r.shape[0] > 4:
        return levinson(r, order)
    T = r.shape[0]
    A = np.zeros((T, order + 1))
    E = np.empty(T)
    for t in range(T):
        rt = r[t].tolist()
        err = rt[0] * (1.0 + WHITE_NOISE_CORRECTION) + ENERGY_FLOOR
        a = [1.0] + [0.0] * order
        for i in range(1, order + 1):
            acc = rt[i]
            if i > 1:
                acc += sum(a[j] * rt[i - j] for j in range(1, i))
            k = -acc / err
            if i > 1:
                prev = a[:]
                for j in range(1, i):
                    a[j] = prev[j] + k * prev[i - j]
            a[i] = k
            err = err * (1.0 - k * k)
        A[t] = a
        E[t] = max(err, ENERGY_FLOOR * 1e-3)
    return A, E


def _cepstrum(a: np.ndarray, err: np.ndarray, n_ceps: int) -> np.ndarray:
    """``lpc.lpc_to_cepstrum`` (same recursion) for a few frames, as a scalar loop."""
    from .lpc import lpc_to_cepstrum

    if a.shape[0] > 4:
        return lpc_to_cepstrum(a, err, n_ceps)
    T, p1 = a.shape
    p = p1 - 1
    out = np.zeros((T, n_ceps))
    for t in range(T):
        at = a[t].tolist()
        c = [math.log(float(err[t]))] + [0.0] * (n_ceps - 1)
        for n in range(1, n_ceps):
            acc = -at[n] if n <= p else 0.0
            for k in range(max(1, n - p), n):
                acc = acc - (k / n) * c[k] * at[n - k]
            c[n] = acc
        out[t] = c
    return out


def _plp(bands: np.ndarray, centres_hz: np.ndarray, order: int, n_ceps: int) -> np.ndarray:
    """``spectral.plp_from_bands`` with the small-batch recursions."""
    from .spectral import plp_from_bands

    return plp_from_bands(bands, centres_hz, order, n_ceps, solve=_levinson, to_cepstrum=_cepstrum)


class _Signal:
    """A growing signal with zeros before index 0, trimmed from the left as frames are done.

    Chunks are collected in a list and joined only when samples are read, so pushing many tiny
    chunks costs O(1) each.
    """

    def __init__(self, pad: int):
        self.pad = int(pad)
        self.buf = np.zeros(self.pad)
        self.parts: list = []
        self.offset = -self.pad  # global index of buf[0]
        self.n = 0               # samples received (global indices 0 .. n-1)

    def append(self, x: np.ndarray) -> None:
        if x.shape[0]:
            self.parts.append(x)
            self.n += x.shape[0]

    def _join(self) -> None:
        if self.parts:
            self.buf = np.concatenate([self.buf] + self.parts)
            self.parts = []

    def get(self, start: int, stop: int) -> np.ndarray:
        """Global samples ``start .. stop - 1``; zeros past the end (stream ended)."""
        self._join()
        a, b = start - self.offset, stop - self.offset
        if a < 0:
            raise AssertionError("stream: requested samples already discarded")  # a bug
        out = self.buf[a:b]
        if out.shape[0] < b - a:
            out = np.concatenate([out, np.zeros(b - a - out.shape[0])])
        return out

    def trim(self, keep_from: int) -> None:
        """Forget samples before global index ``keep_from``."""
        cut = keep_from - self.offset
        if cut > 4096 and cut <= self.buf.shape[0]:
            self.buf = self.buf[cut:]
            self.offset = keep_from


class StreamResampler:
    """``scipy.signal.resample_poly(x, up, down)`` computed chunk by chunk.

    The same taps (Kaiser-windowed sinc, ``half_len = 10 max(up, down)``) are applied by
    ``scipy.signal.upfirdn`` to a sliding segment of the input; output samples are released once
    every input sample under their filter has arrived, and ``flush`` finishes the stream with
    the zero padding of the offline call, so the concatenated output equals ``resample_poly`` on
    the concatenated input (to rounding; same length ``ceil(n up / down)``).

    Parameters
    ----------
    rate_in, rate_out : int
        Sample rates in Hz.
    """

    def __init__(self, rate_in: int, rate_out: int):
        from scipy.signal import firwin

        frac = Fraction(int(rate_out), int(rate_in))
        self.up, self.down = frac.numerator, frac.denominator
        self.identity = self.up == self.down == 1
        up, down = self.up, self.down
        half_len = 10 * max(up, down)
        h = firwin(2 * half_len + 1, 1.0 / max(up, down), window=("kaiser", 5.0)) * up
        n_pre_pad = down - half_len % down
        self.h = np.concatenate([np.zeros(n_pre_pad), h])
        self.pre_remove = (half_len + n_pre_pad) // down
        # input alignment: segments start at multiples of `align` so that the segment's output
        # grid coincides with the global one
        self.align = down // math.gcd(up, down)
        self.sig = _Signal(0)
        self.done = 0  # outputs (after removal) released so far

    def _compute(self, j0: int, j1: int, n_total: int | None) -> np.ndarray:
        """Outputs ``j0 .. j1 - 1`` (after the offline removal of ``pre_remove``)."""
        from scipy.signal import upfirdn

        if j1 <= j0:
            return np.zeros(0)
        up, down, L = self.up, self.down, self.h.shape[0]
        g0, g1 = j0 + self.pre_remove, j1 + self.pre_remove  # indices into the full upfirdn
        lo = max(0, -(-(g0 * down - L + 1) // up))
        lo -= lo % self.align
        # inputs up to (g1 - 1) down / up contribute; zeros after them (past the end of the
        # stream they are the offline zero padding; before it they only reach later outputs)
        hi = g1 * down // up + 1 + L // up + 1
        seg = self.sig.get(lo, hi)
        y = upfirdn(self.h, seg, up, down)
        m0 = g0 - lo * up // down
        out = y[m0:m0 + (j1 - j0)]
        if out.shape[0] != j1 - j0:
            raise AssertionError("resampler: segment too short")  # a bug
        return out

    def push(self, x: np.ndarray) -> np.ndarray:
        """Feed input samples; returns the output samples completed by them."""
        self.feed(x)
        return self.pull()

    def feed(self, x: np.ndarray) -> None:
        """Queue input samples without computing (see ``pull``)."""
        self.sig.append(np.asarray(x, dtype=np.float64))

    def pull(self) -> np.ndarray:
        """The output samples completed by the input fed so far and not yet returned."""
        if self.identity:
            out = self.sig.get(self.done, self.sig.n).copy()
            self.done = self.sig.n
            self.sig.trim(self.done)
            return out
        # output g (full index) needs inputs i <= g * down / up
        ready_full = (self.sig.n * self.up - 1) // self.down + 1 if self.sig.n else 0
        j1 = max(self.done, ready_full - self.pre_remove)
        out = self._compute(self.done, j1, None)
        self.done = j1
        self._trim()
        return out

    def flush(self) -> np.ndarray:
        """End of input: the remaining outputs (``ceil(n up / down)`` in total); then reset."""
        if self.identity:
            out = self.pull()
            self.sig = _Signal(0)
            self.done = 0
            return out
        n = self.sig.n
        total = -(-n * self.up // self.down)
        out = self._compute(self.done, total, n)
        self.sig = _Signal(0)
        self.done = 0
        return out

    def _trim(self):
        g0 = self.done + self.pre_remove
        lo = max(0, -(-(g0 * self.down - self.h.shape[0] + 1) // self.up))
        self.sig.trim(lo - lo % self.align)


class _Framer:
    """Windows of one length centred on a frame grid over a :class:`_Signal`.

    Frame ``k`` holds ``y[c_k - length // 2 : ... + length]`` with ``c_k = rint(k rate / fps)``
    and ``y`` pre-emphasised, times ``window``: the frames of ``framing.iter_frames``.
    """

    def __init__(self, rate: float, fps: float, length: int, window, preemph: float = 0.0):
        self.rate, self.fps, self.length = rate, fps, int(length)
        self.window, self.preemph = window, float(preemph)
        self.half = self.length // 2
        self.next = 0  # next frame to produce

    def centre(self, k):
        return np.rint(np.asarray(k, dtype=np.float64) * (self.rate / self.fps)).astype(np.int64)

    def ready(self, n_avail: int, limit: int | None = None) -> int:
        """Number of frames (from 0) whose window ends before sample ``n_avail`` (or all up to
        ``limit`` when the stream has ended)."""
        if limit is not None:
            return limit
        # right edge c_k - half + length - 1 < n_avail  <=>  c_k < n_avail + half - length + 1
        bound = n_avail + self.half - self.length + 1
        k = max(0, int(math.floor((bound - 0.5) * self.fps / self.rate)) + 2)
        while k > 0 and self.centre(k - 1) >= bound:
            k -= 1
        return k

    def frames(self, sig: _Signal, k0: int, k1: int) -> np.ndarray:
        c = self.centre(np.arange(k0, k1))
        starts = c - self.half
        pre = 1 if self.preemph else 0
        lo = int(starts[0]) - pre
        seg = sig.get(lo, int(starts[-1]) + self.length)
        view = np.lib.stride_tricks.sliding_window_view(seg, self.length + pre)
        raw = view[starts - int(starts[0])]
        if self.preemph:
            fr = raw[:, 1:] - self.preemph * raw[:, :-1]
        else:
            fr = raw.copy()
        if self.window is not None:
            fr *= self.window
        return fr

    def first_needed(self) -> int:
        """Lowest global sample index the next frame needs."""
        return int(self.centre(self.next)) - self.half - 1


class _FormantTracker:
    """Online version of ``lpc.track_formants`` (same costs, same tie-breaking).

    Frames become final when every surviving path agrees on them (then the offline Viterbi
    path agrees too), and gap frames (chosen assignment invalid) once the next valid frame is
    final (linear interpolation, as ``np.interp``). ``max_delay`` (frames, or None) forces a
    decision for frames pending longer than that.
    """

    def __init__(self, n_formants: int, ceiling: float, n_cand: int, max_delay: int | None):
        from itertools import combinations

        from .lpc import reference_formants

        self.n = n_formants
        self.ref = reference_formants(ceiling, n_formants)
        self.combos = np.array(list(combinations(range(n_cand), n_formants)), dtype=np.int64)
        self.S = self.combos.shape[0]
        self.max_delay = max_delay
        self.score = None
        self.t = 0              # frames pushed
        self.base = 0           # global frame index of pending[0]
        self.F, self.valid, self.back = [], [], []  # per pending frame (from base)
        self.prev_logF = self.prev_valid = None
        # decided assignments awaiting output: (frame, values or None for a gap frame)
        self.decided: list = []
        self.out_next = 0       # next frame to output
        self.last_good = None   # (frame, values) of the last valid decided frame
        self.any_good = False
        self.forced = 0         # frames whose output was forced by max_delay

    def push(self, freqs: np.ndarray, bands: np.ndarray) -> list:
        """Candidates of new frames (K, n_cand) each; returns finished rows [(n,), ...]."""
        out = []
        for f, b in zip(freqs, bands):
            self._step(f, b)
            self._decide_converged()
            out += self._emit(final=False)
        return out

    def _step(self, f, b):
        F = f[self.combos]      # (S, n)
        B = b[self.combos]
        valid = np.all(np.isfinite(F), axis=1)
        with np.errstate(invalid="ignore"):
            local = 1.0 * np.sum(np.abs(F - self.ref) / self.ref, axis=1) + \
                1.0 * np.sum(B / F, axis=1)
        local = np.where(valid, local, 1e6)
        logF = np.log(np.where(np.isfinite(F), F, 1.0))
        if self.score is None:
            self.score = local.copy()
            back = np.zeros(self.S, dtype=np.int64)
        else:
            trans = 1.0 * np.sum(np.abs(logF[None, :, :] - self.prev_logF[:, None, :]), axis=2)
            both = self.prev_valid[:, None] & valid[None, :]
            trans = np.where(both, trans, 0.0)
            tot = self.score[:, None] + trans
            back = np.argmin(tot, axis=0)
            self.score = tot[back, np.arange(self.S)] + local
        self.prev_logF, self.prev_valid = logF, valid
        self.F.append(F)
        self.valid.append(valid)
        self.back.append(back)
        self.t += 1

    def _trace(self, end_states):
        """Backtrack from states at the last pushed frame; returns paths (len(pending), k)."""
        P = len(self.back)
        paths = np.empty((P, len(end_states)), dtype=np.int64)
        cur = np.asarray(end_states, dtype=np.int64)
        paths[-1] = cur
        for i in range(P - 1, 0, -1):
            cur = self.back[i][cur]
            paths[i - 1] = cur
        return paths

    def _commit(self, states):
        """Pending frames 0 .. len(states) - 1 take `states`; drop them from pending."""
        for i, s in enumerate(states):
            good = bool(self.valid[i][s])
            self.decided.append((self.base + i, self.F[i][s].copy() if good else None))
        k = len(states)
        del self.F[:k], self.valid[:k], self.back[:k]
        self.base += k

    def _decide_converged(self):
        if len(self.back) <= 1:
            return
        paths = self._trace(np.arange(self.S))
        same = np.all(paths == paths[:, :1], axis=1)
        # frames 0 .. u all agree (agreement at u implies agreement before u)
        nz = np.nonzero(same)[0]
        if nz.shape[0] == 0:
            return
        u = int(nz[-1])
        if u < len(self.back) - 1:
            self._commit(paths[:u + 1, 0])
        # the last pending frame stays (its back pointers are needed for the next frame)

    def _emit(self, final: bool) -> list:
        out = []
        while self.decided:
            frame, val = self.decided[0]
            if frame != self.out_next:
                raise AssertionError("formant tracker out of order")  # a bug
            if val is not None:
                self._fill_gap_to(frame, val, out)
                out.append(val)
                self.last_good = (frame, val)
                self.any_good = True
                self.decided.pop(0)
                self.out_next += 1
                continue
            # a gap frame: needs the next good frame (or the end of the stream)
            nxt = next((d for d in self.decided if d[1] is not None), None)
            if nxt is not None:
                self._fill_gap_to(nxt[0], nxt[1], out)
                continue
            if final:
                self.decided.pop(0)
                out.append(self.last_good[1].copy() if self.last_good is not None
                           else None)  # None: no good frame at all (resolved by caller)
                self.out_next += 1
                continue
            if self.max_delay is not None and self.t - 1 - frame >= self.max_delay:
                self.decided.pop(0)
                out.append(self.last_good[1].copy() if self.last_good is not None
                           else self.ref.copy())
                self.forced += 1
                self.out_next += 1
                continue
            break
        return out

    def _fill_gap_to(self, frame, val, out):
        """Emit the decided gap frames before `frame` (a good frame with values `val`)."""
        while self.decided and self.decided[0][0] < frame:
            g, _ = self.decided.pop(0)
            if self.last_good is None:
                out.append(val.copy())  # leading gap: np.interp holds the first value
            else:
                x0, f0 = self.last_good
                out.append(np.array([np.interp(g, [x0, frame], [f0[i], val[i]])
                                     for i in range(self.n)]))
            self.out_next += 1

    def force(self):
        """Apply max_delay to frames still on undecided paths."""
        if self.max_delay is None or not self.back:
            return []
        if self.t - 1 - self.base < self.max_delay:
            return []
        # decide the frames that have waited max_delay frames, from the current best path
        # (the last frame too when max_delay is 0: later tracebacks stop at the decided frames)
        paths = self._trace([int(np.argmin(self.score))])[:, 0]
        k = min(len(paths), (self.t - 1 - self.max_delay) - self.base + 1)
        if k <= 0:
            return []
        self.forced += k
        self._commit(paths[:k])
        return self._emit(final=False)

    def finish(self) -> list:
        """End of stream: the best path from the last frame decides the rest."""
        out = []
        if self.back:
            paths = self._trace([int(np.argmin(self.score))])[:, 0]
            self._commit(paths)
        rows = self._emit(final=True)
        if rows and any(r is None for r in rows):
            if self.any_good:
                raise AssertionError("formant tracker: gap without a good frame")  # a bug
            rows = [self.ref.copy() for _ in rows]
        out += rows
        return out


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
    **options
        Overrides of ``DEFAULT_OPTIONS``, as for :func:`voicepuppet.audio.extract`.

    Attributes
    ----------
    names : tuple of str
        Column names (those of ``extract`` for the same set).
    frames_out : int
        Frames emitted so far.
    """

    def __init__(self, features="puppet", fps: float = 29.97, rate: int = 16000,
                 formant_lag: int | None = None, **options):
        from . import lpc as lpc_mod
        from . import spectral

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
                                        or formant_lag < 0):
            raise ValueError(f"stream: formant_lag must be None or a whole number of frames >= 0,"
                             f" got {formant_lag!r}")
        self.fset, self.fps, self.rate = fset, fps, rate_i
        opt = fset.settings()
        self.opt = opt
        want = set(fset.features)
        self.want = want
        window_s = float(opt["window_s"]) if opt["window_s"] else max(0.025, 1.0 / fps)
        self.sig = _Signal(8192)
        self.groups = []  # (name, framer, fine factor)
        names: dict[str, list] = {}

        # spectral pass
        self.spec_want = want & {"mfcc", "mfcc_deltas", "rasta_plp", "bands", "log_energy"}
        if self.spec_want:
            n_fft, win, freqs, parseval = spectral.analysis_window(window_s, rate_i, opt["n_fft"] or None)
            self.parseval = parseval
            m = max(1, int(round(100.0 / fps))) if "rasta_plp" in want else 1
            self.m = m
            self.spec = _Framer(rate_i, fps * m, n_fft, win)
            if want & {"mfcc", "mfcc_deltas"}:
                self.melfb = spectral.mel_filterbank(rate_i, n_fft, opt["n_mels"])
            if "bands" in want:
                bands = spectral.SONORANT_BANDS
                self.band_w = np.zeros((len(bands), freqs.shape[0]))
                for i, (lo, hi) in enumerate(bands):
                    self.band_w[i] = ((freqs >= lo) & (freqs < hi)) * parseval
            if "rasta_plp" in want:
                self.barkfb, self.bark_centres = spectral.bark_filterbank(rate_i, n_fft)
                self.rasta_zi = None
                self.rasta_b = np.array([0.2, 0.1, 0.0, -0.1, -0.2])
                self.rasta_a = np.array([1.0, -(0.94 ** (100.0 / (fps * m)))])
            self.spec_rows: list = []
            self.mfcc_hist: list = []   # mfcc rows still needed for deltas
            self.mfcc_base = 0          # frame index of mfcc_hist[0]
            self.mfcc_done = 0          # next frame whose delta is due
        # LPC
        if want & {"lpc", "lpc_cepstra"}:
            order = int(opt["lpc_order"])
            length = max(order + 1, int(round(window_s * rate_i)))
            self.lpc = _Framer(rate_i, fps, length, hamming(length), opt["lpc_preemph"])
            self.lpc_rows: list = []
        # formants
        if "formants" in want:
            ceiling = float(opt["formant_ceiling"])
            fs = int(round(2 * ceiling))
            if fs > rate_i:
                fs = rate_i
            self.f_rate = fs
            self.resampler = StreamResampler(rate_i, fs)
            self.fsig = _Signal(8192)
            n_formants = 3
            self.f_order = 2 * (n_formants + 2)
            length = max(self.f_order + 1, int(round(0.05 * fs)))
            self.fmt = _Framer(fs, fps, length, lpc_mod.gaussian_window(length),
                               math.exp(-2.0 * math.pi * 50.0 / fs))
            self.tracker = _FormantTracker(n_formants, fs / 2.0, (self.f_order + 1) // 2,
                                           formant_lag)
            self.fmt_rows: list = []
        self.formant_lag = formant_lag
        self._next_due = 0
        self.frames_out = 0
        self._ended = False
        self._names = self._column_names()

    # ------------------------------------------------------------------ public
    @property
    def names(self) -> tuple:
        return self._names

    @property
    def n_features(self) -> int:
        return len(self._names)

    @property
    def samples_in(self) -> int:
        """Samples pushed so far."""
        return self.sig.n

    def lookahead_s(self) -> float:
        """Seconds of audio after a frame's centre needed before the frame can be computed
        (the right half of the longest analysis window; formants add their tracker's wait,
        bounded by ``formant_lag`` frames when that is set)."""
        la = 0.0
        if self.spec_want:
            la = max(la, (self.spec.length - self.spec.half) / self.rate)
            if "mfcc_deltas" in self.want:
                la += self.opt["delta_width"] / self.fps
        if self.want & {"lpc", "lpc_cepstra"}:
            la = max(la, (self.lpc.length - self.lpc.half) / self.rate)
        if "formants" in self.want:
            fl = (self.fmt.length - self.fmt.half) / self.f_rate + 0.002  # + resampler taps
            if self.formant_lag is not None:
                fl += self.formant_lag / self.fps
            la = max(la, fl)
        return la

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
        """
        if self._ended:
            raise ValueError("stream: push after flush; create a new StreamingFeatures (or call "
                             "reset()) for a new stream")
        x = pcm_to_float(samples)
        self.sig.append(x)
        if "formants" in self.want:
            self.resampler.feed(x)
        if self.sig.n < self._next_due:  # no window can have completed: nothing to do
            return np.zeros((0, self.n_features))
        rows = self._advance(None)
        self._next_due = self._due()
        return rows

    def _due(self) -> int:
        """Samples received at which the next push has work to do: the window of the next
        formant frame is full (the tracker advances one frame at a time; the other features are
        computed in the same call, batched), or, without formants, every feature's window of the
        next output frame is."""
        if "formants" in self.want:
            fr, r = self.fmt, self.resampler
            last = int(fr.centre(fr.next)) - fr.half + fr.length  # resampled samples
            if r.identity:
                return last
            return -(-((last - 1 + r.pre_remove) * r.down + 1) // r.up)
        due = 0
        target = self.frames_out
        for name, mult in (("spec", getattr(self, "m", 1)), ("lpc", 1)):
            fr = getattr(self, name, None)
            if fr is None:
                continue
            k = target * mult
            if name == "spec" and "mfcc_deltas" in self.want:
                k = (target + int(self.opt["delta_width"])) * mult
            if fr.next > k:
                continue
            due = max(due, int(fr.centre(k)) - fr.half + fr.length)
        return due

    def flush(self) -> np.ndarray:
        """End of the stream: the remaining frames, up to ``ceil(n_samples * fps / rate)`` in
        total (windows past the end see zeros, as offline). Then the object is reset."""
        if self.sig.n == 0:  # nothing was pushed: no frames (and a fresh stream)
            self.reset()
            return np.zeros((0, self.n_features))
        total = n_frames(self.sig.n, self.rate, self.fps)
        if "formants" in self.want:
            self.fsig.append(self.resampler.flush())
        self._ended = True
        rows = self._advance(total)
        self.reset()
        return rows

    def reset(self) -> None:
        """Forget the stream (a new stream starts at time 0)."""
        self.__init__(self.fset, self.fps, self.rate, self.formant_lag)

    # ------------------------------------------------------------------ internals
    def _column_names(self) -> tuple:
        from .featureset import extract, prepare  # noqa: F401  (names follow extract's order)

        opt = self.opt
        cols = {}
        cols["mfcc"] = [f"mfcc{i}" for i in range(opt["n_mfcc"])]
        cols["mfcc_deltas"] = [f"dmfcc{i}" for i in range(opt["n_mfcc"])]
        first = 0 if opt["rasta_c0"] else 1
        cols["rasta_plp"] = [f"rplp{i}" for i in range(first, opt["n_rasta"])]
        cols["bands"] = [f"band{i}" for i in range(4)]
        cols["log_energy"] = ["log_energy"]
        cols["lpc"] = [f"lpc{i}" for i in range(1, int(opt["lpc_order"]) + 1)]
        cols["lpc_cepstra"] = [f"lpcc{i}" for i in range(1, int(opt["n_lpc_cepstra"]) + 1)]
        cols["formants"] = ["f1", "f2", "f3"]
        names = []
        for f in self.fset.features:
            names += cols[f]
        return tuple(names)

    def _advance(self, total: int | None) -> np.ndarray:
        from . import lpc as lpc_mod
        from . import spectral

        want, opt = self.want, self.opt
        if self.spec_want:
            m = self.spec
            k1 = m.ready(self.sig.n, None if total is None else total * self.m)
            if k1 > m.next:
                fr = m.frames(self.sig, m.next, k1)
                self._spectral(fr, m.next, k1, total)
                m.next = k1
            elif total is not None:
                self._spectral(None, m.next, m.next, total)
        if want & {"lpc", "lpc_cepstra"}:
            m = self.lpc
            k1 = m.ready(self.sig.n, total)
            if k1 > m.next:
                fr = m.frames(self.sig, m.next, k1)
                order = int(opt["lpc_order"])
                a, err = _levinson(lpc_mod.autocorrelation(fr, order), order)
                row = []
                if "lpc" in want:
                    row.append(("lpc", a[:, 1:]))
                if "lpc_cepstra" in want:
                    n = int(opt["n_lpc_cepstra"])
                    row.append(("lpc_cepstra", _cepstrum(a, err, n + 1)[:, 1:]))
                self.lpc_rows.append(dict(row))
                m.next = k1
        if "formants" in want:
            if total is None:
                self.fsig.append(self.resampler.pull())
            m = self.fmt
            n_f = self.fsig.n
            k1 = m.ready(n_f, total)
            new = []
            if k1 > m.next:
                fr = m.frames(self.fsig, m.next, k1)
                a, _ = _levinson(lpc_mod.autocorrelation(fr, self.f_order), self.f_order)
                f, b = lpc_mod.formant_candidates(a, self.f_rate,
                                                  max_bandwidth=opt["formant_max_bandwidth"])
                new += self.tracker.push(f, b)
                m.next = k1
            new += self.tracker.force()
            if total is not None:
                new += self.tracker.finish()
            if new:
                self.fmt_rows.append({"formants": np.vstack(new)})
        return self._assemble(total)

    def _spectral(self, fr, k0, k1, total):
        """Spectral rows for fine frames k0 .. k1 - 1 (fr their windowed frames)."""
        from scipy.fft import rfft

        from . import spectral

        want, m = self.want, self.m
        out = {}
        if fr is not None and fr.shape[0]:
            spec = rfft(fr, axis=1)
            P = spec.real ** 2 + spec.imag ** 2
            vid = np.nonzero(np.arange(k0, k1) % m == 0)[0]
            Pv = P[vid]
            if want & {"mfcc", "mfcc_deltas"} and Pv.shape[0]:
                mel = Pv @ self.melfb.T
                mf = spectral.dct_ortho(10.0 * np.log10(np.maximum(mel, spectral.POWER_FLOOR)),
                                        self.opt["n_mfcc"])
                if "mfcc" in want:
                    out["mfcc"] = mf
                if "mfcc_deltas" in want:
                    self.mfcc_hist += list(mf)
            if "bands" in want and Pv.shape[0]:
                out["bands"] = 10.0 * np.log10(Pv @ self.band_w.T + spectral.POWER_FLOOR)
            if "log_energy" in want and Pv.shape[0]:
                out["log_energy"] = (10.0 * np.log10(Pv @ self.parseval + spectral.POWER_FLOOR)
                                     )[:, None]
            if "rasta_plp" in want:
                from scipy.signal import lfilter, lfilter_zi

                logb = np.log(P @ self.barkfb.T + spectral.POWER_FLOOR)
                if self.rasta_zi is None:
                    self.rasta_zi = lfilter_zi(self.rasta_b, self.rasta_a)[:, None] * logb[:1, :]
                filt, self.rasta_zi = lfilter(self.rasta_b, self.rasta_a, logb, axis=0,
                                              zi=self.rasta_zi)
                filt = filt[vid]
                r = _plp(np.exp(filt), self.bark_centres, self.opt["rasta_order"],
                         self.opt["n_rasta"])
                first = 0 if self.opt["rasta_c0"] else 1
                out["rasta_plp"] = r[:, first:]
            if Pv.shape[0] == 0:
                out = {}
        if "mfcc_deltas" in want:
            out_d = self._deltas(total)
            if out_d is not None:
                out["mfcc_deltas"] = out_d
        if out:
            self.spec_rows.append(out)

    def _deltas(self, total):
        """Deltas of the mfcc rows whose +/- width neighbours are known (edges replicated,
        as ``spectral.deltas``); at the end of the stream, all remaining rows."""
        w = int(self.opt["delta_width"])
        base = self.mfcc_base
        n_have = base + len(self.mfcc_hist)
        start = self.mfcc_done
        end = n_have if total is not None else n_have - w
        if end <= start or n_have == 0:
            return None
        X = np.asarray(self.mfcc_hist)
        T = total if total is not None else None
        last = (T - 1) if T is not None else None
        denom = 2.0 * sum(n * n for n in range(1, w + 1))
        t = np.arange(start, end)
        num = np.zeros((end - start, X.shape[1]))
        for n in range(1, w + 1):
            hi = t + n if last is None else np.minimum(t + n, last)
            lo = np.maximum(t - n, 0)
            num += n * (X[hi - base] - X[lo - base])
        self.mfcc_done = end
        keep_from = max(base, end - w)
        self.mfcc_hist = self.mfcc_hist[keep_from - base:]
        self.mfcc_base = keep_from
        return num / denom

    def _assemble(self, total) -> np.ndarray:
        # pool rows per feature
        pools: dict[str, list] = {f: [] for f in self.fset.features}
        for store in ("spec_rows", "lpc_rows", "fmt_rows"):
            for d in getattr(self, store, []):
                for k, v in d.items():
                    pools[k].append(v)
        arrays = {k: (np.vstack(v) if v else np.zeros((0, 1))) for k, v in pools.items()}
        counts = {k: (a.shape[0] if pools[k] else 0) for k, a in arrays.items()}
        n = min(counts.values())
        if total is not None and n != total - self.frames_out:
            raise AssertionError(f"stream: {n} final rows for {total - self.frames_out} frames")
        rows = np.hstack([arrays[f][:n] for f in self.fset.features]) if n else \
            np.zeros((0, self.n_features))
        # keep the surplus
        for store in ("spec_rows", "lpc_rows", "fmt_rows"):
            if not hasattr(self, store):
                continue
            kept = {}
            for d in getattr(self, store):
                for k, v in d.items():
                    kept.setdefault(k, []).append(v)
            setattr(self, store, [{k: np.vstack(v)[n:] for k, v in kept.items()}] if kept else [])
        self.frames_out += n
        self._trim()
        return np.ascontiguousarray(rows, dtype=np.float64)

    def _trim(self):
        need = []
        if self.spec_want:
            need.append(self.spec.first_needed())
        if self.want & {"lpc", "lpc_cepstra"}:
            need.append(self.lpc.first_needed())
        if need:
            self.sig.trim(min(need))
        if "formants" in self.want:
            self.fsig.trim(self.fmt.first_needed())
