"""Rhubarb Lip Sync as a peer: its mouth cues, a mouth trajectory from them, and cue agreement.

Rhubarb Lip Sync (Daniel S. Wolf, MIT licence) turns speech into Preston Blair mouth shapes
A-H and X on a 10 ms grid; it is what most game and animation users reach for. voicepuppet
never runs it at run time: it is a peer of the evaluation and the benchmarks, found at
``$VOICEPUPPET_RHUBARB`` or ``../shared/peers/rhubarb/rhubarb`` beside the repository
(:func:`find_rhubarb`).

Cues become a trajectory with their best possible mapping (:class:`ShapeMap`): each shape is
given the mean of what the *training* frames under that shape have in the truth (their face
coordinates, or their mouth opening), so Rhubarb is credited with every bit of information its
shapes carry about the face; a shape no training frame has gets the training mean.

Cue agreement (:func:`cue_agreement`) compares per-frame shapes with cues derived from the
truth, in two ways: ``geometry``, voicepuppet's own cue rule
(:func:`voicepuppet.render.export.mouth_cues`) applied to the true landmarks, and
``centroid``, the shape whose :class:`ShapeMap` mean (fitted on the training frames under
Rhubarb's cues) is nearest the true face.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["SHAPES", "RECOGNIZERS", "RhubarbError", "find_rhubarb", "Rhubarb", "frame_shapes", "ShapeMap",
           "cue_agreement"]

#: Rhubarb's mouth shapes (basic A-F, extended G, H, X), the order of confusion matrices.
SHAPES = ("A", "B", "C", "D", "E", "F", "G", "H", "X")
#: Rhubarb's two recognisers: English PocketSphinx, and the language-independent phonetic one.
RECOGNIZERS = ("pocketSphinx", "phonetic")
#: Where the peer is looked for, relative to the repository, when ``$VOICEPUPPET_RHUBARB`` is unset.
_DEFAULT = Path("..") / "shared" / "peers" / "rhubarb" / "rhubarb"


class RhubarbError(RuntimeError):
    """Rhubarb is missing, failed, or wrote what cannot be read."""


def find_rhubarb(path=None) -> Path | None:
    """The Rhubarb Lip Sync executable, or None where there is none.

    Parameters
    ----------
    path : path, optional
        The executable; default ``$VOICEPUPPET_RHUBARB``, else ``../shared/peers/rhubarb/rhubarb``
        relative to the repository (the folder above ``python/``) or to the working directory.

    Returns
    -------
    pathlib.Path or None
        The executable's path; None when not given and not found.

    Raises
    ------
    RhubarbError
        ``path`` (or ``$VOICEPUPPET_RHUBARB``) is given but is no executable file.
    """
    given = path if path is not None else os.environ.get("VOICEPUPPET_RHUBARB") or None
    if given is not None:
        p = Path(given)
        if not (p.is_file() and os.access(p, os.X_OK)):
            raise RhubarbError(f"Rhubarb Lip Sync is not at {p} (from "
                               f"{'the argument' if path is not None else '$VOICEPUPPET_RHUBARB'}): give the "
                               "'rhubarb' executable of a Rhubarb 1.14 folder (it needs its res/ beside it)")
        return p
    repo = Path(__file__).resolve().parents[3]
    for base in (repo, Path.cwd()):
        p = (base / _DEFAULT).resolve()
        if p.is_file() and os.access(p, os.X_OK):
            return p
    return None


class Rhubarb:
    """Runs Rhubarb Lip Sync on sound, one thread, and reads its cues.

    Parameters
    ----------
    executable : path, optional
        As :func:`find_rhubarb`'s ``path``.
    cache_dir : path, optional
        Where cues are kept by the sound's content and the recogniser (default: none kept).
    timeout : float
        Seconds one run may take (default 600).

    Raises
    ------
    RhubarbError
        No Rhubarb found (the message says where it was looked for and how to point to it).
    """

    def __init__(self, executable=None, *, cache_dir=None, timeout: float = 600.0):
        exe = find_rhubarb(executable)
        if exe is None:
            raise RhubarbError("Rhubarb Lip Sync not found: set VOICEPUPPET_RHUBARB to its 'rhubarb' executable "
                               f"(looked for {_DEFAULT} beside the repository and the working directory)")
        self.executable = exe
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        self.timeout = float(timeout)

    def cues(self, samples, rate: int, recognizer: str = "pocketSphinx") -> list[dict]:
        """Rhubarb's mouth cues of a sound.

        Parameters
        ----------
        samples : array_like, shape (n,)
            Mono audio in [-1, 1].
        rate : int
            Its sample rate (Hz).
        recognizer : str
            One of :data:`RECOGNIZERS`.

        Returns
        -------
        list of dict
            ``{"start", "end", "value"}`` (seconds, shape letter), consecutive.

        Raises
        ------
        ValueError
            An unknown recogniser or empty sound.
        RhubarbError
            Rhubarb failed (its message), timed out, or wrote no readable cues.
        """
        import soundfile

        if recognizer not in RECOGNIZERS:
            raise ValueError(f"recognizer must be one of {RECOGNIZERS}, got {recognizer!r}")
        x = np.clip(np.asarray(samples, dtype=np.float64).ravel(), -1.0, 1.0)
        if x.size == 0:
            raise ValueError("Rhubarb needs sound: got no samples")
        pcm = np.round(x * 32767).astype("<i2")
        key = hashlib.sha256(pcm.tobytes() + str(int(rate)).encode()).hexdigest()[:20]
        cached = None if self.cache_dir is None else self.cache_dir / f"{key}-{recognizer}.json"
        if cached is not None and cached.is_file():
            return _read_cues(cached)
        with tempfile.TemporaryDirectory(prefix="vp-rhubarb-") as tmp:
            wav, out = Path(tmp) / "speech.wav", Path(tmp) / "cues.json"
            soundfile.write(wav, pcm, int(rate), subtype="PCM_16")
            cmd = [str(self.executable), "-q", "--threads", "1", "-r", recognizer, "-f", "json", "-o", str(out),
                   str(wav)]
            try:
                run = subprocess.run(cmd, capture_output=True, text=True, timeout=self.timeout)
            except subprocess.TimeoutExpired:
                raise RhubarbError(f"Rhubarb ({recognizer}) took over {self.timeout:g} s on {x.size / rate:.1f} s "
                                   "of sound") from None
            if run.returncode != 0:
                raise RhubarbError(f"Rhubarb ({recognizer}) failed with exit code {run.returncode}: "
                                   f"{(run.stderr or run.stdout).strip()[-500:]}")
            cues = _read_cues(out)
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                part = cached.with_suffix(".part")
                part.write_text(out.read_text(encoding="utf-8"), encoding="utf-8")
                part.replace(cached)
        return cues


def _read_cues(path: Path) -> list[dict]:
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        cues = [{"start": float(c["start"]), "end": float(c["end"]), "value": str(c["value"])}
                for c in doc["mouthCues"]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise RhubarbError(f"{path}: not Rhubarb's JSON cues ({type(e).__name__}: {e})") from None
    bad = sorted({c["value"] for c in cues} - set(SHAPES))
    if bad:
        raise RhubarbError(f"{path}: unknown mouth shapes {bad}; expected {SHAPES}")
    return cues


def frame_shapes(cues, n: int, fps: float) -> np.ndarray:
    """The shape in force at each frame's time ``t / fps`` (after the last cue: its shape; X
    where there are no cues).

    Parameters
    ----------
    cues : list of dict
        ``{"start", "end", "value"}``, in time order.
    n : int
        Frames.
    fps : float
        Frame rate.

    Returns
    -------
    ndarray of str, shape (n,)
    """
    out = np.full(int(n), "X", dtype="<U1")
    if not cues:
        return out
    starts = np.array([c["start"] for c in cues])
    idx = np.searchsorted(starts, np.arange(int(n)) / float(fps) + 1e-9, side="right") - 1
    values = np.array([c["value"] for c in cues], dtype="<U1")
    out[idx >= 0] = values[idx[idx >= 0]]
    return out


class ShapeMap:
    """Each mouth shape's mean of what the training frames under it have in the truth.

    Fitted attributes: ``means_`` ({shape: (D,) mean}), ``counts_`` ({shape: frames}) and
    ``default_`` (the mean of all training frames, for shapes not in training).
    """

    def fit(self, shapes, values) -> "ShapeMap":
        """Learn the means.

        Parameters
        ----------
        shapes : list of array of str, each (T_s,)
            Per training sequence, its frames' shapes.
        values : list of array, each (T_s,) or (T_s, D)
            The truth at those frames (face coordinates, or an opening).

        Returns
        -------
        ShapeMap
            self.

        Raises
        ------
        ValueError
            Lengths that differ or no frames.
        """
        if len(shapes) != len(values) or any(len(s) != len(v) for s, v in zip(shapes, values)):
            raise ValueError("shapes and values must have one entry per sequence, of the same frames each")
        S = np.concatenate([np.asarray(s) for s in shapes]) if shapes else np.zeros(0, "<U1")
        V = np.concatenate([np.asarray(v, dtype=np.float64) for v in values]) if values else np.zeros(0)
        if not len(S):
            raise ValueError("no training frames to map the shapes from")
        self.scalar_ = V.ndim == 1
        V = V.reshape(len(V), -1)
        self.default_ = V.mean(axis=0)
        self.means_ = {s: V[S == s].mean(axis=0) for s in SHAPES if (S == s).any()}
        self.counts_ = {s: int((S == s).sum()) for s in self.means_}
        return self

    def predict(self, shapes) -> np.ndarray:
        """The mapped trajectory: each frame's shape mean.

        Parameters
        ----------
        shapes : array of str, shape (T,)
            Each frame's shape.

        Returns
        -------
        ndarray, shape (T,) or (T, D)
            As the training values were.
        """
        out = np.array([self.means_.get(s, self.default_) for s in np.asarray(shapes)]).reshape(len(shapes), -1)
        return out[:, 0] if self.scalar_ else out

    def nearest(self, values) -> np.ndarray:
        """Each frame's nearest shape mean (Euclidean): cues derived from the truth.

        Parameters
        ----------
        values : array, shape (T,) or (T, D)
            The truth per frame, as the map was fitted on.

        Returns
        -------
        ndarray of str, shape (T,)
        """
        names = list(self.means_)
        C = np.array([self.means_[s] for s in names])
        V = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
        d = ((V[:, None, :] - C[None]) ** 2).sum(axis=2)
        return np.array(names, dtype="<U1")[d.argmin(axis=1)]


def cue_agreement(pred, truth) -> dict:
    """How per-frame shapes agree with truth-derived ones.

    Parameters
    ----------
    pred, truth : array of str, shape (T,)
        Per-frame shapes: predicted and derived from the truth.

    Returns
    -------
    dict
        ``agreement`` (share of frames with the same shape), ``confusion`` ({true shape:
        {predicted shape: frames}}, shapes of :data:`SHAPES` that occur) and ``recall`` ({true
        shape: share of its frames predicted as it}).

    Raises
    ------
    ValueError
        ``pred`` and ``truth`` of different lengths.
    """
    p, t = np.asarray(pred), np.asarray(truth)
    if p.shape != t.shape:
        raise ValueError(f"pred and truth must have the same frames, got {p.shape} and {t.shape}")
    conf = {a: {b: int(((t == a) & (p == b)).sum()) for b in SHAPES if ((t == a) & (p == b)).any()}
            for a in SHAPES if (t == a).any()}
    return {"agreement": float((p == t).mean()) if len(t) else float("nan"), "confusion": conf,
            "recall": {a: row.get(a, 0) / sum(row.values()) for a, row in conf.items()}}
