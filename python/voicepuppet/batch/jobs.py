"""Batch work at scale on Dask: animate folders of audio, track folders of video.

``voicepuppet batch animate PUPPET AUDIO_DIR -o OUT_DIR [--format npz,csv,...]`` animates every
audio file under ``AUDIO_DIR`` with a puppet and exports it;
``voicepuppet batch track VIDEO_DIR -o OUT_DIR`` tracks every video. Files run in parallel on a
Dask cluster: a ``LocalCluster`` of ``--workers`` processes by default, or the cluster of
``--scheduler tcp://HOST:8786`` (docs/batch.md says how to start one); how a run behaves
(resumable, failures per file, atomic writes) is :mod:`voicepuppet.batch.engine`'s.

Outputs equal the one-by-one outputs (``puppet.animate`` + :func:`voicepuppet.render.export.export`,
:func:`voicepuppet.tracking.tracker.track_video` + ``save_landmarks``) byte for byte, apart from the
member timestamps numpy writes into ``.npz`` archives (their members are byte-identical).
"""

from __future__ import annotations

import tempfile
import threading
from pathlib import Path

import numpy as np

from voicepuppet.batch.engine import BatchSummary, discover, refusals_reported, run_batch, sha256_file
from voicepuppet.hmm.distributed import connect
from voicepuppet.limits import check_limit
from voicepuppet.puppet import load
from voicepuppet.render.export import FORMATS, export
from voicepuppet.tracking import load_init_points, load_landmarks, save_landmarks, track_video

__all__ = ["AUDIO_SUFFIXES", "VIDEO_SUFFIXES", "animate_file", "animate_folder", "track_file", "track_folder"]

AUDIO_SUFFIXES = (".wav", ".flac", ".ogg", ".mp3", ".m4a", ".aac", ".opus", ".aiff", ".aif")
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v", ".mpg", ".mpeg")


def _clashes(inputs: list[Path], root: Path) -> dict[str, str]:
    """Inputs whose outputs would overwrite an earlier input's (same path but the suffix)."""
    first: dict[str, str] = {}
    out = {}
    for p in inputs:
        rel = p.relative_to(root).as_posix()
        stem = Path(rel).with_suffix("").as_posix()
        if stem in first:
            out[rel] = (f"its outputs would overwrite those of {first[stem]} (same name, another suffix); "
                        "rename one of them")
        else:
            first[stem] = rel
    return out


