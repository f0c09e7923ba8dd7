"""Test-time adaptation of the vocal features (``Puppet.animate(adapt=...)``, adapt.hpp): the C++
kernel against a plain numpy reference of the same EM (its own log densities and log-space
forward-backward), a planted speaker undone through the puppet, τ = ∞ bit-identical to no
adaptation, the command-line switch, and bad values refused."""
import numpy as np
import pytest
from scipy.special import logsumexp

from voicepuppet import _core
from voicepuppet.puppet.model import ADAPT_DEFAULTS, Puppet


# ----------------------------------------------------------------------- numpy reference
def _log_density(z, means, covs):
    out = np.empty((len(z), len(means)))
    for i, (m, c) in enumerate(zip(means, covs)):
        L = np.linalg.cholesky(c)
        u = np.linalg.solve(L, (z - m).T)
        out[:, i] = -0.5 * (len(m) * np.log(2 * np.pi) + 2 * np.log(np.diag(L)).sum() + (u * u).sum(0))
    return out


def _forward_backward(lb, sp, tm):
    T, N = lb.shape
    la, lbt = np.empty((T, N)), np.zeros((T, N))
    with np.errstate(divide="ignore"):
        ltm, lsp = np.log(tm), np.log(sp)
    la[0] = lsp + lb[0]
    for t in range(1, T):
        la[t] = logsumexp(la[t - 1][:, None] + ltm, axis=0) + lb[t]
    for t in range(T - 2, -1, -1):
        lbt[t] = logsumexp(ltm + (lb[t + 1] + lbt[t + 1])[None, :], axis=1)
    ll = logsumexp(la[-1])
    return ll, np.exp(la + lbt - ll)


def _prior(W, means, covs, pi, tau):
    A, b = W[:, 1:], W[:, 0]
    d = len(b)
    tot = tau * np.log(abs(np.linalg.det(A)))
    for i in np.flatnonzero(pi):
        P = np.linalg.inv(covs[i])
        m = A @ means[i] + b - means[i]
        e = -0.5 * (d * np.log(2 * np.pi) + np.linalg.slogdet(covs[i])[1]
                    + np.trace(P @ A @ covs[i] @ A.T) + m @ P @ m)
        tot += tau * pi[i] * e
    return tot


def reference_adapt(z, means, covs, sp, tm, tau, n_iter, sweeps=3):
    """The EM of adapt.hpp written plainly: returns (A, b, penalised log-likelihoods)."""
    T, d = z.shape
    prec = np.linalg.inv(covs)
    W = np.hstack([np.zeros((d, 1)), np.eye(d)])
    xi = np.hstack([np.ones((T, 1)), z])
    hist, pi = [], None
    for it in range(n_iter + 1):
        ll, g = _forward_backward(_log_density(xi @ W.T, means, covs), sp, tm)
        if pi is None:
            pi = g.sum(0) / T
        hist.append(ll + T * np.log(abs(np.linalg.det(W[:, 1:]))) + _prior(W, means, covs, pi, tau))
        if it == n_iter:
            break
        w0 = tau * pi
        n = g.sum(0) + w0
        ext = np.hstack([np.ones((len(means), 1)), means])
        s = g.T @ xi + w0[:, None] * ext
        G = np.einsum("ti,tj,tk->ijk", g, xi, xi) + w0[:, None, None] * np.einsum("ij,ik->ijk", ext, ext)
        G[:, 1:, 1:] += w0[:, None, None] * covs
        beta = n.sum()
        for _ in range(sweeps):
            for r in range(d):
                Gr = np.einsum("i,ijk->jk", prec[:, r, r], G)
                k = np.zeros(d + 1)
                for i in range(len(means)):
                    v = sum(prec[i, r, q] * W[q] for q in range(d) if q != r)
                    k += (prec[i] @ means[i])[r] * s[i] - G[i] @ v
                c = np.zeros(d + 1)
                c[1:] = np.linalg.inv(W[:, 1:])[:, r]
                gk, gc = np.linalg.solve(Gr, k), np.linalg.solve(Gr, c)
                e1, e2 = c @ gc, c @ gk
                disc = np.sqrt(e2 ** 2 + 4 * e1 * beta)
                cands = [a * gc + gk for a in ((-e2 + disc) / (2 * e1), (-e2 - disc) / (2 * e1))]
                W[r] = max(cands, key=lambda w: beta * np.log(abs(c @ w)) - 0.5 * w @ Gr @ w + k @ w)
    return W[:, 1:], W[:, 0], np.array(hist)


