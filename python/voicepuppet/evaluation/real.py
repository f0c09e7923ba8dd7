"""Real people: the voice puppet trained on a real speaker's video, measured against an
independent reference (``voicepuppet evaluate --corpus real``).

Data: the real recordings that ship inside the package (:data:`RECORDINGS`, credited in
third_party_notes.md): Barack Obama in four sessions (an Oval Office address, a White House
address, a weekly address, seven sentence cuts of weekly addresses; 83 s, 25-30 fps, 256² to
1280x720), Ronald Reagan (26 s) and five GRID corpus speakers (3 s each), with their own voices.
The truth is no tracker of ours: MediaPipe Face Mesh run on every frame, kept as layout-free
measures per frame, the mouth's opening (inner lips' middles) and width (mouth corners) over the
inter-ocular distance (``recordings/reference.npz``; ``benchmarks/make_recordings.py`` builds it).

Protocol:

* **Leave one session out** (:func:`leave_one_session_out`): for each of the speaker's sessions,
  the models learn from the other sessions as ``voicepuppet train`` would (the clips tracked by
  the spring-mesh tracker from dlib's first-frame points, put on the first clip's frame grid,
  each recording's audio-video offset estimated and corrected,
  :func:`voicepuppet.puppet.sources.training_sequences`) and animate the held-out session's
  audio (its offset estimated the same way, from its own video: the truth is then in sync with
  the sound every model hears).
* **Any voice** (:func:`any_voice`): the models learn from all of the speaker's sessions and
  animate other speakers' recordings.

Models, each giving the mouth's opening per video frame: the voice puppet (entropic, guided, full
motion; also its most probable trajectory, not widened, its animation without its guide, Brand's
solve, and the puppet trained by conventional Baum-Welch), the ridge regression from ±5 frames of
the same standardised audio features to the face coordinates
(:class:`voicepuppet.puppet.guide.RidgeBaseline`, its α as the guide's: option ``guide_alpha``), a
mouth that opens with the speech's loudness (linear in its log energy, fitted on the training
frames: what many avatar apps do) and the training mean (the mean face); with ``rhubarb`` and
``learned``, what users would pick instead: Rhubarb Lip Sync's cues of the sound (each shape mapped
to the mean reference opening of the training frames under it: its best possible mapping; both
recognisers, the tables show the one of the lower RMSE) and a learned temporal network
(:class:`voicepuppet.evaluation.learned.ConvRegressor`) from the same standardised features to the
face coordinates, as the ridge. The tracker's opening is not the reference's (different points, a
different scale), so every model's opening is mapped to the reference's by the straight line fitted
between the two on the training clips' frames, never the held-out ones.

Measures per held-out clip against the reference opening: Pearson r, RMSE (inter-ocular
distances), spread (the model's standard deviation over the truth's), the best lag (frames
within ±6; positive: the model late) and, for the models that give landmarks, the share of
frames whose inner lips cross. The summary weighs clips by their frames; the puppet's paired
per-clip differences from the other models come with 95% intervals
(:func:`voicepuppet.evaluation.folds.mean_ci`; none for one clip).
"""

from __future__ import annotations

import functools
import hashlib
import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import audio as vaudio, data
from voicepuppet._version import __version__
from voicepuppet.blas import limited
from voicepuppet.evaluation.corpus import tracker_digest
from voicepuppet.evaluation.folds import mean_ci
from voicepuppet.evaluation.learned import ConvRegressor
from voicepuppet.evaluation.rhubarb import RECOGNIZERS, ShapeMap, frame_shapes
from voicepuppet.evaluation.report import markdown_table
from voicepuppet.layout import crossed_lips
from voicepuppet.puppet.guide import RidgeBaseline, lips_score
from voicepuppet.puppet.model import Puppet, load
from voicepuppet.puppet.sources import av_offsets, training_sequences
from voicepuppet.puppet.sync import mouth_opening, shift_audio, speech_loudness
from voicepuppet.tracking.landmarks import load_landmarks, save_landmarks
from voicepuppet.tracking.tracker import VariableFrameRateWarning, track_video

__all__ = ["RECORDINGS", "MODELS", "MAX_LAG", "RealClip", "real_clips", "cues_cache", "tracked_clip",
           "opening_measures", "leave_one_session_out", "any_voice", "summarize", "evaluate_real",
           "format_real", "sample_puppet"]

