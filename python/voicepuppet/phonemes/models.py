"""Phoneme-driven face models (Englebienne, Cootes & Rattray, NIPS 2007), peers of the puppet.

Four generators of face vectors ``Y`` [T, K] (``voicepuppet.face`` coordinates) from phone labels
[T] (indices into :data:`voicepuppet.phonemes.labels.PHONES`, one per video frame), all with the same
interface: ``fit(Y_list, labels_list)``, ``generate(labels)``, ``log_likelihood(Y_list,
labels_list)``.

* :class:`PhonemeMeans` -- the "standard HMM" of the paper's figure 4: one diagonal Gaussian per
  phone; generates each phone's mean face.
* :class:`PhonemeTrajectory` -- Brand's trajectory with phoneme states: one full-covariance
  Gaussian per phone over ``o_t = [y_t, y_t - y_{t-1}]`` and the closed-form solve of
  :func:`voicepuppet.trajectory.solve_trajectory`.
* :class:`SLDS` -- switching linear dynamical system with B = I and known labels: diagonal
  transition ``a_p``, bias ``nu_p``, process and output variances per phone, trained by EM with
  the Kalman smoother (C++ ``slds_smooth``); generates the most likely sequence.
* :class:`DPDS` -- the deterministic process dynamical system: ``x_1 = mu_{s_1}``,
  ``x_t = a_{s_t} * x_{t-1} + nu_{s_t}``, one shared diagonal output variance; ``a`` by L-BFGS-B
  on the profile likelihood (gradient by the adjoint recursion in C++), ``mu``, ``nu`` and the
  variance by the exact linear solve of the paper's Algorithm 1 (C++ ``dpds_solve``); generation
  frame by frame, O(K) memory (:meth:`DPDS.stream`), in :mod:`voicepuppet.phonemes.dpds`.

Phones never seen in training fall back, at generation, to the global statistics (documented
per model in ``docs/phonemes.md``); ``seen_`` says which phones were trained.
"""

from __future__ import annotations

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import _core
from voicepuppet.phonemes.base import PhonemeModel, check_labels, observations
from voicepuppet.phonemes.dpds import DPDS
from voicepuppet.phonemes.labels import N_PHONES
from voicepuppet.trajectory import solve_trajectory

__all__ = ["PhonemeMeans", "PhonemeTrajectory", "SLDS", "MODELS"]


# --------------------------------------------------------------------------------------------
# (1) per-phoneme mean


class PhonemeMeans(PhonemeModel):
    """One diagonal Gaussian per phone; generates each phone's mean (the paper's "HMM").

    Parameters
    ----------
    var_floor : float
        Variance floor as a fraction of each dimension's data variance.
    """

    name = "phoneme-mean"

    def fit(self, Y_list, labels_list, *, progress: bool = False) -> "PhonemeMeans":
        """Fit on sequences ``Y_list`` [T_s, K] with labels [T_s]; returns self.

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
        Y, lab, _ = self._prepare(Y_list, labels_list)
        counts = np.bincount(lab, minlength=N_PHONES).astype(np.float64)
        sq = np.zeros((N_PHONES, Y.shape[1]))
        np.add.at(sq, lab, (Y - self.phone_mean_[lab]) ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            var = sq / counts[:, None]
        var = np.where(self.seen_[:, None], var, self.global_var_)
        self.means_ = self.phone_mean_.copy()
        self.vars_ = np.maximum(var, self.floor_)
        return self

    def generate(self, labels) -> np.ndarray:
        """Mean face of each frame's phone, shape (T, K).

        Parameters
        ----------
        labels : array_like of int, shape (T,)
            Frame labels (indices into :data:`voicepuppet.phonemes.labels.PHONES`).

        Returns
        -------
        ndarray, shape (T, K)
        """
        self._require_fit()
        return self.means_[check_labels(labels)].copy()

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) of the sequences under the per-phone Gaussians.

        Parameters
        ----------
        Y_list : sequence of array_like, each shape (T_s, K)
        labels_list : sequence of array_like of int, each shape (T_s,)

        Returns
        -------
        float
        """
        Y, lab, _ = self._test_data(Y_list, labels_list)
        v = self.vars_[lab]
        return float(-0.5 * np.sum(np.log(2 * np.pi * v) + (Y - self.means_[lab]) ** 2 / v))


# --------------------------------------------------------------------------------------------
# (2) Brand's trajectory with phoneme states


