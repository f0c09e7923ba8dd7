"""``voicepuppet evaluate``: k-fold cross-validation of the voice puppet and its phoneme peers.

Every model sees the same folds (by sequence, :func:`voicepuppet.crossval.kfold`), the same face
vectors (a :class:`voicepuppet.face.FaceSpace` fitted on each fold's training sequences) and the
same measures (:mod:`voicepuppet.metrics`): L1, RMS and L-infinity errors of the face
coordinates and the test log-likelihood per frame (Englebienne et al. figure 4), Err (Voice
Puppetry eq. 7), landmark RMSE over the inter-ocular distance and lip vertex error on the
decoded landmarks (mean pose), each the mean over folds with its 95% confidence interval.

* The voice puppet (``voicepuppet.puppet``) hears the test audio only; it needs no phones.
  With it come its two baselines, learnt from the same fold: ``ridge`` (per-frame ridge
  regression from the standardised audio features over ±5 frames) and ``mean-face`` (the
  training mean face, every frame), and the paired per-fold differences of the puppet's
  measures from theirs (:func:`voicepuppet.crossval.mean_ci`), a second table.
* With ``--peers`` the four phoneme-driven models (:mod:`voicepuppet.dpds`) are given each test
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

import dataclasses
import json
import os
import shlex
from dataclasses import dataclass, field

import numpy as np

from . import phonemes
from .blas import limited

__all__ = ["Sequence", "learnt_points", "synth_sequences", "tracked_landmarks", "load_sequences",
           "cross_validate", "format_table", "write_results", "METRICS", "TRAIN_ON", "BASELINES"]

#: where the models' training landmarks come from (``--train-on``)
TRAIN_ON = ("truth", "tracked")

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

#: The phones whose lips must close (:func:`voicepuppet.metrics.closures`, the ``closed`` measure).
BILABIALS = ("B", "P", "M")


@dataclass
class Sequence:
    """One utterance: landmarks, frame labels and (for the puppet) its audio.

    Attributes
    ----------
    name : str
    points : ndarray, shape (T, P, 2)
    fps : float
    labels : ndarray of int64, shape (T,)
        Indices into :data:`voicepuppet.phonemes.PHONES`.
    samples : ndarray, shape (n,), optional
        Mono audio of exactly these frames.
    rate : int
    train_points : ndarray, shape (T, P, 2), optional
        The landmarks a model learns from when this sequence is in a training fold (e.g. what a
        tracker found), if not ``points``; ``points`` stays what every prediction is measured
        against, and the fold's face space is fitted on these.
    """
    name: str
    points: np.ndarray
    fps: float
    labels: np.ndarray
    samples: np.ndarray | None = None
    rate: int = 16000
    text: str = ""
    meta: dict = field(default_factory=dict)
    train_points: np.ndarray | None = None


def learnt_points(seq: Sequence) -> np.ndarray:
    """The landmarks models learn from in a training fold: ``seq.train_points`` if set, else
    ``seq.points``.

    Raises
    ------
    ValueError
        ``train_points`` of another shape than ``points``.
    """
    if seq.train_points is None:
        return seq.points
    tp = np.asarray(seq.train_points)
    if tp.shape != np.shape(seq.points):
        raise ValueError(f"sequence {seq.name}: train_points must have the shape of its points "
                         f"{np.shape(seq.points)} (the same frames and landmarks), got {tp.shape}; cut "
                         f"them at the same frames")
    return tp


def with_landmark_noise(sequences: list[Sequence], sigma: float, seed: int = 0) -> list[Sequence]:
    """The sequences with independent Gaussian noise of ``sigma`` pixels added to every coordinate
    of the landmarks models learn from (:func:`learnt_points`), as ``train_points``: a worse
    tracker, for measuring how training degrades with tracking error. ``points`` (what every
    prediction is measured against) are untouched; the noise is fixed by ``seed`` and the
    sequence's position. ``sigma = 0`` returns the sequences as given.

    Raises
    ------
    ValueError
        ``sigma`` negative or not finite.
    """
    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma < 0:
        raise ValueError(f"landmark noise must be a finite number of pixels >= 0, got {sigma}")
    if sigma == 0:
        return list(sequences)
    out = []
    for i, seq in enumerate(sequences):
        base = np.asarray(learnt_points(seq), dtype=np.float64)
        rng = np.random.default_rng([int(seed), i])
        out.append(dataclasses.replace(seq, train_points=base + rng.normal(0.0, sigma, np.shape(base))))
    return out


def _alphabet_of(source: str) -> str:
    return "espeak" if source.startswith("espeak") else "arpabet"


def _cut_points(segs, fps: float, n_frames: int, min_pause: float, min_frames: int = 15) -> list[int]:
    cuts = [0]
    for s in segs:
        if s.label == phonemes.SIL and s.end - s.start >= min_pause and 0 < s.start and s.end < n_frames / fps:
            c = int(round(0.5 * (s.start + s.end) * fps))
            if c - cuts[-1] >= min_frames:
                cuts.append(c)
    if len(cuts) > 1 and n_frames - cuts[-1] < min_frames:
        cuts.pop()
    return cuts + [n_frames]


def bilabial_mask(labels) -> np.ndarray:
    """Which frame labels (indices into :data:`voicepuppet.phonemes.PHONES`) are :data:`BILABIALS`."""
    return np.isin(labels, [phonemes.PHONES.index(p) for p in BILABIALS])


def bilabial_frames(clip) -> np.ndarray:
    """(T,) bool: the frames of a performer clip whose phone is one of :data:`BILABIALS` (its lips
    must close), from the clip's own phone timings."""
    return bilabial_mask(phonemes.frame_labels(phonemes.normalize(clip.phones, _alphabet_of(clip.source)),
                                               len(clip.points), clip.fps))


