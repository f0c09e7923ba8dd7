"""Feature extraction: audio in, a :class:`~voicepuppet.audio.featureset.Features` table out.

:func:`extract` runs the streaming front end (:mod:`voicepuppet.audio.stream`, C++) on the whole
signal in one push; :func:`reference_extract` computes the same columns by the numpy definitions
of :mod:`voicepuppet.audio.spectral` and :mod:`voicepuppet.audio.lpc` (the tests' oracle).
"""

from __future__ import annotations

import warnings

import numpy as np
from tqdm import tqdm

from voicepuppet.audio import lpc as lpc_mod
from voicepuppet.audio import pitch as pitch_mod
from voicepuppet.audio import spectral
from voicepuppet.audio.featureset import Features, FeatureSet, analysis_window_s, as_feature_set, feature_of
from voicepuppet.audio.framing import check_fps, n_frames
from voicepuppet.audio.loading import Audio, AudioReader, AudioWarning, load_audio
from voicepuppet.audio.stream import STREAMABLE, StreamingFeatures
from voicepuppet.audio.conditioning import LEVEL_FRAME_S, LEVEL_PERCENTILE, BandLimiter, LevelNormalizer
from voicepuppet.limits import check_limit


def extract(source, fps: float = 29.97, features=None, *, n_out: int | None = None,
            progress: bool = False, **options) -> Features:
    """Compute a feature set at video frame times.

    The streamable features (all but ``f0`` and ``voicing``) are computed by the C++ front end
    (``voicepuppet::StreamingAudioFeatures``) on the whole signal in one push, so offline and
    streamed features are the same computation; F0 and voicing by :mod:`.pitch`.

    Parameters
    ----------
    source : Audio, str or os.PathLike
        Prepared audio or a file to load (audio or video; resampled to 16 kHz).
    fps : float
        Output frame rate (default NTSC 29.97); frame ``k`` is centred at ``k / fps``.
    features : FeatureSet, str or list of str, optional
        A set (default ``"puppet"``), a set name, or feature names.
    n_out : int, optional
        Number of output frames, e.g. the frame count of the video the audio belongs to
        (default ``ceil(duration * fps)``); frames past the end of the audio see silence.
    progress : bool
        Show a tqdm progress bar over the analysis stages.
    **options
        Overrides of ``DEFAULT_OPTIONS`` for this call.

    Returns
    -------
    Features
        ``values`` (T, D), all finite, ``T = n_out`` or ``ceil(duration * fps)``.

    Raises
    ------
    ValueError
        ``fps`` outside [1, 1000], ``n_out`` not a whole number in [1, 10^7]
        (:data:`voicepuppet.limits.LIMITS`), an unknown
        feature, set or option, or audio that cannot be loaded (see :func:`load_audio`).

    Warns
    -----
    AudioWarning
        The audio is shorter than one frame (its one frame is analysed with silence after it).
    """
    return _extract(source, fps, features, n_out, progress, options, reference=False)


def reference_extract(source, fps: float = 29.97, features=None, *, n_out: int | None = None,
                      **options) -> Features:
    """:func:`extract` computed by the numpy definitions in :mod:`.spectral` and :mod:`.lpc`
    (the test oracle of the C++ front end; no production path calls it). Same arguments.

    Parameters
    ----------
    source : Audio, str or os.PathLike
        Prepared audio or a file to load, as for :func:`extract`.
    fps : float
        Output frame rate (default NTSC 29.97); frame ``k`` is centred at ``k / fps``.
    features : FeatureSet, str or list of str, optional
        A set (default ``"puppet"``), a set name, or feature names.
    n_out : int, optional
        Number of output frames (default ``ceil(duration * fps)``).
    **options
        Overrides of ``DEFAULT_OPTIONS`` for this call.

    Returns
    -------
    Features
        The same table as :func:`extract` gives (to rounding).

    Raises
    ------
    ValueError
        As for :func:`extract`.
    """
    return _extract(source, fps, features, n_out, False, options, reference=True)