def _collect(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ----------------------------------------------------------------------------- animate

_PUPPETS: dict = {}
_PUPPET_LOCK = threading.Lock()


def _load_puppet(path: str, digest: str):
    """The puppet at ``path``, loaded once per worker process (keyed by its checksum)."""
    with _PUPPET_LOCK:
        key = (path, digest)
        if key not in _PUPPETS:
            _PUPPETS.clear()
            _PUPPETS[key] = load(path)
        return _PUPPETS[key]


def _format_tags(formats) -> dict[str, str]:
    tags = {}
    for fmt in formats:
        if fmt not in FORMATS:
            raise ValueError(f"unknown export format {fmt!r}; use some of {', '.join(FORMATS)}")
        tag = ("_arkit" if fmt.startswith("arkit") else "") + ("_cues" if fmt.startswith("rhubarb") else "")
        tags[fmt] = tag + FORMATS[fmt]
    if len(tags) != len(formats) or len(set(tags.values())) != len(tags):
        raise ValueError(f"formats {', '.join(formats)} would write the same file twice; name each format once")
    return tags


def _animate_export(puppet, audio_path, out_stem, formats, fps, posterior) -> tuple[list[Path], float]:
    tags = _format_tags(formats)
    if set(tags) <= {"npz", "csv"}:  # landmark files: written a block at a time (long audio in bounded memory)
        done = puppet.animate_to([Path(str(out_stem) + tag) for tag in tags.values()], str(audio_path), fps=fps,
                                 posterior=posterior)
        return done.paths, done.duration
    anim = puppet.animate(str(audio_path), fps=fps, posterior=posterior).animation
    written = []
    for fmt, tag in _format_tags(formats).items():
        p = Path(str(out_stem) + tag)
        export(anim, p, fmt, sound_file=Path(audio_path).name)
        written.append(p)
    return written, anim.duration


def animate_file(puppet, audio_path, out_stem, formats, *, fps=None, posterior=False) -> list[Path]:
    """Animates one audio file and exports it: the one-by-one reference of ``batch animate``.

    Parameters
    ----------
    puppet : voicepuppet.puppet.model.Puppet
    audio_path : str or os.PathLike
        The audio.
    out_stem : str or os.PathLike
        Output path without suffix; each format ``f`` goes to ``out_stem + tag(f)`` (``.npz``,
        ``.csv``, ``_arkit.csv``, ``_cues.json``, ...).
    formats : sequence of str
        Keys of :data:`voicepuppet.render.export.FORMATS`.
    fps : float, optional
        As in ``puppet.animate``.
    posterior : bool
        As in ``puppet.animate``.

    Returns
    -------
    list of Path
        The files written.
    """
    return _animate_export(puppet, audio_path, out_stem, formats, fps, posterior)[0]


@refusals_reported
def _animate_task(audio_path: str, puppet_path: str, puppet_digest: str, out_stem: str, formats: list,
                  fps, posterior: bool) -> dict:
    puppet = _load_puppet(puppet_path, puppet_digest)
    with tempfile.TemporaryDirectory(prefix="voicepuppet-batch-") as d:
        _, duration = _animate_export(puppet, audio_path, Path(d) / Path(out_stem).name, formats, fps, posterior)
        files = _collect(Path(d))
    parent = Path(out_stem).parent.as_posix()
    prefix = "" if parent in ("", ".") else parent + "/"
    return {"files": {prefix + k: v for k, v in files.items()}, "media_seconds": duration}


def animate_folder(puppet_path, audio_dir, out_dir, formats=("npz",), *, fps=None, posterior=False,
                   client=None, scheduler=None, workers=None, timeout=10.0, progress=True) -> BatchSummary:
    """Animates every audio file under ``audio_dir`` with the puppet (``batch animate``).

    Parameters
    ----------
    puppet_path : str or os.PathLike
        A puppet file (``voicepuppet.load``).
    audio_dir : str or os.PathLike
        Folder searched recursively for :data:`AUDIO_SUFFIXES`.
    out_dir : str or os.PathLike
        Output folder; ``a/b.wav`` gives ``out_dir/a/b.npz`` etc.
    formats : sequence of str
        Keys of :data:`voicepuppet.render.export.FORMATS`.
    fps : float, optional
        As in ``puppet.animate``.
    posterior : bool
        As in ``puppet.animate``.
    client : distributed.Client, optional
        An existing client; otherwise one from :func:`voicepuppet.hmm.distributed.connect`
        (``scheduler``, ``workers``, ``timeout``).
    scheduler : str, optional
        Address of a Dask scheduler (default: a local cluster).
    workers : int, optional
        Local worker processes (default: one per CPU); with ``scheduler``, workers to wait for.
    timeout : float
        Seconds to wait for the scheduler and workers.
    progress : bool
        Show a progress bar.

    Returns
    -------
    BatchSummary

    Raises
    ------
    ValueError
        A missing or damaged puppet file (checked before any file is animated), no or unknown
        formats, an ``fps`` outside the limits, an input folder that does not exist, an output
        folder that cannot be written.
    """
    puppet_path = Path(puppet_path)
    if not puppet_path.is_file():
        raise ValueError(f"puppet file {str(puppet_path)!r} does not exist; train one with `voicepuppet train`")
    formats = list(formats)
    if not formats:
        raise ValueError("give at least one output format")
    _format_tags(formats)
    if fps is not None:
        check_limit(fps, "fps", "output fps", "pass --fps within it")
    try:
        puppet_digest = sha256_file(puppet_path)
    except OSError as exc:
        raise ValueError(f"cannot read the puppet file {str(puppet_path)!r}: {exc}") from None
    load(puppet_path)  # a damaged puppet stops the batch here, once, not in every file's task
    inputs = discover(audio_dir, AUDIO_SUFFIXES, exclude=out_dir)
    root = Path(audio_dir)
    fps = None if fps is None else float(fps)
    settings = {"verb": "animate", "puppet_sha256": puppet_digest, "formats": formats, "fps": fps,
                "posterior": bool(posterior)}
    jobs = []
    for p in inputs:
        rel = p.relative_to(root)
        jobs.append((rel.as_posix(), p, (str(puppet_path.resolve()), puppet_digest,
                                         rel.with_suffix("").as_posix(), formats, fps, bool(posterior))))
    clashes = _clashes(inputs, root)
    if client is not None:
        return run_batch("animate", jobs, _animate_task, out_dir, settings, client, progress=progress,
                         clashes=clashes)
    with connect(scheduler, workers, timeout=timeout) as c:
        return run_batch("animate", jobs, _animate_task, out_dir, settings, c, progress=progress, clashes=clashes)


# ----------------------------------------------------------------------------- track

def track_file(video_path, out_npz, *, init="auto", passes: int = 2, **options) -> list[Path]:
    """Tracks one video and writes ``out_npz`` and its ``.csv`` twin: the one-by-one reference of
    ``batch track`` (:func:`voicepuppet.tracking.tracker.track_video` + ``save_landmarks``).

    Parameters
    ----------
    video_path : str or os.PathLike
    out_npz : str or os.PathLike
        The landmarks file written (its ``.csv`` twin beside it).
    init : str or ndarray, shape (P, 2)
        ``"auto"``, or first-frame points, as ``track_video`` takes them.
    passes : int
        Tracking passes.
    **options
        As in :func:`voicepuppet.tracking.tracker.track_video`.

    Returns
    -------
    list of Path
        The files written.
    """
    result = track_video(str(video_path), init, passes=passes, progress=False, **options)
    return save_landmarks(out_npz, result)


@refusals_reported
def _track_task(video_path: str, out_stem: str, init, passes: int, options: dict) -> dict:
    """``init``: "auto", or the points file's ``(points, names)`` as read once for the batch (its
    warnings, e.g. coincident points moved apart, said once up front rather than per file)."""
    if init != "auto":
        points, names = init
        init, options = np.asarray(points, dtype=np.float64), {**options, "names": names}
    with tempfile.TemporaryDirectory(prefix="voicepuppet-batch-") as d:
        stage = Path(d) / (Path(out_stem).name + ".npz")
        track_file(video_path, stage, init=init, passes=passes, **options)
        files = _collect(Path(d))
        lm = load_landmarks(stage)
        fps = float(lm["fps"])  # a variable-rate video's frames are at their times, not k / fps
        seconds = float(lm["times"][-1]) + 1.0 / fps if "times" in lm else len(lm["points"]) / fps
    parent = Path(out_stem).parent.as_posix()
    prefix = "" if parent in ("", ".") else parent + "/"
    return {"files": {prefix + k: v for k, v in files.items()}, "media_seconds": seconds}


def track_folder(video_dir, out_dir, *, init="auto", passes: int = 2, client=None, scheduler=None,
                 workers=None, timeout=10.0, progress=True, **options) -> BatchSummary:
    """Tracks every video under ``video_dir`` (``batch track``); ``a/b.mp4`` gives
    ``out_dir/a/b.npz`` and ``b.csv``.

    Parameters
    ----------
    video_dir : str or os.PathLike
        Folder searched recursively for :data:`VIDEO_SUFFIXES`.
    out_dir : str or os.PathLike
        Output folder.
    init : str
        ``"auto"`` (dlib detector on each video's first frame) or a points file (JSON/CSV,
        see :func:`voicepuppet.tracking.landmarks.load_init_points`) used for every video.
    passes : int
        Tracking passes, as in :func:`voicepuppet.tracking.tracker.track_video`.
    client, scheduler, workers, timeout, progress
        As in :func:`animate_folder`.
    **options
        As in :func:`voicepuppet.tracking.tracker.track_video`.

    Returns
    -------
    BatchSummary

    Raises
    ------
    ValueError
        A bad ``passes`` or points file, an input folder that does not exist, an output folder
        that cannot be written.
    """
    if int(passes) != passes or passes < 1:
        raise ValueError(f"passes must be a positive integer, got {passes!r}")
    settings = {"verb": "track", "passes": int(passes), "options": options}
    if init != "auto":
        init_path = Path(init)
        points, names = load_init_points(init_path)  # a bad points file is refused before any work starts
        init = (points.tolist(), names)
        settings["init_sha256"] = sha256_file(init_path)
    else:
        settings["init"] = "auto"
    root = Path(video_dir)
    inputs = discover(video_dir, VIDEO_SUFFIXES, exclude=out_dir)
    jobs = []
    for p in inputs:
        rel = p.relative_to(root)
        jobs.append((rel.as_posix(), p, (rel.with_suffix("").as_posix(), init, int(passes), dict(options))))
    clashes = _clashes(inputs, root)
    if client is not None:
        return run_batch("track", jobs, _track_task, out_dir, settings, client, progress=progress,
                         clashes=clashes)
    with connect(scheduler, workers, timeout=timeout) as c:
        return run_batch("track", jobs, _track_task, out_dir, settings, c, progress=progress, clashes=clashes)
