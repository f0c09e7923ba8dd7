"""Batch work at scale on Dask: animate folders of audio, track folders of video.

``voicepuppet batch animate PUPPET AUDIO_DIR -o OUT_DIR [--format npz,csv,...]`` animates every
audio file under ``AUDIO_DIR`` with a puppet and exports it;
``voicepuppet batch track VIDEO_DIR -o OUT_DIR`` tracks every video. Files run in parallel on a
Dask cluster: a ``LocalCluster`` of ``--workers`` processes by default, or the cluster of
``--scheduler tcp://HOST:8786`` (docs/batch.md says how to start one).

How a run behaves:

- Workers read the inputs (and the puppet) by path: on a real cluster the input folder must be
  visible at the same path on every worker. Workers send the exported bytes back; this process
  writes every output, each through a temporary file and a rename, so ``OUT_DIR`` only has to
  exist here, no reader sees a half-written file, and an output is written once even when a
  worker dies and Dask runs its task again.
- Resumable: ``OUT_DIR/.voicepuppet-batch.jsonl`` records, per finished input, the SHA-256 of
  the input, of the settings (puppet, formats, ...) and of every output. A re-run skips an input
  whose record matches and whose outputs are all present with those checksums; anything else
  (a changed input, a missing or altered output, other settings) is done again.
- A failure in one file (unreadable, undecodable, a worker that died on it, a full disk when
  writing its outputs) is reported in the summary and does not stop the others; the summary is
  printed and written to ``OUT_DIR/batch-summary.json``. The exit code is 1 if any file failed.
- Outputs equal the one-by-one outputs (``puppet.animate`` + :func:`voicepuppet.render.export.export`,
  :func:`voicepuppet.tracking.tracker.track_video` + ``save_landmarks``) byte for byte, apart from the
  member timestamps numpy writes into ``.npz`` archives (their members are byte-identical).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import shutil
import tempfile
import threading
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

from voicepuppet._files import publish

__all__ = ["AUDIO_SUFFIXES", "VIDEO_SUFFIXES", "MANIFEST_NAME", "SUMMARY_NAME", "FileResult", "BatchSummary",
           "discover", "Manifest", "run_batch", "animate_folder", "track_folder", "output_names",
           "sha256_file"]

AUDIO_SUFFIXES = (".wav", ".flac", ".ogg", ".mp3", ".m4a", ".aac", ".opus", ".aiff", ".aif")
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v", ".mpg", ".mpeg")
MANIFEST_NAME = ".voicepuppet-batch.jsonl"
SUMMARY_NAME = "batch-summary.json"
LOCK_NAME = ".voicepuppet-batch.lock"
_PARTIAL = ".partial"


# ----------------------------------------------------------------------------- files

def sha256_file(path, chunk: int = 1 << 20) -> str:
    """SHA-256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            block = fh.read(chunk)
            if not block:
                break
            h.update(block)
    return h.hexdigest()


def discover(root, suffixes, exclude=None) -> list[Path]:
    """Files under ``root`` (recursively) whose suffix is in ``suffixes``, sorted by relative
    path; hidden files and anything under ``exclude`` (e.g. the output folder) are left out."""
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"input folder {str(root)!r} does not exist or is not a folder")
    excl = Path(exclude).resolve() if exclude is not None else None
    found = []
    for p in root.rglob("*"):
        rel = p.relative_to(root)
        if any(part.startswith(".") for part in rel.parts):
            continue
        if excl is not None and (p.resolve() == excl or excl in p.resolve().parents):
            continue
        if p.suffix.lower() in suffixes and (p.is_file() or p.is_symlink()):
            found.append(p)
    return sorted(found, key=lambda q: q.relative_to(root).as_posix())


