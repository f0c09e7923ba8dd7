"""Tests of voicepuppet.evaluation.folds: folds partition the sequences by count, are seeded, and the
confidence interval matches the t-interval computed from its definition (and covers the true mean
at about the nominal rate on planted Gaussian data)."""

from __future__ import annotations

import numpy as np
import pytest

from voicepuppet.evaluation.folds import kfold, mean_ci

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
