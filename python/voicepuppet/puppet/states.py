"""State-sequence files: a puppet's facial states per frame as CSV, for editing and re-synthesis
(``voicepuppet animate --states-out`` / ``--states-in``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from voicepuppet._files import atomic_path

__all__ = ["save_states", "load_states"]


def save_states(path, states: np.ndarray, fps: float) -> Path:
    """Write a state sequence as CSV ``frame,time,part0[,part1...]``, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write; it must end in ``.csv``.
    states : ndarray of int, shape (T, parts)
        The state of each face part at each frame (e.g. the ``states`` of a
        :class:`voicepuppet.puppet.model.Animated`).
    fps : float
        Their frame rate: frame t is written at time t / fps.

    Returns
    -------
    pathlib.Path
        ``Path(path)``.

    Raises
    ------
    ValueError
        Another suffix, or a folder that does not exist or is not writable.
    """
    T, n_parts = states.shape
    table = np.column_stack([np.arange(T), np.arange(T) / fps, states])
    with atomic_path(path, (".csv",), "states file") as tmp:
        np.savetxt(tmp, table, fmt=["%d", "%.9g"] + ["%d"] * n_parts, delimiter=",",
                   header="frame,time," + ",".join(f"part{k}" for k in range(n_parts)), comments="")
    return Path(path)


def load_states(path) -> tuple[np.ndarray, float]:
    """Read a states CSV written by :func:`save_states` (possibly edited): ``(states, fps)``.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.

    Returns
    -------
    states : ndarray of int64, shape (T, parts)
        The state of each face part at each frame.
    fps : float
        The frame rate, from the median step of the ``time`` column.

    Raises
    ------
    ValueError
        The file does not exist, is not a ``frame,time,part0,...`` CSV, has fewer than 2 rows or
        3 columns, or holds non-integer states.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"states file {str(p)!r} does not exist")
    try:
        table = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"states file {str(p)!r} is not a 'frame,time,part0,...' CSV: {exc}") from None
    if table.shape[0] < 2 or table.shape[1] < 3:
        raise ValueError(f"states file {str(p)!r} needs at least 2 rows of frame,time,part0[,...]")
    states = table[:, 2:]
    if not np.all(states == np.round(states)):
        raise ValueError(f"states file {str(p)!r} holds non-integer states")
    fps = 1.0 / float(np.median(np.diff(table[:, 1])))
    return states.astype(np.int64), fps
