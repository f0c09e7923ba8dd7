"""GaussianHMM against hmmlearn, brute force, textbook numbers and planted truth."""

import itertools

import numpy as np
import pytest

from voicepuppet import _core
from voicepuppet.hmm.gaussian import GaussianHMM

hmmlearn_hmm = pytest.importorskip("hmmlearn.hmm", reason="hmmlearn is a test dependency: pip install hmmlearn")


def random_model(rng, n, d, covariance="full", sparse=False):
    m = GaussianHMM(n, covariance)
    m.startprob_ = rng.dirichlet(np.ones(n))
    A = rng.dirichlet(np.ones(n), size=n)
    if sparse:
        A[rng.random((n, n)) < 0.5] = 0.0
        A[np.arange(n), np.arange(n)] += 0.2
        A /= A.sum(axis=1, keepdims=True)
    m.transmat_ = A
    m.means_ = rng.normal(0, 3, (n, d))
    if covariance == "full":
        B = rng.normal(0, 1, (n, d, d))
        m.covars_ = B @ B.transpose(0, 2, 1) + 0.5 * np.eye(d)
    else:
        m.covars_ = rng.uniform(0.3, 2.0, (n, d))
    return m


def to_hmmlearn(m, **kw):
    h = hmmlearn_hmm.GaussianHMM(m.n_states, covariance_type=m.covariance, init_params="",
                                 covars_prior=0.0, min_covar=0.0, **kw)
    h.startprob_ = m.startprob_.copy()
    h.transmat_ = m.transmat_.copy()
    h.means_ = m.means_.copy()
    h.covars_ = m.covars_.copy()
    return h


def rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)


@pytest.mark.parametrize("covariance", ["full", "diag"])
def test_inference_matches_hmmlearn(rng, covariance):
    m = random_model(rng, 5, 4, covariance)
    X, _ = m.sample(400, random_state=3)
    lengths = [150, 50, 200]
    h = to_hmmlearn(m)
    assert rel(m.score(X, lengths), h.score(X, lengths)) < 1e-10
    assert rel(m.log_density(X), h._compute_log_likelihood(X)) < 1e-10
    assert np.max(np.abs(m.predict_proba(X, lengths) - h.predict_proba(X, lengths))) < 1e-8
    lp, path = m.decode(X, lengths)
    hlp, hpath = h.decode(X, lengths, algorithm="viterbi")
    assert rel(lp, hlp) < 1e-10
    np.testing.assert_array_equal(path, hpath)


@pytest.mark.parametrize("covariance", ["full", "diag"])
def test_one_em_step_matches_hmmlearn(rng, covariance):
    m = random_model(rng, 4, 3, covariance)
    X, _ = m.sample(600, random_state=5)
    lengths = [300, 300]
    h = to_hmmlearn(m, n_iter=1, tol=-np.inf)
    h.fit(X, lengths)
    ours = GaussianHMM(4, covariance, n_iter=1, tol=-np.inf, min_covar=0.0, init_params="")
    for attr in ("startprob_", "transmat_", "means_", "covars_"):
        setattr(ours, attr, getattr(m, attr).copy())
    ours.fit(X, lengths)
    for attr in ("startprob_", "transmat_", "means_", "_covars_"):  # hmmlearn's raw covariances
        assert rel(getattr(ours, attr.lstrip("_")), getattr(h, attr)) < 1e-8, attr


def test_viterbi_and_likelihood_against_brute_force(rng):
    for trial in range(6):
        n, T = 2 + trial % 3, 1 + trial
        m = random_model(rng, n, 2, "full", sparse=bool(trial % 2))
        X, _ = m.sample(T, random_state=trial)
        log_b = m.log_density(X)
        best, best_path, total = -np.inf, None, []
        for path in itertools.product(range(n), repeat=T):
            with np.errstate(divide="ignore"):
                lp = np.log(m.startprob_[path[0]]) + log_b[0, path[0]]
                for t in range(1, T):
                    lp += np.log(m.transmat_[path[t - 1], path[t]]) + log_b[t, path[t]]
            total.append(lp)
            if lp > best:
                best, best_path = lp, path
        total = np.array(total)
        brute_ll = np.log(np.sum(np.exp(total[np.isfinite(total)])))
        assert m.score(X) == pytest.approx(brute_ll, rel=1e-12)
        lp, path = m.decode(X)
        assert lp == pytest.approx(best, rel=1e-12)
        assert tuple(path) == best_path


