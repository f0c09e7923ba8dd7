"""HMM training on a Dask cluster: E-step statistics per sequence on the workers, M-step here.

Baum-Welch and entropic training (:class:`voicepuppet.hmm.gaussian.GaussianHMM` or
``"entropic"``) spend their time in the E-step: log densities, forward-backward and the
γ-weighted Gaussian statistics, all additive over sequences. :class:`DaskEStep` holds the
training sequences on the workers in chunks of whole sequences, computes those statistics (and
the per-sequence log-likelihoods that entropic trimming tests) chunk by chunk on the workers,
and adds them up here in chunk order, so the result does not depend on how many workers there
are or which one ran what. Initialisation, trimming decisions and the M-step stay in this
process; the parameters equal single-process training to rounding (tested to 1e-10).

A lost worker costs nothing but time: each chunk of data is the result of a task whose input
the scheduler keeps, so Dask rebuilds it on another worker and re-runs the E-step tasks.

Usage::

    from voicepuppet.hmm.distributed import connect, fit
    with connect(workers=2) as client:          # or connect("tcp://10.0.0.5:8786")
        fit(EntropicHMM(40, n_iter=30), X, lengths, client=client)

See docs/batch.md for starting a cluster.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from typing import Iterator

import numpy as np

from voicepuppet import _core
from voicepuppet.hmm.gaussian import aligned, check_sequences

__all__ = ["connect", "DaskEStep", "DaskEvaluation", "fit", "chunk_bounds", "DEFAULT_CHUNK_FRAMES"]

#: default size of a chunk of training data (whole sequences, at least one per chunk)
DEFAULT_CHUNK_FRAMES = 4096


def _require_dask():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise ValueError("distributed work needs Dask: pip install 'dask[distributed]'") from None


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, *, timeout: float = 10.0,
            threads_per_worker: int = 1) -> Iterator["distributed.Client"]:  # noqa: F821
    """A Dask client: to the scheduler at ``scheduler`` or to a new local cluster.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler, e.g. ``tcp://127.0.0.1:8786``. ``None``: start a
        ``LocalCluster`` of ``workers`` processes for the duration of the ``with`` block.
    workers : int, optional
        Worker processes of the local cluster (default: the number of CPUs). With a
        ``scheduler``, wait up to ``timeout`` seconds for that many workers to join.
    timeout : float
        Seconds to wait for the scheduler (and workers) before giving up with ``ValueError``
        (default 10).
    threads_per_worker : int
        Threads per local worker process (default 1: the kernels release the GIL; 1 keeps runs
        predictable). Each local worker's C++ kernels get
        ``cpus // (workers * threads_per_worker)`` OpenMP threads (at least 1).

    Yields
    ------
    distributed.Client
        The connected client, closed (with its local cluster, if one was started) when the
        ``with`` block ends.

    Raises
    ------
    ValueError
        Dask missing, ``workers`` not a positive integer, ``timeout`` not positive, a malformed
        address, an unreachable scheduler, or too few workers in time.
    """
    _require_dask()
    from distributed import Client, LocalCluster

    if workers is not None and (int(workers) != workers or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if not (timeout > 0):
        raise ValueError(f"timeout must be > 0 seconds, got {timeout!r}")
    if scheduler is None:
        n = int(workers) if workers is not None else (os.cpu_count() or 1)
        with warnings.catch_warnings():
            # Dask's start-up notes (e.g. about the scratch folder) are not errors of ours.
            warnings.simplefilter("ignore")
            # Dask starts workers with OMP_NUM_THREADS=1; the C++ kernels may use the cores the
            # workers leave free (2 CPUs, 1 worker: 2 OpenMP threads in it).
            omp = max(1, (os.cpu_count() or 1) // (n * threads_per_worker))
            cluster = LocalCluster(n_workers=n, threads_per_worker=threads_per_worker, processes=True,
                                   dashboard_address=None, silence_logs=logging.ERROR,
                                   env={"OMP_NUM_THREADS": str(omp)})
        try:
            with Client(cluster, timeout=timeout) as client:
                yield client
        finally:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cluster.close()
        return
    address = str(scheduler)
    if "://" not in address:
        if ":" not in address:
            raise ValueError(f"scheduler address {address!r} needs a port, e.g. tcp://127.0.0.1:8786")
        address = f"tcp://{address}"
    try:
        client = Client(address, timeout=timeout)
    except (OSError, TimeoutError) as exc:
        raise ValueError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s ({exc}); "
                         "start one with `dask scheduler` and `dask worker ADDRESS` (docs/batch.md), or "
                         "leave out --scheduler to use a local cluster") from None
    try:
        if workers is not None:
            try:
                client.wait_for_workers(int(workers), timeout=timeout)
            except (OSError, TimeoutError):
                have = len(client.nthreads())
                raise ValueError(f"the scheduler at {address} has {have} workers, fewer than the "
                                 f"{int(workers)} asked for, after {timeout:g} s; start more with "
                                 "`dask worker ADDRESS` or ask for fewer") from None
        elif not client.nthreads():
            try:
                client.wait_for_workers(1, timeout=timeout)
            except (OSError, TimeoutError):
                raise ValueError(f"the scheduler at {address} has no workers after {timeout:g} s; "
                                 "start some with `dask worker ADDRESS`") from None
        yield client
    finally:
        client.close()


def chunk_bounds(lengths, chunk_frames: int = DEFAULT_CHUNK_FRAMES) -> list[tuple[int, int]]:
    """Groups consecutive sequences into chunks of at most ``chunk_frames`` frames (a longer
    sequence is a chunk of its own). The grouping depends only on the data, never on the cluster.

    Parameters
    ----------
    lengths : array_like of int, shape (S,)
        Frames per sequence.
    chunk_frames : int
        Most frames in a chunk of several sequences (default :data:`DEFAULT_CHUNK_FRAMES`).

    Returns
    -------
    list of (int, int)
        ``(first, stop)`` sequence indices per chunk, in order, covering all sequences.

    Raises
    ------
    ValueError
        ``chunk_frames`` not a positive integer.
    """
    if int(chunk_frames) != chunk_frames or chunk_frames < 1:
        raise ValueError(f"chunk_frames must be a positive integer, got {chunk_frames!r}")
    bounds, first, frames = [], 0, 0
    for s, n in enumerate(np.asarray(lengths, dtype=np.int64)):
        if s > first and frames + int(n) > chunk_frames:
            bounds.append((first, s))
            first, frames = s, 0
        frames += int(n)
    bounds.append((first, len(lengths)))
    return bounds


# ----------------------------------------------------------------------------- worker side
# Module-level functions: the workers import them from voicepuppet.hmm.distributed.

def _aligned(a) -> np.ndarray:
    """Deserialised buffers (and small numpy arrays) sit at varying addresses; see
    :func:`voicepuppet.hmm.gaussian.aligned`, which every E-step and M-step input goes through."""
    return aligned(a)


def _hold(X: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _aligned(X), np.array(lengths, dtype=np.int64, copy=True)


def _unpack(chunk):
    """The chunk's arrays, copied when they arrived from another worker unaligned (see _hold)."""
    X, lengths = chunk
    return (X if X.ctypes.data % 64 == 0 else _aligned(X)), np.array(lengths, dtype=np.int64, copy=True)


