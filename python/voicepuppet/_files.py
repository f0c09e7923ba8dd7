"""Files: output-path checks and atomic writes, the one way the package writes a file.

Every file voicepuppet writes goes through :func:`atomic_path` (or :func:`publish` for a folder
or a writer that makes its own temporary): a temporary name beside the output, renamed onto it
when complete, so a reader never sees a half-written file and a failure leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Iterator

import numpy as np

__all__ = ["check_output_path", "publish", "atomic_path", "signals_held", "remove_stale_temporaries", "write_npz",
           "read_npz"]


def check_output_path(path, suffixes: tuple[str, ...] | None = None, what: str = "output") -> Path:
    """Checks that ``path`` can be written: known suffix, existing writable folder.

    Raises ``ValueError`` saying what to do otherwise. Returns ``Path(path)``.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    suffixes : tuple of str, optional
        Accepted suffixes in lower case, with the dot (e.g. ``(".npz", ".csv")``); the
        comparison ignores case. None (the default) accepts any.
    what : str
        What the file is, for the messages (default ``"output"``).

    Returns
    -------
    pathlib.Path
        ``Path(path)``.

    Raises
    ------
    ValueError
        An unknown suffix, a folder that does not exist or is not writable, or a ``path``
        that is a folder.
    """
    p = Path(path)
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise ValueError(f"{what} {str(p)!r} has an unknown format {p.suffix or '(no suffix)'!r}; "
                         f"use one of {', '.join(suffixes)}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"{what} folder {str(parent)!r} does not exist; create it first")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{what} folder {str(parent)!r} is not writable; choose another output path")
    if p.is_dir():
        raise ValueError(f"{what} {str(p)!r} is a folder; give a file name")
    return p


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: The process's file-creation mask, read once (os.umask can only be read by setting it).
_UMASK = _umask()


def publish(tmp, path) -> None:
    """Renames the finished temporary file or folder ``tmp`` onto ``path``, first giving it the
    permissions a plainly created one would have (``tempfile.mkstemp`` / ``mkdtemp`` make them
    owner-only).

    Parameters
    ----------
    tmp : str or os.PathLike
        The finished temporary file or folder, beside ``path`` (same file system).
    path : str or os.PathLike
        Its final name (replaced if it exists, by ``os.replace``).
    """
    os.chmod(tmp, (0o777 if os.path.isdir(tmp) else 0o666) & ~_UMASK)
    os.replace(tmp, path)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # someone else's process (or a number no process can have: left alone)
    return True


def remove_stale_temporaries(path) -> list[Path]:
    """Removes the temporaries of ``path`` that runs killed before they finished left behind.

    :func:`atomic_path` names its temporary ``.NAME.PID.XXXX.partial.SUFFIX`` beside the output;
    one whose process no longer runs is debris (a run killed with SIGKILL, or a crash), and the
    next write to the same output removes it. Temporaries of running processes are left alone.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.

    Returns
    -------
    list of pathlib.Path
        The temporaries removed.
    """
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    start = f".{p.name}."
    removed = []
    try:
        candidates = [c for c in folder.iterdir() if c.name.startswith(start) and ".partial" in c.name]
    except OSError:
        return removed
    for c in candidates:
        pid = c.name[len(start):].split(".", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            try:
                c.unlink()
                removed.append(c)
            except OSError:
                pass
    return removed


@contextlib.contextmanager
def atomic_path(path, suffixes: tuple[str, ...] | None = None, what: str = "output") -> Iterator[Path]:
    """Yields a temporary path next to ``path``; on success it is renamed onto ``path``.

    On any exception the temporary file is removed and ``path`` is untouched, so a reader never
    sees a half-written file. The temporary name keeps the suffix (writers that dispatch on it
    still work) and carries the process id, so that temporaries a killed run left behind are
    removed by the next write to the same output (:func:`remove_stale_temporaries`).

    Parameters
    ----------
    path : str or os.PathLike
        The output file, checked by :func:`check_output_path`.
    suffixes : tuple of str, optional
        Accepted suffixes (lower case, with the dot); None (the default) accepts any.
    what : str
        What the file is, for the messages (default ``"output"``).

    Yields
    ------
    pathlib.Path
        The temporary path to write (an empty file exists there).

    Raises
    ------
    ValueError
        ``path`` cannot be written (see :func:`check_output_path`).
    """
    p = check_output_path(path, suffixes, what)
    remove_stale_temporaries(p)
    tmp_path = None
    try:
        with signals_held():  # a Ctrl-C or SIGTERM between creating the file and naming it
            fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.{os.getpid()}.", suffix=f".partial{p.suffix}",
                                       dir=p.parent or ".")
            tmp_path = Path(tmp)
            os.close(fd)
        yield tmp_path
        publish(tmp_path, p)
    finally:
        if tmp_path is not None and tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM are held back (not lost) while the block runs, on POSIX, in the calling
    thread: a step that creates something to clean up (a temporary file, an encoder process) and
    the name its cleanup needs cannot be cut apart by Ctrl-C; the signal's handler runs when the
    block ends. Elsewhere a no-op."""
    import signal

    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def write_npz(fh, arrays: dict) -> None:
    """``np.savez_compressed`` with fixed member timestamps, so equal arrays give equal bytes
    (numpy stamps the current time into each member, which makes re-runs differ byte for byte).
    ``fh`` is a binary file object; members are ``NAME.npy`` in the given order.

    Parameters
    ----------
    fh : file object
        A binary file opened for writing.
    arrays : dict
        Name -> array_like; stored without pickling.
    """
    with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def read_npz(path, what: str = "file") -> dict:
    """Every array of the ``.npz`` archive ``path``, read without pickling.

    Parameters
    ----------
    path : str or os.PathLike
        The archive.
    what : str
        What the file should be, for the messages (default ``"file"``).

    Returns
    -------
    dict
        Array name -> numpy array.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        ``path`` is empty, truncated, not an ``.npz`` archive, or holds pickled objects; the
        message names the file and what was wrong.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{what} {path!r} does not exist")
    if os.path.getsize(path) == 0:
        reason = "the file is empty"
    elif not zipfile.is_zipfile(path):
        reason = "truncated, or another format"
    else:
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, RuntimeError) as exc:
            reason = str(exc) or type(exc).__name__
            if "pickle" in reason:
                reason = "it holds pickled Python objects, which voicepuppet never loads"
    raise ValueError(f"{what} {path!r} is not a readable .npz archive ({reason})")
