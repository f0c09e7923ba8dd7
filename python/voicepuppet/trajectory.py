"""Closed-form trajectory synthesis (Voice Puppetry §4.5, eq. 5-6; MLPG with full covariance).

Given a facial state sequence (or per-frame state weights from forward-backward) and per-state
Gaussians over ``[pose, velocity]``, the most probable trajectory ``Y [T, D]`` minimises

    frame 0:    (y_0 - mu)^T (K^xx)^-1 (y_0 - mu)              (pose marginal; no velocity term)
    frame t>=1: o_t^T K^-1 o_t,   o_t = [y_t - mu, (y_t - y_{t-1}) - mu_dot]

with ``mu, mu_dot, K`` those of the state of frame t. The normal equations are block
tridiagonal; the C++ kernel (``cpp/include/voicepuppet/trajectory.hpp``) factors them by block
Cholesky in O(T D^3) time and O(T D^2) memory, or as D scalar tridiagonal systems for diagonal
covariances. See ``docs/trajectory.md`` for the frame-rate rule, the boundary and the fixed-lag
streaming variant.
"""

from __future__ import annotations

import math

import numpy as np

from voicepuppet import _core

__all__ = [
    "FixedLagTrajectory",
    "MAX_MOTION_GAIN",
    "widen_motion",
    "make_model",
    "resample_states",
    "resample_weights",
    "solve_trajectory",
    "solve_trajectory_weighted",
    "velocity_scale",
]

_COVARIANCE_TYPES = ("full", "diag")


def _check_rate(value, name: str) -> float:
    try:
        rate = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive frame rate in frames per second, got {value!r}") from None
    if not math.isfinite(rate) or rate <= 0.0:
        raise ValueError(f"{name} must be a positive frame rate in frames per second, got {value!r}")
    return rate


def velocity_scale(model_fps: float, out_fps: float) -> float:
    """Velocity scale ``r = model_fps / out_fps`` for synthesis at another frame rate.

    A model whose velocities were measured per training frame (rate ``model_fps``) scores an
    output-frame difference ``d = y_t - y_{t-1}`` (rate ``out_fps``) as the training-frame
    velocity ``d / r``. Equivalently the state Gaussian over ``[pose, d]`` has velocity mean
    ``r * mu_dot``, pose-velocity covariance ``r * K^xv`` and velocity covariance ``r**2 * K^vv``.

    Parameters
    ----------
    model_fps : float
        Frame rate of the training video (the unit of the model's velocities).
    out_fps : float
        Frame rate of the synthesised trajectory.

    Returns
    -------
    float
        ``model_fps / out_fps``.

    Raises
    ------
    ValueError
        A rate that is not positive and finite.
    """
    return _check_rate(model_fps, "model_fps") / _check_rate(out_fps, "out_fps")