def _fresh(d: dict) -> dict:
    """Copies of the arrays in ``d`` (aligned like any new numpy array; see _hold)."""
    return {k: _aligned(v) if isinstance(v, np.ndarray) else v for k, v in d.items()}


def _densities(X, gaussians) -> np.ndarray:
    return _core.gaussian_log_density(X, gaussians["means"], gaussians["covars"], gaussians["covariance"])


def _per_sequence_log_likelihood(log_b, params, lengths) -> list[float]:
    out, a = [], 0
    for n in lengths:
        b = a + int(n)
        out.append(float(_core.log_likelihood(np.ascontiguousarray(log_b[a:b]), params["startprob"],
                                              params["transmat"], np.array([n], dtype=np.int64))))
        a = b
    return out


def _chunk_stats(chunk, params: dict, shift: np.ndarray) -> dict:
    """Baum-Welch statistics of one chunk (the C++ E-step of GaussianHMM.estep)."""
    X, lengths = _unpack(chunk)
    params, shift = _fresh(params), _aligned(shift)
    return _core.gaussian_hmm_estep(X, lengths, params["startprob"], params["transmat"], params["means"],
                                    params["covars"], params["covariance"], shift)


def _chunk_log_likelihood(chunk, params: dict, gaussians: dict) -> list[float]:
    X, lengths = _unpack(chunk)
    params, gaussians = _fresh(params), _fresh(gaussians)
    return _per_sequence_log_likelihood(_densities(X, gaussians), params, lengths)


