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
  frame by frame, O(K) memory (:meth:`DPDS.stream`).

Phones never seen in training fall back, at generation, to the global statistics (documented
per model in ``docs/phonemes.md``); ``seen_`` says which phones were trained.
"""

from __future__ import annotations

import numpy as np

from voicepuppet import _core
from voicepuppet.phonemes.labels import N_PHONES

__all__ = ["PhonemeMeans", "PhonemeTrajectory", "SLDS", "DPDS", "DPDSStream", "MODELS",
           "PhonemePuppet", "stack_sequences", "observations"]


# --------------------------------------------------------------------------------------------
# input checks


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


def _check_labels(labels) -> np.ndarray:
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


class _Model:
    """Shared bookkeeping: dims, trained phones, global statistics."""

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
        self._require_fit()
        return int(self.n_dims_)

    def _test_data(self, Y_list, labels_list):
        self._require_fit()
        return stack_sequences(Y_list, labels_list, self.n_dims_)


# --------------------------------------------------------------------------------------------
# (1) per-phoneme mean


class PhonemeMeans(_Model):
    """One diagonal Gaussian per phone; generates each phone's mean (the paper's "HMM").

    Parameters
    ----------
    var_floor : float
        Variance floor as a fraction of each dimension's data variance.
    """

    name = "phoneme-mean"

    def fit(self, Y_list, labels_list, *, progress: bool = False) -> "PhonemeMeans":
        """Fit on sequences ``Y_list`` [T_s, K] with labels [T_s]; returns self."""
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
        """Mean face of each frame's phone, shape (T, K)."""
        self._require_fit()
        return self.means_[_check_labels(labels)].copy()

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) of the sequences under the per-phone Gaussians."""
        Y, lab, _ = self._test_data(Y_list, labels_list)
        v = self.vars_[lab]
        return float(-0.5 * np.sum(np.log(2 * np.pi * v) + (Y - self.means_[lab]) ** 2 / v))


# --------------------------------------------------------------------------------------------
# (2) Brand's trajectory with phoneme states


class PhonemeTrajectory(_Model):
    """Brand's closed-form trajectory with one ``[pose, velocity]`` Gaussian per phone.

    Parameters
    ----------
    var_floor : float
        Added to each covariance's diagonal as a fraction of the data variance of ``o_t``.
    """

    name = "brand-phoneme"

    def fit(self, Y_list, labels_list, *, progress: bool = False) -> "PhonemeTrajectory":
        """Fit on sequences ``Y_list`` [T_s, K] with labels [T_s]; returns self."""
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
        """Closed-form most probable trajectory for the phone sequence, shape (T, K)."""
        from voicepuppet.trajectory import solve_trajectory

        self._require_fit()
        lab = _check_labels(labels)
        return solve_trajectory(lab, self.means_, None, self.covars_)

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) of ``o_t = [y_t, y_t - y_{t-1}]`` (2K dims: not comparable
        with the other models, as the paper notes)."""
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


class SLDS(_Model):
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
        """
        from tqdm.auto import tqdm

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
        """Most likely sequence (the mean path) for the phones, shape (T, K)."""
        self._require_fit()
        lab = _check_labels(labels)
        return _core.dpds_generate(self.a_, self.mu1_, self.nu_, lab, np.zeros(0, np.int64))

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) by the Kalman filter."""
        Y, lab, off = self._test_data(Y_list, labels_list)
        return float(self._smooth(Y, lab, off)["log_likelihood"])


def _sum_by(lab: np.ndarray, values: np.ndarray) -> np.ndarray:
    out = np.zeros((N_PHONES, values.shape[1]))
    np.add.at(out, lab, values)
    return out


# --------------------------------------------------------------------------------------------
# (4) DPDS


