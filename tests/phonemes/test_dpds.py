"""Tests of the phoneme-driven models (voicepuppet.phonemes) against independent truth.

- DPDS: the C++ gradient of eq. 1 against central finite differences (for fixed parameters and
  for the profile likelihood that training optimises); the exact mu/nu solve against numpy's
  lstsq on a design matrix built column by column with a plain numpy recursion; the training
  log-likelihood never decreases; planted parameters are recovered; streaming equals batch.
- SLDS: the Kalman smoother against a dense Gaussian solve of the whole sequence; EM never
  decreases the log-likelihood.
- Per-phoneme means and Brand's phoneme trajectory: closed forms.
"""

from __future__ import annotations

import numpy as np
import pytest

from voicepuppet import _core
from voicepuppet import phonemes as dpds
from voicepuppet.phonemes.labels import N_PHONES

SEED = 20261123
P = N_PHONES


def labels_seq(rng, T, phones, max_dwell=5):
    out = []
    while len(out) < T:
        out += [int(rng.choice(phones))] * int(rng.integers(1, max_dwell + 1))
    return np.array(out[:T], dtype=np.int64)


def numpy_path(a, mu, nu, lab):
    x = np.zeros((len(lab), a.shape[1]))
    x[0] = mu[lab[0]]
    for t in range(1, len(lab)):
        x[t] = a[lab[t]] * x[t - 1] + nu[lab[t]]
    return x


def planted(rng, n_seq=6, T=60, K=3, phones=(0, 5, 9, 14), noise=0.05):
    a = np.full((P, K), 0.5)
    mu = np.zeros((P, K))
    nu = np.zeros((P, K))
    for p in phones:
        a[p] = rng.uniform(0.3, 0.9, K)
        mu[p] = rng.normal(size=K)
        nu[p] = rng.normal(size=K)
    Ys, Ls = [], []
    for _ in range(n_seq):
        lab = labels_seq(rng, T, phones)
        Ys.append(numpy_path(a, mu, nu, lab) + noise * rng.normal(size=(T, K)))
        Ls.append(lab)
    return a, mu, nu, Ys, Ls


def test_dpds_gradient_matches_finite_differences():
    rng = np.random.default_rng(SEED)
    print("seed", SEED)
    a, mu, nu, Ys, Ls = planted(rng, n_seq=2, T=20)
    Y, lab, off = dpds.stack_sequences(Ys, Ls)
    r = np.array([0.1, 0.2, 0.05])
    a = a + 0.05 * rng.normal(size=a.shape)
    g = _core.dpds_gradient(a, mu, nu, r, Y, off, lab)
    assert g["log_likelihood"] == pytest.approx(
        -0.5 * np.sum(np.log(2 * np.pi * r) + (Y - np.concatenate(
            [numpy_path(a, mu, nu, lab[b:e]) for b, e in zip(off[:-1], off[1:])])) ** 2 / r), rel=1e-12)
    h = 1e-6
    for p in (0, 5, 9, 14):
        for j in range(3):
            ap, am = a.copy(), a.copy()
            ap[p, j] += h
            am[p, j] -= h
            fd = (_core.dpds_gradient(ap, mu, nu, r, Y, off, lab)["log_likelihood"]
                  - _core.dpds_gradient(am, mu, nu, r, Y, off, lab)["log_likelihood"]) / (2 * h)
            assert g["grad_a"][p, j] == pytest.approx(fd, rel=1e-5, abs=1e-5)
    # phones absent from the data have zero gradient
    assert np.all(g["grad_a"][1] == 0)