def _chunk_evaluate(chunk, params: dict, gaussians: dict, shift: np.ndarray) -> dict:
    """Forward-backward on one chunk and everything entropic training needs from it."""
    X, lengths = _unpack(chunk)
    params, gaussians, shift = _fresh(params), _fresh(gaussians), _aligned(shift)
    log_b = _densities(X, gaussians)
    _, post, xi, starts, seq_ll = _core.forward_backward(log_b, params["startprob"], params["transmat"],
                                                          lengths)
    weight, ssum, outer = _core.gaussian_stats(X, post, shift, gaussians["covariance"])
    n = log_b.shape[1]
    if n >= 2:
        top2 = np.partition(log_b, n - 2, axis=1)[:, n - 2:]
        second, first = top2[:, 0], top2[:, 1]
        runner_up = np.where(log_b >= first[:, None], second[:, None], first[:, None])
        exclusive = (post * np.maximum(0.0, log_b - runner_up)).sum(axis=0)
    else:
        exclusive = np.zeros(n)
    return {"log_likelihoods": [float(v) for v in seq_ll],
            "expected_transitions": xi, "expected_starts": starts, "weight": weight, "sum": ssum,
            "outer": outer, "exclusive_evidence": exclusive, "heir_fit": post.T @ log_b}


# ----------------------------------------------------------------------------- client side

def _add(parts: list[dict], keys) -> dict:
    """Sums the arrays under ``keys`` over ``parts`` in list order (a fixed order)."""
    out = {}
    for k in keys:
        acc = _aligned(parts[0][k])
        for p in parts[1:]:
            acc += p[k]
        out[k] = acc
    return out


def _total(values) -> float:
    total = 0.0
    for v in values:
        total += v
    return total


class DaskEvaluation:
    """Forward-backward results of one model over all chunks, reduced in chunk order (the
    distributed counterpart of :class:`voicepuppet.hmm.entropic.LocalEvaluation`).

    Parameters
    ----------
    parts : list of dict
        One result per chunk, in chunk order, as the workers compute them: per-sequence
        ``log_likelihoods`` and the chunk's sums (``expected_transitions``, ``expected_starts``,
        ``weight``, ``sum``, ``outer``, ``exclusive_evidence``, ``heir_fit``).

    Attributes
    ----------
    log_likelihood : float
        log p(X), summed over the sequences in order.
    expected_transitions : ndarray, shape (N, N)
        ξ summed over frames and sequences.
    expected_starts : ndarray, shape (N,)
        The state posteriors of the sequences' first frames, summed.
    """

    def __init__(self, parts: list[dict]):
        self.log_likelihood = _total(ll for p in parts for ll in p["log_likelihoods"])
        sums = _add(parts, ("expected_transitions", "expected_starts", "weight", "sum", "outer",
                            "exclusive_evidence", "heir_fit"))
        self.expected_transitions = sums["expected_transitions"]
        self.expected_starts = sums["expected_starts"]
        self._stats = (sums["weight"], sums["sum"], sums["outer"])
        self._exclusive = sums["exclusive_evidence"]
        fit = sums["heir_fit"]
        np.fill_diagonal(fit, -np.inf)
        self._heirs = np.argmax(fit, axis=1)

    def exclusive_evidence(self) -> np.ndarray:
        """Evidence only state i explains, shape (N,) (see LocalEvaluation).

        Returns
        -------
        ndarray, shape (N,)
            A copy of the summed exclusive evidence of each state.
        """
        return self._exclusive.copy()

    def heirs(self) -> np.ndarray:
        """For each state i, the other state that best explains i's frames.

        Returns
        -------
        ndarray of int, shape (N,)
            argmax_j≠i Σ_t γ_ti log b_j(x_t) for each state i.
        """
        return self._heirs

    def gaussian_stats(self):
        """γ-weighted Gaussian statistics about the data's shift.

        Returns
        -------
        tuple of ndarray
            ``(weight [N], sum [N,D], outer)``, outer full [N*D,D] or diag [N,D], summed over
            the chunks.
        """
        return self._stats


