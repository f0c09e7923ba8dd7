"""voicepuppet: voice-driven facial animation (Brand, Voice Puppetry, SIGGRAPH 1999).

The compiled kernels live in the private module ``voicepuppet._core``; the public API is
spread over submodules named for what they hold (``hmm``, ``trajectory``, ``audio``, ...).
"""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("voicepuppet")
except PackageNotFoundError:  # running from a source tree (PYTHONPATH=python)
    __version__ = "0.1.0"

__all__ = ["__version__"]
