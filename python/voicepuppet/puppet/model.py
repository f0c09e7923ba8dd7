"""The voice puppet: train from a talking face, animate from any audio (Voice Puppetry §4).

Training (:meth:`Puppet.train`), one pass, no back and forth:

1. Face vectors: landmarks → head pose removed (:class:`voicepuppet.face.FaceSpace`) → principal
   components → observations ``o_t = [y_t, y_t − y_{t−1}]``.
2. Facial HMM: a Gaussian HMM with full covariance over pose and velocity, trained by entropic
   MAP-EM (:mod:`voicepuppet.hmm.entropic`), starting from ``n_states`` fully connected states and
   trimming what the data do not support.
3. Occupancy γ [T, N] of the training frames under the facial HMM.
4. Remap (§4.3): each state's vocal Gaussian is the γ-weighted mean and covariance of the
   synchronous, standardised audio features (with their regression deltas over ±2 frames, so
   each frame carries its local dynamics); the vocal HMM shares the facial state machine.
   Means and covariances are shrunk towards the pooled ones by ``A`` frames' worth of evidence
   (A = audio dimensions), so a rarely visited state still has a usable Gaussian. With
   ``vocal_features="projected"`` the vocal Gaussians live instead on a learned projection of
   the audio, the ridge's cross-fitted prediction of the face coordinates from ±``vocal_context``
   frames (:mod:`voicepuppet.puppet.guide`), stored in the file and applied by C++.
5. Guide (``guide="ridge"``, the default): the ridge's prediction ŷ of the face from
   ±``guide_context`` frames of audio and the covariance R of its cross-fitted residuals; at
   synthesis the trajectory solve adds ``λ Σ_t (y_t − ŷ_t)ᵀ R⁻¹ (y_t − ŷ_t)`` (λ, the file's
   ``guide/weight``; ``animate(guide_weight=0)`` is Brand's solve). ``guide="none"``: none.
6. Guide weight (``guide_weight="cv"``, the default): λ from :data:`GUIDE_WEIGHTS` by
   cross-validation on the training audio — the guide and the vocal side refitted on 4 of 5
   folds, the held-out fold animated at every λ, the least squared face error wins (how far the
   vocal HMM generalises on this speaker's own audio decides how much the ridge is trusted);
   or a number.

Animation runs in C++ (:class:`voicepuppet._core.Puppet`, ``cpp/include/voicepuppet/puppet.hpp``):
features → standardise (→ projection) → vocal log densities → Viterbi (or posteriors) → closed-form trajectory at
the output rate (with the guide's evidence) → landmarks at the training mean pose. The puppet file (``.vpp``) is written and
read by C++ too (magic number, format version, CRC-32), so a C++ program animates without Python.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from voicepuppet import _core
from voicepuppet import audio as vaudio
from voicepuppet._files import check_output_path
from voicepuppet.animation import Animation
from voicepuppet.audio import AudioWarning, FeatureSet
from voicepuppet.audio.loading import DEFAULT_RATE
from voicepuppet.blas import limited
from voicepuppet.face import FaceSpace
from voicepuppet.limits import check_limit
from voicepuppet.puppet import long, training
from voicepuppet.puppet.metadata import check_metadata
from voicepuppet.puppet.training import TrainOptions
from voicepuppet.trajectory import MAX_MOTION_GAIN, widen_motion

_D = TrainOptions()  # the defaults of Puppet.train's options

#: Test-time adaptation (``Puppet.animate(adapt=...)``): the kinds and the prior / iterations
#: used unless told otherwise (chosen on the leave-one-reader-out protocol, docs/results.md).
ADAPT_KINDS = ("full",)
ADAPT_DEFAULTS = {"tau": 30.0, "n_iter": 1}


@dataclass
class Animated:
    """What :meth:`Puppet.animate` returns.

    Each parameter is kept as the attribute of the same name.

    Parameters
    ----------
    animation : Animation
        Landmarks [T', P, 2] at the output rate.
    face : ndarray (T', K)
        Face coordinates (the model's own space).
    states : ndarray (T, parts) of int
        Facial states per analysis frame (Viterbi), one column per face part.
    states_fps : float
        Rate of ``states`` (the puppet's rate).
    log_likelihood : float
        Viterbi log p(path, audio), or log p(audio) for posterior synthesis (with adaptation, of
        the input under the adapted model: including T log|det A|).
    transforms : list of dict
        With ``adapt``: per face part, the transform of the vocal features found (``A`` [V, V],
        ``b`` [V], V their dimension: A' standardised features or the projection's K;
        ``log_likelihood``: the penalised log-likelihood before each EM iteration and after the
        last); empty without.
    """

    animation: Animation
    face: np.ndarray
    states: np.ndarray
    states_fps: float
    log_likelihood: float
    transforms: list = field(default_factory=list)


class Puppet:
    """A trained voice puppet. Build with :meth:`train` or :func:`load`.

    Parameters
    ----------
    metadata : dict
        The puppet file's metadata (JSON-able): frame rate, parts, feature set and names,
        training record, ...
    arrays : dict of str to array_like
        The puppet file's arrays (face space, HMMs, audio standardisation, guide, ...), as
        :func:`voicepuppet.puppet.training.train` makes them.

    Attributes
    ----------
    metadata : dict
        A copy of ``metadata``.
    arrays : dict of str to ndarray
        ``arrays`` as numpy arrays.
    face_space : voicepuppet.face.FaceSpace
        The puppet's face space (landmarks to face coordinates and back).

    Raises
    ------
    ValueError
        Metadata or arrays that do not make a puppet: a missing or misshapen array, values out
        of range (checked by the C++ core, ``Puppet`` in ``cpp/include/voicepuppet/puppet.hpp``)
        or metadata that disagrees with them (:func:`voicepuppet.puppet.metadata.check_metadata`).
    """

    def __init__(self, metadata: dict, arrays: dict):
        if not isinstance(metadata, dict):
            raise ValueError(f"a puppet's metadata must be a dict, got {type(metadata).__name__}")
        self.metadata = dict(metadata)
        self.arrays = {k: np.asarray(v) for k, v in arrays.items()}
        self._core = _core.Puppet(json.dumps(self.metadata), self.arrays)
        c = self._core
        check_metadata(self.metadata, n_parts=c.n_parts, n_features=c.n_features, n_points=c.n_points, fps=c.fps)
        missing = [k for k in ["face/weights"] + [f"face/part{i}/variances" for i in range(c.n_parts)]
                   if k not in self.arrays]
        if missing:
            raise ValueError(f"the puppet has no array {missing[0]!r}; it was written by an incompatible tool")
        self.face_space = FaceSpace.from_arrays(self.arrays, self.metadata["parts"])
        gain = self.arrays.get("face/motion_gain")
        if gain is not None and not (gain.shape == (self.face_space.n_dims,) and np.isfinite(gain).all()
                                     and (gain >= 1).all() and (gain <= MAX_MOTION_GAIN).all()):
            raise ValueError(f"the puppet's face/motion_gain must hold {self.face_space.n_dims} gains in "
                             f"[1, {MAX_MOTION_GAIN:g}] (one per face coordinate), got shape {gain.shape}; "
                             "the file is damaged: retrain")
        self._rest: np.ndarray | bool | None = None  # rest_face(), found once

    # ------------------------------------------------------------------------- properties
    @property
    def fps(self) -> float:
        """Frame rate (frames per second) of the puppet: its training landmarks' and its features'."""
        return float(self._core.fps)

    @property
    def feature_set(self):
        """The :class:`voicepuppet.audio.FeatureSet` the puppet reads audio with."""
        return FeatureSet.from_json(self.metadata["feature_set"])

    @property
    def n_points(self) -> int:
        """Number of landmarks P of the animations."""
        return int(self._core.n_points)

    @property
    def part_names(self) -> list:
        """Names of the face parts, one facial HMM each (list of str)."""
        return list(self.metadata["parts"])

    @property
    def guided(self) -> bool:
        """Whether the puppet has a guide (``guide="ridge"``): the ridge's prediction of the face
        as evidence in the trajectory solve (λ = :attr:`guide_weight` unless overridden)."""
        return bool(self._core.guided)

    @property
    def guide_weight(self) -> float:
        """λ stored in the file (0 without a guide)."""
        return float(self._core.guide_weight)

    def n_states(self, part: int = 0) -> int:
        """Number of states of one part's HMM (after training's trimming).

        Parameters
        ----------
        part : int
            Index of the face part (default 0, the first).

        Returns
        -------
        int
            The part's state count.
        """
        return int(self._core.n_states(part))

    #: Seconds of digital silence :meth:`rest_face` animates; it takes the middle frame.
    REST_SECONDS = 1.0

    def rest_face(self) -> np.ndarray | None:
        """The landmarks (P, 2) of the face the puppet makes in silence: its animation of
        :attr:`REST_SECONDS` of digital silence at the middle frame (a pause of its training
        video, decoded as any audio is). Rendering and export retarget an animation's motion
        from it (``Animation.neutral``, which :meth:`animate` sets to it), so audio that begins
        mid-word does not make its first, open-mouthed frame the photo's closed mouth.

        Returns
        -------
        ndarray, shape (P, 2) or None
            The rest face (a copy; computed once per puppet). None for a puppet trained on given
            features (``features_list``): its silence is unknown.
        """
        if self._rest is None:
            n = int(round(self.REST_SECONDS * DEFAULT_RATE))
            silence = vaudio.Audio(np.zeros(n), DEFAULT_RATE, DEFAULT_RATE, 1, "silence")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", vaudio.AudioWarning)  # "the recording is silent"
                feats = vaudio.extract(silence, fps=self.fps, features=self.feature_set)
            self._rest = False
            if list(feats.names) == list(self.metadata.get("feature_names", ())):
                r = self._core.animate(np.ascontiguousarray(feats.values), self.fps, False, "none", 1.0, 1, -1.0)
                pts = r["points"].reshape(len(r["points"]), -1, 2)
                self._rest = pts[len(pts) // 2].copy()
        return None if self._rest is False else self._rest.copy()

    def ridge_input(self, raw) -> np.ndarray:
        """What a ridge regression on this puppet's audio hears: raw features standardised as the
        puppet standardises them (its training mean and std), without the deltas the puppet
        appends (a linear map over a context of frames can form them).

        Parameters
        ----------
        raw : array_like, shape (T, A)
            Raw features made with the puppet's feature set (e.g. ``puppet.audio_features``).

        Returns
        -------
        ndarray, shape (T, A)
            The standardised features.
        """
        return self._core.standardize(np.ascontiguousarray(raw, dtype=np.float64))[:, :self._core.n_features]

    def part_arrays(self, part: int = 0) -> dict:
        """The HMM arrays of one part.

        Parameters
        ----------
        part : int
            Index of the face part (default 0, the first).

        Returns
        -------
        dict of str to ndarray
            ``startprob``, ``transmat``, ``face_means``, ``face_covars``, ``vocal_means``,
            ``vocal_covars`` (the arrays themselves, not copies).
        """
        pre = f"hmm/part{part}/"
        return {k[len(pre):]: v for k, v in self.arrays.items() if k.startswith(pre)}

    def __repr__(self) -> str:
        parts = ", ".join(f"{n}: {self.n_states(i)} states" for i, n in enumerate(self.part_names))
        return (f"<Puppet {self.n_points} points, {self.face_space.n_dims} face dims, "
                f"{self._core.n_features} audio features at {self.fps:g} fps; {parts}>")

    # --------------------------------------------------------------------------- training
    @classmethod
    @limited  # numpy's small dense algebra is faster on one BLAS thread (blas.py)
    def train(cls, points_list, audio_list=None, *, features_list=None, fps: float = 29.97,
              progress: bool = False, client=None,
              n_states: int = _D.n_states, n_iter: int = _D.n_iter, prior: str = _D.prior, z: float = _D.z,
              anneal: bool = _D.anneal, n_components=_D.n_components, max_components: int = _D.max_components,
              parts=_D.parts, feature_set=_D.feature_set, audio_deltas: int = _D.audio_deltas,
              vocal_covariance: str = _D.vocal_covariance, vocal_shrinkage: float = _D.vocal_shrinkage,
              vocal_features: str = _D.vocal_features, vocal_context: int = _D.vocal_context,
              guide: str = _D.guide, guide_context: int = _D.guide_context, guide_weight=_D.guide_weight,
              guide_alpha: str = _D.guide_alpha, min_covar: float = _D.min_covar, init: str = _D.init,
              noise_snrs=_D.noise_snrs, audio_level=_D.audio_level, seed: int = _D.seed) -> "Puppet":
        """Train a puppet from synchronous landmark tracks and audio.

        Parameters
        ----------
        points_list : array (T, P, 2) or list of them
            Landmarks per training sequence (pixels), e.g. from :func:`voicepuppet.tracking.tracker.track_video`.
        audio_list : path, :class:`voicepuppet.audio.Audio`, or a list of them
            The audio of each sequence (audio files or videos with sound), starting at frame 0.
        features_list : array (T, A) or list of them, optional
            Instead of ``audio_list``: raw audio features, one row per landmark frame (then the
            puppet is animated with ``animate(features=...)`` from features made the same way).
        fps : float
            Frame rate of the landmarks; the audio features are computed at this rate.
        progress : bool
            Progress bars (features, entropic EM).
        client : distributed.Client, optional
            Run the HMM's E-steps on this Dask cluster (:mod:`voicepuppet.hmm.distributed`): the same
            parameters as training in one process, for many hours of video.
        n_states, n_iter, prior, z, anneal, init, min_covar, seed
            Training options of the facial HMMs, each described in
            :class:`~voicepuppet.puppet.training.TrainOptions` (defaults:
            :data:`~voicepuppet.puppet.training.TRAIN_DEFAULTS`).
        n_components, max_components, parts
            Training options of the face space (as above).
        feature_set, audio_deltas, audio_level, noise_snrs
            Training options of the audio features (as above).
        vocal_covariance, vocal_shrinkage, vocal_features, vocal_context
            Training options of the vocal Gaussians (as above).
        guide, guide_context, guide_weight, guide_alpha
            Training options of the guide (as above).

        Returns
        -------
        Puppet
            The trained puppet.

        Raises
        ------
        ValueError
            A bad option (:class:`~voicepuppet.puppet.training.TrainOptions`), landmarks and
            audio that do not pair up, or too few training frames for ``n_states`` (at least 10
            frames per state).

        Notes
        -----
        numpy's BLAS runs on one thread while training (``VOICEPUPPET_BLAS_THREADS`` sets
        another count; an ``OPENBLAS_NUM_THREADS`` of your own is left alone:
        :func:`voicepuppet.blas.blas_threads`): on 2 cores, 180 s of training audio trains in
        about 5 s instead of 22.
        """
        options = TrainOptions(
            n_states=n_states, n_iter=n_iter, prior=prior, z=z, anneal=anneal, n_components=n_components, seed=seed,
            max_components=max_components, parts=parts, feature_set=feature_set, audio_deltas=audio_deltas,
            vocal_covariance=vocal_covariance, vocal_shrinkage=vocal_shrinkage, vocal_features=vocal_features,
            vocal_context=vocal_context, guide=guide, guide_context=guide_context, guide_weight=guide_weight,
            guide_alpha=guide_alpha, min_covar=min_covar, init=init, noise_snrs=noise_snrs, audio_level=audio_level)
        metadata, arrays = training.train(points_list, audio_list, features_list=features_list, fps=fps,
                                          options=options, progress=progress, client=client)
        return cls(metadata, arrays)

    # -------------------------------------------------------------------------- animation
    def audio_features(self, audio, n_out: int | None = None, progress: bool = False) -> np.ndarray:
        """Raw (unstandardised) features [T, A] of ``audio`` at the puppet's rate, with the
        puppet's feature set (:meth:`extract`'s values).

        Parameters
        ----------
        audio : path or voicepuppet.audio.Audio
            Audio file, video with sound, or loaded audio.
        n_out : int, optional
            Number of frames (default: ``ceil(duration * fps)``).
        progress : bool
            Show a progress bar (default False).

        Returns
        -------
        ndarray, shape (T, A)
            The raw features, one row per frame.
        """
        return self.extract(audio, n_out=n_out, progress=progress, stacklevel=4).values

    def extract(self, audio, n_out: int | None = None, progress: bool = False, stacklevel: int = 2):
        """The :class:`voicepuppet.audio.Features` the puppet reads from ``audio`` (a file or
        :class:`voicepuppet.audio.Audio`): its feature set at its rate. Audio of a narrower band
        than the puppet analyses (8 kHz telephone audio for a puppet trained on wider-band sound)
        is warned about (``AudioWarning``, :meth:`check_band`).

        Parameters
        ----------
        audio : path or voicepuppet.audio.Audio
            Audio file, video with sound, or loaded audio.
        n_out : int, optional
            Number of frames (default: ``ceil(duration * fps)``).
        progress : bool
            Show a progress bar (default False).
        stacklevel : int
            Stack level of the band warning, counted from the caller (default 2: the caller).

        Returns
        -------
        voicepuppet.audio.Features
            The features at the puppet's rate.
        """
        audio = audio if isinstance(audio, vaudio.Audio) else vaudio.load_audio(audio)
        self.check_band(audio.source_rate, f"audio {audio.path!r}" if audio.path else "audio", stacklevel=stacklevel)
        return vaudio.extract(audio, fps=self.fps, features=self.feature_set, n_out=n_out, progress=progress)

    @property
    def band_hz(self) -> float:
        """The band (Hz) the puppet analyses audio in: its feature set's ``band_hz``, else the
        whole band of the 16 kHz analysis."""
        return float(self.feature_set.settings()["band_hz"] or 0.5 * DEFAULT_RATE)

    def check_band(self, source_rate: int, what: str = "audio", stacklevel: int = 2) -> None:
        """Warn (``AudioWarning``) when audio sampled at ``source_rate`` Hz is of a narrower band
        than the puppet learned (8 kHz telephone audio for a puppet of wider-band sound).

        Parameters
        ----------
        source_rate : int
            Sample rate (Hz) the audio was recorded at.
        what : str
            How the warning names the audio (default ``"audio"``).
        stacklevel : int
            Stack level of the warning, counted from the caller (default 2: the caller).
        """
        edge = 0.5 * source_rate
        if edge < self.band_hz * (1 - 1e-9):
            warnings.warn(f"{what} is sampled at {source_rate} Hz, so its sound stops at {edge:g} Hz, and "
                          f"this puppet learned sound up to {self.band_hz:g} Hz: its features are not those "
                          "the puppet knows and the animation is poorer (8 kHz audio on the demo's data: "
                          f"lip error 34 -> 54 px^2); for such audio train the puppet with --audio-band "
                          f"{edge:g} (docs/puppet.md)", AudioWarning, stacklevel=stacklevel + 1)

    def animate(self, audio=None, *, fps: float | None = None, posterior: bool = False,
                features=None, states=None, states_fps: float | None = None,
                adapt: str | None = None, adapt_tau: float = ADAPT_DEFAULTS["tau"],
                adapt_iter: int = ADAPT_DEFAULTS["n_iter"], guide_weight: float | None = None,
                full_motion: bool = True, progress: bool = False, chunked: bool | None = None) -> Animated:
        """Facial animation for novel audio (any voice, any language).

        Parameters
        ----------
        audio : path or :class:`voicepuppet.audio.Audio`, optional
            What to animate (audio file or video with sound).
        fps : float, optional
            Output frame rate (default: the puppet's).
        posterior : bool
            Posterior-weighted synthesis (all state sequences, weighted) instead of the Viterbi path.
        features : array (T, A), optional
            Raw features at the puppet's rate instead of ``audio``.
        states : array (T,) or (T, parts) of int, optional
            A (possibly edited) state sequence to synthesise from, instead of decoding audio (the
            ``states`` of an earlier result, at :attr:`Animated.states_fps`). Alone: Brand's
            unguided solve. With the ``audio`` or ``features`` they go with: the states replace
            the Viterbi path and nothing else changes (a guided puppet's guide comes from that
            audio), so unedited states give the audio's animation exactly and an edit changes the
            face around the frames it touches. They must then cover the audio's frames (to within
            one frame).
        states_fps : float, optional
            Rate of ``states`` (default: the puppet's; a rate within 1 ppm of the puppet's, as read
            back from a states file's 9-digit times, is the puppet's).
        adapt : {None, "full"}
            ``"full"``: unsupervised test-time adaptation of the input's vocal features (the
            standardised features, or their projection for a ``vocal_features="projected"``
            puppet) to each part's vocal HMM before decoding (``cpp/include/voicepuppet/adapt.hpp``): an
            affine transform A z + b found by EM with the puppet's own state posteriors, against
            a prior of ``adapt_tau`` frames of the puppet's voice. None (default): the features as
            they are. Measured in docs/results.md ("Voices never heard"): not the default.
        adapt_tau : float
            The prior's weight in frames (> 0; ``inf``: no adaptation, bit-identical to None).
        adapt_iter : int
            EM iterations (>= 1).
        guide_weight : float, optional
            λ of a guided puppet's evidence (the ridge's prediction of the face, weighted by the
            inverse covariance of its residuals): None (default) the file's — chosen at training
            by cross-validation on the training audio (files of earlier versions carry 4, the
            first guided ones 1) — 0 Brand's unguided solve, any λ >= 0. A positive value needs a guided
            puppet (:attr:`guided`). The choice is made on the voices of the training audio; on a
            voice never heard puppets of a fixed λ keep the lips closer, at a higher Err
            (docs/results.md, "The guide's weight for voices never heard").
            Given states without audio are synthesised unguided.
        full_motion : bool
            Widen the trajectory's motion (default True): each face coordinate's deviation from
            its mean over the animation is multiplied by the gain the puppet learnt at training,
            how much less its animations of held-out training audio moved than the faces did
            (:func:`voicepuppet.trajectory.widen_motion`), so the mouth moves as much as the
            speaker's did instead of the most probable trajectory's timid average. False: the
            most probable trajectory as it is. The gains were learnt for the puppet's guided
            animation of audio: with a ``guide_weight`` other than its own or states without
            their audio the trajectory is not widened, nor by puppets without gains (a fixed guide weight or no
            guide, or trained before they were stored).
        progress : bool
            Show a progress bar while extracting features from ``audio`` (default False).
        chunked : bool, optional
            Long audio in bounded memory (:mod:`voicepuppet.puppet.long`: features read in blocks,
            the core run on overlapping windows; equal to the whole to 1e-6, ``log_likelihood``
            NaN). None (default): above :data:`~voicepuppet.puppet.long.LONG_AUDIO_S` (5 min);
            True: always; False: never. Not with ``states`` or ``adapt``. The landmarks returned
            hold every frame (235 MB for 2 h at 68 points): :meth:`animate_to` does not.

        Returns
        -------
        Animated
            The animation (its ``neutral`` the puppet's :meth:`rest_face`), face coordinates,
            states and log-likelihood.

        Raises
        ------
        ValueError
            ``fps`` outside [1, 1000] (:data:`voicepuppet.limits.LIMITS`), or more output
            frames than they allow; neither or both of ``audio`` and ``features`` (without
            ``states``); ``adapt`` not None or "full", or given with ``states``; ``posterior``
            with ``states``; ``guide_weight`` not None or a finite number >= 0, or positive for
            states without audio; ``states`` not integers of shape (T,) or (T, parts);
            ``adapt_iter`` not an integer; ``chunked=True`` with ``states`` or ``adapt``.
        """
        r = self._animate(audio, fps, posterior, features, states, states_fps, adapt, adapt_tau, adapt_iter,
                          guide_weight, full_motion, progress, chunked)
        pts = long.all_points(self, r)
        return Animated(Animation(pts, r["out_fps"], neutral=self.rest_face()), r["face"], r["states"], r["states_fps"],
                        r["log_likelihood"], r["transforms"])

    def animate_to(self, path, audio=None, *, features=None, fps: float | None = None, posterior: bool = False,
                   adapt: str | None = None, adapt_tau: float = ADAPT_DEFAULTS["tau"],
                   adapt_iter: int = ADAPT_DEFAULTS["n_iter"], guide_weight: float | None = None,
                   full_motion: bool = True, exaggerate: float | None = None, progress: bool = False,
                   chunked: bool | None = None) -> long.AnimatedFiles:
        """:meth:`animate` straight to animation files (``.npz``, ``.csv``: those
        :func:`~voicepuppet.animation.save_animation` writes), in memory flat with the audio's length
        when chunked (:func:`voicepuppet.puppet.long.animate_to`). Raises what :meth:`animate` does.

        Parameters
        ----------
        path : str or os.PathLike, or a list of them
            The file(s) to write, each ending in ``.npz`` or ``.csv`` (checked first).
        audio, features, fps, posterior, adapt, adapt_tau, adapt_iter, guide_weight, full_motion, progress, chunked
            As for :meth:`animate` (no ``states``: use :meth:`animate`).
        exaggerate : float, optional
            Scale the motion about the animation's mean shape by this factor (default: as is).

        Returns
        -------
        voicepuppet.puppet.long.AnimatedFiles
            The files, the frame count and rate, face coordinates, states and log-likelihood.
        """
        return long.animate_to(self, path, audio, features=features, fps=fps, posterior=posterior, adapt=adapt,
                               adapt_tau=adapt_tau, adapt_iter=adapt_iter, guide_weight=guide_weight,
                               full_motion=full_motion, exaggerate=exaggerate, progress=progress, chunked=chunked)

    def _animate(self, audio, fps, posterior, features, states, states_fps, adapt, adapt_tau, adapt_iter,
                 guide_weight, full_motion, progress, chunked) -> dict:
        """``animate``'s work: a dict (face, points or None when chunked, states, ..., widened)."""
        out_fps = self.fps if fps is None else check_limit(fps, "fps", "output fps")
        sound = (audio is not None) + (features is not None)
        if sound > 1 or (sound == 0 and states is None):
            raise ValueError("give audio or features (one of them), states, or states with the audio or "
                             "features they go with")
        if adapt is not None:
            if adapt not in ADAPT_KINDS:
                raise ValueError(f"adapt must be None or {' or '.join(map(repr, ADAPT_KINDS))}, got {adapt!r}")
            if states is not None:
                raise ValueError("adapt changes how the audio is decoded; given states are not decoded: drop adapt")
        if states is not None and posterior:
            raise ValueError("given states are one path: posterior-weighted synthesis does not apply to them; "
                             "drop posterior (or the states)")
        if guide_weight is None:
            lam = -1.0
        else:
            if isinstance(guide_weight, bool) or not isinstance(guide_weight, (int, float, np.integer, np.floating)):
                raise ValueError(f"guide_weight must be None or a number >= 0, got {guide_weight!r}")
            lam = float(guide_weight)
            if not (lam >= 0 and np.isfinite(lam)):
                raise ValueError(f"guide_weight must be None (the puppet's) or a finite number >= 0 "
                                 f"(0: unguided), got {guide_weight!r}")
            if states is not None and not sound and lam > 0:
                raise ValueError("guide_weight weighs the guide's prediction from the audio; given states "
                                 "without their audio are synthesised unguided: give the audio or drop guide_weight")
        chunk = long.should_chunk(self, chunked, audio, features, states, adapt)
        if states is not None:
            s = np.asarray(states)
            if s.ndim == 1:
                s = s[:, None]
            if s.ndim != 2 or not np.issubdtype(s.dtype, np.integer):
                raise ValueError(f"states must be integers of shape (T,) or (T, parts); got {s.dtype} {s.shape}")
            sf = self.fps if states_fps is None else float(states_fps)
            if abs(sf / self.fps - 1.0) < 1e-6:
                sf = self.fps
            s = np.ascontiguousarray(s, dtype=np.int64)
            if not sound:
                r = self._core.animate_states(s, sf, out_fps)
            else:
                if features is None:
                    features = self.extract(audio, progress=progress, stacklevel=4).values
                r = self._core.animate_states_guided(s, sf, np.ascontiguousarray(features, dtype=np.float64),
                                                     out_fps, lam)
        elif chunk:
            _count(adapt_iter, "adapt_iter")
            if features is None:
                features = long.long_features(self, audio, progress)
            r = long.animate_windows(self._core, np.ascontiguousarray(features, dtype=np.float64), self.fps,
                                     out_fps, posterior, lam, progress=progress)
            r["points"], r["log_likelihood"], sf = None, float("nan"), self.fps
        else:
            if features is None:
                features = self.extract(audio, progress=progress, stacklevel=4).values
            r = self._core.animate(np.ascontiguousarray(features, dtype=np.float64), out_fps, posterior,
                                   adapt or "none", float(adapt_tau), _count(adapt_iter, "adapt_iter"), lam)
            sf = self.fps
        face = r["face"]
        pts = None if r["points"] is None else r["points"].reshape(len(r["points"]), -1, 2)
        own_weight = guide_weight is None or lam == self.guide_weight
        widened = bool(full_motion and sound and own_weight and "face/motion_gain" in self.arrays)
        if widened:  # about the mean of the whole animation (of every window's centre, when chunked)
            face = widen_motion(face, self.arrays["face/motion_gain"])
            if pts is not None:  # widened about its mean, a closed mouth must not cross
                pts = long.points_of(self, face, True)
        return {"face": face, "points": pts, "states": r["states"], "states_fps": sf, "out_fps": out_fps,
                "log_likelihood": float(r["log_likelihood"]), "transforms": list(r.get("transforms", [])),
                "widened": widened}

    # ---------------------------------------------------------------------------- storage
    def save(self, path) -> Path:
        """Write the puppet file (``.vpp``) atomically.

        Parameters
        ----------
        path : str or os.PathLike
            The file to write; it must end in ``.vpp``.

        Returns
        -------
        pathlib.Path
            The path written.

        Raises
        ------
        ValueError
            Another suffix, or a folder that does not exist or is not writable.
        """
        p = check_output_path(path, (".vpp",), "puppet file")
        _core.write_puppet_file(os.fspath(p), json.dumps(self.metadata), self.arrays)
        return p


def _count(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


def load(path) -> Puppet:
    """Read a puppet file (``.vpp``); ValueError names what is wrong with a damaged one.

    Parameters
    ----------
    path : str or os.PathLike
        The puppet file.

    Returns
    -------
    Puppet
        The puppet it holds.

    Raises
    ------
    ValueError
        The file does not exist, is not a puppet file (wrong magic number), comes from a newer
        format version, is damaged (truncated, checksum mismatch, malformed, unreadable metadata)
        or was not written by ``voicepuppet train`` (no part list or feature set), or holds a
        puppet that does not make sense (see :class:`Puppet`: sizes and rates outside
        :data:`voicepuppet.limits.LIMITS`, arrays that disagree, covariances that are not
        positive definite, probabilities that do not sum to 1, metadata of the wrong types).
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"puppet file {str(p)!r} does not exist")
    metadata, arrays = _core.read_puppet_file(os.fspath(p))
    try:  # UTF-8 and nested at most LIMITS["metadata_depth"] levels: checked by the core
        meta = json.loads(metadata)
    except ValueError as exc:
        raise ValueError(f"puppet file {str(p)!r} has unreadable metadata ({exc}); the file is damaged") from None
    if not isinstance(meta, dict) or "parts" not in meta or "feature_set" not in meta:
        raise ValueError(f"puppet file {str(p)!r} lacks its part list or feature set; it was not written "
                         "by voicepuppet train")
    try:
        return Puppet(meta, arrays)
    except ValueError as exc:
        raise ValueError(f"puppet file {str(p)!r}: {exc}") from None


def palette_puppet(palette, name: str) -> Path:
    """The puppet file called ``name`` (with or without ``.vpp``) in the folder ``palette``
    (Brand §6: the animator picks a character's manner from a palette of puppets).

    Parameters
    ----------
    palette : str or os.PathLike
        A folder of ``.vpp`` puppet files.
    name : str
        The puppet's name: its file name, with or without ``.vpp``.

    Returns
    -------
    pathlib.Path
        ``palette/NAME.vpp``.

    Raises
    ------
    ValueError
        ``palette`` is not a folder, or holds no puppet called ``name`` (the message lists those
        it holds).
    """
    folder = Path(palette)
    if not folder.is_dir():
        raise ValueError(f"--palette {str(folder)!r} is not a folder of .vpp puppets")
    available = sorted(p.stem for p in folder.glob("*.vpp"))
    stem = name[:-4] if name.endswith(".vpp") else name
    if stem not in available:
        raise ValueError(f"no puppet {stem!r} in palette {str(folder)!r}; it holds: "
                         f"{', '.join(available) if available else 'no .vpp files'}")
    return folder / f"{stem}.vpp"