def _write_file(path: Path, data: bytes) -> None:
    """Writes ``data`` to ``path`` through a temporary file in the same folder and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=_PARTIAL, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        publish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _remove_partials(out_dir: Path) -> None:
    for p in out_dir.rglob(f".*{_PARTIAL}"):
        try:
            p.unlink()
        except OSError:
            pass


class Manifest:
    """The checksum record of finished inputs: ``OUT_DIR/.voicepuppet-batch.jsonl``, one JSON
    line per finished input (``input``, ``input_sha256``, ``settings``, ``outputs`` {relative
    path: sha256}). Appended and flushed after every file; the last line of an input wins; a
    damaged line (an interrupted append) is ignored."""

    def __init__(self, out_dir):
        self.path = Path(out_dir) / MANIFEST_NAME
        self.entries: dict[str, dict] = {}
        if self.path.is_file():
            with open(self.path, encoding="utf-8") as fh:
                for line in fh:
                    try:
                        e = json.loads(line)
                    except json.JSONDecodeError:
                        continue
                    if isinstance(e, dict) and isinstance(e.get("input"), str):
                        self.entries[e["input"]] = e

    def finished(self, rel: str, input_sha: str, settings: str, out_dir: Path) -> bool:
        """True if ``rel`` was done with this input and these settings and every output is on
        disk with its recorded checksum."""
        e = self.entries.get(rel)
        if not e or e.get("input_sha256") != input_sha or e.get("settings") != settings:
            return False
        outputs = e.get("outputs") or {}
        if not outputs:
            return False
        for name, digest in outputs.items():
            p = out_dir / name
            if not p.is_file() or sha256_file(p) != digest:
                return False
        return True

    def record(self, rel: str, input_sha: str, settings: str, outputs: dict[str, str]) -> None:
        e = {"input": rel, "input_sha256": input_sha, "settings": settings, "outputs": outputs,
             "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        line = json.dumps(e, sort_keys=True) + "\n"
        with open(self.path, "a", encoding="utf-8") as fh:
            fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())
        self.entries[rel] = e


# ----------------------------------------------------------------------------- results

@dataclass
class FileResult:
    """What became of one input: ``status`` is ``done``, ``skipped`` (finished before, checksums
    verified) or ``failed`` (with ``error``); ``outputs`` are paths relative to OUT_DIR;
    ``media_seconds`` the duration of the input's audio or video (done files); ``warnings`` what
    its task warned about on the worker (a stretch where the face was lost, a variable frame
    rate, silent audio), which the one-by-one command would have printed."""

    input: str
    status: str
    outputs: list = field(default_factory=list)
    error: str | None = None
    media_seconds: float = 0.0
    warnings: list = field(default_factory=list)


@dataclass
class BatchSummary:
    """A run: one :class:`FileResult` per input, in input order, and the wall time."""

    verb: str
    files: list
    wall_seconds: float
    workers: int

    def count(self, status: str) -> int:
        return sum(1 for f in self.files if f.status == status)

    @property
    def failed(self) -> list:
        return [f for f in self.files if f.status == "failed"]

    def to_dict(self) -> dict:
        return {"verb": self.verb, "wall_seconds": self.wall_seconds, "workers": self.workers,
                "done": self.count("done"), "skipped": self.count("skipped"), "failed": self.count("failed"),
                "media_seconds_done": sum(f.media_seconds for f in self.files if f.status == "done"),
                "files": [asdict(f) for f in self.files]}

    def text(self) -> str:
        lines = [f"batch {self.verb}: {self.count('done')} done, {self.count('skipped')} skipped (already "
                 f"finished, checksums verified), {self.count('failed')} failed; {self.wall_seconds:.1f} s "
                 f"on {self.workers} workers"]
        for f in self.files:
            lines += [f"  warning {f.input}: {w}" for w in f.warnings]
        for f in self.failed:
            lines.append(f"  FAILED {f.input}: {f.error}")
        return "\n".join(lines)


def _describe(exc: BaseException) -> str:
    name = type(exc).__name__
    if name == "KilledWorker":
        return ("the workers running it died repeatedly (KilledWorker: it may crash the process or "
                "exhaust its memory); check the file")
    if "cancelled" in name.lower() or "CancelledError" in name:
        return ("not finished: the run lost its Dask scheduler (or was cancelled) first; re-run the same "
                "command to do the rest (finished files are skipped)")
    if isinstance(exc, OSError) and exc.errno == 28:
        return f"cannot write its outputs: no space left on device ({exc}); free space and re-run"
    msg = (str(exc).strip() or repr(exc)).splitlines()[0]
    return f"{name}: {msg}"


def _refusals_reported(task: Callable) -> Callable:
    """A task that returns ``{"error": reason}`` for input it refuses (a ValueError, the
    project's clear error for bad input) instead of raising it: the summary lists the file,
    and the worker does not log a traceback for what is the input's fault. Anything else
    still raises (and is logged) on the worker. The warnings the task raised come back in
    ``"warnings"`` (one line each), for the summary rather than the worker's log (Python's
    warning filters are per process: on a worker of several threads, not the local cluster's
    one, a warning can be listed against a file that ran beside it)."""

    @functools.wraps(task)
    def run(*args, **kwargs):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            try:
                value = task(*args, **kwargs)
            except ValueError as exc:
                value = {"error": _describe(exc)}
        notes = list(dict.fromkeys(str(w.message) for w in seen))  # each once, in order
        return {**value, "warnings": notes} if notes else value

    return run


# ----------------------------------------------------------------------------- engine

def output_names(rel: Path, tags: dict[str, str]) -> dict[str, str]:
    """Output base names (relative to OUT_DIR) of input ``rel``: ``rel`` without its suffix plus
    each tag (e.g. ``{"npz": ".npz", "arkit": "_arkit.csv"}``)."""
    stem = rel.with_suffix("").as_posix()
    return {k: stem + t for k, t in tags.items()}


def run_batch(verb: str, jobs: list[tuple[str, Path, tuple]], task: Callable, out_dir,
              settings: dict, client, *, progress: bool = True, clashes: dict | None = None) -> BatchSummary:
    """Runs ``task(input_path, *args)`` for each job on the cluster and writes its outputs.

    Parameters
    ----------
    verb : str
        Name shown in the progress bar and summary.
    jobs : list of (relative name, input path, args)
    task : callable
        A module-level function run on a worker; returns ``{"files": {path relative to
        out_dir: bytes}, "media_seconds": float}``.
    out_dir : path
        Created if missing; the manifest and summary go there.
    settings : dict
        Everything besides the input that determines the outputs (JSON-able); part of the
        resumability check.
    client : distributed.Client
    clashes : dict, optional
        Relative input name -> reason, for inputs not to run (reported as failed).

    Returns
    -------
    BatchSummary
    """
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create the output folder {str(out_dir)!r}: {exc}") from None
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise ValueError(f"output folder {str(out_dir)!r} is not writable; choose another with -o")
    with _exclusive(out_dir):
        return _run_batch(verb, jobs, task, out_dir, settings, client, progress, clashes)


@contextlib.contextmanager
def _exclusive(out_dir: Path):
    """Holds ``OUT_DIR/.voicepuppet-batch.lock`` (an advisory lock) for the run: two runs writing
    into one folder would remove each other's temporaries and interleave the manifest."""
    import fcntl

    fh = open(out_dir / LOCK_NAME, "a")
    try:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise ValueError(f"another voicepuppet batch run is writing into {str(out_dir)!r}; wait for it "
                             "to finish or choose another output folder") from None
        yield
    finally:
        fh.close()


