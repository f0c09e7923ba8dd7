"""Benchmark suite ``dpds``: the phoneme-driven DPDS (Englebienne et al. 2007) against numpy
references of the same algorithms, beside the voice puppet's closed-form synthesis.

Cases (K = 16 face dimensions, 41 phones, phones dwelling 2-12 frames at 29.97 fps):

- ``generate_hour``: DPDS generation for one hour of labels (107,892 frames), C++ recursion vs a
  numpy loop over frames; ``realtime_factor`` = seconds of video per second of compute.
- ``stream_hour``: the same hour pushed one frame at a time through :class:`voicepuppet.phonemes.dpds.DPDSStream`
  (Python call per frame included): ``frame_ms_p50`` / ``frame_ms_p99``.
- ``trajectory_hour``: beside it, the puppet's synthesis kernel on the same hour (Brand's
  closed-form trajectory with one full-covariance Gaussian per phone, block Cholesky), no peer.
- ``puppet_animate_hour``: beside it, the voice puppet's whole animation of the same hour from
  audio feature frames (Viterbi on the vocal HMM, closed-form trajectory, landmarks; features
  precomputed), a 40-state puppet trained on 2 minutes of synthetic landmark/feature frames.
- ``gradient_10min``: the gradient of eq. 1 in a on 10 minutes of labelled frames (17,980
  frames, 20 sequences), C++ adjoint recursion vs the forward chain rule of the paper's appendix
  A in numpy; ``agree`` compares the gradients.
- ``solve_10min``: the exact mu/nu/r solve (Algorithm 1) on the same frames, no peer (the
  tests compare it with lstsq on small problems).
- ``train_10min``: :meth:`voicepuppet.phonemes.dpds.DPDS.fit` on the same 10 minutes (L-BFGS-B, 100
  iterations at most), no peer.
"""

from __future__ import annotations

import time

import numpy as np

from voicepuppet import _core
from voicepuppet.animation import neutral_landmarks
from voicepuppet.bench.runner import case, rel_diff, timeit_interleaved
from voicepuppet.phonemes.dpds import DPDS
from voicepuppet.phonemes.labels import N_PHONES
from voicepuppet.puppet import Puppet
from voicepuppet.trajectory import make_model

FPS = 29.97
K = 16
SEED = 2007


def _labels(rng, T):
    dwell = rng.integers(2, 13, size=T)
    seq = np.repeat(rng.integers(0, N_PHONES, size=T), dwell)[:T]
    return np.ascontiguousarray(seq, dtype=np.int64)


def _params(rng):
    a = rng.uniform(0.5, 0.95, size=(N_PHONES, K))
    mu = rng.normal(size=(N_PHONES, K))
    nu = rng.normal(size=(N_PHONES, K)) * (1 - a)
    return a, mu, nu


def _numpy_generate(a, mu, nu, lab):
    x = np.empty((len(lab), a.shape[1]))
    x[0] = mu[lab[0]]
    for t in range(1, len(lab)):
        x[t] = a[lab[t]] * x[t - 1] + nu[lab[t]]
    return x


def _numpy_gradient(a, mu, nu, r, Y, off, lab):
    """Appendix A: forward chain rule dx_t/da = delta(s_t) x_{t-1} + a_{s_t} dx_{t-1}/da."""
    grad = np.zeros_like(a)
    for b, e in zip(off[:-1], off[1:]):
        x = mu[lab[b]].copy()
        dx = np.zeros_like(a)
        for t in range(b + 1, e):
            p = lab[t]
            dx *= a[p]
            dx[p] += x
            x = a[p] * x + nu[p]
            grad += dx * ((Y[t] - x) / r)
    return grad


def _puppet_animate_case(rng, n_frames: int, repeats: int) -> dict:
    """A 40-state puppet trained on 2 minutes of performer landmarks with synthetic feature
    frames (features_list), then animated from an hour of feature frames."""
    T = int(120 * FPS)
    neutral = neutral_landmarks()
    basis = rng.normal(size=(4, 68, 2))
    z = np.cumsum(rng.normal(size=(T, 4)), axis=0)
    z = (z - z.mean(axis=0)) / z.std(axis=0)
    pts = neutral + np.einsum("tk,kpc->tpc", z, basis)
    A = 12
    mix = rng.normal(size=(4, A))
    feats = z @ mix + 0.3 * rng.normal(size=(T, A))
    puppet = Puppet.train([pts], features_list=[feats], fps=FPS, n_states=40, n_iter=20, seed=0)
    zh = np.cumsum(rng.normal(size=(n_frames, 4)), axis=0) * 0.05
    fh = zh @ mix + 0.3 * rng.normal(size=(n_frames, A))
    t, res = timeit_interleaved({"ours": lambda: puppet.animate(features=fh)}, max(1, repeats - 1))
    return case("puppet_animate_hour", f"T={n_frames}, 40 states, A={A} features, 68 points", t["ours"],
                None, None, None, realtime_factor=n_frames / FPS / t["ours"],
                frames_out=int(len(res["ours"].animation.points)))