def make_model(means, vel_means, covars, covariance_type: str = "full",
               velocity_scale: float = 1.0) -> _core.TrajectoryModel:
    """Check the per-state Gaussians and build the normal-equation blocks once.

    Parameters
    ----------
    means : array_like, shape (N, D), or (N, 2D) when ``vel_means`` is None
        Pose means per state. With ``vel_means=None``, ``means`` holds ``[pose, velocity]``
        means side by side, as a Gaussian HMM trained on ``o_t = [x_t, x_t - x_{t-1}]`` has them.
    vel_means : array_like, shape (N, D), or None
        Velocity means per state, per training frame.
    covars : array_like
        ``"full"``: shape (N, 2D, 2D) or (N*2D, 2D), the covariance of ``[pose, velocity]``;
        ``"diag"``: shape (N, 2D), the variances of ``[pose, velocity]``.
    covariance_type : {"full", "diag"}
        Form of ``covars`` (default ``"full"``).
    velocity_scale : float
        ``model_fps / out_fps`` (see :func:`velocity_scale`); 1 (the default) for the training
        rate.

    Returns
    -------
    voicepuppet._core.TrajectoryModel
        Reusable by :func:`solve_trajectory` and :class:`FixedLagTrajectory` (pass it as ``model``).

    Raises
    ------
    ValueError
        On shapes that do not match, non-finite values, a covariance that is not symmetric
        positive definite (with its condition estimate) or an unknown ``covariance_type``.
    """
    if covariance_type not in _COVARIANCE_TYPES:
        raise ValueError(f"covariance_type must be one of {_COVARIANCE_TYPES}, got {covariance_type!r}")
    means = np.asarray(means, dtype=np.float64)
    if means.ndim != 2 or means.shape[0] == 0 or means.shape[1] == 0:
        raise ValueError(f"means must be 2-D (states, dims) and non-empty, got shape {means.shape}")
    if vel_means is None:
        if means.shape[1] % 2:
            raise ValueError(f"with vel_means=None, means must be (N, 2D) [pose, velocity] means; "
                             f"got an odd number of columns, shape {means.shape}")
        d = means.shape[1] // 2
        means, vel_means = means[:, :d], means[:, d:]
    vel_means = np.ascontiguousarray(vel_means, dtype=np.float64)
    means = np.ascontiguousarray(means, dtype=np.float64)
    n, d = means.shape
    if vel_means.shape != (n, d):
        raise ValueError(f"vel_means must have the shape of means ({n}, {d}), got {vel_means.shape}")
    covars = np.asarray(covars, dtype=np.float64)
    if covariance_type == "full":
        if covars.shape == (n, 2 * d, 2 * d):
            covars = covars.reshape(n * 2 * d, 2 * d)
        if covars.shape != (n * 2 * d, 2 * d):
            raise ValueError(f"covars (full) must have shape ({n}, {2 * d}, {2 * d}) or "
                             f"({n * 2 * d}, {2 * d}) for {n} states of {d} dims, got {covars.shape}")
    elif covars.shape != (n, 2 * d):
        raise ValueError(f"covars (diag) must have shape ({n}, {2 * d}) ([pose, velocity] variances), "
                         f"got {covars.shape}")
    for name, arr in (("means", means), ("vel_means", vel_means), ("covars", covars)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains NaN or infinite values; fix the model")
    return _core.TrajectoryModel(means, vel_means, np.ascontiguousarray(covars), covariance_type,
                                 float(velocity_scale))


def _check_states(states, n_states: int) -> np.ndarray:
    arr = np.asarray(states)
    if arr.ndim != 1:
        raise ValueError(f"states must be 1-D (one state index per frame), got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError("states is empty; pass at least one frame")
    if not (np.issubdtype(arr.dtype, np.integer)
            or (np.issubdtype(arr.dtype, np.floating) and np.all(np.mod(arr, 1) == 0))):
        raise ValueError(f"states must hold integer state indices, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    bad = np.flatnonzero((arr < 0) | (arr >= n_states))
    if bad.size:
        raise ValueError(f"states[{bad[0]}] = {arr[bad[0]]} is out of range: the model has {n_states} "
                         f"states (valid indices 0 .. {n_states - 1})")
    return np.ascontiguousarray(arr)


def _check_weights(weights, n_states: int) -> np.ndarray:
    w = np.ascontiguousarray(weights, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != n_states:
        raise ValueError(f"weights must have shape (T, {n_states}) (one column per state), got {w.shape}")
    if w.shape[0] == 0:
        raise ValueError("weights has zero frames; pass at least one frame")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative (state posteriors or probabilities)")
    zero = np.flatnonzero(w.sum(axis=1) <= 0)
    if zero.size:
        raise ValueError(f"weights row {zero[0]} sums to zero: every frame needs a positive weight on some state")
    return w


def _evidence(targets, precision) -> tuple:
    """The optional evidence as float arrays for the C++ solve (which checks shapes, finiteness,
    symmetry and that both or neither are given)."""
    def f64(a):
        return None if a is None else np.ascontiguousarray(a, dtype=np.float64)

    return f64(targets), f64(precision)


def _rates(model_fps, states_fps, out_fps) -> tuple[float, float | None, float | None]:
    """(velocity scale, fps_in, fps_out); fps_in/out None when no resampling is asked for."""
    if model_fps is None:
        if states_fps is not None or out_fps is not None:
            raise ValueError("model_fps (the training video's frame rate) is required when states_fps "
                             "or out_fps is given")
        return 1.0, None, None
    model_fps = _check_rate(model_fps, "model_fps")
    fps_in = model_fps if states_fps is None else _check_rate(states_fps, "states_fps")
    fps_out = fps_in if out_fps is None else _check_rate(out_fps, "out_fps")
    return model_fps / fps_out, fps_in, fps_out


def solve_trajectory(states, means, vel_means, covars, *, covariance_type: str = "full",
                     model_fps: float | None = None, states_fps: float | None = None,
                     out_fps: float | None = None, evidence_targets=None,
                     evidence_precision=None) -> np.ndarray:
    """Most probable trajectory for a state sequence (Brand's eq. 5-6).

    Parameters
    ----------
    states : array_like of int, shape (T,)
        State index per frame (e.g. Viterbi on the vocal HMM), at rate ``states_fps``.
    means, vel_means, covars, covariance_type
        The per-state ``[pose, velocity]`` Gaussians, as in :func:`make_model`.
    model_fps : float, optional
        Frame rate of the training video. Needed only to synthesise at another rate.
    states_fps : float, optional
        Frame rate of ``states`` (default ``model_fps``).
    out_fps : float, optional
        Frame rate of the output (default ``states_fps``). The states are resampled by sample
        and hold (:func:`resample_states`) and the velocity terms scaled by
        ``model_fps / out_fps`` (:func:`velocity_scale`).
    evidence_targets, evidence_precision : array_like, optional
        Per-frame evidence (both or neither): targets ŷ of shape ``(T_out, D)`` at the output
        rate and one precision W ``(D, D)`` (symmetric positive semi-definite, any weight λ
        folded in). The objective gains ``Σ_t (y_t − ŷ_t)ᵀ W (y_t − ŷ_t)`` (a guided puppet's
        ridge prediction, docs/trajectory.md); the system stays block tridiagonal. W = 0 is the
        plain solve.

    Returns
    -------
    ndarray, shape (T_out, D)
        ``T_out = ceil(T * out_fps / states_fps)`` (``T`` without resampling).

    Raises
    ------
    ValueError
        Bad shapes, indices out of range, an empty sequence, a covariance that is not positive
        definite.
    RuntimeError
        The normal equations are numerically singular (the message gives the condition estimate).

    Notes
    -----
    With full covariance the solve stores one packed D x D factor per frame (about 10 KB at
    D = 50); the calling thread keeps that store, up to 256 MB, for its next solve.
    """
    scale, fps_in, fps_out = _rates(model_fps, states_fps, out_fps)
    model = make_model(means, vel_means, covars, covariance_type, scale)
    s = _check_states(states, model.n_states)
    if fps_in is not None and fps_in != fps_out:
        s = _core.resample_states(s, fps_in, fps_out)
    return _core.solve_trajectory(model, s, *_evidence(evidence_targets, evidence_precision))


def solve_trajectory_weighted(weights, means, vel_means, covars, *, covariance_type: str = "full",
                              model_fps: float | None = None, states_fps: float | None = None,
                              out_fps: float | None = None, evidence_targets=None,
                              evidence_precision=None) -> np.ndarray:
    """Posterior-weighted trajectory: the "weighted combination of all sequences" (§5).

    Minimises the expected cost ``sum_t sum_n weights[t, n] * cost_t(n)``: each frame's
    precision blocks and precision-weighted means are the weighted sums over states.

    Parameters
    ----------
    weights : array_like, shape (T, N)
        Non-negative state weights per frame (e.g. forward-backward posteriors); each row needs
        a positive sum and need not be normalised. One-hot rows give :func:`solve_trajectory`.
    means, vel_means, covars, covariance_type, model_fps, states_fps, out_fps
        As in :func:`solve_trajectory`; weights are resampled by linear interpolation
        (:func:`resample_weights`).
    evidence_targets, evidence_precision : array_like, optional
        As in :func:`solve_trajectory`.

    Returns
    -------
    ndarray, shape (T_out, D)
        ``T_out = ceil(T * out_fps / states_fps)`` (``T`` without resampling).

    Raises
    ------
    ValueError
        Bad shapes, negative or non-finite weights, a row summing to zero, a covariance that
        is not positive definite.
    RuntimeError
        The normal equations are numerically singular.
    """
    scale, fps_in, fps_out = _rates(model_fps, states_fps, out_fps)
    model = make_model(means, vel_means, covars, covariance_type, scale)
    w = _check_weights(weights, model.n_states)
    if fps_in is not None and fps_in != fps_out:
        w = _core.resample_weights(w, fps_in, fps_out)
    return _core.solve_trajectory_weighted(model, w, *_evidence(evidence_targets, evidence_precision))


def resample_states(states, fps_in: float, fps_out: float) -> np.ndarray:
    """Sample-and-hold resampling of a state sequence.

    Output frame ``k`` (time ``k / fps_out``) takes the state of input frame
    ``floor(k * fps_in / fps_out)``; there are ``ceil(T * fps_out / fps_in)`` output frames.

    Parameters
    ----------
    states : array_like of int, shape (T,)
        State index per input frame (>= 0).
    fps_in, fps_out : float
        Input and output frame rates.

    Returns
    -------
    ndarray of int64, shape (T_out,)
        State index per output frame.

    Raises
    ------
    ValueError
        ``states`` not a non-empty 1-D sequence of non-negative integers, or a rate that is
        not positive and finite.
    """
    s = _check_states(states, np.iinfo(np.int64).max)
    return _core.resample_states(s, _check_rate(fps_in, "fps_in"), _check_rate(fps_out, "fps_out"))


def resample_weights(weights, fps_in: float, fps_out: float) -> np.ndarray:
    """Linear-interpolation resampling of per-frame state weights.

    Output frame ``k`` interpolates the input rows at ``u = k * fps_in / fps_out`` (clamped to
    the last frame); row sums are preserved.

    Parameters
    ----------
    weights : array_like, shape (T, N)
        Non-negative state weights per input frame, each row with a positive sum.
    fps_in, fps_out : float
        Input and output frame rates.

    Returns
    -------
    ndarray, shape (T_out, N)
        State weights per output frame.

    Raises
    ------
    ValueError
        ``weights`` not 2-D with at least one frame, negative or non-finite weights, a row
        summing to zero, or a rate that is not positive and finite.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 2:
        raise ValueError(f"weights must be 2-D (frames, states), got shape {w.shape}")
    w = _check_weights(w, w.shape[1])
    return _core.resample_weights(w, _check_rate(fps_in, "fps_in"), _check_rate(fps_out, "fps_out"))


class FixedLagTrajectory:
    """Streaming synthesis: frame t is emitted once frame t + lag has been pushed.

    The emitted frame is the value at t of the exact solution of the system truncated to frames
    0 .. t + lag (a fixed-lag smoother); state is carried between calls in C++, so each push costs
    O(D^3 + lag D^2). :meth:`flush` ends the stream and emits the held-back frames from the full
    solve, so with ``lag >= T - 1`` the output equals :func:`solve_trajectory`. The deviation from
    the full solve as a function of ``lag`` is tabulated in ``docs/trajectory.md``.

    Parameters
    ----------
    means, vel_means, covars, covariance_type
        As in :func:`make_model`.
    lag : int
        Frames of look-ahead (>= 0). Latency is ``lag / out_fps`` seconds.
    velocity_scale : float
        ``model_fps / out_fps`` when the stream runs at another rate than the training video.
    evidence_precision : array_like, optional
        W ``(D, D)`` of per-frame evidence (as :func:`solve_trajectory`): every push then takes
        the frames' targets, and frame t emitted is the value at t of the exact guided solve of
        frames 0 .. t + lag; :meth:`flush` gives the batch guided solve.

    Raises
    ------
    ValueError
        ``lag`` not a whole number >= 0, or a model that :func:`make_model` rejects.
    """

    def __init__(self, means, vel_means, covars, lag: int, *, covariance_type: str = "full",
                 velocity_scale: float = 1.0, evidence_precision=None):
        if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 0:
            raise ValueError(f"lag must be a non-negative integer number of frames, got {lag!r}")
        self._model = make_model(means, vel_means, covars, covariance_type, velocity_scale)
        if evidence_precision is None:
            self._stream = _core.FixedLagTrajectory(self._model, int(lag))
        else:
            self._stream = _core.FixedLagTrajectory(self._model, int(lag),
                                                    _evidence(None, evidence_precision)[1])

    @property
    def lag(self) -> int:
        """Frames of look-ahead."""
        return self._stream.lag

    @property
    def frames_pushed(self) -> int:
        """Frames pushed since the stream (re)started."""
        return self._stream.frames_pushed

    @property
    def frames_emitted(self) -> int:
        """Frames emitted since the stream (re)started."""
        return self._stream.frames_emitted

    @property
    def has_evidence(self) -> bool:
        """Whether pushes carry evidence targets (constructed with ``evidence_precision``)."""
        return self._stream.has_evidence

    def push_states(self, states, targets=None) -> np.ndarray:
        """Push state indices (shape (K,)) and, for a stream with evidence, their targets (K, D);
        returns the frames emitted, shape (K', D).

        Parameters
        ----------
        states : array_like of int, shape (K,) or scalar
            State index per new frame.
        targets : array_like, shape (K, D), optional
            Evidence targets of the new frames (for a stream built with
            ``evidence_precision``).

        Returns
        -------
        ndarray, shape (K', D)
            The frames emitted by this push, in order.

        Raises
        ------
        ValueError
            States that are not integers in range.
        """
        arr = _check_states(np.atleast_1d(np.asarray(states)), self._model.n_states)
        if targets is None:
            return self._stream.push_states(arr)
        return self._stream.push_states(arr, np.atleast_2d(_evidence(targets, None)[0]))

    def push_weights(self, weights, targets=None) -> np.ndarray:
        """Push state weights (shape (K, N), or (N,) for one frame) and, for a stream with
        evidence, their targets (K, D); returns the frames emitted.

        Parameters
        ----------
        weights : array_like, shape (K, N) or (N,)
            Non-negative state weights per new frame, each row with a positive sum.
        targets : array_like, shape (K, D), optional
            Evidence targets of the new frames (for a stream built with
            ``evidence_precision``).

        Returns
        -------
        ndarray, shape (K', D)
            The frames emitted by this push, in order.

        Raises
        ------
        ValueError
            Weights not of shape (K, N), negative or non-finite, or a row summing to zero.
        """
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim == 1:
            w = w[None, :]
        w = _check_weights(w, self._model.n_states)
        if targets is None:
            return self._stream.push_weights(w)
        return self._stream.push_weights(w, np.atleast_2d(_evidence(targets, None)[0]))

    def flush(self) -> np.ndarray:
        """Emit the held-back frames and reset the stream for a new utterance.

        Returns
        -------
        ndarray, shape (K, D)
            The frames not yet emitted, from the full solve.
        """
        return self._stream.flush()



#: The most :func:`widen_motion` widens a coordinate's motion (a factor on its deviations).
MAX_MOTION_GAIN = 3.0


def widen_motion(Y, gain) -> np.ndarray:
    """A trajectory's motion widened about its own mean, per coordinate.

    The most probable trajectory is an average of what the model thinks likely, so it moves less
    than real faces do (with a guide, it leans towards the ridge's prediction, itself shrunk
    towards the mean). Each coordinate's deviation from its mean over the trajectory is
    multiplied by its ``gain``: with the gains a puppet learns at training (how much less its
    animations of held-out training audio moved than the faces did), the animation moves as much
    as the training faces, as statistical speech synthesis restores the variance of its
    parameter trajectories (the variance-scaling post-filter, Silén et al., Interspeech 2012,
    after Toda & Tokuda's global variance).

    Parameters
    ----------
    Y : array_like, shape (T, D)
        The trajectory.
    gain : array_like, shape (D,)
        Factor per coordinate, in [1, :data:`MAX_MOTION_GAIN`].

    Returns
    -------
    ndarray, shape (T, D)
        The widened trajectory (``Y`` as float when it has no frame).

    Raises
    ------
    ValueError
        ``gain`` not of shape (D,) or outside [1, :data:`MAX_MOTION_GAIN`].
    """
    Y = np.asarray(Y, dtype=np.float64)
    g = np.asarray(gain, dtype=np.float64)
    if Y.ndim != 2 or g.shape != (Y.shape[1],):
        raise ValueError(f"gain must have one value per coordinate of Y {Y.shape}, got shape {g.shape}")
    if not (np.isfinite(g).all() and (g >= 1.0).all() and (g <= MAX_MOTION_GAIN).all()):
        raise ValueError(f"every gain must lie in [1, {MAX_MOTION_GAIN:g}]")
    if not len(Y):
        return Y
    mean = Y.mean(axis=0)
    return mean + (Y - mean) * g
