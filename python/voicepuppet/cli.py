"""The ``voicepuppet`` command line.

Each verb lives next to the code it drives: a module exposing ``add_parser(subparsers)`` that
registers its sub-command and sets ``func`` (called with the parsed arguments, returning an
exit code). Only verbs that work are listed in ``VERB_MODULES``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
import warnings

# Order is the order shown in --help.
VERB_MODULES = [
    "voicepuppet.info",
    "voicepuppet.demo",
    "voicepuppet.tracking",
    "voicepuppet.puppet_cli",
    "voicepuppet.features_cli",
    "voicepuppet.render",
    "voicepuppet.export",
    "voicepuppet.batch",
    "voicepuppet.live",
    "voicepuppet.bench",
    "voicepuppet.evaluate",
    "voicepuppet.phonemes",
    "voicepuppet.dpds",
]


class UserError(Exception):
    """An error caused by the user's input: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    from voicepuppet import __version__

    parser = argparse.ArgumentParser(
        prog="voicepuppet",
        description="Voice-driven facial animation (Brand's Voice Puppetry).",
    )
    parser.add_argument("--version", action="version", version=f"voicepuppet {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    for name in VERB_MODULES:
        importlib.import_module(name).add_parser(sub)
    return parser


def blas_threads():
    """The BLAS thread limit the command runs under: ``VOICEPUPPET_BLAS_THREADS`` (default 1).

    numpy's dense algebra here is small (a few hundred dimensions: the ridge baseline's normal
    equations, PCA of the face coordinates, the remapping's scatter matrices), and OpenBLAS's
    worker threads spin for each call: on a 2-core machine under load one ``evaluate`` took 27 s
    with two BLAS threads and 7.5 s with one (docs/benchmarks.md, "BLAS threads"). The C++
    kernels' OpenMP threads are not affected. With ``OPENBLAS_NUM_THREADS`` or
    ``MKL_NUM_THREADS`` set and ``VOICEPUPPET_BLAS_THREADS`` not, BLAS is left as the user set it.
    Returns a context manager.
    """
    value = os.environ.get("VOICEPUPPET_BLAS_THREADS")
    if value is None and ("OPENBLAS_NUM_THREADS" in os.environ or "MKL_NUM_THREADS" in os.environ):
        return contextlib.nullcontext()
    try:
        n = 1 if value is None else int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise UserError(f"VOICEPUPPET_BLAS_THREADS must be a whole number >= 1, got {value!r}; "
                        "unset it for the default (1)")
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=n, user_api="blas")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with blas_threads(), warnings.catch_warnings():
            # Warnings are news for the user (a dropped stretch of video, a fallback), not for a
            # developer: one line each, without the source line of the code that raised them.
            def show(message, category, filename, lineno, file=None, line=None):
                print(f"voicepuppet {args.verb}: warning: {message}", file=sys.stderr)

            warnings.showwarning = show
            return int(args.func(args) or 0)
    except (UserError, ValueError, FileNotFoundError) as exc:
        print(f"voicepuppet {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"voicepuppet {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