def _run_batch(verb, jobs, task, out_dir: Path, settings, client, progress, clashes) -> BatchSummary:
    from distributed import as_completed
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    _remove_partials(out_dir)
    manifest = Manifest(out_dir)
    settings_key = json.dumps(settings, sort_keys=True)
    results: dict[str, FileResult] = {}
    pending = []
    for rel, path, args in jobs:
        if clashes and rel in clashes:
            results[rel] = FileResult(rel, "failed", error=clashes[rel])
            continue
        try:
            digest = sha256_file(path)
        except OSError as exc:
            results[rel] = FileResult(rel, "failed", error=f"cannot read the input: {exc.strerror or exc}")
            continue
        if manifest.finished(rel, digest, settings_key, out_dir):
            results[rel] = FileResult(rel, "skipped", sorted(manifest.entries[rel]["outputs"]))
            continue
        pending.append((rel, path, args, digest))
    workers = len(client.nthreads())
    futures = {}
    for rel, path, args, digest in pending:
        fut = client.submit(task, str(path), *args, pure=False)
        futures[fut.key] = (fut, rel, digest)
    bar = tqdm(total=len(pending), desc=f"batch {verb}", unit="file", disable=not progress)
    try:
        for fut, value in as_completed([f for f, _, _ in futures.values()], with_results=True,
                                       raise_errors=False):
            _, rel, digest = futures.pop(fut.key)
            if fut.status == "error" or isinstance(value, BaseException):
                exc = value if isinstance(value, BaseException) else fut.exception()
                results[rel] = FileResult(rel, "failed", error=_describe(exc))
            elif "error" in value:
                results[rel] = FileResult(rel, "failed", error=value["error"],
                                          warnings=list(value.get("warnings", ())))
            else:
                results[rel] = _store(rel, digest, value, out_dir, manifest, settings_key)
            fut.release()
            bar.update(1)
            if results[rel].status == "failed":
                bar.set_postfix(failed=sum(1 for r in results.values() if r.status == "failed"))
    except BaseException:
        client.cancel([f for f, _, _ in futures.values()])
        raise
    finally:
        bar.close()
        _remove_partials(out_dir)
    summary = BatchSummary(verb, [results[rel] for rel, _, _ in jobs], time.perf_counter() - t0, workers)
    try:
        _write_file(out_dir / SUMMARY_NAME, (json.dumps(summary.to_dict(), indent=2) + "\n").encode())
    except OSError:
        pass  # the summary is still returned and printed; the per-file results say what failed
    return summary


