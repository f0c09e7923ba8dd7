"""Entropic estimation of Gaussian HMMs (Brand, Neural Computation 1999; Voice Puppetry §4.2).

Training maximises the log posterior ``log p(X | θ) + log P_e(θ)`` under the entropic prior
``P_e(θ) ∝ exp(−Z·H(θ))``: a large fully connected HMM whittles itself down to a sparse machine.
The kernels (the MAP multinomial via Lambert W, the entropic covariance, trimming candidates,
the annealing schedule) are C++; this module runs the training loop with trimming verified
against the exact log posterior (the diagnostics the paper reports are
:mod:`voicepuppet.hmm.diagnostics`).

Use it through :class:`EntropicHMM`, a :class:`voicepuppet.hmm.gaussian.GaussianHMM` trained
under the prior::

    EntropicHMM(40, z=1.0, trim=True, n_iter=50).fit(X)

``z`` may also be a sequence of per-iteration weights, e.g. :func:`anneal_schedule`.
See ``docs/entropic.md`` for the method and the state-trimming rule.
"""

from __future__ import annotations

import math

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import _core
from voicepuppet.hmm.gaussian import GaussianHMM, aligned, check_sequences

__all__ = [
    "EntropicHMM", "entropic_multinomial", "entropic_rows", "entropic_objective", "anneal_schedule",
    "log_prior", "fit_entropic", "LocalData", "LocalEvaluation",
]

LOG_2PI_E = math.log(2 * math.pi * math.e)


def _check_z(z) -> float:
    try:
        z = float(z)
    except (TypeError, ValueError):
        raise ValueError(f"z must be a finite number, got {z!r}") from None
    if not math.isfinite(z):
        raise ValueError(f"z must be a finite number (1: minimum entropy, 0: maximum likelihood, "
                         f"< 0: annealing), got {z!r}")
    return z


def _check_evidence(omega, name: str, ndim: int) -> np.ndarray:
    a = np.ascontiguousarray(omega, dtype=np.float64)
    if a.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-D array of expected counts, got shape {a.shape}")
    if a.size == 0:
        raise ValueError(f"{name} is empty; give at least one entry of evidence")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or infinite values; expected counts must be finite")
    if np.any(a < 0):
        raise ValueError(f"{name} has negative entries (min {a.min():.3g}); expected counts must be >= 0")
    return a


def entropic_multinomial(omega, z: float = 1.0) -> np.ndarray:
    """Entropic MAP estimate of a multinomial: argmax over the simplex of Σ (ω_k + Z θ_k) log θ_k.

    Parameters
    ----------
    omega : array_like, shape (K,)
        Non-negative evidence (expected counts).
    z : float
        Prior weight: 1 (default) minimum entropy, 0 maximum likelihood, < 0 maximum-entropy bias.

    Returns
    -------
    theta : ndarray, shape (K,)
        Probabilities summing to one; zero-evidence entries are 0 when ``z > 0``.

    Raises
    ------
    ValueError
        ``z`` not a finite number; ``omega`` not 1-D, empty, not finite or negative; or
        ``omega`` all zero with ``z >= 0`` (no unique estimate).
    """
    z = _check_z(z)
    omega = _check_evidence(omega, "omega", 1)
    if z >= 0 and not np.any(omega > 0):
        raise ValueError(f"omega is all zero: with z = {z} >= 0 the estimate is not unique; "
                         "give some evidence or keep the previous parameters")
    return _core.entropic_multinomial(omega, z)


def entropic_rows(counts, z: float, old) -> np.ndarray:
    """Row-wise :func:`entropic_multinomial` of counts [R, K]; rows without evidence kept from ``old``.

    Parameters
    ----------
    counts : array_like, shape (R, K)
        Non-negative evidence per row (expected counts).
    z : float
        Prior weight, as in :func:`entropic_multinomial`.
    old : array_like, shape (R, K)
        The current probabilities; a row of ``counts`` without evidence keeps its row of these.

    Returns
    -------
    ndarray, shape (R, K)
        The MAP estimate of each row (each sums to one).

    Raises
    ------
    ValueError
        ``z`` not a finite number, ``counts`` not 2-D, empty, not finite or negative, or
        ``old`` of another shape than ``counts``.
    """
    z = _check_z(z)
    counts = _check_evidence(counts, "counts", 2)
    old = np.ascontiguousarray(old, dtype=np.float64)
    if old.shape != counts.shape:
        raise ValueError(f"old must have the shape of counts {counts.shape}, got {old.shape}")
    return _core.entropic_rows(counts, z, old)