def run(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The dpds suite's cases (see the module's docstring).

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
    rng = np.random.default_rng(SEED)
    cases = []
    hour = int(round((60 if quick else 3600) * FPS))
    lab = _labels(rng, hour)
    a, mu, nu = _params(rng)
    empty = np.zeros(0, np.int64)
    t, res = timeit_interleaved({"ours": lambda: _core.dpds_generate(a, mu, nu, lab, empty),
                                 "peer": lambda: _numpy_generate(a, mu, nu, lab)}, repeats)
    cases.append(case("generate_hour", f"T={hour}, K={K}, P={N_PHONES}", t["ours"], "numpy loop",
                      t["peer"], rel_diff(res["ours"], res["peer"]),
                      realtime_factor=hour / FPS / t["ours"]))

    # streaming: one frame per call
    m = DPDS()
    m.n_dims_, m.a_, m.mu_, m.nu_ = K, a, mu, nu
    st = m.stream()
    n_stream = min(hour, 20000 if not quick else 2000)
    per = np.empty(n_stream)
    out = np.empty((n_stream, K))
    for i in range(n_stream):
        t0 = time.perf_counter()
        out[i] = st.push(lab[i:i + 1])[0]
        per[i] = time.perf_counter() - t0
    cases.append(case("stream_hour", f"{n_stream} frames pushed one at a time, K={K}", float(per.sum()),
                      None, None, rel_diff(out, res["ours"][:n_stream]),
                      frame_ms_p50=1000 * float(np.percentile(per, 50)),
                      frame_ms_p99=1000 * float(np.percentile(per, 99)),
                      realtime_factor=n_stream / FPS / float(per.sum())))

    # the puppet's synthesis kernel on the same hour, for scale
    covars = np.empty((N_PHONES, 2 * K, 2 * K))
    for p in range(N_PHONES):
        g = rng.normal(size=(2 * K, 2 * K))
        covars[p] = g @ g.T / (2 * K) + 0.3 * np.eye(2 * K)
    model = make_model(mu, 0.02 * rng.normal(size=(N_PHONES, K)), covars)
    t, _ = timeit_interleaved({"ours": lambda: _core.solve_trajectory(model, lab)}, max(1, repeats - 1))
    cases.append(case("trajectory_hour", f"T={hour}, D={K}, full covariance", t["ours"], None, None, None,
                      realtime_factor=hour / FPS / t["ours"]))

    # the voice puppet's own animation (Viterbi on the vocal HMM + closed-form trajectory +
    # landmarks) from audio feature frames for the same hour, features precomputed
    cases.append(_puppet_animate_case(rng, hour, repeats))

    # training on 10 minutes of labelled frames
    n_seq = 20
    T_seq = int(round((30 if quick else 600) * FPS / n_seq))
    ys, ls = [], []
    for _ in range(n_seq):
        lb = _labels(rng, T_seq)
        ys.append(_numpy_generate(a, mu, nu, lb) + 0.1 * rng.normal(size=(T_seq, K)))
        ls.append(lb)
    Y = np.ascontiguousarray(np.concatenate(ys))
    L = np.concatenate(ls)
    off = np.arange(n_seq + 1, dtype=np.int64) * T_seq
    a0 = np.full_like(a, 0.7)
    floor = np.full(K, 1e-6)

    sol = _core.dpds_solve(a0, Y, off, L, floor)
    t, res = timeit_interleaved(
        {"ours": lambda: _core.dpds_gradient(a0, sol["mu"], sol["nu"], sol["r"], Y, off, L)["grad_a"],
         "peer": lambda: _numpy_gradient(a0, sol["mu"], sol["nu"], sol["r"], Y, off, L)}, repeats)
    cases.append(case("gradient_10min", f"N={len(Y)} frames in {n_seq} sequences, K={K}", t["ours"],
                      "numpy forward chain rule (appendix A)", t["peer"], rel_diff(res["ours"], res["peer"])))
    t, _ = timeit_interleaved({"ours": lambda: _core.dpds_solve(a0, Y, off, L, floor)}, repeats)
    cases.append(case("solve_10min", f"N={len(Y)} frames, K={K}, 2P={2 * N_PHONES} unknowns per dim",
                      t["ours"], None, None, None))
    t0 = time.perf_counter()
    fitted = DPDS(max_iter=100).fit(ys, ls)
    t_fit = time.perf_counter() - t0
    cases.append(case("train_10min", f"N={len(Y)} frames, K={K}, L-BFGS-B <= 100 iterations", t_fit, None,
                      None, None, iterations=len(fitted.history_) - 1,
                      ll_per_frame=fitted.history_[-1] / len(Y),
                      a_error=float(np.max(np.abs(fitted.a_[np.unique(L)] - a[np.unique(L)])))))
    return cases