def split_clip(clip, min_pause: float = 0.2, name: str = "clip", train_points=None) -> list[Sequence]:
    """Cut a performer clip into utterances at the middle of pauses of ``min_pause`` s or more.

    Parameters
    ----------
    clip : voicepuppet.synth.Clip
    min_pause : float
        Shortest silence (seconds) that separates two sequences (no piece is shorter than 15
        frames: shorter pieces stay joined to their neighbour).
    name : str
        Prefix of the sequence names.
    train_points : ndarray, shape (T, P, 2), optional
        Other landmarks of the same frames (e.g. tracked), cut at the same frames into each
        sequence's ``train_points``.

    Returns
    -------
    list of Sequence
    """
    alphabet = _alphabet_of(clip.source)
    T = len(clip.points)
    if train_points is not None and np.shape(train_points) != np.shape(clip.points):
        raise ValueError(f"train_points must have the clip's landmark shape {np.shape(clip.points)}, got "
                         f"{np.shape(train_points)}")
    segs = phonemes.normalize(clip.phones, alphabet)
    labels = phonemes.frame_labels(segs, T, clip.fps)
    cuts = _cut_points(segs, clip.fps, T, min_pause)
    out = []
    for i, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
        sa, sb = int(round(a / clip.fps * clip.rate)), int(round(b / clip.fps * clip.rate))
        out.append(Sequence(f"{name}_{i:02d}" if len(cuts) > 2 else name, clip.points[a:b],
                            float(clip.fps), labels[a:b], np.asarray(clip.samples[sa:sb], np.float32),
                            int(clip.rate), clip.text if len(cuts) == 2 else "", {"source": clip.source},
                            None if train_points is None else np.asarray(train_points[a:b], np.float64)))
    return out


#: bump when the cached tracks' layout or meaning changes
_TRACK_CACHE_VERSION = 1