def extract_file(path, fps: float = 29.97, features=None, *, progress: bool = False,
                 block_s: float = 10.0) -> Features:
    """:func:`extract` of an audio file in bounded memory (a long recording: hours).

    Two passes over the file in blocks (:class:`voicepuppet.audio.loading.AudioReader`): the
    first for the DC offset, the length and the speech level (``level_db``), the second pushes
    the DC-removed samples through the streaming front end (:class:`StreamingFeatures`, given
    the recording's level), so the features equal :func:`extract`'s (to 1e-9: the streaming
    resampler's rounding for files not at 16 kHz, the DC offset's summation order) while memory
    holds one block of audio and the feature rows (24 columns at 29.97 fps: 41 MB for 2 h).

    Parameters
    ----------
    path : str or os.PathLike
        Audio file or video with sound.
    fps : float
        Output frame rate (default 29.97).
    features : FeatureSet, str or list of str, optional
        A set (default ``"puppet"``) of streamable features (not ``f0`` or ``voicing``).
    progress : bool
        Show a tqdm progress bar over the seconds of audio.
    block_s : float
        Seconds of audio read at a time (default 10).

    Returns
    -------
    Features
        As :func:`extract` gives (``T = ceil(duration * fps)``).

    Raises
    ------
    ValueError
        As for :func:`extract`; features that need the whole recording (``f0``, ``voicing``).
    """
    fps = check_fps(fps)
    fset = as_feature_set(features)
    bad = [f for f in fset.features if f not in STREAMABLE]
    if bad:
        raise ValueError(f"features: {', '.join(bad)} need the whole recording at once; extract_file computes "
                         f"only {', '.join(STREAMABLE)} (use extract)")
    opt = fset.settings()
    reader = AudioReader(path, block_s=block_s)
    rate = reader.rate
    level = None
    if opt["level_db"] is not None:  # speech_level_db of the DC-removed recording, from frame sums
        n = max(1, int(round(LEVEL_FRAME_S * rate)))
        sums = reader.scan(frame=n)
        m = reader.mean
        if len(sums):
            power = (sums[:, 1] - 2.0 * m * sums[:, 0] + n * m * m) / n
        else:  # shorter than a frame: its one short frame
            x = np.concatenate(list(reader.blocks()))
            power = np.array([np.mean(x ** 2)])
        p = float(np.percentile(power, LEVEL_PERCENTILE, method="inverted_cdf"))
        level = 10.0 * np.log10(p) if p > 0 else -np.inf
        if np.isfinite(level):  # the too-quiet warning of LevelNormalizer.apply, for a recording of this level
            LevelNormalizer(opt["level_db"], rate, input_level_db=level).apply(np.zeros(0))
    else:
        reader.scan()
    if level is not None and not np.isfinite(level):  # digital silence: gain 1, as apply() takes it
        level = opt["level_db"]
    stream = StreamingFeatures(fset, fps=fps, rate=rate, input_level_db=level)
    T = n_frames(reader.n_samples, rate, fps)
    values = np.empty((T, stream.n_features))
    k = 0

    def put(rows):
        nonlocal k
        rows = rows[:max(0, T - k)]
        values[k:k + len(rows)] = rows
        k += len(rows)

    with tqdm(total=round(reader.duration, 1), desc="features", unit="s", disable=not progress, leave=False) as bar:
        for x in reader.blocks():
            put(stream.push(x))
            bar.update(round(x.size / rate, 1))
        put(stream.flush())
    if k != T or not np.all(np.isfinite(values)):  # a bug, not bad input
        raise RuntimeError(f"features: the stream gave {k} frames for {T}, or non-finite values")
    return Features(values, stream.names, fps, stream.fset, reader.duration, None)


