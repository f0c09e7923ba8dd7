"""What an HMM has learned, as Voice Puppetry reports it (§4.2, §5.1): perplexity of the
transition matrix (average branching factor), context memory (frames), the entropy rate of
decoding, and the share of the posterior mass on the Viterbi path.
"""

from __future__ import annotations

import math

import numpy as np

from voicepuppet import _core

__all__ = ["perplexity", "context_memory", "entropy_rate", "viterbi_share", "diagnostics"]


# ---------------------------------------------------------------------------------- diagnostics
def _stationary(transmat: np.ndarray) -> np.ndarray:
    n = transmat.shape[0]
    # Solve p (A − I) = 0, Σp = 1 in the least-squares sense (unique for an irreducible chain).
    M = np.vstack([transmat.T - np.eye(n), np.ones((1, n))])
    b = np.zeros(n + 1)
    b[-1] = 1.0
    p = np.linalg.lstsq(M, b, rcond=None)[0]
    p = np.clip(p, 0.0, None)
    return p / p.sum()


def perplexity(transmat, weights=None) -> float:
    """Average branching factor exp(Σ_i w_i H(θ_i·)) of a transition matrix, in states.

    Parameters
    ----------
    transmat : array_like, shape (N, N)
        A transition matrix (finite, non-negative, rows summing to 1).
    weights : array_like, shape (N,), optional
        Weight of each state's row entropy H(θ_i·) (e.g. state occupancies; normalised here).
        Default: the stationary distribution of ``transmat``.

    Returns
    -------
    float
        The perplexity, between 1 (deterministic) and N.

    Raises
    ------
    ValueError
        ``transmat`` not square, empty, or not a stochastic matrix; ``weights`` not N
        non-negative numbers with a positive sum.
    """
    A = np.asarray(transmat, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.size == 0:
        raise ValueError(f"transmat must be a square (N, N) matrix, got shape {A.shape}")
    if not np.all(np.isfinite(A)) or np.any(A < 0) or not np.allclose(A.sum(axis=1), 1.0, atol=1e-6):
        raise ValueError("transmat must be finite, non-negative, with rows summing to 1")
    w = _stationary(A) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (A.shape[0],) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError(f"weights must be {A.shape[0]} non-negative numbers with a positive sum")
    w = w / w.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        H = -np.where(A > 0, A * np.log(np.where(A > 0, A, 1.0)), 0.0).sum(axis=1)
    return float(np.exp(w @ H))


def context_memory(transmat, weights=None) -> float:
    """Frames of context the machine carries: log_perplexity(N) = log N / log perplexity
    (Voice Puppetry §5, footnote 1); inf for a deterministic machine.

    Parameters
    ----------
    transmat : array_like, shape (N, N)
        A transition matrix.
    weights : array_like, shape (N,), optional
        State weights of the perplexity (:func:`perplexity`; default: the stationary distribution).

    Returns
    -------
    float
        log N / log :func:`perplexity`, or ``inf`` when the perplexity is 1.
    """
    n = np.asarray(transmat).shape[0]
    p = perplexity(transmat, weights)
    return math.inf if p <= 1.0 + 1e-12 else math.log(n) / math.log(p)


def entropy_rate(log_b, startprob, transmat, lengths=None) -> float:
    """Entropy of the posterior over state sequences, per frame (nats): H(S | X) / T.

    Exact, from one forward-backward pass: H(S|X) = log p(X) − E[log p(S, X)] with
    E[log p(S, X)] = Σ γ_1 log π + Σ ξ_ij log θ_ij + Σ_t Σ_i γ_ti log b_i(x_t).

    Parameters
    ----------
    log_b : array_like, shape (T, N)
        Log densities of the frames under each state.
    startprob : array_like, shape (N,)
        Start probabilities.
    transmat : array_like, shape (N, N)
        Transition probabilities.
    lengths : array_like of int, shape (S,), optional
        Frames per sequence (default: one sequence of T frames).

    Returns
    -------
    float
        H(S | X) / T in nats per frame (>= 0).
    """
    log_b = np.ascontiguousarray(log_b, dtype=np.float64)
    T = log_b.shape[0]
    lengths = np.array([T], dtype=np.int64) if lengths is None else np.ascontiguousarray(lengths, dtype=np.int64)
    pi = np.ascontiguousarray(startprob, dtype=np.float64)
    A = np.ascontiguousarray(transmat, dtype=np.float64)
    ll, post, xi, starts, _ = _core.forward_backward(log_b, pi, A, lengths)

    def xlogy(x, y):
        return np.where(x > 0, x * np.log(np.where(y > 0, y, 1.0)), 0.0)

    expected = xlogy(starts, pi).sum() + xlogy(xi, A).sum() + np.where(post > 0, post * log_b, 0.0).sum()
    return float(max(0.0, ll - expected) / T)


def viterbi_share(log_b, startprob, transmat, lengths=None) -> tuple[float, float]:
    """Share of the posterior mass on the Viterbi path.

    Parameters
    ----------
    log_b : array_like, shape (T, N)
        Log densities of the frames under each state.
    startprob : array_like, shape (N,)
        Start probabilities.
    transmat : array_like, shape (N, N)
        Transition probabilities.
    lengths : array_like of int, shape (S,), optional
        Frames per sequence (default: one sequence of T frames).

    Returns
    -------
    log_share : float
        log p(V | X) = log p(V, X) − log p(X), summed over sequences (<= 0).
    share_per_frame : float
        exp(log_share / T).
    """
    log_b = np.ascontiguousarray(log_b, dtype=np.float64)
    T = log_b.shape[0]
    lengths = np.array([T], dtype=np.int64) if lengths is None else np.ascontiguousarray(lengths, dtype=np.int64)
    pi = np.ascontiguousarray(startprob, dtype=np.float64)
    A = np.ascontiguousarray(transmat, dtype=np.float64)
    vit, _ = _core.viterbi(log_b, pi, A, lengths)
    ll = _core.log_likelihood(log_b, pi, A, lengths)
    log_share = min(0.0, float(vit - ll))
    return log_share, math.exp(log_share / T)


def diagnostics(model, X, lengths=None) -> dict:
    """The paper's measures for a fitted model on data X.

    Parameters
    ----------
    model : GaussianHMM
        A fitted model (:class:`~voicepuppet.hmm.gaussian.GaussianHMM` or :class:`EntropicHMM`).
    X : array_like, shape (T, D)
        Observations, sequences stacked in time.
    lengths : array_like of int, shape (S,), optional
        Frames per sequence (default: one sequence).

    Returns
    -------
    dict
        ``states``, ``arcs`` (non-zero transitions), ``perplexity`` and ``context_memory``
        (weights: the occupancy of X), ``log_likelihood_per_frame``, ``entropy_rate`` (nats per
        frame, :func:`entropy_rate`), ``viterbi_log_share`` and ``viterbi_share_per_frame``
        (:func:`viterbi_share`).
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    log_b = model.log_density(X)
    T = X.shape[0]
    lengths = np.array([T], dtype=np.int64) if lengths is None else np.ascontiguousarray(lengths, dtype=np.int64)
    occupancy = model.predict_proba(X, lengths).sum(axis=0)
    log_share, share = viterbi_share(log_b, model.startprob_, model.transmat_, lengths)
    return {"states": int(model.transmat_.shape[0]), "arcs": int(np.count_nonzero(model.transmat_)),
            "perplexity": perplexity(model.transmat_, occupancy),
            "context_memory": context_memory(model.transmat_, occupancy),
            "log_likelihood_per_frame": model.score(X, lengths) / T,
            "entropy_rate": entropy_rate(log_b, model.startprob_, model.transmat_, lengths),
            "viterbi_log_share": log_share, "viterbi_share_per_frame": share}
