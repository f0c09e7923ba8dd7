"""Tests of voicepuppet.trajectory against independent truth.

- a dense numpy solve of the normal equations assembled from the objective itself
  (stacked selection matrices, not the block formulas of the C++ kernel);
- MLPG: nnmnkwii's ``mlpg`` (peer) and Tokuda's formula y = (W^T U^-1 W)^-1 W^T U^-1 mu in numpy;
- closed forms: one state gives its mean, a step gives the analytic exponential approach,
  one-hot posteriors equal the hard solve;
- planted truth: data sampled around an HMM state path is tracked within a stated bound.
"""

from __future__ import annotations

import numpy as np
import pytest

from voicepuppet import trajectory as tr

SEED = 20261123


def random_model(rng, n, d, corr=True):
    means = rng.normal(size=(n, d))
    vel = 0.3 * rng.normal(size=(n, d))
    a = rng.normal(size=(n, 2 * d, 2 * d))
    covars = a @ a.transpose(0, 2, 1) / (2 * d) + 0.5 * np.eye(2 * d)
    if not corr:
        covars = np.stack([np.diag(np.diag(c)) for c in covars])
    return means, vel, covars


def dwell_states(rng, T, n, max_dwell=6):
    out = []
    while len(out) < T:
        out += [int(rng.integers(n))] * int(rng.integers(1, max_dwell + 1))
    return np.array(out[:T], dtype=np.int64)


def dense_solve(weights, means, vel, covars, targets=None, W=None):
    """Minimise sum_t sum_n w_tn cost_t(n) (+ sum_t (y_t - targets_t)' W (y_t - targets_t)) by a
    dense solve; covars full [N, 2D, 2D]."""
    T, n = weights.shape
    d = means.shape[1]
    H = np.zeros((T * d, T * d))
    r = np.zeros(T * d)
    for t in range(T):
        if W is not None:
            H[t * d:(t + 1) * d, t * d:(t + 1) * d] += W
            r[t * d:(t + 1) * d] += W @ targets[t]
        for s in range(n):
            w = weights[t, s]
            if w == 0:
                continue
            if t == 0:  # pose marginal only
                P = np.linalg.inv(covars[s][:d, :d])
                H[:d, :d] += w * P
                r[:d] += w * P @ means[s]
                continue
            G = np.zeros((2 * d, T * d))
            G[:d, t * d:(t + 1) * d] = np.eye(d)
            G[d:, t * d:(t + 1) * d] = np.eye(d)
            G[d:, (t - 1) * d:t * d] = -np.eye(d)
            P = np.linalg.inv(covars[s])
            H += w * G.T @ P @ G
            r += w * G.T @ P @ np.concatenate([means[s], vel[s]])
    return np.linalg.solve(H, r).reshape(T, d)


def one_hot(states, n):
    w = np.zeros((len(states), n))
    w[np.arange(len(states)), states] = 1.0
    return w


def rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.mark.parametrize("T,d", [(1, 2), (7, 3), (300, 2), (120, 4)])
def test_full_matches_dense_solve(T, d):
    rng = np.random.default_rng(SEED + T)
    means, vel, covars = random_model(rng, 5, d)
    states = dwell_states(rng, T, 5)
    y = tr.solve_trajectory(states, means, vel, covars)
    assert y.shape == (T, d)
    assert rel(y, dense_solve(one_hot(states, 5), means, vel, covars)) < 1e-9


@pytest.mark.parametrize("d", [16, 50])
def test_full_at_benchmark_size_matches_banded_cholesky(d):
    """D = 50 as in the benchmark (several 8-column panels, a narrow last one) against scipy's
    band Cholesky on the banded normal equations assembled in numpy."""
    import scipy.linalg as sla

    from voicepuppet.bench.trajectory import _banded_system

    rng = np.random.default_rng(SEED + d)
    means, vel, covars = random_model(rng, 6, d)
    states = dwell_states(rng, 200, 6)
    ab, rhs = _banded_system(states, means, vel, covars)
    peer = sla.solveh_banded(ab, rhs, lower=True).reshape(len(states), d)
    assert rel(tr.solve_trajectory(states, means, vel, covars), peer) < 1e-10


