"""Phone labels for the phoneme-driven models: the phone set, label files and frame labels.

The phone set (:data:`PHONES`) is explicit: the 39 ARPAbet phonemes of the CMU dictionary plus
silence (``SIL``) and breath (``BR``), 41 labels as in Englebienne et al. (2007, §3). Labels from
other alphabets are mapped onto it by :func:`to_phone`: ARPAbet with stress digits and the TIMIT
extras (``ax``, ``dx``, closures ...), and espeak-ng's English mnemonics (the synthetic
performer's ground truth). Upper-case ``D``, ``T``, ``S``, ``Z``, ``N`` mean different phones in
the two alphabets, so the alphabet is always named.

Frames: phones are sampled every 10 ms and each video frame takes the phone of most of the 10 ms
frames whose centres fall inside it (§2 of the paper), :func:`frame_labels`.

Files: Praat TextGrids (:func:`read_textgrid`, :func:`write_textgrid`, through praatio) and HTS
label files (:func:`read_hts`, :func:`write_hts`; mono or full-context, 100 ns units).
Forced alignment of speech to a transcript with pocketsphinx lives in :func:`align`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from fractions import Fraction
from typing import Iterable, Sequence

import numpy as np

from voicepuppet._files import atomic_path

__all__ = ["PHONES", "SIL", "BREATH", "N_PHONES", "PHONE_INDEX", "Segment", "to_phone",
           "normalize", "segments", "frame_labels", "read_textgrid", "write_textgrid", "read_hts",
           "write_hts", "label_intervals", "align", "AlignmentError"]

#: vowels of ARPAbet (stress digits removed)
_VOWELS = "AA AE AH AO AW AY EH ER EY IH IY OW OY UH UW".split()
#: consonants of ARPAbet
_CONSONANTS = "B CH D DH F G HH JH K L M N NG P R S SH T TH V W Y Z ZH".split()
#: silence and breath labels of the phone set
SIL, BREATH = "SIL", "BR"
#: the phone set: silence, breath, then the 39 ARPAbet phonemes (41 labels)
PHONES: tuple = (SIL, BREATH, *_VOWELS, *_CONSONANTS)
N_PHONES = len(PHONES)
#: phone -> index into PHONES
PHONE_INDEX = {p: i for i, p in enumerate(PHONES)}

_SILENCES = {"sil", "pau", "sp", "spn", "h#", "epi", "pause", "silence", "", "<sil>", "_"}
_BREATHS = {"br", "breath", "brth", "inhale", "exhale", "+breath+", "[breath]"}

# TIMIT / Buckeye extras onto ARPAbet (lower case keys)
_ARPA_EXTRA = {"ax": "AH", "ax-h": "AH", "ix": "IH", "axr": "ER", "ux": "UW", "dx": "D", "nx": "N",
               "en": "N", "em": "M", "el": "L", "eng": "NG", "hv": "HH", "q": "T", "pcl": "P",
               "tcl": "T", "kcl": "K", "bcl": "B", "dcl": "D", "gcl": "G"}

# espeak-ng English phoneme mnemonics (en-us, en-gb and variants) onto ARPAbet
_ESPEAK = {
    "p": "P", "b": "B", "t": "T", "d": "D", "k": "K", "g": "G", "f": "F", "v": "V", "T": "TH",
    "D": "DH", "s": "S", "z": "Z", "S": "SH", "Z": "ZH", "tS": "CH", "dZ": "JH", "h": "HH",
    "m": "M", "n": "N", "N": "NG", "l": "L", "r": "R", "w": "W", "j": "Y", "x": "K", "?": "T",
    "t#": "T", "d#": "D", "t[": "T", "d[": "D", "*": "D", "r-": "R", "l/": "L", "n-": "N",
    "w#": "W", "l^": "L", "n^": "N", "z/": "Z", "s/": "S", "@L": "L",
    "a": "AE", "a#": "AH", "aa": "AE", "A": "AA", "A:": "AA", "A@": "AA", "0": "AA", "0#": "AA",
    "V": "AH", "VR": "ER", "@": "AH", "@#": "AH", "3": "ER", "3:": "ER", "e": "EH", "E": "EH",
    "E@": "EH", "e@": "EH", "e#": "EH", "eI": "EY", "i": "IY", "i:": "IY", "i@": "IY", "I": "IH",
    "I#": "IH", "IR": "ER", "aI": "AY", "aI@": "AY", "aU": "AW", "aU@": "AW", "O": "AO",
    "O:": "AO", "O@": "AO", "o@": "AO", "OI": "OY", "oU": "OW", "o": "OW", "u": "UW", "u:": "UW",
    "U": "UH", "U@": "UH", "_:": SIL, "_!": SIL, "_|": SIL, "_": SIL,
}
# espeak-ng modifiers that arrive as their own phoneme event: merged into the previous phone
_ESPEAK_MODIFIERS = {";", ",", "'", ":", "-"}

_ALPHABETS = ("arpabet", "espeak")


@dataclass(frozen=True)
class Segment:
    """One phone ``label`` (of :data:`PHONES`) from ``start`` to ``end`` seconds.

    Parameters
    ----------
    label : str
        The phone, one of :data:`PHONES`.
    start, end : float
        Start and end of the segment, in seconds.

    Notes
    -----
    Each parameter is kept as the attribute of the same name (the dataclass is frozen).
    """
    label: str
    start: float
    end: float


def _check_alphabet(alphabet: str) -> str:
    if alphabet not in _ALPHABETS:
        raise ValueError(f"alphabet must be one of {_ALPHABETS}, got {alphabet!r}")
    return alphabet


def to_phone(label: str, alphabet: str = "arpabet") -> str:
    """Map one label to the phone set.

    Parameters
    ----------
    label : str
        A phone label: ARPAbet (any case, stress digits allowed; TIMIT extras such as ``ax``,
        ``dx``, ``pcl``), a silence (``sil``, ``pau``, ``sp``, ``h#``, ``_``) or breath (``br``)
        label, or an espeak-ng English mnemonic when ``alphabet="espeak"``.
    alphabet : {"arpabet", "espeak"}

    Returns
    -------
    str
        One of :data:`PHONES`.

    Raises
    ------
    ValueError
        The label is not a phone of that alphabet (the message lists the phone set).
    """
    _check_alphabet(alphabet)
    if not isinstance(label, str):
        raise ValueError(f"phone labels must be strings, got {type(label).__name__} {label!r}")
    lab = label.strip()
    low = lab.lower()
    if low in _SILENCES or lab.startswith("_"):
        return SIL
    if low in _BREATHS:
        return BREATH
    if alphabet == "espeak":
        for key in (lab, lab.rstrip("0123456789"), lab.rstrip("0123456789;[#")):
            if key in _ESPEAK:
                return _ESPEAK[key]
    else:
        up = re.sub(r"[0-9]+$", "", lab).upper()
        if up in PHONE_INDEX:
            return up
        if low in _ARPA_EXTRA:
            return _ARPA_EXTRA[low]
    raise ValueError(f"unknown {alphabet} phone {label!r}; the phone set is {' '.join(PHONES)} "
                     f"(silence: sil/pau/sp/_, breath: br); map or remove it first")


def _rows(items) -> list[tuple[str, float, float]]:
    out = []
    for it in items:
        if hasattr(it, "label"):
            out.append((it.label, float(it.start), float(it.end)))
        else:
            try:
                a, b, c = it
            except (TypeError, ValueError):
                raise ValueError(f"a phone must be (label, start, end) or have .label/.start/.end, "
                                 f"got {it!r}") from None
            # accept (label, start, end) and (start, end, label)
            out.append((str(a), float(b), float(c)) if isinstance(a, str) else (str(c), float(a), float(b)))
    return out


def normalize(items: Iterable, alphabet: str = "arpabet") -> list[Segment]:
    """Phones as :class:`Segment` rows of the phone set, in time order.

    Adjacent equal phones are merged; espeak-ng modifier events (``;``) are merged into the
    phone before them; zero-length phones are dropped.

    Parameters
    ----------
    items : iterable
        ``(label, start, end)`` or ``(start, end, label)`` rows (seconds), or objects with
        ``.label``, ``.start``, ``.end`` (e.g. ``voicepuppet.synth.Phone``).
    alphabet : {"arpabet", "espeak"}

    Returns
    -------
    list of Segment

    Raises
    ------
    ValueError
        Unknown phones, non-finite or negative times, ``end < start``, or overlapping phones.
    """
    _check_alphabet(alphabet)
    rows = sorted(_rows(items), key=lambda r: (r[1], r[2]))
    out: list[Segment] = []
    for label, start, end in rows:
        if not (np.isfinite(start) and np.isfinite(end)) or start < 0 or end < start:
            raise ValueError(f"phone {label!r} has bad times start={start}, end={end}: need "
                             f"0 <= start <= end (seconds)")
        if end - start <= 1e-9:
            continue
        if out and start < out[-1].end - 1e-6:
            raise ValueError(f"phones overlap: {out[-1]} and {label!r} from {start:.3f} s; phone "
                             f"labels must be one tier of consecutive intervals")
        if alphabet == "espeak" and label.strip() in _ESPEAK_MODIFIERS:
            if out:
                out[-1] = Segment(out[-1].label, out[-1].start, end)
            continue
        phone = to_phone(label, alphabet)
        if out and out[-1].label == phone and start <= out[-1].end + 1e-6:
            out[-1] = Segment(phone, out[-1].start, end)
        else:
            out.append(Segment(phone, start, end))
    return out


segments = normalize  # the same, by the name of what it returns


def frame_labels(items, n_frames: int, fps: float, *, alphabet: str = "arpabet",
                 step: float = 0.01, tolerance: float | None = None) -> np.ndarray:
    """Label each video frame with the phone of most of its 10 ms sound frames (§2).

    The phones are sampled at the centres of ``step``-second sound frames; video frame ``t``
    covers ``[t / fps, (t + 1) / fps)`` and takes the phone that labels most of the sound frames
    whose centres fall inside it (ties: the earliest). A video frame that holds no sound-frame
    centre (``fps > 1 / step``) takes the phone at its own centre. Gaps between phones are
    silence.

    Parameters
    ----------
    items : iterable
        Phones, as accepted by :func:`normalize`.
    n_frames : int
        Number of video frames ``T`` (> 0).
    fps : float
        Video frame rate.
    alphabet : {"arpabet", "espeak"}
    step : float
        Sound frame period in seconds (10 ms).
    tolerance : float, optional
        How far (seconds) the phones may stop short of the end of the video, default one video
        frame.

    Returns
    -------
    ndarray of int64, shape (T,)
        Indices into :data:`PHONES`.

    Raises
    ------
    ValueError
        No phones, phones that do not cover the video (the message says where they end),
        bad ``n_frames``, ``fps`` or ``step``.
    """
    if int(n_frames) != n_frames or n_frames <= 0:
        raise ValueError(f"n_frames must be a positive integer, got {n_frames}")
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if not np.isfinite(step) or not 0 < step <= 0.1:
        raise ValueError(f"step must be in (0, 0.1] seconds, got {step}")
    segs = normalize(items, alphabet)
    if not segs:
        raise ValueError("no phones given (all empty or zero-length); cannot label the frames")
    n_frames = int(n_frames)
    duration = n_frames / float(fps)
    tol = 1.0 / fps if tolerance is None else float(tolerance)
    if segs[-1].end < duration - tol:
        raise ValueError(f"the phone labels end at {segs[-1].end:.3f} s but the video lasts "
                         f"{duration:.3f} s ({n_frames} frames at {fps:g} fps); the labels must cover "
                         f"the audio: re-align or trim the video")
    if segs[0].start > tol:
        raise ValueError(f"the phone labels start at {segs[0].start:.3f} s, not at 0; label the "
                         f"leading part (e.g. as silence) or trim the video")
    starts = np.array([s.start for s in segs])
    ends = np.array([s.end for s in segs])
    ids = np.array([PHONE_INDEX[s.label] for s in segs], dtype=np.int64)

    def phone_at(times):
        k = np.searchsorted(starts, times, side="right") - 1
        k = np.clip(k, 0, len(segs) - 1)
        inside = (times >= starts[k]) & (times < ends[k])
        # past the last phone (within tolerance): keep the last phone; gaps: silence
        return np.where(inside | (times >= ends[-1]), ids[k], PHONE_INDEX[SIL])

    n_sound = int(np.ceil(duration / step))
    centres = (np.arange(n_sound) + 0.5) * step
    sound = phone_at(centres)
    owner = np.minimum((centres * fps).astype(np.int64), n_frames - 1)
    counts = np.zeros((n_frames, N_PHONES), dtype=np.int64)
    np.add.at(counts, (owner, sound), 1)
    out = np.argmax(counts, axis=1)
    # ties broken by the earliest phone in time
    best = counts.max(axis=1)
    tied = np.nonzero((counts == best[:, None]).sum(axis=1) > 1)[0]
    for t in tied:
        if best[t] == 0:
            continue
        cand = set(np.nonzero(counts[t] == best[t])[0].tolist())
        for p in sound[owner == t]:
            if int(p) in cand:
                out[t] = p
                break
    empty = best == 0
    if np.any(empty):
        out[empty] = phone_at((np.nonzero(empty)[0] + 0.5) / fps)
    return out.astype(np.int64)


def label_intervals(labels: Sequence[int], fps: float) -> list[Segment]:
    """Frame labels back to phone segments (runs of equal labels), e.g. to write them out.

    Parameters
    ----------
    labels : array_like of int, shape (T,)
        Indices into :data:`PHONES`.
    fps : float

    Returns
    -------
    list of Segment

    Raises
    ------
    ValueError
        Labels that are not a non-empty 1-D integer array indexing :data:`PHONES`, a bad ``fps``.
    """
    lab = np.asarray(labels)
    if lab.ndim != 1 or lab.size == 0 or not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels must be a non-empty 1-D integer array, got shape {lab.shape}, "
                         f"dtype {lab.dtype}")
    if lab.min() < 0 or lab.max() >= N_PHONES:
        raise ValueError(f"labels must index PHONES (0..{N_PHONES - 1}), got {lab.min()}..{lab.max()}")
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    cut = np.nonzero(np.diff(lab))[0] + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [lab.size]])
    return [Segment(PHONES[int(lab[a])], a / fps, b / fps) for a, b in zip(starts, ends)]


# --------------------------------------------------------------------------------------------
# files


def read_textgrid(path, tier: str | None = None, alphabet: str = "arpabet") -> list[Segment]:
    """Phones from a Praat TextGrid interval tier (read with praatio).

    Parameters
    ----------
    path : str or os.PathLike
    tier : str, optional
        Tier name; default the tier named ``phones``/``phone``/``phonemes`` or, failing that,
        the only interval tier.
    alphabet : {"arpabet", "espeak"}

    Returns
    -------
    list of Segment
        Empty intervals are silence.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a readable TextGrid, no such tier or no way to tell which holds the phones, a point
        tier, unknown phones.
    """
    from praatio import textgrid

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"TextGrid {path!r} does not exist")
    try:
        tg = textgrid.openTextgrid(path, includeEmptyIntervals=True)
    except Exception as exc:  # praatio raises a variety of parse errors
        raise ValueError(f"{path!r} is not a readable Praat TextGrid: {exc}") from None
    names = list(tg.tierNames)
    if tier is None:
        interval = [n for n in names if tg.getTier(n).tierType == textgrid.INTERVAL_TIER]
        named = [n for n in interval if n.lower() in ("phones", "phone", "phonemes", "phoneme")]
        if named:
            tier = named[0]
        elif len(interval) == 1:
            tier = interval[0]
        else:
            raise ValueError(f"{path!r} has interval tiers {interval}; say which holds the phones "
                             f"(tier=...)")
    if tier not in names:
        raise ValueError(f"{path!r} has no tier {tier!r}; it has {names}")
    t = tg.getTier(tier)
    if t.tierType != textgrid.INTERVAL_TIER:
        raise ValueError(f"tier {tier!r} of {path!r} is a point tier; phones need an interval tier")
    return normalize([(e.label, e.start, e.end) for e in t.entries], alphabet)


def write_textgrid(items, path, tier: str = "phones", alphabet: str = "arpabet") -> None:
    """Write phones as a Praat TextGrid (long format) with one interval tier, atomically.

    Parameters
    ----------
    items : iterable
        Phones, as accepted by :func:`normalize` (written as phone-set labels).
    path : str or os.PathLike
        Output ``.TextGrid`` path.
    tier : str
    alphabet : {"arpabet", "espeak"}
        Alphabet of ``items``.

    Raises
    ------
    ValueError
        No phones, or a path that cannot be written.
    """
    from praatio import textgrid

    segs = normalize(items, alphabet)
    if not segs:
        raise ValueError("no phones to write")
    end = segs[-1].end
    tg = textgrid.Textgrid()
    tg.addTier(textgrid.IntervalTier(tier, [(s.start, s.end, s.label) for s in segs], 0.0, end))
    with atomic_path(path, (".TextGrid", ".textgrid"), "TextGrid") as tmp:
        tg.save(str(tmp), format="long_textgrid", includeBlankSpaces=True)


_HTS_PHONE = re.compile(r"-([^+]+)\+")


def read_hts(path, alphabet: str = "arpabet") -> list[Segment]:
    """Phones from an HTS label file (``start end label`` per line, 100 ns units).

    Mono labels (``sil``) and full-context labels (``x^y-PHONE+z=...``) are both read.

    Parameters
    ----------
    path : str or os.PathLike
    alphabet : {"arpabet", "espeak"}

    Returns
    -------
    list of Segment

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Malformed lines, no labels, unknown phones.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"HTS label file {path!r} does not exist")
    rows = []
    with open(path, encoding="utf-8") as fh:
        for i, line in enumerate(fh, 1):
            parts = line.split()
            if not parts:
                continue
            if len(parts) < 3:
                raise ValueError(f"{path}:{i}: an HTS label line is 'start end label' (100 ns units), "
                                 f"got {line.strip()!r}")
            try:
                start, end = int(parts[0]), int(parts[1])
            except ValueError:
                raise ValueError(f"{path}:{i}: start and end must be integers (100 ns units), got "
                                 f"{parts[0]!r} {parts[1]!r}") from None
            m = _HTS_PHONE.search(parts[2])
            rows.append((m.group(1) if m else parts[2], start / 1e7, end / 1e7))
    if not rows:
        raise ValueError(f"{path!r} holds no labels")
    return normalize(rows, alphabet)


