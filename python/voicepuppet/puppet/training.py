"""Training a voice puppet (Voice Puppetry §4): the options, the facial HMMs, the remap of their
states into audio-feature space (§4.3), the guide and its weight.

:func:`train` is the one pass :meth:`voicepuppet.puppet.model.Puppet.train` runs (the steps are
listed in :mod:`voicepuppet.puppet.model`); :class:`TrainOptions` holds and checks its options.
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from dataclasses import dataclass
from typing import Any, Optional, Union

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import _core
from voicepuppet import audio as vaudio
from voicepuppet._version import __version__
from voicepuppet.face import FaceSpace, check_landmarks, observations
from voicepuppet.hmm import distributed
from voicepuppet.hmm.entropic import EntropicHMM, anneal_schedule
from voicepuppet.hmm.diagnostics import diagnostics
from voicepuppet.hmm.gaussian import GaussianHMM
from voicepuppet.puppet.guide import (GUIDE_ALPHAS, GUIDE_WEIGHT, GUIDE_WEIGHTS, GUIDES, VOCAL_FEATURES,
                                     cross_fit_folds, fit_guide, fit_projection, lips_score, sequence_runs)

__all__ = ["TrainOptions", "TRAIN_DEFAULTS", "VOCAL_COVARIANCES", "TRAINED_MOTION_GAIN", "check_option_names",
           "train", "training_feature_set", "remap"]

#: Vocal covariance models of :func:`remap` (training option ``vocal_covariance``).
VOCAL_COVARIANCES = ("full", "diag", "tied")
#: The most training widens a face coordinate's motion (``face/motion_gain``; files may hold up to
#: :data:`voicepuppet.trajectory.MAX_MOTION_GAIN`): at 3, voices other than the training
#: speaker's, which the guide already moves more, opened the mouth up to 2.5 times as wide as
#: their own speakers' (docs/results.md, "Real people").
TRAINED_MOTION_GAIN = 2.0


def _check_context(k, name: str, reader: str) -> None:
    """Training option ``name``: frames of audio on each side ``reader`` reads, an int in [0, 100]."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= 100:
        raise ValueError(f"{name} must be an integer in [0, 100] (frames of audio on each side "
                         f"{reader} reads), got {k!r}")