def entropic_objective(omega, theta, z: float) -> float:
    """Σ_k (ω_k + Z θ_k) log θ_k (0 log 0 = 0; −inf when evidence meets a zero probability).

    Parameters
    ----------
    omega : array_like, shape (K,)
        Non-negative evidence (expected counts).
    theta : array_like, shape (K,)
        Probabilities.
    z : float
        Prior weight.

    Returns
    -------
    float
        The entropic objective that :func:`entropic_multinomial` maximises.

    Raises
    ------
    ValueError
        ``z`` not a finite number, or ``omega`` not 1-D, empty, not finite or negative.
    """
    return float(_core.entropic_objective(_check_evidence(omega, "omega", 1),
                                          np.ascontiguousarray(theta, dtype=np.float64), _check_z(z)))


def anneal_schedule(n_iter: int, z_start: float = -1.0, z_final: float = 1.0,
                    n_anneal: int | None = None) -> np.ndarray:
    """Per-iteration prior weights: a cosine ramp from ``z_start`` to ``z_final``, then constant.

    At high temperature (Z < 0) the prior favours spreading probability, so states share the data
    before they specialise.

    Parameters
    ----------
    n_iter : int
        Number of iterations (>= 1): the length of the schedule.
    z_start : float
        Weight the ramp starts from, at the first iteration (default -1).
    z_final : float
        Weight at the end of the ramp and after it (default 1).
    n_anneal : int, optional
        Iterations of the ramp (>= 0; default: half of ``n_iter``).

    Returns
    -------
    ndarray, shape (n_iter,)
        One prior weight per iteration (the ``z`` of :class:`EntropicHMM`).

    Raises
    ------
    ValueError
        ``n_iter`` not a positive integer, ``n_anneal`` not an integer >= 0, or ``z_start`` /
        ``z_final`` not finite.
    """
    if int(n_iter) != n_iter or n_iter < 1:
        raise ValueError(f"n_iter must be a positive integer, got {n_iter!r}")
    n_anneal = int(n_iter) // 2 if n_anneal is None else n_anneal
    if int(n_anneal) != n_anneal or n_anneal < 0:
        raise ValueError(f"n_anneal must be an integer >= 0, got {n_anneal!r}")
    return _core.anneal_schedule(int(n_iter), _check_z(z_start), _check_z(z_final), int(n_anneal))


def log_prior(model, z: float, covar_prior: float = 0.0) -> float:
    """Log entropic prior of a fitted :class:`~voicepuppet.hmm.gaussian.GaussianHMM` (see docs/entropic.md).

    Parameters
    ----------
    model : GaussianHMM
        A model with parameters (``startprob_``, ``transmat_``, ``covars_``).
    z : float
        Weight of the entropic prior.
    covar_prior : float
        Weight ``c`` of a prior term −c/2 · tr K_i⁻¹ on each state's covariance (default 0:
        none, as in training).

    Returns
    -------
    float
        log P_e(θ) of the model's parameters.

    Raises
    ------
    ValueError
        ``z`` not a finite number.
    """
    return float(_core.entropic_log_prior(model.startprob_, model.transmat_, model.covars_2d(),
                                          model.covariance, _check_z(z), float(covar_prior)))


