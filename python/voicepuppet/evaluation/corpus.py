"""Evaluation corpora: landmark sequences with their audio and phone labels.

A :class:`Sequence` is one utterance: true landmarks, audio, frame labels and, optionally,
separate landmarks to learn from (e.g. tracked). :func:`synth_sequences` cuts the synthetic
performer's clips into utterances at their pauses (:func:`split_clip`); :func:`load_sequences`
reads a folder of ``NAME.npz`` + ``NAME.wav`` + ``NAME.TextGrid``/``NAME.lab``;
:func:`tracked_landmarks` tracks a clip's video (cached) so models can learn from what the
tracker finds.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import soundfile

from voicepuppet import _core
from voicepuppet import data as samples
from voicepuppet import synth
from voicepuppet._files import atomic_path, write_npz
from voicepuppet.phonemes import labels as phonemes
from voicepuppet.tracking import tracker as tracking

__all__ = ["TRAIN_ON", "BILABIALS", "Sequence", "learnt_points", "with_landmark_noise", "bilabial_mask", "reader_folds",
           "bilabial_frames", "split_clip", "tracked_landmarks", "synth_sequences", "load_sequences"]

#: where the models' training landmarks come from (``--train-on``)
TRAIN_ON = ("truth", "tracked")
#: The phones whose lips must close (:func:`voicepuppet.evaluation.metrics.closures`, the ``closed`` measure).
BILABIALS = ("B", "P", "M")

@dataclass
class Sequence:
    """One utterance: landmarks, frame labels and (for the puppet) its audio.

    Each parameter is kept as the attribute of the same name.

    Parameters
    ----------
    name : str
        Name of the sequence (in reports and fold lists).
    points : ndarray, shape (T, P, 2)
        The true landmarks: what every prediction is measured against.
    fps : float
        Frame rate of ``points`` and ``labels``.
    labels : ndarray of int64, shape (T,)
        Indices into :data:`voicepuppet.phonemes.labels.PHONES`.
    samples : ndarray, shape (n,), optional
        Mono audio of exactly these frames (default None: no audio).
    rate : int
        Sample rate of ``samples`` in Hz (default 16000).
    text : str
        What is said, where known (default empty).
    meta : dict
        Anything else about the sequence, e.g. its ``source`` (default empty).
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

    Parameters
    ----------
    seq : Sequence
        The sequence.

    Returns
    -------
    ndarray, shape (T, P, 2)
        Its training landmarks.

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

    Parameters
    ----------
    sequences : list of Sequence
        The sequences.
    sigma : float
        Standard deviation of the noise in pixels (>= 0).
    seed : int
        Seed of the noise (default 0), with each sequence's position in the list.

    Returns
    -------
    list of Sequence
        New sequences (copies with ``train_points`` set), or the sequences as given when
        ``sigma`` is 0.

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
    """Which frame labels (indices into :data:`voicepuppet.phonemes.labels.PHONES`) are :data:`BILABIALS`.

    Parameters
    ----------
    labels : array_like of int, shape (T,)
        Phone indices per frame (e.g. a :class:`Sequence`'s ``labels``).

    Returns
    -------
    ndarray of bool, shape (T,)
        True where the phone is B, P or M.
    """
    return np.isin(labels, [phonemes.PHONES.index(p) for p in BILABIALS])


def bilabial_frames(clip) -> np.ndarray:
    """(T,) bool: the frames of a performer clip whose phone is one of :data:`BILABIALS` (its lips
    must close), from the clip's own phone timings.

    Parameters
    ----------
    clip : voicepuppet.synth.Clip
        A performer clip (``phones``, ``source``, ``points``, ``fps``).

    Returns
    -------
    ndarray of bool, shape (T,)
        One entry per frame of ``clip.points``.
    """
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
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def tracker_digest() -> str:
    """The tracker's code by content (the ``voicepuppet.tracking`` sources and the compiled core):
    caches of tracked landmarks key on it, so a changed tracker tracks again."""
    parts = [_file_digest(p) for p in sorted(Path(tracking.__file__).parent.glob("*.py"))]
    return hashlib.sha256(json.dumps([parts, _file_digest(_core.__file__)]).encode()).hexdigest()


def _track_key(video: str, init: np.ndarray) -> str:
    """What a cached track depends on: the video file (size, modification time), the initial
    points, and the tracker's code (the ``voicepuppet.tracking`` sources and the compiled core, by
    content)."""
    st = os.stat(video)
    src = dict(version=_TRACK_CACHE_VERSION, size=st.st_size, mtime_ns=st.st_mtime_ns,
               init=hashlib.sha256(np.ascontiguousarray(init, np.float64).tobytes()).hexdigest(),
               tracker=tracker_digest())
    return hashlib.sha256(json.dumps(src, sort_keys=True).encode()).hexdigest()


