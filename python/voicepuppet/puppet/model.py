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
from voicepuppet.blas import limited
from voicepuppet.animation import Animation
from voicepuppet._files import check_output_path
from voicepuppet.face import FaceSpace, check_landmarks, observations
from voicepuppet.puppet.guide import (GUIDE_WEIGHT, GUIDE_WEIGHTS, GUIDES, VOCAL_FEATURES, cross_fit_folds,
                                     fit_guide, fit_projection, sequence_runs)

#: What ``Puppet.train`` uses unless told otherwise (recorded in each puppet's metadata).
TRAIN_DEFAULTS = {
    "n_states": 40,          # Brand: start large and fully connected, let the prior trim
    "n_iter": 40,
    "prior": "entropic",     # or "ml": conventional Baum-Welch (for comparison)
    "z": 1.0,                # entropic prior weight (1: minimum entropy)
    "anneal": True,          # ramp z from -1 to 1 over the first half of the iterations
    "n_components": 0.98,    # face basis: variance kept per part
    "max_components": 12,
    "parts": None,           # or "upper_lower" (iBUG 68) / dict name -> points
    "feature_set": "puppet",
    "audio_deltas": 2,       # append regression deltas over +-2 frames to the audio features
    "vocal_covariance": "full",  # or "diag", "tied" (one for all states; not better: docs/results.md)
    "vocal_shrinkage": 1.0,  # evidence of the pooled Gaussian in each state's, in units of A frames
    "vocal_features": "audio",  # or "projected": remap on the ridge's cross-fitted face prediction
                                # (with "tied": better across real voices, worse on espeak: docs/results.md)
    "vocal_context": 5,      # +-frames of audio the projection reads (projected only; latency)
    "guide": "ridge",        # or "none": the ridge's prediction of the face as evidence in the
                             # trajectory solve, or Brand's solve alone (docs/puppet.md)
    "guide_context": 5,      # +-frames of audio the guide's ridge reads (guide="ridge" only)
    "guide_weight": "cv",    # the guide's lambda: chosen from GUIDE_WEIGHTS by cross-validation on
                             # the training audio, or a number >= 0 (earlier versions: 4)
    "min_covar": 0.1,        # facial variance floor, x the mean data variance: chosen by CV (docs/results.md)
    "init": "kmeans",        # state means from k-means++, or "frames": random training frames
    "noise_snrs": (),        # SNRs (dB) of white-noise copies of the training audio the vocal side
                             # also learns from, for noisy audio (docs/puppet.md); () none
    "audio_level": -20.0,    # the feature option level_db the puppet is trained with, unless its
                             # feature set sets one: every recording it hears brought to this
                             # speech level (dBFS), frames 35 dB under it dither (pauses rest
                             # whatever the noise floor; docs/puppet.md); None: as recorded
    "seed": 0,
}
#: Test-time adaptation (``Puppet.animate(adapt=...)``): the kinds and the prior / iterations
#: used unless told otherwise (chosen on the leave-one-reader-out protocol, docs/results.md).
ADAPT_KINDS = ("full",)
ADAPT_DEFAULTS = {"tau": 30.0, "n_iter": 1}


