"""Loading audio: files (wav, flac, ogg, mp3, ...) and the audio track of videos (mp4, mov,
mkv, avi).

Audio files are read with soundfile (libsndfile); anything libsndfile does not know (video
containers, AAC, ...) is decoded with PyAV (FFmpeg). The result is mixed to mono, resampled with a
polyphase filter (``scipy.signal.resample_poly``) and has its DC offset removed.
"""

from __future__ import annotations

import contextlib
import math
import os
import warnings
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from voicepuppet import _core

#: Lowest sample rate accepted: below it the formant and band features have no meaning.
MIN_RATE = 8000
#: Default analysis rate: 16 kHz keeps everything up to 8 kHz, enough for speech features.
DEFAULT_RATE = 16000

VIDEO_EXTENSIONS = {".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v", ".mpg", ".mpeg"}


class AudioWarning(UserWarning):
    """A documented degradation of the input (silence, clipping): features stay finite."""


@dataclass(frozen=True)
class Audio:
    """Mono audio ready for analysis.

    Made by :func:`prepare` and :func:`load_audio`; each parameter is kept as the (read-only)
    attribute of the same name.

    Parameters
    ----------
    samples : ndarray, shape (n,)
        float64 samples in [-1, 1] (full scale), mono, DC removed.
    rate : int
        Sample rate of ``samples`` in Hz.
    source_rate : int
        Sample rate of the file before resampling.
    channels : int
        Number of channels in the file before the mono mix.
    path : str or None
        Where it came from (default None).

    Attributes
    ----------
    duration : float
        Length in seconds, ``n / rate``.
    """

    samples: np.ndarray
    rate: int
    source_rate: int
    channels: int
    path: str | None = None

    @property
    def duration(self) -> float:
        """Length in seconds."""
        return self.samples.shape[0] / float(self.rate)

    def __repr__(self) -> str:  # short: never print a million samples
        return (f"Audio(duration={self.duration:.3f} s, rate={self.rate}, "
                f"source_rate={self.source_rate}, channels={self.channels}, path={self.path!r})")


def _read_soundfile(path: str):
    import soundfile as sf

    try:
        data, rate = sf.read(path, dtype="float32", always_2d=True)  # PCM up to 24 bits exactly
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        return None, None, exc
    return data, int(rate), None


@contextlib.contextmanager
def _pyav_audio(path: str):
    """``path`` opened with PyAV: yields ``(container, stream, rate, channels)`` for its first
    audio track, or raises ValueError saying what to do (unreadable, no audio, no decoder)."""
    import av

    try:
        container = av.open(path)
    except (av.error.FFmpegError, OSError) as exc:
        raise ValueError(f"audio: cannot open {path!r} as audio or video ({exc}); expected a wav, "
                         "flac, ogg, mp3 file or a video (mp4, mov, mkv, avi) with an audio "
                         "track") from exc
    with container:
        streams = [s for s in container.streams if s.type == "audio"]
        if not streams:
            raise ValueError(f"audio: {path!r} has no audio track; give a video with sound or "
                             "the audio as a separate file")
        stream = streams[0]
        ctx = stream.codec_context
        if ctx is None:  # FFmpeg knows the container but has no decoder for this codec
            raise ValueError(f"audio: the audio codec of {path!r} is not supported (no decoder "
                             "in FFmpeg); convert it to wav or flac with the tool that made it")
        channels = ctx.channels if hasattr(ctx, "channels") else len(ctx.layout.channels)
        yield container, stream, int(ctx.sample_rate or stream.rate), channels


def _read_pyav(path: str):
    """The first audio track of ``path``, (n, channels) float32, and its rate: the blocks of
    :func:`_pyav_blocks` joined."""
    with _pyav_audio(path) as (_, _, rate, channels):
        pass  # opened for its errors, rate and channel count; the blocks open it again
    blocks = list(_pyav_blocks(path))
    if not blocks:
        return np.zeros((0, max(1, channels)), np.float32), rate
    return np.ascontiguousarray(np.concatenate(blocks)), rate


