"""A learned projection of the audio for the vocal model (training option ``vocal_features``).

The vocal Gaussians of Brand's remap (§4.3) may live in any audio-feature space. With
``vocal_features="projected"`` they live on ŷ_t, the ridge regression's prediction of the face
coordinates y_t from the standardised audio features of frames t−k .. t+k (the map of the ridge
baseline, :class:`RidgeBaseline`): K ≤ 12 dimensions that carry what the
face needs and little of the voice, instead of 48 that carry the voice too (docs/results.md,
"Voices never heard").

The training ŷ are **cross-fitted**: each training fold's ŷ is predicted by a map fitted without
it, so the vocal Gaussians see ŷ as noisy as novel audio gives them. The map stored in the
puppet file is fitted on all training frames and standardised by the cross-fitted ŷ's mean and
standard deviation, folded into one affine map (arrays ``audio/projection*``, applied by C++
``Puppet::vocal_features``):

    v_t = [z_{t−k}, …, z_{t+k}] · P + c,   z = the first ``columns`` standardised feature columns,
    frames beyond the ends repeating the first or last frame.

The same ridge, unstandardised, is a puppet's **guide** (training option ``guide="ridge"``,
:func:`fit_guide`): its prediction ŷ and the covariance R of its cross-fitted residuals enter
the trajectory solve as per-frame Gaussian evidence (arrays ``guide/*``, applied by C++).
"""

from __future__ import annotations

import numpy as np

from voicepuppet.audio import Standardizer
from voicepuppet.blas import limited
from voicepuppet.layout import MOUTH, N_POINTS

RIDGE_CONTEXT = 5
RIDGE_ALPHAS = tuple(10.0 ** np.arange(-2, 5))


def context_stack(A, k: int = RIDGE_CONTEXT) -> np.ndarray:
    """Frames with their ±k neighbours side by side, edges repeated: (T, A·(2k+1)).

    Parameters
    ----------
    A : array_like, shape (T, A)
        Frames of features.
    k : int
        Frames of context on each side (default :data:`RIDGE_CONTEXT`, 5).

    Returns
    -------
    ndarray, shape (T, A·(2k+1))
        Row t holds frames t−k .. t+k, frames beyond the ends repeating the first or last frame.
    """
    A = np.asarray(A, dtype=np.float64)
    T = len(A)
    idx = np.clip(np.arange(T)[:, None] + np.arange(-k, k + 1)[None, :], 0, T - 1)
    return A[idx].reshape(T, -1)


def lips_score(face_space) -> np.ndarray:
    """The linear map from face coordinates to the lips' points of the normalised shapes they
    make (:meth:`voicepuppet.face.FaceSpace.shapes`, 68-point layout: :data:`voicepuppet.layout.MOUTH`):
    :class:`RidgeBaseline`'s ``score`` for an α chosen on the mouth (``guide_alpha="lips"``).

    Parameters
    ----------
    face_space : voicepuppet.face.FaceSpace
        A face space of the 68-point layout.

    Returns
    -------
    ndarray, shape (K, 2·20)
        Row k: how the lips' coordinates move per unit of face coordinate k.

    Raises
    ------
    ValueError
        The face space is not of the 68-point layout.
    """
    if face_space.n_points != N_POINTS:
        raise ValueError(f"guide_alpha='lips' needs the {N_POINTS}-point layout (its lips are points "
                         f"48-67); these faces have {face_space.n_points} points: use 'shared'")
    K = face_space.n_dims
    lips = face_space.shapes(np.vstack([np.zeros(K), np.eye(K)]))[:, MOUTH].reshape(K + 1, -1)
    return lips[1:] - lips[0]


