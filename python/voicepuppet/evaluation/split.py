"""Evaluating a puppet against ground truth (Voice Puppetry §5.1), with baselines.

For a train/test split of landmark sequences with their audio, :func:`evaluate_split` measures:

- ``states``: reconstruction from the facial state sequence (Viterbi on the *facial* HMM of the
  true motion, then the closed-form trajectory): what the state machine can express.
- ``voice``: voice-driven synthesis (Viterbi on the vocal HMM); ``voice-posterior``: the
  posterior-weighted synthesis (§5).
- ``mean-face``: the mean training face, every frame (Err = 1 by construction).
- ``ridge``: per-frame ridge regression from the standardised audio features with ±5 frames of
  context to the face coordinates (regularisation chosen by 5-fold blocked cross-validation on
  the training frames; the features' deltas are left out, as a linear map over the context can
  form them).

Every prediction is compared in the same way: Err (eq. 7), L1/RMS/L∞ on face coordinates (pose
removed), and, with the true head pose re-applied to the prediction (the puppet models the face,
not where the head goes), landmark RMSE / inter-ocular distance, lip vertex error and, where the
sequences come with the frames of B, P, M, the share of those the prediction closes. Model
measures: perplexity, context memory (frames), entropy rate of decoding the test audio (nats per
frame), and bits per frame of the LZMA-compressed state sequence (the "coding" of §5.1).
"""

from __future__ import annotations

import lzma

import numpy as np

from voicepuppet import _core
from voicepuppet import audio as vaudio
from voicepuppet.blas import limited
from voicepuppet.evaluation import metrics
from voicepuppet.face import observations
from voicepuppet.hmm.diagnostics import entropy_rate
from voicepuppet.puppet.guide import RidgeBaseline

#: The row of a guided puppet animated without its guide (``guide_weight=0``: Brand's solve).
UNGUIDED_ROW = "voice, unguided (Brand §4.5)"
#: The row of the puppet's most probable trajectory, not widened to the training motion
#: (``full_motion=False``).
MOST_PROBABLE_ROW = "voice, most probable"


def facial_states(puppet, points) -> np.ndarray:
    """Viterbi states of the facial HMM for true motion ``points`` [T, P, 2]: (T, parts).

    Parameters
    ----------
    puppet : voicepuppet.puppet.model.Puppet
        The puppet whose facial HMMs decode the motion.
    points : ndarray, shape (T, P, 2)
        Landmarks of one sequence.

    Returns
    -------
    ndarray of int64, shape (T, parts)
        The Viterbi state of each face part at each frame.
    """
    Y, _ = puppet.face_space.encode(points)
    cols = []
    for k, sl in enumerate(puppet.face_space.part_slices):
        arr = puppet.part_arrays(k)
        O = np.ascontiguousarray(observations(Y[:, sl]))
        n, d2 = arr["face_means"].shape
        log_b = _core.gaussian_log_density(O, arr["face_means"], arr["face_covars"].reshape(n * d2, d2), "full")
        _, path = _core.viterbi(log_b, arr["startprob"], arr["transmat"], np.array([len(O)], dtype=np.int64))
        cols.append(path)
    return np.stack(cols, axis=1).astype(np.int64)


def bits_per_frame(states) -> float:
    """Size of the LZMA-compressed state sequence in bits per frame (raw LZMA2 stream, no
    container header).

    Parameters
    ----------
    states : array_like of int, shape (T,)
        A state sequence (states >= 0).

    Returns
    -------
    float
        Compressed bits per frame (LZMA2, preset 9).
    """
    s = np.asarray(states, dtype=np.uint8 if np.max(states) < 256 else np.uint16)
    packed = lzma.compress(s.tobytes(), format=lzma.FORMAT_RAW,
                           filters=[{"id": lzma.FILTER_LZMA2, "preset": 9}])
    return 8.0 * len(packed) / len(s)


def decoding_entropy_rate(puppet, features) -> float:
    """Entropy rate (nats per frame) of the vocal HMM's posterior over state sequences.

    Parameters
    ----------
    puppet : voicepuppet.puppet.model.Puppet
        The puppet whose vocal HMMs decode the audio.
    features : array_like, shape (T, A)
        Raw audio features at the puppet's rate.

    Returns
    -------
    float
        :func:`voicepuppet.hmm.diagnostics.entropy_rate` of each part's vocal HMM, averaged over parts.
    """
    z = puppet._core.standardize(np.ascontiguousarray(features, dtype=np.float64))
    rates = []
    for k in range(len(puppet.part_names)):
        arr = puppet.part_arrays(k)
        rates.append(entropy_rate(puppet._core.vocal_log_density(z, k), arr["startprob"], arr["transmat"]))
    return float(np.mean(rates))


