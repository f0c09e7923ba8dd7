"""Gaussian hidden Markov models over facial pose and velocity (Voice Puppetry §3-4, eq. 3).

The kernels (log densities through Cholesky factors, forward-backward, Viterbi, statistics,
M-step, k-means++, sampling) are C++ (``cpp/include/voicepuppet/hmm*.hpp``); this module holds
the estimator with hmmlearn's conventions: ``fit(X, lengths)``, ``score``, ``decode``,
``predict``, ``predict_proba``, ``sample``, and parameters as numpy arrays with trailing
underscores (``startprob_``, ``transmat_``, ``means_``, ``covars_``).
"""

from __future__ import annotations

import math

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import _core

__all__ = ["GaussianHMM", "check_sequences"]

_STOCHASTIC_TOL = 1e-6


def check_sequences(X, lengths=None, *, name: str = "X") -> tuple[np.ndarray, np.ndarray]:
    """Validate observations and sequence lengths.

    Parameters
    ----------
    X : array_like, shape (T, D)
        Observations of all sequences, stacked in time.
    lengths : array_like of int, shape (S,), optional
        Frames per sequence; must sum to T. ``None`` means one sequence.
    name : str
        What the observations are called in error messages (default ``"X"``).

    Returns
    -------
    X : ndarray, shape (T, D), C-contiguous float64
        The observations.
    lengths : ndarray, shape (S,), int64
        The sequence lengths (``[T]`` when ``lengths`` is ``None``).

    Raises
    ------
    ValueError
        ``X`` is not 2-D, has no frames or no dimensions, or holds NaN or infinite values;
        ``lengths`` is empty, not 1-D, not integers, has a length <= 0, or does not sum to T.
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.ndim == 1:
        raise ValueError(f"{name} must be 2-D (frames, dims), got shape {X.shape}; "
                         f"use {name}.reshape(-1, 1) for one-dimensional data")
    if X.ndim != 2:
        raise ValueError(f"{name} must be 2-D (frames, dims), got shape {X.shape}")
    if X.shape[0] == 0:
        raise ValueError(f"{name} has zero frames; pass at least one frame")
    if X.shape[1] == 0:
        raise ValueError(f"{name} has zero dimensions")
    if not np.all(np.isfinite(X)):
        bad = np.argwhere(~np.isfinite(X))[0]
        raise ValueError(f"{name} contains NaN or infinite values (first at frame {bad[0]}, "
                         f"dim {bad[1]}); interpolate or drop those frames")
    if lengths is None:
        return X, np.array([X.shape[0]], dtype=np.int64)
    lengths_arr = np.asarray(lengths)
    if lengths_arr.ndim != 1 or lengths_arr.size == 0:
        raise ValueError(f"lengths must be a non-empty 1-D list of frame counts, got {lengths!r}")
    if not np.all(np.equal(np.mod(lengths_arr, 1), 0)):
        raise ValueError(f"lengths must be integers, got {lengths_arr}")
    lengths_arr = lengths_arr.astype(np.int64)
    if np.any(lengths_arr <= 0):
        raise ValueError(f"lengths must all be positive (no empty sequences), got {lengths_arr.tolist()}")
    if int(lengths_arr.sum()) != X.shape[0]:
        raise ValueError(f"lengths sum to {int(lengths_arr.sum())} but {name} has {X.shape[0]} frames; "
                         "they must agree")
    return X, np.ascontiguousarray(lengths_arr)


def aligned(a) -> np.ndarray:
    """A C-contiguous float64 copy of ``a`` starting on a 64-byte boundary.

    numpy places buffers at varying addresses, and the alignment of the data changes how the
    SIMD kernels split their sums, so the last bits of the results. Everything the training
    kernels read goes through this, so that a fit is reproducible bit for bit for a given seed.

    Parameters
    ----------
    a : array_like
        Any array (converted to float64).

    Returns
    -------
    ndarray
        A new C-contiguous float64 array of ``a``'s shape and values whose data starts at an
        address that is a multiple of 64 bytes.
    """
    a = np.asarray(a, dtype=np.float64)
    buf = np.empty(a.nbytes + 64, dtype=np.uint8)
    offset = (-buf.ctypes.data) % 64
    out = buf[offset:offset + a.nbytes].view(np.float64).reshape(a.shape)
    out[...] = a
    return out


class GaussianHMM:
    """Hidden Markov model with Gaussian emissions (full or diagonal covariance).

    Parameters
    ----------
    n_states : int, default 1
        Number of hidden states N.
    covariance : {"full", "diag"}, default "full"
        Covariance structure of each state's Gaussian.
    n_iter : int, default 10
        Maximum number of EM iterations in :meth:`fit`.
    tol : float, default 1e-2
        EM stops when the log-likelihood gains less than ``tol`` in an iteration.
    min_covar : float, default 1e-3
        Relative variance floor: ``min_covar`` times the mean per-dimension variance of the
        training data is added to every covariance diagonal at initialisation and after each
        M-step (0 gives plain maximum likelihood).
    random_state : int, default 0
        Seed of the initialisation and of :meth:`sample` (deterministic per seed).
    init : {"kmeans", "frames"}, default "kmeans"
        How the state means start: ``"kmeans"`` (k-means++ seeding refined by Lloyd
        iterations) or ``"frames"`` (distinct training frames drawn at random, the plain
        random start of Brand's comparisons). Starts and transitions start uniform and
        covariances at the data's either way.
    init_params, params : str, default "stmc"
        Which parameters to initialise / update: any of ``s`` (starts), ``t`` (transitions),
        ``m`` (means), ``c`` (covariances). As in hmmlearn.
    progress : bool, default False
        Show a progress bar during :meth:`fit`.
    exact : bool, default False
        False (default): with full covariances, :meth:`score`, :meth:`decode`,
        :meth:`score_samples` and the E-step evaluate the log densities in float32 first and in
        double only where they can change the answer (docs/benchmarks.md, "hmm"); the results
        equal the all-double ones to ~1e-13. True: every log density in double.

    Attributes
    ----------
    startprob_ : ndarray, shape (N,)
        Start probabilities (set by :meth:`fit` or by hand).
    transmat_ : ndarray, shape (N, N)
        Transition probabilities, row i the distribution of the state after state i.
    means_ : ndarray, shape (N, D)
        Mean of each state's Gaussian.
    covars_ : ndarray, shape (N, D, D) for "full", (N, D) for "diag"
        Covariance of each state's Gaussian (its diagonal for "diag").
    history_ : list of dict
        One entry per EM iteration: ``iteration``, ``log_likelihood`` (of the parameters
        before that iteration's M-step), ``delta``.
    variance_floor : float
        The absolute variance floor of the last :meth:`initialize` (``min_covar`` times the
        mean per-dimension variance of its data; 0 before).

    Raises
    ------
    ValueError
        ``n_states`` not a positive integer, ``covariance`` or ``init`` not one of their
        values, ``n_iter < 0``, ``min_covar`` negative or not finite, or ``init_params`` /
        ``params`` with letters other than s, t, m, c.

    Notes
    -----
    The constructor's arguments are kept as attributes of the same names.
    """

    def __init__(self, n_states: int = 1, covariance: str = "full", *, n_iter: int = 10,
                 tol: float = 1e-2, min_covar: float = 1e-3, random_state: int = 0,
                 init_params: str = "stmc", params: str = "stmc", progress: bool = False,
                 exact: bool = False, init: str = "kmeans"):
        if int(n_states) != n_states or n_states < 1:
            raise ValueError(f"n_states must be a positive integer, got {n_states!r}")
        if covariance not in ("full", "diag"):
            raise ValueError(f"covariance must be 'full' or 'diag', got {covariance!r}")
        if n_iter < 0:
            raise ValueError(f"n_iter must be >= 0, got {n_iter}")
        if not (min_covar >= 0 and math.isfinite(min_covar)):
            raise ValueError(f"min_covar must be a finite number >= 0, got {min_covar!r}")
        for pname, value in (("init_params", init_params), ("params", params)):
            if set(value) - set("stmc"):
                raise ValueError(f"{pname} may only contain the letters s, t, m, c; got {value!r}")
        if init not in ("kmeans", "frames"):
            raise ValueError(f"init must be 'kmeans' (k-means++ state means) or 'frames' (random training "
                             f"frames), got {init!r}")
        self.init = init
        self.n_states = int(n_states)
        self.covariance = covariance
        self.n_iter = int(n_iter)
        self.tol = float(tol)
        self.min_covar = float(min_covar)
        self.random_state = int(random_state)
        self.init_params = init_params
        self.params = params
        self.progress = bool(progress)
        self.exact = bool(exact)
        self.history_: list[dict] = []
        self.variance_floor = 0.0

    # ------------------------------------------------------------------ parameters
    @property
    def n_features(self) -> int:
        """Dimension D of the observations (the width of :attr:`means_`)."""
        return self.means_.shape[1]

    def covars_2d(self) -> np.ndarray:
        """Covariances as the kernels take them: full [N*D, D], diag [N, D].

        Returns
        -------
        ndarray, shape (N*D, D) or (N, D)
        """
        c = np.ascontiguousarray(self.covars_, dtype=np.float64)
        return c.reshape(-1, c.shape[-1])

    def check_params(self) -> None:
        """Make the parameters contiguous float64 and check their shapes and sums.

        Raises
        ------
        ValueError
            A parameter is missing, has the wrong shape, a probability row does not sum to 1, or
            a covariance is not positive definite.
        """
        for attr in ("startprob_", "transmat_", "means_", "covars_"):
            if not hasattr(self, attr):
                raise ValueError(f"the model has no {attr}; call fit() or set the parameters first")
        n = self.n_states
        self.startprob_ = np.ascontiguousarray(self.startprob_, dtype=np.float64)
        self.transmat_ = np.ascontiguousarray(self.transmat_, dtype=np.float64)
        self.means_ = np.ascontiguousarray(self.means_, dtype=np.float64)
        self.covars_ = np.ascontiguousarray(self.covars_, dtype=np.float64)
        if self.startprob_.shape != (n,):
            raise ValueError(f"startprob_ must have shape ({n},), got {self.startprob_.shape}")
        if self.transmat_.shape != (n, n):
            raise ValueError(f"transmat_ must have shape ({n}, {n}), got {self.transmat_.shape}")
        if self.means_.ndim != 2 or self.means_.shape[0] != n:
            raise ValueError(f"means_ must have shape ({n}, D), got {self.means_.shape}")
        d = self.means_.shape[1]
        want = (n, d, d) if self.covariance == "full" else (n, d)
        if self.covars_.shape != want:
            raise ValueError(f"covars_ must have shape {want} for covariance={self.covariance!r}, "
                             f"got {self.covars_.shape}")
        if not np.isclose(self.startprob_.sum(), 1.0, atol=_STOCHASTIC_TOL):
            raise ValueError(f"startprob_ must sum to 1, sums to {self.startprob_.sum():.6g}")
        rows = self.transmat_.sum(axis=1)
        bad = np.flatnonzero(np.abs(rows - 1.0) > _STOCHASTIC_TOL)
        if bad.size:
            raise ValueError(f"transmat_ rows must sum to 1; row {bad[0]} sums to {rows[bad[0]]:.6g}")
        _core.check_covariances(self.covars_2d(), n, d, self.covariance)

    def _check_X(self, X, lengths):
        X, lengths = check_sequences(X, lengths)
        if hasattr(self, "means_") and X.shape[1] != self.means_.shape[1]:
            raise ValueError(f"X has {X.shape[1]} dimensions but the model has "
                             f"{self.means_.shape[1]}; pass data of the training dimension")
        return X, lengths

    # ------------------------------------------------------------------ inference
    def log_density(self, X) -> np.ndarray:
        """Log emission densities log N(x_t; μ_n, Σ_n), shape (T, N).

        Parameters
        ----------
        X : array_like, shape (T, D)
            Observations (one or more sequences stacked in time).

        Returns
        -------
        ndarray, shape (T, N)
            ``log N(x_t; μ_n, Σ_n)`` for every frame t and state n.
        """
        self.check_params()
        X, _ = self._check_X(X, None)
        return _core.gaussian_log_density(X, self.means_, self.covars_2d(), self.covariance)

    def _model_args(self, X, lengths) -> tuple:
        return (X, lengths, self.startprob_, self.transmat_, self.means_, self.covars_2d(), self.covariance)

    def score(self, X, lengths=None) -> float:
        """Total log-likelihood log p(X) of all sequences.

        Parameters
        ----------
        X : array_like, shape (T, D)
            Observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.

        Returns
        -------
        float
            log p(X), summed over the sequences.
        """
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        return float(_core.gaussian_hmm_score(*self._model_args(X, lengths), exact=self.exact)[0])

    def score_samples(self, X, lengths=None) -> tuple[float, np.ndarray]:
        """Log-likelihood and state posteriors γ, shape (T, N).

        Parameters
        ----------
        X : array_like, shape (T, D)
            Observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.

        Returns
        -------
        log_likelihood : float
            log p(X), summed over the sequences.
        posteriors : ndarray, shape (T, N)
            γ: the probability of each state at each frame given its sequence.
        """
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        ll, gamma = _core.gaussian_hmm_posteriors(*self._model_args(X, lengths), exact=self.exact)[:2]
        return float(ll), gamma

    def predict_proba(self, X, lengths=None) -> np.ndarray:
        """State posteriors γ [T, N] (each row sums to one).

        Parameters
        ----------
        X : array_like, shape (T, D)
            Observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.

        Returns
        -------
        ndarray, shape (T, N)
            γ, as :meth:`score_samples` gives it.
        """
        return self.score_samples(X, lengths)[1]

    def decode(self, X, lengths=None) -> tuple[float, np.ndarray]:
        """Viterbi: (log p(best path, X), best state per frame [T]).

        Parameters
        ----------
        X : array_like, shape (T, D)
            Observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.

        Returns
        -------
        log_prob : float
            log p(best path, X), summed over the sequences.
        states : ndarray of int, shape (T,)
            The most likely state of each frame (each sequence decoded on its own).
        """
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        logprob, path, _ = _core.gaussian_hmm_decode(*self._model_args(X, lengths), exact=self.exact)
        return float(logprob), path

    def predict(self, X, lengths=None) -> np.ndarray:
        """Most likely state per frame (Viterbi), shape (T,).

        Parameters
        ----------
        X : array_like, shape (T, D)
            Observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.

        Returns
        -------
        ndarray of int, shape (T,)
            The states of :meth:`decode`'s best path.
        """
        return self.decode(X, lengths)[1]

    def sample(self, n_samples: int = 1, random_state: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Sample ``(X [n_samples, D], states [n_samples])``; deterministic for a given seed.

        Parameters
        ----------
        n_samples : int
            Number of frames to draw (>= 1; default 1).
        random_state : int, optional
            Seed; ``None`` (default): the model's ``random_state``.

        Returns
        -------
        X : ndarray, shape (n_samples, D)
            The sampled observations.
        states : ndarray of int, shape (n_samples,)
            The state sequence they were drawn from.

        Raises
        ------
        ValueError
            ``n_samples`` not a positive integer, or parameters that :meth:`check_params` refuses.
        """
        self.check_params()
        if int(n_samples) != n_samples or n_samples < 1:
            raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")
        seed = self.random_state if random_state is None else int(random_state)
        return _core.gaussian_hmm_sample(self.startprob_, self.transmat_, self.means_, self.covars_2d(),
                                         self.covariance, int(n_samples), seed)

    # ------------------------------------------------------------------ training
    def initialize(self, X: np.ndarray) -> None:
        """Set the variance floor from ``X`` and start the parameters named in ``init_params``.

        Parameters
        ----------
        X : ndarray, shape (T, D)
            The training frames (all sequences stacked).

        Raises
        ------
        ValueError
            Fewer frames than states, or (when covariances are initialised) a training
            covariance that stays singular with the variance floor.
        """
        n, (T, d) = self.n_states, X.shape
        if T < n:
            raise ValueError(f"{T} frames cannot initialise {n} states; use fewer states or more data")
        data_var = X.var(axis=0)
        self.variance_floor = self.min_covar * float(max(data_var.mean(), 1e-300))
        if "s" in self.init_params or not hasattr(self, "startprob_"):
            self.startprob_ = np.full(n, 1.0 / n)
        if "t" in self.init_params or not hasattr(self, "transmat_"):
            self.transmat_ = np.full((n, n), 1.0 / n)
        if "m" in self.init_params or not hasattr(self, "means_"):
            if self.init == "kmeans":
                self.means_ = _core.kmeans(X, n, self.random_state)
            else:
                pick = np.random.default_rng(self.random_state).choice(T, size=n, replace=False)
                self.means_ = np.array(X[np.sort(pick)], dtype=np.float64)
        if "c" in self.init_params or not hasattr(self, "covars_"):
            cov = np.atleast_2d(np.cov(X, rowvar=False, bias=True)) if T > 1 else np.zeros((d, d))
            cov = cov + self.variance_floor * np.eye(d)
            if np.any(np.linalg.eigvalsh(cov) <= 0):
                raise ValueError("the training data has a degenerate (singular) covariance; "
                                 "raise min_covar or remove constant dimensions")
            if self.covariance == "full":
                self.covars_ = np.tile(cov, (n, 1, 1))
            else:
                self.covars_ = np.tile(np.diag(cov), (n, 1))

    def estep(self, X, lengths=None, shift=None) -> dict:
        """One E-step: expected counts and Gaussian statistics (additive over data).

        Parameters
        ----------
        X : array_like, shape (T, D)
            Observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.
        shift : array_like, shape (D,), optional
            Point the moments are taken about (default: the mean of X).

        Returns
        -------
        dict
            ``log_likelihood``, ``expected_transitions`` [N,N], ``expected_starts`` [N],
            ``weight`` [N], ``sum`` [N,D] and ``outer`` (full: [N*D,D], diag: [N,D]), the
            moments taken about ``shift`` [D].
        """
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        X = X if X.ctypes.data % 64 == 0 else aligned(X)
        shift = X.mean(axis=0) if shift is None else shift
        return _core.gaussian_hmm_estep(X, lengths, aligned(self.startprob_), aligned(self.transmat_),
                                        aligned(self.means_), aligned(self.covars_2d()), self.covariance,
                                        aligned(shift), exact=self.exact)

    def mstep(self, stats: dict) -> None:
        """Maximum-likelihood update of the parameters named in ``params`` from :meth:`estep`.

        Parameters
        ----------
        stats : dict
            E-step statistics with the keys of :meth:`estep`'s result plus ``shift`` [D], the
            point the moments were taken about (summed over data, e.g. from several chunks).
        """
        n = self.n_states
        if "s" in self.params:
            self.startprob_ = _core.normalize_counts(aligned(stats["expected_starts"][None, :]),
                                                     aligned(self.startprob_[None, :]))[0]
        if "t" in self.params:
            self.transmat_ = _core.normalize_counts(aligned(stats["expected_transitions"]),
                                                    aligned(self.transmat_))
        if "m" in self.params or "c" in self.params:
            means, covars = _core.gaussian_mstep(aligned(stats["weight"]), aligned(stats["sum"]),
                                                 aligned(stats["outer"]), aligned(stats["shift"]),
                                                 self.covariance, self.variance_floor, aligned(self.means_),
                                                 aligned(self.covars_2d()))
            if "m" in self.params:
                self.means_ = means
            if "c" in self.params:
                d = self.means_.shape[1]
                self.covars_ = covars.reshape(n, d, d) if self.covariance == "full" else covars

    def parameters(self) -> dict:
        """The current parameters as a plain dict (what an E-step needs).

        Returns
        -------
        dict
            ``startprob`` [N], ``transmat`` [N,N], ``means`` [N,D], ``covars`` (full [N*D,D],
            diag [N,D]) and ``covariance``.
        """
        return {"startprob": self.startprob_, "transmat": self.transmat_, "means": self.means_,
                "covars": self.covars_2d(), "covariance": self.covariance}

    def fit(self, X, lengths=None, estep=None) -> "GaussianHMM":
        """Estimate the parameters by EM (Baum-Welch) from one or more sequences.

        Parameters
        ----------
        X : array_like, shape (T, D)
            Training observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.
        estep : object, optional
            Where the E-step statistics come from (e.g. a cluster:
            :class:`voicepuppet.hmm.distributed.DaskEStep`). ``None`` (default): computed here from
            ``X``. Otherwise an object over the same ``X`` and ``lengths`` with
            ``stats(params, shift) -> dict`` (the keys of :meth:`estep`, ``params`` as
            :meth:`parameters` gives them). The initialisation and the M-step stay here.

        Returns
        -------
        GaussianHMM
            ``self``, fitted; ``history_`` holds the iterations.
        """
        X, lengths = check_sequences(X, lengths)
        X = aligned(X)  # the same data layout in every run: bit-for-bit reproducible fits
        self.initialize(X)
        self.check_params()
        shift = X.mean(axis=0)
        self.history_ = []
        previous = -np.inf
        bar = None
        if self.progress:
            bar = tqdm(total=self.n_iter, desc="EM", unit="it")
        try:
            for it in range(self.n_iter):
                stats = (self.estep(X, lengths, shift) if estep is None
                         else estep.stats(self.parameters(), shift))
                ll = float(stats["log_likelihood"])
                delta = ll - previous
                self.history_.append({"iteration": it, "log_likelihood": ll, "delta": delta})
                if bar is not None:
                    bar.set_postfix(loglik=f"{ll:.6g}")
                    bar.update(1)
                if delta < self.tol:
                    break
                self.mstep(stats)
                previous = ll
        finally:
            if bar is not None:
                bar.close()
        return self