class RidgeBaseline:
    """Ridge regression from context-stacked audio features to face coordinates.

    Parameters
    ----------
    k : int
        Frames of context on each side (:func:`context_stack`; default :data:`RIDGE_CONTEXT`, 5).
    alphas : sequence of float
        The regularisation weights α to choose from (default ``RIDGE_ALPHAS``, 10⁻² .. 10⁴).
    n_folds : int
        Folds of the cross-validation that chooses α (default 5).
    per_target : bool
        Choose α for each face coordinate on its own cross-validated error (default False: one α
        for all, on their summed error). Coordinates differ in how much of them the audio
        predicts: one α, chosen where the summed error is lowest, over-shrinks those it predicts
        best when the others dominate the sum.
    score : array_like, shape (K, M), optional
        Choose the one α on the cross-validated error of ``(Ŷ − Y) @ score`` instead of ``Ŷ − Y``:
        e.g. the lips' points of the shapes the face coordinates make (:func:`lips_score`), so
        that α suits the mouth rather than the head's pose, which the audio hardly predicts and
        which dominates the coordinates' summed error. Not with ``per_target``.

    Attributes
    ----------
    k, alphas, n_folds, per_target, score
        The constructor's arguments.
    alpha : float or ndarray of shape (K,)
        The α chosen by :meth:`fit` (one per face coordinate with ``per_target``).
    W : ndarray, shape (A·(2k+1), K)
        The fitted map (on centred data).
    x_mean, y_mean : ndarray
        The means of the context-stacked features and of the face coordinates, set by :meth:`fit`.
    """

    def __init__(self, k: int = RIDGE_CONTEXT, alphas=RIDGE_ALPHAS, n_folds: int = 5, per_target: bool = False,
                 score=None):
        self.k, self.alphas, self.n_folds, self.per_target = int(k), tuple(alphas), int(n_folds), bool(per_target)
        self.score = None if score is None else np.asarray(score, dtype=np.float64)
        if self.score is not None and per_target:
            raise ValueError("score chooses one α for all face coordinates: give it without per_target")
        if self.score is not None and (self.score.ndim != 2 or not np.isfinite(self.score).all()):
            raise ValueError(f"score must be a finite (K, M) matrix, got shape {self.score.shape}")

    @staticmethod
    def _solve(G, B, alpha):
        from scipy.linalg import cho_factor, cho_solve

        return cho_solve(cho_factor(G + alpha * np.eye(len(G)), lower=True), B)

    @limited
    def fit(self, A_list, Y_list, folds=None) -> "RidgeBaseline":
        """Fit on the sequences ``A_list`` / ``Y_list``, α chosen by ``n_folds``-fold CV over
        contiguous blocks of their stacked frames, or over ``folds`` (frame indices) if given.

        Parameters
        ----------
        A_list : list of array_like, shape (T_s, A)
            Features of each sequence (context-stacked per sequence).
        Y_list : list of array_like, shape (T_s, K)
            Face coordinates of the same frames.
        folds : list of ndarray of int, optional
            Frame indices (into the stacked frames) of each cross-validation fold; default:
            ``n_folds`` contiguous blocks.

        Returns
        -------
        RidgeBaseline
            ``self``, fitted (``alpha``, ``W``, ``x_mean``, ``y_mean``).
        """
        X = np.vstack([context_stack(a, self.k) for a in A_list])
        Y = np.vstack(Y_list)
        self.x_mean, self.y_mean = X.mean(axis=0), Y.mean(axis=0)
        Xc, Yc = X - self.x_mean, Y - self.y_mean
        folds = np.array_split(np.arange(len(X)), self.n_folds) if folds is None else folds
        # Normal equations per fold once; a fold's training system is the total minus the fold.
        parts = [(Xc[f].T @ Xc[f], Xc[f].T @ Yc[f]) for f in folds]
        G, B = sum(p[0] for p in parts), sum(p[1] for p in parts)
        if self.score is not None and len(self.score) != Y.shape[1]:
            raise ValueError(f"score has {len(self.score)} rows for {Y.shape[1]} face coordinates")
        S = np.eye(Y.shape[1]) if self.score is None else self.score
        sse = np.zeros((len(self.alphas), S.shape[1]))  # per α and scored column
        for i, alpha in enumerate(self.alphas):
            for f, (Gf, Bf) in zip(folds, parts):
                sse[i] += np.sum(((Xc[f] @ self._solve(G - Gf, B - Bf, alpha) - Yc[f]) @ S) ** 2, axis=0)
        if not self.per_target:
            self.alpha = self.alphas[int(np.argmin(sse.sum(axis=1)))]
            self.W = self._solve(G, B, self.alpha)
            return self
        best = np.argmin(sse, axis=0)
        self.alpha = np.asarray(self.alphas, dtype=np.float64)[best]
        self.W = np.empty((X.shape[1], Y.shape[1]))
        for i in np.unique(best):
            self.W[:, best == i] = self._solve(G, B[:, best == i], self.alphas[i])
        return self

    def predict(self, A) -> np.ndarray:
        """Face coordinates predicted for features ``A`` [T, A]: (T, K).

        Parameters
        ----------
        A : array_like, shape (T, A)
            Features of one sequence, made as those given to :meth:`fit`.

        Returns
        -------
        ndarray, shape (T, K)
            The predicted face coordinates.
        """
        return (context_stack(A, self.k) - self.x_mean) @ self.W + self.y_mean