def test_umbrella_example_through_log_emission_entry():
    # Wikipedia "Forward-backward algorithm": smoothed P(rain) on days 1..5.
    A = np.array([[0.7, 0.3], [0.3, 0.7]])
    p_umbrella = np.array([0.9, 0.2])
    obs = [1, 1, 0, 1, 1]
    log_b = np.log(np.array([p_umbrella if o else 1 - p_umbrella for o in obs]))
    ll, gamma, xi, starts, _ = _core.forward_backward(log_b, np.array([0.5, 0.5]), A, np.array([5]))
    np.testing.assert_allclose(gamma[:, 0], [0.8673, 0.8204, 0.3075, 0.8204, 0.8673], atol=1e-4)
    _, path = _core.viterbi(log_b, np.array([0.5, 0.5]), A, np.array([5]))
    np.testing.assert_array_equal(path, [0, 0, 1, 0, 0])
    assert xi.sum() == pytest.approx(4.0)


def test_em_never_decreases_likelihood_and_recovers_planted_model(rng):
    truth = random_model(rng, 3, 2, "full")
    truth.means_ = np.array([[0.0, 0.0], [6.0, 0.0], [0.0, 6.0]])
    truth.transmat_ = np.array([[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]])
    X, states = truth.sample(6000, random_state=11)
    m = GaussianHMM(3, "full", n_iter=100, tol=1e-8, random_state=2).fit(X, [3000, 3000])
    lls = np.array([h["log_likelihood"] for h in m.history_])
    assert np.all(np.diff(lls) >= -1e-8 * np.abs(lls[1:]))
    order = [int(np.argmin(np.linalg.norm(m.means_ - mu, axis=1))) for mu in truth.means_]
    assert sorted(order) == [0, 1, 2]
    np.testing.assert_allclose(m.means_[order], truth.means_, atol=0.15)
    np.testing.assert_allclose(m.transmat_[np.ix_(order, order)], truth.transmat_, atol=0.03)
    np.testing.assert_allclose(m.covars_[order], truth.covars_, rtol=0.15, atol=0.1)
    to_true = np.argsort(order)  # fitted state -> planted state
    assert np.mean(to_true[m.predict(X, [3000, 3000])] == states) > 0.97


def test_fit_is_deterministic_for_a_seed(rng):
    X = rng.normal(size=(500, 3))
    a = GaussianHMM(4, "full", n_iter=5, random_state=7).fit(X)
    b = GaussianHMM(4, "full", n_iter=5, random_state=7).fit(X)
    np.testing.assert_array_equal(a.means_, b.means_)
    np.testing.assert_array_equal(a.covars_, b.covars_)
    x1, s1 = a.sample(50, random_state=3)
    x2, s2 = a.sample(50, random_state=3)
    np.testing.assert_array_equal(x1, x2)
    np.testing.assert_array_equal(s1, s2)


def test_sampling_matches_the_model_statistics(rng):
    m = random_model(rng, 2, 2, "full")
    m.transmat_ = np.array([[0.95, 0.05], [0.1, 0.9]])
    X, s = m.sample(40000, random_state=1)
    counts = np.zeros((2, 2))
    np.add.at(counts, (s[:-1], s[1:]), 1)
    np.testing.assert_allclose(counts / counts.sum(1, keepdims=True), m.transmat_, atol=0.01)
    for k in range(2):
        np.testing.assert_allclose(np.cov(X[s == k].T), m.covars_[k], rtol=0.08, atol=0.05)


def test_no_underflow_on_long_peaked_sequences(rng):
    m = random_model(rng, 4, 10, "full", sparse=True)
    X, _ = m.sample(5000, random_state=0)
    X = X * 30.0  # emissions of ~ -1e5 nats: linear-space densities would underflow
    ll_scaled = _core.forward_backward(m.log_density(X), m.startprob_, m.transmat_, np.array([5000]))[0]
    ll_log = _core.forward_backward(m.log_density(X), m.startprob_, m.transmat_, np.array([5000]),
                                    implementation="log")[0]
    assert np.isfinite(ll_scaled)
    assert ll_scaled == pytest.approx(ll_log, rel=1e-12)