@dataclass(frozen=True)
class TrainOptions:
    """What :meth:`Puppet.train <voicepuppet.puppet.model.Puppet.train>` does, beyond its data
    (recorded in each puppet's metadata). Checked when made: a ValueError names a bad value.
    Each parameter is kept as the (read-only: the dataclass is frozen) attribute of the same name.

    Parameters
    ----------
    n_states : int, default 40
        States each facial HMM starts with, fully connected (Brand: start large and let the
        entropic prior trim).
    n_iter : int, default 40
        EM iterations.
    prior : {"entropic", "ml"}, default "entropic"
        Entropic MAP estimation, or conventional Baum-Welch (for comparison).
    z : float, default 1.0
        Weight of the entropic prior (1: minimum entropy).
    anneal : bool, default True
        Ramp z from -1 to 1 over the first half of the iterations.
    n_components : float or int, default 0.98
        Face basis per part: the fraction of variance kept, or a number of components.
    max_components : int, default 12
        At most this many components per part.
    parts : None, "upper_lower" or dict, default None
        One face model (None), the upper and lower face of the 68-point layout, or
        name -> point indices.
    feature_set : str or FeatureSet, default "puppet"
        The audio features (see :mod:`voicepuppet.audio`).
    audio_deltas : int, default 2
        Regression deltas over +-this many frames appended to the audio features.
    vocal_covariance : {"full", "diag", "tied"}, default "full"
        Covariance of each state's vocal Gaussian (:func:`remap`).
    vocal_shrinkage : float, default 1.0
        Evidence of the pooled Gaussian in each state's, in units of the feature count (frames).
    vocal_features : {"audio", "projected"}, default "audio"
        Remap on the audio features, or on the ridge's cross-fitted face prediction
        (:func:`voicepuppet.puppet.guide.fit_projection`).
    vocal_context : int, default 5
        Frames of audio on each side the projection reads (projected only), 0..100.
    guide : {"ridge", "none"}, default "ridge"
        The ridge's prediction of the face as evidence in the trajectory solve, or Brand's solve
        alone.
    guide_context : int, default 5
        Frames of audio on each side the guide's ridge reads, 0..100.
    guide_weight : "cv" or float, default "cv"
        The guide's weight: chosen from :data:`voicepuppet.puppet.guide.GUIDE_WEIGHTS` by
        cross-validation on the training audio, or a number >= 0.
    guide_alpha : {"shared", "per_coordinate", "lips"}, default "shared"
        The guide's ridge regularisation, chosen by cross-validation: one α for all face
        coordinates, one per coordinate, or one for all chosen on the error of the lips' points
        (68-point layout).
    min_covar : float, default 0.1
        Facial variance floor, times the mean data variance.
    init : {"kmeans", "frames"}, default "kmeans"
        State means from k-means++, or random training frames.
    noise_snrs : sequence of float, default ()
        SNRs (dB) of white-noise copies of the training audio that the vocal side also learns
        from; empty: none.
    audio_level : float or None, default -20.0
        The speech level (dBFS) every recording is brought to before analysis (the feature
        option ``level_db``, unless the feature set sets one); None: as recorded.
    seed : int, default 0
        Seeds everything random in training.

    Raises
    ------
    ValueError
        ``prior``, ``vocal_covariance``, ``vocal_features``, ``guide`` or ``guide_alpha`` not one of
        its values, ``vocal_context`` or ``guide_context`` not an integer in [0, 100], ``guide_weight`` not
        "cv" or a finite number >= 0, or a numeric ``guide_weight`` with ``guide="none"``.
    """

    n_states: int = 40
    n_iter: int = 40
    prior: str = "entropic"
    z: float = 1.0
    anneal: bool = True
    n_components: Union[float, int] = 0.98
    max_components: int = 12
    parts: Any = None
    feature_set: Any = "puppet"
    audio_deltas: int = 2
    vocal_covariance: str = "full"
    vocal_shrinkage: float = 1.0
    vocal_features: str = "audio"
    vocal_context: int = 5
    guide: str = "ridge"
    guide_context: int = 5
    guide_weight: Union[str, float] = "cv"
    guide_alpha: str = "shared"
    min_covar: float = 0.1
    init: str = "kmeans"
    noise_snrs: Any = ()
    audio_level: Optional[float] = -20.0
    seed: int = 0

    def as_dict(self) -> dict:
        """The options as a dict, option name -> value (values as given: not copied or converted).

        Returns
        -------
        dict
            One entry per option, in the order of the fields.
        """
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def __post_init__(self):
        if self.prior not in ("entropic", "ml"):
            raise ValueError(f"prior must be 'entropic' or 'ml', got {self.prior!r}")
        if self.vocal_covariance not in VOCAL_COVARIANCES:
            raise ValueError(f"vocal_covariance must be one of {VOCAL_COVARIANCES}, got "
                             f"{self.vocal_covariance!r}")
        if self.vocal_features not in VOCAL_FEATURES:
            raise ValueError(f"vocal_features must be one of {VOCAL_FEATURES}, got {self.vocal_features!r}")
        _check_context(self.vocal_context, "vocal_context", "the projection")
        if self.guide not in GUIDES:
            raise ValueError(f"guide must be one of {GUIDES}, got {self.guide!r}")
        _check_context(self.guide_context, "guide_context", "the guide's ridge")
        mc = self.max_components
        if isinstance(mc, bool) or not isinstance(mc, (int, np.integer)) or mc < 1:
            raise ValueError(f"max_components must be an integer >= 1 (components of the face basis per part), "
                             f"got {mc!r}")
        if self.guide_alpha not in GUIDE_ALPHAS:
            raise ValueError(f"guide_alpha must be one of {GUIDE_ALPHAS}, got {self.guide_alpha!r}")
        gw = self.guide_weight
        if gw != "cv" and (isinstance(gw, bool) or not isinstance(gw, (int, float, np.integer, np.floating))
                           or not (np.isfinite(gw) and gw >= 0)):
            raise ValueError(f"guide_weight must be 'cv' (chosen by cross-validation) or a finite number "
                             f">= 0, got {gw!r}")
        if self.guide == "none" and gw != "cv":
            raise ValueError("guide_weight weighs the guide's evidence; with guide='none' there is none: "
                             "drop guide_weight")


_DEFAULT = TrainOptions()
#: The defaults of :class:`TrainOptions` as a dict (option name -> value).
TRAIN_DEFAULTS = _DEFAULT.as_dict()


