"""k-fold cross-validation of the voice puppet and its phoneme peers.

Every model sees the same folds (by sequence, :func:`voicepuppet.evaluation.folds.kfold`), the same face
vectors (a :class:`voicepuppet.face.FaceSpace` fitted on each fold's training sequences) and the
same measures (:mod:`voicepuppet.evaluation.metrics`): L1, RMS and L-infinity errors of the face
coordinates and the test log-likelihood per frame (Englebienne et al. figure 4), Err (Voice
Puppetry eq. 7), landmark RMSE over the inter-ocular distance and lip vertex error on the
decoded landmarks (mean pose), each the mean over folds with its 95% confidence interval.

* The voice puppet (``voicepuppet.puppet.model``) hears the test audio only; it needs no phones.
  With it come its two baselines, learnt from the same fold: ``ridge`` (per-frame ridge
  regression from the standardised audio features over ±5 frames) and ``mean-face`` (the
  training mean face, every frame), and the paired per-fold differences of the puppet's
  measures from theirs (:func:`voicepuppet.evaluation.folds.mean_ci`), a second table.
* With ``--peers`` the four phoneme-driven models (:mod:`voicepuppet.phonemes.models`) are given each test
  sequence's frame labels (ground-truth phones, 10 ms majority vote).

Data: by default the synthetic performer (:func:`voicepuppet.synth.make_corpus`): its training
clip is cut into utterances at the pauses between sentences, and each held-out clip is one more
sequence; espeak-ng's phone events (and CMU ARCTIC's hand labels) are the ground-truth phones.
Or ``--data DIR``: one sequence per ``NAME.npz`` (``points`` [T, P, 2], ``fps``) with
``NAME.wav`` (audio, for the puppet) and ``NAME.TextGrid`` or ``NAME.lab`` (HTS) phone labels.

With ``--train-on tracked`` (performer only) the models learn from what the spring-mesh tracker
finds in each clip's video (:func:`tracked_landmarks`, cached beside the corpus), cut into the
same sequences; every measure stays against the ground truth.
"""


from __future__ import annotations

import numpy as np
from tqdm.auto import tqdm

from voicepuppet.animation import Animation
from voicepuppet.blas import limited
from voicepuppet.evaluation import metrics
from voicepuppet.evaluation.corpus import bilabial_mask, learnt_points
from voicepuppet.evaluation.folds import check_folds, kfold, over_folds
from voicepuppet.evaluation.learned import ConvRegressor
from voicepuppet.evaluation.rhubarb import RECOGNIZERS, ShapeMap, cue_agreement, frame_shapes
from voicepuppet.evaluation.split import decoding_entropy_rate, facial_states, sequence_features
from voicepuppet.face import FaceSpace
from voicepuppet.phonemes import models as dpds
from voicepuppet.puppet.guide import RidgeBaseline
from voicepuppet.puppet.model import Puppet
from voicepuppet.puppet.training import TRAIN_DEFAULTS, check_option_names, training_feature_set
from voicepuppet.render.export import mouth_cues

__all__ = ["METRICS", "BASELINES", "TOOLS", "UNGUIDED", "MOST_PROBABLE", "COMPARE_MEASURES", "COMPARE_KEPT",
           "ANIMATE_OPTIONS", "cross_validate", "compare_training"]

#: Options of :meth:`voicepuppet.puppet.model.Puppet.animate` a variant of :func:`compare_training`
#: may set beside its training options: test-time adaptation of the input's vocal features.
ANIMATE_OPTIONS = ("adapt", "adapt_tau", "adapt_iter")

#: measure -> (column title, better: "lower" or "higher")
METRICS = {
    "l1": ("L1", "lower"),
    "rms": ("RMS", "lower"),
    "linf": ("L∞", "lower"),
    "loglik": ("test log-lik / frame", "higher"),
    "err": ("Err (eq. 7)", "lower"),
    "lve": ("LVE (px²)", "lower"),
    "rmse_iod": ("RMSE / IOD", "lower"),
    "closed": ("B/P/M closed", "higher"),
}

# --------------------------------------------------------------------------------------------
# cross-validation