#: The real recordings inside the package: ``index.json``, ``reference.npz`` and the videos.
RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"
#: The models compared, in table order.
MODELS = ("voice puppet", "voice puppet, most probable", "voice puppet, unguided", "voice puppet, conventional",
          "ridge", "learned", "rhubarb", "loudness mouth", "mean face")
#: The models that give no landmarks (no crossed share).
_NO_LANDMARKS = ("rhubarb", "loudness mouth", "mean face")
#: The largest lag (frames) the best-lag search looks at, either way.
MAX_LAG = 6


@dataclass(frozen=True)
class RealClip:
    """One real recording and its reference.

    Each parameter is kept as the attribute of the same name.

    Parameters
    ----------
    key : str
        ``speaker-folder/clip``, e.g. ``"obama/oval_office_20s"``.
    speaker : str
        Who speaks.
    session : str
        The recording session (clips of one session share room, camera and sound).
    video : pathlib.Path
        The video with its sound.
    fps : float
        Its frame rate.
    opening : ndarray, shape (T,)
        The reference's mouth opening per video frame (inter-ocular distances).
    width : ndarray, shape (T,)
        The reference's mouth width per video frame (inter-ocular distances).
    """

    key: str
    speaker: str
    session: str
    video: Path
    fps: float
    opening: np.ndarray
    width: np.ndarray


def real_clips(root=None, speaker: str | None = None) -> list:
    """The real recordings with their reference.

    Parameters
    ----------
    root : path, optional
        A folder made as :data:`RECORDINGS` (``index.json``, ``reference.npz``, the videos);
        default: the recordings inside the package.
    speaker : str, optional
        Only this speaker's folder (``"obama"``, ``"reagan"``, ``"grid"``); default: all.

    Returns
    -------
    list of RealClip
        In the index's order.

    Raises
    ------
    ValueError
        ``root`` holds no index or reference, a clip's video is missing, or no clip is of
        ``speaker``.
    """
    root = Path(RECORDINGS if root is None else root)
    index, ref = root / "index.json", root / "reference.npz"
    if not index.is_file() or not ref.is_file():
        raise ValueError(f"{root} holds no real recordings (index.json and reference.npz); give the folder "
                         "made by benchmarks/make_recordings.py, or leave it out for the ones in the package")
    arrays = np.load(ref)
    out = []
    for key, info in json.loads(index.read_text())["clips"].items():
        if speaker is not None and key.split("/")[0] != speaker:
            continue
        video = root / info["file"]
        if not video.is_file():
            raise ValueError(f"{video}: the video of {key} is missing from {root}")
        out.append(RealClip(key, info["speaker"], info["session"], video, float(info["fps"]),
                            np.asarray(arrays[f"{key}/opening"], np.float64),
                            np.asarray(arrays[f"{key}/width"], np.float64)))
    if not out:
        raise ValueError(f"no recordings of {speaker!r} in {root}")
    return out


def _cache_dir(cache_dir) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    return Path(data.cache_dir()) / "real-tracks"


def cues_cache(cache_dir=None) -> Path:
    """Where Rhubarb's cues of the recordings are kept (:class:`voicepuppet.evaluation.rhubarb.Rhubarb`).

    Parameters
    ----------
    cache_dir : path, optional
        The folder given for the tracks (:func:`tracked_clip`); default: as there.

    Returns
    -------
    pathlib.Path
        ``rhubarb-cues`` beside the default tracks' folder, or inside the given one.
    """
    return Path(cache_dir) / "rhubarb-cues" if cache_dir is not None else _cache_dir(None).parent / "rhubarb-cues"


