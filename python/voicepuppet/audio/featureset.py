"""Feature sets: which features, with which settings, and how they are standardised.

A :class:`FeatureSet` names the features and their settings; :func:`voicepuppet.audio.extract.extract`
computes them at an output frame rate into a :class:`Features` table (one row per video frame,
named columns);
:class:`Standardizer` holds per-column mean and standard deviation, fitted once on training audio
and applied unchanged to novel audio, saved and loaded as plain arrays (a puppet file carries
them).

Features (column names in brackets):

- ``lpc``: LPC coefficients ``a_1 .. a_p`` (``lpc1..``), autocorrelation method, pre-emphasis.
- ``lpc_cepstra``: cepstra ``c_1 .. c_n`` of the LPC model (``lpcc1..``).
- ``rasta_plp``: RASTA-PLP cepstra ``c_k .. c_n`` (``rplp0..``; ``c_0`` only if asked).
- ``mfcc``: 13 MFCCs of the log mel power (``mfcc0..``); ``mfcc_deltas``: their regression
  deltas (``dmfcc0..``).
- ``formants``: F1..F3 in Hz (``f1, f2, f3``), LPC roots with bandwidth limits and continuity.
- ``bands``: energies (dB) in the sonorant bands (``band0..``).
- ``f0``: F0 in Hz, interpolated through unvoiced frames (``f0``); ``voicing``: probability.
- ``log_energy``: frame energy in dB (``log_energy``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from voicepuppet._files import atomic_path, read_npz
from voicepuppet.audio.framing import frame_times

FEATURES = ("lpc", "lpc_cepstra", "rasta_plp", "mfcc", "mfcc_deltas", "formants", "bands", "f0",
            "voicing", "log_energy")

#: Settings every feature set starts from (override per set or per call).
DEFAULT_OPTIONS = {
    "window_s": None,        # spectral and LPC window (s); None: max(25 ms, 1 / fps), so the
                             # Hann windows of consecutive frames cover all of the audio
    "n_fft": None,           # FFT length of the spectra; None: the next fast length >= window
    "lpc_order": 12,         # LPC order for lpc / lpc_cepstra (at 16 kHz)
    "lpc_preemph": 0.97,
    "n_lpc_cepstra": 12,     # c_1 .. c_n
    "rasta_order": 8,        # PLP all-pole model order
    "n_rasta": 9,            # number of RASTA-PLP cepstra kept
    "rasta_c0": True,        # keep c_0 (log gain) of RASTA-PLP
    "n_mfcc": 13,
    "n_mels": 40,
    "delta_width": 2,
    "formant_ceiling": 5500.0,
    "formant_max_bandwidth": 1000.0,
    "pitch_floor": 75.0,
    "pitch_ceiling": 600.0,
    "band_hz": None,         # limit the audio to this band (Hz) before any analysis, by
                             # resampling to 2 band_hz and back (conditioning.BandLimiter): 4000 makes
                             # a puppet for telephone audio (8 kHz); None: the whole band
    "level_db": None,        # bring each recording's speech level to this (dBFS) and turn its frames
                             # 35 dB under it into dither, before any analysis (conditioning.LevelNormalizer):
                             # pauses look alike whatever the noise floor, and so do loud and
                             # quiet recordings; None: the samples as they are
}

#: Named feature sets. "puppet" is Brand's mix (section 4.1): LPC and RASTA-PLP cepstra,
#: formants, sonorant band energies and energy.
FEATURE_SETS = {
    "puppet": {"features": ("lpc_cepstra", "rasta_plp", "formants", "bands", "log_energy"),
               "options": {"n_lpc_cepstra": 8, "n_rasta": 9, "rasta_c0": False}},
    "mfcc": {"features": ("mfcc",), "options": {}},
    "mfcc_deltas": {"features": ("mfcc", "mfcc_deltas"), "options": {}},
    "prosody": {"features": ("f0", "voicing", "formants", "log_energy"), "options": {}},
    "all": {"features": FEATURES, "options": {}},
}

DEFAULT_SET = "puppet"


def check_level_db(level) -> float:
    """The feature option ``level_db`` as a float: a speech level in dBFS in [-100, 0].

    Parameters
    ----------
    level : float
        The option's value.

    Returns
    -------
    float
        ``level`` as a float.

    Raises
    ------
    ValueError
        ``level`` is not a number (a bool is not one) in [-100, 0].
    """
    if (isinstance(level, bool) or not isinstance(level, (int, float, np.integer, np.floating))
            or not -100.0 <= level <= 0.0):
        raise ValueError(f"feature option level_db must be a speech level in dBFS between -100 and 0 "
                         f"(e.g. -20) or None, got {level!r}")
    return float(level)


#: Ranges of the numeric options, so that a feature set read from a file cannot ask for sizes
#: (FFT lengths, filter banks, model orders) that exhaust memory.
_OPTION_RANGES = {"window_s": (1e-3, 10.0), "n_fft": (16, 2 ** 20), "lpc_order": (1, 100),
                  "lpc_preemph": (0.0, 1.0), "n_lpc_cepstra": (1, 100), "rasta_order": (1, 100),
                  "n_rasta": (1, 100), "n_mfcc": (1, 1000), "n_mels": (1, 1000), "delta_width": (0, 100),
                  "formant_ceiling": (1.0, 1e5), "formant_max_bandwidth": (1.0, 1e5),
                  "pitch_floor": (1.0, 1e4), "pitch_ceiling": (1.0, 1e4)}
_COUNT_OPTIONS = {"n_fft", "lpc_order", "n_lpc_cepstra", "rasta_order", "n_rasta", "n_mfcc", "n_mels", "delta_width"}


@dataclass(frozen=True)
class FeatureSet:
    """Which features to compute and with which settings.

    Parameters
    ----------
    features : tuple of str
        Names from ``FEATURES``, in output column order.
    options : dict
        Overrides of ``DEFAULT_OPTIONS``.
    name : str
        A label stored with the features (a named set, or "custom", the default).

    Raises
    ------
    ValueError
        No features, a name not in ``FEATURES``, a feature listed twice, an unknown option, an
        invalid ``band_hz`` (not a positive frequency) or ``level_db`` (see
        :func:`check_level_db`), or a numeric option outside its range (e.g. ``n_fft`` in
        [16, 2^20], model orders and counts of coefficients in [1, 100] or [1, 1000]).
    """

    features: tuple
    options: dict = field(default_factory=dict)
    name: str = "custom"

    def __post_init__(self):
        feats = tuple(self.features)
        if not feats:
            raise ValueError(f"feature set needs at least one feature; choose from "
                             f"{', '.join(FEATURES)}")
        for f in feats:
            if f not in FEATURES:
                raise ValueError(f"unknown feature {f!r}; choose from {', '.join(FEATURES)}")
        if len(set(feats)) != len(feats):
            raise ValueError(f"feature set lists a feature twice: {feats}")
        for k in self.options:
            if k not in DEFAULT_OPTIONS:
                raise ValueError(f"unknown feature option {k!r}; known: "
                                 f"{', '.join(DEFAULT_OPTIONS)}")
        band = self.options.get("band_hz")
        if band is not None and (isinstance(band, bool) or not isinstance(band, (int, float, np.integer, np.floating))
                                 or not 0 < band < float("inf")):
            raise ValueError(f"feature option band_hz must be a frequency in Hz above 0 (e.g. 4000 for "
                             f"telephone audio) or None, got {band!r}")
        if self.options.get("level_db") is not None:
            check_level_db(self.options["level_db"])
        for k, (lo, hi) in _OPTION_RANGES.items():
            v = self.options.get(k)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                                  or not lo <= v <= hi or (k in _COUNT_OPTIONS and v != int(v))):
                kind = "a whole number" if k in _COUNT_OPTIONS else "a number"
                raise ValueError(f"feature option {k} must be {kind} in [{lo:g}, {hi:g}], got {v!r}")
        object.__setattr__(self, "features", feats)
        object.__setattr__(self, "options", dict(self.options))

    @classmethod
    def named(cls, name: str, **overrides) -> "FeatureSet":
        """One of ``FEATURE_SETS`` (``"puppet"``, ``"mfcc"``, ...) with optional overrides.

        Parameters
        ----------
        name : str
            A key of ``FEATURE_SETS``.
        **overrides
            Options (keys of ``DEFAULT_OPTIONS``) that replace the set's own.

        Returns
        -------
        FeatureSet
            The named set's features, its options updated with ``overrides``, named ``name``.

        Raises
        ------
        ValueError
            An unknown set name or option.
        """
        if name not in FEATURE_SETS:
            raise ValueError(f"unknown feature set {name!r}; choose from "
                             f"{', '.join(FEATURE_SETS)}")
        spec = FEATURE_SETS[name]
        return cls(spec["features"], {**spec["options"], **overrides}, name)

    def settings(self) -> dict:
        """All options in force (defaults merged with this set's overrides).

        Returns
        -------
        dict
            ``DEFAULT_OPTIONS`` updated with :attr:`options` (a new dict).
        """
        return {**DEFAULT_OPTIONS, **self.options}

    def to_json(self) -> str:
        """The set as JSON (``name``, ``features``, ``options``), as a features file stores it.

        Returns
        -------
        str
            JSON text with sorted keys; :meth:`from_json` reads it back.
        """
        return json.dumps({"name": self.name, "features": list(self.features),
                           "options": self.options}, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "FeatureSet":
        """The set written by :meth:`to_json`.

        Parameters
        ----------
        text : str
            JSON with ``features`` and optionally ``options`` (default none) and ``name``
            (default ``"custom"``).

        Returns
        -------
        FeatureSet
            The set described by ``text``.

        Raises
        ------
        ValueError
            Text that is not JSON, or a set that is not valid (see :class:`FeatureSet`).
        """
        d = json.loads(text)
        return cls(tuple(d["features"]), d.get("options", {}), d.get("name", "custom"))


def as_feature_set(spec) -> FeatureSet:
    """A FeatureSet from a FeatureSet, a set name, or a list or comma-separated string of
    feature names.

    Parameters
    ----------
    spec : FeatureSet, str, iterable of str or None
        A set (returned as it is), a key of ``FEATURE_SETS``, feature names as a list or a
        comma-separated string (a set named "custom"), or None for ``DEFAULT_SET``.

    Returns
    -------
    FeatureSet
        The set ``spec`` describes.

    Raises
    ------
    ValueError
        An unknown feature name, or no feature at all.
    """
    if isinstance(spec, FeatureSet):
        return spec
    if spec is None:
        return FeatureSet.named(DEFAULT_SET)
    if isinstance(spec, str):
        if spec in FEATURE_SETS:
            return FeatureSet.named(spec)
        return FeatureSet(tuple(s.strip() for s in spec.split(",") if s.strip()))
    return FeatureSet(tuple(spec))


@dataclass(frozen=True)
class Features:
    """Audio features at a video frame rate.

    Made by :func:`voicepuppet.audio.extract.extract` or read by :meth:`load`; each parameter is
    kept as the (read-only) attribute of the same name. ``len(features)`` is the number of
    frames T.

    Parameters
    ----------
    values : ndarray, shape (T, D)
        One row per video frame (frame ``k`` centred at ``k / fps``), finite.
    names : tuple of str, length D
        Column names.
    fps : float
        Frame rate of the rows.
    feature_set : FeatureSet
        The set the columns were computed with.
    duration : float
        Seconds of audio analysed.
    voiced : ndarray of bool, shape (T,) or None
        Frames called voiced by the F0 tracker (when ``f0`` or ``voicing`` was computed;
        default None).

    Attributes
    ----------
    times : ndarray, shape (T,)
        Frame times ``k / fps`` in seconds.
    """

    values: np.ndarray
    names: tuple
    fps: float
    feature_set: FeatureSet
    duration: float
    voiced: np.ndarray | None = None

    @property
    def times(self) -> np.ndarray:
        """Frame times ``k / fps`` in seconds, shape (T,)."""
        return frame_times(self.values.shape[0], self.fps)

    def __len__(self) -> int:
        return self.values.shape[0]

    def column(self, name: str) -> np.ndarray:
        """Values of one column.

        Parameters
        ----------
        name : str
            A column name (one of :attr:`names`, e.g. ``"mfcc3"``).

        Returns
        -------
        ndarray, shape (T,)
            The column's values.

        Raises
        ------
        ValueError
            No column has that name.
        """
        return self.values[:, self._index(name)]

    def group(self, feature: str) -> np.ndarray:
        """Columns of one feature.

        Parameters
        ----------
        feature : str
            A feature name (e.g. ``"mfcc"``; see :func:`feature_of`).

        Returns
        -------
        ndarray, shape (T, d)
            The feature's d columns, in table order.

        Raises
        ------
        ValueError
            The table has no column of that feature.
        """
        cols = [i for i, n in enumerate(self.names) if feature_of(n) == feature]
        if not cols:
            raise ValueError(f"feature {feature!r} not in this table; it has "
                             f"{', '.join(self.feature_set.features)}")
        return self.values[:, cols]

    def _index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"no column {name!r}; columns are {', '.join(self.names)}") from None

    def save(self, path) -> None:
        """Write the table to a ``.npz`` or ``.csv`` file.

        ``.npz``: ``features`` (T, D), ``names``, ``times``, ``fps``, ``duration``,
        ``feature_set`` (JSON), ``voiced`` (if known); or ``.csv``: a ``frame,time,<names>``
        header and a row per frame (what ``examples/cpp`` reads). Atomic (temporary file, then
        rename).

        Parameters
        ----------
        path : str or os.PathLike
            Output file; its suffix (``.npz`` or ``.csv``) chooses the format.

        Raises
        ------
        ValueError
            Another suffix, or a folder that does not exist or is not writable.
        """
        path = os.fspath(path)
        suffix = path[-4:].lower()
        if suffix not in (".npz", ".csv"):
            raise ValueError(f"features: output must end in .npz or .csv, got {path!r}")
        with atomic_path(path, (".npz", ".csv"), "features") as tmp:
            if suffix == ".csv":
                table = np.column_stack([np.arange(len(self)), self.times, self.values])
                np.savetxt(tmp, table, delimiter=",", fmt=["%d", "%.6f"] + ["%.17g"] * self.values.shape[1],
                           header=",".join(("frame", "time") + tuple(self.names)), comments="")
            else:
                payload = {"features": self.values, "names": np.array(self.names), "times": self.times,
                           "fps": np.float64(self.fps), "duration": np.float64(self.duration),
                           "feature_set": np.array(self.feature_set.to_json())}
                if self.voiced is not None:
                    payload["voiced"] = self.voiced
                np.savez(tmp, **payload)

    @classmethod
    def load(cls, path) -> "Features":
        """Read a table written by :meth:`save` as ``.npz``.

        Parameters
        ----------
        path : str or os.PathLike
            A ``.npz`` features file.

        Returns
        -------
        Features
            The saved table (``voiced`` None if the file has none).

        Raises
        ------
        ValueError
            The file lacks the arrays of a features file (``features``, ``names``, ``fps``,
            ``duration``, ``feature_set``).
        """
        path = os.fspath(path)
        z = read_npz(path, "features file")
        missing = {"features", "names", "fps", "duration", "feature_set"} - set(z)
        if missing:
            raise ValueError(f"features: {path!r} is not a features file (missing "
                             f"{', '.join(sorted(missing))})")
        return cls(np.array(z["features"]), tuple(str(n) for n in z["names"]),
                   float(z["fps"]), FeatureSet.from_json(str(z["feature_set"])),
                   float(z["duration"]), np.array(z["voiced"]) if "voiced" in z else None)


_PREFIX = {"lpc": "lpc", "lpcc": "lpc_cepstra", "rplp": "rasta_plp", "mfcc": "mfcc",
           "dmfcc": "mfcc_deltas", "band": "bands"}


def feature_of(col: str) -> str:
    """The feature a column belongs to (``"mfcc3"`` -> ``"mfcc"``).

    Parameters
    ----------
    col : str
        A column name of a :class:`Features` table.

    Returns
    -------
    str
        The feature's name: ``"formants"`` for ``f1`` .. ``f5``; otherwise the name without its
        trailing digits, mapped through the column prefixes (``lpcc`` -> ``lpc_cepstra``, ...).
    """
    if col in ("f1", "f2", "f3", "f4", "f5"):
        return "formants"
    if col in ("f0", "voicing", "log_energy"):
        return col
    head = col.rstrip("0123456789")
    return _PREFIX.get(head, head)


def analysis_window_s(opt: dict, fps: float) -> float:
    """Length (s) of the spectral and LPC analysis windows: ``window_s`` if set, else 25 ms or
    one frame period, whichever is longer.

    Parameters
    ----------
    opt : dict
        Options in force (:meth:`FeatureSet.settings`); its ``window_s`` is read.
    fps : float
        Output frame rate.

    Returns
    -------
    float
        Window length in seconds.
    """
    return float(opt["window_s"]) if opt["window_s"] else max(0.025, 1.0 / fps)


@dataclass(frozen=True)
class Standardizer:
    """Per-column standardisation ``(x - mean) / std`` fitted on training features.

    Stored as plain arrays (``to_arrays`` / ``from_arrays``) so that a puppet file carries them
    and novel audio is scaled exactly like the training audio. Build with :meth:`fit` or
    :meth:`from_arrays`; each parameter is kept as the (read-only) attribute of the same name.

    Parameters
    ----------
    mean : ndarray, shape (D,)
        Per-column mean.
    std : ndarray, shape (D,)
        Per-column standard deviation (floored, positive).
    names : tuple of str
        Column names of the features it was fitted on (default empty: fitted on an array, not
        checked).

    Attributes
    ----------
    REL_FLOOR : float
        Floor on std relative to the largest column std (1e-6; also absolute 1e-12).
    """

    mean: np.ndarray
    std: np.ndarray
    names: tuple = ()

    #: Floor on std, relative to the largest column std (and absolute 1e-12): constant columns
    #: (e.g. F0 of a whisper) do not blow up.
    REL_FLOOR = 1e-6

    @classmethod
    def fit(cls, features) -> "Standardizer":
        """Fit on a :class:`Features` table, a list of them (pooled), or an array (T, D).

        Parameters
        ----------
        features : Features, list of Features or array_like, shape (T, D)
            Training features; tables are stacked and must share their columns.

        Returns
        -------
        Standardizer
            Column means and standard deviations (floored at ``REL_FLOOR`` times the largest,
            and 1e-12), with the tables' column names (empty for an array).

        Raises
        ------
        ValueError
            Tables with different columns, fewer than 2 frames, not of shape (T, D), or NaN or
            infinite values.
        """
        if isinstance(features, Features):
            features = [features]
        if isinstance(features, (list, tuple)) and features and isinstance(features[0], Features):
            names = features[0].names
            for f in features[1:]:
                if f.names != names:
                    raise ValueError("standardizer: feature tables have different columns; "
                                     "extract them with the same feature set")
            X = np.vstack([f.values for f in features])
        else:
            X, names = np.asarray(features, dtype=np.float64), ()
        if X.ndim != 2 or X.shape[0] < 2:
            raise ValueError(f"standardizer: need at least 2 frames of shape (T, D), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ValueError("standardizer: features contain NaN or inf")
        mean = X.mean(axis=0)
        std = X.std(axis=0)
        std = np.maximum(std, max(cls.REL_FLOOR * float(std.max()), 1e-12))
        return cls(mean, std, tuple(names))

    def transform(self, features) -> np.ndarray:
        """Standardised values ``(x - mean) / std``.

        Parameters
        ----------
        features : Features or array_like, shape (T, D)
            Features with the columns this was fitted on.

        Returns
        -------
        ndarray, shape (T, D)
            The standardised values.

        Raises
        ------
        ValueError
            A table whose column names differ from the fitted ones, or not D columns.
        """
        if isinstance(features, Features):
            if self.names and features.names != self.names:
                raise ValueError(f"standardizer: columns differ from the ones it was fitted on "
                                 f"({len(features.names)} vs {len(self.names)}); extract novel "
                                 "audio with the training feature set")
            X = features.values
        else:
            X = np.asarray(features, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.mean.shape[0]:
            raise ValueError(f"standardizer: expected (T, {self.mean.shape[0]}) features, got "
                             f"{X.shape}")
        return (X - self.mean) / self.std

    def inverse_transform(self, Z) -> np.ndarray:
        """Undo :meth:`transform`: ``Z * std + mean``.

        Parameters
        ----------
        Z : array_like, shape (T, D)
            Standardised values.

        Returns
        -------
        ndarray, shape (T, D)
            Values in the features' units.
        """
        return np.asarray(Z, dtype=np.float64) * self.std + self.mean

    def to_arrays(self) -> dict:
        """The standardisation as plain numpy arrays (what a puppet file stores).

        Returns
        -------
        dict
            ``{"mean": (D,), "std": (D,), "names": (D,) str}`` (copies); :meth:`from_arrays`
            reads them back.
        """
        return {"mean": self.mean.copy(), "std": self.std.copy(), "names": np.array(self.names)}

    @classmethod
    def from_arrays(cls, mean, std, names=()) -> "Standardizer":
        """A standardizer from the arrays of :meth:`to_arrays`.

        Parameters
        ----------
        mean, std : array_like, shape (D,)
            Per-column mean and standard deviation.
        names : array_like of str, shape (D,) or empty
            Column names (default none).

        Returns
        -------
        Standardizer
            The standardizer of those arrays.

        Raises
        ------
        ValueError
            ``mean`` and ``std`` not 1-D of equal length, a non-finite mean, a std that is not
            finite and positive, or a number of names other than D.
        """
        mean = np.asarray(mean, dtype=np.float64)
        std = np.asarray(std, dtype=np.float64)
        if mean.ndim != 1 or mean.shape != std.shape:
            raise ValueError(f"standardizer: mean and std must be 1-D of equal length, got "
                             f"{mean.shape} and {std.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std)) and np.all(std > 0)):
            raise ValueError("standardizer: mean must be finite and std finite and positive")
        names = tuple(str(n) for n in np.asarray(names).ravel())
        if names and len(names) != mean.shape[0]:
            raise ValueError(f"standardizer: {len(names)} names for {mean.shape[0]} columns")
        return cls(mean, std, names)


__all__ = ["FEATURES", "FEATURE_SETS", "DEFAULT_SET", "DEFAULT_OPTIONS", "FeatureSet", "Features",
           "Standardizer", "as_feature_set", "feature_of", "analysis_window_s", "check_level_db"]