def compare(pred_face, true_points, face_space, must_close=None) -> dict:
    """Measures of predicted face coordinates against true landmarks (true pose re-applied).

    Parameters
    ----------
    pred_face : ndarray, shape (T', K)
        Predicted face coordinates in ``face_space``.
    true_points : ndarray, shape (T, P, 2)
        True landmarks; both are cut to the shorter of T and T'.
    face_space : voicepuppet.face.FaceSpace
        The face space of the prediction (the puppet's).
    must_close : array_like of bool, shape (T,), optional
        The frames of B, P, M.

    Returns
    -------
    dict
        ``err``, ``l1``, ``rms``, ``linf`` on face coordinates; with 68 points also
        ``rmse_iod`` and ``lve`` on the landmarks and, with ``must_close`` and at least one run of
        it, ``closed`` (the share of their runs the prediction closes,
        :func:`voicepuppet.evaluation.metrics.closures`) and ``closed_runs``.
    """
    true_face, pose = face_space.encode(true_points)
    T = min(len(pred_face), len(true_face))
    pf, tf = pred_face[:T], true_face[:T]
    out = {"err": metrics.err(pf, tf), "l1": metrics.l1(pf, tf), "rms": metrics.rms(pf, tf),
           "linf": metrics.linf(pf, tf)}
    if true_points.shape[1] == 68:
        pts = face_space.decode(pf, pose[:T])
        out["rmse_iod"] = metrics.landmark_rmse_iod(pts, true_points[:T])
        out["lve"] = metrics.lip_vertex_error(pts, true_points[:T])
        if must_close is not None:
            closed, runs = metrics.closures(pts, true_points[:T], np.asarray(must_close, bool)[:T])
            if runs:
                out["closed"], out["closed_runs"] = closed / runs, runs
    return out


