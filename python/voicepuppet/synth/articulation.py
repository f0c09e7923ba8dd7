"""The performer's articulatory model: phone timings -> articulator tracks -> 68 landmarks.

Each phone class sets a target and a dominance (how strongly it claims the articulator) for
five articulators: jaw opening, lip aperture effort, spreading, rounding/protrusion and the
labiodental lower-lip tuck. Co-articulation follows Cohen & Massaro: an articulator's value is
the dominance-weighted mean of the targets, each phone's dominance decaying exponentially with the
distance from its segment (Gaussian fall-off, 40-120 ms), then a zero-phase critically damped
second-order filter (the muscle) smooths it. The inner-lip gap is a physical contact: the
jaw and lip efforts add up to an aperture that the lips clip at zero (a smooth softplus), so
bilabials whose effort overshoots into contact close the lips fully. Brows follow prosody (F0
and energy), blinks are a seeded Poisson process, and the head moves by a small smooth
similarity transform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet.audio.pitch import pitch_frames

__all__ = ["ARTICULATORS", "PARAM_NAMES", "phone_class", "Articulation", "articulator_tracks",
           "articulate", "deform", "lip_gap", "INTERNAL_RATE"]

#: the articulators driven by phones
ARTICULATORS = ("jaw", "lips", "spread", "round", "labiodental")
#: every per-frame parameter of an Articulation, in column order
PARAM_NAMES = ARTICULATORS + ("gap", "brows", "blink")
#: rate (Hz) of the internal articulator simulation
INTERNAL_RATE = 200.0

# co-articulation time constants (s) per articulator: rounding anticipates furthest
_TAU = {"jaw": 0.07, "lips": 0.04, "spread": 0.06, "round": 0.12, "labiodental": 0.04}
# muscle time constant of the critically damped smoothing (s)
_MUSCLE = 0.012

# class -> {articulator: (target, dominance)}; unspecified articulators take (0, 0.3)
_CLASSES = {
    "pause": {"jaw": (0.05, 0.4), "lips": (-0.3, 0.4), "spread": (0.0, 0.4), "round": (0.0, 0.4)},
    "bilabial": {"jaw": (0.15, 1.5), "lips": (-1.5, 4.0)},
    "labiodental": {"jaw": (0.12, 1.5), "lips": (0.05, 5.0), "labiodental": (1.0, 5.0)},
    "dental": {"jaw": (0.22, 1.0), "lips": (0.35, 1.0), "spread": (0.2, 0.5)},
    "alveolar": {"jaw": (0.2, 0.8), "lips": (0.3, 0.6)},
    "sibilant": {"jaw": (0.12, 1.5), "lips": (0.2, 1.0), "spread": (0.4, 0.8)},
    "postalveolar": {"jaw": (0.15, 1.2), "lips": (0.3, 1.0), "round": (0.7, 2.0)},
    "velar": {"jaw": (0.3, 0.4), "lips": (0.4, 0.3)},
    "glottal": {"jaw": (0.3, 0.2), "lips": (0.4, 0.2)},
    "rhotic": {"jaw": (0.25, 0.8), "lips": (0.25, 1.0), "round": (0.5, 1.5)},
    "glide_w": {"jaw": (0.15, 1.5), "lips": (0.1, 2.0), "round": (1.0, 4.0), "spread": (0.0, 2.0)},
    "glide_j": {"jaw": (0.15, 1.0), "lips": (0.25, 1.0), "spread": (0.6, 1.5)},
    "lateral": {"jaw": (0.25, 0.8), "lips": (0.35, 0.6)},
    "vowel_open": {"jaw": (0.9, 1.5), "lips": (0.8, 1.0), "spread": (0.2, 1.0), "round": (0.0, 1.0)},
    "vowel_mid": {"jaw": (0.5, 1.2), "lips": (0.55, 1.0), "spread": (0.3, 1.0), "round": (0.0, 1.0)},
    "vowel_front": {"jaw": (0.4, 1.2), "lips": (0.5, 1.0), "spread": (0.7, 1.2), "round": (0.0, 1.0)},
    "vowel_close_front": {"jaw": (0.18, 1.2), "lips": (0.3, 1.0), "spread": (1.0, 1.5),
                          "round": (0.0, 1.0)},
    "vowel_schwa": {"jaw": (0.35, 0.6), "lips": (0.45, 0.6)},
    "vowel_close_back": {"jaw": (0.18, 1.2), "lips": (0.15, 1.0), "round": (1.0, 2.0),
                         "spread": (0.0, 1.5)},
    "vowel_round": {"jaw": (0.55, 1.2), "lips": (0.4, 1.0), "round": (0.8, 2.0),
                    "spread": (0.0, 1.5)},
    "vowel_r": {"jaw": (0.35, 1.0), "lips": (0.35, 1.0), "round": (0.4, 1.0)},
}

# espeak-ng English mnemonics and ARPAbet (CMU ARCTIC labels), lower case
_PHONES = {
    "bilabial": "p b m em",
    "labiodental": "f v",
    "dental": "T D th dh",
    "alveolar": "t d n l/ t# d# t2 d2 n- en dx nx",
    "sibilant": "s z",
    "postalveolar": "S Z tS dZ sh zh ch jh",
    "velar": "k g N x ng",
    "glottal": "h ? hh",
    "rhotic": "r r- * r",
    "glide_w": "w w# wh",
    "glide_j": "j y",
    "lateral": "l L el",
    "vowel_open": "a a# A: A@ aa aa# V 0 ae ah aa",
    "vowel_mid": "e e@ E E2 3 eh",
    "vowel_front": "eI ey",
    "vowel_close_front": "i i: I I# I2 i@ iy ih",
    "vowel_schwa": "@ @2 @5 @L ax ix axr",
    "vowel_close_back": "u: U U@ u uw uh",
    "vowel_round": "O: O O@ o@ oU o 0 ao ow oy OI",
    "vowel_r": "3: er",
}
_PHONE_CLASS = {}
for _cls, _labels in _PHONES.items():
    for _lab in _labels.split():
        _PHONE_CLASS.setdefault(_lab, _cls)
# diphthongs: two targets over the two halves of the segment
_DIPHTHONGS = {"aI": ("vowel_open", "vowel_close_front"), "ay": ("vowel_open", "vowel_close_front"),
               "aU": ("vowel_open", "vowel_close_back"), "aw": ("vowel_open", "vowel_close_back"),
               "OI": ("vowel_round", "vowel_close_front"), "oy": ("vowel_round", "vowel_close_front"),
               "oU": ("vowel_round", "vowel_close_back"), "ow": ("vowel_round", "vowel_close_back"),
               "eI": ("vowel_mid", "vowel_close_front"), "ey": ("vowel_mid", "vowel_close_front"),
               "aI@": ("vowel_open", "vowel_schwa"), "aU@": ("vowel_open", "vowel_schwa"),
               "e@": ("vowel_mid", "vowel_schwa"), "i@": ("vowel_close_front", "vowel_schwa"),
               "U@": ("vowel_close_back", "vowel_schwa"), "A@": ("vowel_open", "vowel_schwa"),
               "O@": ("vowel_round", "vowel_schwa"), "o@": ("vowel_round", "vowel_schwa")}


def phone_class(label: str) -> str:
    """Articulatory class of a phone label (espeak-ng mnemonic or ARPAbet).

    Parameters
    ----------
    label : str

    Returns
    -------
    str
        A class of the articulatory model (``pause``, ``bilabial``, ``vowel_open``, ...);
        unknown labels fall back to ``vowel_schwa`` (with a vowel letter) or ``alveolar``.
    """
    lab = label.strip()
    if lab == "" or lab.startswith("_") or lab.lower() in ("sil", "pau", "sp"):
        return "pause"
    if lab in _DIPHTHONGS:
        return _DIPHTHONGS[lab][0]
    for key in (lab, lab.lower(), lab.rstrip("0123456789#-;"), lab.lower().rstrip("0123456789")):
        if key in _PHONE_CLASS:
            return _PHONE_CLASS[key]
    if any(c in "aeiouAEIOU@3V" for c in lab):
        return "vowel_schwa"
    return "alveolar"


def _segments(phones) -> list[tuple[float, float, str]]:
    out = []
    for ph in phones:
        label, start, end = (ph.label, ph.start, ph.end) if hasattr(ph, "label") else ph
        if end <= start:
            continue
        if label in _DIPHTHONGS:
            mid = 0.5 * (start + end)
            a, b = _DIPHTHONGS[label]
            out += [(start, mid, a), (mid, end, b)]
        else:
            out.append((start, end, phone_class(label)))
    return out


def _critically_damped(x: np.ndarray, tau: float, rate: float) -> np.ndarray:
    """Zero-phase critically damped second-order low-pass (forward and backward)."""
    from scipy.signal import bilinear, filtfilt

    w = 1.0 / tau
    b, a = bilinear([w * w], [1.0, 2.0 * w, w * w], fs=rate)
    pad = min(len(x) - 1, int(6 * tau * rate))
    return filtfilt(b, a, x, padtype="constant", padlen=pad) if pad > 0 else x.copy()


def articulator_tracks(phones, duration: float, rate: float = INTERNAL_RATE) -> np.ndarray:
    """Articulator values at ``rate`` Hz from phone timings.

    Parameters
    ----------
    phones : iterable
        Objects with ``.label``, ``.start``, ``.end`` (seconds), or ``(label, start, end)`` rows.
    duration : float
        Seconds to cover.
    rate : float
        Rate of the tracks in Hz.

    Returns
    -------
    ndarray, shape (ceil(duration * rate) + 1, 5)
        Columns ``ARTICULATORS`` at times ``arange(n) / rate``.
    """
    segs = _segments(phones)
    n = int(np.ceil(duration * rate)) + 1
    t = np.arange(n) / rate
    out = np.zeros((n, len(ARTICULATORS)))
    if not segs:
        segs = [(0.0, duration, "pause")]
    starts = np.array([s[0] for s in segs])
    ends = np.array([s[1] for s in segs])
    # distance of each time to each segment (0 inside)
    dist = np.maximum(0.0, np.maximum(starts[None, :] - t[:, None], t[:, None] - ends[None, :]))
    for k, art in enumerate(ARTICULATORS):
        targ = np.array([_CLASSES[c].get(art, (0.0, 0.3))[0] for _, _, c in segs])
        dom = np.array([_CLASSES[c].get(art, (0.0, 0.3))[1] for _, _, c in segs])
        w = dom[None, :] * np.exp(-(dist / _TAU[art]) ** 2)
        raw = (w @ targ) / np.maximum(w.sum(axis=1), 1e-300)
        out[:, k] = _critically_damped(raw, _MUSCLE, rate)
    return out


# lip geometry, in units of the inter-ocular distance
_GAP_JAW, _GAP_LIPS, _GAP_SOFT = 0.18, 0.15, 0.008


def lip_gap(jaw: np.ndarray, lips: np.ndarray) -> np.ndarray:
    """Inner-lip gap (inter-ocular units): jaw and lip efforts add, contact clips at zero.

    Parameters
    ----------
    jaw, lips : ndarray, shape (T,)
        Jaw opening and lip aperture efforts (0..1).

    Returns
    -------
    ndarray, shape (T,)
    """
    z = (_GAP_JAW * jaw + _GAP_LIPS * lips) / _GAP_SOFT
    return _GAP_SOFT * np.logaddexp(0.0, z)


def _face_frame(neutral: np.ndarray):
    """Centre, unit axes (u along the eyes, v down the face) and inter-ocular distance."""
    a, b = face_layout.OUTER_EYE_CORNERS
    d = float(np.linalg.norm(neutral[b] - neutral[a]))
    u = (neutral[b] - neutral[a]) / d
    v = np.array([-u[1], u[0]])
    if v @ (neutral[8] - neutral[27]) < 0:
        v = -v
    return neutral.mean(axis=0), u, v, d


def deform(neutral: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Landmarks of the face with articulator parameters applied (no head pose).

    Parameters
    ----------
    neutral : ndarray, shape (68, 2)
        The face at rest (mouth closed), pixel coordinates.
    params : ndarray, shape (T, len(PARAM_NAMES))

    Returns
    -------
    ndarray, shape (T, 68, 2)
    """
    c, u, v, d = _face_frame(neutral)
    local = np.stack([(neutral - c) @ u, (neutral - c) @ v], axis=1) / d  # (68, 2)
    P = dict(zip(PARAM_NAMES, np.asarray(params, dtype=np.float64).T))
    T = len(params)
    du = np.zeros((T, 68))
    dv = np.zeros((T, 68))
    g0 = float(np.linalg.norm(local[66] - local[62]))
    dg = P["gap"] - g0
    lower_in, lower_out = [65, 66, 67], [55, 56, 57, 58, 59]
    upper_in, upper_out = [61, 62, 63], [49, 50, 51, 52, 53]
    corners = [48, 54, 60, 64]
    dv[:, lower_in] += 0.75 * dg[:, None]
    dv[:, lower_out] += 0.75 * dg[:, None] - 0.05 * P["labiodental"][:, None]
    dv[:, upper_in] -= 0.25 * dg[:, None]
    dv[:, upper_out] -= 0.2 * dg[:, None]
    dv[:, corners] += (0.3 * dg - 0.025 * P["spread"])[:, None]
    # rounding protrudes the lips: the outline grows rounder (top and bottom outward)
    dv[:, [50, 51, 52]] -= 0.02 * P["round"][:, None]
    dv[:, [56, 57, 58]] += 0.02 * P["round"][:, None]
    # jaw: points below the pivot (ear level) drop with the chin
    pivot = local[[0, 16], 1].mean()
    reach = np.clip((local[0:17, 1] - pivot) / max(local[8, 1] - pivot, 1e-9), 0.0, 1.0)
    dv[:, 0:17] += (0.16 * P["jaw"])[:, None] * reach[None, :] ** 1.5
    # mouth width: spreading widens, rounding narrows, about the mouth centre
    mouth = np.arange(48, 68)
    mu = local[mouth, 0].mean()
    scale = 0.12 * P["spread"] - 0.22 * P["round"]
    du[:, mouth] += scale[:, None] * (local[mouth, 0] - mu)[None, :]
    # brows rise with prosody
    brow_w = np.array([0.6, 0.9, 1.0, 1.0, 0.8, 0.8, 1.0, 1.0, 0.9, 0.6])
    dv[:, 17:27] -= 0.09 * P["brows"][:, None] * brow_w[None, :]
    # blinks: upper lids meet the lower lids
    blink = P["blink"][:, None]
    for upper, lower in (([37, 38], [41, 40]), ([43, 44], [47, 46])):
        gap = local[lower, 1] - local[upper, 1]
        dv[:, upper] += 0.85 * blink * gap[None, :]
        dv[:, lower] -= 0.15 * blink * gap[None, :]
    loc = local[None] + np.stack([du, dv], axis=2)
    return c + d * (loc[..., :1] * u + loc[..., 1:] * v)


