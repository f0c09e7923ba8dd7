"""The ``voicepuppet`` command line.

Each verb lives next to the code it drives: a module exposing ``add_parser(subparsers)`` that
registers its sub-command and sets ``func`` (called with the parsed arguments, returning an
exit code). Only verbs that work are listed in ``VERB_MODULES``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from voicepuppet.blas import blas_threads

# Order is the order shown in --help.
VERB_MODULES = [
    "voicepuppet.cli.info",
    "voicepuppet.cli.demo",
    "voicepuppet.cli.track",
    "voicepuppet.cli.puppet",
    "voicepuppet.cli.features",
    "voicepuppet.cli.render",
    "voicepuppet.cli.export",
    "voicepuppet.cli.batch",
    "voicepuppet.cli.live",
    "voicepuppet.cli.bench",
    "voicepuppet.cli.evaluate",
    "voicepuppet.cli.align",
    "voicepuppet.cli.phoneme_puppet",
]


class UserError(Exception):
    """An error caused by the user's input: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    """The ``voicepuppet`` argument parser, with every verb of ``VERB_MODULES``.

    Returns
    -------
    argparse.ArgumentParser
        The parser; a parsed verb's ``func`` runs it.
    """
    from voicepuppet._version import __version__

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


def main(argv: list[str] | None = None) -> int:
    """Run the ``voicepuppet`` command line.

    Warnings are printed as one line each; a :class:`UserError`, ``ValueError`` or
    ``FileNotFoundError`` is printed as one line and gives exit code 2.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code: the verb's (0 for success), 2 for an error of the user's, 130 when
        interrupted.
    """
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