def check_option_names(options: dict, what: str) -> None:
    """Refuses the keys of ``options`` that name no training option (``seed`` too: the caller
    sets it), before any training starts.

    Parameters
    ----------
    options : dict
        Option name -> value, as given to :meth:`voicepuppet.puppet.model.Puppet.train`.
    what : str
        Whose options they are, for the message (e.g. ``"variant 'a'"``).

    Raises
    ------
    ValueError
        Naming the unknown keys and the known ones.
    """
    known = set(TRAIN_DEFAULTS) - {"seed"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ValueError(f"{what} has unknown training options {unknown}; known: {sorted(known)}")


def train(points_list, audio_list=None, *, features_list=None, fps: float = 29.97,
          options: TrainOptions = _DEFAULT, progress: bool = False, client=None) -> tuple[dict, dict]:
    """Train a puppet: its metadata and arrays (what a puppet file holds).

    Parameters
    ----------
    points_list, audio_list, features_list, fps, progress, client
        As for :meth:`voicepuppet.puppet.model.Puppet.train`.
    options : TrainOptions
        The training options (default: :class:`TrainOptions` ``()``, the defaults).

    Returns
    -------
    metadata : dict
        The puppet file's metadata: format, version, frame rate, points, parts, feature set and
        names, and the training record (frames, sequences, options, per-part diagnostics, guide
        and projection details).
    arrays : dict of str to ndarray
        The puppet file's arrays (frame rate, audio standardisation, face space, each part's
        HMM and vocal Gaussians, the guide and projection when trained).

    Raises
    ------
    ValueError
        Neither or both of ``audio_list`` and ``features_list``, not one audio per landmark
        sequence, too few frames for ``n_states`` (at least 10 per state), features of the
        wrong shape, a negative ``audio_deltas``, or a bad option.
    """
    opt = options.as_dict()
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
    score = lips_score(fs) if opt["guide"] == "ridge" and opt["guide_alpha"] == "lips" else None
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
    vocal, vocal_info = _fit_vocal_side(A, Y, lengths, gammas, opt, columns=raw[0].shape[1], noisy=noisy,
                                        score=score)
    arrays.update(vocal)
    metadata = {"format": "voicepuppet puppet", "created_by": f"voicepuppet {__version__}",
                "fps": float(fps), "n_points": int(points_list[0].shape[1]),
                "parts": fs.part_names, "feature_set": fset.to_json(),
                "feature_names": names, "training": {
                    "frames": int(lengths.sum()), "sequences": int(len(lengths)),
                    "options": _jsonable(opt), "parts": report}}
    metadata["training"].update(vocal_info)
    if opt["guide"] == "ridge" and opt["guide_weight"] == "cv":
        lam, mse, mse_raw, gain = _cross_validated_guide_weight(metadata, arrays, raw, A, Y, lengths, gammas,
                                                                opt, noisy=noisy, score=score, progress=progress)
        arrays["guide/weight"] = np.array([lam])
        arrays["face/motion_gain"] = gain
        metadata["training"]["guide"]["weight"] = lam
        metadata["training"]["guide"]["weight_cv"] = {"weights": list(GUIDE_WEIGHTS), "mse": mse,
                                                      "mse_raw": mse_raw}
    return metadata, arrays


def training_feature_set(feature_set=None, audio_level=_DEFAULT.audio_level):
    """The feature set :meth:`Puppet.train` analyses training audio with for the options
    ``feature_set`` and ``audio_level`` (before the narrowest training audio's band): the set
    with its ``level_db`` set to ``audio_level`` unless it sets its own or ``audio_level`` is
    None. What to extract features with for ``Puppet.train(features_list=...)`` to train the
    puppet training from audio would.

    Parameters
    ----------
    feature_set : str or FeatureSet, optional
        The training option ``feature_set`` (default: its default, ``"puppet"``).
    audio_level : float or None
        The training option ``audio_level``, speech level in dBFS (default -20); None: as recorded.

    Returns
    -------
    voicepuppet.audio.FeatureSet
        The feature set, with ``level_db`` set when it applies.

    Raises
    ------
    ValueError
        ``audio_level`` neither a number nor None (when the set has no ``level_db`` of its own),
        or a ``feature_set`` with an unknown feature name.
    """
    fset = vaudio.as_feature_set(_DEFAULT.feature_set if feature_set is None else feature_set)
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


def _fit_vocal_side(A, Y, lengths, gammas, opt: dict, *, columns: int, noisy=(), score=None) -> tuple[dict, dict]:
    """Everything of a puppet that maps audio to the facial states, given the facial HMMs'
    occupancies ``gammas`` (one (T, N) per part) of the training frames: the guide (option
    ``guide``), the projection (``vocal_features``) and each part's vocal Gaussians (§4.3).
    ``A`` are the standardised features (T, A'), ``Y`` the face coordinates of all parts and
    ``columns`` the features' count without deltas; ``noisy`` holds the same frames' features
    in each noise condition (option ``noise_snrs``, :func:`_noisy_conditions`), which the vocal
    Gaussians also learn from with the same occupancies; ``score``: the guide's α is chosen on it
    (``guide_alpha="lips"``: :func:`lips_score`). Returns (arrays, metadata entries)."""
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
                                         alpha=opt["guide_alpha"], score=score,
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


def _cross_validated_guide_weight(metadata, arrays, raw, A, Y, lengths, gammas, opt, *, noisy=(), score=None,
                                  progress: bool = False) -> tuple[float, list, list, np.ndarray]:
    """λ of :data:`GUIDE_WEIGHTS` with the least squared error of the face's motion on held-out
    training audio (training option ``guide_weight="cv"``).

    Over the folds of :func:`cross_fit_folds`, the vocal side (guide, projection, vocal
    Gaussians: :func:`_fit_vocal_side`) is refitted on the other folds, with the facial HMMs and
    their occupancies of the training frames kept, and each held-out run of frames is animated
    from its raw features ``raw``: decoded once (Viterbi), its trajectory solved at every λ.
    The error is measured about each held-out run's own mean, in the animation and the truth
    alike: a recording's resting face (its head pose, lighting, the tracker's bias on it) is
    no motion the audio can tell, and on real sessions it outweighed the motion, so that the
    choice swung from 0 to 256 with the sessions trained on (docs/results.md, "Real people").
    Returns the λ, the mean squared error per frame about the runs' means for each λ (in the
    face coordinates of all parts), the same error with the means (``mse_raw``) and, per face
    coordinate, how much less the held-out animations at that λ move than the training faces:
    the square root of the ratio of the two's variances about each held-out run's own mean, at
    least 1 (what ``Puppet.animate(full_motion=True)`` widens by)."""
    seq = np.repeat(np.arange(len(lengths)), lengths)
    bounds = np.concatenate([[0], np.cumsum(lengths)])
    weights = [float(lam) for lam in GUIDE_WEIGHTS]
    sse, sse_raw = np.zeros(len(weights)), np.zeros(len(weights))
    moved = np.zeros((len(weights), Y.shape[1]))  # Σ over held-out runs of (face - its mean)²
    truth_moved = np.zeros(Y.shape[1])
    folds = cross_fit_folds(lengths)
    for fold in tqdm(folds, desc="guide weight (cross-validation)", unit="fold", disable=not progress,
                     leave=False):
        rest = np.setdiff1d(np.arange(len(A)), fold)
        rest_lengths = [len(r) for r in sequence_runs(rest, seq)]
        try:
            vocal, _ = _fit_vocal_side(A[rest], Y[rest], rest_lengths, [g[rest] for g in gammas], opt,
                                       columns=raw[0].shape[1], noisy=[N[rest] for N in noisy], score=score)
        except ValueError as exc:  # a fold too small for what the puppet fits: say which step
            raise ValueError(f"choosing the guide's weight by cross-validation on {len(A)} training "
                             f"frames: {exc}; or fix the weight (guide_weight={GUIDE_WEIGHT:g})") from None
        core = _core.Puppet(json.dumps(metadata), {**arrays, **vocal})
        for piece in sequence_runs(fold, seq):
            s = seq[piece[0]]
            x = np.ascontiguousarray(raw[s][piece - bounds[s]], dtype=np.float64)
            faces = core.animate_faces(x, weights)
            truth_motion = Y[piece] - Y[piece].mean(axis=0)
            sse += [float(np.sum((face - face.mean(axis=0) - truth_motion) ** 2)) for face in faces]
            sse_raw += [float(np.sum((face - Y[piece]) ** 2)) for face in faces]
            moved += [np.sum((face - face.mean(axis=0)) ** 2, axis=0) for face in faces]
            truth_moved += np.sum(truth_motion ** 2, axis=0)
    mse, mse_raw = [float(v) / len(A) for v in sse], [float(v) / len(A) for v in sse_raw]
    best = int(np.argmin(sse))
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.sqrt(np.where(moved[best] > 0, truth_moved / moved[best], 1.0))
    return weights[best], mse, mse_raw, np.clip(gain, 1.0, TRAINED_MOTION_GAIN)


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
        Added to every variance (default 1e-3; the features are standardised, so this is relative).
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

    Raises
    ------
    ValueError
        ``gamma`` and ``features`` not 2-D with the same frames, ``covariance`` not one of
        :data:`VOCAL_COVARIANCES`, or ``shrinkage`` negative or not finite.
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