def left_to_right_jump(n=5, d=2, early=10, late=100, spacing=100.0, seed=0):
    """Issue 2: a left-to-right model, `early` frames at the first state's mean, then `late`
    frames at the last state's, thousands of nats too early for the states in between."""
    m = GaussianHMM(n, "diag")
    m.startprob_ = np.eye(n)[0]
    A = 0.9 * np.eye(n) + 0.1 * np.eye(n, k=1)
    A[-1, -1] = 1.0
    m.transmat_ = A
    m.means_ = spacing * np.arange(n)[:, None] * np.ones((1, d))
    m.covars_ = np.ones((n, d))
    r = np.random.default_rng(seed)
    X = np.vstack([r.normal(m.means_[0], 1.0, (early, d)), r.normal(m.means_[-1], 1.0, (late, d))])
    return m, X


def hmmlearn_log_lattices(log_b, startprob, transmat):
    """hmmlearn's own log-space passes (its compiled forward_log / backward_log / log ξ sum)."""
    from hmmlearn import _hmmc
    ll, la = _hmmc.forward_log(startprob, transmat, log_b)
    lbeta = _hmmc.backward_log(startprob, transmat, log_b)
    log_xi = _hmmc.compute_log_xi_sum(la, transmat, lbeta, log_b)
    return ll, np.exp(la + lbeta - ll), np.exp(log_xi)


def test_a_state_far_below_the_others_is_not_lost(rng):
    # Issue 2: the scaled forward pass lost the later states for good (-2.7e6 instead of -2.7e5).
    m, X = left_to_right_jump()
    h = to_hmmlearn(m)
    assert rel(m.score(X), h.score(X)) < 1e-10
    lp, _ = m.decode(X)
    assert lp <= m.score(X) <= lp + 4 * np.log(len(X))  # Viterbi bounds log p(x), independently
    assert np.max(np.abs(m.predict_proba(X) - h.predict_proba(X))) < 1e-10
    for lengths in (None, [40, 1, 69], [10, 100]):
        ll_ref = h.score(X, lengths)
        assert rel(m.score(X, lengths), ll_ref) < 1e-10
        fast = _core.forward_backward(m.log_density(X), m.startprob_, m.transmat_,
                                      np.array(lengths or [len(X)]))
        log = _core.forward_backward(m.log_density(X), m.startprob_, m.transmat_,
                                     np.array(lengths or [len(X)]), implementation="log")
        assert rel(fast[0], log[0]) < 1e-12
        # The reference's exp(log α + log β − ll) carries the rounding of lattice entries of
        # ~|ll| nats (here up to 5.2e5, whose ulp is 5.8e-11; 1.2e-10 seen on an AMD EPYC), as in
        # the C++ test's check.
        rtol = 1e-10 * max(1.0, abs(log[0]) / 1e5)
        for a, b in zip(fast[1:], log[1:]):
            np.testing.assert_allclose(a, b, rtol=rtol, atol=1e-300)


@pytest.mark.parametrize("spacing", [3.0, 30.0, 100.0, 1000.0])
def test_posteriors_and_counts_equal_hmmlearn_log_space_in_every_regime(spacing):
    m, X = left_to_right_jump(n=6, early=15, late=60, spacing=spacing, seed=1)
    log_b = m.log_density(X)
    ll, post, xi, starts, _ = _core.forward_backward(log_b, m.startprob_, m.transmat_, np.array([len(X)]))
    hll, hpost, hxi = hmmlearn_log_lattices(log_b, m.startprob_, m.transmat_)
    assert rel(ll, hll) < 1e-10
    np.testing.assert_allclose(post, hpost, rtol=1e-8, atol=1e-12)
    # Every expected count, even one of 1e-200, to 1e-8 of itself: a count lost to zero would
    # prune its arc for good in EM.
    np.testing.assert_allclose(xi, hxi, rtol=1e-8, atol=1e-300)


def test_em_step_on_the_jump_matches_hmmlearn():
    m, X = left_to_right_jump(n=5, early=20, late=80, spacing=60.0, seed=2)
    X = np.vstack([X, X[::-1]])
    lengths = [100, 100]
    h = to_hmmlearn(m, n_iter=1, tol=-np.inf)
    h.fit(X, lengths)
    ours = GaussianHMM(5, "diag", n_iter=1, tol=-np.inf, min_covar=0.0, init_params="")
    for attr in ("startprob_", "transmat_", "means_", "covars_"):
        setattr(ours, attr, getattr(m, attr).copy())
    ours.fit(X, lengths)
    for attr in ("startprob_", "transmat_", "means_", "_covars_"):
        assert rel(getattr(ours, attr.lstrip("_")), getattr(h, attr)) < 1e-8, attr