@dataclass
class Animated:
    """What :meth:`Puppet.animate` returns.

    Attributes
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
    """A trained voice puppet. Build with :meth:`train` or :func:`load`."""

    def __init__(self, metadata: dict, arrays: dict):
        self.metadata = dict(metadata)
        self.arrays = {k: np.asarray(v) for k, v in arrays.items()}
        self._core = _core.Puppet(json.dumps(self.metadata), self.arrays)
        self.face_space = FaceSpace.from_arrays(self.arrays, self.metadata["parts"])
        self._rest: np.ndarray | bool | None = None  # rest_face(), found once

    # ------------------------------------------------------------------------- properties
    @property
    def fps(self) -> float:
        return float(self._core.fps)

    @property
    def feature_set(self):
        from voicepuppet.audio import FeatureSet

        return FeatureSet.from_json(self.metadata["feature_set"])

    @property
    def n_points(self) -> int:
        return int(self._core.n_points)

    @property
    def part_names(self) -> list:
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
        return int(self._core.n_states(part))

    #: Seconds of digital silence :meth:`rest_face` animates; it takes the middle frame.
    REST_SECONDS = 1.0

    def rest_face(self) -> np.ndarray | None:
        """The landmarks (P, 2) of the face the puppet makes in silence: its animation of
        :attr:`REST_SECONDS` of digital silence at the middle frame (a pause of its training
        video, decoded as any audio is). Rendering and export retarget an animation's motion
        from it (``Animation.neutral``, which :meth:`animate` sets to it), so audio that begins
        mid-word does not make its first, open-mouthed frame the photo's closed mouth. None for
        a puppet trained on given features (``features_list``): its silence is unknown."""
        if self._rest is None:
            from voicepuppet import audio as vaudio
            from voicepuppet.audio.loading import DEFAULT_RATE

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
        """
        return self._core.standardize(np.ascontiguousarray(raw, dtype=np.float64))[:, :self._core.n_features]

    def part_arrays(self, part: int = 0) -> dict:
        """The HMM arrays of one part: startprob, transmat, face_means, face_covars, vocal_means,
        vocal_covars."""
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
              progress: bool = False, client=None, **options) -> "Puppet":
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
        **options
            Overrides of :data:`TRAIN_DEFAULTS`.

        Returns
        -------
        Puppet

        numpy's BLAS runs on one thread while training (``VOICEPUPPET_BLAS_THREADS`` sets
        another count; an ``OPENBLAS_NUM_THREADS`` of your own is left alone:
        :func:`voicepuppet.blas.blas_threads`): on 2 cores, 180 s of training audio trains in
        about 5 s instead of 22.
        """
        from voicepuppet import audio as vaudio
        from voicepuppet.hmm.entropic import EntropicHMM, anneal_schedule, diagnostics
        from voicepuppet.hmm.gaussian import GaussianHMM

        unknown = set(options) - set(TRAIN_DEFAULTS)
        if unknown:
            raise ValueError(f"unknown training options {sorted(unknown)}; known: {sorted(TRAIN_DEFAULTS)}")
        opt = {**TRAIN_DEFAULTS, **options}
        if opt["prior"] not in ("entropic", "ml"):
            raise ValueError(f"prior must be 'entropic' or 'ml', got {opt['prior']!r}")
        if opt["vocal_covariance"] not in VOCAL_COVARIANCES:
            raise ValueError(f"vocal_covariance must be one of {VOCAL_COVARIANCES}, got "
                             f"{opt['vocal_covariance']!r}")
        if opt["vocal_features"] not in VOCAL_FEATURES:
            raise ValueError(f"vocal_features must be one of {VOCAL_FEATURES}, got {opt['vocal_features']!r}")
        _context_option(opt, "vocal_context", "the projection")
        if opt["guide"] not in GUIDES:
            raise ValueError(f"guide must be one of {GUIDES}, got {opt['guide']!r}")
        _context_option(opt, "guide_context", "the guide's ridge")
        gw = opt["guide_weight"]
        if gw != "cv" and (isinstance(gw, bool) or not isinstance(gw, (int, float, np.integer, np.floating))
                           or not (np.isfinite(gw) and gw >= 0)):
            raise ValueError(f"guide_weight must be 'cv' (chosen by cross-validation) or a finite number "
                             f">= 0, got {gw!r}")
        if opt["guide"] == "none" and "guide_weight" in options:
            raise ValueError("guide_weight weighs the guide's evidence; with guide='none' there is none: "
                             "drop guide_weight")
        if isinstance(points_list, np.ndarray) or not isinstance(points_list, (list, tuple)):
            points_list = [points_list]
        if (audio_list is None) == (features_list is None):
            raise ValueError("give either audio_list or features_list")
        sources = audio_list if audio_list is not None else features_list
        if isinstance(sources, np.ndarray) or not isinstance(sources, (list, tuple)):
            sources = [sources]
        if len(points_list) != len(sources) or not points_list:
            raise ValueError(f"give one audio per landmark sequence: {len(points_list)} landmark "
                             f"sequences, {len(sources)} audio")
        points_list = [check_landmarks(p, f"landmarks of sequence {i}") for i, p in enumerate(points_list)]
        lengths = np.array([len(p) for p in points_list])
        if lengths.sum() < 10 * opt["n_states"]:
            need = 10 * opt["n_states"]
            raise ValueError(f"{lengths.sum()} training frames ({lengths.sum() / fps:.1f} s at {fps:g} fps) are too "
                             f"few for {opt['n_states']} states: give at least 10 frames per state, {need} frames "
                             f"({need / fps:.1f} s) of video, or fewer states (n_states; train --states "
                             f"{max(lengths.sum() // 10, 1)})")

        fset = vaudio.as_feature_set(opt["feature_set"])
        if audio_list is not None:
            sources = [a if isinstance(a, vaudio.Audio) else vaudio.load_audio(a) for a in sources]
            fset = _training_band(training_feature_set(fset, opt["audio_level"]), sources)
            feats = [vaudio.extract(a, fps=fps, features=fset, n_out=int(n), progress=progress)
                     for a, n in zip(sources, lengths)]
            names = list(feats[0].names)
        else:
            feats = [np.asarray(f, dtype=np.float64) for f in sources]
            for i, (f, n) in enumerate(zip(feats, lengths)):
                if f.ndim != 2 or len(f) != n or f.shape[1] != feats[0].shape[1]:
                    raise ValueError(f"features_list[{i}] must have shape ({n}, A) with the same A "
                                     f"for all sequences (one row per landmark frame); got {f.shape}")
            names = [f"feature{j}" for j in range(feats[0].shape[1])]
        w = int(opt["audio_deltas"])
        if w < 0 or w != opt["audio_deltas"]:
            raise ValueError(f"audio_deltas must be an integer >= 0, got {opt['audio_deltas']!r}")
        raw = [f.values if hasattr(f, "values") else f for f in feats]
        ext = [_core.append_deltas(np.ascontiguousarray(f, dtype=np.float64), w) for f in raw]
        std = vaudio.Standardizer.fit(np.vstack(ext))
        A = np.vstack([std.transform(f) for f in ext])
        noisy = _noisy_conditions(sources if audio_list is not None else None, lengths, fps, fset, opt,
                                  lambda f: std.transform(_core.append_deltas(f, w)))

        fs = FaceSpace.fit(points_list, opt["n_components"], max_components=opt["max_components"],
                           parts=opt["parts"])
        Y = np.vstack([fs.encode(p)[0] for p in points_list])
        arrays = {"fps": np.array([float(fps)]), "audio/mean": std.mean, "audio/std": std.std,
                  "audio/delta_width": np.array([w], dtype=np.int64)}
        arrays.update(fs.to_arrays())
        report, gammas = [], []
        z = anneal_schedule(opt["n_iter"]) * opt["z"] if opt["anneal"] else opt["z"]
        model, prior = (EntropicHMM, dict(z=z, trim=True)) if opt["prior"] == "entropic" else (GaussianHMM, {})
        for k, sl in enumerate(fs.part_slices):
            O = observations(Y[:, sl], lengths)
            hmm = model(opt["n_states"], "full", n_iter=opt["n_iter"], min_covar=opt["min_covar"],
                              random_state=opt["seed"], init=opt["init"], progress=progress, **prior)
            if client is None:
                hmm.fit(O, lengths)
            else:
                from voicepuppet.hmm import distributed

                distributed.fit(hmm, O, lengths, client=client)
            gammas.append(hmm.predict_proba(O, lengths))
            pre = f"hmm/part{k}/"
            arrays.update({pre + "startprob": _start_distribution(gammas[-1], lengths),
                           pre + "transmat": hmm.transmat_,
                           pre + "face_means": hmm.means_, pre + "face_covars": hmm.covars_})
            diag = diagnostics(hmm, O, lengths)
            report.append({"part": fs.part_names[k], "face_dims": sl.stop - sl.start,
                           "iterations": len(hmm.history_),  # states and arcs (ints) from diag
                           **{key: v if isinstance(v, int) else float(v)
                              for key, v in diag.items() if np.isscalar(v)}})
        vocal, vocal_info = _fit_vocal_side(A, Y, lengths, gammas, opt, columns=raw[0].shape[1], noisy=noisy)
        arrays.update(vocal)
        from voicepuppet import __version__

        metadata = {"format": "voicepuppet puppet", "created_by": f"voicepuppet {__version__}",
                    "fps": float(fps), "n_points": int(points_list[0].shape[1]),
                    "parts": fs.part_names, "feature_set": fset.to_json(),
                    "feature_names": names, "training": {
                        "frames": int(lengths.sum()), "sequences": int(len(lengths)),
                        "options": _jsonable(opt), "parts": report}}
        metadata["training"].update(vocal_info)
        if opt["guide"] == "ridge" and opt["guide_weight"] == "cv":
            lam, mse = _cross_validated_guide_weight(metadata, arrays, raw, A, Y, lengths, gammas, opt,
                                                     noisy=noisy, progress=progress)
            arrays["guide/weight"] = np.array([lam])
            metadata["training"]["guide"]["weight"] = lam
            metadata["training"]["guide"]["weight_cv"] = {"weights": list(GUIDE_WEIGHTS), "mse": mse}
        return cls(metadata, arrays)

    # -------------------------------------------------------------------------- animation
    def audio_features(self, audio, n_out: int | None = None, progress: bool = False) -> np.ndarray:
        """Raw (unstandardised) features [T, A] of ``audio`` at the puppet's rate, with the
        puppet's feature set (:meth:`extract`'s values)."""
        return self.extract(audio, n_out=n_out, progress=progress, stacklevel=4).values

    def extract(self, audio, n_out: int | None = None, progress: bool = False, stacklevel: int = 2):
        """The :class:`voicepuppet.audio.Features` the puppet reads from ``audio`` (a file or
        :class:`voicepuppet.audio.Audio`): its feature set at its rate. Audio of a narrower band
        than the puppet analyses (8 kHz telephone audio for a puppet trained on wider-band sound)
        is warned about (``AudioWarning``, :meth:`check_band`)."""
        from voicepuppet import audio as vaudio

        audio = audio if isinstance(audio, vaudio.Audio) else vaudio.load_audio(audio)
        self.check_band(audio.source_rate, f"audio {audio.path!r}" if audio.path else "audio", stacklevel=stacklevel)
        return vaudio.extract(audio, fps=self.fps, features=self.feature_set, n_out=n_out, progress=progress)

    @property
    def band_hz(self) -> float:
        """The band (Hz) the puppet analyses audio in: its feature set's ``band_hz``, else the
        whole band of the 16 kHz analysis."""
        from voicepuppet.audio.loading import DEFAULT_RATE

        return float(self.feature_set.settings()["band_hz"] or 0.5 * DEFAULT_RATE)

    def check_band(self, source_rate: int, what: str = "audio", stacklevel: int = 2) -> None:
        """Warn (``AudioWarning``) when audio sampled at ``source_rate`` Hz is of a narrower band
        than the puppet learned (8 kHz telephone audio for a puppet of wider-band sound)."""
        from voicepuppet.audio import AudioWarning

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
                progress: bool = False) -> Animated:
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
            they are. Measured in docs/results.md ("test-time adaptation"): not the default.
        adapt_tau : float
            The prior's weight in frames (> 0; ``inf``: no adaptation, bit-identical to None).
        adapt_iter : int
            EM iterations (>= 1).
        guide_weight : float, optional
            λ of a guided puppet's evidence (the ridge's prediction of the face, weighted by the
            inverse covariance of its residuals): None (default) the file's — chosen at training
            by cross-validation on the training audio (files of earlier versions carry 4, the
            first guided ones 1) — 0 Brand's unguided solve, any λ >= 0. A positive value needs a guided
            puppet (:attr:`guided`). The choice is made on the voices of the training audio; a
            voice the puppet never heard may want a larger λ (docs/results.md, "The guide's
            weight chosen at training by cross-validation").
            Given states without audio are synthesised unguided.
        """
        out_fps = float(fps) if fps is not None else self.fps
        if out_fps <= 0 or not np.isfinite(out_fps):
            raise ValueError(f"fps must be positive, got {fps!r}")
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
                    features = self.audio_features(audio, progress=progress)
                r = self._core.animate_states_guided(s, sf, np.ascontiguousarray(features, dtype=np.float64),
                                                     out_fps, lam)
        else:
            if features is None:
                features = self.audio_features(audio, progress=progress)
            r = self._core.animate(np.ascontiguousarray(features, dtype=np.float64), out_fps, posterior,
                                   adapt or "none", float(adapt_tau), _count(adapt_iter, "adapt_iter"), lam)
            sf = self.fps
        pts = r["points"].reshape(len(r["points"]), -1, 2)
        return Animated(Animation(pts, out_fps, neutral=self.rest_face()), r["face"], r["states"], sf,
                        float(r["log_likelihood"]), list(r.get("transforms", [])))

    # ---------------------------------------------------------------------------- storage
    def save(self, path) -> Path:
        """Write the puppet file (``.vpp``) atomically."""
        p = check_output_path(path, (".vpp",), "puppet file")
        _core.write_puppet_file(os.fspath(p), json.dumps(self.metadata), self.arrays)
        return p


