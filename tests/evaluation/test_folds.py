"""Tests of voicepuppet.evaluation.folds: folds partition the sequences by count, are seeded, and the
confidence interval matches the t-interval computed from its definition (and covers the true mean
at about the nominal rate on planted Gaussian data); given folds are checked, and the folds that
leave a voice out (voicepuppet.evaluation.corpus.reader_folds) are what they say."""

from __future__ import annotations

import numpy as np
import pytest

from voicepuppet.evaluation.corpus import Sequence, reader_folds
from voicepuppet.evaluation.folds import check_folds, kfold, mean_ci

SEED = 20261123


@pytest.mark.parametrize("n,k", [(10, 10), (23, 10), (5, 2), (41, 7)])
def test_kfold_partitions_by_sequence_count(n, k):
    folds = kfold(n, k, seed=SEED)
    assert len(folds) == k
    tests = np.concatenate([t for _, t in folds])
    assert sorted(tests.tolist()) == list(range(n))
    sizes = [len(t) for _, t in folds]
    assert max(sizes) - min(sizes) <= 1
    for train, test in folds:
        assert len(np.intersect1d(train, test)) == 0 and len(train) + len(test) == n
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(folds, kfold(n, k, seed=SEED)))
    if n > k:
        assert any(not np.array_equal(a[1], b[1]) for a, b in zip(folds, kfold(n, k, seed=SEED + 1)))


def test_kfold_empty_folds_are_an_error():
    with pytest.raises(ValueError, match="cannot make 10 non-empty folds from 4 sequences"):
        kfold(4, 10)
    with pytest.raises(ValueError, match="k must be"):
        kfold(4, 1)


def test_mean_ci_definition_and_coverage():
    from scipy import stats

    v = np.array([1.0, 2.0, 4.0, 3.5, 2.5])
    m, lo, hi = mean_ci(v)
    half = stats.t.ppf(0.975, 4) * np.std(v, ddof=1) / np.sqrt(5)
    assert (m, lo, hi) == pytest.approx((v.mean(), v.mean() - half, v.mean() + half))
    rng = np.random.default_rng(SEED)
    hits = 0
    for _ in range(2000):
        _, lo, hi = mean_ci(rng.normal(3.0, 2.0, size=10))
        hits += lo <= 3.0 <= hi
    assert 0.93 <= hits / 2000 <= 0.97
    assert mean_ci([2.0]) == (2.0, 2.0, 2.0)
    with pytest.raises(ValueError, match="empty"):
        mean_ci([])


def test_given_folds_are_checked_and_kept():
    folds = check_folds([([3, 1], [0]), (np.array([0]), [2, 1])], 4)
    assert [(a.tolist(), b.tolist()) for a, b in folds] == [([1, 3], [0]), ([0], [1, 2])]
    assert all(a.dtype == np.int64 and b.dtype == np.int64 for a, b in folds)
    for bad, match in [([([0], [1])], "two or more folds"), ([([0], []), ([1], [0])], "at least one"),
                       ([([0, 4], [1]), ([1], [0])], r"indices in 0\.\.3"), ([([0, 0], [1]), ([1], [0])], "distinct"),
                       ([([0, 1], [1]), ([1], [0])], r"sequences \[1\] are in training and test")]:
        with pytest.raises(ValueError, match=match):
            check_folds(bad, 4)


def _read(name, reader):
    return Sequence(name, np.zeros((3, 68, 2)), 30.0, np.zeros(3, np.int64), meta={"reader": reader})


def test_reader_folds_leave_each_voice_out_then_test_the_held_out_speakers():
    seqs = [_read("train_00", "A"), _read("train_01", "A"), _read("train_02", "B"), _read("test_00", "C"),
            _read("test_01", "D")]
    folds = reader_folds(seqs)
    assert [(a.tolist(), b.tolist()) for a, b in folds] == [([0, 1], [2]), ([2], [0, 1]), ([0, 1, 2], [3, 4])]
    with pytest.raises(ValueError, match=r"two readers .* got readers \['A'\]"):
        reader_folds([_read("train_00", "A"), _read("train_01", "A"), _read("test_00", "C")])
    with pytest.raises(ValueError, match="and 0 held out"):
        reader_folds(seqs[:3])
    unlabelled = [Sequence("train_00", np.zeros((3, 68, 2)), 30.0, np.zeros(3, np.int64)), *seqs[1:]]
    with pytest.raises(ValueError, match="None"):
        reader_folds(unlabelled)