def write_hts(items, path, alphabet: str = "arpabet") -> None:
    """Write phones as a mono HTS label file (lower-case labels, 100 ns units), atomically.

    Parameters
    ----------
    items : iterable
        Phones, as accepted by :func:`normalize`.
    path : str or os.PathLike
        Output ``.lab`` path.
    alphabet : {"arpabet", "espeak"}
        Alphabet of ``items``.

    Raises
    ------
    ValueError
        No phones, or a path that cannot be written.
    """
    segs = normalize(items, alphabet)
    if not segs:
        raise ValueError("no phones to write")
    lines = [f"{int(round(s.start * 1e7))} {int(round(s.end * 1e7))} "
             f"{'sil' if s.label == SIL else s.label.lower()}\n" for s in segs]
    with atomic_path(path, None, "HTS label file") as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.writelines(lines)


# --------------------------------------------------------------------------------------------
# forced alignment


class AlignmentError(ValueError):
    """The transcript could not be aligned to the audio (the message says where it failed)."""


def align(audio, transcript: str | None = None, *, sample_rate: int | None = None,
          pronunciations: dict | None = None) -> list[Segment]:
    """Phone segments of speech by pocketsphinx (its bundled US English model).

    With a transcript: forced alignment of the words' dictionary pronunciations (10 ms
    resolution). Without: phone recognition with the English phonetic language model.

    Parameters
    ----------
    audio : str, os.PathLike or ndarray, shape (n,)
        A sound file, or mono samples (then ``sample_rate`` is required).
    transcript : str, optional
        The words spoken (letters, apostrophes; punctuation is ignored).
    sample_rate : int, optional
    pronunciations : dict, optional
        Words the model's dictionary lacks (names, old spellings): ``{"churl": "CH ER L"}``,
        ARPAbet phones without stress digits. A word the dictionary has gets this pronunciation
        as an alternative.

    Returns
    -------
    list of Segment
        Covering the whole audio (gaps are silence).

    Raises
    ------
    AlignmentError
        A word not in the dictionary, or a transcript that does not match the audio (the
        alignment fails or leaves words unaligned; the message says after which word).
    """
    pcm, duration = _pcm16k(audio, sample_rate)
    try:
        from pocketsphinx import Decoder
    except ImportError:  # pragma: no cover - a runtime dependency
        raise RuntimeError("forced alignment needs pocketsphinx: pip install pocketsphinx") from None

    def run(decoder):
        decoder.start_utt()
        decoder.process_raw(pcm, no_search=False, full_utt=True)
        decoder.end_utt()

    if transcript is None:
        from pocketsphinx import get_model_path

        decoder = Decoder(lm=None, allphone=os.path.join(get_model_path(), "en-us", "en-us-phone.lm.bin"),
                          loglevel="FATAL", backtrace=False, beam=1e-20, pbeam=1e-20, lw=2.0)
        run(decoder)
        rows = [(seg.word, seg.start_frame / 100.0, (seg.end_frame + 1) / 100.0) for seg in decoder.seg()]
        if not rows:
            raise AlignmentError("phone recognition found no speech in the audio")
    else:
        if not isinstance(transcript, str) or not transcript.strip():
            raise ValueError(f"transcript must be a non-empty string (or None to recognise phones), "
                             f"got {transcript!r}")
        words = _transcript_words(transcript)
        extra = _pronunciations(pronunciations)

        def make_decoder(**beams):
            dec = Decoder(lm=None, loglevel="FATAL", **beams)
            for word, phones in extra.items():
                dec.add_word(word, phones, True)
            return dec

        decoder = make_decoder()
        missing = [w for w in words if decoder.lookup_word(w) is None]
        if missing:
            raise AlignmentError(f"words not in the pronunciation dictionary: {', '.join(missing)}; "
                                 f"spell them as dictionary words or give their phones (pronunciations=, "
                                 f"or --pronounce WORD='PH PH ...' on the command line)")

        def word_pass(dec):
            dec.set_align_text(" ".join(words))
            run(dec)
            hyp = dec.hyp()
            got = [] if hyp is None else [s.word for s in (dec.seg() or [])
                                          if not s.word.startswith(("<", "["))]
            return hyp, [re.sub(r"\(\d+\)$", "", w) for w in got]

        hyp, got = word_pass(decoder)
        if hyp is None or got != words:
            # default beams prune the only path on some voices (e.g. synthetic speech): retry wide
            decoder = make_decoder(beam=1e-80, wbeam=1e-60, pbeam=1e-80)
            hyp, got = word_pass(decoder)
        if hyp is None or got != words:
            done = 0
            while done < min(len(got), len(words)) and got[done] == words[done]:
                done += 1
            where = (f"after word {done} ({words[done - 1]!r}) of {len(words)}" if done else
                     f"with no path through the {len(words)} words from the start of the audio to its end")
            raise AlignmentError(f"the transcript does not match the audio: alignment failed {where}; "
                                 f"check the transcript and the audio")
        decoder.set_alignment()
        run(decoder)
        alignment = decoder.get_alignment()
        if alignment is None:
            raise AlignmentError(f"the transcript does not match the audio: the phone alignment of the "
                                 f"{len(words)} words failed; check the transcript and the audio")
        rows = []
        for word in alignment:
            for phone in word:
                rows.append((phone.name, phone.start / 100.0, (phone.start + phone.duration) / 100.0))
    rows = [(lab, a, min(b, duration)) for lab, a, b in rows if a < duration]
    segs = normalize([(("sil" if lab.upper() in ("SIL", "+NSN+", "+SPN+") or lab.startswith(("<", "["))
                        else "br" if lab.upper() == "+BREATH+" else lab), a, b) for lab, a, b in rows
                      if b > a])
    # fill gaps (and the tail) with silence so the segments cover the audio
    out: list[Segment] = []
    t = 0.0
    for sg in segs:
        if sg.start > t + 1e-6:
            out.append(Segment(SIL, t, sg.start))
        out.append(sg)
        t = sg.end
    if duration > t + 1e-6:
        out.append(Segment(SIL, t, duration))
    return normalize(out)


