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
not where the head goes), landmark RMSE / inter-ocular distance and lip vertex error. Model
measures: perplexity, context memory (frames), entropy rate of decoding the test audio (nats per
frame), and bits per frame of the LZMA-compressed state sequence (the "coding" of §5.1).
"""

from __future__ import annotations

import lzma

import numpy as np

from voicepuppet import _core, metrics
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

    def fit(self, A_list, Y_list) -> "RidgeBaseline":
        X = np.vstack([context_stack(a, self.k) for a in A_list])
        Y = np.vstack(Y_list)
        self.x_mean, self.y_mean = X.mean(axis=0), Y.mean(axis=0)
        Xc, Yc = X - self.x_mean, Y - self.y_mean
        folds = np.array_split(np.arange(len(X)), self.n_folds)
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


def compare(pred_face, true_points, face_space) -> dict:
    """Measures of predicted face coordinates against true landmarks (true pose re-applied)."""
    true_face, pose = face_space.encode(true_points)
    T = min(len(pred_face), len(true_face))
    pf, tf = pred_face[:T], true_face[:T]
    out = {"err": metrics.err(pf, tf), "l1": metrics.l1(pf, tf), "rms": metrics.rms(pf, tf),
           "linf": metrics.linf(pf, tf)}
    if true_points.shape[1] == 68:
        pts = face_space.decode(pf, pose[:T])
        out["rmse_iod"] = metrics.landmark_rmse_iod(pts, true_points[:T])
        out["lve"] = metrics.lip_vertex_error(pts, true_points[:T])
    return out


def evaluate_split(puppet, train, tests, *, posterior: bool = True, cache: dict | None = None) -> dict:
    """Measure a puppet and the baselines on its training data and held-out data.

    Parameters
    ----------
    puppet : voicepuppet.puppet.Puppet
    train : list of (points [T, P, 2], audio)
        The training sequences (as given to ``Puppet.train``).
    tests : list of (points, audio)
        Held-out sequences.
    cache : dict, optional
        Audio features by (split, index); pass the same dict when evaluating several puppets
        with one feature set on the same data.

    Returns
    -------
    dict
        ``rows``: {method: {"train": {...}, "test": {...}}} with the measures averaged over
        sequences (weighted by frames); ``model``: perplexity, context memory, entropy rate of
        decoding the test audio, bits per frame of the state coding, states and arcs.
    """
    fs = puppet.face_space
    feats = {} if cache is None else cache

    def features(split, i, audio, n):
        key = (split, i)
        if key not in feats:
            feats[key] = puppet.audio_features(audio, n_out=n)
        return feats[key]

    # The ridge sees the standardised features over ±5 frames (their deltas would add nothing a
    # linear map over the context cannot express).
    n_raw = puppet._core.n_features

    def ridge_input(raw):
        return puppet._core.standardize(raw)[:, :n_raw]

    z_train = [ridge_input(features("train", i, a, len(p))) for i, (p, a) in enumerate(train)]
    ridge = RidgeBaseline().fit(z_train, [fs.encode(p)[0] for p, _ in train])
    mean_face = np.zeros(fs.n_dims)  # face coordinates are centred on the mean shape

    rows: dict = {}
    coding = []
    for split, data in (("train", train), ("test", tests)):
        acc: dict = {}
        for i, (points, audio) in enumerate(data):
            T = len(points)
            raw = features(split, i, audio, T)
            z = puppet._core.standardize(raw)
            states = facial_states(puppet, points)
            preds = {
                "states": puppet.animate(states=states).face,
                "voice": puppet.animate(features=raw).face,
                "mean-face": np.broadcast_to(mean_face, (T, fs.n_dims)),
                "ridge": ridge.predict(z[:, :n_raw]),
            }
            if posterior:
                preds["voice-posterior"] = puppet.animate(features=raw, posterior=True).face
            for name, face in preds.items():
                m = compare(face, points, fs)
                slot = acc.setdefault(name, {})
                for key, v in m.items():
                    slot.setdefault(key, []).append((v, T))
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
                                                 for i, (p, a) in enumerate(tests)])) if tests else None,
             "ridge_alpha": ridge.alpha}
    return {"rows": rows, "model": model}


def format_table(result: dict, title: str = "") -> str:
    """A markdown table of :func:`evaluate_split`'s rows."""
    keys = ["err", "rmse_iod", "lve", "rms"]
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
    lines += ["", f"states {m['states']}, arcs {m['arcs']}, perplexity {m['perplexity']:.3g}, context "
              f"memory {m['context_memory']:.3g} frames, test decoding entropy rate "
              f"{m['entropy_rate_test']:.4g} nats/frame, state coding {m['bits_per_frame']:.3g} bits/frame"]
    return "\n".join(lines)
