"""Entropic estimation: the MAP multinomial against direct numerical maximisation (scipy), the
Baum-Welch limit Z = 0, trimming that raises the exact log posterior, a monotone log posterior,
recovery of a planted sparse machine, and the diagnostics against brute-force enumeration."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.special import logsumexp

from voicepuppet import _core
from voicepuppet.hmm import diagnostics as D
from voicepuppet.hmm import entropic as E
from voicepuppet.hmm.entropic import EntropicHMM
from voicepuppet.hmm.gaussian import GaussianHMM

SEED = 20260523


def objective(omega, theta, z):
    m = theta > 0
    if np.any(omega[~m] > 0):
        return -np.inf
    return float(np.sum((omega[m] + z * theta[m]) * np.log(theta[m])))


def numerical_max(omega, z, rng, starts=8):
    """Direct maximisation over the simplex (softmax parametrisation, BFGS, many starts)."""
    K = len(omega)
    best = -np.inf
    for s in range(starts):
        x0 = np.log(omega + 1e-3) if s == 0 else rng.normal(scale=3.0, size=K)
        if s == 1:
            x0 = np.zeros(K)
        if s == 2:  # near the vertex of the largest count
            x0 = np.full(K, -20.0)
            x0[np.argmax(omega)] = 0.0

        def f(x):  # in log space: log θ = x − logsumexp(x) stays finite
            log_th = x - logsumexp(x)
            th = np.exp(log_th)
            g = omega + z * th * (1.0 + log_th)
            return -float(np.sum((omega + z * th) * log_th)), -(g - th * g.sum())

        r = minimize(f, x0, jac=True, method="BFGS", options={"gtol": 1e-12, "maxiter": 2000})
        best = max(best, -float(r.fun))
    return best


@pytest.mark.parametrize("case", range(60))
def test_multinomial_equals_numerical_maximisation(case):
    rng = np.random.default_rng(SEED + case)
    K = int(rng.integers(2, 7))
    omega = rng.exponential(size=K) * 10 ** rng.uniform(-5, 2)  # down to tiny totals
    if case % 3 == 0:
        omega[rng.integers(K)] = 0.0  # zero evidence
    z = [1.0, 0.3, 3.0, -0.5, -2.0][case % 5] * 10 ** rng.uniform(-0.5, 0.5)
    theta = E.entropic_multinomial(omega, z)
    assert theta.shape == (K,) and np.all(theta >= 0)
    assert theta.sum() == pytest.approx(1.0, abs=1e-13)
    ours = objective(omega, theta, z)
    ref = numerical_max(omega, z, rng)
    # ours is a feasible point, so it cannot beat the true maximum by more than rounding...
    assert ours >= ref - 1e-9 * max(1.0, abs(ref)), (omega, z, theta)
    assert E.entropic_objective(omega, theta, z) == pytest.approx(ours, rel=1e-12, abs=1e-300)
    if z > 0:
        assert np.all(theta[omega == 0] == 0.0)  # extinction of unsupported entries


def test_multinomial_matches_scipy_on_tiny_and_huge_scales():
    rng = np.random.default_rng(SEED)
    for scale in (1e-9, 1e-6, 1e3, 1e6):
        omega = rng.exponential(size=4) * scale
        theta = E.entropic_multinomial(omega, 1.0)
        assert objective(omega, theta, 1.0) >= numerical_max(omega, 1.0, rng) - 1e-9 * max(1, scale)
    # With overwhelming evidence the prior is negligible: θ → ω / Σω.
    omega = np.array([3e9, 1e9, 6e9])
    np.testing.assert_allclose(E.entropic_multinomial(omega, 1.0), omega / omega.sum(), rtol=1e-7)


def test_z_zero_is_maximum_likelihood_exactly():
    rng = np.random.default_rng(SEED)
    from voicepuppet.hmm.gaussian import aligned

    counts = rng.exponential(size=(5, 6))
    counts[2, 3] = 0
    # Both kernels read the same 64-byte-aligned buffers: their SIMD sums then split alike.
    counts, old = aligned(counts), aligned(np.full((5, 6), 1 / 6))
    np.testing.assert_array_equal(E.entropic_rows(counts, 0.0, old), _core.normalize_counts(counts, old))


def test_single_survivor_and_rows_without_evidence():
    np.testing.assert_array_equal(E.entropic_multinomial([0, 0, 4.2, 0], 1.0), [0, 0, 1, 0])
    old = np.array([[0.2, 0.8], [0.5, 0.5]])
    out = E.entropic_rows(np.array([[0.0, 0.0], [1.0, 3.0]]), 1.0, old)
    np.testing.assert_array_equal(out[0], old[0])  # no evidence: kept
    assert out[1, 1] > 0.75  # sharper than ML (0.75)


def test_bad_input_is_a_clear_value_error():
    with pytest.raises(ValueError, match="negative"):
        E.entropic_multinomial([1.0, -1.0], 1.0)
    with pytest.raises(ValueError, match="NaN"):
        E.entropic_multinomial([1.0, np.nan], 1.0)
    with pytest.raises(ValueError, match="z must be a finite"):
        E.entropic_multinomial([1.0, 2.0], np.inf)
    with pytest.raises(ValueError, match="all zero"):
        E.entropic_multinomial([0.0, 0.0], 1.0)
    with pytest.raises(TypeError, match="prior"):
        GaussianHMM(3, prior="entropic")  # entropic training is EntropicHMM's
    with pytest.raises(ValueError, match="z must be"):
        EntropicHMM(3, z=float("nan"))
    with pytest.raises(ValueError, match="per-iteration"):
        EntropicHMM(3, z=[1.0, 1.0], n_iter=5).fit(np.random.default_rng(0).normal(size=(50, 2)))
    with pytest.raises(ValueError, match="n_iter"):
        E.anneal_schedule(0)


def test_anneal_schedule():
    z = E.anneal_schedule(20, -2.0, 1.0, 10)
    assert z[0] == pytest.approx(-2.0) and np.all(np.diff(z) >= 0) and np.all(z[10:] == 1.0)


# ------------------------------------------------------------------ training
def planted_cycle(n_frames=3000, seed=1):
    """A 5-state cycle (self 0.6, next 0.4) with well-separated 2-D Gaussians on a pentagon."""
    n = 5
    A = np.zeros((n, n))
    for i in range(n):
        A[i, i], A[i, (i + 1) % n] = 0.6, 0.4
    ang = 2 * np.pi * np.arange(n) / n
    means = 3.0 * np.c_[np.cos(ang), np.sin(ang)]
    cov = np.tile(0.3 * np.eye(2), (n, 1))
    X, states = _core.gaussian_hmm_sample(np.full(n, 1 / n), A, means, cov, "full", n_frames, seed)
    return X, A, means


def test_entropic_training_recovers_the_planted_machine():
    X, A_true, means_true = planted_cycle()
    ml = GaussianHMM(12, n_iter=60, random_state=0, tol=-np.inf).fit(X)
    ent = EntropicHMM(12, n_iter=60, random_state=0, tol=-np.inf, z=1.0).fit(X)
    h = ent.history_
    assert h[-1]["states"] < 12 and h[-1]["states"] == ent.n_states >= 5
    assert set(h[0]) >= {"log_posterior", "log_likelihood", "states", "arcs"}

    def spurious_arcs(model):
        # map every learned state to its planted state; an arc is spurious if the planted
        # machine cannot make that move (only stay or advance along the cycle).
        owner = np.argmin(((model.means_[:, None, :] - means_true[None]) ** 2).sum(-1), axis=1)
        return sum(1 for i, j in zip(*np.nonzero(model.transmat_)) if A_true[owner[i], owner[j]] == 0)

    assert spurious_arcs(ent) == 0
    assert spurious_arcs(ml) > 0
    assert np.count_nonzero(ent.transmat_) < np.count_nonzero(ml.transmat_) / 2
    # Every planted state is covered by some learned state.
    owner = np.argmin(((ent.means_[:, None, :] - means_true[None]) ** 2).sum(-1), axis=1)
    assert set(owner) == set(range(5))
    # Entropic decoding is far less ambiguous.
    d_ent, d_ml = D.diagnostics(ent, X), D.diagnostics(ml, X)
    assert d_ent["entropy_rate"] < 0.5 * d_ml["entropy_rate"]
    assert d_ent["perplexity"] < d_ml["perplexity"]
    assert d_ent["viterbi_log_share"] > d_ml["viterbi_log_share"]


def test_log_posterior_never_decreases_and_trims_raise_it():
    X, _, _ = planted_cycle(1500, seed=3)
    ent = EntropicHMM(10, n_iter=40, random_state=1, tol=-np.inf, z=1.0).fit(X)
    lp = np.array([r["log_posterior"] for r in ent.history_])
    assert np.all(np.diff(lp) >= -1e-8 * np.abs(lp[1:])), np.diff(lp).min()
    assert sum(r["arcs_trimmed"] for r in ent.history_) > 0
    assert sum(r["states_trimmed"] for r in ent.history_) > 0
    # The recorded value is the exact log posterior of the recorded model: recompute at the end.
    final = E._State(ent.startprob_, ent.transmat_, ent.means_, ent.covars_, "full")
    assert final.log_prior(1.0) == pytest.approx(E.log_prior(ent, 1.0))


def test_every_trim_step_raises_the_log_posterior(monkeypatch):
    """Each accepted trim raised the log posterior of its iteration, and the values compared are
    the exact log posteriors (recomputed independently by GaussianHMM.score + log_prior)."""
    X, _, _ = planted_cycle(1500, seed=4)
    seen = []
    real = E._evaluate

    def spy(st, log_b, lengths, z):
        res = real(st, log_b, lengths, z)
        seen.append((E._State(st.startprob.copy(), st.transmat.copy(), st.means.copy(), st.covars.copy(),
                              st.covariance), z, res[0]))
        return res

    real_lp = E._log_posterior

    def spy_lp(st, log_b, lengths, z):
        value = real_lp(st, log_b, lengths, z)
        seen.append((E._State(st.startprob.copy(), st.transmat.copy(), st.means.copy(), st.covars.copy(),
                              st.covariance), z, value))
        return value

    monkeypatch.setattr(E, "_evaluate", spy)
    monkeypatch.setattr(E, "_log_posterior", spy_lp)
    ent = EntropicHMM(10, n_iter=25, random_state=1, tol=-np.inf, z=1.0).fit(X)
    trims = [r for r in ent.history_ if r["arcs_trimmed"] or r["states_trimmed"]]
    assert trims
    for r in trims:
        assert r["log_posterior"] > r["log_posterior_untrimmed"]
    for st, z, value in seen[:: max(1, len(seen) // 12)]:
        m = GaussianHMM(st.n)
        m.startprob_, m.transmat_, m.means_, m.covars_ = st.startprob, st.transmat, st.means, st.covars
        assert m.score(X) + E.log_prior(m, z) == pytest.approx(value, rel=1e-10)


@pytest.mark.parametrize("min_covar", [0.0, 1e-3, 1e-1])
def test_z_zero_reduces_to_baum_welch_exactly(min_covar):
    """With Z = 0 the entropic trainer is Baum-Welch, variance floor included (the floor acts per
    frame in both: K = (S + c w I) / (w + Z)), so entropic vs conventional differ only by the prior."""
    X, _, _ = planted_cycle(800, seed=5)
    ml = GaussianHMM(4, n_iter=8, random_state=2, tol=-np.inf, min_covar=min_covar).fit(X)
    ent = EntropicHMM(4, n_iter=8, random_state=2, tol=-np.inf, min_covar=min_covar, z=0.0,
                      trim=False).fit(X)
    np.testing.assert_allclose(ent.transmat_, ml.transmat_, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(ent.means_, ml.means_, rtol=1e-10)
    np.testing.assert_allclose(ent.covars_, ml.covars_, rtol=1e-9)
    np.testing.assert_allclose([r["log_likelihood"] for r in ent.history_],
                               [r["log_likelihood"] for r in ml.history_], rtol=1e-12)


def test_annealed_training_runs_and_ends_at_z_final():
    X, _, _ = planted_cycle(1000, seed=6)
    zs = E.anneal_schedule(20, -1.0, 1.0, 8)
    ent = EntropicHMM(8, n_iter=20, random_state=0, tol=-np.inf, z=zs).fit(X)
    assert [r["z"] for r in ent.history_] == pytest.approx(list(zs[:len(ent.history_)]))
    fixed = [r["log_posterior"] for r in ent.history_ if r["z"] == 1.0]
    assert np.all(np.diff(fixed) >= -1e-8 * np.abs(fixed[1:]))


# ------------------------------------------------------------------ diagnostics
def brute_force_paths(log_b, pi, A):
    T, N = log_b.shape
    with np.errstate(divide="ignore"):
        lpi, lA = np.log(pi), np.log(A)
    logs = []
    for path in itertools.product(range(N), repeat=T):
        v = lpi[path[0]] + log_b[0, path[0]]
        for t in range(1, T):
            v += lA[path[t - 1], path[t]] + log_b[t, path[t]]
        logs.append(v)
    logs = np.array(logs)
    return logs - logsumexp(logs)  # log p(path | X)


def test_entropy_rate_and_viterbi_share_against_enumeration():
    rng = np.random.default_rng(SEED)
    T, N = 6, 3
    log_b = rng.normal(size=(T, N))
    pi = np.array([0.5, 0.5, 0.0])
    A = np.array([[0.7, 0.3, 0.0], [0.0, 0.6, 0.4], [0.2, 0.0, 0.8]])
    lp = brute_force_paths(log_b, pi, A)
    p = np.exp(lp[np.isfinite(lp)])
    H = -np.sum(p * np.log(p))
    assert D.entropy_rate(log_b, pi, A) == pytest.approx(H / T, rel=1e-10)
    log_share, per_frame = D.viterbi_share(log_b, pi, A)
    assert log_share == pytest.approx(np.max(lp), rel=1e-10)
    assert per_frame == pytest.approx(math.exp(np.max(lp) / T))


def test_perplexity_and_context_memory():
    n = 26
    cycle = np.roll(np.eye(n), 1, axis=1)
    assert D.perplexity(cycle) == pytest.approx(1.0)
    assert D.context_memory(cycle) == math.inf
    assert D.perplexity(np.full((n, n), 1 / n)) == pytest.approx(n)
    # Brand's footnote: branching factor 2.08 among 26 states ≈ 4.5 frames of context.
    A = np.zeros((n, n))
    for i in range(n):
        A[i, i], A[i, (i + 1) % n] = 0.5, 0.5
    assert D.perplexity(A) == pytest.approx(2.0)
    assert D.context_memory(A) == pytest.approx(math.log(26) / math.log(2))
    with pytest.raises(ValueError, match="rows summing"):
        D.perplexity(np.ones((2, 2)))


def test_progress_bar_is_shown(capsys):
    X, _, _ = planted_cycle(300, seed=7)
    EntropicHMM(4, n_iter=3, progress=True, tol=-np.inf).fit(X)
    assert "entropic EM" in capsys.readouterr().err


def test_diagonal_covariances_and_several_sequences():
    X, _, _ = planted_cycle(1200, seed=8)
    lengths = [500, 400, 300]
    ent = EntropicHMM(8, "diag", n_iter=30, random_state=0, tol=-np.inf).fit(X, lengths)
    lp = np.array([r["log_posterior"] for r in ent.history_])
    assert np.all(np.diff(lp) >= -1e-8 * np.abs(lp[1:]))
    assert ent.covars_.shape == (ent.n_states, 2) and ent.n_states <= 8
    assert np.isfinite(ent.score(X, lengths))