def _file_digest(path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _track_key(video: str, init: np.ndarray) -> str:
    """What a cached track depends on: the video file (size, modification time), the initial
    points, and the tracker's code (``tracking.py`` and the compiled core, by content)."""
    import hashlib

    from . import _core, tracking

    st = os.stat(video)
    src = dict(version=_TRACK_CACHE_VERSION, size=st.st_size, mtime_ns=st.st_mtime_ns,
               init=hashlib.sha256(np.ascontiguousarray(init, np.float64).tobytes()).hexdigest(),
               tracking=_file_digest(tracking.__file__), core=_file_digest(_core.__file__))
    return hashlib.sha256(json.dumps(src, sort_keys=True).encode()).hexdigest()


def tracked_landmarks(clip, cache_dir=None, *, progress: bool = True) -> np.ndarray:
    """What :func:`voicepuppet.tracking.track_video` finds in a performer clip's video, tracked
    from the clip's first ground-truth frame (as ``voicepuppet demo`` does), on the clip's frames.

    The track is cached as ``cache_dir/STEM.npz`` (default: a ``tracked`` folder beside the
    video) under a key of the video file's size and modification time, the initial points and
    the tracker's code; any change re-tracks.

    Parameters
    ----------
    clip : voicepuppet.synth.Clip
        ``video`` (path) and ``points`` (T, P, 2), the ground truth.
    cache_dir : str, optional

    Returns
    -------
    ndarray, shape (T, P, 2)
        One row per ground-truth frame: a track one or two frames shorter (a decoder that drops
        the last frames) is padded with its last frame.

    Raises
    ------
    ValueError
        A missing video, or a track whose frame count is further than 2 frames from the clip's.
    """
    from .animation import atomic_path, write_npz

    video = os.fspath(clip.video)
    if not os.path.isfile(video):
        raise ValueError(f"clip video {video!r} does not exist; rebuild the corpus (delete its corpus.json)")
    truth = np.asarray(clip.points, np.float64)
    init = truth[0]
    stem = os.path.splitext(os.path.basename(video))[0]
    folder = os.path.join(os.path.dirname(video), "tracked") if cache_dir is None else os.fspath(cache_dir)
    path = os.path.join(folder, stem + ".npz")
    key = _track_key(video, init)
    points = None
    if os.path.exists(path):
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["key"]) == key:
                    points = np.asarray(z["points"], np.float64)
        except (OSError, ValueError, KeyError):
            points = None  # unreadable: track again and overwrite
    if points is None:
        from . import tracking

        points = np.asarray(tracking.track_video(video, init=init, progress=progress).points, np.float64)
        os.makedirs(folder, exist_ok=True)
        with atomic_path(path, (".npz",), "tracked landmarks") as tmp:
            with open(tmp, "wb") as fh:
                write_npz(fh, {"points": points, "key": np.str_(key)})
    T = len(truth)
    if points.ndim != 3 or points.shape[1:] != truth.shape[1:] or abs(len(points) - T) > 2:
        raise ValueError(f"tracking {video!r} gave landmarks of shape {points.shape}, expected {truth.shape} "
                         f"(its ground truth's frames, within 2): the video and its landmarks disagree; "
                         f"rebuild the corpus")
    if len(points) < T:
        points = np.concatenate([points, np.repeat(points[-1:], T - len(points), axis=0)])
    return points[:T]


def synth_sequences(out_dir=None, train_seconds: float = 60.0, n_test: int = 3, seed: int = 0,
                    progress: bool = True, train_on: str = "truth", speech: str = "espeak") -> list[Sequence]:
    """The synthetic performer as sequences: its training clip cut into utterances, then the
    held-out clips (espeak-ng sentences and CMU ARCTIC a0009; with ``speech="real"`` the
    performer of :func:`voicepuppet.synth.make_real_corpus`, which speaks real recordings).

    Parameters
    ----------
    out_dir : str, optional
        Corpus folder (default ``~/.cache/voicepuppet/evaluate-corpus``); cached.
    train_seconds, n_test, seed
        As in :func:`voicepuppet.synth.make_corpus`.
    train_on : {"truth", "tracked"}
        ``"tracked"``: every sequence's ``train_points`` are its clip's tracked landmarks
        (:func:`tracked_landmarks`, cached in ``out_dir/tracked``), cut at the same frames as
        the ground truth; ``"truth"``: none (models learn from the ground truth).
    speech : {"espeak", "real"}
        ``"real"``: the real-speech performer (then ``train_seconds`` and ``n_test`` are not
        used; its default folder is ``~/.cache/voicepuppet/evaluate-corpus-real``).

    Returns
    -------
    list of Sequence
    """
    from . import synth
    from .audio import samples

    if train_on not in TRAIN_ON:
        raise ValueError(f"train_on must be one of {TRAIN_ON}, got {train_on!r}")

    if speech not in ("espeak", "real"):
        raise ValueError(f"speech must be 'espeak' or 'real', got {speech!r}")
    if out_dir is None:
        out_dir = os.path.join(samples.cache_dir(), "evaluate-corpus" + ("-real" if speech == "real" else ""))
    if speech == "real":
        corpus = synth.make_real_corpus(out_dir, seed=seed, progress=progress)
    else:
        corpus = synth.make_corpus(out_dir, train_seconds=train_seconds, n_test=n_test, seed=seed,
                                   progress=progress)
    def fit_of(clip):
        return tracked_landmarks(clip, progress=progress) if train_on == "tracked" else None

    seqs = split_clip(corpus.train, name="train", train_points=fit_of(corpus.train))
    for i, clip in enumerate(corpus.test):
        seqs += split_clip(clip, min_pause=1e9, name=f"test_{i:02d}", train_points=fit_of(clip))
    return seqs


