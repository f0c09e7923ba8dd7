"""Hidden Markov models over face observations: the Gaussian HMM (:mod:`~voicepuppet.hmm.gaussian`),
its entropic MAP training (:mod:`~voicepuppet.hmm.entropic`, one-way: it uses the HMM, never the
reverse) and E-steps distributed over a Dask cluster (:mod:`~voicepuppet.hmm.distributed`)."""

from voicepuppet.hmm.entropic import EntropicHMM, fit_entropic
from voicepuppet.hmm.gaussian import GaussianHMM, aligned, check_sequences

__all__ = ["EntropicHMM", "GaussianHMM", "aligned", "check_sequences", "fit_entropic"]
