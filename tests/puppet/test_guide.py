"""The guide (training option ``guide``): the ridge's prediction ŷ of the face as evidence in the
trajectory solve. Python's ``Puppet.animate`` against a dense numpy solve of the guided objective
(1 and 2 parts, Viterbi and posterior, two output rates), λ = 0 against a ``guide="none"``
puppet, the stored map against the ridge baseline, the file (round trip, format version, an old
version-1 file), a planted world where only the ridge hears the face, bad options and arrays."""
from pathlib import Path

import numpy as np
import pytest

from voicepuppet import _core
from voicepuppet.face import FaceSpace
from voicepuppet.layout import MOUTH
from voicepuppet.puppet.guide import RidgeBaseline, context_stack, lips_score
from voicepuppet.layout import RIGID
from voicepuppet.puppet.guide import GUIDE_WEIGHTS, cross_fit
from voicepuppet.puppet.model import Puppet, load
from voicepuppet.puppet.training import TRAIN_DEFAULTS

FPS = 30.0
DATA = Path(__file__).resolve().parents[1] / "data"


def _world(rng, T, P=68):
    """A face of P points making one of three shapes in runs of 12 frames (smoothed), and 5
    audio features: 2 that say the shape, mixed with 3 of noise by a fixed map."""
    world = np.random.default_rng(1)
    base = world.normal(size=(P, 2)) * 40 + 160
    modes = world.normal(size=(3, P, 2)) * 4
    modes[:, list(RIGID)[: min(P, 68)] if P == 68 else []] = 0
    states = np.repeat(rng.integers(0, 3, T // 12 + 1), 12)[:T]
    shape = base + modes[states] + rng.normal(0, 0.3, (T, P, 2))
    k = np.array([0.25, 0.5, 0.25])
    shape = np.apply_along_axis(lambda v: np.convolve(np.pad(v, 1, mode="edge"), k, "valid"), 0, shape)
    articulation = world.normal(0, 2, (3, 2))[states] + rng.normal(0, 0.7, (T, 2))
    noise = rng.normal(0, 1, (T, 3))
    return shape, np.hstack([articulation, noise]) @ world.normal(size=(5, 5))


OPTS = dict(fps=FPS, n_states=5, n_iter=10, n_components=3, audio_deltas=1, seed=0)


@pytest.fixture(scope="module")
def data():
    train = _world(np.random.default_rng(5), 600)
    test = _world(np.random.default_rng(6), 150)
    return train, test


@pytest.fixture(scope="module")
def puppets(data):
    (pts, feats), _ = data
    out = {}
    for parts in (None, "upper_lower"):
        for guide in ("ridge", "none"):
            out[parts, guide] = Puppet.train([pts], features_list=[feats], parts=parts, guide=guide,
                                             guide_context=3, **OPTS)
    return out


# ------------------------------------------------------------------ the numpy reference
def _dense_guided(means, covars, weights, r, yhat, W):
    """argmin_y Σ_t Σ_n w_tn (frame t's cost under n) + Σ_t (y_t − ŷ_t)ᵀ W (y_t − ŷ_t), with
    velocities scaled by r (the rate ratio), by a dense solve of the stacked normal equations."""
    T, (N, D2) = len(weights), means.shape
    D = D2 // 2
    S = np.diag(np.r_[np.ones(D), np.full(D, r)])
    H = np.zeros((T * D, T * D))
    g = np.zeros(T * D)
    for t in range(T):
        E = np.zeros((D, T * D))
        E[:, t * D:(t + 1) * D] = np.eye(D)
        H += E.T @ W @ E
        g += E.T @ W @ yhat[t]
        for n in range(N):
            w = weights[t, n]
            if w == 0:
                continue
            K = S @ covars[n] @ S
            target = np.r_[means[n, :D], r * means[n, D:]]
            if t == 0:
                P0 = np.linalg.inv(K[:D, :D])
                H += w * E.T @ P0 @ E
                g += w * E.T @ P0 @ target[:D]
                continue
            M = np.zeros((2 * D, T * D))
            M[:D, t * D:(t + 1) * D] = np.eye(D)
            M[D:, t * D:(t + 1) * D] = np.eye(D)
            M[D:, (t - 1) * D:t * D] = -np.eye(D)
            Pk = np.linalg.inv(K)
            H += w * M.T @ Pk @ M
            g += w * M.T @ Pk @ target
    return np.linalg.solve(H, g).reshape(T, D)


def _interp_rows(x, fps_in, fps_out):
    """Linear interpolation of rows at u = k·fps_in/fps_out (clamped), k < ceil(T·fps_out/fps_in)."""
    n = int(np.ceil(len(x) * fps_out / fps_in - 1e-9))
    u = np.minimum(np.arange(n) * fps_in / fps_out, len(x) - 1)
    return np.stack([np.interp(u, np.arange(len(x)), c) for c in x.T], axis=1)


def _reference(pup, feats, *, posterior, fps):
    """The guided face of ``pup`` for ``feats`` from the file's arrays, in numpy (the decoded
    states or posteriors come from the C++ decoder: the solve is what is checked)."""
    a = pup.arrays
    z = pup._core.standardize(np.ascontiguousarray(feats))
    k, C = int(a["guide/context"][0]), int(a["guide/columns"][0])
    yhat = context_stack(z[:, :C], k) @ a["guide/map"] + a["guide/offset"]
    yhat = _interp_rows(yhat, FPS, fps)
    lam = float(a["guide/weight"][0])
    R = a["guide/covariance"]
    faces = []
    for p, sl in enumerate(pup.face_space.part_slices):
        arr = pup.part_arrays(p)
        log_b = pup._core.vocal_log_density(z, p)
        if posterior:
            _, gamma = _core.forward_backward(log_b, arr["startprob"], arr["transmat"],
                                              np.array([len(z)], dtype=np.int64))[:2]
            weights = _interp_rows(gamma, FPS, fps)
        else:
            _, path = _core.viterbi(log_b, arr["startprob"], arr["transmat"], np.array([len(z)], dtype=np.int64))
            n = int(np.ceil(len(path) * fps / FPS - 1e-9))
            held = path[np.minimum(np.floor(np.arange(n) * FPS / fps + 1e-9).astype(int), len(path) - 1)]
            weights = np.eye(len(arr["startprob"]))[held]
        Rp = R[sl, sl]
        Rp = Rp + 1e-9 * (np.trace(Rp) / len(Rp) or 1.0) * np.eye(len(Rp))  # kGuideCovarianceFloor
        faces.append(_dense_guided(arr["face_means"], arr["face_covars"], weights, FPS / fps, yhat[:, sl],
                                   lam * np.linalg.inv(Rp)))
    return np.hstack(faces)


@pytest.mark.parametrize("parts", [None, "upper_lower"], ids=["one-part", "upper-lower"])
@pytest.mark.parametrize("posterior", [False, True], ids=["viterbi", "posterior"])
@pytest.mark.parametrize("fps", [FPS, 47.0], ids=["own-rate", "47fps"])
def test_guided_animation_is_the_dense_solve_of_the_guided_objective(puppets, data, parts, posterior, fps):
    pup = puppets[parts, "ridge"]
    _, (_, feats) = data
    assert pup.guided and pup.guide_weight in GUIDE_WEIGHTS and pup._core.n_parts == (1 if parts is None else 2)
    assert pup.guide_weight > 0  # the planted world's audio carries the face: the choice is a guided solve
    face = pup.animate(full_motion=False, features=feats, posterior=posterior, fps=fps).face
    ref = _reference(pup, feats, posterior=posterior, fps=fps)
    assert face.shape == ref.shape
    np.testing.assert_allclose(face, ref, rtol=0, atol=1e-8 * np.abs(ref).max())
    # the guide moves the face: the unguided solve is measurably elsewhere
    assert np.abs(pup.animate(full_motion=False, features=feats, posterior=posterior, fps=fps, guide_weight=0).face - face).max() > 1e-3


@pytest.mark.parametrize("parts", [None, "upper_lower"], ids=["one-part", "upper-lower"])
def test_weight_zero_is_the_unguided_puppet_of_the_same_seed(puppets, data, parts):
    guided, plain = puppets[parts, "ridge"], puppets[parts, "none"]
    _, (_, feats) = data
    assert not plain.guided and plain.guide_weight == 0.0
    assert not any(k.startswith("guide/") for k in plain.arrays)
    for posterior in (False, True):
        for fps in (None, 47.0):
            a = guided.animate(features=feats, posterior=posterior, fps=fps, guide_weight=0).face
            b = plain.animate(features=feats, posterior=posterior, fps=fps).face
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
            # None is the file's λ, and the same λ given explicitly the same
            np.testing.assert_array_equal(guided.animate(features=feats, posterior=posterior, fps=fps).face,
                                          guided.animate(features=feats, posterior=posterior, fps=fps,
                                                         guide_weight=guided.guide_weight).face)
    # given states alone are synthesised unguided, as by the unguided puppet
    s = guided.animate(features=feats).states
    np.testing.assert_allclose(guided.animate(states=s).face, plain.animate(states=s).face, atol=1e-12)


@pytest.mark.parametrize("parts", [None, "upper_lower"], ids=["one-part", "upper-lower"])
@pytest.mark.parametrize("fps", [None, 47.0], ids=["own-rate", "47fps"])
def test_given_states_with_their_audio_are_the_guided_animation(puppets, data, parts, fps):
    """Brand §6's editing loop: the states animate decoded, given back with the same audio,
    give its face exactly (the guide's evidence comes from that audio); alone, the unguided
    solve; the guide's weight applies to them as to the audio."""
    pup = puppets[parts, "ridge"]
    _, (_, feats) = data
    r = pup.animate(features=feats, fps=fps)
    again = pup.animate(features=feats, states=r.states, states_fps=r.states_fps, fps=fps)
    np.testing.assert_array_equal(again.face, r.face)
    np.testing.assert_array_equal(again.states, r.states)
    for w in (0.0, 2.0):
        np.testing.assert_array_equal(pup.animate(features=feats, states=r.states, fps=fps, guide_weight=w).face,
                                      pup.animate(features=feats, fps=fps, guide_weight=w).face)
    # the rate as a states file's 9-digit times give it back
    sfps = 1.0 / float(np.median(np.diff(np.array([f"{t:.9g}" for t in np.arange(len(r.states)) / FPS],
                                                  dtype=float))))
    assert sfps != FPS
    np.testing.assert_array_equal(pup.animate(features=feats, states=r.states, states_fps=sfps, fps=fps).face,
                                  r.face)
    with pytest.raises(ValueError, match="one path"):
        pup.animate(features=feats, states=r.states, posterior=True)
    with pytest.raises(ValueError, match="not decoded"):
        pup.animate(features=feats, states=r.states, adapt="full")
    with pytest.raises(ValueError, match="decoded from"):
        pup.animate(features=feats, states=r.states[: len(r.states) // 2])
    with pytest.raises(ValueError, match="give the audio or drop guide_weight"):
        pup.animate(states=r.states, guide_weight=2.0)
    with pytest.raises(ValueError, match="states with the audio"):
        pup.animate(audio="x.wav", features=feats, states=r.states)


def test_stored_guide_is_the_ridge_baseline_and_its_cross_fitted_residuals(puppets, data):
    pup = puppets[None, "ridge"]
    (pts, feats), (_, test_feats) = data
    a = pup.arrays
    assert TRAIN_DEFAULTS["guide"] == "ridge" and TRAIN_DEFAULTS["guide_context"] == 5
    assert int(a["guide/context"][0]) == 3 and int(a["guide/columns"][0]) == 5  # features without deltas
    Z, Y = pup.ridge_input(feats), pup.face_space.encode(pts)[0]
    ridge = RidgeBaseline(3).fit([Z], [Y])
    zt = pup._core.standardize(np.ascontiguousarray(test_feats))
    np.testing.assert_allclose(pup._core.guide_predict(zt), ridge.predict(pup.ridge_input(test_feats)),
                               rtol=1e-10, atol=1e-10)
    res = Y - cross_fit(context_stack(Z, 3), Y, [len(Y)])
    np.testing.assert_allclose(a["guide/covariance"], np.cov(res, rowvar=False, bias=True), rtol=1e-12, atol=1e-14)
    assert pup.metadata["training"]["guide"]["alpha"] == ridge.alpha
    assert pup.metadata["training"]["options"]["guide"] == "ridge"


def test_alpha_per_target_is_each_target_fitted_alone():
    """Per target, the α and map are those of a ridge on that target alone; with one target
    audible and one noise the two choices differ, and neither is the shared α of both."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(400, 6))
    audible = X @ rng.normal(size=6) + rng.normal(0, 0.3, 400)
    noise = 0.2 * X[:, 0] + rng.normal(0, 5.0, 400)
    Y = np.c_[audible, noise]
    both = RidgeBaseline(1, per_target=True).fit([X], [Y])
    shared = RidgeBaseline(1).fit([X], [Y])
    for j in range(2):
        alone = RidgeBaseline(1).fit([X], [Y[:, [j]]])
        assert both.alpha[j] == alone.alpha
        np.testing.assert_allclose(both.W[:, j], alone.W[:, 0], rtol=1e-12, atol=1e-12)
    assert both.alpha[0] < both.alpha[1]
    assert shared.alpha != both.alpha[0]
    assert both.predict(X[:5]).shape == shared.predict(X[:5]).shape == (5, 2)


def test_the_guide_alpha_option_fits_the_guide_per_coordinate(data):
    (pts, feats), _ = data
    pup = Puppet.train([pts], features_list=[feats], guide_context=3, guide_alpha="per_coordinate", **OPTS)
    Z, Y = pup.ridge_input(feats), pup.face_space.encode(pts)[0]
    ridge = RidgeBaseline(3, per_target=True).fit([Z], [Y])
    np.testing.assert_allclose(pup.arrays["guide/map"], ridge.W, rtol=1e-10, atol=1e-12)
    assert pup.metadata["training"]["guide"]["alpha"] == ridge.alpha.tolist()
    assert pup.metadata["training"]["options"]["guide_alpha"] == "per_coordinate"
    assert TRAIN_DEFAULTS["guide_alpha"] == "shared"
    with pytest.raises(ValueError, match="guide_alpha must be one of"):
        Puppet.train([pts], features_list=[feats], guide_alpha="each", **OPTS)


def test_a_scored_alpha_is_chosen_on_the_scored_columns():
    """α chosen on ``(Ŷ − Y) @ score``: the identity scores as no score does; scoring only the
    audible target picks the α of a ridge on that target alone (not the shared α, which the
    noise target drags up), and the map is still fitted to every target at that α."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(400, 6))
    audible = X @ rng.normal(size=6) + rng.normal(0, 0.3, 400)
    noise = 0.2 * X[:, 0] + rng.normal(0, 5.0, 400)
    Y = np.c_[audible, noise]
    plain = RidgeBaseline(1).fit([X], [Y])
    identity = RidgeBaseline(1, score=np.eye(2)).fit([X], [Y])
    assert identity.alpha == plain.alpha
    np.testing.assert_array_equal(identity.W, plain.W)
    scored = RidgeBaseline(1, score=[[1.0], [0.0]]).fit([X], [Y])
    alone = RidgeBaseline(1).fit([X], [Y[:, [0]]])
    assert scored.alpha == alone.alpha != plain.alpha
    at_alpha = RidgeBaseline(1, alphas=(scored.alpha,)).fit([X], [Y])
    np.testing.assert_allclose(scored.W, at_alpha.W, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="without per_target"):
        RidgeBaseline(1, per_target=True, score=np.eye(2))
    with pytest.raises(ValueError, match="3 rows for 2 face coordinates"):
        RidgeBaseline(1, score=np.eye(3)).fit([X], [Y])


def test_lips_score_is_the_map_from_face_coordinates_to_the_lips(data):
    """``lips_score``: the lips' points of ``FaceSpace.shapes`` are their rest position plus
    ``Y @ score`` for any face coordinates (the shapes are linear in them); other layouts refuse."""
    (pts, _), _ = data
    fs = FaceSpace.fit([pts], 0.98)
    S = lips_score(fs)
    assert S.shape == (fs.n_dims, 2 * len(MOUTH))
    Y = np.random.default_rng(0).normal(size=(7, fs.n_dims))
    rest = fs.shapes(np.zeros((1, fs.n_dims)))[0, MOUTH].ravel()
    np.testing.assert_allclose(fs.shapes(Y)[:, MOUTH].reshape(7, -1), rest + Y @ S, rtol=1e-10, atol=1e-9)
    with pytest.raises(ValueError, match="needs the 68-point layout"):
        lips_score(FaceSpace.fit([pts[:, :30]], 0.98))


def test_the_guide_alpha_option_lips_chooses_alpha_on_the_lips(data):
    (pts, feats), _ = data
    pup = Puppet.train([pts], features_list=[feats], guide_context=3, guide_alpha="lips", **OPTS)
    Z, Y = pup.ridge_input(feats), pup.face_space.encode(pts)[0]
    ridge = RidgeBaseline(3, score=lips_score(pup.face_space)).fit([Z], [Y])
    np.testing.assert_allclose(pup.arrays["guide/map"], ridge.W, rtol=1e-10, atol=1e-12)
    assert pup.metadata["training"]["guide"]["alpha"] == ridge.alpha
    assert pup.metadata["training"]["options"]["guide_alpha"] == "lips"
    with pytest.raises(ValueError, match="needs the 68-point layout"):
        Puppet.train([pts[:, :30]], features_list=[feats], guide_alpha="lips", **OPTS)


def test_file_round_trip_and_format_version(puppets, data, tmp_path):
    _, (_, feats) = data
    for (parts, guide), pup in puppets.items():
        path = pup.save(tmp_path / f"{parts}-{guide}.vpp")
        version = int.from_bytes(path.read_bytes()[8:12], "little")
        assert version == 3
        q = load(path)
        assert q.guided == (guide == "ridge")
        for meta in (pup.metadata, q.metadata):  # whole numbers, as trained and as read back
            for part in meta["training"]["parts"]:
                assert type(part["states"]) is int and type(part["arcs"]) is int
        for posterior in (False, True):
            np.testing.assert_array_equal(q.animate(features=feats, posterior=posterior).animation.points,
                                          pup.animate(features=feats, posterior=posterior).animation.points)
    assert _core.PUPPET_FORMAT_VERSION == 3
    # an older reader (versions 1 and 2) refuses every file instead of animating a guided one
    # unguided or missing a damaged header: the header says 3, which such a reader calls newer
    # than it reads


def _old_world():
    """The audio features of the old file's animation (the script that wrote it, /tmp/vo/proj
    oldfile.py of the lead's check: the same generator, seed 7)."""
    rng = np.random.default_rng(7)
    st = np.repeat(rng.integers(0, 3, 60), 15)
    rng.normal(size=(12, 2))
    rng.normal(size=(3, 12, 2))
    rng.normal(0, 0.3, (900, 12, 2))
    return rng.normal(0, 3, (3, 5))[st] + rng.normal(size=(900, 5))


def test_an_old_version_1_file_animates_as_before():
    # tests/data/old_unguided.vpp: written by voicepuppet before the guide (format version 1);
    # old_unguided_anim.npz: every 30th frame of its Viterbi and posterior animations then.
    path = DATA / "old_unguided.vpp"
    assert int.from_bytes(path.read_bytes()[8:12], "little") == 1
    p = load(path)
    assert not p.guided
    assert p.metadata["training"]["parts"][0]["states"] == 6  # stored as 6.0, read as a whole number
    assert type(p.metadata["training"]["parts"][0]["states"]) is int
    ref = np.load(DATA / "old_unguided_anim.npz")
    feats = _old_world()
    # To rounding: the solves round differently on another CPU (the core is built with
    # -march=native). Posterior-weighted, on an AMD EPYC with AVX2, 13 of the 720 coordinates
    # differ from those of the machine that wrote the reference by one ulp; Viterbi, on an Intel
    # Xeon (2026-12-04), 2 of 720 by one ulp.
    for kind, posterior in (("viterbi", False), ("posterior", True)):
        np.testing.assert_allclose(p.animate(features=feats, posterior=posterior).animation.points[::30],
                                   ref[kind], rtol=1e-14, atol=0, err_msg=kind)


def test_planted_guide_helps_when_the_vocal_model_hears_nothing(data):
    # The vocal HMM is trained on the audio shuffled in time against the face (its states hear
    # nothing), the guide's ridge on the true audio (the same face space: it is fitted on the
    # landmarks alone). Unguided, the deaf puppet's face is worse than the mean face; the
    # ridge's evidence pulls it most of the way back: the guided face is closer to the truth.
    (pts, feats), (test_pts, test_feats) = data
    shuffled = feats[np.random.default_rng(11).permutation(len(feats))]
    hmm = Puppet.train([pts], features_list=[shuffled], guide="none", **OPTS)
    ridge = Puppet.train([pts], features_list=[feats], guide="ridge", guide_weight=4.0, **OPTS)  # a known λ
    np.testing.assert_array_equal(hmm.arrays["face/part0/basis"], ridge.arrays["face/part0/basis"])
    deaf = Puppet(hmm.metadata, {**hmm.arrays, **{k: v for k, v in ridge.arrays.items() if k.startswith("guide/")}})
    truth = deaf.face_space.encode(test_pts)[0]

    def err(face):  # squared error relative to the truth's variance (the mean face scores 1)
        return float(np.sum((face - truth) ** 2) / np.sum((truth - truth.mean(0)) ** 2))

    unguided = err(deaf.animate(features=test_feats, guide_weight=0).face)
    guided = err(deaf.animate(features=test_feats).face)
    alone = err(deaf._core.guide_predict(deaf._core.standardize(np.ascontiguousarray(test_feats))))
    assert unguided > 1.5  # measured 3.9: decoded states unrelated to the face
    assert guided < 0.6 * unguided  # measured 2.1
    assert alone < guided  # the posterior given both lies between: the deaf HMM still pulls
    # a stronger guide weight moves it further towards the ridge
    assert err(deaf.animate(features=test_feats, guide_weight=10.0).face) < guided


def test_bad_options_and_arrays_are_refused_by_name(puppets, data):
    (pts, feats), (_, test_feats) = data
    with pytest.raises(ValueError, match="guide must be one of"):
        Puppet.train([pts], features_list=[feats], guide="ridge2", **OPTS)
    for bad in (-1, 101, 1.5, True):
        with pytest.raises(ValueError, match="guide_context must be an integer in"):
            Puppet.train([pts], features_list=[feats], guide_context=bad, **OPTS)
    pup, plain = puppets[None, "ridge"], puppets[None, "none"]
    for bad in (-1.0, np.inf, np.nan, "1", True):
        with pytest.raises(ValueError, match="guide_weight"):
            pup.animate(features=test_feats, guide_weight=bad)
    with pytest.raises(ValueError, match="needs a guided puppet"):
        plain.animate(features=test_feats, guide_weight=0.5)
    plain.animate(features=test_feats, guide_weight=0)  # 0 is Brand's solve: fine on any puppet
    s = pup.animate(features=test_feats).states
    with pytest.raises(ValueError, match="without their audio are synthesised unguided"):
        pup.animate(states=s, guide_weight=1.0)
    K = pup.face_space.n_dims
    cases = {"guide/covariance": np.eye(K + 1), "guide/map": np.zeros((3, K)), "guide/context": np.array([101]),
             "guide/columns": np.array([0]), "guide/weight": np.array([-1.0]), "guide/offset": np.zeros(K + 1)}
    for name, value in cases.items():
        with pytest.raises(ValueError, match=name):
            Puppet(pup.metadata, {**pup.arrays, name: value})
    missing = {k: v for k, v in pup.arrays.items() if k != "guide/covariance"}
    with pytest.raises(ValueError, match="guide/covariance"):
        Puppet(pup.metadata, missing)
    nan = pup.arrays["guide/map"].copy()
    nan[0, 0] = np.nan
    with pytest.raises(ValueError, match="guide/map"):
        Puppet(pup.metadata, {**pup.arrays, "guide/map": nan})
    indefinite = -np.eye(K)
    with pytest.raises(ValueError, match="guide/covariance"):
        Puppet(pup.metadata, {**pup.arrays, "guide/covariance": indefinite})


@pytest.mark.parametrize("parts", [None, "upper_lower"])
def test_a_guided_puppet_streams_its_offline_animation(puppets, data, parts):
    """The C++ stream of a trained guided puppet (one and two parts) with lags covering the
    clip is the offline guided animation; its guide look-ahead defaults to the full ±3."""
    _, (_, feats) = data
    feats = np.ascontiguousarray(feats)
    core = puppets[parts, "ridge"]._core
    for posterior, fps in ((False, 0.0), (True, 25.0)):
        ref = np.asarray(core.animate(feats, fps, posterior)["points"])
        sp = _core.StreamingPuppet(core, 1000, 1000, fps, posterior)
        assert (sp.guide_lag, sp.guide_weight) == (3, puppets[parts, "ridge"].guide_weight)
        got = [np.asarray(sp.push(feats[a:a + 7]).points) for a in range(0, feats.shape[0], 7)]
        got = np.vstack(got + [np.asarray(sp.flush().points)])
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-8 * np.abs(ref).max())
    with pytest.raises(ValueError, match="needs a guided puppet"):
        _core.StreamingPuppet(puppets[parts, "none"]._core, 5, 5, 0.0, False, guide_weight=1.0)


def test_trajectory_binding_takes_the_evidence(puppets):
    pup = puppets[None, "ridge"]
    model = pup._core.trajectory_model(0.0, 0)
    s = np.zeros(20, dtype=np.int64)
    K = pup.face_space.n_dims
    y = np.ones((20, K))
    unguided = _core.solve_trajectory(model, s)
    np.testing.assert_array_equal(_core.solve_trajectory(model, s, y, np.zeros((K, K))), unguided)
    np.testing.assert_allclose(_core.solve_trajectory(model, s, y, 1e9 * np.eye(K)), y, atol=1e-6)
    with pytest.raises(ValueError, match="pass both or neither"):
        _core.solve_trajectory(model, s, y)
    with pytest.raises(ValueError, match="evidence.targets must be 20 x"):
        _core.solve_trajectory_weighted(model, np.ones((20, pup.n_states())), y[:5], np.eye(K))