def _store(rel: str, digest: str, value: dict, out_dir: Path, manifest: Manifest, settings_key: str) -> FileResult:
    """Writes one input's outputs (all or none) and records them in the manifest."""
    written: list[Path] = []
    try:
        checks = {}
        for name, data in sorted(value["files"].items()):
            p = out_dir / name
            _write_file(p, data)
            written.append(p)
            checks[name] = hashlib.sha256(data).hexdigest()
        manifest.record(rel, digest, settings_key, checks)
    except OSError as exc:
        for p in written:
            try:
                p.unlink()
            except OSError:
                pass
        return FileResult(rel, "failed", error=_describe(exc))
    return FileResult(rel, "done", sorted(checks), media_seconds=float(value.get("media_seconds", 0.0)),
                      warnings=list(value.get("warnings", ())))


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
    from voicepuppet.puppet.model import load

    with _PUPPET_LOCK:
        key = (path, digest)
        if key not in _PUPPETS:
            _PUPPETS.clear()
            _PUPPETS[key] = load(path)
        return _PUPPETS[key]


def _format_tags(formats) -> dict[str, str]:
    from voicepuppet.render.export import FORMATS

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
    from voicepuppet.render.export import export

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
    audio_path : path of the audio
    out_stem : path without suffix; each format ``f`` goes to ``out_stem + tag(f)`` (``.npz``,
        ``.csv``, ``_arkit.csv``, ``_cues.json``, ...)
    formats : sequence of keys of :data:`voicepuppet.render.export.FORMATS`
    fps, posterior : as in ``puppet.animate``

    Returns
    -------
    list of Path
        The files written.
    """
    return _animate_export(puppet, audio_path, out_stem, formats, fps, posterior)[0]


@_refusals_reported
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
    puppet_path : path of a puppet file (``voicepuppet.load``)
    audio_dir : folder searched recursively for :data:`AUDIO_SUFFIXES`
    out_dir : output folder; ``a/b.wav`` gives ``out_dir/a/b.npz`` etc.
    formats : keys of :data:`voicepuppet.render.export.FORMATS`
    fps, posterior : as in ``puppet.animate``
    client : an existing ``distributed.Client``; otherwise one from
        :func:`voicepuppet.hmm.distributed.connect` (``scheduler``, ``workers``, ``timeout``)
    progress : show a progress bar

    Returns
    -------
    BatchSummary
    """
    from voicepuppet.hmm.distributed import connect

    puppet_path = Path(puppet_path)
    if not puppet_path.is_file():
        raise ValueError(f"puppet file {str(puppet_path)!r} does not exist; train one with `voicepuppet train`")
    formats = list(formats)
    if not formats:
        raise ValueError("give at least one output format")
    _format_tags(formats)
    if fps is not None and not (float(fps) > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    try:
        puppet_digest = sha256_file(puppet_path)
    except OSError as exc:
        raise ValueError(f"cannot read the puppet file {str(puppet_path)!r}: {exc}") from None
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
    ``batch track`` (:func:`voicepuppet.tracking.tracker.track_video` + ``save_landmarks``)."""
    from voicepuppet.tracking.landmarks import save_landmarks
    from voicepuppet.tracking.tracker import track_video

    result = track_video(str(video_path), init, passes=passes, progress=False, **options)
    return save_landmarks(out_npz, result)


@_refusals_reported
def _track_task(video_path: str, out_stem: str, init, passes: int, options: dict) -> dict:
    """``init``: "auto", or the points file's ``(points, names)`` as read once for the batch (its
    warnings, e.g. coincident points moved apart, said once up front rather than per file)."""
    if init != "auto":
        import numpy as np

        points, names = init
        init, options = np.asarray(points, dtype=np.float64), {**options, "names": names}
    with tempfile.TemporaryDirectory(prefix="voicepuppet-batch-") as d:
        stage = Path(d) / (Path(out_stem).name + ".npz")
        track_file(video_path, stage, init=init, passes=passes, **options)
        files = _collect(Path(d))
        from voicepuppet.tracking.landmarks import load_landmarks

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
    video_dir : folder searched recursively for :data:`VIDEO_SUFFIXES`
    out_dir : output folder
    init : ``"auto"`` (dlib detector on each video's first frame) or a points file (JSON/CSV,
        see :func:`voicepuppet.tracking.landmarks.load_init_points`) used for every video
    passes, **options : as in :func:`voicepuppet.tracking.tracker.track_video`
    client, scheduler, workers, timeout, progress : as in :func:`animate_folder`

    Returns
    -------
    BatchSummary
    """
    from voicepuppet.hmm.distributed import connect
    from voicepuppet.tracking.landmarks import load_init_points

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