@dataclass
class Articulation:
    """Ground-truth motion of the performer.

    Parameters
    ----------
    points : ndarray, shape (T, 68, 2)
        Landmarks in pixel coordinates of the video (x, y), head pose applied.
    fps : float
        Video frame rate.
    params : ndarray, shape (T, 8)
        Per-frame parameters, columns ``PARAM_NAMES``: articulators (0..1 efforts), ``gap``
        (inner-lip gap in inter-ocular units), ``brows`` and ``blink`` (0..1).
    pose : ndarray, shape (T, 4)
        Head pose: rotation (rad), scale, x and y translation (px) about ``centre``.
    centre : ndarray, shape (2,)
        The centre of the head pose's rotation and scaling (px); :func:`articulate` takes the
        mean of the neutral landmarks.
    neutral : ndarray, shape (68, 2)
        The face at rest, in pixel coordinates.

    Notes
    -----
    Each parameter is kept as the attribute of the same name.
    """
    points: np.ndarray
    fps: float
    params: np.ndarray
    pose: np.ndarray
    centre: np.ndarray
    neutral: np.ndarray

    @property
    def n_frames(self) -> int:
        """Frames T."""
        return len(self.points)

    def param(self, name: str) -> np.ndarray:
        """One column of :attr:`params`.

        Parameters
        ----------
        name : str
            One of ``PARAM_NAMES``.

        Returns
        -------
        ndarray, shape (T,)
        """
        return self.params[:, PARAM_NAMES.index(name)]


