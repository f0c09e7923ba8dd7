"""The ``voicepuppet`` command line: one module per verb or family of verbs."""

from voicepuppet.cli.main import UserError, main

__all__ = ["UserError", "main"]