def test_diag_matches_dense_solve_and_full_path():
    rng = np.random.default_rng(SEED)
    means, vel, covars = random_model(rng, 4, 3, corr=False)
    variances = np.stack([np.diag(c) for c in covars])
    states = dwell_states(rng, 250, 4)
    y = tr.solve_trajectory(states, means, vel, variances, covariance_type="diag")
    assert rel(y, dense_solve(one_hot(states, 4), means, vel, covars)) < 1e-9
    assert rel(y, tr.solve_trajectory(states, means, vel, covars)) < 1e-12


@pytest.mark.parametrize("covariance_type", ["full", "diag"])
def test_weighted_matches_dense_and_one_hot_equals_hard(covariance_type):
    rng = np.random.default_rng(SEED + 1)
    n, d, T = 4, 3, 150
    means, vel, covars = random_model(rng, n, d, corr=covariance_type == "full")
    c = covars if covariance_type == "full" else np.stack([np.diag(k) for k in covars])
    gamma = rng.dirichlet(np.ones(n) * 0.5, size=T)
    y = tr.solve_trajectory_weighted(gamma, means, vel, c, covariance_type=covariance_type)
    assert rel(y, dense_solve(gamma, means, vel, covars)) < 1e-9
    states = dwell_states(rng, T, n)
    hard = tr.solve_trajectory(states, means, vel, c, covariance_type=covariance_type)
    soft = tr.solve_trajectory_weighted(one_hot(states, n), means, vel, c, covariance_type=covariance_type)
    assert rel(soft, hard) < 1e-14


def test_matches_nnmnkwii_mlpg():
    """Peer: nnmnkwii's MLPG with window y_t - y_{t-1}. nnmnkwii drops the delta term at the first
    and the last frame; ours drops it at the first only, so the last frame gets its own state whose
    velocity variance is 1e300 (precision 1e-300, i.e. no velocity term)."""
    paramgen = pytest.importorskip("nnmnkwii.paramgen")
    rng = np.random.default_rng(SEED + 2)
    n, d, T = 5, 6, 400
    means = rng.normal(size=(n, d))
    vel = 0.3 * rng.normal(size=(n, d))
    var = rng.uniform(0.05, 2.0, size=(n, 2 * d))
    states = dwell_states(rng, T, n)
    windows = [(0, 0, np.array([1.0])), (1, 0, np.array([-1.0, 1.0]))]
    peer = paramgen.mlpg(np.hstack([means[states], vel[states]]), var[states], windows)
    last = states[-1]
    means2 = np.vstack([means, means[last]])
    vel2 = np.vstack([vel, vel[last]])
    var2 = np.vstack([var, var[last]])
    var2[-1, d:] = 1e300
    states2 = states.copy()
    states2[-1] = n
    ours = tr.solve_trajectory(states2, means2, vel2, var2, covariance_type="diag")
    assert rel(ours, peer) < 1e-8


def test_matches_tokuda_mlpg_formula():
    """Independent numpy MLPG: y = (W^T U^-1 W)^-1 W^T U^-1 mu, W stacking identity and the
    first-difference window (no delta row at frame 0), one static dimension at a time."""
    rng = np.random.default_rng(SEED + 3)
    n, d, T = 3, 2, 200
    means = rng.normal(size=(n, d))
    vel = 0.3 * rng.normal(size=(n, d))
    var = rng.uniform(0.1, 3.0, size=(n, 2 * d))
    states = dwell_states(rng, T, n)
    ours = tr.solve_trajectory(states, means, vel, var, covariance_type="diag")
    W = np.vstack([np.eye(T), (np.eye(T) - np.eye(T, k=-1))[1:]])
    for j in range(d):
        mu = np.concatenate([means[states, j], vel[states[1:], j]])
        uinv = np.concatenate([1 / var[states, j], 1 / var[states[1:], d + j]])
        y = np.linalg.solve(W.T @ (uinv[:, None] * W), W.T @ (uinv * mu))
        assert rel(ours[:, j], y) < 1e-10


def test_one_state_gives_its_mean():
    rng = np.random.default_rng(SEED + 4)
    means, vel, covars = random_model(rng, 1, 4)
    y = tr.solve_trajectory(np.zeros(40, dtype=int), means, np.zeros_like(vel), covars)
    np.testing.assert_allclose(y, np.repeat(means, 40, axis=0), rtol=0, atol=1e-12)