def _prosody(samples: np.ndarray, rate: int, fps: float, n: int) -> np.ndarray:
    """Brow raise 0..1 per frame from the energy and F0 of the audio."""
    x = np.asarray(samples, dtype=np.float64)
    centres = (np.arange(n) / fps * rate).astype(int)
    half = int(0.02 * rate)
    energy = np.array([np.sqrt(np.mean(x[max(0, c - half):c + half] ** 2) + 1e-12) for c in centres])
    edb = 20.0 * np.log10(energy + 1e-6)
    loud = np.clip((edb - (edb.max() - 35.0)) / 35.0, 0.0, 1.0)
    f0, _ = pitch_frames(x, rate, fps, n)
    voiced = np.isfinite(f0)
    high = np.zeros(n)
    if voiced.sum() > 3:
        semis = 12.0 * np.log2(f0[voiced] / np.median(f0[voiced]))
        high[voiced] = np.clip(semis / 4.0, 0.0, 1.0)
    raw = 0.6 * high + 0.4 * loud ** 2
    return np.clip(_critically_damped(raw, 0.12, fps), 0.0, 1.0)


def _blinks(n: int, fps: float, rng: np.random.Generator) -> np.ndarray:
    """Blink closure 0..1 per frame: Poisson onsets (mean 3.5 s apart, at least 1.2 s)."""
    t = np.arange(n) / fps
    out = np.zeros(n)
    onset = rng.uniform(0.3, 2.5)
    while onset < t[-1] if n else False:
        close, hold, reopen = 0.08, 0.04, 0.16
        s = t - onset
        a = np.where(s < 0, 0.0, np.where(s < close, 0.5 - 0.5 * np.cos(np.pi * s / close),
                     np.where(s < close + hold, 1.0,
                              np.where(s < close + hold + reopen,
                                       0.5 + 0.5 * np.cos(np.pi * (s - close - hold) / reopen), 0.0))))
        out = np.maximum(out, a)
        onset += 1.2 + rng.exponential(2.3)
    return out