def test_profile_gradient_matches_finite_differences():
    """Training minimises -max_{mu,nu,r} L(a, ...): its gradient is dL/da at the optimum."""
    rng = np.random.default_rng(SEED + 1)
    a, _, _, Ys, Ls = planted(rng, n_seq=3, T=25)
    Y, lab, off = dpds.stack_sequences(Ys, Ls)
    floor = np.zeros(3)
    a = a + 0.1 * rng.normal(size=a.shape)
    s = _core.dpds_solve(a, Y, off, lab, floor)
    g = _core.dpds_gradient(a, s["mu"], s["nu"], s["r"], Y, off, lab)
    assert g["log_likelihood"] == pytest.approx(s["log_likelihood"], rel=1e-12)
    h = 1e-6
    for p, j in [(0, 0), (5, 1), (9, 2), (14, 0)]:
        ap, am = a.copy(), a.copy()
        ap[p, j] += h
        am[p, j] -= h
        fd = (_core.dpds_solve(ap, Y, off, lab, floor)["log_likelihood"]
              - _core.dpds_solve(am, Y, off, lab, floor)["log_likelihood"]) / (2 * h)
        assert g["grad_a"][p, j] == pytest.approx(fd, rel=1e-4, abs=1e-4)


def test_mu_nu_solve_matches_lstsq():
    rng = np.random.default_rng(SEED + 2)
    a, _, _, Ys, Ls = planted(rng, n_seq=4, T=30)
    Y, lab, off = dpds.stack_sequences(Ys, Ls)
    s = _core.dpds_solve(a, Y, off, lab, np.zeros(3))
    K = Y.shape[1]
    for j in range(K):
        cols = []
        for k in range(2 * P):
            mu = np.zeros((P, K))
            nu = np.zeros((P, K))
            (mu if k < P else nu)[k % P, j] = 1.0
            cols.append(np.concatenate([numpy_path(a, mu, nu, lab[b:e])[:, j]
                                        for b, e in zip(off[:-1], off[1:])]))
        X = np.stack(cols, axis=1)
        theta, *_ = np.linalg.lstsq(X, Y[:, j], rcond=None)
        used = np.concatenate([s["mu_used"], s["nu_used"]]).astype(bool)
        np.testing.assert_allclose(np.concatenate([s["mu"][:, j], s["nu"][:, j]])[used], theta[used],
                                   rtol=1e-7, atol=1e-9)
        assert s["r"][j] == pytest.approx(np.mean((Y[:, j] - X @ theta) ** 2), rel=1e-8)
    # mu is identifiable only for phones that start a sequence
    starts = set(lab[off[:-1]].tolist())
    assert set(np.nonzero(s["mu_used"])[0].tolist()) == starts


def test_dpds_training_increases_likelihood_and_recovers_planted_parameters():
    rng = np.random.default_rng(SEED + 3)
    a, mu, nu, Ys, Ls = planted(rng, n_seq=12, T=80, noise=0.02)
    m = dpds.DPDS(max_iter=300, var_floor=1e-6).fit(Ys, Ls)
    h = np.array(m.history_)
    assert h.size > 3 and np.all(np.diff(h) >= -1e-9 * np.abs(h[:-1]))
    assert h[-1] > h[0]
    for p in (0, 5, 9, 14):
        np.testing.assert_allclose(m.a_[p], a[p], atol=0.05)
        np.testing.assert_allclose(m.nu_[p], nu[p], atol=0.1)
    # residual variance near the planted noise (0.02^2)
    assert np.all(m.r_ < 2 * 0.02 ** 2) and np.all(m.r_ > 0.5 * 0.02 ** 2)
    lab = labels_seq(rng, 50, (0, 5, 9, 14))
    np.testing.assert_allclose(m.generate(lab), numpy_path(m.a_, m.mu_, m.nu_, lab), rtol=1e-12)


def test_dpds_stream_equals_generate():
    rng = np.random.default_rng(SEED + 4)
    _, _, _, Ys, Ls = planted(rng, n_seq=3, T=40)
    m = dpds.DPDS(max_iter=20).fit(Ys, Ls)
    lab = labels_seq(rng, 101, (0, 5, 9, 14, 20))  # phone 20 unseen: falls back, still finite
    st = m.stream()
    parts = [st.push(lab[:1]), st.push(lab[1:50]), st.push(np.array([], np.int64)), st.push(lab[50:])]
    np.testing.assert_allclose(np.concatenate(parts), m.generate(lab), rtol=0, atol=1e-14)
    assert st.frames == 101
    assert np.all(np.isfinite(m.generate(lab)))


