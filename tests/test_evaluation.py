import numpy as np
import pytest

from voicepuppet import evaluation
from voicepuppet.puppet import Puppet

from test_puppet import _planted


def test_context_stack_edges():
    A = np.arange(5.0)[:, None]
    S = evaluation.context_stack(A, 2)
    np.testing.assert_array_equal(S[0], [0, 0, 0, 1, 2])
    np.testing.assert_array_equal(S[4], [2, 3, 4, 4, 4])


def test_ridge_recovers_a_planted_lagged_map(rng):
    A = rng.normal(size=(2000, 3))
    W1, W2 = rng.normal(size=(3, 2)), rng.normal(size=(3, 2))
    Y = np.roll(A, 2, axis=0) @ W1 + np.roll(A, -1, axis=0) @ W2 + 0.01 * rng.normal(size=(2000, 2))
    model = evaluation.RidgeBaseline(k=3).fit([A[:1500]], [Y[:1500]])
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
    pts, feats, _ = _planted(np.random.default_rng(7))
    test_pts, test_feats, _ = _planted(np.random.default_rng(8), T=300)
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
    table = evaluation.format_table(r)
    assert "| voice |" in table and "| ridge |" in table