def test_step_is_the_analytic_exponential_approach():
    a, c, m0, m1 = 3.0, 8.0, 1.0, -2.0
    means = np.array([[m0], [m1]])
    var = np.array([[1 / a, 1 / c], [1 / a, 1 / c]])
    T, k = 300, 150
    states = (np.arange(T) >= k).astype(int)
    y = tr.solve_trajectory(states, means, np.zeros((2, 1)), var, covariance_type="diag")[:, 0]
    rho = ((a + 2 * c) - np.sqrt((a + 2 * c) ** 2 - 4 * c * c)) / (2 * c)
    j = np.arange(40)
    delta = m1 - m0
    np.testing.assert_allclose(y[k + j], m1 - delta * rho ** (j + 1) / (1 + rho), rtol=1e-12)
    np.testing.assert_allclose(y[k - 1 - j], m0 + delta * rho ** (j + 1) / (1 + rho), rtol=1e-12)


def test_first_frame_has_no_velocity_term():
    """Frame 0 is scored by the pose marginal N(mu, K^xx) only: changing the velocity mean or the
    velocity covariance of frame 0's state (used nowhere else) leaves the trajectory unchanged,
    while the same change on a later frame's state moves it."""
    rng = np.random.default_rng(SEED + 5)
    means, vel, covars = random_model(rng, 3, 2)
    states = np.array([0, 1, 1, 2, 2, 1])
    y = tr.solve_trajectory(states, means, vel, covars)
    vel2, cov2 = vel.copy(), covars.copy()
    vel2[0] += 5.0
    cov2[0][2:, 2:] *= 3.0  # velocity block; K^xx untouched
    cov2[0][:2, 2:] *= 0.5
    cov2[0][2:, :2] *= 0.5
    np.testing.assert_allclose(tr.solve_trajectory(states, means, vel2, cov2), y, rtol=1e-12, atol=1e-12)
    vel3 = vel.copy()
    vel3[2] += 5.0
    assert np.max(np.abs(tr.solve_trajectory(states, means, vel3, covars) - y)) > 0.1


def test_sampled_path_is_tracked():
    """Planted truth: x_t = mu_{s(t)} + noise (sd sigma) along a sticky Markov path. The
    trajectory from the true states tracks x with RMS error below 1.2 sigma (pure noise
    would give sigma; state switches add a little smoothing bias), and much closer to the
    noise-free path mu_{s(t)} than the data is."""
    rng = np.random.default_rng(SEED + 6)
    n, d, T, sigma = 6, 4, 3000, 0.1
    means = rng.normal(size=(n, d)) * 2.0
    states = dwell_states(rng, T, n, max_dwell=12)
    x = means[states] + sigma * rng.normal(size=(T, d))
    dx = np.diff(x, axis=0)
    vel = np.zeros((n, d))
    var = np.hstack([np.full((n, d), sigma**2), np.full((n, d), np.var(dx, axis=0))])
    y = tr.solve_trajectory(states, means, vel, var, covariance_type="diag")
    assert np.sqrt(np.mean((y - x) ** 2)) < 1.2 * sigma
    assert np.sqrt(np.mean((y - means[states]) ** 2)) < np.sqrt(np.mean((x - means[states]) ** 2))


@pytest.mark.parametrize("lag", [0, 1, 3, 10])
def test_fixed_lag_frames_are_truncated_dense_solves(lag):
    rng = np.random.default_rng(SEED + 7)
    n, d, T = 3, 2, 40
    means, vel, covars = random_model(rng, n, d)
    states = dwell_states(rng, T, n)
    stream = tr.FixedLagTrajectory(means, vel, covars, lag)
    parts = [stream.push_states(states[i:i + 7]) for i in range(0, T, 7)]
    parts.append(stream.flush())
    y = np.vstack(parts)
    assert y.shape == (T, d)
    for t in range(T - lag):
        truth = dense_solve(one_hot(states[:t + lag + 1], n), means, vel, covars)[t]
        assert np.max(np.abs(y[t] - truth)) < 1e-10 * np.max(np.abs(truth))
    full = tr.solve_trajectory(states, means, vel, covars)
    assert rel(y[T - lag - 1:], full[T - lag - 1:]) < 1e-12
    assert stream.frames_pushed == 0


