"""numpy's BLAS threads while voicepuppet computes (:func:`blas_threads`)."""

from __future__ import annotations

import contextlib
import functools
import os


def blas_threads():
    """The BLAS thread limit the commands and the entry points of :func:`limited` run under:
    ``VOICEPUPPET_BLAS_THREADS`` (default 1).

    numpy's dense algebra here is small (a few hundred dimensions: the ridge baseline's normal
    equations, PCA of the face coordinates, the remapping's scatter matrices), and OpenBLAS's
    worker threads spin for each call: on a 2-core machine under load one ``evaluate`` took 27 s
    with two BLAS threads and 7.5 s with one (docs/benchmarks.md, "BLAS threads"). The C++
    kernels' OpenMP threads are not affected. With ``OPENBLAS_NUM_THREADS`` or
    ``MKL_NUM_THREADS`` set and ``VOICEPUPPET_BLAS_THREADS`` not, BLAS is left as the user set it.
    Returns a context manager.

    Returns
    -------
    contextlib.AbstractContextManager
        ``threadpoolctl.threadpool_limits`` on the BLAS libraries, or a no-op context when the
        user set OpenBLAS's or MKL's own variable.

    Raises
    ------
    ValueError
        ``VOICEPUPPET_BLAS_THREADS`` is not a whole number >= 1.
    """
    value = os.environ.get("VOICEPUPPET_BLAS_THREADS")
    if value is None and ("OPENBLAS_NUM_THREADS" in os.environ or "MKL_NUM_THREADS" in os.environ):
        return contextlib.nullcontext()
    try:
        n = 1 if value is None else int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"VOICEPUPPET_BLAS_THREADS must be a whole number >= 1, got {value!r}; "
                         "unset it for the default (1)")
    # scipy's wheels carry their own OpenBLAS (the ridge's Cholesky solves run on it), and
    # threadpoolctl limits only the libraries loaded when the limit is set: load it first.
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=n, user_api="blas")


_depth = 0  # limited calls in progress: the outermost sets the limit (about 1 ms), inner ones keep it


def limited(fn):
    """Decorator: ``fn`` runs under :func:`blas_threads` (the public entry points whose numpy
    algebra is small and many: training, the ridge baseline, the evaluation harness), however it
    is called: from the commands, or from a user's Python. Inside another limited call (the
    ridge fits of training: 36 per puppet) the limit already holds and is not set again.

    Parameters
    ----------
    fn : callable
        The function to limit.

    Returns
    -------
    callable
        A wrapper of ``fn`` (same name and docstring, by :func:`functools.wraps`).
    """
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        global _depth
        if _depth:
            return fn(*args, **kwargs)
        _depth += 1
        try:
            with blas_threads():
                return fn(*args, **kwargs)
        finally:
            _depth -= 1

    return wrapper
