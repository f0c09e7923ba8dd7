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

from voicepuppet import _core, metrics
from voicepuppet.blas import limited
from voicepuppet.face import observations

RIDGE_CONTEXT = 5
RIDGE_ALPHAS = tuple(10.0 ** np.arange(-2, 5))


def context_stack(A, k: int = RIDGE_CONTEXT) -> np.ndarray:
    """Frames with their ±k neighbours side by side, edges repeated: (T, A·(2k+1))."""
    A = np.asarray(A, dtype=np.float64)
    T = len(A)
    idx = np.clip(np.arange(T)[:, None] + np.arange(-k, k + 1)[None, :], 0, T - 1)
    return A[idx].reshape(T, -1)


class RidgeBaseline:
    """Ridge regression from context-stacked audio features to face coordinates."""

    def __init__(self, k: int = RIDGE_CONTEXT, alphas=RIDGE_ALPHAS, n_folds: int = 5):
        self.k, self.alphas, self.n_folds = int(k), tuple(alphas), int(n_folds)

    @staticmethod
    def _solve(G, B, alpha):
        from scipy.linalg import cho_factor, cho_solve

        return cho_solve(cho_factor(G + alpha * np.eye(len(G)), lower=True), B)

    @limited
    def fit(self, A_list, Y_list, folds=None) -> "RidgeBaseline":
        """Fit on the sequences ``A_list`` / ``Y_list``, α chosen by ``n_folds``-fold CV over
        contiguous blocks of their stacked frames, or over ``folds`` (frame indices) if given."""
        X = np.vstack([context_stack(a, self.k) for a in A_list])
        Y = np.vstack(Y_list)
        self.x_mean, self.y_mean = X.mean(axis=0), Y.mean(axis=0)
        Xc, Yc = X - self.x_mean, Y - self.y_mean
        folds = np.array_split(np.arange(len(X)), self.n_folds) if folds is None else folds
        # Normal equations per fold once; a fold's training system is the total minus the fold.
        parts = [(Xc[f].T @ Xc[f], Xc[f].T @ Yc[f]) for f in folds]
        G, B = sum(p[0] for p in parts), sum(p[1] for p in parts)
        scores = []
        for alpha in self.alphas:
            sse = 0.0
            for f, (Gf, Bf) in zip(folds, parts):
                W = self._solve(G - Gf, B - Bf, alpha)
                sse += float(np.sum((Xc[f] @ W - Yc[f]) ** 2))
            scores.append(sse)
        self.alpha = self.alphas[int(np.argmin(scores))]
        self.W = self._solve(G, B, self.alpha)
        return self

    def predict(self, A) -> np.ndarray:
        return (context_stack(A, self.k) - self.x_mean) @ self.W + self.y_mean


#: The row of a guided puppet animated without its guide (``guide_weight=0``: Brand's solve).
UNGUIDED_ROW = "voice, unguided (Brand §4.5)"


def ridge_input(puppet, raw) -> np.ndarray:
    """What the ridge baseline hears: raw audio features [T, A] standardised as ``puppet``
    standardises them (its training mean and std), without the deltas the puppet appends (a
    linear map over ±5 frames of context can form them): (T, A).

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    raw : array (T, A)
        Raw features made with the puppet's feature set (e.g. ``puppet.audio_features``).
    """
    return puppet._core.standardize(np.ascontiguousarray(raw, dtype=np.float64))[:, :puppet._core.n_features]


def facial_states(puppet, points) -> np.ndarray:
    """Viterbi states of the facial HMM for true motion ``points`` [T, P, 2]: (T, parts)."""
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
    container header)."""
    s = np.asarray(states, dtype=np.uint8 if np.max(states) < 256 else np.uint16)
    packed = lzma.compress(s.tobytes(), format=lzma.FORMAT_RAW,
                           filters=[{"id": lzma.FILTER_LZMA2, "preset": 9}])
    return 8.0 * len(packed) / len(s)


def decoding_entropy_rate(puppet, features) -> float:
    """Entropy rate (nats per frame) of the vocal HMM's posterior over state sequences."""
    from voicepuppet.entropic import entropy_rate

    z = puppet._core.standardize(np.ascontiguousarray(features, dtype=np.float64))
    rates = []
    for k in range(len(puppet.part_names)):
        arr = puppet.part_arrays(k)
        rates.append(entropy_rate(puppet._core.vocal_log_density(z, k), arr["startprob"], arr["transmat"]))
    return float(np.mean(rates))


