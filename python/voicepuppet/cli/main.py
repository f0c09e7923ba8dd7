"""The ``voicepuppet`` command line.

Each verb (or family of verbs) has its module in :mod:`voicepuppet.cli`, exposing
``add_parser(subparsers)`` that registers its sub-command and sets ``func`` (called with the
parsed arguments, returning an exit code); ``VERB_MODULES`` lists them. :func:`main` gives every
verb one way out: a user's error is one line and exit code 2, Ctrl-C and SIGTERM stop it cleanly,
and no output may overwrite an input.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
import traceback
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


#: Options that name what a verb writes; every other option or argument naming an existing file
#: is something it reads, which no output may overwrite.
OUTPUT_OPTIONS = ("output", "out", "json", "states_out", "overlay")


class Terminated(KeyboardInterrupt):
    """SIGTERM, turned into an interruption so that a verb stops as it does on Ctrl-C: its
    temporary files removed, nothing half-written left (exit code 143)."""


def _terminate(signum, frame):
    raise Terminated()


def refuse_overwriting_inputs(args) -> None:
    """Refuse a command whose output would overwrite one of its own inputs.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line.

    Raises
    ------
    UserError
        An option of :data:`OUTPUT_OPTIONS` names the same file as an input, naming both.
    """
    values = vars(args)
    inputs = [v for k, vals in values.items() if k not in OUTPUT_OPTIONS
              for v in (vals if isinstance(vals, list) else [vals]) if isinstance(v, str) and os.path.isfile(v)]
    for name in OUTPUT_OPTIONS:
        out = values.get(name)
        if not isinstance(out, str) or not os.path.exists(out):
            continue
        for src in inputs:
            if os.path.samefile(out, src):
                flag = "-o" if name == "output" else f"--{name.replace('_', '-')}"
                raise UserError(f"{flag} {out} is also what the command reads ({src}); write to another "
                                "file: voicepuppet never overwrites its input")


class UserError(Exception):
    """An error caused by the user's input: printed as one line, exit code 2."""


#: What a verb raises for a failure it expects: the input (``UserError``, ``ValueError``), the
#: file system (``OSError``: a missing file, a full disk, a name too long, no permission) or the
#: environment and numerics (``RuntimeError``: a missing tool, a numerical failure in the core).
EXPECTED_ERRORS = (UserError, ValueError, OSError, RuntimeError)

#: The kinds of ``RuntimeError`` that only a bug raises (runaway recursion, a code path called
#: before it was written): caught before :data:`EXPECTED_ERRORS`, reported as bugs.
BUG_ERRORS = (RecursionError, NotImplementedError)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _bug(verb: str) -> int:
    traceback.print_exc()
    print(f"voicepuppet {verb}: internal error: this is a bug in voicepuppet, not in your input; please "
          "report it with the command line, the traceback above and `voicepuppet --version`", file=sys.stderr)
    return 1


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

    Warnings are printed as one line each; an expected failure (:data:`EXPECTED_ERRORS`, or
    running out of memory) is printed as one line and gives exit code 2; anything else is a bug:
    its traceback, a line asking to report it, and exit code 1.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code: the verb's (0 for success), 2 for an expected failure, 1 for a bug, 130
        when interrupted, 143 when terminated (SIGTERM).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _terminate) if threading.current_thread() is threading.main_thread() else None
    try:
        refuse_overwriting_inputs(args)
        with blas_threads(), warnings.catch_warnings():
            # Warnings are news for the user (a dropped stretch of video, a fallback), not for a
            # developer: one line each, without the source line of the code that raised them.
            def show(message, category, filename, lineno, file=None, line=None):
                print(f"voicepuppet {args.verb}: warning: {message}", file=sys.stderr)

            warnings.showwarning = show
            return int(args.func(args) or 0)
    except BUG_ERRORS:
        return _bug(args.verb)
    except EXPECTED_ERRORS as exc:
        print(f"voicepuppet {args.verb}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"voicepuppet {args.verb}: error: not enough memory for this input; free memory, or split the "
              "input into shorter pieces", file=sys.stderr)
        return 2
    except Terminated:
        print(f"voicepuppet {args.verb}: terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print(f"voicepuppet {args.verb}: interrupted", file=sys.stderr)
        return 130
    except Exception:
        return _bug(args.verb)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
