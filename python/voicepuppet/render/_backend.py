"""The pyvista backend: its import and headless set-up, package-private to :mod:`voicepuppet.render`.

pyvista (and VTK under it) is an optional, heavy dependency: it is imported here, when a mesh
is first drawn, read or written, never at import time. Rendering is off screen through headless
EGL with Mesa (``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``, set unless already set).
Only the modules of :mod:`voicepuppet.render` use this module.
"""

from __future__ import annotations

import os


def import_pyvista():
    """The ``pyvista`` module, imported on first use, with VTK set to render off screen.

    Returns
    -------
    module
        ``pyvista``.

    Raises
    ------
    ValueError
        pyvista is not installed (the message says how to install it, or to draw landmarks in 2-D).
    """
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        import pyvista
    except ImportError:
        raise ValueError("mesh rendering needs pyvista: pip install pyvista (and Mesa's EGL: "
                         "apt-get install libegl1 libgl1-mesa-dri), or use renderer='2d'") from None
    return pyvista
