"""Distributed HMM training (voicepuppet.hmm.distributed): E-step statistics on Dask workers, M-step
here, parameters equal to single-process training (Baum-Welch and entropic, full and diagonal
covariances, with trimming), independent of the chunking of the data; clear errors for an
unreachable scheduler."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from voicepuppet.hmm.distributed import DaskEStep, chunk_bounds, connect, fit
from voicepuppet.hmm.entropic import EntropicHMM
from voicepuppet.hmm.gaussian import GaussianHMM

SEED = 20261123
PARAMS = ("startprob_", "transmat_", "means_", "covars_")


@pytest.fixture(scope="module")
def client():
    with connect(workers=2, timeout=60) as c:
        yield c


def planted(seed=SEED, n_seq=7, dims=3):
    """Sequences from a planted 4-state ring with well separated means (seed printed on failure)."""
    rng = np.random.default_rng(seed)
    means = rng.normal(scale=4.0, size=(4, dims))
    A = np.array([[.8, .2, 0, 0], [0, .8, .2, 0], [0, 0, .8, .2], [.2, 0, 0, .8]])
    seqs = []
    for s in range(n_seq):
        z, xs = int(rng.integers(4)), []
        for _ in range(30 + 11 * s):
            xs.append(means[z] + rng.normal(size=dims))
            z = int(rng.choice(4, p=A[z]))
        seqs.append(np.array(xs))
    return np.vstack(seqs), [len(s) for s in seqs]


def assert_same(a: GaussianHMM, b: GaussianHMM, tol=1e-10):
    assert a.n_states == b.n_states
    for name in PARAMS:
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=tol, err_msg=name)


def test_chunks_are_whole_sequences_in_order():
    assert chunk_bounds([5, 5, 5], 10) == [(0, 2), (2, 3)]
    assert chunk_bounds([50, 5, 5], 10) == [(0, 1), (1, 3)]
    assert chunk_bounds([3], 1) == [(0, 1)]
    with pytest.raises(ValueError, match="chunk_frames"):
        chunk_bounds([3], 0)


@pytest.mark.parametrize("covariance", ["full", "diag"])
def test_baum_welch_equals_single_process(client, covariance):
    X, lengths = planted()
    kw = dict(n_states=5, covariance=covariance, n_iter=12, tol=-np.inf, random_state=3)
    local = GaussianHMM(**kw).fit(X, lengths)
    dist = fit(GaussianHMM(**kw), X, lengths, client=client, chunk_frames=90)
    assert len(dist.history_) == len(local.history_) == 12
    assert_same(local, dist)
    np.testing.assert_allclose([h["log_likelihood"] for h in dist.history_],
                               [h["log_likelihood"] for h in local.history_], rtol=1e-12)


@pytest.mark.parametrize("covariance,z", [("full", 1.0), ("diag", 1.0), ("full", 2.0)])
def test_entropic_equals_single_process_with_trimming(client, covariance, z):
    X, lengths = planted(SEED + 1)
    kw = dict(n_states=9, covariance=covariance, n_iter=25, z=z, random_state=5)
    local = EntropicHMM(**kw).fit(X, lengths)
    dist = fit(EntropicHMM(**kw), X, lengths, client=client, chunk_frames=120)
    # the run exercised trimming (so the per-sequence trial log-likelihoods were used)
    assert sum(h["states_trimmed"] for h in local.history_) > 0
    assert sum(h["arcs_trimmed"] for h in local.history_) > 0
    assert [(h["states"], h["arcs"]) for h in dist.history_] == [(h["states"], h["arcs"]) for h in local.history_]
    assert_same(local, dist)
    np.testing.assert_allclose([h["log_posterior"] for h in dist.history_],
                               [h["log_posterior"] for h in local.history_], rtol=1e-12)


def test_result_does_not_depend_on_scheduling(client):
    """Reduction in chunk order: two runs (tasks finishing in whatever order) agree exactly."""
    X, lengths = planted(SEED + 2)
    kw = dict(n_states=4, covariance="full", n_iter=6, tol=-np.inf, random_state=1)
    a = fit(GaussianHMM(**kw), X, lengths, client=client, chunk_frames=40)
    b = fit(GaussianHMM(**kw), X, lengths, client=client, chunk_frames=40)
    assert_same(a, b, tol=0.0)


def test_estep_statistics_add_up_to_the_local_estep(client):
    X, lengths = planted(SEED + 3)
    m = GaussianHMM(4, n_iter=0, random_state=2).fit(X, lengths)  # initialised parameters only
    shift = X.mean(axis=0)
    want = m.estep(X, lengths, shift)
    with DaskEStep(client, X, lengths, "full", chunk_frames=50) as estep:
        assert len(estep.bounds) > 3
        got = estep.stats(m.parameters(), shift)
        ll = estep.log_likelihood(m.parameters(), estep.densities(m.parameters()))
    for k in ("expected_transitions", "expected_starts", "weight", "sum", "outer"):
        np.testing.assert_allclose(got[k], want[k], rtol=1e-12, atol=1e-9, err_msg=k)
    assert got["log_likelihood"] == pytest.approx(want["log_likelihood"], rel=1e-13)
    assert ll == pytest.approx(m.score(X, lengths), rel=1e-13)


def test_bad_input_is_refused_clearly(client):
    X, lengths = planted(SEED + 4)
    with pytest.raises(ValueError, match="lengths sum"):
        DaskEStep(client, X, [5, 5])
    with pytest.raises(ValueError, match="covariance"):
        DaskEStep(client, X, lengths, "spherical")
    with DaskEStep(client, X, lengths) as estep:
        with pytest.raises(ValueError, match="means must have shape"):
            estep.stats({"means": np.zeros((2, 7))}, X.mean(axis=0))
    with pytest.raises(ValueError, match="closed"):
        estep.stats(GaussianHMM(2, n_iter=0).fit(X, lengths).parameters(), X.mean(axis=0))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_is_a_clear_error_not_a_hang():
    address = f"tcp://127.0.0.1:{_free_port()}"  # nothing listens there
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match="cannot reach the Dask scheduler") as info:
        with connect(address, timeout=2):
            pass
    assert "dask scheduler" in str(info.value)
    assert time.perf_counter() - t0 < 60  # bounded by the timeout, not a hang
    with pytest.raises(ValueError, match="needs a port"):
        with connect("localhost"):
            pass
    with pytest.raises(ValueError, match="workers must be a positive integer"):
        with connect(workers=0):
            pass


def test_training_survives_a_killed_worker(client):
    """A worker process is SIGKILLed after the second E-step: the chunks it held are rebuilt from
    the task graph on the others and training ends with the single-process parameters."""
    import os
    import signal

    X, lengths = planted(SEED + 5)
    kw = dict(n_states=4, covariance="full", n_iter=6, tol=-np.inf, random_state=2)
    local = GaussianHMM(**kw).fit(X, lengths)
    pids_before = client.run(os.getpid)
    with DaskEStep(client, X, lengths, "full", chunk_frames=60) as estep:
        calls = [0]
        real_stats = estep.stats

        def stats_then_kill(params, shift):
            calls[0] += 1
            if calls[0] == 2:
                holders = client.who_has(estep._chunks)
                victim = next(iter(next(w for w in holders.values() if w)))
                os.kill(pids_before[victim], signal.SIGKILL)
            return real_stats(params, shift)

        estep.stats = stats_then_kill
        dist = GaussianHMM(**kw).fit(X, lengths, estep=estep)
    assert calls[0] == 6
    assert_same(local, dist)
    client.wait_for_workers(2, timeout=60)  # the nanny restarts the worker for the next tests
    assert set(client.run(os.getpid).values()) != set(pids_before.values())  # one really died