#: Guides of :meth:`voicepuppet.puppet.model.Puppet.train` (option ``guide``): "ridge" adds the
#: ridge's prediction of the face as evidence in the trajectory solve, "none" is Brand's solve.
GUIDES = ("ridge", "none")

#: Vocal feature spaces of :meth:`voicepuppet.puppet.model.Puppet.train` (option ``vocal_features``).
VOCAL_FEATURES = ("audio", "projected")


def cross_fit_folds(lengths, n_folds: int = 5, groups=None) -> list:
    """Frame indices of the cross-fitting folds over sequences of ``lengths`` (concatenated).

    With at least ``n_folds`` sequences a fold is a run of whole consecutive sequences; with
    fewer, every sequence is cut into ``n_folds`` consecutive blocks and fold j holds block j of
    each (so one long training video is cross-fitted too). ``groups`` (one label per sequence)
    keeps sequences together: copies of one recording (its noisy conditions, all of one length)
    are then never on both sides of a fold; the count that matters is that of the groups.

    Parameters
    ----------
    lengths : array_like of int, shape (S,)
        Frames per sequence.
    n_folds : int
        Number of folds (default 5).
    groups : array_like, shape (S,), optional
        One label per sequence; sequences with one label stay in one fold.

    Returns
    -------
    list of ndarray of int
        ``n_folds`` arrays of frame indices into the concatenated sequences.

    Raises
    ------
    ValueError
        ``groups`` without one label per sequence.
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    seq_frames = [np.arange(s, s + n) for s, n in zip(starts, lengths)]
    labels = np.arange(len(lengths)) if groups is None else np.asarray(groups)
    if len(labels) != len(lengths):
        raise ValueError(f"groups must give one label per sequence: {len(labels)} for {len(lengths)}")
    order = list(dict.fromkeys(labels.tolist()))  # the groups in order of first appearance
    if len(order) >= n_folds:
        chunks = [set(c) for c in np.array_split(np.array(order, dtype=object), n_folds)]
        return [np.concatenate([f for f, g in zip(seq_frames, labels.tolist()) if g in c]) for c in chunks]
    blocks = [np.array_split(f, n_folds) for f in seq_frames]
    return [np.concatenate([b[j] for b in blocks]) for j in range(n_folds)]


def sequence_runs(frames, sequence) -> list:
    """Sorted frame indices cut into runs of consecutive frames of one sequence each.

    Parameters
    ----------
    frames : array_like of int
        Sorted frame indices.
    sequence : ndarray of int, shape (T,)
        ``sequence[t]``: the sequence of frame t.

    Returns
    -------
    list of ndarray of int
        The runs, in order.
    """
    frames = np.asarray(frames)
    cut = np.flatnonzero((np.diff(frames) != 1) | (np.diff(sequence[frames]) != 0)) + 1
    return np.split(frames, cut)


def cross_fit(X, Y, lengths, n_folds: int = 5, groups=None, per_target: bool = False, score=None) -> np.ndarray:
    """Cross-fitted ridge predictions (T, K) of ``Y`` from the rows of ``X`` (T, C).

    The frames of each fold of :func:`cross_fit_folds` are predicted by a :class:`RidgeBaseline`
    (its own α choice) fitted on the other folds, so no frame's prediction has seen its own
    target (nor, with ``groups``, another copy of it).

    Parameters
    ----------
    X : ndarray, shape (T, C)
        Regression inputs, one row per frame (already context-stacked: no further context is added).
    Y : array_like, shape (T, K)
        Targets.
    lengths : array_like of int, shape (S,)
        Frames per sequence (they add up to T).
    n_folds : int
        Cross-fitting folds (default 5).
    groups : array_like, shape (S,), optional
        One label per sequence: sequences that are copies of one recording (:func:`cross_fit_folds`).
    per_target : bool
        α per face coordinate (:class:`RidgeBaseline`).
    score : array_like, shape (K, M), optional
        What α is chosen on (:class:`RidgeBaseline`).

    Returns
    -------
    ndarray, shape (T, K)
        The cross-fitted predictions.
    """
    yhat = np.empty(np.shape(Y), dtype=np.float64)
    lengths = np.asarray(lengths, dtype=np.int64)
    seq = np.repeat(np.arange(len(lengths)), lengths)
    labels = None if groups is None else np.asarray(groups)
    for fold in cross_fit_folds(lengths, n_folds, labels):
        rest = np.setdiff1d(np.arange(len(X)), fold)
        ridge = RidgeBaseline(0, per_target=per_target, score=score)
        if labels is None:
            ridge.fit([X[rest]], [Y[rest]])
        else:  # α's own folds keep the copies together too
            runs = sequence_runs(rest, seq)
            ridge.fit([X[rest]], [Y[rest]], folds=cross_fit_folds([len(r) for r in runs], ridge.n_folds,
                                                                  [labels[seq[r[0]]] for r in runs]))
        yhat[fold] = ridge.predict(X[fold])
    return yhat


def _context_ridge(standardized, face, lengths, *, context, columns, n_folds, what: str, option: str, groups=None,
                   per_target: bool = False, score=None):
    """The ridge from ±k frames of the first ``columns`` of ``standardized`` (T, A') to ``face``
    (T, K), its arguments checked (``option`` names the context in errors, ``what`` the map):
    ``(Y, k, yhat, full)``, the face as float, k, the cross-fitted predictions (T, K) and the
    :class:`RidgeBaseline` fitted on all frames (rows context-stacked per sequence, edges
    repeated); ``per_target``: α per face coordinate; ``score``: what one α is chosen on."""
    Z = np.asarray(standardized, dtype=np.float64)
    Y = np.asarray(face, dtype=np.float64)
    lengths = np.asarray(lengths, dtype=np.int64)
    if isinstance(context, bool) or int(context) != context or context < 0:
        raise ValueError(f"{option} must be an integer >= 0, got {context!r}")
    if not 1 <= columns <= Z.shape[1]:
        raise ValueError(f"columns must be in [1, {Z.shape[1]}], got {columns!r}")
    if len(Z) != len(Y) or lengths.sum() != len(Z):
        raise ValueError(f"standardized {Z.shape} and face {Y.shape} must have the frames of lengths "
                         f"(adding up to {int(lengths.sum())})")
    if len(Z) < 2 * n_folds:
        raise ValueError(f"{len(Z)} training frames are too few to cross-fit {what} over "
                         f"{n_folds} folds; give more training audio")
    k = int(context)
    Z = Z[:, :columns]
    bounds = np.concatenate([[0], np.cumsum(lengths)])
    # Context is stacked per sequence (edges repeated), then frames go to folds.
    X = np.vstack([context_stack(Z[a:b], k) for a, b in zip(bounds[:-1], bounds[1:])])
    full = RidgeBaseline(0, per_target=per_target, score=score)
    full.fit([X], [Y], folds=None if groups is None else cross_fit_folds(lengths, full.n_folds, groups))
    return Y, k, cross_fit(X, Y, lengths, n_folds, groups, per_target, score), full


#: The guide's fixed weight λ (training option ``guide_weight`` given as a number; the default
#: of :func:`fit_guide`). 1 would be the posterior of the face given both the vocal HMM's
#: trajectory and the ridge's prediction; 4 was selected (the largest costing the voice heard in
#: training at most +0.005 Err) and confirmed on voices never heard (docs/results.md, "The
#: guide's weight for voices never heard").
GUIDE_WEIGHT = 4.0

#: The weights ``Puppet.train(guide_weight="cv")`` chooses from by cross-validation on its
#: training audio (docs/results.md, "The guide's weight chosen at training by cross-validation";
#: 128 and 256 added on 2026-12-02, "The top of the guide's weight grid").
GUIDE_WEIGHTS = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0)

#: How the guide's ridge regularises (training option ``guide_alpha``), each α chosen by
#: cross-validation (:class:`RidgeBaseline`): one α for all face coordinates on their summed
#: error, one per coordinate, or one for all on the error of the lips' points (:func:`lips_score`).
GUIDE_ALPHAS = ("shared", "per_coordinate", "lips")


def fit_guide(standardized, face, lengths, *, context: int, columns: int, n_folds: int = 5,
              weight: float = GUIDE_WEIGHT, groups=None, alpha: str = "shared", score=None):
    """Fit the guide: the ridge's prediction ŷ of the face from ±k frames of audio and the
    covariance R of its cross-fitted residuals, used as evidence in the trajectory solve
    (``+ λ Σ_t (y_t − ŷ_t)ᵀ R⁻¹ (y_t − ŷ_t)``, ``cpp/include/voicepuppet/puppet.hpp``).

    Parameters
    ----------
    standardized : array (T, A')
        Standardised training features (as the puppet standardises them), sequences concatenated.
    face : array (T, K)
        The training face coordinates of all parts (the puppet's face space).
    lengths : array of int
        Frames per training sequence (they add up to T).
    context : int
        k: frames of context on each side.
    columns : int
        How many leading columns of ``standardized`` the map reads (A: the features without
        their deltas, as the ridge baseline hears them).
    n_folds : int
        Cross-fitting folds (:func:`cross_fit_folds`).
    weight : float
        λ written as ``guide/weight`` (>= 0).
    groups : array of labels, optional
        One per sequence: sequences that are copies of one recording (:func:`cross_fit_folds`).
    alpha : {"shared", "per_coordinate", "lips"}
        One ridge α for all face coordinates, one per coordinate, or one chosen on the error of
        the lips (:data:`GUIDE_ALPHAS`, :class:`RidgeBaseline`'s ``per_target`` and ``score``).
    score : array (K, M), optional
        With ``alpha="lips"``: the face space's :func:`lips_score` (required then).

    Returns
    -------
    arrays : dict
        ``guide/map`` [columns·(2k+1), K] and ``guide/offset`` [K] (ŷ_t = [z_{t−k} … z_{t+k}] ·
        map + offset, the ridge fitted on all frames with its own α), ``guide/context`` [1] and
        ``guide/columns`` [1] (int), ``guide/covariance`` [K, K] (R: the covariance of the
        cross-fitted residuals y − ŷ_cf, as large as novel audio makes them), ``guide/weight``
        [1] (λ = ``weight``).
    info : dict
        α (a list of one per coordinate with ``alpha="per_coordinate"``), folds, context, columns
        and the residuals' mean variance (for the metadata).
    """
    if alpha not in GUIDE_ALPHAS:
        raise ValueError(f"the guide's alpha must be one of {GUIDE_ALPHAS}, got {alpha!r}")
    if (alpha == "lips") != (score is not None):
        raise ValueError("the guide's alpha 'lips' needs score (lips_score of the face space), and only it "
                         f"takes one; got alpha={alpha!r}, score {'missing' if score is None else 'given'}")
    Y, k, yhat, full = _context_ridge(standardized, face, lengths, context=context, columns=columns,
                                      n_folds=n_folds, what="the guide", option="guide_context", groups=groups,
                                      per_target=alpha == "per_coordinate", score=score)
    res = Y - yhat
    R = np.cov(res, rowvar=False, bias=True).reshape(Y.shape[1], Y.shape[1])
    arrays = {"guide/map": np.ascontiguousarray(full.W),
              "guide/offset": np.ascontiguousarray(full.y_mean - full.x_mean @ full.W),
              "guide/context": np.array([k], dtype=np.int64),
              "guide/columns": np.array([int(columns)], dtype=np.int64),
              "guide/covariance": np.ascontiguousarray(0.5 * (R + R.T)),
              "guide/weight": np.array([float(weight)])}
    info = {"alpha": full.alpha.tolist() if full.per_target else float(full.alpha), "folds": int(n_folds),
            "context": k, "columns": int(columns), "residual_variance": float(np.trace(R) / len(R))}
    return arrays, info


def fit_projection(standardized, face, lengths, *, context: int, columns: int, n_folds: int = 5):
    """Fit the projection and the cross-fitted training features it gives.

    Parameters
    ----------
    standardized : array (T, A')
        Standardised training features (as the puppet standardises them), sequences concatenated.
    face : array (T, K)
        The training face coordinates (the regression's target).
    lengths : array of int
        Frames per training sequence (they add up to T).
    context : int
        k: frames of context on each side (0: the frame alone).
    columns : int
        How many leading columns of ``standardized`` the map reads (A' for all of them; A for the
        features without their deltas).
    n_folds : int
        Cross-fitting folds (:func:`cross_fit_folds`).

    Returns
    -------
    train_features : array (T, K)
        Cross-fitted ŷ of the training frames, standardised: what the vocal Gaussians are fitted on.
    arrays : dict
        ``audio/projection`` [columns·(2k+1), K], ``audio/projection_offset`` [K],
        ``audio/projection_context`` [1] (int k), ``audio/projection_columns`` [1] (int).
    info : dict
        The ridge's α (of the map on all frames), folds, context, columns (for the metadata).
    """
    Y, k, yhat, full = _context_ridge(standardized, face, lengths, context=context, columns=columns,
                                      n_folds=n_folds, what="the projection", option="vocal_context")
    std = Standardizer.fit(yhat)
    P = full.W / std.std
    c = (full.y_mean - full.x_mean @ full.W - std.mean) / std.std
    arrays = {"audio/projection": np.ascontiguousarray(P), "audio/projection_offset": c,
              "audio/projection_context": np.array([k], dtype=np.int64),
              "audio/projection_columns": np.array([int(columns)], dtype=np.int64)}
    info = {"alpha": float(full.alpha), "folds": int(n_folds), "context": k, "columns": int(columns)}
    return std.transform(yhat), arrays, info
