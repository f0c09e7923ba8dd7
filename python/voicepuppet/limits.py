"""The sane range of every size a user or a file controls, checked where it comes in.

Frame rates, frame counts, points, picture sizes: a number from a file or an option is checked
against its range before anything is allocated from it, so a damaged or hostile value is refused
with a ``ValueError`` that names the field, the value and the range, instead of exhausting memory
or time. The table is the C++ core's (``cpp/include/voicepuppet/limits.hpp``), which checks
puppet files with the same numbers.

- ``fps``: 1 to 1000, frames per second of puppets, animations, features and outputs;
- ``frames``: 1 to 10 000 000, frames of one sequence (92 hours at 29.97 fps);
- ``points``: 1 to 10 000, landmarks of a face;
- ``states``: 1 to 1000, states of one face part's HMM;
- ``dims``: 1 to 1000, audio feature columns, vocal features, a part's face coordinates;
- ``parts``: 1 to 64, face parts of a puppet;
- ``metadata_depth``: 0 to 64, nesting of arrays and objects in a puppet's metadata JSON;
- ``image_side``: 16 to 8192, width or height of a rendered picture in pixels;
- ``pixel``: -1e6 to 1e6, where a puppet's state means may place a landmark (pixels).
"""

from __future__ import annotations

import math
import numbers

from voicepuppet import _core

__all__ = ["LIMITS", "check_limit"]

#: name -> (lowest, highest) allowed value, as in the table above.
LIMITS: dict = {name: tuple(bounds) for name, bounds in _core.LIMITS.items()}


def check_limit(value, limit: str, name: str, hint: str = "") -> float:
    """``value`` checked to lie in the range of :data:`LIMITS` ``[limit]``.

    Parameters
    ----------
    value : int or float
        The number to check (anything ``float()`` accepts).
    limit : str
        Which range: a key of :data:`LIMITS` (``"fps"``, ``"frames"``, ``"points"``, ...).
    name : str
        What the value is, for the message (e.g. ``"--fps"``, ``"animation fps"``).
    hint : str
        What to do instead, appended to the message (default none).

    Returns
    -------
    float
        ``value`` as a float (integers stay exact up to 2**53).

    Raises
    ------
    ValueError
        ``value`` is not a number, is NaN, or lies outside the range; the message names
        ``name``, the value and the range.
    """
    lo, hi = LIMITS[limit]
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be a number in [{_fmt(lo)}, {_fmt(hi)}], got {value!r}") from None
    if math.isnan(x) or not lo <= x <= hi:
        raise ValueError(f"{name} = {_fmt(value)} is outside [{_fmt(lo)}, {_fmt(hi)}]" + (f"; {hint}" if hint else ""))
    return x


def _fmt(value) -> str:
    """Integers in full, other numbers as C++ streams them (``1e+09``)."""
    return str(int(value)) if isinstance(value, numbers.Integral) else f"{float(value):g}"