@functools.lru_cache(maxsize=None)
def _digest(path: str) -> str:
    """A video's content key (read once per process: every fold asks for its training tracks)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def tracked_clip(clip: RealClip, cache_dir=None, progress: bool = False, detector_anchors: bool = True) -> Path:
    """The clip tracked as ``voicepuppet track --init auto`` does (a landmark file, cached).

    Parameters
    ----------
    clip : RealClip
        The recording.
    cache_dir : path, optional
        Where tracks are kept (default: ``real-tracks`` in ``$VOICEPUPPET_CACHE`` or
        ``~/.cache/voicepuppet``); a track is reused while the video and the tracker's code
        (:func:`voicepuppet.evaluation.corpus.tracker_digest`) are the same.
    progress : bool
        Progress bars while tracking.
    detector_anchors : bool
        Track with dlib's lips anchoring the mesh's (as ``--init auto`` does by default; False:
        ``voicepuppet track --no-detector-anchors``).

    Returns
    -------
    pathlib.Path
        The landmark file (``points``, ``fps``, ``times``, ``lost``).
    """
    digest = _digest(str(clip.video))
    kind = "" if detector_anchors else "-unanchored"
    path = _cache_dir(cache_dir) / f"{clip.key.replace('/', '-')}-{digest}-{tracker_digest()[:16]}{kind}.npz"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        with warnings.catch_warnings():  # the training sequences resample, saying so
            warnings.simplefilter("ignore", VariableFrameRateWarning)
            result = track_video(str(clip.video), init="auto", progress=progress, detector_anchors=detector_anchors)
        save_landmarks(path, result, csv=False)  # through a temporary file and a rename
    return path


def _best_lag(pred: np.ndarray, truth: np.ndarray) -> int:
    n, best, lag = len(truth), -np.inf, 0
    for k in range(-MAX_LAG, MAX_LAG + 1):  # the prediction at t + k against the truth at t
        a, b = (pred[k:], truth[:n - k]) if k >= 0 else (pred[:n + k], truth[-k:])
        if a.std() > 0 and b.std() > 0:
            r = float(np.corrcoef(a, b)[0, 1])
            if r > best:
                best, lag = r, k
    return lag


def opening_measures(pred, truth) -> dict:
    """How a predicted mouth opening follows the true one (both in inter-ocular distances).

    Parameters
    ----------
    pred : array_like, shape (T,)
        The prediction per frame (cut or padded with its last value to the truth's length).
    truth : array_like, shape (T,)
        The reference per frame.

    Returns
    -------
    dict
        ``r`` (Pearson; NaN for a constant prediction), ``rmse``, ``spread`` (standard deviation
        over the truth's) and ``lag`` (frames, the prediction's best lag within ±:data:`MAX_LAG`).
    """
    truth = np.asarray(truth, dtype=np.float64)
    pred = _fit_length(np.asarray(pred, dtype=np.float64), len(truth))
    flat = pred.std() <= 1e-12 * (1.0 + abs(pred.mean()))
    return {"r": float("nan") if flat else float(np.corrcoef(pred, truth)[0, 1]),
            "rmse": float(np.sqrt(np.mean((pred - truth) ** 2))),
            "spread": float(pred.std() / truth.std()),
            "lag": 0 if flat else _best_lag(pred, truth)}


def _fit_length(x: np.ndarray, n: int) -> np.ndarray:
    if len(x) >= n:
        return x[:n]
    return np.concatenate([x, np.repeat(x[-1:], n - len(x), axis=0)])


def _tracker(cache_dir, progress: bool, detector_anchors: bool):
    """The clip -> cached track function of one evaluation (:func:`tracked_clip` with its options)."""
    return functools.partial(tracked_clip, cache_dir=cache_dir, progress=progress, detector_anchors=detector_anchors)


def _in_sync(clips, track) -> list:
    """Each clip's sound, shifted into sync with its face (offsets per session, as train does);
    ``track``: clip -> its track file (:func:`_tracker`)."""
    sounds = [vaudio.load_audio(c.video) for c in clips]
    by_session: dict = {}
    for i, c in enumerate(clips):
        by_session.setdefault(c.session, []).append(i)
    for idx in by_session.values():
        fps = clips[idx[0]].fps
        recs = [(load_landmarks(track(clips[i]))["points"], sounds[i], "")
                for i in idx]
        for i, off in zip(idx, av_offsets(recs, fps)):
            sounds[i] = shift_audio(sounds[i], off)
    return sounds


@dataclass
class _Models:
    """What one training set gives: the puppets, the baselines and the map to the reference."""

    puppets: dict
    ridge: RidgeBaseline
    loudness: np.ndarray  # opening = polyval(loudness, dB)
    mean: float
    to_reference: np.ndarray  # reference opening = polyval(to_reference, tracker opening)
    fps: float
    offsets: list
    learned: ConvRegressor | None = None


def _train(train: list, options: dict, track, learned: bool = False) -> _Models:
    tracks = [track(c) for c in train]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # resampled frame grids and dropped frames, said in train
        points, sounds, fps, offsets = training_sequences(landmarks=tracks, audio=[c.video for c in train])
    puppets = {"voice puppet": Puppet.train(points, sounds, fps=fps, **options),
               "voice puppet, conventional": Puppet.train(points, sounds, fps=fps, **{**options, "prior": "ml"})}
    main = puppets["voice puppet"]
    feats = [main.audio_features(a, n_out=len(p)) for p, a in zip(points, sounds)]
    faces = [main.face_space.encode(p)[0] for p in points]
    alpha = main.metadata["training"]["options"]["guide_alpha"]
    ridge = RidgeBaseline(per_target=alpha == "per_coordinate", score=lips_score(main.face_space) if alpha == "lips"
                          else None).fit([main.ridge_input(f) for f in feats], faces)
    net = ConvRegressor(seed=options.get("seed", 0)).fit([main.ridge_input(f) for f in feats], faces) if learned else None
    loud = np.concatenate([speech_loudness(a, fps, len(p)) for p, a in zip(points, sounds)])
    opening = np.concatenate([mouth_opening(p) for p in points])
    ours, theirs = [], []
    for c, t in zip(train, tracks):  # on the video frames, where the reference is
        o = mouth_opening(load_landmarks(t)["points"])
        n = min(len(o), len(c.opening))
        ok = np.isfinite(o[:n]) & np.isfinite(c.opening[:n])
        ours.append(o[:n][ok])
        theirs.append(c.opening[:n][ok])
    return _Models(puppets, ridge, np.polyfit(loud, opening, 1), float(np.nanmean(opening)),
                   np.polyfit(np.concatenate(ours), np.concatenate(theirs), 1), fps, offsets, net)


def _predict(models: _Models, clip: RealClip, sound, rhubarb: dict | None = None) -> dict:
    """Each model's opening for ``clip`` at its frames (reference units), and crossed shares;
    ``rhubarb``: per recogniser, the clip's openings from its cues (reference units already)."""
    n, out, crossed = len(clip.opening), {}, {}
    main = models.puppets["voice puppet"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # short or quiet test audio is animated as it is
        runs = {"voice puppet": main.animate(sound, fps=clip.fps),
                "voice puppet, most probable": main.animate(sound, fps=clip.fps, full_motion=False),
                "voice puppet, unguided": main.animate(sound, fps=clip.fps, guide_weight=0),
                "voice puppet, conventional": models.puppets["voice puppet, conventional"].animate(sound, fps=clip.fps)}
        feats = main.audio_features(sound)
    for name, run in runs.items():
        pts = run.animation.points
        out[name] = mouth_opening(pts)
        crossed[name] = float(crossed_lips(pts).mean())
    ridge_pts = main.face_space.decode(models.ridge.predict(main.ridge_input(feats)))
    t = np.arange(n) / clip.fps
    out["ridge"] = np.interp(t, np.arange(len(ridge_pts)) / models.fps, mouth_opening(ridge_pts))
    crossed["ridge"] = float(crossed_lips(ridge_pts).mean())
    if models.learned is not None:
        net_pts = main.face_space.decode(models.learned.predict(main.ridge_input(feats)))
        out["learned"] = np.interp(t, np.arange(len(net_pts)) / models.fps, mouth_opening(net_pts))
        crossed["learned"] = float(crossed_lips(net_pts).mean())
    out["loudness mouth"] = np.polyval(models.loudness, speech_loudness(sound, clip.fps, n))
    out["mean face"] = np.full(n, models.mean)
    preds = {k: np.polyval(models.to_reference, _fit_length(v, n)) for k, v in out.items()}
    for rec, opening in (rhubarb or {}).items():
        preds[f"rhubarb/{rec}"] = opening
    return {k: {**opening_measures(v, clip.opening), "crossed": crossed.get(k, 0.0), "frames": n}
            for k, v in preds.items()}


def _rhubarb_openings(rhubarb, clips, sounds) -> dict:
    """Per recogniser, each clip's Rhubarb shape per video frame (from its sound in sync)."""
    return {rec: [frame_shapes(rhubarb.cues(a.samples, a.rate, rec), len(c.opening), c.fps)
                  for c, a in zip(clips, sounds)] for rec in RECOGNIZERS}


def _shape_maps(shapes: dict, clips: list, train: list) -> dict:
    """Per recogniser, each shape's mean reference opening over the ``train`` clips' frames
    under it (its best possible mapping; frames without a reference left out)."""
    out = {}
    for rec, per_clip in shapes.items():
        ok = [np.isfinite(clips[i].opening) for i in train]
        out[rec] = ShapeMap().fit([per_clip[i][m] for i, m in zip(train, ok)],
                                  [clips[i].opening[m] for i, m in zip(train, ok)])
    return out


@limited
def leave_one_session_out(clips: list, *, options: dict | None = None, cache_dir=None,
                          rhubarb=None, learned: bool = False, progress: bool = False,
                          detector_anchors: bool = True) -> dict:
    """Leave-one-session-out over one speaker's clips (see the module's description).

    Parameters
    ----------
    clips : list of RealClip
        One speaker's recordings, in at least two sessions.
    options : dict, optional
        Training options of the puppets (:meth:`voicepuppet.puppet.model.Puppet.train`; default
        its defaults; ``prior`` is set to ``"ml"`` for the conventional one).
    cache_dir : path, optional
        Where tracks are cached (:func:`tracked_clip`).
    rhubarb : voicepuppet.evaluation.rhubarb.Rhubarb, optional
        Add Rhubarb Lip Sync (``rhubarb/pocketSphinx``, ``rhubarb/phonetic``): its cues of each
        clip's sound in sync, each shape mapped to the mean reference opening of the training
        clips' frames under it.
    learned : bool
        Add the learned peer (``learned``; needs PyTorch): a
        :class:`voicepuppet.evaluation.learned.ConvRegressor` from the features as the puppet
        standardises them to its face coordinates, mapped to the reference as the ridge is.
    progress : bool
        Progress bars.
    detector_anchors : bool
        Train on tracks made with dlib's lips anchoring the mesh's (:func:`tracked_clip`; the
        default, as ``--init auto`` tracks).

    Returns
    -------
    dict
        ``clips``: per held-out clip, ``key``, ``session`` and per model its measures
        (:func:`opening_measures` plus ``crossed`` and ``frames``); ``sessions``: per held-out
        session, the offsets corrected in its training recordings (s).

    Raises
    ------
    ValueError
        Fewer than two sessions.
    """
    sessions = list(dict.fromkeys(c.session for c in clips))
    if len(sessions) < 2:
        raise ValueError(f"leaving one session out needs two or more sessions, got {sessions}")
    track = _tracker(cache_dir, progress, detector_anchors)
    sounds = _in_sync(clips, track)
    shapes = _rhubarb_openings(rhubarb, clips, sounds) if rhubarb is not None else {}
    rows, info = [], {}
    for s in tqdm(sessions, desc="sessions", disable=not progress):
        models = _train([c for c in clips if c.session != s], dict(options or {}), track, learned)
        info[s] = {"training_offsets_s": [float(o) for o in models.offsets]}
        maps = _shape_maps(shapes, clips, [i for i, c in enumerate(clips) if c.session != s])
        for i, (c, sound) in enumerate(zip(clips, sounds)):
            if c.session == s:
                cues = {rec: maps[rec].predict(shapes[rec][i]) for rec in maps}
                rows.append({"key": c.key, "session": s, "models": _predict(models, c, sound, cues)})
    return {"clips": rows, "sessions": info}


@limited
def any_voice(train: list, tests: list, *, options: dict | None = None, cache_dir=None,
              rhubarb=None, learned: bool = False, voices: list | None = None, progress: bool = False,
              detector_anchors: bool = True) -> dict:
    """The models trained on all of ``train`` animate other speakers' recordings.

    Parameters
    ----------
    train : list of RealClip
        The speaker the models learn.
    tests : list of RealClip
        Other speakers' recordings (their own offsets corrected per session).
    options : dict, optional
        Training options of the puppets (as :func:`leave_one_session_out`).
    cache_dir : path, optional
        Where tracks are cached (:func:`tracked_clip`).
    rhubarb : voicepuppet.evaluation.rhubarb.Rhubarb, optional
        Add Rhubarb (as :func:`leave_one_session_out`; its shapes mapped from all of ``train``).
    learned : bool
        Add the learned peer (as :func:`leave_one_session_out`).
    voices : list of voicepuppet.data.Recording, optional
        Speech without faces (CMU ARCTIC, LibriVox: :func:`voicepuppet.data.real_recordings`)
        to animate too: with no reference opening to correlate with, how much the mouth moves
        against how much the training speaker's does.
    progress : bool
        Progress bars.
    detector_anchors : bool
        Train on tracks made with dlib's lips anchoring the mesh's (:func:`tracked_clip`; the
        default, as ``--init auto`` tracks).

    Returns
    -------
    dict
        ``clips``: per test clip, ``key``, ``session`` and per model its measures (as
        :func:`leave_one_session_out`). With ``voices``, ``no_face``: ``truth_spread`` (the
        median over ``train`` of a clip's reference-opening standard deviation, inter-ocular
        distances) and ``recordings``, per recording its ``name``, ``seconds`` and per model
        (the puppet, its most probable trajectory, the loudness mouth) ``spread`` (its opening's
        standard deviation over ``truth_spread``) and ``r_loudness`` (its correlation with the
        speech loudness in dB: does it move with the voice).
    """
    track = _tracker(cache_dir, progress, detector_anchors)
    models = _train(train, dict(options or {}), track, learned)
    sounds = _in_sync(tests, track)
    shapes, maps = {}, {}
    if rhubarb is not None:
        own = _in_sync(train, track)
        maps = _shape_maps(_rhubarb_openings(rhubarb, train, own), train, list(range(len(train))))
        shapes = _rhubarb_openings(rhubarb, tests, sounds)
    out = {"clips": [{"key": c.key, "session": c.session,
                      "models": _predict(models, c, s, {rec: maps[rec].predict(shapes[rec][i]) for rec in maps})}
                     for i, (c, s) in enumerate(zip(tests, sounds))]}
    if voices:
        out["no_face"] = _no_face(models, train, voices)
    return out


def _no_face(models: _Models, train: list, recordings: list) -> dict:
    """The models animate recordings without a face (:func:`any_voice`'s ``voices``)."""
    fps = models.fps
    truth_spread = float(np.median([np.nanstd(c.opening) for c in train]))
    main = models.puppets["voice puppet"]
    rows = []
    for rec in recordings:
        sound = vaudio.load_audio(rec.wav)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            runs = {"voice puppet": main.animate(sound, fps=fps),
                    "voice puppet, most probable": main.animate(sound, fps=fps, full_motion=False)}
        n = min(len(r.animation.points) for r in runs.values())
        loud = speech_loudness(sound, fps, n)
        openings = {k: np.polyval(models.to_reference, mouth_opening(r.animation.points)[:n]) for k, r in runs.items()}
        openings["loudness mouth"] = np.polyval(models.to_reference, np.polyval(models.loudness, loud))
        rows.append({"name": rec.name, "seconds": float(sound.duration),
                     "models": {k: {"spread": float(v.std() / truth_spread),
                                    "r_loudness": float(np.corrcoef(v, loud)[0, 1]) if v.std() > 0 else float("nan")}
                                for k, v in openings.items()}})
    return {"truth_spread": truth_spread, "recordings": rows}


def summarize(rows: list) -> dict:
    """The summary of a protocol's clips, as :func:`format_real` shows it.

    Parameters
    ----------
    rows : list of dict
        The ``clips`` of :func:`leave_one_session_out` or :func:`any_voice`.

    Returns
    -------
    dict
        Per model: frame-weighted means of ``r``, ``rmse`` and ``spread``, the median ``lag``
        and the largest ``crossed`` share; per model but the puppet, ``puppet_minus``: the
        puppet's paired per-clip differences of r and RMSE (``mean``, ``lo``, ``hi``: 95% CI).
        With Rhubarb's two recognisers, ``rhubarb`` is the one of the lower RMSE (its
        ``recognizer`` says which).
    """
    w = np.array([r["models"]["voice puppet"]["frames"] for r in rows], float)
    out = {}
    for m in rows[0]["models"]:
        vals = {k: np.array([r["models"][m][k] for r in rows], float) for k in ("r", "rmse", "spread", "lag", "crossed")}
        out[m] = {"r": float(np.average(vals["r"], weights=w)) if np.isfinite(vals["r"]).all() else float("nan"),
                  "rmse": float(np.average(vals["rmse"], weights=w)),
                  "spread": float(np.average(vals["spread"], weights=w)),
                  "lag": float(np.median(vals["lag"])), "crossed": float(vals["crossed"].max())}
        if m != "voice puppet":
            diff = {}
            for k in ("r", "rmse"):
                d = np.array([r["models"]["voice puppet"][k] - r["models"][m][k] for r in rows], float)
                if np.isfinite(d).all():
                    mean, lo, hi = mean_ci(d) if len(d) > 1 else (float(d[0]), float("nan"), float("nan"))
                    diff[k] = {"mean": mean, "lo": lo, "hi": hi}
            out[m]["puppet_minus"] = diff
    recs = [r for r in RECOGNIZERS if f"rhubarb/{r}" in out]
    if recs:
        best = min(recs, key=lambda r: out[f"rhubarb/{r}"]["rmse"])
        out["rhubarb"] = dict(out[f"rhubarb/{best}"], recognizer=best)
    return out


def evaluate_real(root=None, *, speaker: str = "obama", options: dict | None = None, cache_dir=None,
                  rhubarb=None, learned: bool = False, voices: list | None = None, progress: bool = False,
                  detector_anchors: bool = True) -> dict:
    """Both protocols on the real recordings: leave one of ``speaker``'s sessions out, and
    ``speaker``'s models animating every other speaker.

    Parameters
    ----------
    root : path, optional
        The recordings (:func:`real_clips`; default: the ones in the package).
    speaker : str
        The speaker the models learn (a folder of the recordings; default ``"obama"``).
    options : dict, optional
        Training options of the puppets.
    cache_dir : path, optional
        Where tracks are cached (:func:`tracked_clip`).
    rhubarb : voicepuppet.evaluation.rhubarb.Rhubarb, optional
        Add Rhubarb Lip Sync's rows (both recognisers; the tables show the one of the lower RMSE).
    learned : bool
        Add the learned peer's row (needs PyTorch).
    voices : list of voicepuppet.data.Recording, optional
        Speech without faces to animate too (:func:`any_voice`).
    progress : bool
        Progress bars.
    detector_anchors : bool
        Train on tracks made with dlib's lips anchoring the mesh's (:func:`tracked_clip`; the
        default, as ``--init auto`` tracks).

    Returns
    -------
    dict
        ``loso`` and ``any_voice``: each ``clips`` (per clip and model, the measures) and
        ``summary`` (per model, see :func:`format_real`), ``any_voice`` also ``no_face`` with
        ``voices``; ``speaker`` and ``options``.
    """
    own = real_clips(root, speaker)
    others = [c for c in real_clips(root) if c.key.split("/")[0] != speaker]
    loso = leave_one_session_out(own, options=options, cache_dir=cache_dir, rhubarb=rhubarb, learned=learned,
                                 progress=progress, detector_anchors=detector_anchors)
    loso["summary"] = summarize(loso["clips"])
    result = {"speaker": speaker, "options": dict(options or {}), "loso": loso}
    if others:
        heard = any_voice(own, others, options=options, cache_dir=cache_dir, rhubarb=rhubarb, learned=learned,
                          voices=voices, progress=progress, detector_anchors=detector_anchors)
        heard["summary"] = summarize(heard["clips"])
        by_speaker: dict = {}
        for row in heard["clips"]:
            by_speaker.setdefault(row["key"].split("/")[0], []).append(row)
        heard["by_speaker"] = {k: summarize(v) for k, v in by_speaker.items()}
        result["any_voice"] = heard
    return result


def _table(summary: dict) -> list:
    def ci(d):
        if not d:
            return "–"
        return f"{d['mean']:+.3f} [{d['lo']:+.3f}, {d['hi']:+.3f}]" if np.isfinite(d["lo"]) else f"{d['mean']:+.3f}"

    rows = []
    for m in (m for m in MODELS if m in summary):
        s = summary[m]
        diff = s.get("puppet_minus", {})
        name = f"rhubarb ({s['recognizer']})" if m == "rhubarb" else m
        rows.append([name, "–" if not np.isfinite(s["r"]) else f"{s['r']:.3f}", f"{s['rmse']:.4f}", f"{s['spread']:.2f}",
                     f"{s['lag']:+.0f}", f"{100 * s['crossed']:.1f}" if m not in _NO_LANDMARKS else "–",
                     "" if m == "voice puppet" else ci(diff.get("r")),
                     "" if m == "voice puppet" else ci(diff.get("rmse"))])
    return markdown_table(["model", "opening r", "RMSE / IOD", "spread", "lag", "crossed %",
                           "puppet − model: r", "puppet − model: RMSE"], rows)


def format_real(result: dict) -> str:
    """The tables of :func:`evaluate_real` as Markdown.

    Parameters
    ----------
    result : dict
        What :func:`evaluate_real` returns.

    Returns
    -------
    str
        One table per protocol (and per other speaker, and for voices without faces): per model, the opening's correlation
        with the reference, its RMSE (inter-ocular distances), spread (model / truth), median
        best lag (frames), the largest share of a clip's frames with crossed inner lips, and the
        puppet's paired per-clip differences from the model (mean [95% CI]).
    """
    n = len(result["loso"]["clips"])
    lines = [f"Leave one session out ({result['speaker']}, {n} held-out clips, "
             f"{len(result['loso']['sessions'])} sessions)", ""]
    lines += _table(result["loso"]["summary"])
    if "any_voice" in result:
        for who, summary in result["any_voice"]["by_speaker"].items():
            k = sum(1 for r in result["any_voice"]["clips"] if r["key"].startswith(who + "/"))
            lines += ["", f"Any voice: the {result['speaker']} models animate {who} ({k} clip{'s' * (k != 1)})", ""]
            lines += _table(summary)
    if "no_face" in result.get("any_voice", {}):
        nf = result["any_voice"]["no_face"]
        lines += ["", f"Voices without faces: the {result['speaker']} puppet's opening spread over the "
                      f"{result['speaker']} reference's ({nf['truth_spread']:.4f} IOD), and its correlation with "
                      "the speech loudness", ""]
        names = ["voice puppet", "voice puppet, most probable", "loudness mouth"]
        lines += markdown_table(["recording", "s"] + [f"{m}: spread" for m in names] + ["puppet: r loudness"],
                                [[r["name"], f"{r['seconds']:.1f}"] + [f"{r['models'][m]['spread']:.2f}" for m in names]
                                 + [f"{r['models']['voice puppet']['r_loudness']:.2f}"] for r in nf["recordings"]])
    return "\n".join(lines) + "\n"


def sample_puppet(cache_dir=None, progress: bool = False) -> Puppet:
    """A puppet of a real speaker, ready to animate any audio: Barack Obama, trained with the
    defaults on all four sessions of the recordings inside the package (83 s).

    Made on first use (the videos tracked and the puppet trained: about a minute) and kept.

    Parameters
    ----------
    cache_dir : path, optional
        Where the puppet and the tracks are kept (default: ``$VOICEPUPPET_CACHE`` or
        ``~/.cache/voicepuppet``); remade when voicepuppet's version or its tracker changes.
    progress : bool
        Progress bars and a line saying it is being made.

    Returns
    -------
    Puppet
    """
    base = Path(cache_dir) if cache_dir is not None else _cache_dir(None).parent
    path = base / f"sample-obama-{__version__}-{tracker_digest()[:12]}.vpp"
    if not path.is_file():
        if progress:
            print(f"making the sample puppet (Barack Obama, 83 s of video; once): {path}")
        clips = real_clips(speaker="obama")
        tracks = [tracked_clip(c, base / "real-tracks", progress) for c in clips]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # resampled frame grids, said in train
            points, sounds, fps, _ = training_sequences(landmarks=tracks, audio=[c.video for c in clips])
        path.parent.mkdir(parents=True, exist_ok=True)
        Puppet.train(points, sounds, fps=fps, progress=progress).save(path)
    return load(path)
