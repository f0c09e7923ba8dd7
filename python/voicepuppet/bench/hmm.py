"""HMM suite: GaussianHMM (full covariance) against hmmlearn's on the same model and data.

Sizes as the foundation issue fixes them: N = 26 states, D = 100 (25 points x 2 coordinates,
pose + velocity), T = 18,000 frames (10 minutes at 30 fps). Cases ``score``, ``decode`` and
``fit`` (10 EM iterations from identical starting parameters), plus the GFLOP/s of the emission
kernels (all-double, and the float32 screening pass that score, decode and fit run first) beside
numpy's large matrix multiply in double and in float32, measured in the same run.
"""

from __future__ import annotations

import time

import numpy as np

from voicepuppet import _core
from voicepuppet.bench.runner import case, rel_diff, timeit_interleaved
from voicepuppet.hmm.gaussian import GaussianHMM


def _peer():
    try:
        from hmmlearn import hmm
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ValueError("the hmm benchmark compares against hmmlearn: pip install hmmlearn") from exc
    return hmm


def make_problem(n: int, d: int, T: int, seed: int = 0) -> tuple[GaussianHMM, np.ndarray]:
    """A random sticky full-covariance model and T frames sampled from it.

    Parameters
    ----------
    n : int
        States.
    d : int
        Dimensions.
    T : int
        Frames.
    seed : int

    Returns
    -------
    model : GaussianHMM
    X : ndarray, shape (T, d)
    """
    rng = np.random.default_rng(seed)
    m = GaussianHMM(n, "full", random_state=seed)
    m.startprob_ = np.full(n, 1.0 / n)
    A = rng.dirichlet(np.ones(n), size=n) * 0.2
    A[np.arange(n), np.arange(n)] += 0.8
    m.transmat_ = A
    m.means_ = rng.normal(0.0, 1.0, (n, d))
    B = rng.normal(0.0, 1.0 / np.sqrt(d), (n, d, d))
    m.covars_ = B @ B.transpose(0, 2, 1) + 0.5 * np.eye(d)
    X, _ = m.sample(T, random_state=seed + 1)
    return m, X


def _matmul_gflops(repeats: int, dtype=np.float64) -> float:
    a = np.random.default_rng(0).normal(size=(2000, 2000)).astype(dtype)
    b = a.T.copy()
    best = np.inf
    for _ in range(max(2, repeats)):
        t0 = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - t0)
    return 2 * 2000**3 / best / 1e9


def run(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The hmm suite's cases (see the module's docstring).

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
    ValueError
        The peer is not installed (the message says what to install).
    """
    hmm = _peer()
    n, d, T = (8, 20, 2000) if quick else (26, 100, 18000)
    size = f"N={n} D={d} T={T} full"
    model, X = make_problem(n, d, T)
    lengths = np.array([T])

    peer = hmm.GaussianHMM(n, covariance_type="full", init_params="", covars_prior=0.0, min_covar=0.0,
                           n_iter=10, tol=-np.inf)

    def reset_peer():
        peer.startprob_ = model.startprob_.copy()
        peer.transmat_ = model.transmat_.copy()
        peer.means_ = model.means_.copy()
        peer.covars_ = model.covars_.copy()

    reset_peer()
    cases = []

    covars2d = model.covars_.reshape(n * d, d)
    args = (X, lengths, model.startprob_, model.transmat_, model.means_, covars2d, "full")
    screening = _core.gaussian_hmm_score(*args)[1]
    refined = f"{screening['refined'] / screening['entries']:.3f}"

    t, r = timeit_interleaved({"ours": lambda: model.score(X), "peer": lambda: peer.score(X)}, repeats)
    cases.append(case("score", size, t["ours"], "hmmlearn", t["peer"], rel_diff(r["ours"], r["peer"]),
                      refined_in_double=refined,
                      agree_all_double=rel_diff(r["ours"], _core.gaussian_hmm_score(*args, exact=True)[0])))

    t, r = timeit_interleaved({"ours": lambda: model.decode(X), "peer": lambda: peer.decode(X)}, repeats)
    path_agree = float(np.mean(r["ours"][1] == r["peer"][1]))
    cases.append(case("decode", size, t["ours"], "hmmlearn", t["peer"], rel_diff(r["ours"][0], r["peer"][0]),
                      path_agreement=path_agree))

    def fit_ours(exact=False):
        f = GaussianHMM(n, "full", n_iter=10, tol=-np.inf, min_covar=0.0, init_params="", exact=exact)
        for attr in ("startprob_", "transmat_", "means_", "covars_"):
            setattr(f, attr, getattr(model, attr).copy())
        return f.fit(X, lengths)

    def fit_peer():
        reset_peer()
        return peer.fit(X, lengths)

    fit_repeats = max(1, (repeats + 2) // 3)  # hmmlearn's 10 iterations take over a minute
    t, r = timeit_interleaved({"ours": fit_ours, "peer": fit_peer}, fit_repeats)
    def agreement(a, b):
        return max(rel_diff(a.means_, b.means_), rel_diff(a.covars_, b.covars_), rel_diff(a.transmat_, b.transmat_))

    exact_fit = fit_ours(exact=True)
    cases.append(case("fit", size + " 10 EM iterations", t["ours"], "hmmlearn", t["peer"],
                      agreement(r["ours"], r["peer"]), agree_all_double=agreement(r["ours"], exact_fit)))

    t, _ = timeit_interleaved({"double": lambda: _core.gaussian_log_density(X, model.means_, covars2d, "full"),
                               "float32": lambda: _core.gaussian_log_density_screened(X, model.means_, covars2d)},
                              repeats)
    flops = n * T * (2.0 * d * d + 3.0 * d)  # counted as a dense D x D product per frame and state
    cases.append(case("emission_kernel", size + " double", t["double"], None, None, None,
                      gflops=flops / t["double"] / 1e9, numpy_matmul_gflops=_matmul_gflops(repeats)))
    cases.append(case("emission_screen_f32", size + " float32 + error bounds", t["float32"], None, None, None,
                      gflops=flops / t["float32"] / 1e9,
                      numpy_matmul_f32_gflops=_matmul_gflops(repeats, np.float32)))
    return cases
