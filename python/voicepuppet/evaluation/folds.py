"""k-fold cross-validation by sequence, and confidence intervals over folds.

Englebienne et al. (2007, §2) split their data into 10 folds "based on the number of sequences in
each set (rather than the total amount of data)": :func:`kfold` does the same, seeded. Errors are
averaged per fold and reported as the mean over folds with the 95% confidence interval of the
true error from Student's t with k - 1 degrees of freedom (:func:`mean_ci`), the error bars of
the paper's figure 4.
"""

from __future__ import annotations

import numpy as np

__all__ = ["kfold", "check_folds", "mean_ci", "fold_summary"]


def kfold(n_sequences: int, k: int = 10, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split ``n_sequences`` sequences into ``k`` folds of (nearly) equal sequence counts.

    Parameters
    ----------
    n_sequences : int
        Number of sequences ``S``.
    k : int
        Number of folds, ``2 <= k <= S`` (every test fold non-empty, every training set non-empty).
    seed : int
        Seeds the shuffle of the sequences.

    Returns
    -------
    list of (train, test)
        ``k`` pairs of sorted int64 index arrays; the test folds partition ``0..S-1``.

    Raises
    ------
    ValueError
        ``k < 2`` or ``k > S`` (a fold would be empty): the message says how many sequences there are.
    """
    if int(n_sequences) != n_sequences or n_sequences < 0:
        raise ValueError(f"n_sequences must be a non-negative integer, got {n_sequences}")
    if int(k) != k or k < 2:
        raise ValueError(f"k must be an integer >= 2 (folds), got {k}")
    if k > n_sequences:
        raise ValueError(f"cannot make {k} non-empty folds from {n_sequences} sequences; use k <= "
                         f"{n_sequences} or more (shorter) sequences")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    order = np.random.default_rng(int(seed)).permutation(int(n_sequences))
    folds = np.array_split(order, int(k))
    out = []
    for i, test in enumerate(folds):
        train = np.concatenate([f for j, f in enumerate(folds) if j != i])
        out.append((np.sort(train).astype(np.int64), np.sort(test).astype(np.int64)))
    return out


def check_folds(folds, n_sequences: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Folds given as they are (e.g. :func:`voicepuppet.evaluation.corpus.reader_folds`), checked.

    Parameters
    ----------
    folds : sequence of (train, test)
        Index arrays into ``n_sequences`` sequences; the test sets need not partition them.
    n_sequences : int
        Number of sequences ``S``.

    Returns
    -------
    list of (train, test)
        Sorted int64 index arrays.

    Raises
    ------
    ValueError
        Fewer than two folds, an empty side, an index outside ``0..S-1`` or repeated, or a
        sequence on both sides of a fold.
    """
    out = []
    for j, pair in enumerate(folds):
        train, test = (np.sort(np.asarray(side, dtype=np.int64).ravel()) for side in pair)
        for name, side in (("train", train), ("test", test)):
            if not len(side) or side.min() < 0 or side.max() >= n_sequences or len(np.unique(side)) != len(side):
                raise ValueError(f"fold {j}: its {name} sequences must be distinct indices in 0..{n_sequences - 1}, "
                                 f"at least one; got {side.tolist()}")
        if np.intersect1d(train, test).size:
            raise ValueError(f"fold {j}: sequences {np.intersect1d(train, test).tolist()} are in training and test")
        out.append((train, test))
    if len(out) < 2:
        raise ValueError(f"give two or more folds, got {len(out)}")
    return out


def mean_ci(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean of per-fold values and its ``level`` confidence interval (Student's t).

    Parameters
    ----------
    values : array_like, shape (k,)
        One value per fold (finite).
    level : float
        Confidence level in (0, 1).

    Returns
    -------
    (mean, low, high) : tuple of float
        With one value the interval is (mean, mean).

    Raises
    ------
    ValueError
        No values, a value that is not finite, or ``level`` outside (0, 1).
    """
    from scipy import stats

    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 0:
        raise ValueError("no values to average (empty folds?)")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"values must be finite, got {v}")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    m = float(v.mean())
    if v.size == 1:
        return m, m, m
    half = float(stats.t.ppf(0.5 + level / 2, v.size - 1) * v.std(ddof=1) / np.sqrt(v.size))
    return m, m - half, m + half


def fold_summary(values) -> dict:
    """Per-fold values with their mean and 95% interval (:func:`mean_ci`), as the evaluation
    harnesses report every measure.

    Parameters
    ----------
    values : sequence of float
        One value per fold (finite).

    Returns
    -------
    dict
        ``{"mean", "low", "high", "folds"}``: the mean, the interval's ends and the values.
    """
    mean, low, high = mean_ci(values)
    return {"mean": mean, "low": low, "high": high, "folds": [float(v) for v in values]}


def over_folds(values, n_folds: int, measure: str) -> dict | None:
    """:func:`fold_summary` of a measure's per-fold values ``[(fold, value)]``
    when every fold has one; for ``closed``, over the folds that have (those whose test sequences
    hold a B, P or M), at least two, listed in ``fold_index``; else None (not reported).

    Parameters
    ----------
    values : list of (int, float)
        ``(fold index, value)`` of the folds that have the measure.
    n_folds : int
        Number of folds.
    measure : str
        The measure's name (``"closed"`` may miss folds).

    Returns
    -------
    dict or None
        The :func:`fold_summary` (plus ``fold_index`` for a ``closed`` that misses folds), or None.
    """
    if len(values) == n_folds:
        return fold_summary([v for _, v in values])
    if measure == "closed" and len(values) >= 2:
        return {**fold_summary([v for _, v in values]), "fold_index": [i for i, _ in values]}
    return None