class DPDS(_Model):
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
        """
        from scipy.optimize import minimize
        from tqdm.auto import tqdm

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
        """Mean path for the phones, shape (T, K); O(T K) time."""
        self._require_fit()
        lab = _check_labels(labels)
        return _core.dpds_generate(self.a_, self.mu_, self.nu_, lab, np.zeros(0, np.int64))

    def stream(self) -> "DPDSStream":
        """A frame-by-frame generator (O(K) memory) equal to :meth:`generate`."""
        self._require_fit()
        return DPDSStream(self)

    def log_likelihood(self, Y_list, labels_list) -> float:
        """Total log-likelihood (nats) of eq. 1 with the trained shared variance."""
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
        """Frames for the next phone labels (int, shape (n,)), shape (n, K)."""
        lab = np.asarray(labels)
        if lab.ndim == 0:
            lab = lab[None]
        if lab.size == 0:
            return np.zeros((0, self._s.state.size))
        return self._s.push(_check_labels(lab))

    def reset(self) -> None:
        """Start a new sequence (its first frame is the start mean of its phone)."""
        self._s.reset()

    @property
    def frames(self) -> int:
        """Frames generated so far."""
        return int(self._s.frames)


#: the four models by name, in the order of the paper's figure 4
MODELS = {"phoneme-mean": PhonemeMeans, "brand-phoneme": PhonemeTrajectory, "slds": SLDS, "dpds": DPDS}


# --------------------------------------------------------------------------------------------
# a phoneme-driven puppet: a model + the face space, from phones to landmarks

_FILE_VERSION = 1


class PhonemePuppet:
    """A phoneme-driven face model with its face space: phones in, landmarks out.

    The users' counterpart of :class:`voicepuppet.puppet.model.Puppet` for the phoneme peers: train on
    landmark sequences with their phone labels, animate from phones (or from speech and its
    transcript, aligned by :func:`voicepuppet.phonemes.labels.align`), save and load.

    Attributes
    ----------
    model : PhonemeMeans, PhonemeTrajectory, SLDS or DPDS
    face_space : voicepuppet.face.FaceSpace
    fps : float
    """

    def __init__(self, model, face_space, fps: float):
        self.model, self.face_space, self.fps = model, face_space, float(fps)

    @classmethod
    def train(cls, points_list, phones_list, *, fps: float = 29.97, model: str = "dpds",
              alphabet: str = "arpabet", n_components=0.98, progress: bool = False,
              **options) -> "PhonemePuppet":
        """Train on landmark sequences and their phones.

        Parameters
        ----------
        points_list : list of ndarray, each shape (T_s, P, 2)
        phones_list : list
            Per sequence: phone segments (as accepted by :func:`voicepuppet.phonemes.labels.normalize`)
            or frame labels (int array of shape (T_s,)).
        fps : float
            Frame rate of the landmarks.
        model : {"phoneme-mean", "brand-phoneme", "slds", "dpds"}
        alphabet : {"arpabet", "espeak"}
            Alphabet of phone segments.
        n_components : int or float
            Face-space size (:meth:`voicepuppet.face.FaceSpace.fit`).
        **options
            Passed to the model's constructor.
        """
        from voicepuppet.face import FaceSpace

        if model not in MODELS:
            raise ValueError(f"model must be one of {list(MODELS)}, got {model!r}")
        if isinstance(points_list, np.ndarray):
            points_list = [points_list]
        if len(points_list) != len(phones_list):
            raise ValueError(f"give phones for every landmark sequence: {len(points_list)} sequences, "
                             f"{len(phones_list)} phone lists")
        fs = FaceSpace.fit(list(points_list), n_components=n_components)
        Y = [fs.encode(p)[0] for p in points_list]
        labels = [_frame_labels(ph, len(p), fps, alphabet) for ph, p in zip(phones_list, points_list)]
        m = MODELS[model](**options).fit(Y, labels, progress=progress)
        return cls(m, fs, fps)

    def animate(self, phones=None, *, audio=None, transcript: str | None = None,
                n_frames: int | None = None, alphabet: str = "arpabet"):
        """Landmarks for phones, or for speech (aligned to ``transcript`` by pocketsphinx).

        Parameters
        ----------
        phones : segments or int array (T,), optional
            Phone segments (seconds) or frame labels.
        audio : path or ndarray, optional
            Instead of ``phones``: speech to align (16 kHz mono samples or a sound file).
        transcript : str, optional
            The words of ``audio`` (phone recognition without it).
        n_frames : int, optional
            Frames to generate from segments (default: their duration times fps).
        alphabet : {"arpabet", "espeak"}

        Returns
        -------
        voicepuppet.animation.Animation
            Landmarks at the mean training pose, at the training frame rate.
        """
        from voicepuppet.animation import Animation
        from voicepuppet.phonemes.labels import align

        if (phones is None) == (audio is None):
            raise ValueError("give exactly one of phones or audio")
        if audio is not None:
            phones = align(audio, transcript, sample_rate=16000 if isinstance(audio, np.ndarray) else None)
            alphabet = "arpabet"
        lab = np.asarray(phones) if isinstance(phones, np.ndarray) else None
        if lab is None or lab.dtype.kind not in "iu":
            from voicepuppet.phonemes.labels import normalize

            segs = normalize(phones, alphabet)
            if not segs:
                raise ValueError("no phones to animate")
            n = int(round(segs[-1].end * self.fps)) if n_frames is None else int(n_frames)
            lab = _frame_labels(segs, n, self.fps, "arpabet")
        Y = self.model.generate(lab)
        return Animation(self.face_space.decode(Y), self.fps)

    def save(self, path) -> None:
        """Write the puppet as ``.npz`` (atomically)."""
        from voicepuppet._files import atomic_path

        arrays = {k: v for k, v in vars(self.model).items() if k.endswith("_") and isinstance(v, np.ndarray)}
        params = {k: v for k, v in vars(self.model).items()
                  if not k.endswith("_") and isinstance(v, (int, float, str, bool))}
        payload = {f"model/{k}": v for k, v in arrays.items()}
        payload.update(self.face_space.to_arrays("face/"))
        import json as _json

        meta = dict(version=_FILE_VERSION, kind=self.model.name, fps=self.fps, n_dims=self.model.n_dims,
                    params=params, part_names=list(self.face_space.part_names))
        payload["meta"] = np.array(_json.dumps(meta))
        with atomic_path(path, (".npz",), "phoneme puppet") as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, **payload)

    @classmethod
    def load(cls, path) -> "PhonemePuppet":
        """Read a puppet written by :meth:`save`."""
        import json as _json
        import os

        from voicepuppet.face import FaceSpace

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"phoneme puppet {path!r} does not exist")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            meta = _json.loads(str(arrays.pop("meta")))
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"{path!r} is not a phoneme puppet file ({exc})") from None
        if meta.get("version") != _FILE_VERSION or meta.get("kind") not in MODELS:
            raise ValueError(f"{path!r}: unsupported phoneme puppet (version {meta.get('version')}, "
                             f"kind {meta.get('kind')!r})")
        m = MODELS[meta["kind"]](**meta["params"])
        for k, v in arrays.items():
            if k.startswith("model/"):
                setattr(m, k[len("model/"):], v)
        m.n_dims_ = int(meta["n_dims"])
        fs = FaceSpace.from_arrays(arrays, meta["part_names"], "face/")
        return cls(m, fs, meta["fps"])


def _frame_labels(phones, n_frames: int, fps: float, alphabet: str) -> np.ndarray:
    from voicepuppet.phonemes.labels import frame_labels

    arr = np.asarray(phones) if isinstance(phones, np.ndarray) else None
    if arr is not None and arr.dtype.kind in "iu":
        if arr.shape != (n_frames,):
            raise ValueError(f"frame labels must have shape ({n_frames},) (one per landmark frame), "
                             f"got {arr.shape}")
        return _check_labels(arr)
    return frame_labels(phones, n_frames, fps, alphabet=alphabet)


# --------------------------------------------------------------------------------------------
# command line: voicepuppet phoneme-puppet train|animate


def _read_labels(path, alphabet: str):
    from voicepuppet.phonemes import labels as phonemes

    low = str(path).lower()
    if low.endswith(".textgrid"):
        return phonemes.read_textgrid(path, alphabet=alphabet)
    if low.endswith(".lab"):
        return phonemes.read_hts(path, alphabet=alphabet)
    raise ValueError(f"phone labels must be a .TextGrid or an HTS .lab file, got {str(path)!r}")


def _run_train(args) -> int:
    from voicepuppet.animation import load_animation

    if len(args.landmarks) != len(args.labels):
        raise ValueError(f"give one label file per landmark file: {len(args.landmarks)} landmark files, "
                         f"{len(args.labels)} label files")
    anims = [load_animation(p) for p in args.landmarks]
    fps = anims[0].fps
    for p, a in zip(args.landmarks, anims):
        if abs(a.fps - fps) > 1e-6:
            raise ValueError(f"all landmark files must share one frame rate; {p} has {a.fps}, "
                             f"{args.landmarks[0]} has {fps}")
    phones = [_read_labels(p, args.alphabet) for p in args.labels]
    n_comp = float(args.components) if "." in args.components else int(args.components)
    pp = PhonemePuppet.train([a.points for a in anims], phones, fps=fps, model=args.model,
                             alphabet=args.alphabet, n_components=n_comp, progress=not args.quiet)
    pp.save(args.output)
    n = sum(len(a.points) for a in anims)
    print(f"{args.model} on {n} frames of {len(anims)} sequences ({pp.face_space.n_dims} face dims); "
          f"wrote {args.output}")
    return 0


def _run_animate(args) -> int:
    from voicepuppet.animation import save_animation

    pp = PhonemePuppet.load(args.puppet)
    if (args.audio is None) == (args.labels is None):
        raise ValueError("give AUDIO (with --transcript, or phone recognition without) or --labels FILE")
    if args.labels is not None:
        anim = pp.animate(_read_labels(args.labels, args.alphabet))
    else:
        anim = pp.animate(audio=args.audio, transcript=args.transcript)
    save_animation(anim, args.output)
    print(f"{len(anim.points)} frames at {anim.fps:g} fps; wrote {args.output}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("phoneme-puppet", help="train or animate a phoneme-driven face model (DPDS, SLDS, ...)",
                       description="Phoneme-driven peers of the voice puppet: train a model on landmark "
                                   "sequences with their phone labels, animate it from phone labels or "
                                   "from speech and its transcript (pocketsphinx alignment).")
    ss = p.add_subparsers(dest="action", metavar="ACTION")
    ss.required = True
    t = ss.add_parser("train", help="train on landmarks (.npz/.csv) and phone labels (.TextGrid/.lab)")
    t.add_argument("--landmarks", nargs="+", required=True, metavar="FILE", help="landmark animations, one per sequence")
    t.add_argument("--labels", nargs="+", required=True, metavar="FILE", help="phone labels, one per sequence")
    t.add_argument("--model", choices=list(MODELS), default="dpds", help="which model (default dpds)")
    t.add_argument("--alphabet", choices=["arpabet", "espeak"], default="arpabet")
    t.add_argument("--components", default="0.98", help="face-space size: integer or variance fraction")
    t.add_argument("-o", "--output", required=True, metavar="MODEL.npz")
    t.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    t.set_defaults(func=_run_train)
    a = ss.add_parser("animate", help="landmarks from speech + transcript, or from phone labels")
    a.add_argument("puppet", help="a model written by 'phoneme-puppet train'")
    a.add_argument("audio", nargs="?", help="speech to align (sound file)")
    a.add_argument("-t", "--transcript", help="the words of AUDIO (phone recognition without)")
    a.add_argument("--labels", metavar="FILE", help="phone labels (.TextGrid/.lab) instead of AUDIO")
    a.add_argument("--alphabet", choices=["arpabet", "espeak"], default="arpabet")
    a.add_argument("-o", "--output", required=True, metavar="ANIM.npz|.csv")
    a.set_defaults(func=_run_animate)
