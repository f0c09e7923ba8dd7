import numpy as np
import pytest

from voicepuppet.evaluation import crossval, report
from voicepuppet.evaluation import split as evaluation
from voicepuppet.puppet import guide
from voicepuppet.puppet.model import Puppet

from support import planted_puppet_data


def test_context_stack_edges():
    A = np.arange(5.0)[:, None]
    S = guide.context_stack(A, 2)
    np.testing.assert_array_equal(S[0], [0, 0, 0, 1, 2])
    np.testing.assert_array_equal(S[4], [2, 3, 4, 4, 4])


def test_ridge_recovers_a_planted_lagged_map(rng):
    A = rng.normal(size=(2000, 3))
    W1, W2 = rng.normal(size=(3, 2)), rng.normal(size=(3, 2))
    Y = np.roll(A, 2, axis=0) @ W1 + np.roll(A, -1, axis=0) @ W2 + 0.01 * rng.normal(size=(2000, 2))
    model = guide.RidgeBaseline(k=3).fit([A[:1500]], [Y[:1500]])
    pred = model.predict(A[1500:])
    inner = slice(5, -5)  # away from the wrapped edges of np.roll
    assert np.sqrt(np.mean((pred[inner] - Y[1500:][inner]) ** 2)) < 0.05
    assert model.alpha <= 1.0


def test_bits_per_frame_orders_codings(rng):
    assert evaluation.bits_per_frame(np.zeros(3000, int)) < 0.1  # a few bytes for 3000 frames
    runs = np.repeat(rng.integers(0, 40, 300), 10)
    noise = rng.integers(0, 40, 3000)
    assert evaluation.bits_per_frame(runs) < evaluation.bits_per_frame(noise)
    assert evaluation.bits_per_frame(noise) > 4.5  # log2(40) = 5.3 bits of entropy per frame


def test_evaluate_split_on_planted_puppet():
    pts, feats, _ = planted_puppet_data(np.random.default_rng(7))
    test_pts, test_feats, _ = planted_puppet_data(np.random.default_rng(8), T=300)
    p = Puppet.train([pts], features_list=[feats], fps=30.0, n_states=6, n_iter=15, n_components=3)

    class Feats:  # animate the planted features through the evaluation's audio path
        def __init__(self, f):
            self.f = f

    p.audio_features = lambda audio, n_out=None, progress=False: audio.f
    r = evaluation.evaluate_split(p, [(pts, Feats(feats))], [(test_pts, Feats(test_feats))])
    rows = r["rows"]
    assert rows["voice"]["test"]["err"] < 0.2 < rows["mean-face"]["test"]["err"]
    assert rows["states"]["test"]["err"] < 0.2
    assert r["model"]["bits_per_frame"] < 2.0
    table = report.format_split(r)
    assert "| voice |" in table and "| ridge |" in table
    n, arcs = r["model"]["states"][0], r["model"]["arcs"][0]
    assert f"\nstates {n}, arcs {arcs}, perplexity" in table and isinstance(n, int)  # not [6.0]
    assert r["model"]["guide_weight"] == p.guide_weight and r["model"]["guide_weight_cv"]
    assert table.endswith(f"bits/frame, guide weight {p.guide_weight:g} (chosen by cross-validation)")