def _hmm(rng, N=4, d=3):
    means = rng.normal(0, 2.5, (N, d))
    L = rng.normal(0, 0.3, (N, d, d))
    covs = L @ L.transpose(0, 2, 1) + 0.5 * np.eye(d)
    tm = np.full((N, N), 0.1 / (N - 1))
    np.fill_diagonal(tm, 0.9)
    return means, covs, np.full(N, 1.0 / N), tm


@pytest.mark.parametrize("tau, n_iter", [(20.0, 3), (2.0, 1)])
def test_kernel_equals_the_numpy_reference(tau, n_iter):
    rng = np.random.default_rng(5)
    means, covs, sp, tm = _hmm(rng)
    X, _ = _core.gaussian_hmm_sample(sp, tm, means, covs.reshape(-1, 3), "full", 150, 3)
    z = (X - [0.5, -0.2, 0.3]) @ np.linalg.inv([[1.1, 0.2, 0], [0, 0.9, 0.1], [0.1, 0, 1.2]]).T
    A, b, hist = reference_adapt(z, means, covs, sp, tm, tau, n_iter)
    r = _core.adapt_features(np.ascontiguousarray(z), np.zeros(0, np.int64), means, covs.reshape(-1, 3),
                             "full", sp, tm, "full", tau, n_iter, 3)
    np.testing.assert_allclose(r["A"], A, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r["b"], b, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r["log_likelihood"], hist, rtol=1e-10)
    assert np.all(np.diff(hist) >= -1e-9 * abs(hist[0])) and hist[-1] > hist[0]


