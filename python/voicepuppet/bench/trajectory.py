"""Benchmark suite ``trajectory``: closed-form trajectory synthesis against its peers.

Cases (D = 50, i.e. 25 points x 2, 26 states, states dwelling 1-8 frames):

- ``full``: full [pose, velocity] covariance; ours (block Cholesky) vs ``scipy.linalg.solveh_banded``
  on the same banded normal equations (assembly excluded from the peer's time; our time includes
  building the model). Reports GFLOP/s at 2.33 D^3 flops per frame beside numpy's large
  matrix-multiply GFLOP/s measured in the same run, single-threaded, and the time of the first
  solve (``ours_first_call_s``: it also pays the page faults of the factor store, which later
  solves on the same thread reuse).
- ``diag``: diagonal covariance (D scalar tridiagonal systems) vs nnmnkwii's ``mlpg``.
- ``weighted``: posterior-weighted full-covariance synthesis (no peer).
- ``full_hour`` / ``diag_hour``: T = 108,000 (one hour at 30 fps), ours only (the banded peer would
  need about 9 GB), with peak memory of the solve measured in a child process.
- ``stream``: the fixed-lag stream (lag 15), per-frame compute percentiles.

Every case reports ``realtime_factor``: frames at 29.97 fps synthesised per second of compute.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np

from voicepuppet import _core, trajectory as tr
from voicepuppet.bench.runner import case, rel_diff, timeit_interleaved

FPS = 29.97
N_STATES = 26
SEED = 1999


def _model(rng, n, d, full=True):
    means = rng.normal(size=(n, d))
    vel = 0.05 * rng.normal(size=(n, d))
    if full:
        a = rng.normal(size=(n, 2 * d, 2 * d))
        covars = a @ a.transpose(0, 2, 1) / (2 * d) + 0.3 * np.eye(2 * d)
    else:
        covars = rng.uniform(0.05, 1.0, size=(n, 2 * d))
    return means, vel, covars


def _states(rng, T, n):
    dwell = rng.integers(1, 9, size=T)
    seq = np.repeat(rng.integers(0, n, size=T), dwell)
    return np.ascontiguousarray(seq[:T], dtype=np.int64)


def _banded_system(states, means, vel, covars):
    """Lower banded form (2D rows) of the normal equations, assembled independently in numpy."""
    T, d = len(states), means.shape[1]
    P = np.linalg.inv(covars)
    A, B, C = P[:, :d, :d], P[:, :d, d:], P[:, d:, d:]
    Bt = B.transpose(0, 2, 1)
    first = np.linalg.inv(covars[:, :d, :d])
    diag = (A + B + Bt + C)[states]
    diag[0] = first[states[0]]
    diag[:-1] += C[states[1:]]
    lower = -(B + C)[states[1:]]  # H[t, t-1]
    rhs = (np.einsum("nij,nj->ni", A + Bt, means) + np.einsum("nij,nj->ni", B + C, vel))[states]
    rhs[0] = np.einsum("ij,j->i", first[states[0]], means[states[0]])
    rhs[:-1] -= (np.einsum("nji,nj->ni", B, means) + np.einsum("nij,nj->ni", C, vel))[states[1:]]
    ab = np.zeros((2 * d, T * d))
    for i in range(d):
        for j in range(i + 1):
            ab[i - j, j::d] = diag[:, i, j]
        for j in range(d):
            ab[d + i - j, j:(T - 1) * d:d] = lower[:, i, j]
    return ab, rhs.ravel()


def _gemm_gflops() -> float:
    n = 1500
    a = np.random.default_rng(0).normal(size=(n, n))
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        a @ a
        best = min(best, time.perf_counter() - t0)
    return 2 * n**3 / best / 1e9


_CHILD = r"""
import json, sys, time
import numpy as np
from voicepuppet import _core, trajectory as tr
T, d, full = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "full"
rng = np.random.default_rng(1999)
sys.path.insert(0, "")
from voicepuppet.bench.trajectory import _model, _states
means, vel, covars = _model(rng, 26, d, full)
states = _states(rng, T, 26)
model = tr.make_model(means, vel, covars, "full" if full else "diag")
def hwm_kb():  # this process's peak RSS (ru_maxrss would inherit the parent's peak across fork)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    return 0
base = hwm_kb()
t0 = time.perf_counter()
y = _core.solve_trajectory(model, states)
dt = time.perf_counter() - t0
peak = hwm_kb()
print(json.dumps({"seconds": dt, "peak_mb": (peak - base) / 1024.0, "process_peak_mb": peak / 1024.0}))
"""


def _child_solve(T: int, d: int, kind: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(T), str(d), kind], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool, repeats: int) -> list[dict]:
    """The trajectory suite's cases (see the module's docstring).

    Parameters
    ----------
    quick : bool
        Small sizes, for a smoke run.
    repeats : int
        Timed repeats per case (median).

    Returns
    -------
    list of dict
        Rows made by :func:`voicepuppet.bench.runner.case`.

    Raises
    ------
    ImportError
        A peer is not installed (the message says what to install).
    """
    try:
        import scipy.linalg as sla
        from nnmnkwii.paramgen import mlpg
        from threadpoolctl import threadpool_limits
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("the trajectory benchmark needs its peers: pip install scipy nnmnkwii threadpoolctl "
                          f"(missing: {exc.name})") from exc

    rng = np.random.default_rng(SEED)
    d = 10 if quick else 50
    sizes = [1000] if quick else [4000, 18000]
    cases = []
    with threadpool_limits(1):
        gemm = _gemm_gflops()
        for T in sizes:
            # ---- full covariance vs solveh_banded on the same banded system
            means, vel, covars = _model(rng, N_STATES, d, True)
            states = _states(rng, T, N_STATES)
            ab, rhs = _banded_system(states, means, vel, covars)

            def ours_full():
                return _core.solve_trajectory(tr.make_model(means, vel, covars, "full"), states)

            def peer_full():
                return sla.solveh_banded(ab, rhs, lower=True, check_finite=False).reshape(T, d)

            # the first solve of this size on the thread also pays the page faults of its factor store
            t0 = time.perf_counter()
            ours_full()
            first_call = time.perf_counter() - t0
            med, res = timeit_interleaved({"ours": ours_full, "peer": peer_full}, repeats)
            del ab
            flops = 2.33 * d**3 * T
            cases.append(case("full", f"T={T} D={d} N={N_STATES}", med["ours"], "scipy.linalg.solveh_banded",
                              med["peer"], rel_diff(res["ours"], res["peer"]),
                              realtime_factor=T / FPS / med["ours"], gflops=flops / med["ours"] / 1e9,
                              numpy_gemm_gflops=gemm, ours_first_call_s=first_call))

            # ---- diagonal covariance vs nnmnkwii mlpg (last frame given no delta term in ours too)
            means, vel, var = _model(rng, N_STATES, d, False)
            last = states[-1]
            m2, v2, var2 = (np.vstack([x, x[last]]) for x in (means, vel, var))
            var2[-1, d:] = 1e300
            s2 = states.copy()
            s2[-1] = N_STATES
            windows = [(0, 0, np.array([1.0])), (1, 0, np.array([-1.0, 1.0]))]
            mean_frames = np.hstack([means[states], vel[states]])
            var_frames = var[states]

            def ours_diag():
                return _core.solve_trajectory(tr.make_model(m2, v2, var2, "diag"), s2)

            def peer_diag():
                return mlpg(mean_frames, var_frames, windows)

            med, res = timeit_interleaved({"ours": ours_diag, "peer": peer_diag}, repeats)
            cases.append(case("diag", f"T={T} D={d} N={N_STATES}", med["ours"], "nnmnkwii.paramgen.mlpg",
                              med["peer"], rel_diff(res["ours"], res["peer"]),
                              realtime_factor=T / FPS / med["ours"]))

        # ---- posterior-weighted (no peer)
        T = sizes[-1]
        means, vel, covars = _model(rng, N_STATES, d, True)
        gamma = rng.dirichlet(np.full(N_STATES, 0.1), size=T)
        model = tr.make_model(means, vel, covars, "full")
        med, _ = timeit_interleaved({"ours": lambda: _core.solve_trajectory_weighted(model, gamma)}, repeats)
        cases.append(case("weighted", f"T={T} D={d} N={N_STATES}", med["ours"], None, None, None,
                          realtime_factor=T / FPS / med["ours"]))

        # ---- fixed-lag stream, per-frame compute
        lag = 15
        states = _states(rng, 2000 if not quick else 300, N_STATES)
        stream = _core.FixedLagTrajectory(model, lag)
        per = []
        for s in states:
            t0 = time.perf_counter()
            stream.push_states(np.array([s], dtype=np.int64))
            per.append(time.perf_counter() - t0)
        stream.flush()
        per_ms = np.array(per[lag:]) * 1e3
        cases.append(case("stream", f"lag={lag} D={d} N={N_STATES} frames={len(states)}",
                          float(np.sum(per)), None, None, None,
                          realtime_factor=len(states) / FPS / float(np.sum(per)),
                          frame_ms_p50=float(np.percentile(per_ms, 50)),
                          frame_ms_p99=float(np.percentile(per_ms, 99))))

    # ---- one hour at 30 fps, ours only, in a child process (peak memory of the solve)
    if not quick:
        for kind in ("full", "diag"):
            T = 108_000
            r = _child_solve(T, d, kind)
            cases.append(case(f"{kind}_hour", f"T={T} D={d} N={N_STATES}", r["seconds"], None, None, None,
                              realtime_factor=T / FPS / r["seconds"], peak_mem_mb=r["peak_mb"],
                              process_peak_mem_mb=r["process_peak_mb"],
                              **({"gflops": 2.33 * d**3 * T / r["seconds"] / 1e9} if kind == "full" else {})))
    return cases


def lag_deviation_table(lags=(0, 1, 2, 4, 8, 16, 32, 64), T: int = 3000, d: int = 50,
                        vel_sd=(1.0, 0.3, 0.1)) -> list[dict]:
    """Deviation of the fixed-lag stream from the full solve, as a function of the lag.

    Diagonal-covariance models with pose sd 1 and velocity sd ``v`` (26 states, means N(0, 1),
    dwell 1-8 frames), full covariance off; the smaller the velocity sd relative to the pose sd,
    the smoother the trajectory and the longer the look-ahead it needs. Deviation is the largest
    absolute difference over all frames and dims divided by the largest ``|y|`` of the full solve.

    Parameters
    ----------
    lags : sequence of int
        The stream's look-aheads.
    T : int
        Frames.
    d : int
        Dimensions.
    vel_sd : sequence of float
        Velocity standard deviations (the pose's is 1).

    Returns
    -------
    list of dict
        ``{"vel_sd", "lag", "max_rel_dev"}`` per model and lag.
    """
    rows = []
    for v in vel_sd:
        rng = np.random.default_rng(SEED)
        means = rng.normal(size=(N_STATES, d))
        vel = np.zeros((N_STATES, d))
        var = np.hstack([np.ones((N_STATES, d)), np.full((N_STATES, d), v * v)])
        states = _states(rng, T, N_STATES)
        model = tr.make_model(means, vel, var, "diag")
        full = _core.solve_trajectory(model, states)
        for lag in lags:
            stream = _core.FixedLagTrajectory(model, lag)
            y = np.vstack([stream.push_states(states), stream.flush()])
            rows.append({"vel_sd": v, "lag": lag,
                         "max_rel_dev": float(np.max(np.abs(y - full)) / np.max(np.abs(full)))})
    return rows


if __name__ == "__main__":  # python -m voicepuppet.bench.trajectory: the fixed-lag table of docs/trajectory.md
    table = lag_deviation_table()
    lags = sorted({r["lag"] for r in table})
    print("| velocity sd / pose sd | " + " | ".join(f"L={k}" for k in lags) + " |")
    print("|---|" + "---|" * len(lags))
    for v in sorted({r["vel_sd"] for r in table}, reverse=True):
        devs = {r["lag"]: r["max_rel_dev"] for r in table if r["vel_sd"] == v}
        print(f"| {v:g} | " + " | ".join(f"{devs[k]:.1e}" for k in lags) + " |")