def test_fixed_lag_deviation_decreases_with_lag():
    rng = np.random.default_rng(SEED + 8)
    means, vel, covars = random_model(rng, 5, 3)
    states = dwell_states(rng, 300, 5)
    full = tr.solve_trajectory(states, means, vel, covars)
    devs = []
    for lag in (0, 2, 8, 32):
        s = tr.FixedLagTrajectory(means, vel, covars, lag)
        y = np.vstack([s.push_states(states), s.flush()])
        devs.append(np.max(np.abs(y - full)))
    assert devs[0] > devs[1] > devs[2] > devs[3]
    assert devs[3] < 1e-6 * np.max(np.abs(full))


def test_fixed_lag_weights_equal_batch_weighted():
    rng = np.random.default_rng(SEED + 9)
    means, vel, covars = random_model(rng, 3, 2)
    gamma = rng.dirichlet(np.ones(3), size=30)
    s = tr.FixedLagTrajectory(means, vel, covars, 100)
    assert s.push_weights(gamma).shape == (0, 2)
    assert rel(s.flush(), tr.solve_trajectory_weighted(gamma, means, vel, covars)) < 1e-12


def random_evidence(rng, T, d):
    """Targets [T, d] and a PSD precision of rank d - 1 (a singular W must work too)."""
    B = rng.normal(size=(d, d - 1))
    return rng.normal(size=(T, d)), 2.0 * B @ B.T


def test_evidence_matches_dense_solve_hard_and_weighted():
    rng = np.random.default_rng(SEED + 20)
    n, d, T = 4, 3, 25
    means, vel, covars = random_model(rng, n, d)
    states = dwell_states(rng, T, n)
    y, W = random_evidence(rng, T, d)
    got = tr.solve_trajectory(states, means, vel, covars, evidence_targets=y, evidence_precision=W)
    truth = dense_solve(one_hot(states, n), means, vel, covars, y, W)
    assert rel(got, truth) < 1e-10
    assert rel(got, tr.solve_trajectory(states, means, vel, covars)) > 1e-3  # the evidence moved it
    gamma = rng.dirichlet(np.ones(n), size=T)
    got = tr.solve_trajectory_weighted(gamma, means, vel, covars, evidence_targets=y,
                                       evidence_precision=W)
    assert rel(got, dense_solve(gamma, means, vel, covars, y, W)) < 1e-10
    # W = 0 is the plain solve exactly; a huge W gives the targets
    np.testing.assert_array_equal(
        tr.solve_trajectory(states, means, vel, covars, evidence_targets=y,
                            evidence_precision=np.zeros((d, d))),
        tr.solve_trajectory(states, means, vel, covars))
    big = tr.solve_trajectory(states, means, vel, covars, evidence_targets=y,
                              evidence_precision=1e10 * np.eye(d))
    assert np.max(np.abs(big - y)) < 1e-6


def test_evidence_targets_are_at_the_output_rate():
    rng = np.random.default_rng(SEED + 21)
    means, vel, covars = random_model(rng, 3, 2)
    states = dwell_states(rng, 30, 3)
    y60 = rng.normal(size=(60, 2))  # 30 frames at 30 fps -> 60 at 60 fps
    out = tr.solve_trajectory(states, means, vel, covars, model_fps=30, out_fps=60,
                              evidence_targets=y60, evidence_precision=np.eye(2))
    assert out.shape == (60, 2)
    with pytest.raises(ValueError, match="60"):
        tr.solve_trajectory(states, means, vel, covars, model_fps=30, out_fps=60,
                            evidence_targets=y60[:30], evidence_precision=np.eye(2))
    with pytest.raises(ValueError, match="both or neither"):
        tr.solve_trajectory(states, means, vel, covars, evidence_targets=y60[:30])


