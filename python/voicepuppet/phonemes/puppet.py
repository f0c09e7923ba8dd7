"""A phoneme-driven puppet: one of the phoneme-driven models with its face space, from phones
(or speech and its transcript) to landmarks; trained, saved and loaded as a file.
"""

from __future__ import annotations

import json
import os

import numpy as np

from voicepuppet._files import atomic_path, read_npz
from voicepuppet.animation import Animation
from voicepuppet.face import FaceSpace
from voicepuppet.phonemes.base import check_labels
from voicepuppet.phonemes.labels import align, frame_labels, normalize
from voicepuppet.phonemes.models import MODELS

__all__ = ["PhonemePuppet"]

_FILE_VERSION = 1


class PhonemePuppet:
    """A phoneme-driven face model with its face space: phones in, landmarks out.

    The users' counterpart of :class:`voicepuppet.puppet.model.Puppet` for the phoneme peers: train on
    landmark sequences with their phone labels, animate from phones (or from speech and its
    transcript, aligned by :func:`voicepuppet.phonemes.labels.align`), save and load.

    Parameters
    ----------
    model : PhonemeMeans, PhonemeTrajectory, SLDS or DPDS
        A trained model of face vectors.
    face_space : voicepuppet.face.FaceSpace
        The face space the model's vectors live in.
    fps : float
        Frame rate of the landmarks.

    Attributes
    ----------
    model : PhonemeMeans, PhonemeTrajectory, SLDS or DPDS
    face_space : voicepuppet.face.FaceSpace
    fps : float
    """

    def __init__(self, model, face_space, fps: float):
        self.model, self.face_space, self.fps = model, face_space, float(fps)

    @classmethod
    def train(cls, points_list, phones_list, *, fps: float = 29.97, model: str = "dpds",
              alphabet: str = "arpabet", n_components=0.98, progress: bool = False,
              **options) -> "PhonemePuppet":
        """Train on landmark sequences and their phones.

        Parameters
        ----------
        points_list : list of ndarray, each shape (T_s, P, 2)
            The landmark sequences (a single array is taken as one sequence).
        phones_list : list
            Per sequence: phone segments (as accepted by :func:`voicepuppet.phonemes.labels.normalize`)
            or frame labels (int array of shape (T_s,)).
        fps : float
            Frame rate of the landmarks.
        model : {"phoneme-mean", "brand-phoneme", "slds", "dpds"}
            The model (:data:`voicepuppet.phonemes.models.MODELS`; default ``"dpds"``).
        alphabet : {"arpabet", "espeak"}
            Alphabet of phone segments.
        n_components : int or float
            Face-space size (:meth:`voicepuppet.face.FaceSpace.fit`).
        progress : bool
            Show the model's progress bar while fitting, for the models that have one
            (default ``False``).
        **options
            Passed to the model's constructor.

        Returns
        -------
        PhonemePuppet
            The trained puppet.

        Raises
        ------
        ValueError
            An unknown model, a phone list missing for a landmark sequence, phones that do not
            cover their landmarks (see :func:`voicepuppet.phonemes.labels.frame_labels`).
        """
        if model not in MODELS:
            raise ValueError(f"model must be one of {list(MODELS)}, got {model!r}")
        if isinstance(points_list, np.ndarray):
            points_list = [points_list]
        if len(points_list) != len(phones_list):
            raise ValueError(f"give phones for every landmark sequence: {len(points_list)} sequences, "
                             f"{len(phones_list)} phone lists")
        fs = FaceSpace.fit(list(points_list), n_components=n_components)
        Y = [fs.encode(p)[0] for p in points_list]
        labels = [_frame_labels(ph, len(p), fps, alphabet) for ph, p in zip(phones_list, points_list)]
        m = MODELS[model](**options).fit(Y, labels, progress=progress)
        return cls(m, fs, fps)

    def animate(self, phones=None, *, audio=None, transcript: str | None = None,
                n_frames: int | None = None, alphabet: str = "arpabet"):
        """Landmarks for phones, or for speech (aligned to ``transcript`` by pocketsphinx).

        Parameters
        ----------
        phones : segments or int array (T,), optional
            Phone segments (seconds) or frame labels.
        audio : path or ndarray, optional
            Instead of ``phones``: speech to align (16 kHz mono samples or a sound file).
        transcript : str, optional
            The words of ``audio`` (phone recognition without it).
        n_frames : int, optional
            Frames to generate from segments (default: their duration times fps).
        alphabet : {"arpabet", "espeak"}

        Returns
        -------
        voicepuppet.animation.Animation
            Landmarks at the mean training pose, at the training frame rate.

        Raises
        ------
        ValueError
            Both or neither of ``phones`` and ``audio``, no phones.
        voicepuppet.phonemes.labels.AlignmentError
            The transcript does not align with the audio.
        """
        if (phones is None) == (audio is None):
            raise ValueError("give exactly one of phones or audio")
        if audio is not None:
            phones = align(audio, transcript, sample_rate=16000 if isinstance(audio, np.ndarray) else None)
            alphabet = "arpabet"
        lab = np.asarray(phones) if isinstance(phones, np.ndarray) else None
        if lab is None or lab.dtype.kind not in "iu":
            segs = normalize(phones, alphabet)
            if not segs:
                raise ValueError("no phones to animate")
            n = int(round(segs[-1].end * self.fps)) if n_frames is None else int(n_frames)
            lab = _frame_labels(segs, n, self.fps, "arpabet")
        Y = self.model.generate(lab)
        return Animation(self.face_space.decode(Y), self.fps)

    def save(self, path) -> None:
        """Write the puppet as ``.npz`` (atomically).

        Parameters
        ----------
        path : str or os.PathLike
            Output ``.npz`` path.
        """
        arrays = {k: v for k, v in vars(self.model).items() if k.endswith("_") and isinstance(v, np.ndarray)}
        params = {k: v for k, v in vars(self.model).items()
                  if not k.endswith("_") and isinstance(v, (int, float, str, bool))}
        payload = {f"model/{k}": v for k, v in arrays.items()}
        payload.update(self.face_space.to_arrays("face/"))
        meta = dict(version=_FILE_VERSION, kind=self.model.name, fps=self.fps, n_dims=self.model.n_dims,
                    params=params, part_names=list(self.face_space.part_names))
        payload["meta"] = np.array(json.dumps(meta))
        with atomic_path(path, (".npz",), "phoneme puppet") as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, **payload)

    @classmethod
    def load(cls, path) -> "PhonemePuppet":
        """Read a puppet written by :meth:`save`.

        Parameters
        ----------
        path : str or os.PathLike

        Returns
        -------
        PhonemePuppet

        Raises
        ------
        FileNotFoundError
            No such file.
        ValueError
            Not a phoneme puppet file, or one of an unsupported version.
        """
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"phoneme puppet {path!r} does not exist")
        arrays = read_npz(path, "phoneme puppet file")
        try:
            meta = json.loads(str(arrays.pop("meta")))
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"{path!r} is not a phoneme puppet file ({exc})") from None
        if meta.get("version") != _FILE_VERSION or meta.get("kind") not in MODELS:
            raise ValueError(f"{path!r}: unsupported phoneme puppet (version {meta.get('version')}, "
                             f"kind {meta.get('kind')!r})")
        m = MODELS[meta["kind"]](**meta["params"])
        for k, v in arrays.items():
            if k.startswith("model/"):
                setattr(m, k[len("model/"):], v)
        m.n_dims_ = int(meta["n_dims"])
        fs = FaceSpace.from_arrays(arrays, meta["part_names"], "face/")
        return cls(m, fs, meta["fps"])


def _frame_labels(phones, n_frames: int, fps: float, alphabet: str) -> np.ndarray:
    arr = np.asarray(phones) if isinstance(phones, np.ndarray) else None
    if arr is not None and arr.dtype.kind in "iu":
        if arr.shape != (n_frames,):
            raise ValueError(f"frame labels must have shape ({n_frames},) (one per landmark frame), "
                             f"got {arr.shape}")
        return check_labels(arr)
    return frame_labels(phones, n_frames, fps, alphabet=alphabet)
