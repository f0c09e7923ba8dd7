"""``voicepuppet bench SUITE --json FILE``: our kernels side by side with a peer.

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

from voicepuppet._files import atomic_path

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
}


def timeit_interleaved(fns: dict[str, Callable[[], object]], repeats: int) -> tuple[dict, dict]:
    """Run each callable ``repeats`` times, interleaved (a, b, a, b, ...).

    Returns ``(median_seconds, last_result)``, both keyed like ``fns``.
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
    """Largest relative difference between two arrays (or scalars), scaled by max(|b|, 1e-300)."""
    import numpy as np

    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    scale = max(float(np.max(np.abs(b))) if b.size else 0.0, 1e-300)
    return float(np.max(np.abs(a - b)) / scale) if a.size else 0.0


def case(name: str, size: str, ours_s: float, peer: str | None, peer_s: float | None,
         agree: float | None, **extra) -> dict:
    """One row of the benchmark JSON (schema of DESIGN.md)."""
    row = {"name": name, "size": size, "ours_s": ours_s, "peer": peer, "peer_s": peer_s,
           "ratio": (peer_s / ours_s) if (peer_s and ours_s) else None, "agree": agree}
    row.update(extra)
    return row


def machine_info() -> dict:
    import numpy

    from voicepuppet import _core

    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "python": platform.python_version(), "numpy": numpy.__version__,
            "core": _core.build_info()}


def write_json_atomic(path: str, payload: dict) -> None:
    """Write JSON to ``path`` through a temporary file and a rename (never half-written)."""
    with atomic_path(path, (".json",), "benchmark results") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(payload, fh, indent=2)
        fh.write("\n")


def print_table(cases: list[dict]) -> None:
    print(f"{'case':<24}{'size':<34}{'ours_s':>10}{'peer_s':>10}{'ratio':>8}{'agree':>10}  peer")
    for c in cases:
        fmt = lambda v, f: (f % v) if isinstance(v, (int, float)) else "-"  # noqa: E731
        print(f"{c['name']:<24}{c['size']:<34}{fmt(c['ours_s'], '%.4f'):>10}"
              f"{fmt(c['peer_s'], '%.4f'):>10}{fmt(c['ratio'], '%.2f'):>8}"
              f"{fmt(c['agree'], '%.1e'):>10}  {c['peer'] or '-'}")
        for k, v in c.items():
            if k not in {"name", "size", "ours_s", "peer", "peer_s", "ratio", "agree"}:
                print(f"{'':<24}{k} = {v}")


def _run(args) -> int:
    from voicepuppet.cli.main import UserError

    if args.suite not in SUITES:
        raise UserError(f"unknown suite {args.suite!r}; choose one of {', '.join(sorted(SUITES))}")
    module = importlib.import_module(SUITES[args.suite])
    cases = module.run(quick=args.quick, repeats=args.repeats)
    print_table(cases)
    if args.json:
        write_json_atomic(args.json, {"suite": args.suite, "machine": machine_info(), "cases": cases})
        print(f"wrote {args.json}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="benchmark a kernel family against its peer",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("suite", choices=sorted(SUITES), help="which benchmark suite")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON (schema of DESIGN.md)")
    p.add_argument("--repeats", type=int, default=3, help="timed repeats per case (median; default 3)")
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    p.set_defaults(func=_run)