@pytest.mark.parametrize("lag", [0, 3])
def test_fixed_lag_with_evidence_frames_are_truncated_dense_solves(lag):
    rng = np.random.default_rng(SEED + 22)
    n, d, T = 3, 2, 30
    means, vel, covars = random_model(rng, n, d)
    states = dwell_states(rng, T, n)
    y, W = random_evidence(rng, T, d)
    stream = tr.FixedLagTrajectory(means, vel, covars, lag, evidence_precision=W)
    assert stream.has_evidence
    parts = [stream.push_states(states[i:i + 7], y[i:i + 7]) for i in range(0, T, 7)]
    out = np.vstack(parts + [stream.flush()])
    for t in range(T - lag):
        truth = dense_solve(one_hot(states[:t + lag + 1], n), means, vel, covars, y, W)[t]
        assert np.max(np.abs(out[t] - truth)) < 1e-10 * np.max(np.abs(truth))
    full = tr.solve_trajectory(states, means, vel, covars, evidence_targets=y, evidence_precision=W)
    assert rel(out[T - lag - 1:], full[T - lag - 1:]) < 1e-12
    gamma = rng.dirichlet(np.ones(n), size=T)
    stream = tr.FixedLagTrajectory(means, vel, covars, 100, evidence_precision=W)
    assert stream.push_weights(gamma, y).shape == (0, d)
    assert rel(stream.flush(), tr.solve_trajectory_weighted(
        gamma, means, vel, covars, evidence_targets=y, evidence_precision=W)) < 1e-12
    with pytest.raises(ValueError, match="needs the frames' targets"):
        stream.push_states(states[:3])
    with pytest.raises(ValueError, match="no evidence"):
        tr.FixedLagTrajectory(means, vel, covars, 2).push_states(states[:3], y[:3])


def test_other_frame_rate_is_the_documented_change_of_variables():
    """At out_fps the solve equals a dense solve of the model with mu_dot -> r mu_dot,
    K^xv -> r K^xv, K^vv -> r^2 K^vv (r = model_fps / out_fps) on the sample-and-hold states."""
    rng = np.random.default_rng(SEED + 10)
    means, vel, covars = random_model(rng, 3, 2)
    states = dwell_states(rng, 30, 3)
    model_fps, out_fps = 29.97, 60.0
    r = model_fps / out_fps
    y = tr.solve_trajectory(states, means, vel, covars, model_fps=model_fps, out_fps=out_fps)
    idx = np.floor(np.arange(int(np.ceil(30 * out_fps / model_fps))) * model_fps / out_fps + 1e-9).astype(int)
    S = np.diag(np.r_[np.ones(2), np.full(2, r)])
    scaled = np.stack([S @ k @ S for k in covars])
    truth = dense_solve(one_hot(states[idx], 3), means, r * vel, scaled)
    assert y.shape == truth.shape == (61, 2)
    assert rel(y, truth) < 1e-9
    # same rate: identical to no rates at all
    same = tr.solve_trajectory(states, means, vel, covars, model_fps=25.0, out_fps=25.0)
    assert rel(same, tr.solve_trajectory(states, means, vel, covars)) < 1e-15


def test_doubling_the_rate_halves_per_frame_velocity():
    means, vel, var = np.zeros((1, 1)), np.ones((1, 1)), np.array([[1e6, 1e-4]])
    y1 = tr.solve_trajectory(np.zeros(41, int), means, vel, var, covariance_type="diag")
    y2 = tr.solve_trajectory(np.zeros(41, int), means, vel, var, covariance_type="diag",
                             model_fps=30.0, out_fps=60.0)
    assert y2.shape == (82, 1)
    assert np.diff(y1[:, 0])[20] == pytest.approx(1.0, rel=1e-6)
    assert np.diff(y2[:, 0])[40] == pytest.approx(0.5, rel=1e-6)