def dense_posterior(a, nu, q, r, mu1, v1, y, lab):
    """One sequence, one dim: x = M e + c, y = x + v; posterior and evidence by dense algebra."""
    T = len(y)
    M = np.zeros((T, T))
    c = np.zeros(T)
    ev = np.zeros(T)
    for t in range(T):
        p = lab[t]
        c[t] = mu1[p] if t == 0 else a[p] * c[t - 1] + nu[p]
        ev[t] = v1[p] if t == 0 else q[p]
        M[t, t] = 1.0
        if t:
            M[t, :t] = a[p] * M[t - 1, :t]
    Sx = M @ np.diag(ev) @ M.T
    Sy = Sx + np.diag(r[lab])
    mean = c + Sx @ np.linalg.solve(Sy, y - c)
    cov = Sx - Sx @ np.linalg.solve(Sy, Sx)
    sign, logdet = np.linalg.slogdet(Sy)
    ll = -0.5 * (T * np.log(2 * np.pi) + logdet + (y - c) @ np.linalg.solve(Sy, y - c))
    return mean, cov, ll


def test_kalman_smoother_matches_dense_solve():
    rng = np.random.default_rng(SEED + 5)
    K, T = 2, 12
    a = rng.uniform(-0.9, 0.9, (P, K))
    nu = rng.normal(size=(P, K))
    q = rng.uniform(0.05, 0.5, (P, K))
    r = rng.uniform(0.05, 0.5, (P, K))
    mu1 = rng.normal(size=(P, K))
    v1 = rng.uniform(0.1, 1.0, (P, K))
    labs = [labels_seq(rng, T, (1, 2, 3)), labels_seq(rng, T - 4, (2, 7))]
    ys = [rng.normal(size=(len(lb), K)) for lb in labs]
    Y, lab, off = dpds.stack_sequences(ys, labs)
    sm = _core.slds_smooth(a, nu, q, r, mu1, v1, Y, off, lab)
    total = 0.0
    for s, (b, e) in enumerate(zip(off[:-1], off[1:])):
        for j in range(K):
            mean, cov, ll = dense_posterior(a[:, j], nu[:, j], q[:, j], r[:, j], mu1[:, j], v1[:, j],
                                            Y[b:e, j], lab[b:e])
            total += ll
            np.testing.assert_allclose(sm["mean"][b:e, j], mean, rtol=1e-9, atol=1e-10)
            np.testing.assert_allclose(sm["var"][b:e, j], np.diag(cov), rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(sm["cross"][b + 1:e, j], np.diag(cov, -1), rtol=1e-9, atol=1e-12)
    assert sm["log_likelihood"] == pytest.approx(total, rel=1e-11)


def test_slds_em_never_decreases_likelihood():
    rng = np.random.default_rng(SEED + 6)
    a, mu, nu, Ys, Ls = planted(rng, n_seq=6, T=60, noise=0.1)
    # add process noise so the SLDS has something to explain
    Ys = [y + np.cumsum(0.03 * rng.normal(size=y.shape), axis=0) for y in Ys]
    m = dpds.SLDS(n_iter=25, tol=0).fit(Ys, Ls)
    h = np.array(m.history_)
    assert h.size == 25
    assert np.all(np.diff(h) >= -1e-8 * np.abs(h[:-1])), np.diff(h)
    assert h[-1] > h[0]
    assert m.log_likelihood(Ys, Ls) >= h[-1] - 1e-6 * abs(h[-1])  # after the last M-step
    lab = Ls[0]
    np.testing.assert_allclose(m.generate(lab), numpy_path(m.a_, m.mu1_, m.nu_, lab), rtol=1e-12)


def test_phoneme_means_and_trajectory_closed_forms():
    rng = np.random.default_rng(SEED + 7)
    _, _, _, Ys, Ls = planted(rng, n_seq=4, T=50)
    pm = dpds.PhonemeMeans().fit(Ys, Ls)
    Y, lab, off = dpds.stack_sequences(Ys, Ls)
    for p in (0, 5, 9, 14):
        np.testing.assert_allclose(pm.means_[p], Y[lab == p].mean(axis=0), rtol=1e-12)
    test_lab = labels_seq(rng, 30, (0, 5, 9, 14))
    np.testing.assert_array_equal(pm.generate(test_lab), pm.means_[test_lab])
    ll = pm.log_likelihood(Ys[:1], Ls[:1])
    v = pm.vars_[Ls[0]]
    assert ll == pytest.approx(-0.5 * np.sum(np.log(2 * np.pi * v) + (Ys[0] - pm.means_[Ls[0]]) ** 2 / v))
    tr = dpds.PhonemeTrajectory().fit(Ys, Ls)
    O = dpds.observations(Y, off)
    np.testing.assert_allclose(tr.means_[9], O[lab == 9].mean(axis=0), rtol=1e-12)
    # a trajectory through one state with zero mean velocity is that state's pose mean
    tr.means_[9, 3:] = 0.0
    np.testing.assert_allclose(tr.generate(np.full(40, 9, np.int64)), np.tile(tr.means_[9, :3], (40, 1)),
                               rtol=1e-9, atol=1e-12)
    # the log-likelihood is the Gaussian density of o_t
    from scipy.stats import multivariate_normal

    O0 = dpds.observations(Ys[0], np.array([0, len(Ys[0])]))
    ref = sum(multivariate_normal(tr.means_[p], tr.covars_[p]).logpdf(o) for o, p in zip(O0, Ls[0]))
    assert tr.log_likelihood(Ys[:1], Ls[:1]) == pytest.approx(ref, rel=1e-10)


def test_bad_input():
    rng = np.random.default_rng(SEED + 8)
    _, _, _, Ys, Ls = planted(rng, n_seq=2, T=10)
    m = dpds.DPDS(max_iter=2)
    with pytest.raises(ValueError, match="not trained"):
        m.generate(Ls[0])
    with pytest.raises(ValueError, match="no sequences"):
        m.fit([], [])
    with pytest.raises(ValueError, match="one label sequence per face sequence"):
        m.fit(Ys, Ls[:1])
    with pytest.raises(ValueError, match="one phone per frame"):
        m.fit(Ys, [Ls[0], Ls[1][:5]])
    with pytest.raises(ValueError, match="phone set"):
        m.fit(Ys, [Ls[0], Ls[1] + 100])
    with pytest.raises(ValueError, match="NaN"):
        m.fit([Ys[0] * np.nan], Ls[:1])
    m.fit(Ys, Ls)
    with pytest.raises(ValueError, match="dims"):
        m.log_likelihood([Ys[0][:, :2]], Ls[:1])
    with pytest.raises(ValueError, match="integer"):
        m.generate(np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match="a_bound"):
        dpds.DPDS(a_bound=1.5)


@pytest.fixture(scope="module")
def performer():
    """Three utterances of the performer (espeak-ng phones, articulated landmarks, no video)."""
    from voicepuppet.animation import neutral_landmarks
    from voicepuppet.synth import speech
    from voicepuppet.synth.articulation import articulate

    out = []
    for i, text in enumerate(["Please remember to feed the fish before you leave.",
                              "Who knows where the old ferry will take us tomorrow?",
                              "You can hear the waves when the wind blows from the west."]):
        u = speech.speak(text, voice="en-us", rate=150)
        art = articulate(u.phones, u.samples, u.rate, neutral_landmarks(), fps=29.97, seed=i)
        out.append((u, art.points))
    return out


@pytest.mark.parametrize("kind", list(dpds.MODELS))
def test_phoneme_puppet_train_animate_save_load(performer, tmp_path, kind):
    from voicepuppet.phonemes.labels import frame_labels

    pts = [p for _, p in performer]
    phones = [u.phones for u, _ in performer]
    opts = {"max_iter": 30} if kind == "dpds" else {}
    pp = dpds.PhonemePuppet.train(pts, phones, fps=29.97, model=kind, alphabet="espeak", **opts)
    u0, p0 = performer[0]
    anim = pp.animate(u0.phones, n_frames=len(p0), alphabet="espeak")
    assert anim.points.shape == p0.shape and anim.fps == 29.97
    lab = frame_labels(u0.phones, len(p0), 29.97, alphabet="espeak")
    np.testing.assert_allclose(anim.points, pp.face_space.decode(pp.model.generate(lab)), rtol=1e-12)
    # a training utterance is reproduced far better than by the mean face
    from voicepuppet.evaluation import metrics

    truth = pp.face_space.decode(pp.face_space.encode(p0)[0])
    assert metrics.err(anim.points, truth) < 0.6
    path = tmp_path / "pp.npz"
    pp.save(path)
    back = dpds.PhonemePuppet.load(path)
    np.testing.assert_array_equal(back.animate(lab).points, pp.animate(lab).points)
    assert type(back.model) is type(pp.model) and back.fps == pp.fps


def test_phoneme_puppet_from_speech_and_bad_input(performer, tmp_path):
    pts = [p for _, p in performer]
    pp = dpds.PhonemePuppet.train(pts, [u.phones for u, _ in performer], fps=29.97, alphabet="espeak",
                                  max_iter=20)
    u, p = performer[0]  # (pocketsphinx loses the synthetic voice in sentence 1 after "old")
    from scipy.signal import resample_poly

    x = resample_poly(u.samples.astype(np.float64), 16000, u.rate) if u.rate != 16000 else u.samples
    anim = pp.animate(audio=np.asarray(x, np.float64), transcript=u.text)
    assert abs(len(anim.points) - len(p)) <= 1
    with pytest.raises(ValueError, match="exactly one"):
        pp.animate()
    with pytest.raises(ValueError, match="model must be one of"):
        dpds.PhonemePuppet.train(pts, [u.phones for u, _ in performer], model="lstm")
    with pytest.raises(ValueError, match="phones for every"):
        dpds.PhonemePuppet.train(pts, [])
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="phoneme puppet file .* is not a readable .npz archive .truncated, or another format"):
        dpds.PhonemePuppet.load(tmp_path / "bad.npz")