def compare(pred_face, true_points, face_space, must_close=None) -> dict:
    """Measures of predicted face coordinates against true landmarks (true pose re-applied);
    with ``must_close`` (T,), the frames of B, P, M, also ``closed`` (the share of their runs the
    prediction closes, :func:`voicepuppet.metrics.closures`) and ``closed_runs``."""
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
    puppet : voicepuppet.puppet.Puppet
    train : list of (points [T, P, 2], audio) or (points, audio, must_close [T] bool)
        The training sequences, with the landmarks every prediction is measured against (and,
        where given, the frames of B, P, M: the ``closed`` measure).
    tests : list of (points, audio) or (points, audio, must_close)
        Held-out sequences.
    fit_points : list of [T, P, 2] arrays, optional
        The landmarks the puppet was trained on, one per training sequence, when they are not
        ``train``'s (a puppet trained on tracked landmarks, measured against the ground truth):
        the ridge baseline is fitted on these too, so both learn from the same data.
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
    z_train = [ridge_input(puppet, features("train", i, a, len(p))) for i, (p, a, *_) in enumerate(train)]
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
                "mean-face": np.broadcast_to(mean_face, (T, fs.n_dims)),
                "ridge": ridge.predict(ridge_input(puppet, raw)),
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


def format_table(result: dict, title: str = "") -> str:
    """A markdown table of :func:`evaluate_split`'s rows."""
    keys = ["err", "rmse_iod", "lve", "rms"]
    if any("closed" in r.get(split, {}) for r in result["rows"].values() for split in ("train", "test")):
        keys.append("closed")
    lines = []
    if title:
        lines += [f"**{title}**", ""]
    lines.append("| method | " + " | ".join(f"{k} train | {k} test" for k in keys) + " |")
    lines.append("|---|" + "---:|" * (2 * len(keys)))
    for name, row in result["rows"].items():
        cells = []
        for k in keys:
            for split in ("train", "test"):
                v = row.get(split, {}).get(k)
                cells.append("" if v is None else f"{v:.4g}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    m = result["model"]
    guide = ""
    if m.get("guide_weight") is not None:
        guide = f", guide weight {m['guide_weight']:g}" + (" (chosen by cross-validation)"
                                                          if m.get("guide_weight_cv") else "")
    states, arcs = (" / ".join(str(n) for n in m[k]) for k in ("states", "arcs"))  # one per face part
    lines += ["", f"states {states}, arcs {arcs}, perplexity {m['perplexity']:.3g}, context "
              f"memory {m['context_memory']:.3g} frames, test decoding entropy rate "
              f"{m['entropy_rate_test']:.4g} nats/frame, state coding {m['bits_per_frame']:.3g} bits/frame"
              + guide]
    return "\n".join(lines)


# ------------------------------------------------------------------ paired training comparison
#: measures of :func:`compare_training` (all: lower is better)
COMPARE_MEASURES = ("err", "lve", "rmse_iod", "closed", "entropy_rate", "states_err")


def sequence_features(seqs, fps: float, features=None):
    """The raw audio features of each sequence, one row per frame, computed once for all folds.

    Parameters
    ----------
    seqs : list of voicepuppet.evaluate.Sequence
    fps : float
        Frame rate of the features.
    features : list of arrays (T_s, A), optional
        Given features, one per sequence (then every feature set asked for gets these).

    Returns
    -------
    callable ``(i, feature_set) -> ndarray (T_i, A)``, caching what it computes.

    Raises
    ------
    ValueError
        Given features of the wrong count or shape; a sequence without audio (and no features).
    """
    from voicepuppet import audio as vaudio

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


@limited
def compare_training(sequences, variants: dict, *, baseline: str | None = None, k: int = 10,
                     seed: int = 0, n_components=0.98, features=None, progress: bool = False) -> dict:
    """Paired k-fold comparison of puppet training options on the same folds.

    In every fold (:func:`voicepuppet.crossval.kfold` by sequence) each variant is a
    :meth:`voicepuppet.puppet.Puppet.train` on the same training sequences (landmarks and their
    audio features, computed once) with ``seed`` and its own options; it animates the test
    sequences' audio (Viterbi on the vocal HMM). Per fold and variant, pooled over the fold's test
    frames: ``err`` (eq. 7), ``lve``, ``rmse_iod`` and ``closed`` (the share of B, P, M whose lips
    close, over the folds whose test sequences have one, as in ``cross_validate``) on the face coordinates of a
    :class:`voicepuppet.face.FaceSpace` fitted on the fold's training sequences (as
    :func:`voicepuppet.evaluate.cross_validate`), ``entropy_rate`` of decoding the test audio
    (nats per frame, frame-weighted) and ``states_err``, the Err of the reconstruction from the
    facial HMM's Viterbi states of the true motion; plus ``states`` and ``arcs`` kept.

    Puppets and each fold's face space learn from the training sequences'
    :func:`voicepuppet.evaluate.learnt_points` (``train_points`` where set, e.g. tracked
    landmarks); every measure is against the test sequences' ``points`` (the ground truth).

    Parameters
    ----------
    sequences : list of voicepuppet.evaluate.Sequence
        With audio (``samples``, ``rate``).
    variants : dict
        name -> dict of :data:`voicepuppet.puppet.TRAIN_DEFAULTS` overrides (``seed`` is set here).
    baseline : str, optional
        The variant the others are paired against (default: the last one).
    k, seed : int
        Folds and the seed of folds and models.
    n_components : int or float
        Evaluation face space per fold, as in ``FaceSpace.fit``.
    features : list of arrays (T_s, A), optional
        Raw audio features of each sequence, one row per frame, instead of computing them from
        the sequences' audio (then every variant uses these).

    Returns
    -------
    dict
        ``variants``: {name: {measure: {"mean", "low", "high", "folds"}}};
        ``differences``: {name: {measure: {...}}} of ``name − baseline`` per fold, mean and 95%
        Student-t interval over folds (:func:`voicepuppet.crossval.mean_ci`); ``config``.
    """
    from tqdm.auto import tqdm

    from voicepuppet.crossval import kfold
    from voicepuppet.evaluate import _as_face, _fold_metrics, _over_folds, bilabial_mask, learnt_points
    from voicepuppet.face import FaceSpace
    from voicepuppet.puppet import TRAIN_DEFAULTS, Puppet, training_feature_set

    seqs = list(sequences)
    if not isinstance(variants, dict) or len(variants) < 2:
        raise ValueError(f"variants must be a dict of at least two named option sets, got {variants!r}")
    names = list(variants)
    baseline = names[-1] if baseline is None else baseline
    if baseline not in variants:
        raise ValueError(f"baseline {baseline!r} is not one of the variants {names}")
    for name, opts in variants.items():
        unknown = set(opts) - (set(TRAIN_DEFAULTS) - {"seed"})
        if unknown:
            raise ValueError(f"variant {name!r} has unknown training options {sorted(unknown)}; known: "
                             f"{sorted(set(TRAIN_DEFAULTS) - {'seed'})}")
    if not seqs:
        raise ValueError("no sequences to compare on")
    fit = [learnt_points(s) for s in seqs]  # refuses train_points of the wrong shape up front
    fps = float(seqs[0].fps)
    features_of = sequence_features(seqs, fps, features)
    fsets = {name: training_feature_set(variants[name].get("feature_set"),
                                        variants[name].get("audio_level", TRAIN_DEFAULTS["audio_level"]))
             for name in names}

    folds = kfold(len(seqs), k, seed)
    per_fold: dict = {n: [] for n in names}
    bar = tqdm(total=len(folds) * len(names), desc="paired comparison", unit="model", disable=not progress)
    for fi, (tr, te) in enumerate(folds):
        fs = FaceSpace.fit([fit[i] for i in tr], n_components=n_components)
        Yte = [fs.encode(seqs[i].points)[0] for i in te]
        shut = [bilabial_mask(seqs[i].labels[:len(y)]) for i, y in zip(te, Yte)]
        for name in names:
            bar.set_postfix(fold=fi + 1, variant=name)
            opts = dict(variants[name], seed=seed)
            puppet = Puppet.train([fit[i] for i in tr], features_list=[features_of(i, fsets[name]) for i in tr],
                                  fps=fps, **opts)
            voice, states, rates = [], [], []
            for i, y in zip(te, Yte):
                f = features_of(i, fsets[name])
                voice.append(_as_face(puppet.animate(features=f, fps=fps).animation.points, len(y), fs))
                s = facial_states(puppet, seqs[i].points)
                states.append(_as_face(puppet.animate(states=s, fps=fps).animation.points, len(y), fs))
                rates.append((decoding_entropy_rate(puppet, f), len(y)))
            row = _fold_metrics(voice, Yte, fs, None, shut)
            row["states_err"] = _fold_metrics(states, Yte, fs, None)["err"]
            row["entropy_rate"] = sum(r * n for r, n in rates) / sum(n for _, n in rates)
            parts = puppet.metadata["training"]["parts"]
            row["states"] = int(sum(p["states"] for p in parts))
            row["arcs"] = int(sum(p["arcs"] for p in parts))
            per_fold[name].append(row)
            bar.update()
    bar.close()

    measures = [m for m in COMPARE_MEASURES + ("states", "arcs")
                if _over_folds([(i, r[m]) for i, r in enumerate(per_fold[baseline]) if m in r], len(folds), m)]
    out = {"variants": {}, "differences": {}, "config": {
        "k": int(k), "seed": int(seed), "sequences": len(seqs), "frames": int(sum(len(s.points) for s in seqs)),
        "fps": fps, "n_components": n_components, "baseline": baseline,
        "separate_training_landmarks": any(s.train_points is not None for s in seqs),
        "options": {n: dict(variants[n]) for n in names},
        "folds": [[seqs[i].name for i in te] for _, te in folds]}}
    for name in names:  # every variant has a measure in the same folds (the folds' test sequences)
        out["variants"][name] = {m: _over_folds([(i, r[m]) for i, r in enumerate(per_fold[name]) if m in r],
                                                len(folds), m) for m in measures}
        if name != baseline:
            out["differences"][name] = {
                m: _over_folds([(i, a[m] - b[m]) for i, (a, b) in enumerate(zip(per_fold[name], per_fold[baseline]))
                                if m in a], len(folds), m) for m in measures}
    return out


def format_difference(d: dict) -> str:
    """A paired difference's cell: ``mean [low, high]`` of its 95% interval, signed."""
    return f"{d['mean']:+.3g} [{d['low']:+.3g}, {d['high']:+.3g}]"


def format_comparison(result: dict) -> str:
    """Markdown: each variant's measures (mean ± half-width of the 95% interval over folds), then
    each paired difference against the baseline with its interval."""
    def cell(v, digits=4):
        return f"{v['mean']:.{digits}g} ± {0.5 * (v['high'] - v['low']):.2g}"

    measures = [m for m in COMPARE_MEASURES + ("states", "arcs") if m in next(iter(result["variants"].values()))]
    lines = ["| variant | " + " | ".join(measures) + " |", "|---|" + "---:|" * len(measures)]
    for name, row in result["variants"].items():
        lines.append(f"| {name} | " + " | ".join(cell(row[m]) for m in measures) + " |")
    base = result["config"]["baseline"]
    lines += ["", f"| paired difference (fold by fold) | " + " | ".join(measures) + " |",
              "|---|" + "---:|" * len(measures)]
    for name, row in result["differences"].items():
        lines.append(f"| {name} − {base} | " + " | ".join(
            format_difference(row[m]) for m in measures) + " |")
    c = result["config"]
    lines += ["", f"{c['k']}-fold cross-validation by sequence ({c['sequences']} sequences, {c['frames']} frames "
              f"at {c['fps']:.4g} fps, seed {c['seed']}); variants: mean over folds ± half-width of the 95% "
              f"interval; differences: mean [95% interval] of the per-fold differences (Student's t, "
              f"{c['k'] - 1} degrees of freedom). Lower is better for every measure."
              + (" Puppets and face spaces learnt from the sequences' separate training landmarks (e.g. "
                 "tracked); measured against the ground truth." if c.get("separate_training_landmarks") else "")]
    return "\n".join(lines) + "\n"