def test_resampling():
    np.testing.assert_array_equal(tr.resample_states([0, 1, 2], 10, 20), [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(tr.resample_states([0, 1, 2, 3], 20, 10), [0, 2])
    w = tr.resample_weights(np.eye(2), 1, 2)
    np.testing.assert_allclose(w, [[1, 0], [0.5, 0.5], [0, 1], [0, 1]])


@pytest.mark.parametrize("call,match", [
    (lambda m, v, c: tr.solve_trajectory([0, 3], m, v, c), r"states\[1\] = 3 is out of range"),
    (lambda m, v, c: tr.solve_trajectory([], m, v, c), "states is empty"),
    (lambda m, v, c: tr.solve_trajectory([[0]], m, v, c), "states must be 1-D"),
    (lambda m, v, c: tr.solve_trajectory([0.5], m, v, c), "integer state indices"),
    (lambda m, v, c: tr.solve_trajectory([0], m, v[:2], c), "vel_means must have the shape"),
    (lambda m, v, c: tr.solve_trajectory([0], m, v, c[:, :2]), "covars \\(full\\) must have shape"),
    (lambda m, v, c: tr.solve_trajectory([0], m, v, c, covariance_type="spherical"), "covariance_type"),
    (lambda m, v, c: tr.solve_trajectory([0], m * np.nan, v, c), "means contains NaN"),
    (lambda m, v, c: tr.solve_trajectory([0], m, v, -c), "not positive definite"),
    (lambda m, v, c: tr.solve_trajectory([0], m, v, c, out_fps=60), "model_fps"),
    (lambda m, v, c: tr.solve_trajectory([0], m, v, c, model_fps=-1), "model_fps must be a positive"),
    (lambda m, v, c: tr.solve_trajectory_weighted(np.ones((2, 2)), m, v, c), r"weights must have shape \(T, 3\)"),
    (lambda m, v, c: tr.solve_trajectory_weighted(np.zeros((2, 3)), m, v, c), "row 0 sums to zero"),
    (lambda m, v, c: tr.solve_trajectory_weighted(-np.ones((2, 3)), m, v, c), "non-negative"),
    (lambda m, v, c: tr.FixedLagTrajectory(m, v, c, -1), "lag must be"),
    (lambda m, v, c: tr.FixedLagTrajectory(m, v, c, 2).push_states([5]), "out of range"),
])
def test_bad_input_raises_value_error(call, match):
    rng = np.random.default_rng(SEED + 11)
    m, v, c = random_model(rng, 3, 2)
    with pytest.raises(ValueError, match=match):
        call(m, v, c)


def test_asymmetric_covariance_is_rejected():
    rng = np.random.default_rng(SEED + 12)
    m, v, c = random_model(rng, 2, 2)
    c[1, 0, 3] += 0.1
    with pytest.raises(ValueError, match="state 1 .* is not symmetric"):
        tr.solve_trajectory([0, 1], m, v, c)


def test_ill_conditioned_system_reports_condition_estimate():
    var = np.array([[1e10, 1e-6]])  # pose almost free, velocity pinned: the level is unidentified
    with pytest.raises(RuntimeError, match="condition estimate"):
        tr.solve_trajectory(np.zeros(50, int), np.zeros((1, 1)), np.zeros((1, 1)), var, covariance_type="diag")


def test_widen_motion_scales_each_coordinate_about_its_own_mean(rng):
    """Each coordinate's deviations from its mean are multiplied by its gain: the mean is kept,
    the standard deviation multiplied; gains outside [1, MAX_MOTION_GAIN] are refused."""
    from voicepuppet.trajectory import MAX_MOTION_GAIN, widen_motion

    Y = rng.normal(size=(200, 3)) * np.array([0.1, 0.5, 2.0]) + np.array([1.0, -2.0, 0.0])
    gain = np.array([1.0, 2.0, MAX_MOTION_GAIN])
    out = widen_motion(Y, gain)
    np.testing.assert_allclose(out.mean(axis=0), Y.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(out.std(axis=0), gain * Y.std(axis=0), rtol=1e-12)
    np.testing.assert_allclose(out[:, 0], Y[:, 0], atol=1e-15)
    np.testing.assert_allclose(out[5] - out[9], gain * (Y[5] - Y[9]), rtol=1e-12)  # no smoothing, no shift
    assert widen_motion(Y[:0], gain).shape == (0, 3)
    with pytest.raises(ValueError, match="one value per coordinate"):
        widen_motion(Y, gain[:2])
    for bad in (0.5, MAX_MOTION_GAIN + 0.1, np.nan):
        with pytest.raises(ValueError, match="every gain"):
            widen_motion(Y, np.array([1.0, 1.0, bad]))


def test_close_crossed_lips_meets_crossed_pairs_and_leaves_the_rest():
    from voicepuppet.layout import INNER_LIP_PAIRS, close_crossed_lips, neutral_landmarks

    face = neutral_landmarks()
    crossed = face.copy()
    up, lo = INNER_LIP_PAIRS[1]
    crossed[lo], crossed[up] = face[up] - [0, 3], face[lo] + [0, 3]  # the lower above the upper
    out = close_crossed_lips(np.stack([face, crossed]))
    np.testing.assert_array_equal(out[0], face)  # in order: untouched
    np.testing.assert_allclose(out[1, up], out[1, lo], atol=1e-9)  # crossed: met in the middle
    np.testing.assert_allclose(out[1, up] + out[1, lo], crossed[up] + crossed[lo], atol=1e-9)
    others = [i for i in range(68) if i not in (up, lo)]
    np.testing.assert_array_equal(out[1, others], crossed[others])
    with pytest.raises(ValueError, match="68-point"):
        close_crossed_lips(face[None, :10])