# ---------------------------------------------------------------------------------- training
class _State:
    """Parameters of the model being trained (kept apart so that a rejected trim is a no-op)."""

    def __init__(self, startprob, transmat, means, covars, covariance):
        self.startprob, self.transmat, self.means, self.covars = startprob, transmat, means, covars
        self.covariance = covariance

    @property
    def n(self) -> int:
        return self.transmat.shape[0]

    def covars_2d(self) -> np.ndarray:
        return np.ascontiguousarray(self.covars.reshape(-1, self.covars.shape[-1]))

    def params(self) -> dict:
        """The parameters as :meth:`voicepuppet.hmm.gaussian.GaussianHMM.parameters` gives them."""
        return {"startprob": self.startprob, "transmat": self.transmat, "means": self.means,
                "covars": self.covars_2d(), "covariance": self.covariance}

    def log_prior(self, z: float) -> float:
        """Brand's entropic prior alone (no covariance prior: training never uses one)."""
        return float(_core.entropic_log_prior(self.startprob, self.transmat, self.covars_2d(),
                                              self.covariance, z, 0.0))


class LocalEvaluation:
    """Forward-backward at one model on data held in this process (see :class:`LocalData`).

    Parameters
    ----------
    data : LocalData
        The data (frames, sequence lengths, covariance type, shift).
    log_b : ndarray, shape (T, N)
        Log densities of the frames under the model's Gaussians (:meth:`LocalData.densities`).
    params : dict
        The model's parameters as :meth:`voicepuppet.hmm.gaussian.GaussianHMM.parameters` gives
        them (``startprob`` and ``transmat`` are used).

    Attributes
    ----------
    log_likelihood : float
        log p(X), summed over the sequences.
    expected_transitions : ndarray, shape (N, N)
        ξ summed over frames and sequences.
    expected_starts : ndarray, shape (N,)
        The state posteriors of the sequences' first frames, summed.
    """

    def __init__(self, data: "LocalData", log_b: np.ndarray, params: dict):
        ll, post, xi, starts, _ = _core.forward_backward(log_b, params["startprob"], params["transmat"],
                                                          data.lengths)
        self.log_likelihood, self.expected_transitions, self.expected_starts = float(ll), xi, starts
        self._data, self._log_b, self._post = data, log_b, post
        self._heirs = None

    def exclusive_evidence(self) -> np.ndarray:
        """Σ_t γ_ti · max(0, log b_i(x_t) − max_{j≠i} log b_j(x_t)), shape (N,): the evidence only
        state i explains (N >= 2).

        Returns
        -------
        ndarray, shape (N,)
            The exclusive evidence of each state.
        """
        log_b, post = self._log_b, self._post
        n = log_b.shape[1]
        top2 = np.partition(log_b, n - 2, axis=1)[:, n - 2:]
        second, first = top2[:, 0], top2[:, 1]
        runner_up = np.where(log_b >= first[:, None], second[:, None], first[:, None])
        advantage = np.maximum(0.0, log_b - runner_up)
        return (post * advantage).sum(axis=0)

    def heirs(self) -> np.ndarray:
        """For each state i, the other state that best explains i's frames.

        Returns
        -------
        ndarray of int, shape (N,)
            argmax_j≠i Σ_t γ_ti log b_j(x_t) for each state i (computed once, then cached).
        """
        if self._heirs is None:
            fit = self._post.T @ self._log_b  # [i, j]
            np.fill_diagonal(fit, -np.inf)
            self._heirs = np.argmax(fit, axis=1)
        return self._heirs

    def gaussian_stats(self):
        """γ-weighted Gaussian statistics about the data's ``shift``.

        Returns
        -------
        weight : ndarray, shape (N,)
            Σ_t γ_ti.
        sum : ndarray, shape (N, D)
            The γ-weighted sum of the frames minus ``shift``.
        outer : ndarray, shape (N*D, D) for "full", (N, D) for "diag"
            The γ-weighted sum of their outer products (squares for "diag").
        """
        return _core.gaussian_stats(self._data.X, self._post, self._data.shift, self._data.covariance)


