"""Vocal Gaussians on a learned projection of the audio (training option ``vocal_features``):
planted voices that differ by a speaker-specific linear distortion, cross-fitting, the stored
map against scikit-learn's ridge, C++ against Python, the file round trip, bad values."""
import numpy as np
import pytest

from voicepuppet import _core
from voicepuppet.puppet.guide import context_stack
from voicepuppet.puppet.guide import cross_fit, cross_fit_folds, fit_projection
from voicepuppet.puppet.model import Puppet, load


def _voice(rng, nuisance_mean, nuisance_spread, T=900, P=12):
    """A performer with three facial states (rest, open, round) visited in runs. The audio is a
    shared articulatory signal (2 dims that say the state) mixed with a speaker's own signal
    (3 dims, mean and spread per speaker, independent of the face) by one fixed linear map: a
    speaker-specific linear distortion of the same articulation."""
    world = np.random.default_rng(1)
    base = np.stack([np.cos(np.linspace(0, 2 * np.pi, P, endpoint=False)),
                     np.sin(np.linspace(0, 2 * np.pi, P, endpoint=False))], axis=1) * 50 + 160
    modes = np.zeros((3, P, 2))
    modes[1, P // 4, 1] = 25.0
    modes[2, :, 0] = (base[:, 0] - 160) * -0.3
    states = np.repeat(rng.integers(0, 3, T // 15), 15)[:T]
    shape = base + modes[states] + rng.normal(0, 0.3, (T, P, 2))
    k = np.array([0.25, 0.5, 0.25])
    shape = np.apply_along_axis(lambda v: np.convolve(np.pad(v, 1, mode="edge"), k, "valid"), 0, shape)
    articulation = world.normal(0, 2, (3, 2))[states] + rng.normal(0, 0.5, (T, 2))
    speaker = np.asarray(nuisance_mean) + rng.normal(0, 1, (T, 3)) * np.asarray(nuisance_spread)
    mix = world.normal(size=(5, 5))
    return shape, np.hstack([articulation, speaker]) @ mix, states


def _err(puppet, pts, feats):
    r = puppet.animate(features=feats)
    truth, _ = puppet.face_space.encode(pts)
    return float(np.sum((r.face - truth) ** 2) / np.sum((truth - truth.mean(0)) ** 2))


OPTS = dict(fps=30.0, n_states=6, n_iter=20, n_components=3, audio_deltas=0)


@pytest.fixture(scope="module")
def voices():
    train = _voice(np.random.default_rng(7), [0, 0, 0], [1.0, 0.3, 0.5])
    other = _voice(np.random.default_rng(8), [2.5, -2.0, 1.5], [0.4, 1.5, 1.2], T=600)
    return train, other


def test_projected_puppet_decodes_a_voice_it_never_heard(voices):
    # The chosen configuration (projection + one vocal covariance, docs/results.md) against the
    # default puppet. (In this planted world the tied covariance on the raw features reads the
    # other voice too: a linear discriminant ignores a speaker signal independent of the states;
    # on real readers it did not, 0.47 against 0.39 Err.)
    (pts, feats, _), (test_pts, test_feats, _) = voices
    same = _voice(np.random.default_rng(9), [0, 0, 0], [1.0, 0.3, 0.5], T=600)[:2]
    errs = {}
    for vf, cov in (("audio", "full"), ("projected", "tied")):
        p = Puppet.train([pts], features_list=[feats], vocal_features=vf, vocal_context=1,
                         vocal_covariance=cov, **OPTS)
        errs[vf] = _err(p, test_pts, test_feats)
        errs[vf + " same voice"] = _err(p, *same)
    # Both read the training voice; only the projection, which ignores the speaker's own signal,
    # reads the other voice.
    assert errs["audio same voice"] < 0.15 and errs["projected same voice"] < 0.15, errs
    assert errs["projected"] < 0.15 and errs["audio"] > 5 * errs["projected"], errs


def test_cross_fitted_predictions_never_see_their_own_targets():
    rng = np.random.default_rng(3)
    lengths = np.array([40, 55, 30, 60, 45, 50])
    X = rng.normal(size=(lengths.sum(), 4))
    Y = X @ rng.normal(size=(4, 2)) + rng.normal(0, 0.5, (lengths.sum(), 2))
    folds = cross_fit_folds(lengths, 5)
    np.testing.assert_array_equal(np.sort(np.concatenate(folds)), np.arange(lengths.sum()))
    assert len(folds[0]) == 40 + 55  # whole consecutive sequences
    yhat = cross_fit(X, Y, lengths)
    for j, fold in enumerate(folds):
        Y2 = Y.copy()
        Y2[fold] += rng.normal(0, 10, (len(fold), 2))  # wreck this fold's targets
        again = cross_fit(X, Y2, lengths)
        np.testing.assert_array_equal(again[fold], yhat[fold])
        others = np.setdiff1d(np.arange(len(X)), fold)
        assert not np.allclose(again[others], yhat[others])
    # One sequence: each fold is one block of it.
    blocks = cross_fit_folds([23], 5)
    assert [len(b) for b in blocks] == [5, 5, 5, 4, 4]
    np.testing.assert_array_equal(np.concatenate(blocks), np.arange(23))


def test_copies_of_a_recording_stay_in_one_fold():
    """groups: sequences that are copies of one recording (its noisy conditions) are never on
    both sides of a fold, with few groups (blocks, aligned across the copies) and with many
    (whole groups); the cross-fitted prediction of a copy is then unmoved by wrecking its other
    copies' targets too, which the ungrouped folds do not promise."""
    rng = np.random.default_rng(11)
    for base in ([120, 90], [40, 55, 30, 60, 45, 50]):
        base = np.array(base)
        k = 3
        lengths = np.tile(base, k)
        groups = np.tile(np.arange(len(base)), k)
        folds = cross_fit_folds(lengths, 5, groups)
        np.testing.assert_array_equal(np.sort(np.concatenate(folds)), np.arange(lengths.sum()))
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        where = np.empty(lengths.sum(), dtype=int)
        for j, f in enumerate(folds):
            where[f] = j
        for s in range(len(base)):
            copies = [where[starts[s + c * len(base)]:starts[s + c * len(base)] + base[s]] for c in range(k)]
            for c in copies[1:]:
                np.testing.assert_array_equal(c, copies[0])  # frame t of each copy: one fold
        X = rng.normal(size=(lengths.sum(), 4))
        X[len(X) // k:] = np.tile(X[:len(X) // k], (k - 1, 1)) + rng.normal(0, 0.1, (len(X) - len(X) // k, 4))
        Y = np.tile((X[:len(X) // k] @ rng.normal(size=(4, 2))), (k, 1)) + rng.normal(0, 0.5, (len(X), 2))
        yhat = cross_fit(X, Y, lengths, groups=groups)
        for j, fold in enumerate(folds):
            Y2 = Y.copy()
            Y2[fold] += rng.normal(0, 10, (len(fold), 2))
            np.testing.assert_array_equal(cross_fit(X, Y2, lengths, groups=groups)[fold], yhat[fold])
        plain = cross_fit_folds(lengths, 5)
        split = any(len({tuple(np.isin(np.arange(starts[s + c * len(base)], starts[s + c * len(base)] + 3), f))
                         for c in range(k)}) > 1 for f in plain for s in range(len(base)))
        assert split == (len(lengths) >= 5)  # without groups, whole-sequence folds part the copies
    with pytest.raises(ValueError, match="one label per sequence"):
        cross_fit_folds([10, 10], 5, groups=[0])
    np.testing.assert_array_equal(np.concatenate(cross_fit_folds([40, 55, 30, 60, 45, 50], 5, np.arange(6))),
                                  np.concatenate(cross_fit_folds([40, 55, 30, 60, 45, 50], 5)))


def test_stored_map_is_sklearn_ridge_standardised_by_the_cross_fitted_predictions():
    from sklearn.linear_model import Ridge

    rng = np.random.default_rng(5)
    lengths = np.array([70, 90, 80, 60, 100])
    Z = rng.normal(size=(lengths.sum(), 6))
    Y = Z[:, :2] @ rng.normal(size=(2, 3)) + rng.normal(0, 0.3, (lengths.sum(), 3))
    train, arrays, info = fit_projection(Z, Y, lengths, context=2, columns=4)
    assert arrays["audio/projection"].shape == (4 * 5, 3)
    assert info == {"alpha": info["alpha"], "folds": 5, "context": 2, "columns": 4}
    bounds = np.concatenate([[0], np.cumsum(lengths)])
    X = np.vstack([context_stack(Z[a:b, :4], 2) for a, b in zip(bounds[:-1], bounds[1:])])
    yhat = cross_fit(X, Y, lengths)
    np.testing.assert_allclose(train, (yhat - yhat.mean(0)) / yhat.std(0), atol=1e-12)
    ref = Ridge(alpha=info["alpha"]).fit(X, Y).predict(X)
    ours = X @ arrays["audio/projection"] + arrays["audio/projection_offset"]
    np.testing.assert_allclose(ours, (ref - yhat.mean(0)) / yhat.std(0), atol=1e-9)


@pytest.fixture(scope="module")
def projected(voices):
    (pts, feats, _), _ = voices
    return Puppet.train([pts], features_list=[feats], **{**OPTS, "audio_deltas": 2}, vocal_features="projected",
                        vocal_context=3, vocal_covariance="tied")


def test_cpp_animation_is_the_projection_composed_in_python(projected, voices):
    from scipy.stats import multivariate_normal

    p = projected
    _, (_, feats, _) = voices
    arr = p.arrays
    assert p._core.projected and p._core.projection_context == 3 and p._core.n_vocal == 3
    assert int(arr["audio/projection_columns"][0]) == 5  # the features without their deltas
    z = p._core.standardize(np.ascontiguousarray(feats))
    assert z.shape[1] == 10
    v = context_stack(z[:, :5], 3) @ arr["audio/projection"] + arr["audio/projection_offset"]
    np.testing.assert_allclose(p._core.project(z), v, rtol=1e-9, atol=1e-9)
    part = p.part_arrays(0)
    ours = p._core.vocal_log_density(z, 0)
    ref = np.stack([multivariate_normal(m, c).logpdf(v) for m, c in zip(part["vocal_means"], part["vocal_covars"])], 1)
    np.testing.assert_allclose(ours, ref, rtol=1e-9)
    logp, path = _core.viterbi(ref, part["startprob"], part["transmat"], np.array([len(v)], dtype=np.int64))
    r = p.animate(features=feats)
    np.testing.assert_array_equal(r.states[:, 0], path)
    assert abs(r.log_likelihood - logp) <= 1e-9 * abs(logp)
    assert p.metadata["training"]["options"]["vocal_features"] == "projected"
    assert p.metadata["training"]["projection"]["context"] == 3


def test_projected_puppet_file_round_trip(projected, voices, tmp_path):
    _, (_, feats, _) = voices
    q = load(projected.save(tmp_path / "projected.vpp"))
    for name in ("audio/projection", "audio/projection_offset", "audio/projection_context",
                 "audio/projection_columns"):
        np.testing.assert_array_equal(q.arrays[name], projected.arrays[name])
    for post in (False, True):
        np.testing.assert_array_equal(q.animate(features=feats, posterior=post).animation.points,
                                      projected.animate(features=feats, posterior=post).animation.points)
    # A plain puppet stores no projection and decodes the standardised features themselves.
    plain = Puppet.train([projected.face_space.decode(np.zeros((200, 3)))], features_list=[feats[:200]],
                         fps=30.0, n_states=3, n_iter=3, n_components=1)
    assert not any(k.startswith("audio/projection") for k in plain.arrays) and not plain._core.projected
    z = plain._core.standardize(np.ascontiguousarray(feats))
    np.testing.assert_array_equal(plain._core.project(z), z)


def test_bad_projection_options(projected, voices):
    (pts, feats, _), _ = voices
    with pytest.raises(ValueError, match="vocal_features must be one of"):
        Puppet.train([pts], features_list=[feats], vocal_features="ridge", **OPTS)
    for bad in (-1, 1.5, True, 101):
        with pytest.raises(ValueError, match="vocal_context must be an integer"):
            Puppet.train([pts], features_list=[feats], vocal_features="projected", vocal_context=bad, **OPTS)
    with pytest.raises(ValueError, match="too few to cross-fit"):
        fit_projection(np.zeros((6, 2)), np.zeros((6, 1)), [6], context=0, columns=2)
    with pytest.raises(ValueError, match="columns must be in"):
        fit_projection(np.zeros((60, 2)), np.zeros((60, 1)), [60], context=0, columns=3)
    with pytest.raises(ValueError, match="projection_columns"):
        Puppet(projected.metadata, {**projected.arrays, "audio/projection_columns": np.array([11])})
    # It streams (live/test_live.py, cpp/tests/test_streaming.cpp); a look-ahead beyond the
    # projection's context (3 here) is refused.
    with pytest.raises(ValueError, match="projection_lag must be -1"):
        _core.StreamingPuppet(projected._core, 5, 5, 0.0, False, -1, 4)


def test_a_projected_puppet_is_adapted_in_its_projected_space(projected, voices):
    # Test-time adaptation (animate(adapt="full")) acts on the vocal features the Gaussians live
    # in: for a projected puppet the projection of the standardised frames (3 dims here, not the
    # 10 standardised columns). The kernel's transform is the numpy reference's on them.
    from test_adapt import reference_adapt

    p = projected
    _, (_, feats, _) = voices
    r = p.animate(features=feats, adapt="full", adapt_tau=20.0, adapt_iter=2)
    (tr,) = r.transforms
    assert tr["A"].shape == (3, 3) and tr["b"].shape == (3,)
    v = p._core.project(p._core.standardize(np.ascontiguousarray(feats)))
    part = p.part_arrays(0)
    A, b, hist = reference_adapt(v, part["vocal_means"], part["vocal_covars"], part["startprob"],
                                 part["transmat"], 20.0, 2)
    np.testing.assert_allclose(tr["A"], A, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(tr["b"], b, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(tr["log_likelihood"], hist, rtol=1e-9)
    assert not np.allclose(A, np.eye(3))  # the other voice is adapted to