def test_phoneme_puppet_verb(performer, tmp_path, capsys):
    from voicepuppet.animation import Animation, load_animation, save_animation
    from voicepuppet import data as samples
    from voicepuppet.cli.main import main
    from voicepuppet.phonemes.labels import write_hts, write_textgrid

    lms, labs = [], []
    for i, (u, pts) in enumerate(performer):
        save_animation(Animation(pts, 29.97), tmp_path / f"s{i}.npz")
        write_textgrid(u.phones, tmp_path / f"s{i}.TextGrid", alphabet="espeak")
        lms.append(str(tmp_path / f"s{i}.npz"))
        labs.append(str(tmp_path / f"s{i}.TextGrid"))
    model = tmp_path / "m.npz"
    assert main(["phoneme-puppet", "train", "--landmarks", *lms, "--labels", *labs, "-o", str(model), "-q"]) == 0
    assert "dpds on" in capsys.readouterr().out
    out = tmp_path / "a.npz"
    assert main(["phoneme-puppet", "animate", str(model), "--labels", labs[0], "-o", str(out)]) == 0
    anim = load_animation(out)
    assert abs(len(anim.points) - len(performer[0][1])) <= 1
    wav, lab = samples.arctic_a0009(with_labels=True)
    assert main(["phoneme-puppet", "animate", str(model), wav, "-t",
                 "He turned sharply, and faced Gregson across the table.", "-o", str(tmp_path / "b.csv")]) == 0
    import soundfile

    duration = soundfile.info(wav).duration
    assert abs(len(load_animation(tmp_path / "b.csv").points) - duration * 29.97) <= 1.0
    assert main(["phoneme-puppet", "train", "--landmarks", *lms, "--labels", *labs[:1], "-o",
                 str(tmp_path / "x.npz")]) == 2
    assert "one label file per landmark file" in capsys.readouterr().err
    assert main(["phoneme-puppet", "animate", str(model), "-o", str(tmp_path / "y.npz")]) == 2
    assert not (tmp_path / "x.npz").exists() and not (tmp_path / "y.npz").exists()
