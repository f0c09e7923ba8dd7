"""The batch engine: inputs run as tasks on a Dask cluster, their outputs written here, resumably.

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
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import json
import os
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

from tqdm.auto import tqdm

from voicepuppet._files import publish

__all__ = ["MANIFEST_NAME", "SUMMARY_NAME", "LOCK_NAME", "FileResult", "BatchSummary", "Manifest", "discover",
           "output_names", "refusals_reported", "run_batch", "sha256_file", "write_file"]

MANIFEST_NAME = ".voicepuppet-batch.jsonl"
SUMMARY_NAME = "batch-summary.json"
LOCK_NAME = ".voicepuppet-batch.lock"
_PARTIAL = ".partial"


# ----------------------------------------------------------------------------- files

def sha256_file(path, chunk: int = 1 << 20) -> str:
    """SHA-256 hex digest of a file's bytes.

    Parameters
    ----------
    path : str or os.PathLike
    chunk : int
        Bytes read at a time.

    Returns
    -------
    str
        64 hexadecimal digits.
    """
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
    path; hidden files and anything under ``exclude`` (e.g. the output folder) are left out.

    Parameters
    ----------
    root : str or os.PathLike
        The folder searched.
    suffixes : sequence of str
        Lower-case suffixes with their dot (``.wav``); a file's suffix is compared in lower case.
    exclude : str or os.PathLike, optional
        A folder whose contents are left out.

    Returns
    -------
    list of Path

    Raises
    ------
    ValueError
        ``root`` is not a folder.
    """
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


def write_file(path: Path, data: bytes) -> None:
    """Writes ``data`` to ``path`` through a temporary file in the same folder and a rename
    (synced to disk first; a run's leftover temporaries are removed at its start and end).

    Parameters
    ----------
    path : Path
        The output; its folder is created if missing.
    data : bytes
    """
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
    damaged line (an interrupted append) is ignored.

    Parameters
    ----------
    out_dir : str or os.PathLike
        The output folder holding the manifest (read if it exists).
    """

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
        """Whether ``rel`` was done with this input and these settings and every output is on
        disk with its recorded checksum.

        Parameters
        ----------
        rel : str
            The input's path relative to the input folder.
        input_sha : str
            SHA-256 of the input now.
        settings : str
            The run's settings as canonical JSON.
        out_dir : Path
            The output folder.

        Returns
        -------
        bool
        """
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
        """Append (and flush to disk) the record of a finished input.

        Parameters
        ----------
        rel : str
            The input's path relative to the input folder.
        input_sha : str
            SHA-256 of the input.
        settings : str
            The run's settings as canonical JSON.
        outputs : dict
            ``{output path relative to OUT_DIR: sha256}``.
        """
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
    rate, silent audio), which the one-by-one command would have printed.

    Parameters
    ----------
    input : str
        The input's path relative to the input folder.
    status : {"done", "skipped", "failed"}
        What became of the input.
    outputs : list of str, optional
        Its outputs, as paths relative to OUT_DIR (default: none).
    error : str or None, optional
        Why it failed (``None`` unless ``status`` is ``failed``).
    media_seconds : float, optional
        Duration of the input's audio or video, for done files (default 0).
    warnings : list of str, optional
        What its task warned about on the worker (default: none).

    Notes
    -----
    Each parameter is kept as the attribute of the same name.
    """

    input: str
    status: str
    outputs: list = field(default_factory=list)
    error: str | None = None
    media_seconds: float = 0.0
    warnings: list = field(default_factory=list)


@dataclass
class BatchSummary:
    """A run: one :class:`FileResult` per input, in input order, and the wall time.

    Parameters
    ----------
    verb : str
        ``animate`` or ``track`` (or the name given to :func:`run_batch`).
    files : list of FileResult
        One result per input, in input order.
    wall_seconds : float
        Wall time of the run, in seconds.
    workers : int
        Worker threads of the cluster.

    Notes
    -----
    Each parameter is kept as the attribute of the same name.
    """

    verb: str
    files: list
    wall_seconds: float
    workers: int

    def count(self, status: str) -> int:
        """How many inputs have a status.

        Parameters
        ----------
        status : {"done", "skipped", "failed"}

        Returns
        -------
        int
        """
        return sum(1 for f in self.files if f.status == status)

    @property
    def failed(self) -> list:
        """The failed inputs' results."""
        return [f for f in self.files if f.status == "failed"]

    def to_dict(self) -> dict:
        """The summary as JSON-able data.

        Returns
        -------
        dict
            What ``batch-summary.json`` holds.
        """
        return {"verb": self.verb, "wall_seconds": self.wall_seconds, "workers": self.workers,
                "done": self.count("done"), "skipped": self.count("skipped"), "failed": self.count("failed"),
                "media_seconds_done": sum(f.media_seconds for f in self.files if f.status == "done"),
                "files": [asdict(f) for f in self.files]}

    def text(self) -> str:
        """The summary as printed.

        Returns
        -------
        str
            Counts and wall time, then each warning and failure, one per line.
        """
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


def refusals_reported(task: Callable) -> Callable:
    """A task that returns ``{"error": reason}`` for input it refuses (a ValueError, the
    project's clear error for bad input) instead of raising it: the summary lists the file,
    and the worker does not log a traceback for what is the input's fault. Anything else
    still raises (and is logged) on the worker. The warnings the task raised come back in
    ``"warnings"`` (one line each), for the summary rather than the worker's log (Python's
    warning filters are per process: on a worker of several threads, not the local cluster's
    one, a warning can be listed against a file that ran beside it).

    Parameters
    ----------
    task : callable
        A task for :func:`run_batch`.

    Returns
    -------
    callable
        The task, reporting refusals and warnings in its result.
    """

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
    each tag (e.g. ``{"npz": ".npz", "arkit": "_arkit.csv"}``).

    Parameters
    ----------
    rel : Path
        The input's path relative to the input folder.
    tags : dict
        ``{format: tag}``.

    Returns
    -------
    dict
        ``{format: output path relative to OUT_DIR}``.
    """
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
        One entry per input; ``args`` follow the input path in the call of ``task``.
    task : callable
        A module-level function run on a worker; returns ``{"files": {path relative to
        out_dir: bytes}, "media_seconds": float}``.
    out_dir : path
        Created if missing; the manifest and summary go there.
    settings : dict
        Everything besides the input that determines the outputs (JSON-able); part of the
        resumability check.
    client : distributed.Client
        The Dask cluster the tasks run on.
    progress : bool, optional
        Show a progress bar (default ``True``).
    clashes : dict, optional
        Relative input name -> reason, for inputs not to run (reported as failed).

    Returns
    -------
    BatchSummary
        One result per job, in job order; also written to ``OUT_DIR/batch-summary.json`` (unless
        that write fails).

    Raises
    ------
    ValueError
        The output folder cannot be created or written, or another run is writing into it.
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
        write_file(out_dir / SUMMARY_NAME, (json.dumps(summary.to_dict(), indent=2) + "\n").encode())
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
            write_file(p, data)
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