# ----------------------------------------------------------------------------- CLI

def _finish(summary: BatchSummary, out_dir, quiet: bool) -> int:
    print(summary.text())
    done = [f for f in summary.files if f.status == "done"]
    if done and summary.wall_seconds > 0:
        media = sum(f.media_seconds for f in done)
        print(f"{media:.1f} s of media in {summary.wall_seconds:.1f} s wall "
              f"({media / summary.wall_seconds:.2f}x real time); summary in {Path(out_dir) / SUMMARY_NAME}")
    return 1 if summary.failed else 0


def _cli_animate(args) -> int:
    formats = [f.strip() for f in args.format.split(",") if f.strip()]
    summary = animate_folder(args.puppet, args.audio_dir, args.output, formats, fps=args.fps,
                             posterior=args.posterior, scheduler=args.scheduler, workers=args.workers,
                             timeout=args.timeout, progress=not args.quiet)
    return _finish(summary, args.output, args.quiet)


def _cli_track(args) -> int:
    summary = track_folder(args.video_dir, args.output, init=args.init, passes=args.passes,
                           scheduler=args.scheduler, workers=args.workers, timeout=args.timeout,
                           progress=not args.quiet, patch_radius=args.patch_radius, levels=args.levels)
    return _finish(summary, args.output, args.quiet)


def _cluster_arguments(p) -> None:
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler to use, e.g. tcp://127.0.0.1:8786 (default: a local cluster)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local worker processes (default: one per CPU); with --scheduler, wait for N workers")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for the scheduler and workers (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def add_parser(sub) -> None:
    p = sub.add_parser("batch", help="animate or track whole folders in parallel (Dask; resumable)",
                       description="Batch work on a Dask cluster (local by default): resumable through a "
                                   "checksum manifest in the output folder, a failure in one file reported "
                                   "in the summary without stopping the others. See docs/batch.md.")
    verbs = p.add_subparsers(dest="batch_verb", metavar="WHAT")
    verbs.required = True
    a = verbs.add_parser("animate", help="animate every audio file of a folder with a puppet",
                         description="Animate every audio file under AUDIO_DIR (recursively) with PUPPET and "
                                     "export each in the given formats to OUT_DIR (same relative paths).")
    a.add_argument("puppet", help="puppet file (voicepuppet train)")
    a.add_argument("audio_dir", help="folder of audio files (" + ", ".join(AUDIO_SUFFIXES) + ")")
    a.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="output folder (created if missing)")
    a.add_argument("--format", default="npz",
                   help="comma-separated export formats: npz, csv, arkit, arkit-json, rhubarb, rhubarb-tsv, "
                        "gltf, pvd (default: npz)")
    a.add_argument("--fps", type=float, help="output frame rate (default: the puppet's)")
    a.add_argument("--posterior", action="store_true", help="posterior-weighted trajectories instead of Viterbi")
    _cluster_arguments(a)
    a.set_defaults(func=_cli_animate)
    t = verbs.add_parser("track", help="track facial landmarks in every video of a folder",
                         description="Track every video under VIDEO_DIR (recursively) with the spring-mesh "
                                     "tracker; writes OUT_DIR/<name>.npz and .csv per video.")
    t.add_argument("video_dir", help="folder of videos (" + ", ".join(VIDEO_SUFFIXES) + ")")
    t.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="output folder (created if missing)")
    t.add_argument("--init", default="auto", metavar="POINTS.json|auto",
                   help="first-frame points for every video, or auto (dlib detector per video; default)")
    t.add_argument("--passes", type=int, default=2, help="tracking passes (default 2)")
    t.add_argument("--patch-radius", type=int, default=6, help="SSD patch radius in pixels (default 6)")
    t.add_argument("--levels", type=int, default=3, help="image pyramid levels (default 3)")
    _cluster_arguments(t)
    t.set_defaults(func=_cli_track)