def training_feature_set(feature_set=None, audio_level=TRAIN_DEFAULTS["audio_level"]):
    """The feature set :meth:`Puppet.train` analyses training audio with for the options
    ``feature_set`` and ``audio_level`` (before the narrowest training audio's band): the set
    with its ``level_db`` set to ``audio_level`` unless it sets its own or ``audio_level`` is
    None. What to extract features with for ``Puppet.train(features_list=...)`` to train the
    puppet training from audio would."""
    from voicepuppet import audio as vaudio

    fset = vaudio.as_feature_set(TRAIN_DEFAULTS["feature_set"] if feature_set is None else feature_set)
    if audio_level is None or "level_db" in fset.options:
        return fset
    if isinstance(audio_level, bool) or not isinstance(audio_level, (int, float, np.integer, np.floating)):
        raise ValueError(f"audio_level must be a speech level in dBFS (e.g. -20) or None, got {audio_level!r}")
    return vaudio.FeatureSet(fset.features, {**fset.options, "level_db": float(audio_level)}, fset.name)


def _training_band(fset, sounds):
    """``fset`` with ``band_hz`` lowered to the narrowest training sound's band (half its
    source rate) when that is narrower than what ``fset`` analyses: the puppet then hears every
    audio as band-limited as its training audio was (8 kHz training audio and 16 kHz novel audio
    otherwise give features the vocal model never saw). A warning says so."""
    from voicepuppet import audio as vaudio

    band = fset.settings()["band_hz"] or 0.5 * min(a.rate for a in sounds)
    narrow = min(sounds, key=lambda a: a.source_rate)
    if 0.5 * narrow.source_rate >= band * (1 - 1e-9):
        return fset
    edge = 0.5 * narrow.source_rate
    where = f" {narrow.path!r}" if narrow.path else ""
    warnings.warn(f"training audio{where} is sampled at {narrow.source_rate} Hz (sound up to {edge:g} Hz): "
                  f"the puppet band-limits all audio to {edge:g} Hz (--audio-band), so wider-band "
                  "audio animates as its training audio sounded", vaudio.AudioWarning, stacklevel=3)
    return vaudio.FeatureSet(fset.features, {**fset.options, "band_hz": edge}, fset.name)