def resample_taps(up: int, down: int) -> np.ndarray:
    """The filter of ``scipy.signal.resample_poly(x, up, down)`` (Kaiser(5)-windowed sinc,
    ``half_len = 10 max(up, down)``, times ``up``).

    Parameters
    ----------
    up, down : int
        Up- and down-sampling factors.

    Returns
    -------
    ndarray, shape (2 half_len + 1,)
        The filter taps.
    """
    from scipy.signal import firwin

    half_len = 10 * max(up, down)
    return firwin(2 * half_len + 1, 1.0 / max(up, down), window=("kaiser", 5.0)) * up


def resample(x: np.ndarray, rate_in: int, rate_out: int) -> np.ndarray:
    """Resample by the rational factor ``rate_out / rate_in`` (polyphase filtering).

    Parameters
    ----------
    x : ndarray, shape (N,)
    rate_in, rate_out : int
        Sample rates (Hz).

    Returns
    -------
    ndarray, shape (N * rate_out / rate_in,)
        ``x`` itself when the rates are equal.
    """
    from scipy.signal import resample_poly

    if rate_in == rate_out:
        return x
    frac = Fraction(int(rate_out), int(rate_in))
    return resample_poly(x, frac.numerator, frac.denominator)


def _count_clipped(x: np.ndarray, peak: float) -> int:
    """Samples of ``x`` (any shape) within 1 ppm of the recording's ``peak`` magnitude."""
    at = peak * (1.0 - 1e-6)
    return int(np.count_nonzero(x >= at) + np.count_nonzero(x <= -at))


def _warn_clipped(fraction: float, where: str, stacklevel: int) -> None:
    if fraction > 1e-3:
        warnings.warn(f"audio{where}: {100 * fraction:.2f}% of samples are at full scale "
                      "(clipped); formants and LPC features will be distorted",
                      AudioWarning, stacklevel=stacklevel + 1)


def _warn_silent(where: str, stacklevel: int) -> None:
    warnings.warn(f"audio{where}: the recording is silent; features are finite (energy at "
                  "its floor, F0 unvoiced) but carry no information", AudioWarning,
                  stacklevel=stacklevel + 1)