class DaskEStep:
    """Training data on a Dask cluster, answering the E-step questions of
    :meth:`voicepuppet.hmm.gaussian.GaussianHMM.fit` (``estep=``) and
    :func:`voicepuppet.hmm.entropic.fit_entropic`.

    Parameters
    ----------
    client : distributed.Client
        The cluster to hold the data and run the E-steps on.
    X : array_like, shape (T, D)
        All training sequences stacked in time (the same array given to ``fit``).
    lengths : array_like of int, shape (S,), optional
        Frames per sequence; must sum to T. ``None`` (default): one sequence.
    covariance : {"full", "diag"}
        Covariance type of the model to train (default "full").
    chunk_frames : int
        Whole sequences are grouped into chunks of at most this many frames (default
        :data:`DEFAULT_CHUNK_FRAMES`); one task per chunk and E-step. The grouping depends on the
        data only, so results do not depend on the cluster.

    Attributes
    ----------
    client : distributed.Client
        The client given.
    covariance : str
        The covariance type given.
    n_frames, n_dims : int
        T and D of ``X``.
    shift : ndarray, shape (D,)
        The mean of all frames, about which the Gaussian statistics are taken.
    bounds : list of (int, int)
        The chunks, as :func:`chunk_bounds` gives them.

    Raises
    ------
    ValueError
        ``covariance`` not "full" or "diag", bad observations or lengths, or a bad ``chunk_frames``.

    Notes
    -----
    Use it as a context manager, or call :meth:`close`, to release the data on the cluster.
    """

    def __init__(self, client, X, lengths=None, covariance: str = "full",
                 chunk_frames: int = DEFAULT_CHUNK_FRAMES):
        if covariance not in ("full", "diag"):
            raise ValueError(f"covariance must be 'full' or 'diag', got {covariance!r}")
        X, lengths = check_sequences(X, lengths)
        self.client, self.covariance = client, covariance
        self.n_frames, self.n_dims = X.shape
        self.shift = X.mean(axis=0)  # as fit_entropic computes it (checked there)
        self.bounds = chunk_bounds(lengths, chunk_frames)
        starts = np.concatenate([[0], np.cumsum(lengths)])
        self._chunks = []
        with warnings.catch_warnings():
            # The data goes into the task graph on purpose: the scheduler keeps it, so a chunk
            # held by a worker that dies is rebuilt on another (scattered data would be lost).
            warnings.filterwarnings("ignore", message=".*Large object.*")
            for first, stop in self.bounds:
                Xc = np.ascontiguousarray(X[starts[first]:starts[stop]])
                Lc = np.ascontiguousarray(lengths[first:stop])
                self._chunks.append(client.submit(_hold, Xc, Lc, pure=False))

    def close(self) -> None:
        """Releases the data held on the cluster."""
        for f in self._chunks:
            f.release()
        self._chunks = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _map(self, fn, *args) -> list:
        if not self._chunks:
            raise ValueError("this DaskEStep is closed; make a new one")
        futures = [self.client.submit(fn, c, *args, pure=False) for c in self._chunks]
        try:
            return self.client.gather(futures)  # in chunk order
        finally:
            for f in futures:
                f.release()

    def _check(self, params: dict) -> None:
        means = np.asarray(params["means"])
        if means.ndim != 2 or means.shape[1] != self.n_dims:
            raise ValueError(f"means must have shape (N, {self.n_dims}) to match the data, got {means.shape}")

    # Baum-Welch ----------------------------------------------------------------------
    def stats(self, params: dict, shift) -> dict:
        """E-step statistics of all sequences (the keys of GaussianHMM.estep), summed in chunk order.

        Parameters
        ----------
        params : dict
            Model parameters as :meth:`voicepuppet.hmm.gaussian.GaussianHMM.parameters` gives them.
        shift : array_like, shape (D,)
            Point the moments are taken about.

        Returns
        -------
        dict
            ``log_likelihood``, ``expected_transitions``, ``expected_starts``, ``weight``,
            ``sum``, ``outer`` (as :meth:`voicepuppet.hmm.gaussian.GaussianHMM.estep` gives them)
            and ``shift``.

        Raises
        ------
        ValueError
            ``means`` of another dimension than the data, or the data already released (:meth:`close`).
        """
        self._check(params)
        shift = np.ascontiguousarray(shift, dtype=np.float64)
        parts = self._map(_chunk_stats, params, shift)
        out = _add(parts, ("expected_transitions", "expected_starts", "weight", "sum", "outer"))
        out["log_likelihood"] = _total(p["log_likelihood"] for p in parts)
        out["shift"] = _aligned(shift)
        return out

    # entropic training (the protocol of voicepuppet.hmm.entropic.LocalData) -----------------
    def densities(self, params: dict) -> dict:
        """A handle standing for the log densities of the Gaussians in ``params`` (computed on
        the workers when needed).

        Parameters
        ----------
        params : dict
            Model parameters (``means``, ``covars`` and ``covariance`` are used).

        Returns
        -------
        dict
            The Gaussians (``means``, ``covars``, ``covariance``): the handle.

        Raises
        ------
        ValueError
            ``means`` of another dimension than the data.
        """
        self._check(params)
        return {"means": np.ascontiguousarray(params["means"]),
                "covars": np.ascontiguousarray(params["covars"]), "covariance": params["covariance"]}

    def drop_state(self, gaussians: dict, i: int) -> dict:
        """The handle without state ``i``.

        Parameters
        ----------
        gaussians : dict
            A handle from :meth:`densities` (or from this method).
        i : int
            The state to leave out.

        Returns
        -------
        dict
            The handle of the Gaussians without state ``i``.
        """
        n, d = gaussians["means"].shape
        covars = gaussians["covars"]
        if gaussians["covariance"] == "full":
            covars = np.delete(covars.reshape(n, d, d), i, axis=0).reshape(-1, d)
        else:
            covars = np.delete(covars, i, axis=0)
        return {"means": np.ascontiguousarray(np.delete(gaussians["means"], i, axis=0)),
                "covars": np.ascontiguousarray(covars), "covariance": gaussians["covariance"]}

    def log_likelihood(self, params: dict, gaussians: dict) -> float:
        """Σ over sequences (in order) of the per-sequence forward log-likelihoods.

        Parameters
        ----------
        params : dict
            Model parameters (``startprob`` and ``transmat`` are used).
        gaussians : dict
            A handle from :meth:`densities` or :meth:`drop_state`.

        Returns
        -------
        float
            The log-likelihood of all sequences.
        """
        parts = self._map(_chunk_log_likelihood, params, gaussians)
        return _total(ll for p in parts for ll in p)

    def evaluate(self, params: dict, gaussians: dict) -> DaskEvaluation:
        """Forward-backward on every chunk (Gaussian statistics about ``shift``), reduced in
        chunk order.

        Parameters
        ----------
        params : dict
            Model parameters (``startprob`` and ``transmat`` are used).
        gaussians : dict
            A handle from :meth:`densities` or :meth:`drop_state`.

        Returns
        -------
        DaskEvaluation
            The log-likelihood, expected counts and what trimming and the M-step need.
        """
        return DaskEvaluation(self._map(_chunk_evaluate, params, gaussians, self.shift))