class LocalData:
    """The data side of entropic training, in this process (the default of :func:`fit_entropic`).

    An object with the same methods over the same data (e.g.
    :class:`voicepuppet.hmm.distributed.DaskEStep`) computes them elsewhere; training calls only these:

    - ``densities(params) -> handle``: the log densities [T, N] of the Gaussians in ``params``
      (or anything that stands for them);
    - ``drop_state(handle, i) -> handle``: the same without state i;
    - ``log_likelihood(params, handle) -> float``: Σ over sequences of log p(x | params), a
      forward pass (raises ``RuntimeError`` when no state sequence explains the data);
    - ``evaluate(params, handle) -> evaluation``: forward-backward, with ``log_likelihood``,
      ``expected_transitions``, ``expected_starts``, ``exclusive_evidence()``, ``heirs()`` and
      ``gaussian_stats()`` (see :class:`LocalEvaluation`);
    - ``shift`` [D]: the mean of all frames, ``X.mean(axis=0)``, about which the Gaussian
      statistics are taken.

    ``params`` are dicts as :meth:`voicepuppet.hmm.gaussian.GaussianHMM.parameters` gives them.

    Parameters
    ----------
    X : ndarray, shape (T, D)
        All training frames, sequences stacked in time (C-contiguous float64, as
        :func:`voicepuppet.hmm.gaussian.check_sequences` gives them).
    lengths : ndarray of int64, shape (S,)
        Frames per sequence (summing to T).
    covariance : {"full", "diag"}
        Covariance type of the model's Gaussians.

    Attributes
    ----------
    X, lengths, covariance
        The constructor's arguments.
    shift : ndarray, shape (D,)
        The mean of all frames.
    """

    def __init__(self, X: np.ndarray, lengths: np.ndarray, covariance: str):
        self.X, self.lengths, self.covariance = X, lengths, covariance
        self.shift = X.mean(axis=0)

    def densities(self, params: dict) -> np.ndarray:
        """Log densities of every frame under the Gaussians in ``params``.

        Parameters
        ----------
        params : dict
            Model parameters (``means`` and ``covars`` are used).

        Returns
        -------
        ndarray, shape (T, N)
            The log densities; here they are their own handle.
        """
        return _core.gaussian_log_density(self.X, params["means"], params["covars"], self.covariance)

    def drop_state(self, log_b: np.ndarray, i: int) -> np.ndarray:
        """The log densities without state ``i``.

        Parameters
        ----------
        log_b : ndarray, shape (T, N)
            Log densities from :meth:`densities`.
        i : int
            The state to leave out.

        Returns
        -------
        ndarray, shape (T, N - 1)
            ``log_b`` without column ``i``.
        """
        return np.ascontiguousarray(np.delete(log_b, i, axis=1))

    def log_likelihood(self, params: dict, log_b: np.ndarray) -> float:
        """Σ over sequences of log p(x | params), a forward pass.

        Parameters
        ----------
        params : dict
            Model parameters (``startprob`` and ``transmat`` are used).
        log_b : ndarray, shape (T, N)
            Log densities from :meth:`densities` (or :meth:`drop_state`).

        Returns
        -------
        float
            The log-likelihood of all sequences.

        Raises
        ------
        RuntimeError
            No state sequence explains the data.
        """
        return float(_core.log_likelihood(log_b, params["startprob"], params["transmat"], self.lengths))

    def evaluate(self, params: dict, log_b: np.ndarray) -> LocalEvaluation:
        """Forward-backward at ``params``.

        Parameters
        ----------
        params : dict
            Model parameters (``startprob`` and ``transmat`` are used).
        log_b : ndarray, shape (T, N)
            Log densities from :meth:`densities` (or :meth:`drop_state`).

        Returns
        -------
        LocalEvaluation
            The log-likelihood, expected counts and what trimming and the M-step need.
        """
        return LocalEvaluation(self, log_b, params)


_TRIALS = [0]  # forward passes spent on trimming trials (reported per iteration in the history)


def _log_posterior(st: _State, log_b, data, z) -> float:
    """Exact log posterior at st from a forward pass only (for trimming trials)."""
    _TRIALS[0] += 1
    return data.log_likelihood(st.params(), log_b) + st.log_prior(z)


def _evaluate(st: _State, log_b, data, z):
    """Forward-backward at st: (log posterior, log-likelihood, evaluation)."""
    ev = data.evaluate(st.params(), log_b)
    return ev.log_likelihood + st.log_prior(z), ev.log_likelihood, ev