@limited
def evaluate_split(puppet, train, tests, *, fit_points=None, posterior: bool = True,
                   cache: dict | None = None) -> dict:
    """Measure a puppet and the baselines on its training data and held-out data.

    Parameters
    ----------
    puppet : voicepuppet.puppet.model.Puppet
    train : list of (points [T, P, 2], audio) or (points, audio, must_close [T] bool)
        The training sequences, with the landmarks every prediction is measured against (and,
        where given, the frames of B, P, M: the ``closed`` measure).
    tests : list of (points, audio) or (points, audio, must_close)
        Held-out sequences.
    fit_points : list of [T, P, 2] arrays, optional
        The landmarks the puppet was trained on, one per training sequence, when they are not
        ``train``'s (a puppet trained on tracked landmarks, measured against the ground truth):
        the ridge baseline is fitted on these too, so both learn from the same data.
    posterior : bool
        Also measure posterior-weighted synthesis (the ``voice-posterior`` row; default True).
    cache : dict, optional
        Audio features by (split, index); pass the same dict when evaluating several puppets
        with one feature set on the same data.

    Returns
    -------
    dict
        ``rows``: {method: {"train": {...}, "test": {...}}} with the measures averaged over
        sequences (weighted by frames); ``model``: perplexity, context memory, entropy rate of
        decoding the test audio, bits per frame of the state coding, states and arcs, the guide's
        weight (None without a guide) and whether it was chosen by cross-validation.

    Raises
    ------
    ValueError
        ``fit_points`` without one array per training sequence of its frame count.
    """
    fs = puppet.face_space
    feats = {} if cache is None else cache

    def features(split, i, audio, n):
        key = (split, i)
        if key not in feats:
            feats[key] = puppet.audio_features(audio, n_out=n)
        return feats[key]

    if fit_points is None:
        fit_points = [p for p, *_ in train]
    if len(fit_points) != len(train) or any(len(f) != len(p) for f, (p, *_) in zip(fit_points, train)):
        raise ValueError(f"fit_points: expected one landmark array per training sequence with its frame "
                         f"count {[len(p) for p, *_ in train]}, got {[len(f) for f in fit_points]}; pass "
                         f"the landmarks the puppet was trained on, cut to the same frames")
    z_train = [puppet.ridge_input(features("train", i, a, len(p))) for i, (p, a, *_) in enumerate(train)]
    ridge = RidgeBaseline().fit(z_train, [fs.encode(f)[0] for f in fit_points])
    mean_face = np.zeros(fs.n_dims)  # face coordinates are centred on the mean shape

    rows: dict = {}
    coding = []
    for split, data in (("train", train), ("test", tests)):
        acc: dict = {}
        for i, (points, audio, *shut) in enumerate(data):
            T = len(points)
            raw = features(split, i, audio, T)
            states = facial_states(puppet, points)
            preds = {
                "states": puppet.animate(states=states).face,
                "voice": puppet.animate(features=raw).face,
                MOST_PROBABLE_ROW: puppet.animate(features=raw, full_motion=False).face,
                "mean-face": np.broadcast_to(mean_face, (T, fs.n_dims)),
                "ridge": ridge.predict(puppet.ridge_input(raw)),
            }
            if posterior:
                preds["voice-posterior"] = puppet.animate(features=raw, posterior=True).face
            if puppet.guided:  # the same puppet without its guide's evidence
                preds[UNGUIDED_ROW] = puppet.animate(features=raw, guide_weight=0).face
            for name, face in preds.items():
                m = compare(face, points, fs, shut[0] if shut else None)
                runs = m.pop("closed_runs", 0)
                slot = acc.setdefault(name, {})
                for key, v in m.items():  # the closed share pooled over runs, the rest over frames
                    slot.setdefault(key, []).append((v, runs if key == "closed" else T))
            if split == "train":
                coding.append(bits_per_frame(states[:, 0]))
        for name, slot in acc.items():
            rows.setdefault(name, {})[split] = {
                key: float(sum(v * w for v, w in vals) / sum(w for _, w in vals)) for key, vals in slot.items()}

    parts = puppet.metadata["training"]["parts"]
    model = {"states": [p["states"] for p in parts], "arcs": [p["arcs"] for p in parts],
             "perplexity": float(np.mean([p["perplexity"] for p in parts])),
             "context_memory": float(np.mean([p["context_memory"] for p in parts])),
             "bits_per_frame": float(np.mean(coding)),
             "entropy_rate_test": float(np.mean([decoding_entropy_rate(puppet, features("test", i, a, len(p)))
                                                 for i, (p, a, *_) in enumerate(tests)])) if tests else None,
             "ridge_alpha": ridge.alpha, "guide_weight": puppet.guide_weight if puppet.guided else None,
             "guide_weight_cv": "weight_cv" in puppet.metadata["training"].get("guide", {})}
    return {"rows": rows, "model": model}


def sequence_features(seqs, fps: float, features=None):
    """The raw audio features of each sequence, one row per frame, computed once for all folds.

    Parameters
    ----------
    seqs : list of voicepuppet.evaluation.crossval.Sequence
    fps : float
        Frame rate of the features.
    features : list of arrays (T_s, A), optional
        Given features, one per sequence (then every feature set asked for gets these).

    Returns
    -------
    callable
        ``(i, feature_set) -> ndarray (T_i, A)``: the features of sequence i, caching what it
        computes.

    Raises
    ------
    ValueError
        Given features of the wrong count or shape; a sequence without audio (and no features).
    """
    if features is not None:
        features = [np.asarray(f, dtype=np.float64) for f in features]
        if len(features) != len(seqs) or any(f.ndim != 2 or len(f) != len(s.points)
                                             for f, s in zip(features, seqs)):
            raise ValueError(f"features must be one (T, A) array per sequence ({len(seqs)} sequences), with "
                             f"one row per frame of its landmarks; got {[np.shape(f) for f in features]}")
        return lambda i, feature_set: features[i]
    for s in seqs:
        if s.samples is None:
            raise ValueError(f"sequence {s.name} has no audio; the voice puppet needs it (give "
                             f"NAME.wav, or evaluate without the puppet: --no-puppet)")
    cache: dict = {}

    def of(i, feature_set):
        key = (i, str(feature_set))
        if key not in cache:
            seq = seqs[i]
            a = vaudio.prepare(np.asarray(seq.samples, dtype=np.float64), int(seq.rate))
            cache[key] = vaudio.extract(a, fps=fps, features=feature_set, n_out=len(seq.points)).values
        return cache[key]

    return of