class PhonemeTrajectory(PhonemeModel):
    """Brand's closed-form trajectory with one ``[pose, velocity]`` Gaussian per phone.

    Parameters
    ----------
    var_floor : float
        Added to each covariance's diagonal as a fraction of the data variance of ``o_t``.
    """

    name = "brand-phoneme"

    def fit(self, Y_list, labels_list, *, progress: bool = False) -> "PhonemeTrajectory":
        """Fit on sequences ``Y_list`` [T_s, K] with labels [T_s]; returns self.

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
        Y, lab, off = self._prepare(Y_list, labels_list)
        O = observations(Y, off)
        k2 = O.shape[1]
        gmean = O.mean(axis=0)
        gcov = np.cov(O.T, bias=True).reshape(k2, k2)
        floor = self.var_floor * np.maximum(np.diag(gcov), 1e-300)
        means = np.tile(gmean, (N_PHONES, 1))
        covs = np.tile(gcov + np.diag(floor), (N_PHONES, 1, 1))
        for p in np.nonzero(self.seen_)[0]:
            Op = O[lab == p]
            means[p] = Op.mean(axis=0)
            d = Op - means[p]
            covs[p] = d.T @ d / len(Op) + np.diag(floor)
        self.means_, self.covars_ = means, covs
        return self

    def generate(self, labels) -> np.ndarray:
        """Closed-form most probable trajectory for the phone sequence, shape (T, K).

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
        return solve_trajectory(lab, self.means_, None, self.covars_)

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) of ``o_t = [y_t, y_t - y_{t-1}]`` (2K dims: not comparable
        with the other models, as the paper notes).

        Parameters
        ----------
        Y_list : sequence of array_like, each shape (T_s, K)
        labels_list : sequence of array_like of int, each shape (T_s,)

        Returns
        -------
        float
        """
        from scipy.linalg import solve_triangular

        Y, lab, off = self._test_data(Y_list, labels_list)
        O = observations(Y, off)
        total = 0.0
        for p in np.unique(lab):
            L = np.linalg.cholesky(self.covars_[p])
            z = solve_triangular(L, (O[lab == p] - self.means_[p]).T, lower=True)
            n = z.shape[1]
            total += -0.5 * (n * (O.shape[1] * np.log(2 * np.pi) + 2 * np.sum(np.log(np.diag(L))))
                             + np.sum(z * z))
        return float(total)


# --------------------------------------------------------------------------------------------
# (3) SLDS with B = I


class SLDS(PhonemeModel):
    """Labelled switching linear dynamical system with B = I, trained by EM.

    Per phone ``p`` (all diagonal, so every face dimension is a scalar LDS):
    ``x_1 ~ N(mu1_p, var1_p)``, ``x_t = a_p * x_{t-1} + nu_p + w``, ``w ~ N(0, q_p)``,
    ``y_t = x_t + v``, ``v ~ N(0, r_p)``.

    Parameters
    ----------
    n_iter : int
        Maximum EM iterations.
    tol : float
        Stop when the log-likelihood per frame improves by less than this.
    a_bound : float
        ``|a| <= a_bound < 1`` (a constrained M-step) keeps the generated path stable.
    var_floor : float
        Variance floor (fraction of the data variance) for q, r and var1.

    Raises
    ------
    ValueError
        ``a_bound`` outside (0, 1), a bad ``n_iter`` or ``tol``.
    """

    name = "slds"

    def __init__(self, n_iter: int = 50, tol: float = 1e-5, a_bound: float = 0.999,
                 var_floor: float = 1e-3):
        super().__init__(var_floor)
        if not 0 < a_bound < 1:
            raise ValueError(f"a_bound must be in (0, 1), got {a_bound}")
        self.a_bound = float(a_bound)
        if int(n_iter) != n_iter or n_iter < 1:
            raise ValueError(f"n_iter must be a positive integer, got {n_iter}")
        if not np.isfinite(tol) or tol < 0:
            raise ValueError(f"tol must be non-negative, got {tol}")
        self.n_iter, self.tol = int(n_iter), float(tol)

    def _smooth(self, Y, lab, off):
        return _core.slds_smooth(self.a_, self.nu_, self.q_, self.r_, self.mu1_, self.var1_, Y, off, lab)

    def fit(self, Y_list, labels_list, *, progress: bool = False) -> "SLDS":
        """EM on sequences ``Y_list`` [T_s, K] with labels [T_s]; returns self.

        ``history_`` holds the log-likelihood (nats, total) before each M-step; it never
        decreases (tested).

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
        Y, lab, off = self._prepare(Y_list, labels_list)
        N, K = Y.shape
        cnt = np.bincount(lab, minlength=N_PHONES).astype(np.float64)
        sq = np.zeros((N_PHONES, K))
        np.add.at(sq, lab, (Y - self.phone_mean_[lab]) ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            pvar = np.where(self.seen_[:, None], sq / cnt[:, None], self.global_var_)
        pvar = np.maximum(pvar, self.floor_)
        self.a_ = np.full((N_PHONES, K), 0.5)
        self.nu_ = 0.5 * self.phone_mean_
        self.q_ = 0.5 * pvar
        self.r_ = 0.5 * pvar
        self.mu1_ = self.phone_mean_.copy()
        self.var1_ = pvar.copy()
        first = np.zeros(N, bool)
        first[off[:-1]] = True
        rest = ~first
        prev = np.nonzero(rest)[0] - 1
        lr = lab[rest]
        lf = lab[first]
        self.history_ = []
        bar = tqdm(range(self.n_iter), desc="SLDS EM", disable=not progress, leave=False)
        for _ in bar:
            sm = self._smooth(Y, lab, off)
            ll = float(sm["log_likelihood"])
            if self.history_ and (ll - self.history_[-1]) / N < self.tol:
                self.history_.append(ll)
                break
            self.history_.append(ll)
            m, v, c = sm["mean"], sm["var"], sm["cross"]
            exx = m * m + v
            # transitions: per phone and dim, a 2x2 least-squares system in (a, nu)
            s_pp = _sum_by(lr, exx[prev])
            s_p = _sum_by(lr, m[prev])
            s_cp = _sum_by(lr, m[rest] * m[prev] + c[rest])
            s_c = _sum_by(lr, m[rest])
            s_cc = _sum_by(lr, exx[rest])
            n = np.bincount(lr, minlength=N_PHONES).astype(np.float64)[:, None]
            det = s_pp * n - s_p * s_p
            ok = (n > 1) & (det > 1e-12 * np.maximum(s_pp * n, 1e-300))
            with np.errstate(invalid="ignore", divide="ignore"):
                a_new = (s_cp * n - s_p * s_c) / det
                nu_new = (s_pp * s_c - s_p * s_cp) / det
            # |a| <= a_bound keeps generation stable: where the unconstrained optimum lies
            # outside, the constrained optimum of this convex quadratic is on the bound
            # (nu re-solved given a), so EM still never decreases the likelihood
            with np.errstate(invalid="ignore", divide="ignore"):
                clipped = np.clip(a_new, -self.a_bound, self.a_bound)
                nu_new = np.where(clipped != a_new, (s_c - clipped * s_p) / n, nu_new)
            a = np.where(ok, clipped, self.a_)
            nu = np.where(ok, nu_new, self.nu_)
            with np.errstate(invalid="ignore", divide="ignore"):
                q = (s_cc - 2 * a * s_cp - 2 * nu * s_c + a * a * s_pp + 2 * a * nu * s_p + n * nu * nu) / n
                self.q_ = np.where(n > 0, np.maximum(q, self.floor_), self.q_)
            self.a_, self.nu_ = a, nu
            nr = cnt[:, None]
            rr = _sum_by(lab, (Y - m) ** 2 + v)
            with np.errstate(invalid="ignore", divide="ignore"):
                self.r_ = np.where(nr > 0, np.maximum(rr / nr, self.floor_), self.r_)
            n1 = np.bincount(lf, minlength=N_PHONES).astype(np.float64)[:, None]
            with np.errstate(invalid="ignore", divide="ignore"):
                mu1 = _sum_by(lf, m[first]) / n1
                var1 = _sum_by(lf, exx[first]) / n1 - mu1 * mu1
                self.mu1_ = np.where(n1 > 0, mu1, self.mu1_)
                self.var1_ = np.where(n1 > 0, np.maximum(var1, self.floor_), self.var1_)
            bar.set_postfix(ll_per_frame=f"{ll / N:.4f}")
        return self

    def generate(self, labels) -> np.ndarray:
        """Most likely sequence (the mean path) for the phones, shape (T, K).

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
        return _core.dpds_generate(self.a_, self.mu1_, self.nu_, lab, np.zeros(0, np.int64))

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) by the Kalman filter.

        Parameters
        ----------
        Y_list : sequence of array_like, each shape (T_s, K)
        labels_list : sequence of array_like of int, each shape (T_s,)

        Returns
        -------
        float
        """
        Y, lab, off = self._test_data(Y_list, labels_list)
        return float(self._smooth(Y, lab, off)["log_likelihood"])


def _sum_by(lab: np.ndarray, values: np.ndarray) -> np.ndarray:
    out = np.zeros((N_PHONES, values.shape[1]))
    np.add.at(out, lab, values)
    return out


#: the four models by name, in the order of the paper's figure 4
MODELS = {"phoneme-mean": PhonemeMeans, "brand-phoneme": PhonemeTrajectory, "slds": SLDS, "dpds": DPDS}