def fit(model, X, lengths=None, *, client=None, scheduler: str | None = None, workers: int | None = None,
        chunk_frames: int = DEFAULT_CHUNK_FRAMES, timeout: float = 10.0):
    """Fits ``model`` (a :class:`voicepuppet.hmm.gaussian.GaussianHMM`) with its E-steps on a Dask cluster.

    Parameters
    ----------
    model : GaussianHMM
        Baum-Welch (:class:`~voicepuppet.hmm.gaussian.GaussianHMM`) or entropic
        (:class:`~voicepuppet.hmm.entropic.EntropicHMM`).
    X : array_like, shape (T, D)
        Training observations of all sequences, stacked in time.
    lengths : array_like of int, shape (S,), optional
        Frames per sequence; must sum to T. ``None`` (default): one sequence.
    client : distributed.Client, optional
        An existing client; otherwise one is made by :func:`connect` (``scheduler``, ``workers``,
        ``timeout``) for this call.
    scheduler : str, optional
        Without ``client``: address of a running scheduler; ``None`` (default): a local cluster.
    workers : int, optional
        Without ``client``: worker processes of the local cluster, or how many to wait for at
        ``scheduler`` (see :func:`connect`).
    timeout : float
        Without ``client``: seconds to wait for the scheduler and workers (default 10).
    chunk_frames : int
        See :class:`DaskEStep` (default :data:`DEFAULT_CHUNK_FRAMES`).

    Returns
    -------
    model
        Fitted; its parameters equal ``model.fit(X, lengths)`` in one process up to rounding.
    """
    if client is None:
        with connect(scheduler, workers, timeout=timeout) as c:
            return fit(model, X, lengths, client=c, chunk_frames=chunk_frames)
    with DaskEStep(client, X, lengths, model.covariance, chunk_frames) as estep:
        return model.fit(X, lengths, estep=estep)