def _fold_metrics(preds, truths, face_space, loglik: float | None, must_close=None) -> dict:
    """A fold's measures from the predicted and true face coordinates of its test sequences;
    ``must_close``: per sequence, its frames of :data:`BILABIALS` (the ``closed`` share, 68 points)."""
    Yp = np.concatenate(preds)
    Yt = np.concatenate(truths)
    Pp = face_space.decode(Yp)
    Pt = face_space.decode(Yt)
    out = {"l1": metrics.l1(Yp, Yt), "rms": metrics.rms(Yp, Yt), "linf": metrics.linf(Yp, Yt),
           "err": metrics.err(Yp, Yt), "frames": int(len(Yt))}
    if Pt.shape[1] == 68:
        out["lve"] = metrics.lip_vertex_error(Pp, Pt)
        out["rmse_iod"] = metrics.landmark_rmse_iod(Pp, Pt)
        if must_close is not None:  # per sequence: a run of B, P, M does not go on into the next
            cut = np.cumsum([len(t) for t in truths])[:-1]
            counts = [metrics.closures(p, t, m) for p, t, m in zip(np.split(Pp, cut), np.split(Pt, cut), must_close)]
            runs = sum(n for _, n in counts)
            if runs:
                out["closed"] = sum(c for c, _ in counts) / runs
    if loglik is not None:
        out["loglik"] = loglik / len(Yt)
    return out


def _puppet_predictions(train, test, face_space, feats_train, feats_test, *, n_states, seed):
    """Train the voice puppet on the training sequences' learnt landmarks and their raw audio
    features (one row per frame); animate the test sequences' features. Returns the face
    coordinates in ``face_space`` (cut or padded, last frame, to each length) and the puppet."""
    puppet = Puppet.train([learnt_points(s) for s in train], features_list=feats_train, fps=train[0].fps,
                          n_states=n_states, seed=seed, progress=False)
    preds = [_as_face(puppet.animate(features=f, fps=s.fps).animation.points, len(s.points), face_space)
             for s, f in zip(test, feats_test)]
    return preds, puppet


#: The model of a guided voice puppet animated without its guide (``guide_weight=0``).
UNGUIDED = "voice-puppet, unguided (Brand §4.5)"
#: The voice puppet's most probable trajectory, not widened to the training motion
#: (``full_motion=False``).
MOST_PROBABLE = "voice-puppet, most probable"


def _variant_predictions(puppet, test, face_space, feats_test, **how):
    """The same puppet's test predictions animated another way (``how``: options of
    :meth:`voicepuppet.puppet.model.Puppet.animate`), as _puppet_predictions."""
    return [_as_face(puppet.animate(features=f, fps=s.fps, **how).animation.points, len(s.points), face_space)
            for s, f in zip(test, feats_test)]


def _baseline_predictions(puppet, Ytr, feats_train, feats_test, lengths):
    """The two baselines of the voice puppet, learnt from a fold's training sequences.

    ``ridge``: :class:`voicepuppet.puppet.guide.RidgeBaseline` (±5 frames, regularisation chosen by
    its blocked cross-validation) from the features as the puppet standardises them
    (:meth:`voicepuppet.puppet.model.Puppet.ridge_input`) to the training face coordinates ``Ytr``;
    ``mean-face``: the mean of ``Ytr``, every frame. Returns ({name: [face coordinates per test
    sequence]}, the ridge's regularisation).
    """
    ridge = RidgeBaseline().fit([puppet.ridge_input(f) for f in feats_train], Ytr)
    mean = np.vstack(Ytr).mean(axis=0)
    preds = {"ridge": [ridge.predict(puppet.ridge_input(f)) for f in feats_test],
             "mean-face": [np.tile(mean, (int(n), 1)) for n in lengths]}
    return preds, float(ridge.alpha)


def _as_face(points, n, face_space) -> np.ndarray:
    """Landmarks cut or padded (last frame) to n frames, in ``face_space`` coordinates."""
    if len(points) < n:
        points = np.concatenate([points, np.repeat(points[-1:], n - len(points), axis=0)])
    return face_space.encode(points[:n])[0]


