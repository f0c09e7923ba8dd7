"""voicepuppet: voice-driven facial animation (Brand, Voice Puppetry, SIGGRAPH 1999).

The compiled kernels live in the private module ``voicepuppet._core``; the public API is
spread over subpackages in the order of the data flow (``tracking``, ``face``, ``audio``, ``hmm``,
``trajectory``, ``puppet``, ``animation``, ``render``, ``phonemes``, ``evaluation``, ``live``,
``batch``).
The puppet itself is here too (DESIGN.md, "Python API"): ``voicepuppet.Puppet.train(...)``,
``voicepuppet.load(path)``, ``puppet.animate(audio)``, ``puppet.save(path)``.
"""

from voicepuppet._version import __version__

__all__ = ["__version__", "Puppet", "load"]


def __getattr__(name):
    # imported on first use, so ``import voicepuppet`` (and the command line) stays light
    if name in ("Puppet", "load"):
        from voicepuppet.puppet import model as puppet

        return getattr(puppet, name)
    raise AttributeError(f"module 'voicepuppet' has no attribute {name!r}")