def test_diagonal_covariances_are_adapted_as_their_full_matrices():
    rng = np.random.default_rng(6)
    means, covs, sp, tm = _hmm(rng)
    var = np.abs(rng.normal(1, 0.2, (4, 3)))
    z = means[rng.integers(0, 4, 120)] * 1.1 + rng.normal(0, 0.8, (120, 3))
    none = np.zeros(0, np.int64)
    d = _core.adapt_features(z, none, means, var, "diag", sp, tm, "full", 10.0, 2, 3)
    f = _core.adapt_features(z, none, means, np.stack([np.diag(v) for v in var]).reshape(-1, 3), "full",
                             sp, tm, "full", 10.0, 2, 3)
    np.testing.assert_allclose(d["A"], f["A"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(d["b"], f["b"], rtol=0, atol=1e-12)


# ------------------------------------------------------------------- through the puppet
def _performer(rng, T, voice=None):
    """Three facial states visited in runs; the audio (5 columns) says which one. ``voice``
    (M, c) plants a speaker: the features heard are M⁻¹ (x − c) of the performer's x."""
    P = 12
    ang = np.linspace(0, 2 * np.pi, P, endpoint=False)
    base = np.stack([np.cos(ang), np.sin(ang)], axis=1) * 50 + 160
    modes = np.zeros((3, P, 2))
    modes[1, P // 4, 1] = 25.0
    modes[2, :, 0] = (base[:, 0] - 160) * -0.3
    states = np.repeat(rng.integers(0, 3, T // 15), 15)[:T]
    pts = base + modes[states] + rng.normal(0, 0.3, (T, P, 2))
    audio_means = np.random.default_rng(1).normal(0, 2, (3, 5))
    x = audio_means[states] + rng.normal(0, 1.0, (T, 5))
    if voice is not None:
        M, c = voice
        x = (x - c) @ np.linalg.inv(M).T
    return pts, x, states


VOICE = (np.eye(5) + np.diag([0.3, -0.2, 0.25, 0.0, -0.15]) + 0.1 * np.eye(5, k=1),
         np.array([1.5, -1.0, 0.8, 1.2, -0.7]))


@pytest.fixture(scope="module")
def puppet():
    pts, x, _ = _performer(np.random.default_rng(7), 900)
    # guide="none": adaptation transforms the vocal features only, not the guide's input (the
    # planted speaker would still reach the face through the guide's ridge)
    return Puppet.train([pts], features_list=[x], fps=30.0, n_states=6, n_iter=20, n_components=3,
                        audio_deltas=0, guide="none")


@pytest.fixture(scope="module")
def guided():
    """The same performance trained with the default guide (the ridge's ŷ in the solve) at a
    fixed λ = 4 (cross-validation chooses 0 for this performer, whose states the audio names)."""
    pts, x, _ = _performer(np.random.default_rng(7), 900)
    return Puppet.train([pts], features_list=[x], fps=30.0, n_states=6, n_iter=20, n_components=3,
                        audio_deltas=0, guide_weight=4.0)


def _purity(decoded, states):
    return sum(np.bincount(states[decoded == s]).max() for s in np.unique(decoded)) / len(states)


def test_a_planted_speaker_is_undone_and_the_states_recovered(puppet):
    pts, heard, states = _performer(np.random.default_rng(8), 900, VOICE)
    _, performer, _ = _performer(np.random.default_rng(8), 900)  # the same frames, undistorted
    clean = puppet.animate(features=performer)
    plain = puppet.animate(features=heard)
    r = puppet.animate(features=heard, adapt="full", adapt_tau=5.0, adapt_iter=8)
    assert _purity(plain.states[:, 0], states) < 0.9
    assert _purity(r.states[:, 0], states) >= _purity(clean.states[:, 0], states) - 0.005
    truth, _ = puppet.face_space.encode(pts)

    def err(a):
        return np.sum((a.face - truth) ** 2) / np.sum((truth - truth.mean(0)) ** 2)

    assert err(plain) > 0.3 and err(r) < err(clean) + 0.01
    # The transform found is the planted one in the standardised space z = (x − m) / s:
    # A z_heard + b = z_performer.
    m, s = puppet.arrays["audio/mean"], puppet.arrays["audio/std"]
    M, c = VOICE
    A_true = np.diag(1 / s) @ M @ np.diag(s)
    b_true = (M @ m + c - m) / s
    (t,) = r.transforms
    # The scales and the shift are found; the off-diagonal entries only roughly (a rotation of
    # the states' round noise is invisible, and three sounds pin five columns down only so far).
    np.testing.assert_allclose(np.diag(t["A"]), np.diag(A_true), atol=0.06)
    assert np.linalg.norm(t["b"] - b_true) < 0.3 * np.linalg.norm(b_true)
    assert np.abs(t["A"] - A_true).max() < 0.2
    assert np.all(np.diff(t["log_likelihood"]) >= -1e-9 * abs(t["log_likelihood"][0]))
    assert plain.transforms == []


def test_infinite_tau_is_no_adaptation_bit_for_bit(puppet):
    _, heard, _ = _performer(np.random.default_rng(9), 300, VOICE)
    for posterior in (False, True):
        plain = puppet.animate(features=heard, posterior=posterior)
        inf = puppet.animate(features=heard, posterior=posterior, adapt="full", adapt_tau=np.inf)
        np.testing.assert_array_equal(inf.face, plain.face)
        np.testing.assert_array_equal(inf.states, plain.states)
        assert inf.log_likelihood == plain.log_likelihood
        np.testing.assert_array_equal(inf.transforms[0]["A"], np.eye(5))


def test_log_likelihood_is_the_inputs_under_the_adapted_model(puppet):
    # Posterior synthesis reports log p(z) under the adapted model: the forward pass on A z + b
    # plus T log|det A|, i.e. the EM's last penalised value less its prior term.
    _, heard, _ = _performer(np.random.default_rng(10), 240, VOICE)
    r = puppet.animate(features=heard, posterior=True, adapt="full", adapt_tau=15.0, adapt_iter=3)
    arr = puppet.part_arrays(0)
    means, covs, sp, tm = arr["vocal_means"], arr["vocal_covars"], arr["startprob"], arr["transmat"]
    z = puppet._core.standardize(heard)
    _, g = _forward_backward(_log_density(z, means, covs), sp, tm)
    (t,) = r.transforms
    W = np.hstack([t["b"][:, None], t["A"]])
    ll, _ = _forward_backward(_log_density(z @ t["A"].T + t["b"], means, covs), sp, tm)
    want = ll + len(z) * np.log(abs(np.linalg.det(t["A"])))
    assert r.log_likelihood == pytest.approx(want, rel=1e-10)
    assert t["log_likelihood"][-1] == pytest.approx(want + _prior(W, means, covs, g.mean(0), 15.0), rel=1e-10)


def test_each_face_part_adapts_to_its_own_vocal_model():
    pts, x, _ = _performer(np.random.default_rng(7), 900)
    p = Puppet.train([pts], features_list=[x], fps=30.0, n_states=5, n_iter=10, n_components=2,
                     audio_deltas=0, parts={"upper": range(0, 6), "lower": range(6, 12)})
    _, heard, _ = _performer(np.random.default_rng(8), 300, VOICE)
    r = p.animate(features=heard, adapt="full", adapt_tau=10.0, adapt_iter=2)
    assert len(r.transforms) == 2
    z = p._core.standardize(heard)
    for k, t in enumerate(r.transforms):
        arr = p.part_arrays(k)
        ref = _core.adapt_features(z, np.zeros(0, np.int64), arr["vocal_means"],
                                   arr["vocal_covars"].reshape(-1, z.shape[1]), "full", arr["startprob"],
                                   arr["transmat"], "full", 10.0, 2)
        np.testing.assert_array_equal(t["A"], ref["A"])
        lb = _core.gaussian_log_density(z @ t["A"].T + t["b"], arr["vocal_means"],
                                        arr["vocal_covars"].reshape(-1, z.shape[1]), "full")
        np.testing.assert_array_equal(r.states[:, k], _core.viterbi(lb, arr["startprob"], arr["transmat"],
                                                                    np.zeros(0, np.int64))[1])


def test_defaults_and_bad_values(puppet):
    _, heard, _ = _performer(np.random.default_rng(9), 60)
    r = puppet.animate(features=heard, adapt="full")
    assert len(r.transforms[0]["log_likelihood"]) == ADAPT_DEFAULTS["n_iter"] + 1
    with pytest.raises(ValueError, match="adapt must be None or 'full', got 'bias'"):
        puppet.animate(features=heard, adapt="bias")
    with pytest.raises(ValueError, match="tau"):
        puppet.animate(features=heard, adapt="full", adapt_tau=0.0)
    with pytest.raises(ValueError, match="tau"):
        puppet.animate(features=heard, adapt="full", adapt_tau=float("nan"))
    with pytest.raises(ValueError, match="n_iter"):
        puppet.animate(features=heard, adapt="full", adapt_iter=0)
    with pytest.raises(ValueError, match="adapt_iter must be an integer"):
        puppet.animate(features=heard, adapt="full", adapt_iter=1.5)
    with pytest.raises(ValueError, match="given states are not decoded"):
        puppet.animate(states=np.zeros(10, np.int64), adapt="full")


# ------------------------------------------------------------------------ command line
def test_animate_switch_and_live_refuses(tmp_path, capsys):
    import soundfile as sf

    from voicepuppet.cli.main import main

    rng = np.random.default_rng(3)
    fps, rate, P = 25.0, 16000, 10
    ang = np.linspace(0, 2 * np.pi, P, endpoint=False)
    base = np.stack([np.cos(ang), np.sin(ang)], axis=1) * 40 + 120
    shapes = np.stack([base, base * [1.0, 1.3] - [0, 36], base * [0.7, 1.0] + [36, 0]])

    def performance(T, pitch=1.0):
        states = np.repeat(rng.integers(0, 3, T // 10 + 1), 10)[:T]
        t = np.arange(int(round(T / fps * rate))) / rate
        tone = np.array([220.0, 700.0, 1800.0])[states[np.minimum((t * fps).astype(int), T - 1)]] * pitch
        audio = 0.3 * np.sin(2 * np.pi * tone * t) + 0.003 * rng.normal(size=len(t))
        return shapes[states] + rng.normal(0, 0.2, (T, P, 2)), audio

    pts, audio = performance(500)
    sf.write(tmp_path / "train.wav", audio, rate)
    sf.write(tmp_path / "test.wav", performance(150, pitch=1.1)[1], rate)
    p = Puppet.train([pts], [str(tmp_path / "train.wav")], fps=fps, n_states=6, n_iter=10)
    p.save(tmp_path / "p.vpp")
    args = ["animate", str(tmp_path / "p.vpp"), str(tmp_path / "test.wav"), "--quiet", "-o"]
    assert main(args + [str(tmp_path / "a.npz"), "--adapt", "full", "--adapt-tau", "50", "--adapt-iter", "2"]) == 0
    want = p.animate(str(tmp_path / "test.wav"), adapt="full", adapt_tau=50.0, adapt_iter=2)
    with np.load(tmp_path / "a.npz") as z:
        np.testing.assert_allclose(z["points"], want.animation.points, rtol=0, atol=1e-9)
    capsys.readouterr()
    assert main(args + [str(tmp_path / "b.npz"), "--adapt-tau", "50"]) == 2
    assert "give --adapt full too" in capsys.readouterr().err
    assert main(["animate", str(tmp_path / "p.vpp"), "--states-in", str(tmp_path / "s.csv"), "--adapt", "full",
                 "-o", str(tmp_path / "c.npz")]) == 2
    assert "the states of --states-in are not decoded" in capsys.readouterr().err
    assert not (tmp_path / "b.npz").exists() and not (tmp_path / "c.npz").exists()
    # Live animation has no whole input to adapt to: it has no such switch.
    with pytest.raises(SystemExit) as e:
        main(["live", str(tmp_path / "p.vpp"), "--adapt", "full"])
    assert e.value.code == 2
    assert "unrecognized arguments: --adapt" in capsys.readouterr().err


def test_a_guided_puppets_guide_reads_the_inputs_own_features(guided):
    """The transform adapts the decoder's input; the guide's ŷ reads the input's own z (feeding
    it A z + b was measured and not adopted: docs/puppet.md, "Tried and dropped").
    The face is Brand's solve of the decoded states with the evidence ŷ(z), recomposed from the
    parts; τ = ∞ is no adaptation bit for bit, guide included."""
    from voicepuppet import _core

    assert guided._core.guided and not guided._core.projected
    pts, heard, _ = _performer(np.random.default_rng(8), 900, VOICE)
    truth, _ = guided.face_space.encode(pts)
    plain = guided.animate(full_motion=False, features=heard)
    r = guided.animate(full_motion=False, features=heard, adapt="full", adapt_tau=5.0, adapt_iter=8)
    assert np.sum((r.face - truth) ** 2) < 0.8 * np.sum((plain.face - truth) ** 2)
    core = guided._core
    (t,) = r.transforms
    z = np.asarray(core.standardize(np.ascontiguousarray(heard)))
    W = core.guide_weight * np.asarray(core.guide_precision(0))
    model = core.trajectory_model(0.0, 0)
    face = _core.solve_trajectory(model, r.states[:, 0], np.asarray(core.guide_predict(z)), W)
    np.testing.assert_allclose(r.face, face, rtol=0, atol=1e-8 * np.abs(face).max())
    adapted = _core.solve_trajectory(model, r.states[:, 0], np.asarray(core.guide_predict(
        z @ np.asarray(t["A"]).T + np.asarray(t["b"]))), W)
    assert np.abs(adapted - face).max() > 1e-3  # the two readings differ: the test tells them apart
    inf = guided.animate(full_motion=False, features=heard, adapt="full", adapt_tau=np.inf)
    np.testing.assert_array_equal(inf.face, plain.face)