def _drop_state(st: _State, i: int, into: int) -> _State | None:
    """The model with state i merged into state ``into``: arcs and start mass that went to i go
    to ``into``, then i is deleted. None if some state would be left without an exit."""
    A = st.transmat.copy()
    pi = st.startprob.copy()
    A[:, into] += A[:, i]
    pi[into] += pi[i]
    keep = np.delete(np.arange(st.n), i)
    A = A[np.ix_(keep, keep)]
    rows = A.sum(axis=1)
    pi = pi[keep]
    if np.any(rows <= 0) or pi.sum() <= 0:
        return None
    return _State(np.ascontiguousarray(pi / pi.sum()), np.ascontiguousarray(A / rows[:, None]),
                  np.ascontiguousarray(st.means[keep]), np.ascontiguousarray(st.covars[keep]), st.covariance)


def _state_trim_scores(st: _State, ev, z) -> np.ndarray:
    """Estimated log-posterior gain of deleting each state (the rule of docs/entropic.md):
    its description cost Z·[H(θ_i·) + ½ log((2πe)^D |K_i|)] minus the evidence only it explains, Σ_t γ_ti · max(0, log b_i(x_t) − max_{j≠i} log b_j(x_t))."""
    n = st.n
    if n < 2:
        return np.full(n, -np.inf)
    cost = _core.entropic_state_costs(st.transmat, st.covars_2d(), st.covariance, z, 0.0)
    return cost - ev.exclusive_evidence()


def _record(history, it, z, lp, lp0, ll, st, n_arcs_trimmed, n_states_trimmed, trials):
    history.append({"iteration": it, "z": z, "log_posterior": lp, "log_posterior_untrimmed": lp0,
                    "log_likelihood": ll,
                    "states": int(st.n), "arcs": int(np.count_nonzero(st.transmat)),
                    "arcs_trimmed": int(n_arcs_trimmed), "states_trimmed": int(n_states_trimmed),
                    "trim_trials": int(trials)})


class EntropicHMM(GaussianHMM):
    """A Gaussian HMM trained by entropic MAP-EM (:func:`fit_entropic`) instead of Baum-Welch.

    Parameters
    ----------
    n_states, covariance, **options
        As for :class:`voicepuppet.hmm.gaussian.GaussianHMM`.
    z : float or sequence of float
        Weight of the entropic prior (1, the default: minimum entropy; 0: maximum likelihood;
        < 0: high temperature), or one value per iteration (see :func:`anneal_schedule`).
    trim : bool
        Trim arcs and states whenever that raises the log posterior (default True).

    Attributes
    ----------
    history_ : list of dict
        One entry per iteration, as :func:`fit_entropic` returns them (``log_posterior``,
        ``states``, ``arcs``, ...); states may be trimmed, so ``n_states`` can shrink.
    z, trim
        The constructor's arguments.

    Raises
    ------
    ValueError
        ``z`` not a finite number or a 1-D sequence of them, or an option
        :class:`~voicepuppet.hmm.gaussian.GaussianHMM` refuses.
    """

    def __init__(self, n_states: int = 1, covariance: str = "full", *, z=1.0, trim: bool = True, **options):
        super().__init__(n_states, covariance, **options)
        z_values = np.atleast_1d(np.asarray(z, dtype=np.float64))
        if z_values.ndim != 1 or z_values.size == 0 or not np.all(np.isfinite(z_values)):
            raise ValueError(f"z must be a finite number or a 1-D sequence of them, got {z!r}")
        self.z = z
        self.trim = bool(trim)

    def fit(self, X, lengths=None, estep=None) -> "EntropicHMM":
        """Estimate the parameters by entropic MAP-EM, trimming as it goes.

        Parameters
        ----------
        X : array_like, shape (T, D)
            Training observations of all sequences, stacked in time.
        lengths : array_like of int, shape (S,), optional
            Frames per sequence; must sum to T. ``None`` (default): one sequence.
        estep : object, optional
            Where the data-side quantities come from (default :class:`LocalData` over ``X``; on
            a cluster :class:`voicepuppet.hmm.distributed.DaskEStep`).

        Returns
        -------
        EntropicHMM
            ``self``, fitted; ``history_`` holds the iterations (see :func:`fit_entropic`).
        """
        fit_entropic(self, X, lengths, estep=estep)
        return self


