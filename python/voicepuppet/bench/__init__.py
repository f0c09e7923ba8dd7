"""Benchmarks: our kernels side by side with a peer, one suite per module (``hmm``, ``audio``,
``tracker``, ``render``, ``trajectory``, ``entropic``, ``synth``, ``pipeline``, ``live``,
``dpds``, ``batch``), run by :mod:`.runner` (``voicepuppet bench SUITE --json FILE``)."""

from voicepuppet.bench.runner import (SUITES, case, machine_info, print_table, rel_diff, run_suite,
                                      timeit_interleaved, write_json_atomic)

__all__ = ["SUITES", "case", "machine_info", "print_table", "rel_diff", "run_suite", "timeit_interleaved",
           "write_json_atomic"]