def _context_option(opt: dict, name: str, reader: str) -> int:
    """Training option ``name``: frames of audio on each side ``reader`` reads, an int in [0, 100]."""
    k = opt[name]
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= 100:
        raise ValueError(f"{name} must be an integer in [0, 100] (frames of audio on each side "
                         f"{reader} reads), got {k!r}")
    return int(k)


def _fit_vocal_side(A, Y, lengths, gammas, opt: dict, *, columns: int, noisy=()) -> tuple[dict, dict]:
    """Everything of a puppet that maps audio to the facial states, given the facial HMMs'
    occupancies ``gammas`` (one (T, N) per part) of the training frames: the guide (option
    ``guide``), the projection (``vocal_features``) and each part's vocal Gaussians (§4.3).
    ``A`` are the standardised features (T, A'), ``Y`` the face coordinates of all parts and
    ``columns`` the features' count without deltas; ``noisy`` holds the same frames' features
    in each noise condition (option ``noise_snrs``, :func:`_noisy_conditions`), which the vocal
    Gaussians also learn from with the same occupancies. Returns (arrays, metadata entries)."""
    arrays, info = {}, {}
    if opt["guide"] == "ridge":
        # The ridge baseline's map (features without deltas, its own alpha) and the covariance
        # of its cross-fitted residuals, in the puppet's face space: evidence in the solve.
        weight = GUIDE_WEIGHT if opt["guide_weight"] == "cv" else float(opt["guide_weight"])
        # Noisy conditions: the ridge learns from them too, each a copy of the clean sequences,
        # kept in their fold (so the residuals it is weighted by are of audio it has not heard).
        k = len(noisy) + 1
        guide, info["guide"] = fit_guide(np.vstack([A, *noisy]), np.vstack([Y] * k), list(lengths) * k,
                                         context=int(opt["guide_context"]), columns=columns, weight=weight,
                                         groups=np.tile(np.arange(len(lengths)), k) if noisy else None)
        arrays.update(guide)
    V = A
    if opt["vocal_features"] == "projected":
        # With context the map reads the features alone (its context can form their deltas).
        k = int(opt["vocal_context"])
        V, proj, info["projection"] = fit_projection(A, Y, lengths, context=k,
                                                     columns=columns if k != 0 else A.shape[1])
        arrays.update(proj)
    if len(noisy):
        V = np.vstack([V, *noisy])  # the projection refuses noisy conditions (Puppet.train)
    for p, gamma in enumerate(gammas):
        gamma = np.vstack([gamma] * (len(noisy) + 1))
        vm, vc = remap(gamma, V, opt["vocal_covariance"], shrinkage=opt["vocal_shrinkage"] * V.shape[1])
        arrays.update({f"hmm/part{p}/vocal_means": vm, f"hmm/part{p}/vocal_covars": vc})
    return arrays, info