#: the voice puppet's baselines, evaluated with it (:func:`_baseline_predictions`)
BASELINES = ("ridge", "mean-face")
#: what users would pick instead of the puppet (``rhubarb``, ``learned`` of :func:`cross_validate`)
TOOLS = ("rhubarb", "learned")


def _rhubarb_cues(rhubarb, seqs) -> dict:
    """Per recogniser, each sequence's Rhubarb shape per frame (from its audio)."""
    out = {}
    for rec in RECOGNIZERS:
        out[rec] = []
        for s in seqs:
            if s.samples is None:
                raise ValueError(f"sequence {s.name} has no audio; Rhubarb needs it")
            out[rec].append(frame_shapes(rhubarb.cues(s.samples, s.rate, rec), len(s.points), s.fps))
    return out


def _export_shapes(points, fps, neutral) -> np.ndarray:
    """voicepuppet's Rhubarb-cue export (:func:`voicepuppet.render.export.mouth_cues`) per frame."""
    cues = mouth_cues(Animation(points, fps), neutral)
    return frame_shapes(cues, len(points), fps)


def _tool_fold(cues, tr_idx, te_idx, Ytr, Yte, fs, preds_puppet, fps, shut) -> tuple[dict, dict]:
    """Rhubarb in one fold, each recogniser with its best mapping (:class:`ShapeMap` of the
    training frames' face coordinates), and the cue agreement of its cues and of the export of
    the puppet's animation with the truth-derived cues (``geometry``: the export rule on the
    true landmarks; ``centroid``: the nearest shape mean of the recogniser's map)."""
    rows, agree = {}, {}
    neutral = fs.decode(np.vstack(Ytr).mean(axis=0)[None])[0]
    truth_pts = [fs.decode(y) for y in Yte]
    geometry = np.concatenate([_export_shapes(p, fps, neutral) for p in truth_pts])
    ours = np.concatenate([_export_shapes(fs.decode(y), fps, neutral) for y in preds_puppet])
    for rec, per_seq in cues.items():
        smap = ShapeMap().fit([per_seq[i] for i in tr_idx], Ytr)
        test = [per_seq[i][:len(y)] for i, y in zip(te_idx, Yte)]
        rows[rec] = _fold_metrics([smap.predict(c) for c in test], Yte, fs, None, shut)
        theirs = np.concatenate(test)
        centroid = smap.nearest(np.vstack(Yte))
        agree[rec] = {"geometry": {"rhubarb": cue_agreement(theirs, geometry), "export": cue_agreement(ours, geometry)},
                      "centroid": {"rhubarb": cue_agreement(theirs, centroid), "export": cue_agreement(ours, centroid)}}
    return rows, agree


