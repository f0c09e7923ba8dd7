"""The benchmark runner: the suites by name, interleaved timing, the rows of the results and
their table and JSON file (schema of DESIGN.md).

Every suite is a module of this package with a function ``run(quick: bool, repeats: int)``
returning a list of cases made by :func:`case`. Timings are medians over ``repeats`` runs with
ours and the peer interleaved (these machines are small and noisy); ``ratio = peer_s / ours_s``
(above 1: we are faster) and ``agree`` is the largest relative difference between the answers.
Peers are benchmark dependencies only: a suite whose peer is missing says what to install.
"""

from __future__ import annotations

import importlib
import json
import os
import platform
import statistics
import time
from typing import Callable

import numpy as np

from voicepuppet import _core
from voicepuppet._files import atomic_path

__all__ = ["SUITES", "case", "machine_info", "print_table", "rel_diff", "run_suite", "timeit_interleaved",
           "write_json_atomic"]

# suite name -> module implementing run(quick, repeats)
SUITES = {
    "hmm": "voicepuppet.bench.hmm",
    "audio": "voicepuppet.bench.audio",
    "tracker": "voicepuppet.bench.tracker",
    "render": "voicepuppet.bench.render",
    "trajectory": "voicepuppet.bench.trajectory",
    "entropic": "voicepuppet.bench.entropic",
    "synth": "voicepuppet.bench.synth",
    "pipeline": "voicepuppet.bench.pipeline",
    "live": "voicepuppet.bench.live",
    "dpds": "voicepuppet.bench.dpds",
    "batch": "voicepuppet.bench.batch",
    "peers": "voicepuppet.bench.peers",
}


def timeit_interleaved(fns: dict[str, Callable[[], object]], repeats: int) -> tuple[dict, dict]:
    """Run each callable ``repeats`` times, interleaved (a, b, a, b, ...).

    Parameters
    ----------
    fns : dict
        ``{name: callable}``, each called without arguments.
    repeats : int
        Runs of each (at least one).

    Returns
    -------
    (median_seconds, last_result) : tuple of dict
        Both keyed like ``fns``.
    """
    times: dict[str, list[float]] = {k: [] for k in fns}
    results: dict[str, object] = {}
    for _ in range(max(1, repeats)):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            results[name] = fn()
            times[name].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}, results


def rel_diff(a, b) -> float:
    """Largest relative difference between two arrays (or scalars), scaled by ``max(|b|, 1e-300)``.

    Parameters
    ----------
    a, b : array_like
        Of the same shape (or broadcastable).

    Returns
    -------
    float
        0 for empty arrays.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    scale = max(float(np.max(np.abs(b))) if b.size else 0.0, 1e-300)
    return float(np.max(np.abs(a - b)) / scale) if a.size else 0.0


def case(name: str, size: str, ours_s: float, peer: str | None, peer_s: float | None,
         agree: float | None, **extra) -> dict:
    """One row of the benchmark JSON (schema of DESIGN.md).

    Parameters
    ----------
    name : str
        The case.
    size : str
        The problem's size, in words.
    ours_s : float
        Our time in seconds (median).
    peer : str or None
        The peer's name (None: no peer).
    peer_s : float or None
        The peer's time in seconds (median).
    agree : float or None
        How far the answers differ (the suite says how it is measured).
    **extra
        More columns (realtime factors, percentiles, ...).

    Returns
    -------
    dict
        With ``ratio = peer_s / ours_s`` (None without both times).
    """
    row = {"name": name, "size": size, "ours_s": ours_s, "peer": peer, "peer_s": peer_s,
           "ratio": (peer_s / ours_s) if (peer_s and ours_s) else None, "agree": agree}
    row.update(extra)
    return row


def machine_info() -> dict:
    """The machine the benchmark ran on.

    Returns
    -------
    dict
        Platform, processor, CPUs, Python, numpy and the compiled core's build
        (``_core.build_info``).
    """
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
            "core": _core.build_info()}


def write_json_atomic(path: str, payload: dict) -> None:
    """Write JSON to ``path`` through a temporary file and a rename (never half-written).

    Parameters
    ----------
    path : str
        A ``.json`` path in an existing, writable folder.
    payload : dict
        JSON-able.

    Raises
    ------
    ValueError
        The path is not a ``.json`` file in a writable folder.
    """
    with atomic_path(path, (".json",), "benchmark results") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(payload, fh, indent=2)
        fh.write("\n")


def print_table(cases: list[dict]) -> None:
    """Print the cases as a table, each case's extra columns below it.

    Parameters
    ----------
    cases : list of dict
        Rows made by :func:`case`.
    """
    print(f"{'case':<24}{'size':<34}{'ours_s':>10}{'peer_s':>10}{'ratio':>8}{'agree':>10}  peer")
    for c in cases:
        fmt = lambda v, f: (f % v) if isinstance(v, (int, float)) else "-"  # noqa: E731
        print(f"{c['name']:<24}{c['size']:<34}{fmt(c['ours_s'], '%.4f'):>10}"
              f"{fmt(c['peer_s'], '%.4f'):>10}{fmt(c['ratio'], '%.2f'):>8}"
              f"{fmt(c['agree'], '%.1e'):>10}  {c['peer'] or '-'}")
        for k, v in c.items():
            if k not in {"name", "size", "ours_s", "peer", "peer_s", "ratio", "agree"}:
                print(f"{'':<24}{k} = {v}")


def run_suite(suite: str, *, quick: bool = False, repeats: int = 3) -> list[dict]:
    """Run one benchmark suite.

    Parameters
    ----------
    suite : str
        A key of :data:`SUITES`.
    quick : bool
        Small sizes, for a smoke run.
    repeats : int
        Timed repeats per case (median).

    Returns
    -------
    list of dict
        The suite's cases (:func:`case`).

    Raises
    ------
    ValueError
        An unknown suite, or a suite whose peer or data is missing (the message says what to
        install).
    """
    if suite not in SUITES:
        raise ValueError(f"unknown suite {suite!r}; choose one of {', '.join(sorted(SUITES))}")
    return importlib.import_module(SUITES[suite]).run(quick=quick, repeats=repeats)
