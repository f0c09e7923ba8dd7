"""Entropic suite: entropic training (EntropicHMM, z=1, trimming on) against conventional
Baum-Welch training of the same model, from the same initialisation, in the same run.

Sizes as issue 3 fixes them: T = 18,000 frames, D = 100, 40 initial fully connected states,
30 EM iterations. The figure of merit is the cost of one iteration: ``ours_s`` is the entropic
seconds per iteration, ``peer_s`` the conventional one (``ratio = peer_s / ours_s``; the target
is ratio >= 1/1.5, i.e. an entropic iteration costs at most 1.5x a conventional one). The extra
work of entropic estimation is O(N^2) per iteration (Lambert-W M-step, trimming tests) plus a
forward pass over the already computed densities per trimming trial.
"""

from __future__ import annotations

import time

import numpy as np

from voicepuppet.bench.hmm import make_problem
from voicepuppet.bench.runner import case
from voicepuppet.hmm.entropic import EntropicHMM
from voicepuppet.hmm.gaussian import GaussianHMM


def _train(X, n, n_iter, prior):
    model, kw = (EntropicHMM, {"z": 1.0, "trim": True}) if prior else (GaussianHMM, {})
    m = model(n, "full", n_iter=n_iter, tol=-np.inf, random_state=0, **kw)
    t0 = time.perf_counter()
    m.fit(X)
    return time.perf_counter() - t0, m


def run(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The entropic suite's case (see the module's docstring).

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
    """
    n_true, n, d, T, n_iter = (8, 12, 20, 2000, 10) if quick else (26, 40, 100, 18000, 30)
    _, X = make_problem(n_true, d, T)
    per_iter = {"entropic": [], "conventional": []}
    models = {}
    for _ in range(max(1, repeats)):  # interleaved: entropic, conventional, entropic, ...
        for name in ("entropic", "conventional"):
            seconds, m = _train(X, n, n_iter, name == "entropic")
            per_iter[name].append(seconds / len(m.history_))
            models[name] = m
    ent, conv = models["entropic"], models["conventional"]
    ll_ent = ent.score(X) / T
    ll_conv = conv.score(X) / T
    ours, peer = float(np.median(per_iter["entropic"])), float(np.median(per_iter["conventional"]))
    return [case("fit_per_iteration", f"N0={n} D={d} T={T} full, {n_iter} it", ours, "conventional", peer,
                 abs(ll_ent - ll_conv) / max(abs(ll_conv), 1e-300),
                 cost_ratio=ours / peer, states_final=int(ent.n_states),
                 arcs_final=int(np.count_nonzero(ent.transmat_)),
                 arcs_conventional=int(np.count_nonzero(conv.transmat_)),
                 loglik_per_frame_entropic=ll_ent, loglik_per_frame_conventional=ll_conv)]