def _noisy_conditions(sounds, lengths, fps, fset, opt, standardize) -> list:
    """The training audio's features in each noise condition of option ``noise_snrs``: for each
    SNR (dB), every sequence's audio with white Gaussian noise at that SNR (of the sequence's
    mean power; seeded by ``seed``) analysed as the clean audio is and ``standardize``d, stacked
    like the clean features: a list of (T, A') arrays, one per SNR (empty without the option)."""
    from voicepuppet import audio as vaudio

    snrs = () if opt["noise_snrs"] is None else opt["noise_snrs"]
    if isinstance(snrs, (int, float, str)) or not all(isinstance(v, (int, float, np.integer, np.floating))
                                                 and not isinstance(v, bool) and np.isfinite(v) for v in snrs):
        raise ValueError(f"noise_snrs must be a list of SNRs in dB (e.g. [20, 10]), got {snrs!r}")
    if not len(snrs):
        return []
    if sounds is None:
        raise ValueError("noise_snrs adds noise to the training audio: give audio_list, not features_list")
    if opt["vocal_features"] != "audio":
        raise ValueError("noise_snrs trains the vocal Gaussians on the audio features: use it with "
                         "vocal_features='audio'")
    rng = np.random.default_rng([int(opt["seed"]), 20261203])
    out = []
    for snr in snrs:
        rows = []
        for a, n in zip(sounds, lengths):
            power = float(np.mean(a.samples ** 2)) if a.samples.size else 0.0
            x = a.samples + rng.normal(0.0, np.sqrt(power / 10.0 ** (float(snr) / 10.0)), a.samples.shape)
            with warnings.catch_warnings():  # the copy's clipping is ours, not the user's recording's
                warnings.simplefilter("ignore", vaudio.AudioWarning)
                noisy = vaudio.prepare(np.clip(x, -1.0, 1.0), a.rate, target_rate=None, remove_dc=False)
            f = vaudio.extract(noisy, fps=fps, features=fset, n_out=int(n)).values
            rows.append(standardize(np.ascontiguousarray(f, dtype=np.float64)))
        out.append(np.vstack(rows))
    return out