def _pronunciations(given) -> dict:
    """``{word: "PH PH ..."}`` checked against pocketsphinx's US English phone set."""
    if not given:
        return {}
    if not isinstance(given, dict):
        raise ValueError(f"pronunciations must be a dict {{word: 'PH PH ...'}}, got {type(given).__name__}")
    out = {}
    for word, phones in given.items():
        w = str(word).strip().lower()
        ph = str(phones).split() if isinstance(phones, str) else [str(p) for p in phones]
        bad = [p for p in ph if p.upper() not in PHONE_INDEX or p.upper() in (SIL, BREATH)]
        if not re.fullmatch(r"[a-z0-9']+", w) or not ph or bad:
            raise ValueError(f"pronunciation of {word!r}: expected a word (letters, digits, apostrophes) "
                             f"and ARPAbet phones without stress digits from {' '.join(PHONES[2:])}; "
                             f"got {phones!r}" + (f" ({', '.join(bad)} not phones)" if bad else ""))
        out[w] = " ".join(p.upper() for p in ph)
    return out


def _transcript_words(text: str) -> list[str]:
    words = re.findall(r"[a-z0-9']+", text.lower().replace("-", " "))
    if not words:
        raise ValueError(f"the transcript {text!r} holds no words")
    return words


def _pcm16k(audio, sample_rate):
    """16 kHz mono int16 bytes of a file or sample array, and the duration in seconds."""
    from scipy.signal import resample_poly

    if isinstance(audio, (str, os.PathLike)):
        import soundfile

        path = os.fspath(audio)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"audio file {path!r} does not exist")
        try:
            x, rate = soundfile.read(path, dtype="float64", always_2d=True)
        except RuntimeError as exc:
            raise ValueError(f"cannot read {path!r} as a sound file: {exc}") from None
        x = x.mean(axis=1)
    else:
        if sample_rate is None:
            raise ValueError("sample_rate is required when audio is an array of samples")
        x = np.asarray(audio, dtype=np.float64)
        rate = int(sample_rate)
        if x.ndim != 1:
            raise ValueError(f"audio samples must be mono (1-D), got shape {x.shape}")
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError("the audio is empty or holds NaN/infinite samples")
    if rate <= 0:
        raise ValueError(f"sample_rate must be positive, got {rate}")
    duration = x.size / float(rate)
    if rate != 16000:
        f = Fraction(16000, int(rate))
        x = resample_poly(x, f.numerator, f.denominator)
    pcm = (np.clip(x, -1.0, 1.0) * 32767).astype("<i2").tobytes()
    return pcm, duration