def test_evaluate_split_fits_the_ridge_on_the_puppets_landmarks():
    # A puppet trained on noisy landmarks (as tracked ones) is measured against the clean truth;
    # the ridge must learn from the same noisy landmarks, not from the truth the puppet never saw.
    pts, feats, _ = planted_puppet_data(np.random.default_rng(7))
    test_pts, test_feats, _ = planted_puppet_data(np.random.default_rng(8), T=300)
    noisy = pts + np.random.default_rng(9).normal(scale=0.2 * pts.std(), size=pts.shape)
    p = Puppet.train([noisy], features_list=[feats], fps=30.0, n_states=6, n_iter=15, n_components=3)

    class Feats:
        def __init__(self, f):
            self.f = f

    p.audio_features = lambda audio, n_out=None, progress=False: audio.f
    train, tests = [(pts, Feats(feats))], [(test_pts, Feats(test_feats))]
    clean = evaluation.evaluate_split(p, train, tests, posterior=False)["rows"]
    fair = evaluation.evaluate_split(p, train, tests, fit_points=[noisy], posterior=False)["rows"]
    assert fair["voice"] == clean["voice"]  # the puppet and the measuring stick are the same
    # fitted on the truth the ridge scores 0.012 on the test frames; on the noisy landmarks 0.024
    assert fair["ridge"]["test"]["err"] > 1.5 * clean["ridge"]["test"]["err"]
    with pytest.raises(ValueError, match="fit_points"):
        evaluation.evaluate_split(p, train, tests, fit_points=[noisy[:-1]])


def _planted_sequences(n_seq=6, T=240):
    from voicepuppet.evaluation.corpus import Sequence

    seqs, feats = [], []
    for s in range(n_seq):
        pts, f, _ = planted_puppet_data(np.random.default_rng(100 + s), T=T)
        seqs.append(Sequence(f"s{s}", pts, 30.0, np.zeros(T, np.int64)))
        feats.append(f)
    return seqs, feats


def test_compare_training_pairs_folds_and_separates_a_crippled_variant():
    """A variant whose vocal Gaussians are all the pooled one (shrinkage 1e6: the audio cannot
    steer the decoding) must lose on Err in every fold, with a paired interval below zero; the
    differences are the fold-by-fold differences of the variants' values; a variant paired
    with an identical copy of itself differs by exactly 0."""
    seqs, feats = _planted_sequences()
    # unguided: the guide's ridge would steer the face from the audio past a deaf vocal model
    # (at λ = 4 the crippled variant scores 0.07)
    base = {"n_states": 6, "n_iter": 12, "n_components": 3, "guide": "none"}
    variants = {"good": base, "same": dict(base), "guided": dict(base, guide="ridge", guide_weight=2.0),
                "deaf": dict(base, vocal_shrinkage=1e6)}
    r = crossval.compare_training(seqs, variants, k=3, seed=0, n_components=3, features=feats)
    good, deaf = r["variants"]["good"], r["variants"]["deaf"]
    print({n: v["err"]["folds"] for n, v in r["variants"].items()})
    assert good["err"]["mean"] < 0.3 < deaf["err"]["mean"]
    d = r["differences"]["good"]["err"]
    np.testing.assert_allclose(d["folds"], np.subtract(good["err"]["folds"], deaf["err"]["folds"]), atol=1e-12)
    assert d["high"] < 0 and d["low"] < d["mean"] < d["high"]
    same = r["differences"]["same"]
    np.testing.assert_allclose(np.subtract(same["err"]["folds"], d["folds"]), 0, atol=1e-12)  # same == good
    for m in ("err", "entropy_rate", "states_err"):
        assert all(np.isfinite(good[m]["folds"])) and len(good[m]["folds"]) == 3
    assert all(0 <= v < np.log(6) for v in good["entropy_rate"]["folds"])
    assert "closed" not in good  # the planted sequences' labels hold no B, P, M
    assert sum(len(f) for f in r["config"]["folds"]) == len(seqs)
    # what each fold's puppet is: its guide's weight (0 without a guide), states and arcs
    assert good["guide_weight"]["folds"] == [0.0] * 3 and r["variants"]["guided"]["guide_weight"]["folds"] == [2.0] * 3
    assert all(0 < a <= s * s for a, s in zip(good["arcs"]["folds"], good["states"]["folds"]))
    table = report.format_comparison(r)
    assert "| good − deaf |" in table and "| deaf |" in table
    assert table.splitlines()[0].endswith("| states | arcs | guide_weight |")
    assert "states, arcs, guide_weight: what the puppets are" in table