def _cross_validated_guide_weight(metadata, arrays, raw, A, Y, lengths, gammas, opt, *, noisy=(),
                                  progress: bool = False) -> tuple[float, list]:
    """λ of :data:`GUIDE_WEIGHTS` with the least squared error of the face on held-out
    training audio (training option ``guide_weight="cv"``).

    Over the folds of :func:`cross_fit_folds`, the vocal side (guide, projection, vocal
    Gaussians: :func:`_fit_vocal_side`) is refitted on the other folds, with the facial HMMs and
    their occupancies of the training frames kept, and each held-out run of frames is animated
    from its raw features ``raw``: decoded once (Viterbi), its trajectory solved at every λ.
    Returns the λ and the mean squared error per frame for each λ (in the face coordinates of
    all parts)."""
    from tqdm.auto import tqdm

    seq = np.repeat(np.arange(len(lengths)), lengths)
    bounds = np.concatenate([[0], np.cumsum(lengths)])
    weights = [float(lam) for lam in GUIDE_WEIGHTS]
    sse = np.zeros(len(weights))
    folds = cross_fit_folds(lengths)
    for fold in tqdm(folds, desc="guide weight (cross-validation)", unit="fold", disable=not progress,
                     leave=False):
        rest = np.setdiff1d(np.arange(len(A)), fold)
        rest_lengths = [len(r) for r in sequence_runs(rest, seq)]
        try:
            vocal, _ = _fit_vocal_side(A[rest], Y[rest], rest_lengths, [g[rest] for g in gammas], opt,
                                       columns=raw[0].shape[1], noisy=[N[rest] for N in noisy])
        except ValueError as exc:  # a fold too small for what the puppet fits: say which step
            raise ValueError(f"choosing the guide's weight by cross-validation on {len(A)} training "
                             f"frames: {exc}; or fix the weight (guide_weight={GUIDE_WEIGHT:g})") from None
        core = _core.Puppet(json.dumps(metadata), {**arrays, **vocal})
        for piece in sequence_runs(fold, seq):
            s = seq[piece[0]]
            x = np.ascontiguousarray(raw[s][piece - bounds[s]], dtype=np.float64)
            faces = core.animate_faces(x, weights)
            sse += [float(np.sum((face - Y[piece]) ** 2)) for face in faces]
    mse = [float(v) / len(A) for v in sse]
    return weights[int(np.argmin(sse))], mse