def _extract(source, fps, features, n_out, progress, options, reference: bool) -> Features:
    fps = check_fps(fps)
    fset = as_feature_set(features)
    if options:
        fset = FeatureSet(fset.features, {**fset.options, **options}, fset.name)
    opt = fset.settings()
    audio = source if isinstance(source, Audio) else load_audio(source)
    x, rate = audio.samples, audio.rate
    if n_out is None:
        T = n_frames(x.shape[0], rate, fps)
        if x.shape[0] / rate < 1.0 / fps:
            where = f" in {audio.path!r}" if audio.path else ""
            warnings.warn(f"audio{where}: {1e3 * x.shape[0] / rate:.1f} ms long, shorter than one "
                          f"frame ({1e3 / fps:.1f} ms at {fps:g} fps); its one frame is analysed "
                          "with silence after it", AudioWarning, stacklevel=3)
    elif isinstance(n_out, (int, np.integer)) and not isinstance(n_out, bool) and n_out >= 1:
        T = int(check_limit(n_out, "frames", "n_out (frames)", "extract long audio in pieces"))
    else:
        raise ValueError(f"n_out must be a positive whole number of frames, got {n_out!r}")
    want = set(fset.features)
    # The options on the samples (the stream's own front end, in its order), once for every
    # feature: the stream below is given the result with them off.
    if opt["level_db"] is not None:
        x = LevelNormalizer(opt["level_db"], rate).apply(x)
    if opt["band_hz"] is not None:
        x = BandLimiter(opt["band_hz"], rate).apply(x)
    cols: dict[str, tuple[list[str], np.ndarray]] = {}
    framewise = [f for f in fset.features if f not in ("f0", "voicing")]
    stages = [bool(framewise), bool(want & {"f0", "voicing"})]
    bar = tqdm(total=sum(stages), desc="features", unit="stage", disable=not progress,
               leave=False)
    if framewise and not reference:
        bar.set_postfix_str("spectra, lpc, formants")
        sub = FeatureSet(tuple(framewise), {**fset.options, "level_db": None, "band_hz": None}, fset.name)
        s = StreamingFeatures(sub, fps=fps, rate=rate)
        values = s.process(x, T)
        for f in framewise:
            idx = [j for j, n in enumerate(s.names) if feature_of(n) == f]
            cols[f] = ([s.names[j] for j in idx], values[:, idx])
        bar.update()
    elif framewise:
        cols.update(_reference_columns(x, rate, fps, T, want, opt))
        bar.update()
    voiced = None
    if want & {"f0", "voicing"}:
        bar.set_postfix_str("f0")
        f0, prob = pitch_mod.pitch_frames(x, rate, fps, T, floor=opt["pitch_floor"],
                                          ceiling=opt["pitch_ceiling"])
        voiced = np.isfinite(f0)
        if "f0" in want:
            cols["f0"] = (["f0"], pitch_mod.fill_unvoiced(f0)[:, None])
        if "voicing" in want:
            cols["voicing"] = (["voicing"], prob[:, None])
        bar.update()
    bar.close()

    names: list[str] = []
    blocks = []
    for feat in fset.features:
        n, v = cols[feat]
        names += n
        blocks.append(np.asarray(v, dtype=np.float64).reshape(T, -1))
    values = np.ascontiguousarray(np.hstack(blocks))
    if not np.all(np.isfinite(values)):  # a bug, not bad input: every path floors its logs
        bad = [names[j] for j in np.nonzero(~np.all(np.isfinite(values), axis=0))[0]]
        raise RuntimeError(f"features: non-finite values in {bad}")
    return Features(values, tuple(names), fps, fset, audio.duration, voiced)


def _reference_columns(x, rate, fps, T, want, opt) -> dict:
    """The streamable features by the numpy definitions (``reference_extract``)."""
    window_s = analysis_window_s(opt, fps)
    cols: dict[str, tuple[list[str], np.ndarray]] = {}
    spec_want = want & {"mfcc", "mfcc_deltas", "rasta_plp", "bands", "log_energy"}
    if spec_want:
        kinds = {("mfcc" if k == "mfcc_deltas" else k) for k in spec_want}
        sp = spectral.spectral_features(x, rate, fps, T, want=kinds, window_s=window_s,
                                        n_fft=opt["n_fft"], n_mfcc=opt["n_mfcc"],
                                        n_mels=opt["n_mels"], rasta_order=opt["rasta_order"],
                                        rasta_ceps=opt["n_rasta"])
        if "mfcc" in sp:
            m = sp["mfcc"]
            cols["mfcc"] = ([f"mfcc{i}" for i in range(m.shape[1])], m)
            if "mfcc_deltas" in want:
                cols["mfcc_deltas"] = ([f"dmfcc{i}" for i in range(m.shape[1])],
                                       spectral.deltas(m, opt["delta_width"]))
        if "rasta_plp" in sp:
            r = sp["rasta_plp"]
            first = 0 if opt["rasta_c0"] else 1
            cols["rasta_plp"] = ([f"rplp{i}" for i in range(first, r.shape[1])], r[:, first:])
        if "bands" in sp:
            b = sp["bands"]
            cols["bands"] = ([f"band{i}" for i in range(b.shape[1])], b)
        if "log_energy" in sp:
            cols["log_energy"] = (["log_energy"], sp["log_energy"][:, None])
    if want & {"lpc", "lpc_cepstra"}:
        order = int(opt["lpc_order"])
        a, err = lpc_mod.lpc_frames(x, rate, fps, T, order=order, window_s=window_s,
                                    preemph=opt["lpc_preemph"])
        if "lpc" in want:
            cols["lpc"] = ([f"lpc{i}" for i in range(1, order + 1)], a[:, 1:])
        if "lpc_cepstra" in want:
            n = int(opt["n_lpc_cepstra"])
            c = lpc_mod.lpc_to_cepstrum(a, err, n + 1)[:, 1:]
            cols["lpc_cepstra"] = ([f"lpcc{i}" for i in range(1, n + 1)], c)
    if "formants" in want:
        f = lpc_mod.formant_frames(x, rate, fps, T, ceiling=opt["formant_ceiling"],
                                   max_bandwidth=opt["formant_max_bandwidth"])
        cols["formants"] = ([f"f{i}" for i in range(1, f.shape[1] + 1)], f)
    return cols
