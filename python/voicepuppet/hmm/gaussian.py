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

    Returns
    -------
    X : ndarray, shape (T, D), C-contiguous float64
    lengths : ndarray, shape (S,), int64
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
    kernels read goes through this, so that a fit is reproducible bit for bit for a given seed."""
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
    n_states : int
        Number of hidden states N.
    covariance : {"full", "diag"}
        Covariance structure of each state's Gaussian.
    n_iter : int
        Maximum number of EM iterations in :meth:`fit`.
    tol : float
        EM stops when the log-likelihood gains less than ``tol`` in an iteration.
    min_covar : float
        Relative variance floor: ``min_covar`` times the mean per-dimension variance of the
        training data is added to every covariance diagonal at initialisation and after each
        M-step (0 gives plain maximum likelihood).
    random_state : int
        Seed of the initialisation and of :meth:`sample` (deterministic per seed).
    init : {"kmeans", "frames"}
        How the state means start: ``"kmeans"`` (k-means++ seeding refined by Lloyd
        iterations) or ``"frames"`` (distinct training frames drawn at random, the plain
        random start of Brand's comparisons). Starts and transitions start uniform and
        covariances at the data's either way.
    init_params, params : str
        Which parameters to initialise / update: any of ``s`` (starts), ``t`` (transitions),
        ``m`` (means), ``c`` (covariances). As in hmmlearn.
    progress : bool
        Show a progress bar during :meth:`fit`.
    exact : bool
        False (default): with full covariances, :meth:`score`, :meth:`decode`,
        :meth:`score_samples` and the E-step evaluate the log densities in float32 first and in
        double only where they can change the answer (docs/benchmarks.md, "hmm"); the results
        equal the all-double ones to ~1e-13. True: every log density in double.

    Attributes
    ----------
    startprob_ : ndarray, shape (N,)
    transmat_ : ndarray, shape (N, N)
    means_ : ndarray, shape (N, D)
    covars_ : ndarray, shape (N, D, D) for "full", (N, D) for "diag"
    history_ : list of dict
        One entry per EM iteration: ``iteration``, ``log_likelihood`` (of the parameters
        before that iteration's M-step), ``delta``.
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
        """Log emission densities log N(x_t; μ_n, Σ_n), shape (T, N)."""
        self.check_params()
        X, _ = self._check_X(X, None)
        return _core.gaussian_log_density(X, self.means_, self.covars_2d(), self.covariance)

    def _model_args(self, X, lengths) -> tuple:
        return (X, lengths, self.startprob_, self.transmat_, self.means_, self.covars_2d(), self.covariance)

    def score(self, X, lengths=None) -> float:
        """Total log-likelihood log p(X) of all sequences."""
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        return float(_core.gaussian_hmm_score(*self._model_args(X, lengths), exact=self.exact)[0])

    def score_samples(self, X, lengths=None) -> tuple[float, np.ndarray]:
        """Log-likelihood and state posteriors γ, shape (T, N)."""
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        ll, gamma = _core.gaussian_hmm_posteriors(*self._model_args(X, lengths), exact=self.exact)[:2]
        return float(ll), gamma

    def predict_proba(self, X, lengths=None) -> np.ndarray:
        """State posteriors γ [T, N] (each row sums to one)."""
        return self.score_samples(X, lengths)[1]

    def decode(self, X, lengths=None) -> tuple[float, np.ndarray]:
        """Viterbi: (log p(best path, X), best state per frame [T])."""
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        logprob, path, _ = _core.gaussian_hmm_decode(*self._model_args(X, lengths), exact=self.exact)
        return float(logprob), path

    def predict(self, X, lengths=None) -> np.ndarray:
        """Most likely state per frame (Viterbi), shape (T,)."""
        return self.decode(X, lengths)[1]

    def sample(self, n_samples: int = 1, random_state: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Sample ``(X [n_samples, D], states [n_samples])``; deterministic for a given seed."""
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

        Returns a dict with ``log_likelihood``, ``expected_transitions`` [N,N],
        ``expected_starts`` [N], ``weight`` [N], ``sum`` [N,D] and ``outer`` (full: [N*D,D],
        diag: [N,D]), the moments taken about ``shift`` [D] (default: the mean of X).
        """
        self.check_params()
        X, lengths = self._check_X(X, lengths)
        X = X if X.ctypes.data % 64 == 0 else aligned(X)
        shift = X.mean(axis=0) if shift is None else shift
        return _core.gaussian_hmm_estep(X, lengths, aligned(self.startprob_), aligned(self.transmat_),
                                        aligned(self.means_), aligned(self.covars_2d()), self.covariance,
                                        aligned(shift), exact=self.exact)

    def mstep(self, stats: dict) -> None:
        """Maximum-likelihood update of the parameters named in ``params`` from :meth:`estep`."""
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
        """The current parameters as a plain dict (what an E-step needs): ``startprob`` [N],
        ``transmat`` [N,N], ``means`` [N,D], ``covars`` (full [N*D,D], diag [N,D]) and
        ``covariance``."""
        return {"startprob": self.startprob_, "transmat": self.transmat_, "means": self.means_,
                "covars": self.covars_2d(), "covariance": self.covariance}

    def fit(self, X, lengths=None, estep=None) -> "GaussianHMM":
        """Estimate the parameters by EM (Baum-Welch) from one or more sequences.

        Parameters
        ----------
        X : array_like, shape (T, D)
        lengths : array_like of int, shape (S,), optional
        estep : object, optional
            Where the E-step statistics come from (e.g. a cluster:
            :class:`voicepuppet.hmm.distributed.DaskEStep`). ``None`` (default): computed here from
            ``X``. Otherwise an object over the same ``X`` and ``lengths`` with
            ``stats(params, shift) -> dict`` (the keys of :meth:`estep`, ``params`` as
            :meth:`parameters` gives them). The initialisation and the M-step stay here.

        Returns
        -------
        self
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