def fit_entropic(model, X, lengths=None, estep=None) -> list[dict]:
    """Train ``model`` (an :class:`EntropicHMM`) by entropic MAP-EM.

    Each iteration: log densities and forward-backward; if ``model.trim`` and Z > 0, transition
    trimming (Brand's test θ_ij ≤ exp(−(ξ_ij/θ_ij)/Z)) and then state trimming, each kept only if
    the exact log posterior (a forward pass on the same densities) rises; then the entropic
    M-step (MAP multinomials for starts and rows, entropic covariances). At fixed Z every step
    is a generalised EM step, so the log posterior never decreases.

    Training stops after ``model.n_iter`` iterations, or earlier when, at an unchanged Z, an
    iteration trims nothing and gains less than ``model.tol`` in log posterior. The model's
    parameters and ``n_states`` are set to the result.

    Parameters
    ----------
    model : EntropicHMM
        The model to train: its options (``z``, ``trim``, ``n_iter``, ``tol``, ``params``,
        ``progress``, ...) and initialisation (:meth:`~voicepuppet.hmm.gaussian.GaussianHMM.initialize`).
    X : array_like, shape (T, D)
        Training observations of all sequences, stacked in time.
    lengths : array_like of int, shape (S,), optional
        Frames per sequence; must sum to T. ``None`` (default): one sequence.
    estep : object, optional
        Computes the data-side quantities (default: :class:`LocalData` over ``X``), e.g. on a
        cluster (:class:`voicepuppet.hmm.distributed.DaskEStep`); initialisation, trimming
        decisions and the M-step stay here.

    Returns
    -------
    list of dict
        Also stored as ``model.history_``: one dict per iteration with ``iteration``, ``z``,
        ``log_posterior`` and ``log_likelihood`` (at the parameters entering that iteration's
        M-step, after trimming), ``log_posterior_untrimmed`` (the same before trimming),
        ``states``, ``arcs``, how many arcs / states that iteration trimmed (``arcs_trimmed``,
        ``states_trimmed``) and ``trim_trials`` (forward passes spent).

    Raises
    ------
    ValueError
        Bad observations or lengths, fewer per-iteration ``z`` values than ``n_iter`` (give one
        value or one per iteration), a non-finite ``z``, or an ``estep`` over other data than ``X``.
    RuntimeError
        An iteration's model has no state sequence that explains the data (lower z, use
        ``trim=False``, or start from more states).
    """
    X, lengths = check_sequences(X, lengths)
    X = aligned(X)  # one data layout in every run (see voicepuppet.hmm.gaussian.aligned)
    model.initialize(X)
    model.check_params()
    n_iter = model.n_iter
    zs = np.asarray(model.z, dtype=np.float64).ravel()
    if zs.size == 1:
        zs = np.full(max(n_iter, 1), float(zs[0]))
    if zs.size < n_iter:
        raise ValueError(f"z has {zs.size} per-iteration values but n_iter = {n_iter}; give one value "
                         "or one per iteration (see voicepuppet.hmm.entropic.anneal_schedule)")
    for z in zs:
        _check_z(z)
    # The variance floor c acts per frame, as in Baum-Welch: K = (S + c w I) / (w + Z⁺), so Z = 0
    # is Baum-Welch with its floor. It is not part of the prior: the log posterior is the
    # log-likelihood plus Brand's entropic prior alone (no covariance prior term).
    floor = model.variance_floor
    cov = model.covariance
    shift = X.mean(axis=0)
    data = LocalData(X, lengths, cov) if estep is None else estep
    if not np.array_equal(np.asarray(data.shift), shift):
        raise ValueError("estep holds other data than X (its shift, the mean frame, differs); build it "
                         "from the same X and lengths")
    st = _State(model.startprob_.copy(), model.transmat_.copy(), model.means_.copy(),
                model.covars_.copy(), cov)
    history: list[dict] = []
    bar = None
    if model.progress:
        bar = tqdm(total=n_iter, desc="entropic EM", unit="it")
    previous, previous_z = -np.inf, None
    try:
        for it in range(n_iter):
            z = float(zs[it])
            log_b = data.densities(st.params())
            try:
                lp, ll, ev = _evaluate(st, log_b, data, z)
            except RuntimeError as exc:
                raise RuntimeError(f"entropic training at iteration {it} (z = {z}, {st.n} states, "
                                   f"{int(np.count_nonzero(st.transmat))} arcs) has no state sequence "
                                   f"that explains the data: {exc}. Lower z, use trim=False, or start "
                                   "from more states") from exc
            arcs_trimmed = states_trimmed = 0
            lp_untrimmed = lp
            trials_before = _TRIALS[0]
            if model.trim and z > 0:
                # Transition trimming: all candidates, then the weaker half, then a quarter.
                flags = _core.transition_trim_candidates(st.transmat, ev.expected_transitions, z)
                cand = np.argwhere(flags > 0)
                if len(cand):
                    order = np.argsort(st.transmat[cand[:, 0], cand[:, 1]])
                    for frac in (1.0, 0.5, 0.25):
                        k = max(1, int(math.ceil(frac * len(cand))))
                        f = np.zeros_like(flags)
                        sel = cand[order[:k]]
                        f[sel[:, 0], sel[:, 1]] = 1.0
                        trial = _State(st.startprob, _core.trim_transitions(st.transmat, f), st.means,
                                       st.covars, cov)
                        if _log_posterior(trial, log_b, data, z) > lp:
                            st, (lp, ll, ev) = trial, _evaluate(trial, log_b, data, z)
                            arcs_trimmed = k
                            break
                        if k == 1:
                            break
                # State trimming: best-scoring candidates first, each verified exactly.
                scores = _state_trim_scores(st, ev, z)
                tried = 0
                while st.n > 1 and tried < 3:
                    i = int(np.argmax(scores))
                    if not scores[i] > 0:
                        break
                    tried += 1
                    scores[i] = -np.inf
                    trial = _drop_state(st, i, int(ev.heirs()[i]))
                    if trial is None:
                        continue
                    trial_log_b = data.drop_state(log_b, i)
                    try:
                        accept = _log_posterior(trial, trial_log_b, data, z) > lp
                    except RuntimeError:  # no allowed path without this state
                        continue
                    if accept:
                        res = _evaluate(trial, trial_log_b, data, z)
                        st, log_b, (lp, ll, ev) = trial, trial_log_b, res
                        scores = _state_trim_scores(st, ev, z)
                        states_trimmed += 1
            _record(history, it, z, lp, lp_untrimmed, ll, st, arcs_trimmed, states_trimmed,
                    _TRIALS[0] - trials_before)
            if bar is not None:
                bar.set_postfix(logpost=f"{lp:.6g}", states=st.n, arcs=int(np.count_nonzero(st.transmat)))
                bar.update(1)
            if previous_z == z and lp - previous < model.tol and not (arcs_trimmed or states_trimmed):
                break
            previous, previous_z = lp, z
            # Entropic M-step.
            weight, ssum, outer = ev.gaussian_stats()
            xi, starts = ev.expected_transitions, ev.expected_starts
            params = model.params
            if "s" in params:
                st.startprob = _core.entropic_rows(starts[None, :], z, st.startprob[None, :])[0]
            if "t" in params:
                st.transmat = _core.entropic_rows(xi, z, st.transmat)
            if "m" in params or "c" in params:
                means, covars = _core.entropic_gaussian_mstep(weight, ssum, outer, shift, cov, z, floor,
                                                              st.means, st.covars_2d())
                if "m" in params:
                    st.means = means
                if "c" in params:
                    d = st.means.shape[1]
                    st.covars = covars.reshape(st.n, d, d) if cov == "full" else covars
    finally:
        if bar is not None:
            bar.close()
    model.n_states = st.n
    model.startprob_, model.transmat_ = st.startprob, st.transmat
    model.means_, model.covars_ = st.means, st.covars
    model.history_ = history
    return history