def load_sequences(folder, alphabet: str = "arpabet") -> list[Sequence]:
    """User data: one sequence per ``NAME.npz`` in ``folder`` (sorted by name).

    Each ``NAME.npz`` holds ``points`` [T, P, 2] and ``fps``; beside it ``NAME.TextGrid`` or
    ``NAME.lab`` (HTS) gives the phones, and ``NAME.wav`` (optional) the audio.

    Raises
    ------
    ValueError
        No sequences, missing labels, labels that do not cover the frames, unknown phones.
    """
    import soundfile

    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"data folder {folder!r} does not exist")
    names = sorted(f[:-4] for f in os.listdir(folder) if f.endswith(".npz"))
    if not names:
        raise ValueError(f"{folder!r} holds no NAME.npz landmark files")
    out = []
    for n in names:
        stem = os.path.join(folder, n)
        with np.load(stem + ".npz") as z:
            if "points" not in z or "fps" not in z:
                raise ValueError(f"{stem}.npz must hold 'points' [T, P, 2] and 'fps'")
            pts = np.asarray(z["points"], np.float64)
            fps = float(z["fps"])
        if pts.ndim != 3 or pts.shape[2] != 2 or len(pts) < 2:
            raise ValueError(f"{stem}.npz: points must have shape (T >= 2, P, 2), got {pts.shape}")
        if os.path.exists(stem + ".TextGrid"):
            segs = phonemes.read_textgrid(stem + ".TextGrid", alphabet=alphabet)
        elif os.path.exists(stem + ".lab"):
            segs = phonemes.read_hts(stem + ".lab", alphabet=alphabet)
        else:
            raise ValueError(f"{stem}: no phone labels; give {n}.TextGrid or {n}.lab (HTS), e.g. from "
                             f"voicepuppet.phonemes.align")
        try:
            labels = phonemes.frame_labels(segs, len(pts), fps)
        except ValueError as exc:
            raise ValueError(f"{stem}: {exc}") from None
        x, rate = None, 16000
        if os.path.exists(stem + ".wav"):
            x, rate = soundfile.read(stem + ".wav", dtype="float32", always_2d=True)
            x = x.mean(axis=1)
        out.append(Sequence(n, pts, fps, labels, x, int(rate)))
    fps0 = out[0].fps
    for s in out:
        if abs(s.fps - fps0) > 1e-6:
            raise ValueError(f"all sequences must share one frame rate; {s.name} has {s.fps}, "
                             f"{out[0].name} has {fps0}")
    return out


# --------------------------------------------------------------------------------------------
# cross-validation


def _fold_metrics(preds, truths, face_space, loglik: float | None, must_close=None) -> dict:
    """A fold's measures from the predicted and true face coordinates of its test sequences;
    ``must_close``: per sequence, its frames of :data:`BILABIALS` (the ``closed`` share, 68 points)."""
    from . import metrics

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
    try:
        from .puppet import Puppet
    except ImportError as exc:
        raise ValueError(f"the voice puppet is not available in this installation ({exc}); evaluate "
                         f"the phoneme models alone with --peers --no-puppet") from None

    puppet = Puppet.train([learnt_points(s) for s in train], features_list=feats_train, fps=train[0].fps,
                          n_states=n_states, seed=seed, progress=False)
    preds = [_as_face(puppet.animate(features=f, fps=s.fps).animation.points, len(s.points), face_space)
             for s, f in zip(test, feats_test)]
    return preds, puppet


#: The model of a guided voice puppet animated without its guide (``guide_weight=0``).
UNGUIDED = "voice-puppet, unguided (Brand §4.5)"


def _unguided_predictions(puppet, test, face_space, feats_test):
    """The same puppet's test predictions with Brand's unguided solve (as _puppet_predictions)."""
    return [_as_face(puppet.animate(features=f, fps=s.fps, guide_weight=0).animation.points, len(s.points),
                     face_space) for s, f in zip(test, feats_test)]


