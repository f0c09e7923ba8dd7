"""The puppet file's metadata checked for meaning: what a puppet's readers (the animator, ``info``,
``train``'s report, evaluation) take from it is there, of the right type, and agrees with the
arrays the C++ core has validated (``cpp/include/voicepuppet/puppet.hpp``). The core itself has
checked that the text is UTF-8 and nests at most ``LIMITS["metadata_depth"]`` levels, so Python's
``json`` reads it without recursing deeply.

The metadata, as :func:`voicepuppet.puppet.training.train` writes it:

- ``parts``: the face parts' names, one per part of the arrays (list of str);
- ``feature_set``: the feature set, as :meth:`voicepuppet.audio.FeatureSet.to_json` writes it;
- ``feature_names`` (optional): one name per raw audio feature column;
- ``fps``, ``n_points`` (optional): copies of the arrays' frame rate and point count;
- ``created_by``, ``format`` (optional): text;
- ``training`` (optional): ``frames``, ``sequences``, ``options`` (dict), ``parts`` (one dict
  per part: ``part`` name, ``states``, ``arcs``, ``face_dims`` whole numbers, ``perplexity``,
  ``context_memory`` numbers), ``guide`` (dict; ``weight_cv`` with as many
  ``mse`` (error about each held-out run's mean) as ``weights``, and ``mse_raw`` (with the means)
  in puppets trained since it was added).
"""

from __future__ import annotations

import math
import numbers

from voicepuppet.audio import FeatureSet
from voicepuppet.limits import LIMITS

__all__ = ["check_metadata"]


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _real(value) -> float | None:
    """``value`` as a float if it is a number a float holds (JSON integers can be longer), else None."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return None
    try:
        return float(value)
    except OverflowError:
        return None


def _number(value) -> bool:
    return _real(value) is not None


def _whole(where: str, key: str, value, lo: float, hi: float) -> int:
    x = _real(value)
    if x is None or not (math.isfinite(x) and x.is_integer() and lo <= x <= hi):
        raise ValueError(f"{where}{key} must be a whole number in [{lo:g}, {hi:g}], got {_show(value)}")
    return int(value)


def _check_training(training, n_parts: int, where: str) -> None:
    if not isinstance(training, dict):
        raise ValueError(f"{where}training must be an object, got {_show(training)}")
    for key in ("frames", "sequences"):
        if key in training:
            training[key] = _whole(where, f"training.{key}", training[key], 0, 1e15)
    for key in ("options", "guide"):
        if not isinstance(training.get(key, {}), dict):
            raise ValueError(f"{where}training.{key} must be an object, got {_show(training[key])}")
    parts = training.get("parts", [])
    if not isinstance(parts, list) or len(parts) != n_parts or not all(isinstance(p, dict) for p in parts):
        raise ValueError(f"{where}training.parts must be a list of {n_parts} objects (one per face part), "
                         f"got {_show(parts)}")
    n_states, n_dims = LIMITS["states"][1], LIMITS["dims"][1]
    for k, part in enumerate(parts):
        at = f"training.parts[{k}]."
        if not isinstance(part.get("part"), str):
            raise ValueError(f"{where}{at}part must be the part's name, got {_show(part.get('part'))}")
        for key, hi in (("states", n_states), ("arcs", n_states ** 2), ("face_dims", n_dims)):
            part[key] = _whole(where, at + key, part.get(key), 0, hi)
        for key in ("perplexity", "context_memory"):
            if not _number(part.get(key)):
                raise ValueError(f"{where}{at}{key} must be a number, got {_show(part.get(key))}")
    cv = training.get("guide", {}).get("weight_cv")
    if cv is not None:
        ok = isinstance(cv, dict) and all(isinstance(cv.get(k), list) and all(_number(v) for v in cv[k])
                                          for k in ("weights", "mse"))
        if not ok or len(cv["weights"]) != len(cv["mse"]) or not cv["weights"]:
            raise ValueError(f"{where}training.guide.weight_cv must hold lists of numbers 'weights' and 'mse' "
                             f"of one length, got {_show(cv)}")


def check_metadata(metadata, *, n_parts: int, n_features: int, n_points: int, fps: float,
                   source: str = "the puppet") -> dict:
    """Check a puppet's metadata against the arrays' sizes (see the module's description).

    Parameters
    ----------
    metadata : object
        The metadata, as ``json.loads`` gives it.
    n_parts, n_features, n_points : int
        The face parts, raw audio feature columns and points of the puppet's arrays.
    fps : float
        The frame rate of the puppet's arrays.
    source : str
        What the metadata belongs to, for the messages (default ``"the puppet"``).

    Returns
    -------
    dict
        ``metadata`` itself, with the whole numbers of ``training`` (``states``, ``arcs``,
        ``face_dims``, ``frames``, ``sequences``) as ``int`` (older files stored floats).

    Raises
    ------
    ValueError
        A missing ``parts`` or ``feature_set``, a field of the wrong type, a feature set that
        does not parse, or counts that disagree with the arrays; the message names the field
        and what was expected.
    """
    where = f"{source}'s metadata: "
    if not isinstance(metadata, dict):
        raise ValueError(f"{where}must be a JSON object, got {_show(metadata)}")
    for key in ("parts", "feature_set"):
        if key not in metadata:
            raise ValueError(f"{where}has no {key!r}; it was not written by voicepuppet train")
    parts = metadata["parts"]
    if not isinstance(parts, list) or len(parts) != n_parts or not all(isinstance(p, str) and p for p in parts):
        raise ValueError(f"{where}parts must be a list of {n_parts} names (one per face part of the arrays), "
                         f"got {_show(parts)}")
    if not isinstance(metadata["feature_set"], str):
        raise ValueError(f"{where}feature_set must be JSON text, got {_show(metadata['feature_set'])}")
    try:
        FeatureSet.from_json(metadata["feature_set"])
    except (ValueError, KeyError, TypeError, AttributeError, OverflowError) as exc:
        raise ValueError(f"{where}feature_set does not describe a feature set ({type(exc).__name__}: "
                         f"{_show(str(exc))})") from None
    names = metadata.get("feature_names", [""] * n_features)
    if not isinstance(names, list) or len(names) != n_features or not all(isinstance(n, str) for n in names):
        raise ValueError(f"{where}feature_names must be a list of {n_features} names (one per audio feature "
                         f"column), got {_show(names)}")
    if "fps" in metadata and not math.isclose(_real(metadata["fps"]) or 0.0, fps, rel_tol=1e-9):
        raise ValueError(f"{where}fps must be the arrays' frame rate {fps:g}, got {_show(metadata['fps'])}")
    if "n_points" in metadata and not (_number(metadata["n_points"]) and metadata["n_points"] == n_points):
        raise ValueError(f"{where}n_points must be the arrays' {n_points} points, got {_show(metadata['n_points'])}")
    for key in ("created_by", "format"):
        if not isinstance(metadata.get(key, ""), str):
            raise ValueError(f"{where}{key} must be text, got {_show(metadata[key])}")
    if "training" in metadata:
        _check_training(metadata["training"], n_parts, where)
    return metadata