@pytest.mark.parametrize("bad, message", [
    (lambda m, X: m.score(X[:, :2]), "dimensions"),
    (lambda m, X: m.score(np.where(np.arange(X.size).reshape(X.shape) == 7, np.nan, X)), "NaN"),
    (lambda m, X: m.score(X, lengths=[10, 10]), "lengths sum to 20"),
    (lambda m, X: m.score(X, lengths=[100, 0]), "positive"),
    (lambda m, X: m.score(X[:0]), "zero frames"),
    (lambda m, X: m.score(X[:, 0]), "2-D"),
])
def test_bad_input_gives_clear_value_errors(rng, bad, message):
    m = random_model(rng, 3, 3, "full")
    X, _ = m.sample(100, random_state=0)
    with pytest.raises(ValueError, match=message):
        bad(m, X)


def test_random_frame_start_draws_distinct_training_frames_per_seed(rng):
    X = rng.normal(size=(300, 2))
    starts = []
    for seed in (4, 4, 5):
        m = GaussianHMM(6, "full", n_iter=0, random_state=seed, init="frames")
        m.initialize(X)
        rows = [int(np.flatnonzero(np.all(X == mu, axis=1))[0]) for mu in m.means_]  # each mean is a frame
        assert len(set(rows)) == 6
        starts.append(m.means_)
    np.testing.assert_array_equal(starts[0], starts[1])
    assert not np.array_equal(starts[0], starts[2])
    km = GaussianHMM(6, "full", n_iter=0, random_state=4)
    km.initialize(X)
    assert not any(np.all(X == mu, axis=1).any() for mu in km.means_)  # k-means means are averages
    # EM from random starts (which can stick: one state over two clusters) finds a planted model
    # of well-separated states in the best of a few seeds, its likelihood never decreasing (no
    # variance floor: plain EM)
    truth = random_model(rng, 3, 2, "full")
    truth.means_ = np.array([[0.0, 0.0], [6.0, 0.0], [0.0, 6.0]])
    truth.covars_ = np.tile(0.3 * np.eye(2), (3, 1, 1))
    Y, states = truth.sample(3000, random_state=11)
    fits = [GaussianHMM(3, "full", n_iter=100, tol=1e-8, min_covar=0.0, random_state=s, init="frames").fit(Y)
            for s in range(5)]
    for f in fits:
        lls = np.array([h["log_likelihood"] for h in f.history_])
        assert np.all(np.diff(lls) >= -1e-8 * np.abs(lls[1:]))
    fit = max(fits, key=lambda f: f.score(Y))
    order = [int(np.argmin(np.linalg.norm(fit.means_ - mu, axis=1))) for mu in truth.means_]
    np.testing.assert_allclose(fit.means_[order], truth.means_, atol=0.2)
    with pytest.raises(ValueError, match="init must be"):
        GaussianHMM(3, init="random")


