"""The package's version: the installed distribution's, or the source tree's."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("voicepuppet")
except PackageNotFoundError:  # running from a source tree (PYTHONPATH=python)
    __version__ = "0.1.0"

__all__ = ["__version__"]