def test_compare_training_refuses_bad_input():
    seqs, feats = _planted_sequences(n_seq=3, T=120)
    with pytest.raises(ValueError, match="at least two"):
        crossval.compare_training(seqs, {"a": {}}, k=2, features=feats)
    with pytest.raises(ValueError, match="unknown training options"):
        crossval.compare_training(seqs, {"a": {}, "b": {"n_stats": 3}}, k=2, features=feats)
    with pytest.raises(ValueError, match="baseline"):
        crossval.compare_training(seqs, {"a": {}, "b": {}}, baseline="c", k=2, features=feats)
    with pytest.raises(ValueError, match="one row per"):
        crossval.compare_training(seqs, {"a": {}, "b": {}}, k=2, features=feats[:2])


def test_compare_training_learns_from_train_points_and_measures_against_the_truth(monkeypatch):
    """Sequences with separate training landmarks (as tracked ones): equal to ``points`` they
    change nothing; time-reversed (the audio no longer says where the face is) the puppets learn
    nothing useful, while the measure is still against the true ``points``; landmarks of
    another shape are refused with the sequence named."""
    from dataclasses import replace

    seqs, feats = _planted_sequences(n_seq=4, T=240)
    variants = {"a": {"n_states": 6, "n_iter": 12, "n_components": 3},
                "b": {"n_states": 6, "n_iter": 12, "n_components": 3, "prior": "ml"}}

    def run(ss):
        return crossval.compare_training(ss, variants, k=2, seed=0, n_components=3, features=feats)

    plain = run(seqs)
    assert plain["config"]["separate_training_landmarks"] is False
    same = run([replace(s, train_points=s.points.copy()) for s in seqs])
    assert same["config"]["separate_training_landmarks"] is True
    for name in variants:
        for m in ("err", "entropy_rate", "states_err", "arcs"):
            # (equal up to rounding: a copy may sit differently aligned for the vector kernels)
            np.testing.assert_allclose(same["variants"][name][m]["folds"], plain["variants"][name][m]["folds"],
                                       rtol=1e-9)
    from voicepuppet.evaluation import crossval as ev
    from voicepuppet.evaluation.folds import kfold
    from voicepuppet.face import FaceSpace

    seen = []  # what every fold is measured against, in the face space it fitted
    fold_metrics = ev._fold_metrics
    monkeypatch.setattr(ev, "_fold_metrics",
                        lambda p, t, fs, ll, shut=None: seen.append((t, fs)) or fold_metrics(p, t, fs, ll, shut))
    # reversed in time, and a fixed deformation so that the face space fitted on them differs
    offset = np.random.default_rng(3).normal(scale=0.5, size=seqs[0].points.shape[1:])
    rev = run([replace(s, train_points=s.points[::-1] + offset) for s in seqs])
    folds = kfold(len(seqs), 2, 0)
    assert len(seen) == 2 * len(folds) * len(variants)  # voice and states, per variant and fold
    for j, (truths, fs) in enumerate(seen):
        te = folds[j // (2 * len(variants))][1]
        for y, i in zip(truths, te, strict=True):
            np.testing.assert_array_equal(y, fs.encode(seqs[i].points)[0])
        # ... in the face space fitted on the training sequences' train_points, not on their truth
        tr = folds[j // (2 * len(variants))][0]
        np.testing.assert_allclose(fs.mean_shape, FaceSpace.fit([seqs[i].points[::-1] + offset for i in tr],
                                                                n_components=3).mean_shape, atol=1e-12)
        assert not np.allclose(fs.mean_shape, FaceSpace.fit([seqs[i].points for i in tr],
                                                            n_components=3).mean_shape, atol=1e-3)
    print({n: (plain["variants"][n]["err"]["mean"], rev["variants"][n]["err"]["mean"]) for n in variants})
    for name in variants:
        assert plain["variants"][name]["err"]["mean"] < 0.3 < rev["variants"][name]["err"]["mean"]
    assert "separate training landmarks" in report.format_comparison(rev)
    bad = [replace(s, train_points=s.points[:-1]) if i == 2 else s for i, s in enumerate(seqs)]
    with pytest.raises(ValueError, match="sequence s2: train_points must have the shape"):
        run(bad)
