"""Training data from videos and landmark files: each sequence's landmarks on the audio's frame
grid with its audio, cut where the face was lost (what ``voicepuppet train`` feeds
:meth:`voicepuppet.puppet.model.Puppet.train`)."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from voicepuppet import audio as vaudio
from voicepuppet.layout import N_POINTS
from voicepuppet.limits import check_limit
from voicepuppet.puppet.sync import AvOffset, estimate_av_offset, estimate_shared_av_offset, shift_audio
from voicepuppet.tracking import tracker
from voicepuppet.tracking.landmarks import load_landmarks, on_uniform_grid
from voicepuppet.tracking.tracker import VariableFrameRateWarning

__all__ = ["MAX_LOST_SHARE", "MIN_SEGMENT", "MAX_AV_MISMATCH_S", "usable_segments", "training_sequences",
           "av_offsets"]

#: A frame whose share of lost points exceeds this is not used for training.
MAX_LOST_SHARE = 0.3
#: Shortest run of usable frames kept for training.
MIN_SEGMENT = 10
#: A face and its audio whose durations differ by more than this (s) are warned about: they may
#: not belong together.
MAX_AV_MISMATCH_S = 0.5


def usable_segments(points, lost=None, audio=None, fps: float = 29.97, where: str = ""):
    """Split a tracked sequence where the face was lost; returns ``[(points, audio), ...]``.

    Frames with more than :data:`MAX_LOST_SHARE` of their points flagged lost are dropped, and
    runs shorter than :data:`MIN_SEGMENT` frames too; a warning says how much was dropped. A NaN
    or infinite point (another tool's mark for a point it lost) counts as lost; one on a frame
    that is kept is refused, with its frame. The audio of each kept run is cut to match
    (``audio`` is an :class:`voicepuppet.audio.Audio`).

    Parameters
    ----------
    points : array_like, shape (T, P, 2)
        The sequence's landmarks.
    lost : array_like of bool, shape (T, P), optional
        The tracker's lost flags per point (default: only non-finite points are lost).
    audio : voicepuppet.audio.Audio, optional
        The sequence's audio, starting at frame 0 (needed when frames are dropped).
    fps : float
        Frame rate of ``points`` (default 29.97), to cut the audio.
    where : str
        Prefix of the messages naming the sequence (e.g. ``"clip.mp4: "``; default none).

    Returns
    -------
    list of (ndarray, voicepuppet.audio.Audio)
        The kept runs' landmarks, shape (T_i, P, 2), with their audio; the whole sequence as
        given when nothing is lost.

    Raises
    ------
    ValueError
        A NaN or infinite point on a kept frame, or no run of :data:`MIN_SEGMENT` usable frames.
    """
    T = len(points)
    missing = ~np.isfinite(np.asarray(points, dtype=np.float64)).reshape(T, -1, 2).all(axis=2)
    if lost is None and not missing.any():
        return [(points, audio)]
    lost = missing if lost is None else np.asarray(lost, dtype=bool).reshape(T, -1) | missing
    bad = lost.mean(axis=1) > MAX_LOST_SHARE
    if missing[~bad].any():
        t, p = np.argwhere(missing & ~bad[:, None])[0]
        raise ValueError(f"{where}point {p} of frame {t} is NaN or infinite on a frame where the face is found "
                         f"(at most {100 * MAX_LOST_SHARE:g}% of its points lost); fill it in (interpolate) or "
                         "drop the frame")
    if not bad.any():
        return [(points, audio)]
    runs, start = [], None
    for t in range(T + 1):
        ok = t < T and not bad[t]
        if ok and start is None:
            start = t
        elif not ok and start is not None:
            if t - start >= MIN_SEGMENT:
                runs.append((start, t))
            start = None
    kept = sum(b - a for a, b in runs)
    if not runs:
        raise ValueError(f"{where}the face is lost in {int(bad.sum())} of {T} frames, leaving no run of "
                         f"{MIN_SEGMENT} usable frames; check the video or the tracker's init points")
    warnings.warn(f"{where}the face was lost in {int(bad.sum())} of {T} frames; training on the "
                  f"{len(runs)} stretch(es) where it was found ({kept} frames)", stacklevel=2)
    out = []
    for a, b in runs:
        s0, s1 = int(round(a / fps * audio.rate)), int(round(b / fps * audio.rate))
        out.append((points[a:b], replace(audio, samples=audio.samples[s0:s1])))
    return out


def training_sequences(videos=(), landmarks=(), audio=(), *, init="auto", av_offset=None, progress: bool = False,
                       report=None):
    """The training sequences of a puppet from videos and/or landmark files with their audio.

    Each video is tracked (unless its landmarks are given), its landmarks put on a uniform frame
    grid (:func:`voicepuppet.tracking.landmarks.on_uniform_grid`) and cut where the face was lost
    (:func:`usable_segments`). Every sound is loaded before any tracking, so a video without an
    audio track fails at once.

    Parameters
    ----------
    videos : sequence of path
        Training videos (their sound is the audio unless ``audio`` is given).
    landmarks : sequence of path
        Landmark files (``voicepuppet track`` output), one per video or instead of videos.
    audio : sequence of path
        One sound per sequence, instead of the videos' own.
    init : str, path or ndarray
        The tracker's initialisation (see :func:`voicepuppet.tracking.tracker.track_video`).
    av_offset : float, optional
        How late every recording's sound runs against its face (s), corrected as given; None
        (default): estimated per recording (68-point landmarks; others are taken as in sync).
    progress : bool
        Progress bars while tracking.
    report : callable, optional
        Called with one line per recording saying its offset and what was done about it.

    Returns
    -------
    points_list : list of ndarray, shape (T_i, P, 2)
    audio_list : list of voicepuppet.audio.Audio
    fps : float
        The frame rate of every sequence.
    offsets : list of float
        The offset corrected in each recording (s; 0 where none was).

    Raises
    ------
    ValueError
        The inputs do not pair up, a file is unreadable, or sequences run at different rates.
    """
    videos, marks, audios = list(videos), list(landmarks), list(audio)
    if not videos and not marks:
        raise ValueError("give training videos, or --landmarks with --audio")
    if marks and videos and len(marks) != len(videos):
        raise ValueError(f"{len(marks)} --landmarks files for {len(videos)} videos; give one per video")
    if audios and len(audios) != max(len(videos), len(marks)):
        raise ValueError(f"{len(audios)} --audio files for {max(len(videos), len(marks))} sequences; give one each")
    if marks and not videos and not audios:
        raise ValueError("--landmarks needs --audio (or the videos they were tracked from)")
    n = max(len(videos), len(marks))
    # Every sound before any tracking: a video without an audio track fails in a second, not
    # after minutes of tracking it (and the ones before it).
    sounds = [vaudio.load_audio(audios[i] if audios else videos[i]) for i in range(n)]
    if av_offset is not None and not (np.isfinite(av_offset) and abs(av_offset) < 10.0):
        raise ValueError(f"the audio-video offset must be a number of seconds under 10 either way, got {av_offset!r}")
    recordings, fps = [], None
    for i in range(n):
        if marks:
            data = load_landmarks(marks[i])
            if "points" not in data:
                raise ValueError(f"{marks[i]}: no 'points' array; expected landmarks from voicepuppet track")
            if "fps" not in data:
                raise ValueError(f"{marks[i]}: no 'fps' array: the landmarks' frame rate is needed to pair them "
                                 "with the audio; save it with the points (np.savez(..., points=..., fps=...))")
            f = float(np.asarray(data["fps"], dtype=np.float64).reshape(-1)[0])
            if not (np.isfinite(f) and 1.0 <= f <= 1000.0):
                raise ValueError(f"{marks[i]}: fps is {f:g}; a frame rate between 1 and 1000 frames per second "
                                 "is expected")
            pts = data["points"]
            if pts.ndim != 3 or pts.shape[2] != 2:
                raise ValueError(f"{marks[i]}: points must have shape (T, P, 2), got {pts.shape}")
            check_limit(len(pts), "frames", f"{marks[i]}: landmark frames")
            check_limit(pts.shape[1], "points", f"{marks[i]}: landmark points per frame")
            lost, times = data.get("lost"), data.get("times")
            where = f"{marks[i]}: "
        else:
            print(f"tracking {videos[i]} ...")
            with warnings.catch_warnings():  # the resampling below says it, with what it did
                warnings.simplefilter("ignore", VariableFrameRateWarning)
                res = tracker.track_video(videos[i], init=init, progress=progress)
            pts, f, lost, times, where = res.points, res.fps, res.lost, res.times, f"{videos[i]}: "
        if fps is None:
            fps = f
        elif times is None and abs(f - fps) > 1e-3:
            raise ValueError(f"sequence {i} runs at {f:g} fps but the first at {fps:g}; use one frame rate")
        pts, lost = on_uniform_grid(pts, lost, times, fps, where)
        seen, heard = len(pts) / fps, sounds[i].duration
        if abs(seen - heard) > MAX_AV_MISMATCH_S:
            warnings.warn(f"{where}the face runs {seen:.2f} s and its audio {heard:.2f} s ("
                          f"{audios[i] if audios else videos[i]}): "
                          + ("the frames after the audio ends are trained on silence" if seen > heard else
                             "the audio after the last frame is not used")
                          + "; check that the two belong together", stacklevel=2)
        recordings.append((pts, lost, sounds[i], where))
    offsets = av_offsets([(p, a, w) for p, _, a, w in recordings], fps, av_offset, report)
    points_list, audio_list = [], []
    for (pts, lost, sound, where), offset in zip(recordings, offsets):
        for seg in usable_segments(pts, lost, shift_audio(sound, offset), fps, where):
            points_list.append(seg[0])
            audio_list.append(seg[1])
    return points_list, audio_list, fps, offsets


def av_offsets(recordings, fps: float, av_offset=None, report=None) -> list:
    """The audio-video offset to correct in each recording of one speaker.

    The given offset for all, or each recording's estimate (:func:`voicepuppet.puppet.sync.estimate_av_offset`)
    where it is reliable; the recordings whose own estimate is not reliable are judged together
    (:func:`voicepuppet.puppet.sync.estimate_shared_av_offset`: sentence cuts of one source share
    its offset), and that estimate is used for them when it is reliable. An estimate under a
    frame is not corrected: it is within a face's natural lead on its sound and the estimate's
    spread. Recordings whose landmarks are not of the 68-point layout are taken as in sync.

    Parameters
    ----------
    recordings : sequence of (points, audio, where)
        Each recording's landmarks (T_i, P, 2) on a uniform grid at ``fps``, its sound
        (:class:`voicepuppet.audio.Audio`, starting with frame 0), and the prefix of the
        messages naming it (e.g. ``"clip.mp4: "``).
    fps : float
        The landmarks' frame rate.
    av_offset : float, optional
        How late every recording's sound runs (s), corrected as given; None (default): estimated.
    report : callable, optional
        Called with one line per recording saying its offset and what was done about it.

    Returns
    -------
    list of float
        The offset to correct in each recording (s; 0 where none is).
    """
    say = report or (lambda line: None)
    if av_offset is not None:
        for _, _, where in recordings:
            if av_offset:
                say(f"{where}audio-video offset {1000 * av_offset:+.0f} ms (given): corrected")
        return [float(av_offset)] * len(recordings)
    offsets, unsure = [0.0] * len(recordings), []
    for i, (points, sound, where) in enumerate(recordings):
        if np.asarray(points).shape[1] != N_POINTS:
            say(f"{where}audio-video offset not estimated ({np.asarray(points).shape[1]} landmarks, not 68): "
                "taken as in sync")
            continue
        est: AvOffset = estimate_av_offset(points, sound, fps)
        if est.reliable:
            offsets[i] = _act_on(est, fps, where, say)
        else:
            unsure.append((i, est))
    if len(unsure) > 1:
        shared = estimate_shared_av_offset([(recordings[i][0], recordings[i][1], fps) for i, _ in unsure])
        if shared.reliable:
            for i, _ in unsure:
                offsets[i] = _act_on(shared, fps, recordings[i][2], say,
                                     f" (judged with the {len(unsure) - 1} other recording(s) too short or "
                                     "unclear to judge alone)")
            return offsets
    for i, est in unsure:
        say(f"{recordings[i][2]}audio-video offset not estimated reliably ({est.reason}): taken as in sync; "
            "--av-offset MS sets it")
    return offsets


def _act_on(est: AvOffset, fps: float, where: str, say, together: str = "") -> float:
    """The offset to correct for a reliable estimate (none under a frame), said."""
    if abs(est.seconds * fps) < 1.0:
        say(f"{where}audio and video {est.describe(fps)}{together}")
        return 0.0
    say(f"{where}{est.describe(fps)}{together}: corrected (--av-offset MS overrides)")
    return est.seconds
