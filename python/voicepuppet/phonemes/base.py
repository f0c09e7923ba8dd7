"""What the phoneme-driven models share: input checks (:func:`stack_sequences`,
:func:`check_labels`), the observations ``[y_t, y_t - y_{t-1}]`` and the base class
:class:`PhonemeModel` (dimensions, trained phones, global statistics).
"""

from __future__ import annotations

import numpy as np

from voicepuppet.phonemes.labels import N_PHONES

__all__ = ["PhonemeModel", "check_labels", "observations", "stack_sequences"]


def stack_sequences(Y_list, labels_list, n_dims: int | None = None):
    """Check and stack sequences of face vectors with their frame labels.

    Parameters
    ----------
    Y_list : sequence of array_like, each shape (T_s, K)
    labels_list : sequence of array_like of int, each shape (T_s,)
        Indices into :data:`voicepuppet.phonemes.labels.PHONES`.
    n_dims : int, optional
        Expected ``K``.

    Returns
    -------
    Y : ndarray, shape (N, K)
    labels : ndarray of int64, shape (N,)
    offsets : ndarray of int64, shape (S + 1,)

    Raises
    ------
    ValueError
        No sequences, mismatched counts or lengths, empty sequences, non-finite values, labels
        outside the phone set.
    """
    if isinstance(Y_list, np.ndarray) and Y_list.ndim == 2:
        Y_list = [Y_list]
    if isinstance(labels_list, np.ndarray) and labels_list.ndim == 1:
        labels_list = [labels_list]
    Y_list, labels_list = list(Y_list), list(labels_list)
    if not Y_list:
        raise ValueError("no sequences given; need at least one (Y [T, K], labels [T]) pair")
    if len(Y_list) != len(labels_list):
        raise ValueError(f"got {len(Y_list)} face sequences but {len(labels_list)} label sequences; "
                         f"give one label sequence per face sequence")
    ys, ls = [], []
    for i, (y, lab) in enumerate(zip(Y_list, labels_list)):
        y = np.asarray(y, dtype=np.float64)
        lab = np.asarray(lab)
        if y.ndim != 2 or y.shape[0] == 0 or y.shape[1] == 0:
            raise ValueError(f"sequence {i}: Y must be a non-empty 2-D array (frames, dims), got shape "
                             f"{y.shape}")
        if n_dims is not None and y.shape[1] != n_dims:
            raise ValueError(f"sequence {i}: Y has {y.shape[1]} dims, the model has {n_dims}")
        if ys and y.shape[1] != ys[0].shape[1]:
            raise ValueError(f"sequence {i}: Y has {y.shape[1]} dims, sequence 0 has {ys[0].shape[1]}")
        if not np.all(np.isfinite(y)):
            raise ValueError(f"sequence {i}: Y contains NaN or infinite values")
        if lab.shape != (y.shape[0],):
            raise ValueError(f"sequence {i}: labels must have shape ({y.shape[0]},) (one phone per "
                             f"frame), got {lab.shape}")
        if lab.size and not np.issubdtype(lab.dtype, np.integer):
            raise ValueError(f"sequence {i}: labels must be integer phone indices (see "
                             f"voicepuppet.phonemes.labels.frame_labels), got dtype {lab.dtype}")
        if lab.min() < 0 or lab.max() >= N_PHONES:
            raise ValueError(f"sequence {i}: labels must index the phone set 0..{N_PHONES - 1}, got "
                             f"{lab.min()}..{lab.max()}")
        ys.append(y)
        ls.append(lab.astype(np.int64))
    offsets = np.concatenate([[0], np.cumsum([len(y) for y in ys])]).astype(np.int64)
    return np.ascontiguousarray(np.concatenate(ys)), np.concatenate(ls), offsets


def check_labels(labels) -> np.ndarray:
    """Check the frame labels of one sequence to generate from.

    Parameters
    ----------
    labels : array_like of int, shape (T,)
        Indices into :data:`voicepuppet.phonemes.labels.PHONES`.

    Returns
    -------
    ndarray of int64, shape (T,)

    Raises
    ------
    ValueError
        Empty, not one-dimensional, not integers, or outside the phone set.
    """
    lab = np.asarray(labels)
    if lab.ndim != 1 or lab.size == 0:
        raise ValueError(f"labels must be a non-empty 1-D array of phone indices, got shape {lab.shape}")
    if not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels must be integer phone indices, got dtype {lab.dtype}")
    if lab.min() < 0 or lab.max() >= N_PHONES:
        raise ValueError(f"labels must index the phone set 0..{N_PHONES - 1}, got {lab.min()}..{lab.max()}")
    return np.ascontiguousarray(lab, dtype=np.int64)


def observations(Y: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """``o_t = [y_t, y_t - y_{t-1}]`` per sequence; a sequence's first frame takes the velocity
    of its second (zero for one-frame sequences).

    Parameters
    ----------
    Y : ndarray, shape (N, K)
    offsets : ndarray of int, shape (S + 1,)

    Returns
    -------
    ndarray, shape (N, 2K)
    """
    vel = np.zeros_like(Y)
    vel[1:] = Y[1:] - Y[:-1]
    for b, e in zip(offsets[:-1], offsets[1:]):
        vel[b] = vel[b + 1] if e - b > 1 else 0.0
    return np.hstack([Y, vel])


class PhonemeModel:
    """Shared bookkeeping of the phoneme-driven models: dims, trained phones, global statistics.

    Subclasses implement ``fit(Y_list, labels_list)``, ``generate(labels)`` and
    ``log_likelihood(Y_list, labels_list)``.

    Parameters
    ----------
    var_floor : float
        Variance floor as a fraction of each dimension's data variance, in (0, 1).

    Raises
    ------
    ValueError
        ``var_floor`` outside (0, 1).
    """

    name = "model"

    def __init__(self, var_floor: float = 1e-3):
        if not np.isfinite(var_floor) or not 0 < var_floor < 1:
            raise ValueError(f"var_floor must be in (0, 1) (a fraction of the data variance), got {var_floor}")
        self.var_floor = float(var_floor)
        self.n_dims_: int | None = None
        self.seen_: np.ndarray | None = None

    def _prepare(self, Y_list, labels_list):
        Y, lab, off = stack_sequences(Y_list, labels_list)
        self.n_dims_ = Y.shape[1]
        self.seen_ = np.bincount(lab, minlength=N_PHONES) > 0
        self.global_mean_ = Y.mean(axis=0)
        gvar = Y.var(axis=0)
        if np.any(gvar <= 0):
            gvar = np.where(gvar > 0, gvar, max(float(gvar.max()), 1.0))
        self.global_var_ = gvar
        self.floor_ = self.var_floor * gvar
        counts = np.bincount(lab, minlength=N_PHONES).astype(np.float64)
        sums = np.zeros((N_PHONES, Y.shape[1]))
        np.add.at(sums, lab, Y)
        with np.errstate(invalid="ignore", divide="ignore"):
            pm = sums / counts[:, None]
        self.phone_mean_ = np.where(self.seen_[:, None], pm, self.global_mean_)
        return Y, lab, off

    def _require_fit(self):
        if self.n_dims_ is None:
            raise ValueError(f"this {type(self).__name__} is not trained; call fit(Y_list, labels_list) first")

    @property
    def n_dims(self) -> int:
        """Face dimensions K of the trained model."""
        self._require_fit()
        return int(self.n_dims_)

    def _test_data(self, Y_list, labels_list):
        self._require_fit()
        return stack_sequences(Y_list, labels_list, self.n_dims_)