def _start_distribution(gamma: np.ndarray, lengths) -> np.ndarray:
    """The start distribution a puppet decodes novel audio from: the occupancies of the training
    sequences' first frames, with one more sequence's worth drawn from the occupancy of all frames.

    The HMM's own start vector learns where the training sequences began: from one video, a point
    mass on its first state, so that every animation would have to begin in the face the video
    began with. Novel audio may begin anywhere in the performer's manner; from many utterances
    the starts stay informative (they begin in silence, as recordings do) and the occupancy
    only smooths them."""
    firsts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    start = gamma[firsts].sum(axis=0) + gamma.mean(axis=0)
    return start / start.sum()


def _count(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


def _jsonable(value):
    """Options as plain JSON values (ranges, arrays and dicts of them become lists and dicts)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (range, list, tuple, np.ndarray)):
        return [_jsonable(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "to_json"):  # a FeatureSet
        return json.loads(value.to_json())
    return value


def load(path) -> Puppet:
    """Read a puppet file (``.vpp``); ValueError names what is wrong with a damaged one."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"puppet file {str(p)!r} does not exist")
    metadata, arrays = _core.read_puppet_file(os.fspath(p))
    try:
        meta = json.loads(metadata)
    except json.JSONDecodeError as exc:
        raise ValueError(f"puppet file {str(p)!r} has unreadable metadata ({exc}); the file is damaged") from None
    if not isinstance(meta, dict) or "parts" not in meta or "feature_set" not in meta:
        raise ValueError(f"puppet file {str(p)!r} lacks its part list or feature set; it was not written "
                         "by voicepuppet train")
    for part in meta.get("training", {}).get("parts", []):  # files before 2026-12-03 stored floats
        for key in ("states", "arcs"):
            if key in part:
                part[key] = int(part[key])
    return Puppet(meta, arrays)


#: Vocal covariance models of :func:`remap` (training option ``vocal_covariance``).
VOCAL_COVARIANCES = ("full", "diag", "tied")


def remap(gamma, features, covariance: str = "full", floor: float = 1e-3, shrinkage=None):
    """Vocal Gaussians per state from occupancies and synchronous features (§4.3).

    Parameters
    ----------
    gamma : array (T, N)
        State occupancies of the training frames under the facial HMM.
    features : array (T, A)
        Standardised audio features of the same frames.
    covariance : {"full", "diag", "tied"}
        ``"tied"``: one full covariance for all states, the pooled within-state scatter
        ``Σ_i S_i / Σ_i w_i`` (a linear-discriminant vocal model: the states differ by their
        means only), returned as N equal copies so a puppet file stores it as "full".
    floor : float
        Added to every variance (the features are standardised, so this is relative).
    shrinkage : float, optional
        κ, frames of evidence given to the pooled Gaussian (default: A, the feature count).

    Returns
    -------
    means : (N, A)
        ``(Σ_t γ_ti x_t + κ x̄) / (w_i + κ)``: each state's weighted mean shrunk towards the
        pooled mean ``x̄`` with κ frames of evidence (``w_i = Σ_t γ_ti``).
    covars : (N, A, A) for "full" and "tied", (N, A) for "diag"
        "full" / "diag": ``(S_i + κ Σ) / (w_i + κ)``, the weighted scatter ``S_i`` of state i about
        its mean shrunk towards the pooled covariance ``Σ`` with κ frames of evidence; "tied":
        ``Σ_i S_i / Σ_i w_i`` for every state; each plus ``floor`` on the variances.
    """
    g = np.asarray(gamma, dtype=np.float64)
    X = np.asarray(features, dtype=np.float64)
    if g.ndim != 2 or X.ndim != 2 or len(g) != len(X):
        raise ValueError(f"gamma (T, N) and features (T, A) must have the same frames; got {g.shape} "
                         f"and {X.shape}")
    if covariance not in VOCAL_COVARIANCES:
        raise ValueError(f"covariance must be one of {VOCAL_COVARIANCES}, got {covariance!r}")
    A = X.shape[1]
    kappa = float(A) if shrinkage is None else float(shrinkage)
    if not (kappa >= 0 and np.isfinite(kappa)):
        raise ValueError(f"shrinkage must be a finite number >= 0, got {shrinkage!r}")
    w = g.sum(axis=0)
    mu_all = X.mean(axis=0)
    pooled = np.cov(X, rowvar=False, bias=True).reshape(A, A)
    means = (g.T @ X + kappa * mu_all) / (w + kappa)[:, None]
    if covariance == "diag":
        covs = np.empty((g.shape[1], A))
        for i in range(g.shape[1]):
            d = X - means[i]
            covs[i] = (g[:, i] @ (d * d) + kappa * np.diag(pooled)) / (w[i] + kappa) + floor
        return means, covs
    if covariance == "tied":
        scatter = np.zeros((A, A))
        for i in range(g.shape[1]):
            d = X - means[i]
            scatter += (d * g[:, i:i + 1]).T @ d
        tied = scatter / w.sum() + floor * np.eye(A)
        tied = 0.5 * (tied + tied.T)
        return means, np.repeat(tied[None], g.shape[1], axis=0)
    covs = np.empty((g.shape[1], A, A))
    for i in range(g.shape[1]):
        d = X - means[i]
        covs[i] = ((d * g[:, i:i + 1]).T @ d + kappa * pooled) / (w[i] + kappa) + floor * np.eye(A)
        covs[i] = 0.5 * (covs[i] + covs[i].T)
    return means, covs
