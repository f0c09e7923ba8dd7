"""The deterministic process dynamical system (DPDS) of Englebienne, Cootes & Rattray (NIPS
2007): ``x_1 = mu_{s_1}``, ``x_t = a_{s_t} * x_{t-1} + nu_{s_t}``, one shared diagonal output
variance; ``a`` by L-BFGS-B on the profile likelihood (gradient by the adjoint recursion in C++),
``mu``, ``nu`` and the variance by the exact linear solve of the paper's Algorithm 1 (C++
``dpds_solve``); generation frame by frame, O(K) memory (:meth:`DPDS.stream`).
"""

from __future__ import annotations

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import _core
from voicepuppet.phonemes.base import PhonemeModel, check_labels
from voicepuppet.phonemes.labels import N_PHONES

__all__ = ["DPDS", "DPDSStream"]


class DPDS(PhonemeModel):
    """Deterministic process dynamical system (Englebienne et al. 2007, §3 and appendix A).

    ``x_1 = mu_{s_1}``, ``x_t = a_{s_t} * x_{t-1} + nu_{s_t}``, ``y_t = x_t + v``,
    ``v ~ N(0, diag(r))`` with ``r`` shared by all phones.

    Parameters
    ----------
    max_iter : int
        Maximum L-BFGS-B iterations on ``a``.
    a_init : float
        Initial value of every transition coefficient.
    a_bound : float
        ``|a| <= a_bound < 1`` keeps generation stable over any length.
    var_floor : float
        Floor of ``r`` (fraction of the data variance).

    Raises
    ------
    ValueError
        A negative or fractional ``max_iter``, ``a_bound`` outside (0, 1), ``|a_init| > a_bound``.
    """

    name = "dpds"

    def __init__(self, max_iter: int = 200, a_init: float = 0.5, a_bound: float = 0.999,
                 var_floor: float = 1e-3):
        super().__init__(var_floor)
        if int(max_iter) != max_iter or max_iter < 0:
            raise ValueError(f"max_iter must be a non-negative integer, got {max_iter}")
        if not 0 < a_bound < 1:
            raise ValueError(f"a_bound must be in (0, 1), got {a_bound}")
        if not abs(a_init) <= a_bound:
            raise ValueError(f"a_init must be within +-a_bound ({a_bound}), got {a_init}")
        self.max_iter, self.a_init, self.a_bound = int(max_iter), float(a_init), float(a_bound)

    def fit(self, Y_list, labels_list, *, progress: bool = False) -> "DPDS":
        """Train on sequences ``Y_list`` [T_s, K] with labels [T_s]; returns self.

        ``history_`` holds the log-likelihood (nats, total) after each L-BFGS-B iteration,
        non-decreasing (each iteration satisfies the Wolfe conditions).

        Parameters
        ----------
        Y_list : sequence of array_like, each shape (T_s, K)
            Face vectors.
        labels_list : sequence of array_like of int, each shape (T_s,)
            Frame labels (indices into :data:`voicepuppet.phonemes.labels.PHONES`).
        progress : bool
            Show a progress bar.

        Returns
        -------
        self

        Raises
        ------
        ValueError
            Bad sequences (see :func:`voicepuppet.phonemes.base.stack_sequences`).
        """
        from scipy.optimize import minimize

        Y, lab, off = self._prepare(Y_list, labels_list)
        N, K = Y.shape
        shape = (N_PHONES, K)

        def evaluate(flat):
            a = np.ascontiguousarray(flat.reshape(shape))
            s = _core.dpds_solve(a, Y, off, lab, self.floor_)
            g = _core.dpds_gradient(a, s["mu"], s["nu"], s["r"], Y, off, lab)
            return -s["log_likelihood"] / N, -g["grad_a"].ravel() / N

        x0 = np.full(N_PHONES * K, self.a_init)
        f0, _ = evaluate(x0)
        self.history_ = [-f0 * N]
        bar = tqdm(total=self.max_iter, desc="DPDS L-BFGS", disable=not progress, leave=False)

        def callback(intermediate_result):
            # scipy passes the accepted iterate with its objective: no extra solve
            self.history_.append(float(-intermediate_result.fun * N))
            bar.update()
            bar.set_postfix(ll_per_frame=f"{self.history_[-1] / N:.4f}")

        if self.max_iter > 0:
            res = minimize(evaluate, x0, jac=True, method="L-BFGS-B",
                           bounds=[(-self.a_bound, self.a_bound)] * x0.size, callback=callback,
                           options=dict(maxiter=self.max_iter, ftol=1e-10, gtol=1e-7))
            xa = res.x
            self.converged_ = bool(res.success)
        else:
            xa = x0
            self.converged_ = False
        bar.close()
        a = np.ascontiguousarray(xa.reshape(shape))
        s = _core.dpds_solve(a, Y, off, lab, self.floor_)
        self.a_ = a
        mu_used = s["mu_used"].astype(bool)
        nu_used = s["nu_used"].astype(bool)
        self.mu_ = np.where(mu_used[:, None], s["mu"], self.phone_mean_)
        self.nu_ = np.where(nu_used[:, None], s["nu"], (1.0 - a) * self.phone_mean_)
        self.r_ = s["r"]
        self.log_likelihood_ = float(s["log_likelihood"])
        return self

    def generate(self, labels) -> np.ndarray:
        """Mean path for the phones, shape (T, K); O(T K) time.

        Parameters
        ----------
        labels : array_like of int, shape (T,)
            Frame labels (indices into :data:`voicepuppet.phonemes.labels.PHONES`).

        Returns
        -------
        ndarray, shape (T, K)
        """
        self._require_fit()
        lab = check_labels(labels)
        return _core.dpds_generate(self.a_, self.mu_, self.nu_, lab, np.zeros(0, np.int64))

    def stream(self) -> "DPDSStream":
        """A frame-by-frame generator (O(K) memory) equal to :meth:`generate`.

        Returns
        -------
        DPDSStream
        """
        self._require_fit()
        return DPDSStream(self)

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) of eq. 1 with the trained shared variance.

        Parameters
        ----------
        Y_list : sequence of array_like, each shape (T_s, K)
        labels_list : sequence of array_like of int, each shape (T_s,)

        Returns
        -------
        float
        """
        Y, lab, off = self._test_data(Y_list, labels_list)
        g = _core.dpds_gradient(self.a_, self.mu_, self.nu_, self.r_, Y, off, lab)
        return float(g["log_likelihood"])


class DPDSStream:
    """Streaming DPDS generation: push phone labels as they arrive, get their frames at once.

    Parameters
    ----------
    model : DPDS
        A trained model.
    """

    def __init__(self, model: DPDS):
        model._require_fit()
        self._s = _core.DpdsStream(model.a_, model.mu_, model.nu_)

    def push(self, labels) -> np.ndarray:
        """Frames for the next phone labels.

        Parameters
        ----------
        labels : int or array_like of int, shape (n,)
            The next frames' phone indices.

        Returns
        -------
        ndarray, shape (n, K)
        """
        lab = np.asarray(labels)
        if lab.ndim == 0:
            lab = lab[None]
        if lab.size == 0:
            return np.zeros((0, self._s.state.size))
        return self._s.push(check_labels(lab))

    def reset(self) -> None:
        """Start a new sequence (its first frame is the start mean of its phone)."""
        self._s.reset()

    @property
    def frames(self) -> int:
        """Frames generated so far."""
        return int(self._s.frames)
