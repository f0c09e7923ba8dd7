"""The live puppet: audio in as it is heard, face frames out with a latency you choose.

:class:`LivePuppet` composes the streaming front end (:mod:`voicepuppet.audio.stream`) and the
C++ streaming puppet (``voicepuppet::StreamingPuppet``, ``cpp/include/voicepuppet/streaming.hpp``:
fixed-lag Viterbi or posteriors, then the fixed-lag trajectory solve):

>>> live = LivePuppet(voicepuppet.load("me.vpp"), lag_ms=150)     # doctest: +SKIP
>>> frames = live.push(chunk)          # any number of samples -> LiveFrames (M frames, M >= 0)
>>> frames.points.shape                # (M, P, 2) pixel landmarks                # doctest: +SKIP
>>> rest = live.flush()                # end of the stream: the frames still held back

Latency. A face frame ``k`` shows the sound at time ``k / fps``. It can be emitted once the
analysis windows around that time are full (``window_s``: about 17 ms after it for the spectra,
26 ms for the formants), plus the look-ahead given to the formant tracker, the audio deltas, a
projected puppet's vocal features (``vocal_features="projected"``: ±k frames of audio), the state
decoder and the trajectory solve. A guided puppet's guide (the ridge's prediction of the face from
±k_g frames of audio, docs/puppet.md) looks ahead alongside the projection and the decoder, so
its look-ahead up to theirs costs no latency. ``lag_ms`` is the budget for all of it: the windows
take what they need and the rest (whole frames) is split between the look-aheads (see
:func:`split_lag`).
Below the windows' own look-ahead (``lag_ms`` under ~26 ms) nothing is left to split and the
latency is the windows'.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from voicepuppet import _core
from voicepuppet.audio.stream import StreamingFeatures
from voicepuppet.audio.conditioning import StreamResampler, pcm_to_float
from voicepuppet.puppet import load

#: Sample rate of the analysis (the rate puppets are trained at: load_audio's default).
ANALYSIS_RATE = 16000

__all__ = ["ANALYSIS_RATE", "TRUSTED_GUIDE_WEIGHT", "LiveFrames", "LivePuppet", "split_lag"]


@dataclass
class LiveFrames:
    """Face frames emitted by :meth:`LivePuppet.push` or :meth:`LivePuppet.flush`.

    Its ``len`` is the number of frames M.

    Parameters
    ----------
    first_frame : int
        Output index of the first frame.
    points : ndarray, shape (M, P, 2)
        Pixel landmarks (x, y) at the training mean pose.
    face : ndarray, shape (M, K)
        Face coordinates (parts side by side).
    fps : float
        Output frame rate; frame ``k`` shows the sound at ``k / fps`` seconds.

    Notes
    -----
    Each parameter is kept as the attribute of the same name.
    """

    first_frame: int
    points: np.ndarray
    face: np.ndarray
    fps: float

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def frames(self) -> np.ndarray:
        """Output indices, shape (M,)."""
        return np.arange(self.first_frame, self.first_frame + len(self))

    @property
    def times(self) -> np.ndarray:
        """Times in seconds of the sound each frame shows, shape (M,)."""
        return self.frames / self.fps


#: A guide weighted at least this much (a puppet that trusts the ridge over its vocal HMM, as the
#: training's cross-validation decides for real speech) gets one frame more of the budget in
#: :func:`split_lag`, from the trajectory (docs/streaming.md, "The split for a puppet that
#: trusts its guide").
TRUSTED_GUIDE_WEIGHT = 8.0


def split_lag(lag_ms: float, fps: float, window_s: float, formants: bool,
              delta_width: int = 0, projection_context: int = 0, guide_context: int = 0,
              guide_weight: float = 0.0) -> tuple:
    """Split a latency budget into look-aheads (frames at ``fps``).

    The analysis windows take ``window_s``; the whole frames left, ``B = floor((lag_ms / 1000 -
    window_s) fps)``, are shared: if the feature set has formants, one frame in four (at most
    2) to the formant tracker; if the puppet's vocal features are a projection of ±k frames,
    half the rest, rounded up (at most ``projection_context`` k), to its look-ahead (measured
    better than a third, docs/streaming.md); if they read audio deltas (``delta_width`` w > 0),
    a third of the rest (at most w) to theirs; the remainder to the state decoder and the
    trajectory solve, half each (the decoder gets the odd frame). A guided puppet's guide
    (``guide_context`` k_g > 0) reads the audio alongside the projection and the decoder, so it
    gets their look-ahead for free: ``guide_lag = min(k_g, projection_lag + decode_lag)``
    (giving it more of the budget was measured not to pay at λ = 4, docs/streaming.md). A guide
    weighted ``guide_weight`` >= :data:`TRUSTED_GUIDE_WEIGHT` takes one frame of the trajectory's
    share (when it has one) for the decoder, and so for itself, in a puppet without a projection
    (measured better for puppets of real speech, λ 32–64, on readers they never heard).

    Parameters
    ----------
    lag_ms : float
        The latency budget in milliseconds (>= 0).
    fps : float
        Frame rate of the look-aheads (the puppet's).
    window_s : float
        Look-ahead of the analysis windows in seconds
        (:meth:`voicepuppet.audio.stream.StreamingFeatures.lookahead_s`).
    formants : bool
        Whether the feature set has formants.
    delta_width : int
        Width w of the audio deltas the vocal features read (0: none).
    projection_context : int
        Context k of a projected puppet's vocal features (0: not projected).
    guide_context : int
        Context k_g of a guided puppet's guide (0: no guide).
    guide_weight : float
        λ of the guide on this stream.

    Returns
    -------
    (formant_lag, delta_lag, projection_lag, guide_lag, decode_lag, trajectory_lag) : tuple of int

    Raises
    ------
    ValueError
        ``lag_ms`` is negative, not finite or not a number.
    """
    if not (isinstance(lag_ms, (int, float)) and math.isfinite(lag_ms) and lag_ms >= 0):
        raise ValueError(f"lag_ms must be a non-negative number of milliseconds, got {lag_ms!r}")
    budget = max(0, int(math.floor((lag_ms / 1000.0 - window_s) * fps + 1e-9)))
    f = min(2, budget // 4) if formants else 0
    rest = budget - f
    pl = min(int(projection_context), (rest + 1) // 2)
    rest -= pl
    dl = min(int(delta_width), rest // 3)
    rest -= dl
    decode = (rest + 1) // 2
    if guide_context > 0 and guide_weight >= TRUSTED_GUIDE_WEIGHT and not projection_context \
            and rest - decode > 0:  # (measured on puppets without a projection)
        decode += 1
    gl = min(int(guide_context), pl + decode)
    return f, dl, pl, gl, decode, rest - decode


class LivePuppet:
    """A voice puppet driven live: push audio chunks, get face frames.

    Parameters
    ----------
    puppet : voicepuppet.puppet.model.Puppet or str
        The puppet (or the path of a ``.vpp`` file). Its feature set must be streamable
        (``voicepuppet.audio.stream.STREAMABLE``: every named set except those with F0).
    lag_ms : float
        Latency budget in milliseconds (see :func:`split_lag`); ignored for the look-aheads given
        explicitly below.
    fps : float, optional
        Output frame rate (default: the puppet's).
    posterior : bool
        Posterior-weighted synthesis (fixed-lag smoothed posteriors) instead of the fixed-lag
        Viterbi path.
    rate : int
        Sample rate of the pushed audio; other rates than 16000 are resampled on the stream with
        ``resample_poly``'s filter.
    formant_lag, delta_lag, projection_lag, guide_lag, decode_lag, trajectory_lag : int, optional
        Explicit look-aheads in frames. ``formant_lag=-1`` waits for the formant tracker's
        exact decisions (unbounded latency), ``delta_lag=-1`` uses the delta look-ahead the
        vocal features need to be exact (the puppet's delta width; 0 when they are a projection
        of the features alone, as ``vocal_features="projected"`` trains them),
        ``projection_lag=-1`` a projected puppet's full context k (0 .. k; missing future frames
        repeat the newest one), ``guide_lag=-1`` a guided puppet's full guide context k_g (0 ..
        k_g, likewise); with all four at -1 and large decode and trajectory lags the output is
        exactly ``puppet.animate`` of the same audio.
    guide_weight : float, optional
        λ of a guided puppet's guide (default: the file's, chosen at training); 0 streams Brand's unguided
        trajectory, as ``animate(guide_weight=0)``.
    input_level_db : float, optional
        For a puppet that brings audio to a speech level (feature option ``level_db``, the
        default of training): the live audio's speech level in dBFS, if known
        (:func:`voicepuppet.audio.conditioning.speech_level_db` of a recording of the same source),
        so the stream is scaled as ``animate`` scales it from the first sample; without it the
        level is estimated from what has been heard (the first second as it comes).

    Raises
    ------
    ValueError
        A puppet whose features the stream cannot compute, look-aheads out of their ranges
        (beyond the puppet's delta width, projection or guide context), a bad ``fps``,
        ``rate`` (a whole number of Hz >= 8000) or ``guide_weight``.
    """

    def __init__(self, puppet, lag_ms: float = 150.0, *, fps: float | None = None,
                 posterior: bool = False, rate: int = ANALYSIS_RATE, formant_lag: int | None = None,
                 delta_lag: int | None = None, projection_lag: int | None = None,
                 guide_lag: int | None = None, guide_weight: float | None = None,
                 decode_lag: int | None = None, trajectory_lag: int | None = None,
                 input_level_db: float | None = None):
        if isinstance(puppet, (str, os.PathLike)):
            puppet = load(puppet)
        core = getattr(puppet, "_core", None)
        if core is None or not hasattr(puppet, "feature_set"):
            raise ValueError(f"puppet must be a voicepuppet Puppet or a .vpp path, got "
                             f"{type(puppet).__name__}")
        self.puppet = puppet
        fset = puppet.feature_set
        names = list(puppet.metadata.get("feature_names", []))
        self.features = StreamingFeatures(fset, fps=puppet.fps, rate=ANALYSIS_RATE, input_level_db=input_level_db)
        if names and list(self.features.names) != names:
            raise ValueError(f"this puppet was trained on features the stream cannot compute "
                             f"(columns {names[:3]}...; the stream makes "
                             f"{list(self.features.names)[:3]}...): train it from audio with a "
                             "streamable feature set")
        if int(core.n_features) != self.features.n_features:
            raise ValueError(f"puppet expects {core.n_features} audio features, its feature set "
                             f"gives {self.features.n_features}; the puppet file is inconsistent")
        has_formants = "formants" in fset.features
        window = self.features.lookahead_s()
        width = int(core.delta_width)
        k = int(core.projection_context)
        if guide_weight is None:
            lam = float(core.guide_weight) if core.guided else 0.0
        elif not (isinstance(guide_weight, (int, float, np.number)) and math.isfinite(guide_weight)
                  and guide_weight >= 0):
            raise ValueError(f"guide_weight must be a finite number >= 0, got {guide_weight!r}")
        else:
            lam = float(guide_weight)
        kg = int(core.guide_context) if lam > 0 else 0  # (a positive λ for an unguided puppet:
        # StreamingPuppet says it needs a guided one)
        # the delta look-ahead the vocal features need (none for a projection of the features
        # alone, a projected puppet's default with context)
        f, dl, pl, gl, d, t = split_lag(float(lag_ms), puppet.fps, window, has_formants,
                                        int(core.vocal_delta_width), k, kg, lam)
        f = f if formant_lag is None else formant_lag
        dl = dl if delta_lag is None else delta_lag
        pl = pl if projection_lag is None else projection_lag
        d = d if decode_lag is None else decode_lag
        t = t if trajectory_lag is None else trajectory_lag
        if guide_lag is not None:
            gl = guide_lag
        elif projection_lag is not None or decode_lag is not None:
            # the free look-ahead follows explicit projection / decoder lags
            gl = min(kg, max(0, (k if pl < 0 else pl) + d))
        for name, v in (("formant_lag", f), ("delta_lag", dl), ("projection_lag", pl),
                        ("guide_lag", gl), ("decode_lag", d), ("trajectory_lag", t)):
            if not isinstance(v, (int, np.integer)) or v < (-1 if name in ("formant_lag",
                                                                          "delta_lag",
                                                                          "projection_lag",
                                                                          "guide_lag")
                                                             else 0):
                raise ValueError(f"{name} must be a whole number of frames >= 0, got {v!r}")
        if dl > width:
            raise ValueError(f"delta_lag must be at most the puppet's delta width {width}, got "
                             f"{dl}")
        if pl > k:
            raise ValueError(f"projection_lag must be at most the puppet's projection context "
                             f"{k} (frames of audio on each side its vocal features read), got "
                             f"{pl}")
        if guide_lag is not None and guide_lag > int(core.guide_context):
            raise ValueError(f"guide_lag must be at most the puppet's guide context "
                             f"{int(core.guide_context)} (frames of audio on each side its guide "
                             f"reads; 0 for a puppet without a guide), got {guide_lag}")
        self.formant_lag = None if f < 0 else int(f)
        if has_formants:
            self.features = StreamingFeatures(fset, fps=puppet.fps, rate=ANALYSIS_RATE,
                                              formant_lag=self.formant_lag, input_level_db=input_level_db)
        out_fps = 0.0 if fps is None else float(fps)
        if fps is not None and not (math.isfinite(out_fps) and out_fps > 0):
            raise ValueError(f"fps must be positive, got {fps!r}")
        self.core = _core.StreamingPuppet(core, int(d), int(t), out_fps, bool(posterior), int(dl),
                                          int(pl), int(gl), lam)
        self.fps = float(self.core.output_fps)
        try:
            rate_i = int(rate)
        except (TypeError, ValueError):
            raise ValueError(f"rate must be a whole number of Hz, got {rate!r}") from None
        if rate_i != rate or rate_i < 8000:
            raise ValueError(f"rate must be a whole number of Hz >= 8000, got {rate!r}")
        self.rate = rate_i
        puppet.check_band(rate_i, "the live audio", stacklevel=2)
        self.resampler = None if rate_i == ANALYSIS_RATE else StreamResampler(rate_i, ANALYSIS_RATE)
        self.lag_ms = float(lag_ms)
        self.samples_in = 0
        self._n_points = int(core.n_points)
        self._n_dims = int(core.n_dims)

    @property
    def n_points(self) -> int:
        """Landmarks per frame (P of :attr:`LiveFrames.points`)."""
        return self._n_points

    @property
    def delta_lag(self) -> int:
        """Look-ahead of the audio deltas, in feature frames."""
        return int(self.core.delta_lag)

    @property
    def projection_lag(self) -> int:
        """Look-ahead of a projected puppet's vocal features, in feature frames."""
        return int(self.core.projection_lag)

    @property
    def guide_lag(self) -> int:
        """The guide's look-ahead (0 for an unguided stream)."""
        return int(self.core.guide_lag)

    @property
    def guide_weight(self) -> float:
        """λ of the guide on this stream (0: unguided)."""
        return float(self.core.guide_weight)

    @property
    def decode_lag(self) -> int:
        """Look-ahead of the state decoder, in feature frames."""
        return int(self.core.decode_lag)

    @property
    def trajectory_lag(self) -> int:
        """Look-ahead of the trajectory solve, in frames at the output rate."""
        return int(self.core.trajectory_lag)

    @property
    def latency_s(self) -> float:
        """Algorithmic latency in seconds: analysis windows + formant tracker bound + delta
        look-ahead + the longer of (projection + decoder) and the guide's look-ahead + the
        trajectory's (compute time not included). Unbounded
        (inf) when the formant tracker waits for exact decisions."""
        if self.formant_lag is None and "formants" in self.puppet.feature_set.features:
            return math.inf
        return self.features.lookahead_s() + self.core.latency_seconds

    def push(self, samples) -> LiveFrames:
        """Feed audio samples (any number, at ``rate``; floats in full scale or integer PCM).

        Parameters
        ----------
        samples : array_like, shape (n,) or (n, channels)
            The next samples of the stream (channels are averaged).

        Returns
        -------
        LiveFrames
            The face frames completed by this chunk (possibly none).
        """
        x = pcm_to_float(samples)
        self.samples_in += x.shape[0]
        if self.resampler is not None:
            x = self.resampler.push(x)
        feats = self.features.push(x)
        if feats.shape[0] == 0:  # no new feature frame: nothing can be decided
            return LiveFrames(int(self.core.frames_emitted), np.zeros((0, self._n_points, 2)),
                              np.zeros((0, self._n_dims)), self.fps)
        return self._frames(self.core.push(feats))

    def flush(self) -> LiveFrames:
        """End of the stream: every frame still held back (windows past the end see silence,
        as offline). Then the puppet is ready for a new stream.

        Returns
        -------
        LiveFrames
            The frames held back until now.
        """
        if self.resampler is not None:
            tail = self.resampler.flush()
            rows = [self.features.push(tail)] if tail.size else []
        else:
            rows = []
        rows.append(self.features.flush())
        a = self.core.push(np.vstack(rows))
        b = self.core.flush()
        self.samples_in = 0
        out_a, out_b = self._frames(a), self._frames(b)
        return LiveFrames(out_a.first_frame, np.concatenate([out_a.points, out_b.points]),
                          np.concatenate([out_a.face, out_b.face]), self.fps)

    def _frames(self, r) -> LiveFrames:
        pts = np.asarray(r.points)
        return LiveFrames(int(r.first_frame), pts.reshape(pts.shape[0], pts.shape[1] // 2, 2),
                          np.asarray(r.face), self.fps)