def _head_pose(n: int, fps: float, loud: np.ndarray, d: float, rng: np.random.Generator):
    """Small smooth similarity motion: sums of slow sinusoids plus a nod with the speech."""
    t = np.arange(n) / fps

    def wander(amp):
        f = rng.uniform(0.05, 0.4, size=3)
        ph = rng.uniform(0, 2 * np.pi, size=3)
        w = rng.uniform(0.5, 1.0, size=3)
        return amp * (np.sin(2 * np.pi * f[:, None] * t[None] + ph[:, None]) * w[:, None]).sum(0) / w.sum()

    angle = wander(np.deg2rad(2.0))
    scale = 1.0 + wander(0.01)
    tx = wander(0.03 * d)
    ty = wander(0.02 * d) + 0.02 * d * loud
    return np.stack([angle, scale, tx, ty], axis=1)


def apply_pose(points: np.ndarray, pose: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Similarity transform per frame: ``s R (p - centre) + centre + t``.

    Parameters
    ----------
    points : ndarray, shape (T, P, 2)
    pose : ndarray, shape (T, 4)
        Rotation (rad), scale, x and y translation (px) per frame.
    centre : ndarray, shape (2,)

    Returns
    -------
    ndarray, shape (T, P, 2)
    """
    ang, s, tx, ty = pose.T
    cs, sn = np.cos(ang) * s, np.sin(ang) * s
    p = points - centre
    x = cs[:, None] * p[..., 0] - sn[:, None] * p[..., 1]
    y = sn[:, None] * p[..., 0] + cs[:, None] * p[..., 1]
    return np.stack([x + centre[0] + tx[:, None], y + centre[1] + ty[:, None]], axis=-1)


def articulate(phones, samples: np.ndarray, rate: int, neutral: np.ndarray, *,
               fps: float = 30000 / 1001, n_frames: int | None = None, seed: int = 0,
               head_motion: bool = True, blinks: bool = True) -> Articulation:
    """Ground-truth facial motion for speech with phone timings.

    Parameters
    ----------
    phones : list of Phone or (label, start, end)
    samples : ndarray, shape (n,)
        The speech (drives brows and head nods).
    rate : int
        Sample rate of ``samples``.
    neutral : ndarray, shape (68, 2)
        The face at rest in video pixel coordinates.
    fps : float
        Video frame rate (default 29.97).
    n_frames : int, optional
        Default ``round(duration * fps)``.
    seed : int
        Seeds blinks and head motion.
    head_motion : bool
        Move the head by a small smooth similarity transform (default ``True``); without it the
        pose is the identity in every frame.
    blinks : bool
        Blink at seeded random times (default ``True``); without it the ``blink`` parameter is 0.

    Returns
    -------
    Articulation
        The motion, one row per video frame.

    Raises
    ------
    ValueError
        ``fps`` is not a positive number, ``neutral`` is not finite landmarks of shape (68, 2),
        or the speech lasts less than two frames.
    """
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number of frames per second, got {fps}")
    neutral = np.asarray(neutral, dtype=np.float64)
    if neutral.shape != (face_layout.N_POINTS, 2) or not np.isfinite(neutral).all():
        raise ValueError(f"neutral must be finite landmarks of shape (68, 2), got {neutral.shape}")
    samples = np.asarray(samples)
    duration = len(samples) / float(rate)
    n = int(round(duration * fps)) if n_frames is None else int(n_frames)
    if n < 2:
        raise ValueError(f"the speech must last at least two frames ({2 / fps:.3f} s at {fps} fps), "
                         f"got {duration:.3f} s")
    rng = np.random.default_rng(seed)
    tracks = articulator_tracks(phones, max(duration, n / fps), INTERNAL_RATE)
    tf = np.arange(n) / fps
    ti = np.arange(len(tracks)) / INTERNAL_RATE
    art = np.stack([np.interp(tf, ti, tracks[:, k]) for k in range(tracks.shape[1])], axis=1)
    gap = lip_gap(art[:, 0], art[:, 1])
    brows = _prosody(samples, rate, fps, n)
    blink = _blinks(n, fps, rng) if blinks else np.zeros(n)
    params = np.column_stack([art, gap, brows, blink])
    local = deform(neutral, params)
    c, _, _, d = _face_frame(neutral)
    pose = _head_pose(n, fps, brows, d, rng) if head_motion else np.tile([0.0, 1.0, 0.0, 0.0], (n, 1))
    points = apply_pose(local, pose, c)
    return Articulation(points, float(fps), params, pose, c, neutral)