@limited
def cross_validate(sequences, *, k: int = 10, seed: int = 0, peers: bool = True,
                   puppet: bool = True, n_components=0.98, n_states: int = 40,
                   features=None, rhubarb=None, learned: bool = False, folds=None, progress: bool = True) -> dict:
    """k-fold cross-validation by sequence of the voice puppet, its baselines and the phoneme peers.

    Models and each fold's face space learn from the training sequences' :func:`learnt_points`
    (``train_points`` where set); predictions are measured against the test sequences' ``points``.
    With the puppet come its two baselines, learnt from the same fold: ``ridge`` (per-frame ridge
    regression over ±5 frames of the audio features as the fold's puppet standardises them, to the
    face coordinates of the training landmarks) and ``mean-face`` (the training mean face, every
    frame), and the paired per-fold differences ``voice-puppet − ridge`` and ``voice-puppet −
    mean-face``.

    Parameters
    ----------
    sequences : list of Sequence
    k : int
        Folds (2..len(sequences)).
    seed : int
        Seeds the folds and every model.
    peers : bool
        Evaluate the four phoneme models.
    puppet : bool
        Evaluate the voice puppet and its baselines (needs audio or ``features``).
    n_components : int or float
        Face-space size per fold (``FaceSpace.fit``): an int, or the fraction of variance kept.
    n_states : int
        Voice puppet states.
    features : list of array (T, A), optional
        Raw audio features per sequence, one row per frame, instead of computing them from each
        sequence's audio (the puppet's default feature set, once per sequence for all folds).
    rhubarb : voicepuppet.evaluation.rhubarb.Rhubarb, optional
        Evaluate Rhubarb Lip Sync (row ``rhubarb``; with the puppet): both recognisers on each
        sequence's audio, each shape mapped to the mean face coordinates of the fold's training
        frames under it (:class:`voicepuppet.evaluation.rhubarb.ShapeMap`); the row is the
        recogniser with the lower mean Err. Beside it, the frame agreement and per-shape confusion
        of its cues and of voicepuppet's cue export of the puppet's animation with cues derived
        from the truth (:mod:`voicepuppet.evaluation.rhubarb`), pooled over the folds.
    learned : bool
        Evaluate the learned peer (row ``learned``; with the puppet): a
        :class:`voicepuppet.evaluation.learned.ConvRegressor` per fold from the features as the
        fold's puppet standardises them to the training face coordinates (needs PyTorch).
    folds : list of (train, test), optional
        These folds instead of ``k`` seeded ones (:func:`voicepuppet.evaluation.folds.check_folds`;
        e.g. :func:`voicepuppet.evaluation.corpus.reader_folds`, which leave a voice out).
    progress : bool
        Show a progress bar over folds and models (default True).

    Returns
    -------
    dict
        ``{"models": {name: {measure: {"mean", "low", "high", "folds": [...]}}}, "differences":
        {"voice-puppet": {baseline: {measure: {...}}}}, "config": ...}``; a difference's
        ``folds`` are the puppet's per-fold values minus the baseline's, its interval
        :func:`voicepuppet.evaluation.folds.mean_ci` of them. The ridge's entry also lists the
        regularisation chosen per fold (``alpha``), the learned peer's its epochs. With
        ``rhubarb``: ``"rhubarb": {"recognizer": the one in the table, "recognizers": {name:
        measures}, "cues": {recogniser: {"geometry"|"centroid": {"rhubarb"|"export":
        agreement}}}}`` (:func:`voicepuppet.evaluation.rhubarb.cue_agreement` of the pooled
        folds, and ``folds``: the per-fold agreements).

    Raises
    ------
    ValueError
        Neither the puppet nor the peers enabled, ``k`` not in 2..len(sequences), a sequence's
        ``train_points`` of another shape than its ``points``, or (for the puppet) a sequence
        without audio and no ``features``, or ``features`` of the wrong count or shape.
    """
    seqs = list(sequences)
    for s in seqs:
        learnt_points(s)  # refuses train_points of the wrong shape before any training
    if not peers and not puppet:
        raise ValueError("nothing to evaluate: enable the puppet or the peers (--peers)")
    if (rhubarb is not None or learned) and not puppet:
        raise ValueError("Rhubarb and the learned peer are evaluated beside the voice puppet: enable the puppet")
    fps = float(seqs[0].fps) if seqs else 0.0
    if puppet:
        features_at = sequence_features(seqs, fps, features)
        fset = training_feature_set()  # as training from the audio would analyse it

        def features_of(i):
            return features_at(i, fset)

    folds = kfold(len(seqs), k, seed) if folds is None else check_folds(folds, len(seqs))
    tools = [t for t, on in zip(TOOLS, (rhubarb is not None, learned)) if on]
    names = (["voice-puppet", *BASELINES, *tools] if puppet else []) + (list(dpds.MODELS) if peers else [])
    per_fold: dict = {n: [] for n in names}
    alphas, epochs, by_recognizer, agreements = [], [], {r: [] for r in RECOGNIZERS}, []
    cues = _rhubarb_cues(rhubarb, seqs) if rhubarb is not None else None
    bar = tqdm(total=len(folds) * len(names), desc="cross-validation", unit="model",
               disable=not progress)
    for fi, (tr_idx, te_idx) in enumerate(folds):
        train = [seqs[i] for i in tr_idx]
        test = [seqs[i] for i in te_idx]
        fs = FaceSpace.fit([learnt_points(s) for s in train], n_components=n_components)
        Ytr = [fs.encode(learnt_points(s))[0] for s in train]
        Yte = [fs.encode(s.points)[0] for s in test]
        shut = [bilabial_mask(s.labels[:len(y)]) for s, y in zip(test, Yte)]
        if puppet:
            bar.set_postfix(fold=fi + 1, model="voice-puppet")
            f_tr, f_te = [features_of(i) for i in tr_idx], [features_of(i) for i in te_idx]
            preds, pup = _puppet_predictions(train, test, fs, f_tr, f_te, n_states=n_states, seed=seed)
            per_fold["voice-puppet"].append(_fold_metrics(preds, Yte, fs, None, shut))
            per_fold.setdefault(MOST_PROBABLE, []).append(
                _fold_metrics(_variant_predictions(pup, test, fs, f_te, full_motion=False), Yte, fs, None, shut))
            if pup.guided:
                per_fold.setdefault(UNGUIDED, []).append(
                    _fold_metrics(_variant_predictions(pup, test, fs, f_te, guide_weight=0), Yte, fs, None, shut))
            bar.update()
            base, alpha = _baseline_predictions(pup, Ytr, f_tr, f_te, [len(y) for y in Yte])
            alphas.append(alpha)
            for name in BASELINES:
                per_fold[name].append(_fold_metrics(base[name], Yte, fs, None, shut))
                bar.update()
            if learned:
                bar.set_postfix(fold=fi + 1, model="learned")
                net = ConvRegressor(seed=seed).fit([pup.ridge_input(f) for f in f_tr], Ytr)
                epochs.append(net.epochs_)
                per_fold["learned"].append(
                    _fold_metrics([net.predict(pup.ridge_input(f)) for f in f_te], Yte, fs, None, shut))
                bar.update()
            if cues is not None:
                rows, agree = _tool_fold(cues, tr_idx, te_idx, Ytr, Yte, fs, preds, fps, shut)
                for rec, row in rows.items():
                    by_recognizer[rec].append(row)
                agreements.append(agree)
                bar.update()
        for name in (dpds.MODELS if peers else ()):
            bar.set_postfix(fold=fi + 1, model=name)
            model = dpds.MODELS[name]().fit(Ytr, [s.labels for s in train])
            preds = [model.generate(s.labels) for s in test]
            ll = model.log_likelihood(Yte, [s.labels for s in test])
            per_fold[name].append(_fold_metrics(preds, Yte, fs, ll, shut))
            bar.update()
    bar.close()
    if cues is not None:
        err = {r: np.mean([row["err"] for row in rows]) for r, rows in by_recognizer.items()}
        best = min(err, key=err.get)
        per_fold["rhubarb"] = by_recognizer[best]

    result = {"models": {}, "differences": {}, "config": {
        "k": len(folds), "seed": int(seed), "sequences": len(seqs), "frames": int(sum(len(s.points) for s in seqs)),
        "fps": fps, "n_components": n_components, "n_states": int(n_states),
        "separate_training_landmarks": any(s.train_points is not None for s in seqs),
        "folds": [[seqs[i].name for i in te] for _, te in folds]}}
    for name, rows in per_fold.items():
        entry = {m: v for m in METRICS
                 if (v := over_folds([(i, r[m]) for i, r in enumerate(rows) if m in r], len(rows), m))}
        entry["frames"] = [r["frames"] for r in rows]
        result["models"][name] = entry
    if puppet:
        result["models"]["ridge"]["alpha"] = alphas
        if learned:
            result["models"]["learned"]["epochs"] = epochs
        voice = per_fold["voice-puppet"]
        result["differences"]["voice-puppet"] = {
            name: {m: v for m in METRICS
                   if (v := over_folds([(i, a[m] - b[m]) for i, (a, b) in enumerate(zip(voice, per_fold[name]))
                                         if m in a and m in b], len(voice), m))}
            for name in (*BASELINES, *tools, MOST_PROBABLE)}
    if cues is not None:
        result["rhubarb"] = {
            "recognizer": best,
            "recognizers": {r: {m: v for m in METRICS
                                if (v := over_folds([(i, x[m]) for i, x in enumerate(rows) if m in x], len(rows), m))}
                            for r, rows in by_recognizer.items()},
            "cues": {r: {how: {who: _pooled([a[r][how][who] for a in agreements]) for who in ("rhubarb", "export")}
                         for how in ("geometry", "centroid")} for r in RECOGNIZERS}}
    return result