def prepare(samples, rate, *, target_rate: int | None = DEFAULT_RATE, remove_dc: bool = True,
            path: str | None = None) -> Audio:
    """Turn raw samples into analysis-ready :class:`Audio`.

    Parameters
    ----------
    samples : array_like, shape (n,) or (n, channels)
        Samples in full scale [-1, 1]; integer PCM (int16, int32, uint8) is scaled by its
        type's range.
    rate : int
        Sample rate of ``samples`` in Hz (at least ``MIN_RATE``).
    target_rate : int or None
        Resample to this rate (polyphase filter; default ``DEFAULT_RATE``, 16000); None keeps
        ``rate``.
    remove_dc : bool
        Subtract the mean (the DC offset of the recording); default True.
    path : str, optional
        Where the samples came from: named in messages and kept in :attr:`Audio.path`.

    Returns
    -------
    Audio
        Mono (channels averaged) float64 samples at ``target_rate`` (or ``rate``).

    Raises
    ------
    ValueError
        Samples that are not numbers or not of shape (n,) or (n, channels), empty input, NaN or
        infinite samples, a rate that is not a whole number of Hz, a rate or ``target_rate``
        below ``MIN_RATE``.

    Warns
    -----
    AudioWarning
        Pure silence (features stay finite: a floor replaces log(0)); clipped audio (more than
        0.1 % of samples at full scale).
    """
    where = f" in {path!r}" if path else ""
    x = np.asarray(samples)
    if x.dtype.kind not in "fiu":
        raise ValueError(f"audio: samples must be numbers, got dtype {x.dtype}{where}")
    if x.dtype.kind == "i":  # PCM integers: full scale is the type's range
        x = x.astype(np.float64) / float(2 ** (8 * x.dtype.itemsize - 1))
    elif x.dtype.kind == "u":
        half = float(2 ** (8 * x.dtype.itemsize - 1))
        x = (x.astype(np.float64) - half) / half
    if x.dtype not in (np.float32, np.float64):
        x = x.astype(np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(f"audio: samples must have shape (n,) or (n, channels), got {x.shape}")
    channels = x.shape[1]
    if x.shape[0] == 0 or channels == 0:
        raise ValueError(f"audio: no samples{where} (empty audio); give a recording with sound")
    if not np.all(np.isfinite(x)):
        bad = int(np.count_nonzero(~np.isfinite(x)))
        raise ValueError(f"audio: {bad} NaN or infinite samples{where}; repair or re-encode the "
                         "file (e.g. ffmpeg -i IN out.wav)")
    try:
        rate_f = float(rate)
    except (TypeError, ValueError):
        raise ValueError(f"audio: rate must be a number in Hz, got {rate!r}") from None
    if not math.isfinite(rate_f) or rate_f != int(rate_f):
        raise ValueError(f"audio: rate must be a whole number of Hz, got {rate!r}")
    rate = int(rate_f)
    if rate < MIN_RATE:
        raise ValueError(f"audio: sample rate {rate} Hz{where} is below the minimum {MIN_RATE} Hz; "
                         "speech features need at least telephone bandwidth (re-record or give "
                         "the original file)")
    if target_rate is not None and int(target_rate) < MIN_RATE:
        raise ValueError(f"audio: target_rate must be at least {MIN_RATE} Hz, got {target_rate}")
    # Without temporaries the size of x (an hour of 48 kHz stereo is 1.4 GB of float32).
    peak = max(float(x.max()), -float(x.min()))
    if peak >= 1.0 - 1e-6:
        _warn_clipped(_count_clipped(x, peak) / x.size, where, stacklevel=2)
    # Files are read as float32 (half the memory of float64); the mix and all after it are float64.
    mono = x.mean(axis=1, dtype=np.float64) if channels > 1 else x[:, 0].astype(np.float64)
    out_rate = rate if target_rate is None else int(target_rate)
    mono = resample(mono, rate, out_rate)
    if remove_dc:
        mono = mono - mono.mean()
    if not np.any(np.abs(mono) > 1e-7):
        _warn_silent(where, stacklevel=2)
    return Audio(samples=np.ascontiguousarray(mono), rate=out_rate, source_rate=rate,
                 channels=channels, path=path)


def load_audio(path, *, rate: int | None = DEFAULT_RATE, remove_dc: bool = True) -> Audio:
    """Load an audio file or the audio track of a video, mono, resampled, DC removed.

    Parameters
    ----------
    path : str or os.PathLike
        wav, flac, ogg, mp3 (soundfile) or anything FFmpeg decodes, including the first audio
        track of mp4, mov, mkv and avi videos (PyAV).
    rate : int or None
        Output sample rate in Hz (default 16000); None keeps the file's rate.
    remove_dc : bool
        Subtract the DC offset.

    Returns
    -------
    Audio
        ``samples`` (n,), ``rate``, ``duration``, ``source_rate``, ``channels``.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        Not a decodable audio file, a video without an audio track, an unsupported codec, empty
        audio, NaN samples or a sample rate below 8 kHz.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"audio: no such file {path!r}")
    if os.path.isdir(path):
        raise ValueError(f"audio: {path!r} is a directory; give an audio or video file")
    if os.path.getsize(path) == 0:
        raise ValueError(f"audio: {path!r} is an empty file (0 bytes); give a recording with sound")
    data = None
    ext = os.path.splitext(path)[1].lower()
    if ext not in VIDEO_EXTENSIONS:
        data, file_rate, _ = _read_soundfile(path)
    if data is None:
        data, file_rate = _read_pyav(path)
    return prepare(data, file_rate, target_rate=rate, remove_dc=remove_dc, path=path)


def _soundfile_blocks(path: str, n: int):
    import soundfile as sf

    with sf.SoundFile(path) as f:
        while True:
            data = f.read(n, dtype="float32", always_2d=True)
            if not len(data):
                return
            yield data


def _pyav_blocks(path: str):
    """``_read_pyav``'s samples (n, channels) float32, frame by frame (the same shift to the
    video's start)."""
    import av

    with _pyav_audio(path) as (container, stream, rate, _):
        resampler = av.AudioResampler(format="fltp", layout=None, rate=None)
        video_start = 0.0
        for s in container.streams:
            if s.type == "video" and s.start_time is not None and s.time_base is not None:
                video_start = float(s.start_time * s.time_base)
                break
        drop = None
        try:
            for frame in container.decode(stream):
                if drop is None:
                    first = float(frame.time) if frame.time is not None else video_start
                    shift = int(round((first - video_start) * rate))
                    if shift > 0:
                        yield np.zeros((shift, len(frame.layout.channels)), np.float32)
                    drop = max(0, -shift)
                for out in [*resampler.resample(frame)]:
                    a = np.ascontiguousarray(out.to_ndarray().T)
                    a, drop = a[drop:], max(0, drop - len(a))
                    if len(a):
                        yield a
            for out in resampler.resample(None):
                a = np.ascontiguousarray(out.to_ndarray().T)
                a, drop = a[drop or 0:], max(0, (drop or 0) - len(a))
                if len(a):
                    yield a
        except (av.error.FFmpegError, ValueError) as exc:
            raise ValueError(f"audio: cannot decode the audio track of {path!r} ({exc}); convert it to wav, "
                             "e.g. ffmpeg -i IN -vn -ac 1 out.wav") from exc


class AudioReader:
    """An audio file (or a video's sound) read in blocks in bounded memory: the samples
    :func:`load_audio` gives, mono and resampled (by :class:`~voicepuppet.audio.conditioning.StreamResampler`,
    equal to ``resample_poly`` to 1e-12), without holding the recording.

    :meth:`scan` reads the file once for what needs all of it (the DC offset, the peak, the
    length, and sums over frames of the caller's size); :meth:`blocks` then yields the samples
    with the DC offset removed, as ``load_audio`` would have them, and at the end warns as
    ``prepare`` does (clipping, silence).

    Parameters
    ----------
    path : str or os.PathLike
        As for :func:`load_audio`.
    rate : int
        Output sample rate in Hz (default 16000).
    block_s : float
        Seconds of the file read at a time (default 10).

    Attributes
    ----------
    path : str
    rate, source_rate, channels : int
    duration : float or None
        The length (s) the file's header announces (None if it does not), until :meth:`scan`
        measures it.
    n_samples : int or None
        Samples at ``rate`` (after :meth:`scan`).
    mean : float or None
        The DC offset (after :meth:`scan`).

    Raises
    ------
    FileNotFoundError, ValueError
        As for :func:`load_audio`.
    """

    def __init__(self, path, rate: int = DEFAULT_RATE, block_s: float = 10.0):
        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"audio: no such file {path!r}")
        if os.path.isdir(path):
            raise ValueError(f"audio: {path!r} is a directory; give an audio or video file")
        if os.path.getsize(path) == 0:
            raise ValueError(f"audio: {path!r} is an empty file (0 bytes); give a recording with sound")
        self.path, self.rate, self.block_s = path, int(rate), float(block_s)
        self.duration = None
        self._soundfile = False
        if os.path.splitext(path)[1].lower() not in VIDEO_EXTENSIONS:
            import soundfile as sf

            try:
                info = sf.info(path)
                self.source_rate, self.channels = int(info.samplerate), int(info.channels)
                self.duration = info.frames / float(info.samplerate) if info.frames > 0 else None
                self._soundfile = True
            except (sf.LibsndfileError, RuntimeError, TypeError):
                pass
        if not self._soundfile:
            with _pyav_audio(path) as (container, _, self.source_rate, self.channels):
                if container.duration:
                    self.duration = container.duration / 1e6
        if self.source_rate < MIN_RATE:
            raise ValueError(f"audio: sample rate {self.source_rate} Hz in {path!r} is below the minimum "
                             f"{MIN_RATE} Hz; speech features need at least telephone bandwidth (re-record or "
                             "give the original file)")
        self.n_samples = self.mean = None
        self._peak = 0.0

    def _raw(self):
        """The file's blocks (n, channels) float32, checked finite."""
        where = f" in {self.path!r}"
        it = (_soundfile_blocks(self.path, max(1, int(self.block_s * self.source_rate))) if self._soundfile
              else _pyav_blocks(self.path))
        for data in it:
            if not np.all(np.isfinite(data)):
                bad = int(np.count_nonzero(~np.isfinite(data)))
                raise ValueError(f"audio: {bad} NaN or infinite samples{where}; repair or re-encode the "
                                 "file (e.g. ffmpeg -i IN out.wav)")
            yield data

    def _mono(self, on_raw=None):
        """Mono float64 blocks at :attr:`rate` (``prepare``'s mix and resampling), DC not removed."""
        frac = Fraction(self.rate, self.source_rate)  # conditioning.StreamResampler, which stands below
        up, down = frac.numerator, frac.denominator
        rs = None if up == down else _core.PolyphaseResampler(up, down, resample_taps(up, down))
        for data in self._raw():
            if on_raw is not None:
                on_raw(data)
            mono = data.mean(axis=1, dtype=np.float64) if data.shape[1] > 1 else data[:, 0].astype(np.float64)
            yield mono if rs is None else rs.push(np.ascontiguousarray(mono))
        if rs is not None:
            yield rs.flush()

    def scan(self, frame: int | None = None):
        """Read the file once: its length, DC offset and peak, and optionally the sums of the
        samples and of their squares over consecutive ``frame``-sample frames (time 0 the first
        sample at :attr:`rate`; the last, partial frame left out).

        Parameters
        ----------
        frame : int, optional
            Frame length in samples at :attr:`rate`.

        Returns
        -------
        ndarray, shape (F, 2), or None
            Per frame, the sum of the samples and of their squares (DC not removed), with ``frame``.

        Raises
        ------
        ValueError
            No samples, or NaN or infinite ones.
        """
        total, n, peak = 0.0, 0, 0.0
        sums, carry = [], np.zeros(0)

        def on_raw(data):
            nonlocal peak
            peak = max(peak, float(data.max()), -float(data.min()))

        for x in self._mono(on_raw):
            total += float(np.sum(x))
            n += x.size
            if frame:
                buf = np.concatenate([carry, x]) if carry.size else x
                k = buf.size // frame
                if k:
                    v = buf[:k * frame].reshape(k, frame)
                    sums.append(np.column_stack([v.sum(axis=1), np.einsum("ij,ij->i", v, v)]))
                carry = buf[k * frame:].copy()
        if n == 0:
            raise ValueError(f"audio: no samples in {self.path!r} (empty audio); give a recording with sound")
        self.n_samples, self.mean, self._peak = n, total / n, peak
        self.duration = n / float(self.rate)
        if frame:
            return np.vstack(sums) if sums else np.zeros((0, 2))
        return None

    def blocks(self):
        """The samples, mono at :attr:`rate` with the DC offset removed, block by block
        (:meth:`scan` first); after the last block, ``prepare``'s warnings (clipping, silence).

        Yields
        ------
        ndarray, shape (n,)
            float64 samples.
        """
        if self.mean is None:
            self.scan()
        where = f" in {self.path!r}"
        clipped, count, sound = 0, 0, False

        def on_raw(data):
            nonlocal clipped, count
            count += data.size
            if self._peak >= 1.0 - 1e-6:
                clipped += _count_clipped(data, self._peak)

        for x in self._mono(on_raw):
            x = x - self.mean
            sound = sound or bool(np.any(np.abs(x) > 1e-7))
            yield x
        if count:
            _warn_clipped(clipped / count, where, stacklevel=2)
        if not sound:
            _warn_silent(where, stacklevel=2)
