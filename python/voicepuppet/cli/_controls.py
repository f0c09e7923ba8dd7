"""The animator's controls on the command line (Brand §6), shared by ``render`` and ``export``:
package-private to :mod:`voicepuppet.cli`.

:func:`add_control_arguments` adds ``--exaggerate``, ``--expression``, ``--expression-time`` and
``--fade``; :func:`apply_control_arguments` unpacks them into
:func:`voicepuppet.animation.apply_controls`.
"""

from __future__ import annotations

import argparse

from voicepuppet.animation import Animation, apply_controls
from voicepuppet.render import ACTION_UNITS, expression_offset


def add_control_arguments(p: argparse.ArgumentParser) -> None:
    """Adds ``--exaggerate``, ``--expression``, ``--expression-time``, ``--fade`` (Brand §6).

    Parameters
    ----------
    p : argparse.ArgumentParser
        a verb's parser.
    """
    p.add_argument("--exaggerate", type=float, help="scale deviations from the mean shape (1: as is)")
    p.add_argument("--expression", help=f"whole-face offset, e.g. smile_left=1,smile_right=1 (units: "
                                        f"{', '.join(ACTION_UNITS)})")
    p.add_argument("--expression-time", help="START:END seconds of the expression (default: all)")
    p.add_argument("--fade", type=float, default=0.0, help="seconds of ramp at each end of the expression")


def _expression_time(text: str | None) -> tuple[float, float | None]:
    """(start, end) seconds of ``--expression-time START:END`` (either may be left out)."""
    start, end = 0.0, None
    if text:
        a, _, b = text.partition(":")
        try:
            start = float(a) if a else 0.0
            end = float(b) if b else None
        except ValueError:
            raise ValueError(f"--expression-time must be START:END in seconds, got {text!r}") from None
    return start, end


def apply_control_arguments(anim: Animation, args: argparse.Namespace) -> Animation:
    """The controls of :func:`add_control_arguments` applied to ``anim``: ``--exaggerate``, then
    ``--expression`` (made on the exaggerated rest face) over ``--expression-time`` with ``--fade``.

    Parameters
    ----------
    anim : Animation
        the animation as loaded.
    args : argparse.Namespace
        the parsed command line.

    Returns
    -------
    Animation
        with ``neutral`` set (:func:`voicepuppet.animation.apply_controls`).

    Raises
    ------
    ValueError
        a bad ``--exaggerate``, ``--expression`` or ``--expression-time``.
    """
    anim = apply_controls(anim, exaggeration=getattr(args, "exaggerate", None))
    if getattr(args, "expression", None):
        start, end = _expression_time(args.expression_time)
        anim = apply_controls(anim, offset=expression_offset(anim.rest, args.expression), start=start, end=end,
                              fade=args.fade)
    return anim
