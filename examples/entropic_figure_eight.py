"""Voice Puppetry figure 4 (top two panels): conventional vs entropic HMMs of a noisy figure-eight.

A point orbits a figure-eight; we observe its 2-D position and velocity (4-D measurements of a
2-D manifold, ambiguous where the orbit crosses itself). From the same initialisation, a
fully connected HMM is trained conventionally (Baum-Welch) and entropically; the script draws
each model over the data, synthesises a trajectory from a random walk through each model
(voicepuppet.trajectory, Brand eq. 5-6) and prints the table of docs/entropic.md.

    PYTHONPATH=python python examples/entropic_figure_eight.py --out docs/img
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from voicepuppet import _core
from voicepuppet.hmm import diagnostics as D
from voicepuppet.hmm.entropic import EntropicHMM
from voicepuppet.hmm.gaussian import GaussianHMM
from voicepuppet.trajectory import solve_trajectory


def figure_eight(n_frames: int, seed: int, noise: float = 0.08, period: float = 60.0) -> np.ndarray:
    """Observations [x, y, dx, dy] of a figure-eight x = sin φ, y = sin φ cos φ, with a jittered
    phase rate and isotropic position noise (velocities are differences of noisy positions)."""
    rng = np.random.default_rng(seed)
    dphi = 2 * np.pi / period * (1 + 0.15 * np.sin(np.arange(n_frames + 1) / 97.0)
                                 + 0.05 * rng.standard_normal(n_frames + 1))
    phi = np.cumsum(dphi)
    pos = np.c_[np.sin(phi), np.sin(phi) * np.cos(phi)] + noise * rng.standard_normal((n_frames + 1, 2))
    return np.ascontiguousarray(np.c_[pos[1:], pos[1:] - pos[:-1]])


def draw(ax, model, X, title):
    from matplotlib.patches import Ellipse

    ax.plot(X[:, 0], X[:, 1], ".", ms=1.5, color="0.75", zorder=0)
    mu = model.means_[:, :2]
    A = model.transmat_
    for i, j in zip(*np.nonzero(A)):
        if i == j or A[i, j] < 1e-3:
            continue
        ax.annotate("", xy=mu[j], xytext=mu[i],
                    arrowprops=dict(arrowstyle="->", lw=0.4 + 1.6 * A[i, j], color="tab:blue",
                                    alpha=0.3 + 0.7 * A[i, j], shrinkA=2, shrinkB=2))
    for n in range(model.n_states):
        C = model.covars_[n][:2, :2]
        vals, vecs = np.linalg.eigh(C)
        ang = np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1]))
        ax.add_patch(Ellipse(mu[n], 2 * np.sqrt(vals[1]), 2 * np.sqrt(vals[0]), angle=ang,
                             fill=False, lw=0.8, color="tab:red"))
    ax.plot(mu[:, 0], mu[:, 1], "x", color="k", ms=5)
    ax.set_title(title, fontsize=9)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def random_walk(model, n_frames, seed):
    _, states = _core.gaussian_hmm_sample(model.startprob_, model.transmat_, model.means_,
                                          model.covars_2d(), model.covariance, n_frames, seed)
    return states


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="docs/img", help="folder for the PNGs")
    p.add_argument("--states", type=int, default=24)
    p.add_argument("--iters", type=int, default=100)
    p.add_argument("--frames", type=int, default=3000)
    args = p.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    X = figure_eight(args.frames, seed=1)
    X_test = figure_eight(args.frames // 2, seed=2)
    common = dict(n_iter=args.iters, random_state=0, tol=-np.inf, covariance="full")
    models = {
        "conventional": GaussianHMM(args.states, **common).fit(X),
        "entropic": EntropicHMM(args.states, z=1.0, **common).fit(X),
    }
    rows = {}
    for name, m in models.items():
        d = D.diagnostics(m, X_test)
        rows[name] = {k: d[k] for k in ("states", "arcs", "perplexity", "context_memory",
                                        "log_likelihood_per_frame", "entropy_rate",
                                        "viterbi_share_per_frame")}
    print(json.dumps(rows, indent=2))
    h = models["entropic"].history_
    print("entropic history (every 10th):",
          [(r["iteration"], r["states"], r["arcs"], round(r["log_posterior"], 1)) for r in h[::10]])

    os.makedirs(args.out, exist_ok=True)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, (name, m) in zip(axes, models.items()):
        draw(ax, m, X, f"{name}: {m.n_states} states, {np.count_nonzero(m.transmat_)} arcs")
    fig.tight_layout()
    tmp = os.path.join(args.out, "entropic_figure8_models.tmp.png")
    fig.savefig(tmp, dpi=130)
    os.replace(tmp, os.path.join(args.out, "entropic_figure8_models.png"))
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, (name, m) in zip(axes, models.items()):
        states = random_walk(m, 400, seed=5)
        Y = solve_trajectory(states, m.means_, None, m.covars_, covariance_type="full")
        ax.plot(X[:, 0], X[:, 1], ".", ms=1.0, color="0.85", zorder=0)
        ax.plot(Y[:, 0], Y[:, 1], "-", lw=0.9, color="tab:green")
        ax.set_title(f"{name}: trajectory from a 400-frame random walk", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    tmp = os.path.join(args.out, "entropic_figure8_walks.tmp.png")
    fig.savefig(tmp, dpi=130)
    os.replace(tmp, os.path.join(args.out, "entropic_figure8_walks.png"))
    plt.close(fig)


if __name__ == "__main__":
    main()