def _baseline_predictions(puppet, Ytr, feats_train, feats_test, lengths):
    """The two baselines of the voice puppet, learnt from a fold's training sequences.

    ``ridge``: :class:`voicepuppet.evaluation.RidgeBaseline` (±5 frames, regularisation chosen by
    its blocked cross-validation) from the features as the puppet standardises them
    (:func:`voicepuppet.evaluation.ridge_input`) to the training face coordinates ``Ytr``;
    ``mean-face``: the mean of ``Ytr``, every frame. Returns ({name: [face coordinates per test
    sequence]}, the ridge's regularisation).
    """
    from .evaluation import RidgeBaseline, ridge_input

    ridge = RidgeBaseline().fit([ridge_input(puppet, f) for f in feats_train], Ytr)
    mean = np.vstack(Ytr).mean(axis=0)
    preds = {"ridge": [ridge.predict(ridge_input(puppet, f)) for f in feats_test],
             "mean-face": [np.tile(mean, (int(n), 1)) for n in lengths]}
    return preds, float(ridge.alpha)


def _as_face(points, n, face_space) -> np.ndarray:
    """Landmarks cut or padded (last frame) to n frames, in ``face_space`` coordinates."""
    if len(points) < n:
        points = np.concatenate([points, np.repeat(points[-1:], n - len(points), axis=0)])
    return face_space.encode(points[:n])[0]


#: the voice puppet's baselines, evaluated with it (:func:`_baseline_predictions`)
BASELINES = ("ridge", "mean-face")


def _over_folds(values, n_folds: int, measure: str) -> dict | None:
    """:func:`voicepuppet.crossval.fold_summary` of a measure's per-fold values ``[(fold, value)]``
    when every fold has one; for ``closed``, over the folds that have (those whose test sequences
    hold a B, P or M), at least two, listed in ``fold_index``; else None (not reported)."""
    from .crossval import fold_summary

    if len(values) == n_folds:
        return fold_summary([v for _, v in values])
    if measure == "closed" and len(values) >= 2:
        return {**fold_summary([v for _, v in values]), "fold_index": [i for i, _ in values]}
    return None