def test_bad_parameters_are_named(rng):
    m = random_model(rng, 3, 3, "full")
    X, _ = m.sample(20, random_state=0)
    m.transmat_ = m.transmat_ * 1.1
    with pytest.raises(ValueError, match="transmat_ rows must sum to 1"):
        m.score(X)
    m = random_model(rng, 3, 3, "full")
    m.covars_[1] = np.diag([1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=r"covars\[1\] is not positive definite"):
        m.score(X)
    with pytest.raises(ValueError, match="covariance"):
        GaussianHMM(3, "spherical")
    with pytest.raises(ValueError, match="frames cannot initialise"):
        GaussianHMM(30).fit(X)
    with pytest.raises(ValueError, match="singular"):
        GaussianHMM(2, min_covar=0.0).fit(np.column_stack([X[:, 0], X[:, 0]]))


# ----------------------------------------------------------------- float32 screening (full covariance)

def screening_model(rng, n, d, *, spread, cond=10.0, left_to_right=False, stay=0.9):
    """Sticky full-covariance model whose means lie `spread` apart (in units of the noise)
    and whose covariances have condition number `cond`."""
    m = GaussianHMM(n, "full")
    m.startprob_ = np.full(n, 1.0 / n)
    if left_to_right:
        A = np.eye(n) * stay + np.eye(n, k=1) * (1 - stay)
        A[-1, -1] = 1.0
        m.startprob_ = np.eye(n)[0]
    else:
        A = rng.dirichlet(np.ones(n), size=n) * (1 - stay) + np.eye(n) * stay
    m.transmat_ = A
    m.means_ = rng.normal(0.0, spread / np.sqrt(d), (n, d))
    covs = []
    for _ in range(n):
        Q, _ = np.linalg.qr(rng.normal(size=(d, d)))
        covs.append((Q * np.geomspace(1.0, 1.0 / cond, d)) @ Q.T)
    m.covars_ = np.array(covs)
    return m


def exact_twin(m):
    e = GaussianHMM(m.n_states, m.covariance, exact=True)
    for attr in ("startprob_", "transmat_", "means_", "covars_"):
        setattr(e, attr, getattr(m, attr).copy())
    return e


def screened_vs_exact(m, X, lengths):
    """The screened answers against the all-double ones; returns the screening info."""
    e = exact_twin(m)
    assert m.score(X, lengths) == pytest.approx(e.score(X, lengths), rel=1e-12, abs=0)
    lp, path = m.decode(X, lengths)
    elp, epath = e.decode(X, lengths)
    assert lp == pytest.approx(elp, rel=1e-12, abs=0)
    np.testing.assert_array_equal(path, epath)
    ll, gamma = m.score_samples(X, lengths)
    ell, egamma = e.score_samples(X, lengths)
    assert ll == pytest.approx(ell, rel=1e-12, abs=0)
    assert np.max(np.abs(gamma - egamma)) < 1e-10
    args = (X, np.asarray(lengths, dtype=np.int64), m.startprob_, m.transmat_, m.means_,
            m.covars_2d(), "full")
    return {"score": _core.gaussian_hmm_score(*args)[1], "decode": _core.gaussian_hmm_decode(*args)[2],
            "posteriors": _core.gaussian_hmm_posteriors(*args)[5]}


def test_float32_screening_bound_holds_where_float32_is_poor(rng):
    d = 24
    cases = {
        "well separated": (screening_model(rng, 6, d, spread=30.0), 0.0),
        "ill-conditioned covariances": (screening_model(rng, 6, d, spread=30.0, cond=1e7), 0.0),
        "data far from the origin": (screening_model(rng, 6, d, spread=30.0), 1e5),
    }
    for name, (m, offset) in cases.items():
        X, _ = m.sample(800, random_state=1)
        m.means_ = m.means_ + offset
        X = X + offset
        est, bound = _core.gaussian_log_density_screened(X, m.means_, m.covars_2d())
        exact = m.log_density(X)
        assert np.all(np.abs(est - exact) <= bound), name
        # the bound is not vacuous: within a few hundred times the real error at the top entries
        top = exact.argmax(axis=1)
        rows = np.arange(len(X))
        assert np.median(bound[rows, top]) < 1e-2 * np.median(np.abs(exact[rows, top])) + 1.0, name
    # float32 overflow is flagged, not trusted
    m = screening_model(rng, 3, d, spread=5.0)
    X, _ = m.sample(50, random_state=2)
    X[7] = 1e30
    est, bound = _core.gaussian_log_density_screened(X, m.means_, m.covars_2d())
    assert np.all(np.isinf(bound[7]))
    assert np.all(np.isfinite(bound[np.arange(50) != 7]))


def test_screened_inference_equals_all_double_on_separated_states(rng):
    m = screening_model(rng, 20, 16, spread=40.0)
    X, _ = m.sample(6000, random_state=3)
    lengths = [2500, 500, 3000]
    info = screened_vs_exact(m, X, lengths)
    for what, i in info.items():  # the screening really skipped most double evaluations
        assert not i["all_double"], what
        assert i["refined"] < 0.2 * i["entries"], what


def test_screened_inference_equals_all_double_when_transitions_overrule_emissions(rng):
    # left-to-right: the best-emitting state is often unreachable, so the first refinement
    # (near each frame's best emission) misses the states the lattice needs; more rounds follow
    m = screening_model(rng, 8, 12, spread=25.0, left_to_right=True, stay=0.995)
    X, _ = m.sample(3000, random_state=4)
    X[1500:1510] = 0.4 * X[1500:1510] + 0.6 * m.means_[7]  # looks like the last state, too early
    info = screened_vs_exact(m, X, [3000])
    for what, i in info.items():
        assert i["rounds"] >= 2 and not i["all_double"], what
    assert rel(m.score(X), to_hmmlearn(m).score(X)) < 1e-10


@pytest.mark.parametrize("case", ["overlapping states", "ill-conditioned", "far offset", "long and many"])
def test_screened_inference_equals_all_double_in_hard_cases(rng, case):
    if case == "overlapping states":  # posteriors dense: falls back to all-double
        m = screening_model(rng, 10, 10, spread=0.5)
        X, _ = m.sample(2000, random_state=5)
        info = screened_vs_exact(m, X, [2000])
        assert info["score"]["all_double"]
    elif case == "ill-conditioned":
        m = screening_model(rng, 8, 20, spread=20.0, cond=1e8)
        X, _ = m.sample(2000, random_state=6)
        screened_vs_exact(m, X, [1000, 1000])
    elif case == "far offset":
        m = screening_model(rng, 8, 20, spread=20.0)
        X, _ = m.sample(2000, random_state=7)
        m.means_ = m.means_ + 3e4
        screened_vs_exact(m, X + 3e4, [2000])
    else:
        m = screening_model(rng, 32, 12, spread=30.0, stay=0.6)
        X, _ = m.sample(20000, random_state=8)
        info = screened_vs_exact(m, X, [5000] * 4)
        assert info["score"]["refined"] < 0.2 * info["score"]["entries"]


def test_screened_inference_matches_hmmlearn(rng):
    m = screening_model(rng, 10, 16, spread=20.0)
    X, _ = m.sample(3000, random_state=9)
    h = to_hmmlearn(m)
    assert rel(m.score(X), h.score(X)) < 1e-10
    lp, path = m.decode(X)
    hlp, hpath = h.decode(X, algorithm="viterbi")
    assert rel(lp, hlp) < 1e-10
    np.testing.assert_array_equal(path, hpath)
    assert np.max(np.abs(m.predict_proba(X) - h.predict_proba(X))) < 1e-8


def test_screened_em_equals_all_double_em_and_hmmlearn(rng):
    m = screening_model(rng, 8, 12, spread=15.0)
    X, _ = m.sample(4000, random_state=10)
    lengths = [2000, 2000]
    fits = {}
    for exact in (False, True):
        f = GaussianHMM(8, "full", n_iter=3, tol=-np.inf, min_covar=0.0, init_params="", exact=exact)
        for attr in ("startprob_", "transmat_", "means_", "covars_"):
            setattr(f, attr, getattr(m, attr).copy())
        fits[exact] = f.fit(X, lengths)
    for attr in ("startprob_", "transmat_", "means_", "covars_"):
        assert rel(getattr(fits[False], attr), getattr(fits[True], attr)) < 1e-10, attr
    h = to_hmmlearn(m, n_iter=3, tol=-np.inf)
    h.fit(X, lengths)
    for attr in ("startprob_", "transmat_", "means_", "_covars_"):
        assert rel(getattr(fits[False], attr.lstrip("_")), getattr(h, attr)) < 1e-8, attr
    stats = fits[False].estep(X, lengths)
    assert not stats["screening"]["all_double"]


def test_sparse_outer_statistics_equal_the_dense_sums(rng):
    T, n, d = 3000, 6, 5
    X = rng.normal(size=(T, d)) * 3 + 1.0
    logits = rng.normal(size=(T, n)) * 25  # very peaked posteriors: most γ ≈ 0
    post = np.exp(logits - logits.max(axis=1, keepdims=True))
    post /= post.sum(axis=1, keepdims=True)
    shift = X.mean(axis=0)
    weight, ssum, outer = _core.gaussian_stats(X, post, shift, "full")
    Xs = X - shift
    dense = np.einsum("tn,ti,tj->nij", post, Xs, Xs).reshape(n * d, d)
    assert rel(outer, dense) < 1e-12
    np.testing.assert_allclose(weight, post.sum(axis=0), rtol=1e-13)
    assert (post < 1e-15).mean() > 0.3  # frames were actually skipped


def test_screened_fit_is_deterministic_for_a_seed(rng):
    m = screening_model(rng, 6, 12, spread=20.0)
    X, _ = m.sample(2000, random_state=12)
    a = GaussianHMM(6, "full", n_iter=4, random_state=3).fit(X)
    b = GaussianHMM(6, "full", n_iter=4, random_state=3).fit(X[:, :].copy())
    np.testing.assert_array_equal(a.means_, b.means_)
    np.testing.assert_array_equal(a.covars_, b.covars_)
    assert [h["log_likelihood"] for h in a.history_] == [h["log_likelihood"] for h in b.history_]