def tracked_landmarks(clip, cache_dir=None, *, progress: bool = True) -> np.ndarray:
    """What :func:`voicepuppet.tracking.tracker.track_video` finds in a performer clip's video, tracked
    from the clip's first ground-truth frame (as ``voicepuppet demo`` does), on the clip's frames.

    The track is cached as ``cache_dir/STEM.npz`` (default: a ``tracked`` folder beside the
    video) under a key of the video file's size and modification time, the initial points and
    the tracker's code; any change re-tracks.

    Parameters
    ----------
    clip : voicepuppet.synth.Clip
        ``video`` (path) and ``points`` (T, P, 2), the ground truth.
    cache_dir : str, optional
        Folder of the cached tracks (default: a ``tracked`` folder beside the video).
    progress : bool
        Show the tracker's progress bar when it runs (default True).

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
    progress : bool
        Show progress bars while building the corpus and tracking (default True).

    Returns
    -------
    list of Sequence
        The training clip's utterances (``train_NN``), then one sequence per held-out clip
        (``test_NN``).

    Raises
    ------
    ValueError
        ``train_on`` or ``speech`` not one of their values.
    """
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
    if speech == "real":
        _label_readers(seqs, corpus)
    return seqs


def _label_readers(seqs: list, corpus) -> None:
    """Each real-speech sequence's ``meta["reader"]``: who reads it (:attr:`voicepuppet.data.Recording.speaker`).
    The training clip is the first of :data:`voicepuppet.synth.REAL_TRAIN` (one reader) and then
    the others (a second reader), with a pause between them where :func:`split_clip` cuts; the
    held-out clips are :data:`voicepuppet.synth.REAL_TEST` in order."""
    first, *rest = samples.real_recordings(synth.REAL_TRAIN)
    if len({r.speaker for r in rest}) != 1 or rest[0].speaker == first.speaker:
        raise RuntimeError(f"the real-speech training clip is not two readers, the first alone: "
                           f"{[r.speaker for r in (first, *rest)]}")
    # The cut between the readers lies in the silence around the end of the first reading (its own
    # trailing silence, then the pause): a sequence is the first reader's if its middle is before that end.
    end = soundfile.info(first.wav).duration
    start = 0
    for s in seqs:
        if s.name.startswith("train"):
            s.meta["reader"] = first.speaker if (start + len(s.points) / 2) / s.fps < end else rest[0].speaker
            start += len(s.points)
    tests = [s for s in seqs if not s.name.startswith("train")]
    for s, r in zip(tests, samples.real_recordings(synth.REAL_TEST)):
        s.meta["reader"] = r.speaker


def reader_folds(sequences) -> list[tuple[np.ndarray, np.ndarray]]:
    """Folds that leave a voice out, over real-speech sequences (:func:`synth_sequences` with
    ``speech="real"``): train on one training reader and test on the other, both ways, then
    train on both and test on the held-out speakers (``test_*``, CMU ARCTIC).

    Parameters
    ----------
    sequences : list of Sequence
        With ``meta["reader"]`` on every training sequence (``train_*``): two readers.

    Returns
    -------
    list of (train, test)
        Three pairs of sorted int64 index arrays: reader A → B, B → A, both → held out.

    Raises
    ------
    ValueError
        Training sequences without a reader, not two readers, or no held-out sequence.
    """
    train = [i for i, s in enumerate(sequences) if s.name.startswith("train")]
    held = np.array([i for i, s in enumerate(sequences) if not s.name.startswith("train")], dtype=np.int64)
    readers = [sequences[i].meta.get("reader") for i in train]
    names = list(dict.fromkeys(readers))
    if None in names or len(names) != 2 or not len(held):
        raise ValueError(f"leaving a voice out needs training sequences of two readers (meta['reader']) and "
                         f"held-out ones: got readers {names} and {len(held)} held out; use the real-speech "
                         f"sequences (synth_sequences(speech='real'))")
    a, b = (np.array([i for i, r in zip(train, readers) if r == n], dtype=np.int64) for n in names)
    return [(a, b), (b, a), (np.array(train, dtype=np.int64), held)]


def load_sequences(folder, alphabet: str = "arpabet") -> list[Sequence]:
    """User data: one sequence per ``NAME.npz`` in ``folder`` (sorted by name).

    Each ``NAME.npz`` holds ``points`` [T, P, 2] and ``fps``; beside it ``NAME.TextGrid`` or
    ``NAME.lab`` (HTS) gives the phones, and ``NAME.wav`` (optional) the audio.

    Parameters
    ----------
    folder : str or os.PathLike
        The data folder.
    alphabet : {"arpabet", "espeak"}
        Phone alphabet of the label files (default "arpabet").

    Returns
    -------
    list of Sequence
        One per ``NAME.npz``, sorted by name (audio as float32 mono, channels averaged).

    Raises
    ------
    FileNotFoundError
        ``folder`` does not exist.
    ValueError
        No sequences, a ``NAME.npz`` without ``points`` [T >= 2, P, 2] or ``fps``, missing
        labels, labels that do not cover the frames, unknown phones, or sequences of different
        frame rates.
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
                             f"voicepuppet.phonemes.labels.align")
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