@limited
def cross_validate(sequences, *, k: int = 10, seed: int = 0, peers: bool = True,
                   puppet: bool = True, n_components=0.98, n_states: int = 40,
                   features=None, progress: bool = True) -> dict:
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

    Returns
    -------
    dict
        ``{"models": {name: {measure: {"mean", "low", "high", "folds": [...]}}}, "differences":
        {"voice-puppet": {baseline: {measure: {...}}}}, "config": ...}``; a difference's
        ``folds`` are the puppet's per-fold values minus the baseline's, its interval
        :func:`voicepuppet.crossval.mean_ci` of them. The ridge's entry also lists the
        regularisation chosen per fold (``alpha``).
    """
    from tqdm.auto import tqdm

    from . import dpds
    from .crossval import kfold
    from .face import FaceSpace

    seqs = list(sequences)
    for s in seqs:
        learnt_points(s)  # refuses train_points of the wrong shape before any training
    if not peers and not puppet:
        raise ValueError("nothing to evaluate: enable the puppet or the peers (--peers)")
    fps = float(seqs[0].fps) if seqs else 0.0
    if puppet:
        from .evaluation import sequence_features
        from .puppet import training_feature_set

        features_at = sequence_features(seqs, fps, features)
        fset = training_feature_set()  # as training from the audio would analyse it

        def features_of(i):
            return features_at(i, fset)

    folds = kfold(len(seqs), k, seed)
    names = (["voice-puppet", *BASELINES] if puppet else []) + (list(dpds.MODELS) if peers else [])
    per_fold: dict = {n: [] for n in names}
    alphas = []
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
            if pup.guided:
                per_fold.setdefault(UNGUIDED, []).append(
                    _fold_metrics(_unguided_predictions(pup, test, fs, f_te), Yte, fs, None, shut))
            bar.update()
            base, alpha = _baseline_predictions(pup, Ytr, f_tr, f_te, [len(y) for y in Yte])
            alphas.append(alpha)
            for name in BASELINES:
                per_fold[name].append(_fold_metrics(base[name], Yte, fs, None, shut))
                bar.update()
        for name in (dpds.MODELS if peers else ()):
            bar.set_postfix(fold=fi + 1, model=name)
            model = dpds.MODELS[name]().fit(Ytr, [s.labels for s in train])
            preds = [model.generate(s.labels) for s in test]
            ll = model.log_likelihood(Yte, [s.labels for s in test])
            per_fold[name].append(_fold_metrics(preds, Yte, fs, ll, shut))
            bar.update()
    bar.close()

    result = {"models": {}, "differences": {}, "config": {
        "k": int(k), "seed": int(seed), "sequences": len(seqs), "frames": int(sum(len(s.points) for s in seqs)),
        "fps": fps, "n_components": n_components, "n_states": int(n_states),
        "separate_training_landmarks": any(s.train_points is not None for s in seqs),
        "folds": [[seqs[i].name for i in te] for _, te in folds]}}
    for name, rows in per_fold.items():
        entry = {m: v for m in METRICS
                 if (v := _over_folds([(i, r[m]) for i, r in enumerate(rows) if m in r], len(rows), m))}
        entry["frames"] = [r["frames"] for r in rows]
        result["models"][name] = entry
    if puppet:
        result["models"]["ridge"]["alpha"] = alphas
        voice = per_fold["voice-puppet"]
        result["differences"]["voice-puppet"] = {
            name: {m: v for m in METRICS
                   if (v := _over_folds([(i, a[m] - b[m]) for i, (a, b) in enumerate(zip(voice, per_fold[name]))
                                         if m in a and m in b], len(voice), m))}
            for name in BASELINES}
    return result


def format_table(result: dict) -> str:
    """Markdown table: one row per model, ``mean ± half-width`` of the 95% interval per measure;
    then, where the result has them, the paired per-fold differences (``voice-puppet − ridge``,
    ``voice-puppet − mean-face``), ``mean [low, high]`` of the 95% interval."""
    from .evaluation import format_difference

    cols = [m for m in METRICS if any(m in e for e in result["models"].values())]
    head = "| model | " + " | ".join(METRICS[m][0] for m in cols) + " |"
    sep = "|---|" + "---:|" * len(cols)
    lines = [head, sep]
    for name, e in result["models"].items():
        cells = []
        for m in cols:
            if m in e:
                v = e[m]
                cells.append(f"{v['mean']:.4g} ± {0.5 * (v['high'] - v['low']):.2g}")
            else:
                cells.append("—")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    c = result["config"]
    diffs = result.get("differences") or {}
    dcols = [m for m in METRICS if any(m in d for by in diffs.values() for d in by.values())]
    if dcols:
        lines += ["", "| paired difference (fold by fold) | " + " | ".join(METRICS[m][0] for m in dcols) + " |",
                  "|---|" + "---:|" * len(dcols)]
        for a, by in diffs.items():
            for b, d in by.items():
                lines.append(f"| {a} − {b} | " + " | ".join(
                    format_difference(d[m]) if m in d else "—" for m in dcols) + " |")
    lines.append("")
    lines.append(f"{c['k']}-fold cross-validation by sequence ({c['sequences']} sequences, {c['frames']} "
                 f"frames at {c['fps']:.4g} fps, seed {c['seed']}); mean over folds ± half-width of the "
                 f"95% confidence interval (Student's t). Face coordinates: FaceSpace per fold "
                 f"(n_components={c['n_components']}). Log-likelihoods are per frame of the test data under "
                 f"each model (brand-phoneme's is of [y, Δy], 2K dims, not comparable; the puppet's "
                 f"face model is not conditioned on phones: —)."
                 + (" ridge: per-frame ridge regression over ±5 frames of the audio features as the fold's "
                    "voice puppet standardises them (regularisation by blocked cross-validation on the "
                    "training frames); mean-face: the fold's training mean face, every frame (Err 1 by "
                    "construction)." if "ridge" in result["models"] else "")
                 + (f" Paired differences: mean [95% interval] of the per-fold differences (Student's t, "
                    f"{c['k'] - 1} degrees of freedom); below 0: the voice puppet's error is lower." if dcols
                    else "")
                 + (" B/P/M closed: the share of the stretches of B, P, M whose lips the model closes (a gap of "
                    "at most 1 % of the inter-ocular distance in one of their frames; higher is better, the "
                    "truth 1), over the folds whose test sequences have one." if "closed" in cols else "")
                 + (" Models and face spaces learnt from the sequences' separate training landmarks "
                    "(e.g. tracked); measured against the ground truth." if c.get("separate_training_landmarks")
                    else ""))
    return "\n".join(lines) + "\n"


def write_results(result: dict, md_path=None, json_path=None, command: str = "") -> None:
    """Write the table (markdown) and the full result (JSON), each atomically."""
    from .animation import atomic_path

    if md_path:
        with atomic_path(md_path, (".md",), "results table") as tmp:
            text = format_table(result)
            if command:
                text = f"```\n{command}\n```\n\n" + text
            tmp.write_text(text, encoding="utf-8")
    if json_path:
        with atomic_path(json_path, (".json",), "results JSON") as tmp:
            payload = dict(result, command=command)
            tmp.write_text(json.dumps(payload, indent=1) + "\n", encoding="utf-8")


# --------------------------------------------------------------------------------------------
# command line


def _command(args) -> str:
    """The command line that reproduces this run (from the parsed options)."""
    import shlex

    parts = ["voicepuppet", "evaluate"]
    opts = [("--data", args.data), ("--corpus-dir", args.corpus_dir)]
    if not args.data:
        if args.speech == "real":
            opts += [("--speech", "real")]
        else:
            opts += [("--train-seconds", f"{60.0 if args.train_seconds is None else args.train_seconds:g}"),
                     ("--n-test", str(3 if args.n_test is None else args.n_test))]
        opts += [("--corpus-seed", None if args.corpus_seed is None else str(args.corpus_seed)),
                 ("--train-on", None if args.train_on == "truth" else args.train_on)]
    else:
        opts += [("--alphabet", args.alphabet)]
    opts += [("--landmark-noise", f"{args.landmark_noise:g}" if args.landmark_noise else None),
             ("--folds", str(args.folds)), ("--seed", str(args.seed)), ("--states", str(args.states)),
             ("--components", args.components), ("-o", args.out), ("--json", args.json)]
    for flag, val in opts:
        if val is not None:
            parts += [flag, shlex.quote(str(val))]
    parts += [f for f, on in (("--peers", args.peers), ("--no-puppet", args.no_puppet)) if on]
    return " ".join(parts)


def _parse_variant(text: str):
    """``NAME`` or ``NAME:key=value,key=value`` -> (name, training options); values are JSON
    (numbers, true/false, quoted strings) or plain strings."""
    name, _, rest = text.partition(":")
    if not name:
        raise ValueError(f"--variant must be NAME or NAME:key=value,...; got {text!r}")
    opts = {}
    for item in filter(None, rest.split(",")):
        key, eq, val = item.partition("=")
        if not eq or not key:
            raise ValueError(f"--variant {text!r}: expected key=value, got {item!r}")
        try:
            opts[key] = json.loads(val)
        except json.JSONDecodeError:
            opts[key] = val
    return name, opts


def _run_comparison(args, seqs, n_comp) -> int:
    from . import evaluation

    given = args.variant or ["entropic", "conventional:prior=ml"]
    variants = dict(_parse_variant(v) for v in given)
    if len(variants) < 2:
        raise ValueError(f"--compare-training needs at least two differently named variants, got {given}")
    for opts in variants.values():
        opts.setdefault("n_states", args.states)
    result = evaluation.compare_training(seqs, variants, k=args.folds, seed=args.seed, n_components=n_comp,
                                         progress=not args.quiet)
    command = _command(args) + " --compare-training" + "".join(
        f" --variant {shlex.quote(v)}" for v in (args.variant or []))
    text = evaluation.format_comparison(result)
    print(text, end="")
    from .animation import atomic_path

    if args.out:
        with atomic_path(args.out, (".md",), "results table") as tmp:
            tmp.write_text(f"```\n{command}\n```\n\n" + text, encoding="utf-8")
    if args.json:
        with atomic_path(args.json, (".json",), "results JSON") as tmp:
            tmp.write_text(json.dumps(dict(result, command=command), indent=1) + "\n", encoding="utf-8")
    for p in (args.out, args.json):
        if p:
            print(f"wrote {p}")
    return 0


def _run(args) -> int:

    if args.data:
        for flag, val, default in (("--train-on", args.train_on, "truth"), ("--corpus-seed", args.corpus_seed, None)):
            if val != default:
                raise ValueError(f"{flag} is for the synthetic performer; with --data the sequences are "
                                 f"yours (put the landmarks to learn from, e.g. tracked ones, in NAME.npz)")
        seqs = load_sequences(args.data, alphabet=args.alphabet)
    else:
        if args.corpus_seed is not None and args.corpus_seed < 0:
            raise ValueError(f"--corpus-seed must be a non-negative integer, got {args.corpus_seed}")
        if args.speech == "real" and (args.train_seconds is not None or args.n_test is not None):
            raise ValueError("--train-seconds and --n-test choose espeak-ng speech; the real-speech "
                             "performer (--speech real) has its fixed recordings: leave them out")
        seqs = synth_sequences(args.corpus_dir, train_seconds=60.0 if args.train_seconds is None else args.train_seconds,
                               n_test=3 if args.n_test is None else args.n_test,
                               seed=args.seed if args.corpus_seed is None else args.corpus_seed,
                               progress=not args.quiet, train_on=args.train_on, speech=args.speech)
    seqs = with_landmark_noise(seqs, args.landmark_noise, seed=args.seed)
    try:
        n_comp = float(args.components) if "." in args.components else int(args.components)
    except ValueError:
        raise ValueError(f"--components must be an integer or a fraction such as 0.98, got "
                         f"{args.components!r}") from None
    if args.compare_training:
        return _run_comparison(args, seqs, n_comp)
    result = cross_validate(seqs, k=args.folds, seed=args.seed, peers=args.peers,
                            puppet=not args.no_puppet, n_components=n_comp, n_states=args.states,
                            progress=not args.quiet)
    command = _command(args)
    print(format_table(result), end="")
    write_results(result, args.out, args.json, command)
    for p in (args.out, args.json):
        if p:
            print(f"wrote {p}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("evaluate", help="cross-validate the voice puppet and its phoneme peers",
                       description="k-fold cross-validation by sequence of the voice puppet, its baselines "
                                   "(ridge regression over +-5 frames of audio features, the mean face) "
                                   "and (with --peers) the four phoneme-driven models on the same folds: "
                                   "L1, RMS, Linf, test log-likelihood, Err (eq. 7), lip vertex error, "
                                   "landmark RMSE/IOD and the share of B/P/M stretches whose lips close, "
                                   "with 95% confidence intervals, and the puppet's "
                                   "paired per-fold differences from each baseline. Default data: the "
                                   "synthetic performer.")
    p.add_argument("--data", metavar="DIR", help="user data: NAME.npz + NAME.wav + NAME.TextGrid|.lab "
                   "per sequence (default: the synthetic performer)")
    p.add_argument("--alphabet", choices=["arpabet", "espeak"], default="arpabet",
                   help="phone alphabet of the label files (default arpabet)")
    p.add_argument("--corpus-dir", metavar="DIR", help="where the synthetic performer is built/cached")
    p.add_argument("--speech", choices=["espeak", "real"], default="espeak",
                   help="what the performer speaks: espeak-ng sentences (default) or the real recordings "
                        "that ship inside packages (two LibriVox readers to learn from, two CMU ARCTIC "
                        "speakers held out; voicepuppet.synth.make_real_corpus)")
    p.add_argument("--train-seconds", type=float, help="performer training speech (s; default 60, espeak only)")
    p.add_argument("--n-test", type=int, help="performer held-out espeak-ng sentences (default 3, espeak only)")
    p.add_argument("--folds", type=int, default=10, help="k of k-fold cross-validation (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seeds the corpus, the folds and the models")
    p.add_argument("--corpus-seed", type=int, metavar="N",
                   help="seed of the performer corpus alone (default: --seed), e.g. a second partition "
                        "of the same corpus: --seed 1 --corpus-seed 0")
    p.add_argument("--train-on", choices=TRAIN_ON, default="truth",
                   help="performer landmarks the models learn from: 'truth' (default) or 'tracked' (what "
                        "the spring-mesh tracker finds in each clip's video from its first true frame, "
                        "cached beside the corpus); measures stay against the ground truth")
    p.add_argument("--landmark-noise", type=float, default=0.0, metavar="PX",
                   help="add independent Gaussian noise of PX pixels to every training landmark (a worse "
                        "tracker; seeded by --seed); measures stay against the clean landmarks")
    p.add_argument("--peers", action="store_true", help="also evaluate the four phoneme-driven models")
    p.add_argument("--no-puppet", action="store_true", help="skip the voice puppet (and its baselines)")
    p.add_argument("--states", type=int, default=40, help="voice puppet states (default 40)")
    p.add_argument("--components", default="0.98",
                   help="face-space size: an integer, or a variance fraction such as 0.98 (default)")
    p.add_argument("--compare-training", action="store_true",
                   help="paired comparison of puppet training variants on the same folds (default: "
                        "entropic vs conventional Baum-Welch): per-fold differences of Err, LVE, decoding "
                        "entropy rate with 95%% intervals")
    p.add_argument("--variant", action="append", metavar="NAME[:key=value,...]",
                   help="a training variant for --compare-training (repeat; options of Puppet.train, "
                        "e.g. 'conventional:prior=ml'); the last one is the baseline")
    p.add_argument("-o", "--out", metavar="FILE.md", help="write the table (markdown)")
    p.add_argument("--json", metavar="FILE.json", help="write the full results (JSON)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)