def _pooled(per_fold: list) -> dict:
    """Cue agreements of the folds pooled: confusion counts summed, agreement and recall of them."""
    conf: dict = {}
    for a in per_fold:
        for t, row in a["confusion"].items():
            for p, n in row.items():
                conf.setdefault(t, {}).setdefault(p, 0)
                conf[t][p] += n
    total = sum(n for row in conf.values() for n in row.values())
    return {"agreement": sum(row.get(t, 0) for t, row in conf.items()) / total if total else float("nan"),
            "confusion": conf, "recall": {t: row.get(t, 0) / sum(row.values()) for t, row in conf.items()},
            "folds": [a["agreement"] for a in per_fold]}


#: measures of :func:`compare_training` (all: lower is better)
COMPARE_MEASURES = ("err", "lve", "rmse_iod", "closed", "entropy_rate", "states_err")
#: What each fold's puppet of a variant is, kept beside the measures: states and arcs left after
#: training (summed over face parts) and the guide's weight λ (chosen per fold with ``guide_weight="cv"``).
COMPARE_KEPT = ("states", "arcs", "guide_weight")

@limited
def compare_training(sequences, variants: dict, *, baseline: str | None = None, k: int = 10,
                     seed: int = 0, n_components=0.98, features=None, folds=None, progress: bool = False) -> dict:
    """Paired k-fold comparison of puppet training options on the same folds.

    In every fold (:func:`voicepuppet.evaluation.folds.kfold` by sequence) each variant is a
    :meth:`voicepuppet.puppet.model.Puppet.train` on the same training sequences (landmarks and their
    audio features, computed once) with ``seed`` and its own options; it animates the test
    sequences' audio (Viterbi on the vocal HMM). Per fold and variant, pooled over the fold's test
    frames: ``err`` (eq. 7), ``lve``, ``rmse_iod`` and ``closed`` (the share of B, P, M whose lips
    close, over the folds whose test sequences have one, as in ``cross_validate``) on the face coordinates of a
    :class:`voicepuppet.face.FaceSpace` fitted on the fold's training sequences (as
    :func:`voicepuppet.evaluation.crossval.cross_validate`), ``entropy_rate`` of decoding the test audio
    (nats per frame, frame-weighted) and ``states_err``, the Err of the reconstruction from the
    facial HMM's Viterbi states of the true motion; plus what the puppet is (:data:`COMPARE_KEPT`:
    ``states``, ``arcs``, ``guide_weight``).

    Puppets and each fold's face space learn from the training sequences'
    :func:`voicepuppet.evaluation.crossval.learnt_points` (``train_points`` where set, e.g. tracked
    landmarks); every measure is against the test sequences' ``points`` (the ground truth).

    Parameters
    ----------
    sequences : list of voicepuppet.evaluation.crossval.Sequence
        With audio (``samples``, ``rate``).
    variants : dict
        name -> dict of :data:`voicepuppet.puppet.training.TRAIN_DEFAULTS` overrides (``seed`` is set
        here), and of :data:`ANIMATE_OPTIONS` with which the variant animates the test audio.
    baseline : str, optional
        The variant the others are paired against (default: the last one).
    k, seed : int
        Folds and the seed of folds and models.
    n_components : int or float
        Evaluation face space per fold, as in ``FaceSpace.fit``.
    features : list of arrays (T_s, A), optional
        Raw audio features of each sequence, one row per frame, instead of computing them from
        the sequences' audio (then every variant uses these).
    folds : list of (train, test), optional
        These folds instead of ``k`` seeded ones (as in ``cross_validate``).
    progress : bool
        Show a progress bar over folds and variants (default False).

    Returns
    -------
    dict
        ``variants``: {name: {measure: {"mean", "low", "high", "folds"}}};
        ``differences``: {name: {measure: {...}}} of ``name − baseline`` per fold, mean and 95%
        Student-t interval over folds (:func:`voicepuppet.evaluation.folds.mean_ci`); ``config``.

    Raises
    ------
    ValueError
        Fewer than two variants, a ``baseline`` that is not one of them, a variant with unknown
        training options, no sequences, ``k`` not in 2..len(sequences), or sequences without
        audio and no ``features``.
    """

    seqs = list(sequences)
    if not isinstance(variants, dict) or len(variants) < 2:
        raise ValueError(f"variants must be a dict of at least two named option sets, got {variants!r}")
    names = list(variants)
    baseline = names[-1] if baseline is None else baseline
    if baseline not in variants:
        raise ValueError(f"baseline {baseline!r} is not one of the variants {names}")
    for name, opts in variants.items():
        check_option_names({k: v for k, v in opts.items() if k not in ANIMATE_OPTIONS}, f"variant {name!r}")
    if not seqs:
        raise ValueError("no sequences to compare on")
    fit = [learnt_points(s) for s in seqs]  # refuses train_points of the wrong shape up front
    fps = float(seqs[0].fps)
    features_of = sequence_features(seqs, fps, features)
    fsets = {name: training_feature_set(variants[name].get("feature_set"),
                                        variants[name].get("audio_level", TRAIN_DEFAULTS["audio_level"]))
             for name in names}

    folds = kfold(len(seqs), k, seed) if folds is None else check_folds(folds, len(seqs))
    per_fold: dict = {n: [] for n in names}
    bar = tqdm(total=len(folds) * len(names), desc="paired comparison", unit="model", disable=not progress)
    for fi, (tr, te) in enumerate(folds):
        fs = FaceSpace.fit([fit[i] for i in tr], n_components=n_components)
        Yte = [fs.encode(seqs[i].points)[0] for i in te]
        shut = [bilabial_mask(seqs[i].labels[:len(y)]) for i, y in zip(te, Yte)]
        for name in names:
            bar.set_postfix(fold=fi + 1, variant=name)
            opts = dict(variants[name], seed=seed)
            animate = {k: opts.pop(k) for k in ANIMATE_OPTIONS if k in opts}
            puppet = Puppet.train([fit[i] for i in tr], features_list=[features_of(i, fsets[name]) for i in tr],
                                  fps=fps, **opts)
            voice, states, rates = [], [], []
            for i, y in zip(te, Yte):
                f = features_of(i, fsets[name])
                voice.append(_as_face(puppet.animate(features=f, fps=fps, **animate).animation.points, len(y), fs))
                s = facial_states(puppet, seqs[i].points)
                states.append(_as_face(puppet.animate(states=s, fps=fps).animation.points, len(y), fs))
                rates.append((decoding_entropy_rate(puppet, f), len(y)))
            row = _fold_metrics(voice, Yte, fs, None, shut)
            row["states_err"] = _fold_metrics(states, Yte, fs, None)["err"]
            row["entropy_rate"] = sum(r * n for r, n in rates) / sum(n for _, n in rates)
            parts = puppet.metadata["training"]["parts"]
            row["states"] = int(sum(p["states"] for p in parts))
            row["arcs"] = int(sum(p["arcs"] for p in parts))
            row["guide_weight"] = puppet.guide_weight
            per_fold[name].append(row)
            bar.update()
    bar.close()

    measures = [m for m in COMPARE_MEASURES + COMPARE_KEPT
                if over_folds([(i, r[m]) for i, r in enumerate(per_fold[baseline]) if m in r], len(folds), m)]
    out = {"variants": {}, "differences": {}, "config": {
        "k": len(folds), "seed": int(seed), "sequences": len(seqs), "frames": int(sum(len(s.points) for s in seqs)),
        "fps": fps, "n_components": n_components, "baseline": baseline,
        "separate_training_landmarks": any(s.train_points is not None for s in seqs),
        "options": {n: dict(variants[n]) for n in names},
        "folds": [[seqs[i].name for i in te] for _, te in folds]}}
    for name in names:  # every variant has a measure in the same folds (the folds' test sequences)
        out["variants"][name] = {m: over_folds([(i, r[m]) for i, r in enumerate(per_fold[name]) if m in r],
                                                len(folds), m) for m in measures}
        if name != baseline:
            out["differences"][name] = {
                m: over_folds([(i, a[m] - b[m]) for i, (a, b) in enumerate(zip(per_fold[name], per_fold[baseline]))
                                if m in a], len(folds), m) for m in measures}
    return out
