"""Audio front end on synthetic signals with known answers: loading, framing, LPC, formants, F0,
spectra, feature sets, bad input. Peers on real speech are in test_audio_peers.py."""

import math
import os

import warnings

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
import soundfile as sf

from voicepuppet import audio
from voicepuppet.audio import lpc, pitch, spectral
from voicepuppet.audio.framing import frame_centres, iter_frames
from voicepuppet.cli.main import main

RATE = 16000


def source_filter_vowel(formants, bandwidths, f0, duration=1.0, rate=RATE, jitter=0.0, rng=None):
    """A vowel from the source-filter model: an impulse train at f0 through the all-pole filter
    with the given resonances (known formants and F0), as planted ground truth."""
    n = int(duration * rate)
    src = np.zeros(n)
    period = rate / f0
    t = 0.0
    while t < n:
        src[int(t)] = 1.0
        t += period * (1.0 + (jitter * rng.standard_normal() if rng is not None else 0.0))
    a = np.array([1.0])
    for F, B in zip(formants, bandwidths):
        r = math.exp(-math.pi * B / rate)
        a = np.convolve(a, [1.0, -2.0 * r * math.cos(2 * math.pi * F / rate), r * r])
    y = scipy.signal.lfilter([1.0], a, src)
    # glottal roll-off (-12 dB/oct from a double pole) so the spectrum looks like speech
    y = scipy.signal.lfilter([1.0], [1.0, -1.9, 0.9025], y)
    return 0.5 * y / np.max(np.abs(y)), a


# ------------------------------------------------------------------------------------ framing
def test_frame_count_and_times():
    # 2 s at 29.97 fps: frames 0..59 have times < 2 s (59 / 29.97 = 1.9686)
    assert audio.n_frames(2 * RATE, RATE, 29.97) == 60
    assert audio.n_frames(2 * RATE, RATE, 25) == 50
    assert audio.n_frames(2 * RATE + 1, RATE, 25) == 51
    np.testing.assert_allclose(audio.frame_times(3, 25.0), [0.0, 0.04, 0.08])
    np.testing.assert_array_equal(frame_centres(3, RATE, 25.0), [0, 640, 1280])


def test_iter_frames_centres_and_zero_padding():
    x = np.arange(1, 11, dtype=float)
    (sl, fr), = list(iter_frames(x, np.array([0, 5, 9]), 4))
    np.testing.assert_array_equal(fr, [[0, 0, 1, 2], [4, 5, 6, 7], [8, 9, 10, 0]])


@pytest.mark.parametrize("fps", [29.97, 25.0])
@pytest.mark.parametrize("feature", ["log_energy", "bands", "mfcc"])
def test_click_lands_in_the_right_frame(fps, feature, rng):
    dur = 4.0
    x = 1e-4 * rng.standard_normal(int(dur * RATE))
    click_times = [0.5013, 1.2345, 2.71, 3.3333]
    for t in click_times:
        x[int(round(t * RATE))] = 0.9
    a = audio.prepare(x, RATE)
    f = audio.extract(a, fps=fps, features=[feature])
    col = f.values[:, 0]
    # local maxima of the energy track: one per click, at the frame nearest the click
    expected = [int(round(t * fps)) for t in click_times]
    for t, k in zip(click_times, expected):
        lo, hi = max(0, k - 3), k + 4
        assert lo + int(np.argmax(col[lo:hi])) == k, (t, fps, col[lo:hi])
    assert f.times[expected[1]] == pytest.approx(expected[1] / fps)


# ------------------------------------------------------------------------------------ LPC
def test_levinson_matches_toeplitz_solve(rng):
    x = rng.standard_normal((5, 400))
    r = lpc.autocorrelation(x, 10)
    a, err = lpc.levinson(r, 10)
    for i in range(5):
        r0 = r[i].copy()
        r0[0] = r0[0] * (1 + lpc.WHITE_NOISE_CORRECTION) + lpc.ENERGY_FLOOR
        sol = scipy.linalg.solve_toeplitz(r0[:10], -r0[1:11])
        np.testing.assert_allclose(a[i, 1:], sol, rtol=1e-9, atol=1e-12)
        assert err[i] == pytest.approx(r0[0] + r0[1:11] @ sol, rel=1e-9)


def test_autocorrelation_matches_direct():
    x = np.arange(7, dtype=float)[None, :] - 2.0
    r = lpc.autocorrelation(x, 3)
    direct = [np.dot(x[0, :7 - k], x[0, k:]) for k in range(4)]
    np.testing.assert_allclose(r[0], direct, atol=1e-12)


def test_lpc_recovers_a_known_ar_process(rng):
    a_true = np.array([1.0, -1.3, 0.8, -0.2])  # stable AR(3)
    assert np.all(np.abs(np.roots(a_true)) < 1)
    x = scipy.signal.lfilter([1.0], a_true, rng.standard_normal(4 * RATE))
    a, err = lpc.lpc_frames(x, RATE, 2.0, 3, order=3, window_s=1.0, preemph=0.0)
    np.testing.assert_allclose(a[1:, :], np.tile(a_true, (2, 1)), atol=0.03)
    # prediction error power of unit-variance innovations through a Hamming window
    w = np.hamming(RATE)
    assert err[1] / np.sum(w * w) == pytest.approx(1.0, rel=0.1)


def test_lpc_cepstrum_equals_real_cepstrum_of_model():
    a = np.array([[1.0, -1.3, 0.8, -0.2], [1.0, 0.5, 0.25, 0.0]])
    err = np.array([0.3, 2.0])
    c = lpc.lpc_to_cepstrum(a, err, 20)
    n = 4096
    A = np.fft.fft(a, n, axis=1)
    logspec = np.log(err[:, None] / np.abs(A) ** 2)
    ceps = np.fft.ifft(logspec, axis=1).real
    np.testing.assert_allclose(c, ceps[:, :20], atol=1e-10)


def test_formants_and_f0_of_a_synthetic_vowel(rng):
    formants, bws = (700.0, 1220.0, 2600.0), (80.0, 90.0, 120.0)
    x, _ = source_filter_vowel(formants, bws, f0=120.0, duration=1.5)
    a = audio.prepare(x, RATE)
    f = audio.extract(a, fps=29.97, features=["formants", "f0", "voicing"])
    mid = slice(5, len(f) - 5)
    F = f.group("formants")[mid]
    np.testing.assert_allclose(np.median(F, axis=0), formants, rtol=0.04)
    np.testing.assert_allclose(f.column("f0")[mid], 120.0, rtol=0.01)
    assert np.all(f.column("voicing")[mid] > 0.9)
    assert np.all(f.voiced[mid])


@pytest.mark.parametrize("f0", [90.0, 150.0, 240.0, 400.0])
def test_pitch_of_pulse_trains(f0):
    x, _ = source_filter_vowel((500.0, 1500.0, 2500.0), (80.0, 100.0, 120.0), f0=f0,
                               duration=1.0)
    est, prob = pitch.pitch_frames(x, RATE, 100.0, 100)
    inner = est[10:90]
    assert np.all(np.isfinite(inner))
    np.testing.assert_allclose(inner, f0, rtol=0.01)


def test_pitch_unvoiced_on_noise_and_silence(rng):
    x = np.concatenate([0.3 * rng.standard_normal(RATE), np.zeros(RATE)])
    est, prob = pitch.pitch_frames(x, RATE, 50.0, 100)
    assert np.mean(np.isnan(est)) > 0.9
    assert np.all(prob[55:95] < 0.05)  # silence
    assert np.all(np.isfinite(prob))


def test_formant_tracking_bridges_gaps():
    f = np.array([[500, 1500, 2500, np.nan]] * 3 + [[500, np.nan, np.nan, np.nan]] +
                 [[520, 1540, 2600, 3500]] * 3, dtype=float)
    b = np.where(np.isfinite(f), 100.0, np.nan)
    out = lpc.track_formants(f, b, ceiling=5000.0)
    np.testing.assert_allclose(out[3], [510, 1520, 2550])
    np.testing.assert_allclose(out[-1], [520, 1540, 2600])


# ------------------------------------------------------------------------------------ spectra
def test_band_energy_and_log_energy_of_a_sinusoid():
    A = 0.3
    t = np.arange(2 * RATE) / RATE
    x = A * np.sin(2 * np.pi * 700.0 * t)
    f = audio.extract(audio.prepare(x, RATE, remove_dc=False), fps=25.0,
                      features=["bands", "log_energy"])
    inner = slice(2, len(f) - 2)
    expect_db = 10 * np.log10(A * A / 2)
    np.testing.assert_allclose(f.column("log_energy")[inner], expect_db, atol=0.05)
    np.testing.assert_allclose(f.column("band1")[inner], expect_db, atol=0.1)  # 400-1000 Hz
    assert np.all(f.column("band3")[inner] < expect_db - 60)  # 2.5-4 kHz: window leakage only


def test_mel_filterbank_and_deltas_match_librosa(rng):
    librosa = pytest.importorskip("librosa")
    np.testing.assert_allclose(spectral.mel_filterbank(RATE, 512, 40),
                               librosa.filters.mel(sr=RATE, n_fft=512, n_mels=40), atol=1e-10)
    np.testing.assert_allclose(spectral.mel_filterbank(22050, 1024, 64, 50.0, 8000.0),
                               librosa.filters.mel(sr=22050, n_fft=1024, n_mels=64, fmin=50.0,
                                                   fmax=8000.0), atol=1e-10)
    x = rng.standard_normal((50, 13))
    np.testing.assert_allclose(spectral.deltas(x, 2),
                               librosa.feature.delta(x.T, width=5, mode="nearest").T, atol=1e-12)


def test_gain_invariance_of_rasta_plp_and_mfcc_offset(rng):
    x, _ = source_filter_vowel((600.0, 1700.0, 2500.0), (80.0, 100.0, 120.0), f0=130.0,
                               duration=2.0, jitter=0.02, rng=rng)
    x = x + 0.01 * rng.standard_normal(x.shape[0])
    f1 = audio.extract(audio.prepare(x, RATE), features=["rasta_plp", "mfcc"], rasta_c0=True)
    f2 = audio.extract(audio.prepare(0.25 * x, RATE), features=["rasta_plp", "mfcc"],
                       rasta_c0=True)
    # RASTA's filter has zero gain at DC: a constant log-spectral offset (a channel gain) is
    # removed exactly, from the first frame on.
    np.testing.assert_allclose(f1.group("rasta_plp"), f2.group("rasta_plp"), atol=1e-6)
    # MFCC has no such normalisation: c0 moves by 20 log10(gain) * sqrt(n_mels) (orthonormal
    # DCT of a constant dB shift), the other coefficients stay.
    d = f1.group("mfcc") - f2.group("mfcc")
    np.testing.assert_allclose(d[:, 0], -20 * np.log10(0.25) * np.sqrt(40), rtol=1e-6)
    np.testing.assert_allclose(d[:, 1:], 0.0, atol=1e-6)


def test_rasta_filter_removes_constant_and_passes_syllable_rate():
    fr = 100.0
    t = np.arange(400) / fr
    const = np.full((400, 1), 3.0)
    np.testing.assert_allclose(spectral.rasta_filter(const, fr), 0.0, atol=1e-12)
    # a 4 Hz modulation (syllable rate) passes, a 0.1 Hz drift is strongly attenuated
    fast = spectral.rasta_filter(np.sin(2 * np.pi * 4 * t)[:, None], fr)[200:]
    slow = spectral.rasta_filter(np.sin(2 * np.pi * 0.1 * t)[:, None], fr)[200:]
    assert np.max(np.abs(fast)) > 0.5
    assert np.max(np.abs(slow)) < 0.1


# ------------------------------------------------------------------------------------ sets
def test_default_set_columns_and_finiteness(rng):
    x, _ = source_filter_vowel((600.0, 1700.0, 2500.0), (80.0, 100.0, 120.0), f0=130.0,
                               duration=1.0)
    x = np.concatenate([x, np.zeros(RATE // 2)])
    f = audio.extract(audio.prepare(x, RATE))
    assert f.feature_set.name == "puppet"
    assert f.names == (tuple(f"lpcc{i}" for i in range(1, 9)) + tuple(f"rplp{i}" for i in
                       range(1, 9)) + ("f1", "f2", "f3") + tuple(f"band{i}" for i in range(4)) +
                       ("log_energy",))
    assert f.values.shape == (audio.n_frames(x.shape[0], RATE, 29.97), 24)
    assert np.all(np.isfinite(f.values))


def test_silence_warns_and_gives_finite_features():
    with pytest.warns(audio.AudioWarning, match="silent"):
        a = audio.prepare(np.zeros(RATE), RATE)
    f = audio.extract(a, features="all")
    assert np.all(np.isfinite(f.values))
    assert not np.any(f.voiced)
    np.testing.assert_allclose(f.column("log_energy"), -100.0, atol=1e-6)


def test_audio_shorter_than_one_frame_warns_and_gives_one_frame(rng):
    a = audio.prepare(0.1 * rng.standard_normal(100), RATE)  # 6.25 ms
    with pytest.warns(audio.AudioWarning, match=r"6\.2 ms long, shorter than one frame \(33\.4 ms"):
        f = audio.extract(a, fps=29.97)
    assert f.values.shape == (1, 24) and np.all(np.isfinite(f.values))
    one = audio.prepare(0.1 * rng.standard_normal(RATE // 25), RATE)  # one 25 fps frame exactly
    with warnings.catch_warnings():
        warnings.simplefilter("error", audio.AudioWarning)
        assert audio.extract(one, fps=25).values.shape[0] == 1


def test_clipping_warns(rng):
    x = np.clip(3 * rng.standard_normal(RATE), -1, 1)
    with pytest.warns(audio.AudioWarning, match="clipped"):
        audio.prepare(x, RATE)
    low = np.clip(0.2 * rng.standard_normal((RATE, 2)), -0.9, 0.3)  # stereo, then clipped at -1 only
    low[:: 100] = -1.0
    with pytest.warns(audio.AudioWarning, match=r"1\.00% of samples are at full scale"):
        audio.prepare(low, RATE)


def test_files_are_read_without_loss_in_half_the_memory(tmp_path, rng):
    """Files are decoded to float32 (16- and 24-bit PCM exactly) and mixed in float64: the
    samples are the float64 mean of the channels' PCM values."""
    for subtype, full in (("PCM_16", 2 ** 15), ("PCM_24", 2 ** 23)):
        pcm = rng.integers(-full, full, size=(4000, 2))
        path = tmp_path / f"stereo_{subtype}.wav"
        sf.write(path, pcm.astype(np.int32) * (2 ** 31 // full), RATE, subtype=subtype)
        a = audio.load_audio(path, rate=None, remove_dc=False)
        np.testing.assert_array_equal(a.samples, pcm.mean(axis=1) / full)
        assert a.samples.dtype == np.float64 and a.channels == 2


def test_standardizer_fit_transform_and_arrays(rng):
    train = rng.normal(5.0, 3.0, size=(500, 4))
    train[:, 3] = 7.0  # a constant column must not blow up
    s = audio.Standardizer.fit(train)
    z = s.transform(train)
    np.testing.assert_allclose(z[:, :3].mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(z[:, :3].std(axis=0), 1.0, atol=1e-12)
    assert np.all(np.isfinite(z))
    s2 = audio.Standardizer.from_arrays(**s.to_arrays())
    novel = rng.normal(0.0, 1.0, size=(10, 4))
    np.testing.assert_array_equal(s2.transform(novel), s.transform(novel))
    np.testing.assert_allclose(s.inverse_transform(s.transform(novel)), novel, atol=1e-12)
    with pytest.raises(ValueError, match="expected"):
        s.transform(np.zeros((3, 5)))
    with pytest.raises(ValueError, match="std"):
        audio.Standardizer.from_arrays(np.zeros(2), np.array([1.0, 0.0]))


def test_standardizer_checks_columns():
    x = np.sin(np.arange(RATE) * 0.05)
    f_a = audio.extract(audio.prepare(x, RATE), features="mfcc")
    f_b = audio.extract(audio.prepare(x, RATE), features=["log_energy"])
    s = audio.Standardizer.fit(f_a)
    assert s.names == f_a.names
    with pytest.raises(ValueError, match="feature set"):
        s.transform(f_b)


def test_feature_set_validation():
    with pytest.raises(ValueError, match="unknown feature 'pitchh'"):
        audio.FeatureSet(("pitchh",))
    with pytest.raises(ValueError, match="unknown feature set"):
        audio.FeatureSet.named("nope")
    with pytest.raises(ValueError, match="unknown feature option"):
        audio.FeatureSet(("mfcc",), {"n_mfccs": 3})
    fs = audio.FeatureSet.named("puppet", n_lpc_cepstra=4)
    assert audio.FeatureSet.from_json(fs.to_json()) == fs
    with pytest.raises(ValueError, match="fps"):
        audio.extract(audio.prepare(np.ones(RATE) * 0.1 + np.sin(np.arange(RATE)), RATE),
                      fps=0)


def test_features_save_load_roundtrip(tmp_path):
    x = np.sin(np.arange(RATE) * 0.05) * 0.2
    f = audio.extract(audio.prepare(x, RATE), fps=25.0, features="prosody")
    p = tmp_path / "f.npz"
    f.save(p)
    g = audio.Features.load(p)
    np.testing.assert_array_equal(g.values, f.values)
    assert g.names == f.names and g.fps == 25.0 and g.feature_set == f.feature_set
    np.testing.assert_array_equal(g.voiced, f.voiced)
    assert not [n for n in os.listdir(tmp_path) if n != "f.npz"]


# ------------------------------------------------------------------------------------ loading
def _tone(rate, seconds=1.0, freq=440.0, channels=1):
    t = np.arange(int(rate * seconds)) / rate
    x = 0.5 * np.sin(2 * np.pi * freq * t)
    return np.stack([x] * channels, axis=1) if channels > 1 else x


def _dominant_hz(a):
    spec = np.abs(np.fft.rfft(a.samples))
    return np.fft.rfftfreq(a.samples.shape[0], 1.0 / a.rate)[int(np.argmax(spec))]


@pytest.mark.parametrize("ext,fmt,subtype", [(".wav", "WAV", "PCM_16"), (".flac", "FLAC", None),
                                             (".ogg", "OGG", "VORBIS"), (".mp3", "MP3", None)])
def test_load_audio_formats_resample_and_mix(tmp_path, ext, fmt, subtype):
    p = tmp_path / f"tone{ext}"
    x = _tone(44100, 1.0, 440.0, channels=2) + 0.1  # stereo, 44.1 kHz, with DC
    sf.write(p, np.clip(x, -1, 1), 44100, format=fmt, subtype=subtype)
    a = audio.load_audio(p)
    assert a.rate == 16000 and a.source_rate == 44100 and a.channels == 2
    assert a.duration == pytest.approx(1.0, abs=0.06)  # mp3 pads its frames
    assert abs(_dominant_hz(a) - 440.0) <= 2.0
    assert abs(a.samples.mean()) < 1e-9  # DC removed


def _write_video(path, codec_audio=None, seconds=1.0):
    av = pytest.importorskip("av")
    with av.open(str(path), "w") as out:
        v = out.add_stream("mpeg4", rate=25)
        v.width, v.height, v.pix_fmt = 64, 48, "yuv420p"
        if codec_audio:
            a = out.add_stream(codec_audio, rate=16000)
            a.layout = "mono"
        n = int(seconds * 25)
        for i in range(n):
            frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), i * 5 % 255, np.uint8),
                                               format="rgb24")
            for pkt in v.encode(frame):
                out.mux(pkt)
        for pkt in v.encode():
            out.mux(pkt)
        if codec_audio:
            x = _tone(16000, seconds, 440.0).astype(np.float32)
            fmt = "fltp" if codec_audio == "aac" else "s16"
            data = x[None, :] if fmt == "fltp" else (x * 32767).astype(np.int16)[None, :]
            af = av.AudioFrame.from_ndarray(data, format=fmt, layout="mono")
            af.sample_rate = 16000
            for pkt in a.encode(af):
                out.mux(pkt)
            for pkt in a.encode():
                out.mux(pkt)


@pytest.mark.parametrize("ext,codec", [(".mp4", "aac"), (".mkv", "pcm_s16le"),
                                       (".avi", "pcm_s16le"), (".mov", "aac")])
def test_load_audio_track_of_video(tmp_path, ext, codec):
    p = tmp_path / f"clip{ext}"
    _write_video(p, codec)
    a = audio.load_audio(p)
    assert a.rate == 16000 and a.channels == 1
    assert a.duration == pytest.approx(1.0, abs=0.1)
    assert abs(_dominant_hz(a) - 440.0) <= 3.0


def test_video_without_audio_track(tmp_path):
    p = tmp_path / "silent_video.mp4"
    _write_video(p, None)
    with pytest.raises(ValueError, match="no audio track"):
        audio.load_audio(p)


def test_bad_inputs(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        audio.load_audio(tmp_path / "missing.wav")
    empty = tmp_path / "empty.wav"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="empty"):
        audio.load_audio(empty)
    junk = tmp_path / "junk.wav"
    junk.write_bytes(b"this is not audio at all" * 10)
    with pytest.raises(ValueError, match="cannot open"):
        audio.load_audio(junk)
    header_only = tmp_path / "header.wav"
    sf.write(header_only, np.zeros(0), 16000)
    with pytest.raises(ValueError, match="no samples"):
        audio.load_audio(header_only)
    low = tmp_path / "low.wav"
    sf.write(low, _tone(4000), 4000)
    with pytest.raises(ValueError, match="below the minimum 8000 Hz"):
        audio.load_audio(low)
    with pytest.raises(ValueError, match="NaN"):
        audio.prepare(np.array([0.1, np.nan, 0.2] * 1000), RATE)
    with pytest.raises(ValueError, match="shape"):
        audio.prepare(np.zeros((2, 2, 2)), RATE)
    with pytest.raises(ValueError, match="rate"):
        audio.prepare(np.zeros(100), "fast")


def test_cli_features(tmp_path, capsys):
    wav = tmp_path / "v.wav"
    x, _ = source_filter_vowel((600.0, 1700.0, 2500.0), (80.0, 100.0, 120.0), 130.0, 1.0)
    sf.write(wav, x, RATE)
    out = tmp_path / "f.npz"
    assert main(["features", str(wav), "-o", str(out), "--fps", "25", "--set", "mfcc",
                 "--deltas"]) == 0
    with np.load(out) as z:
        assert z["features"].shape == (25, 26)
        assert float(z["fps"]) == 25.0
        assert list(z["names"][:2]) == ["mfcc0", "mfcc1"]
    assert "features:" in capsys.readouterr().err  # the progress bar
    assert main(["features", str(wav), "-o", str(out), "--frames", "31", "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    with np.load(out) as z:
        assert z["features"].shape == (31, 24)  # the default "puppet" set at 29.97 fps
    assert main(["features", str(tmp_path / "nope.wav"), "-o", str(out)]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["features", str(wav), "-o", str(tmp_path / "x.txt")]) == 2


def _ffmpeg_video(tmp_path, name, audio_args, offset=None):
    """A 3 s video made by the ffmpeg tool (as a user's file would be) whose sound is two clicks,
    at 1.0 s and 2.0 s of the audio."""
    import shutil
    import subprocess

    ffmpeg = shutil.which("ffmpeg")
    assert ffmpeg, "the ffmpeg tool is needed (Debian package ffmpeg, installed by .ci/setup)"
    x = np.zeros(3 * RATE)
    x[RATE], x[2 * RATE] = 0.9, -0.9
    wav = tmp_path / "clicks.wav"
    sf.write(wav, x, RATE)
    out = tmp_path / name
    cmd = [ffmpeg, "-loglevel", "error", "-y", "-f", "lavfi", "-i",
           "color=c=gray:s=64x48:r=25:d=3"]
    cmd += (["-itsoffset", str(offset)] if offset else []) + ["-i", str(wav), "-c:v", "mpeg4"]
    subprocess.run(cmd + audio_args + [str(out)], check=True)
    return out


@pytest.mark.parametrize("name,audio_args,offset", [
    ("aac.mp4", ["-c:a", "aac"], None),
    ("vorbis.mkv", ["-c:a", "libvorbis"], None),
    ("pcm.mov", ["-c:a", "pcm_s16le"], None),
    ("late_audio.mp4", ["-c:a", "aac"], 0.37),
])
def test_video_audio_stays_in_sync(tmp_path, name, audio_args, offset):
    """Encoder priming and a delayed audio track do not shift the sound against the video:
    each click lands in the video frame nearest its time, at 29.97 and 25 fps."""
    a = audio.load_audio(_ffmpeg_video(tmp_path, name, audio_args, offset))
    shift = offset or 0.0
    for fps in (29.97, 25.0):
        e = audio.extract(a, fps=fps, features=["log_energy"]).column("log_energy")
        for t in (1.0 + shift, 2.0 + shift):
            k = int(round(t * fps))
            assert k - 2 + int(np.argmax(e[k - 2:k + 3])) == k, (name, fps, t)
    peaks = np.sort(np.argsort(-np.abs(a.samples))[:2])
    np.testing.assert_allclose(peaks / RATE, [1.0 + shift, 2.0 + shift], atol=2e-3)


def test_telephone_rate_8khz():
    """At the lowest accepted rate (8 kHz, kept as is) the formant ceiling drops to Nyquist and
    the known vowel is still recovered."""
    formants = (700.0, 1220.0, 2600.0)
    x, _ = source_filter_vowel(formants, (80.0, 90.0, 120.0), f0=110.0, duration=1.0, rate=8000)
    a = audio.prepare(x, 8000, target_rate=None)
    f = audio.extract(a, fps=29.97, features="all")
    assert np.all(np.isfinite(f.values))
    mid = slice(5, len(f) - 5)
    np.testing.assert_allclose(np.median(f.group("formants")[mid], axis=0), formants, rtol=0.05)
    np.testing.assert_allclose(f.column("f0")[mid], 110.0, rtol=0.01)


def test_unsupported_codec(tmp_path):
    """A WAV container declaring a codec nobody decodes (format tag 0x1234)."""
    import struct

    data = np.zeros(1600, dtype="<i2").tobytes()
    fmt = struct.pack("<HHIIHH", 0x1234, 1, 16000, 32000, 2, 16)
    body = b"WAVE" + b"fmt " + struct.pack("<I", len(fmt)) + fmt + b"data" + \
        struct.pack("<I", len(data)) + data
    p = tmp_path / "odd_codec.wav"
    p.write_bytes(b"RIFF" + struct.pack("<I", len(body)) + body)
    with pytest.raises(ValueError, match="codec .* not supported"):
        audio.load_audio(p)


def test_integer_pcm_is_scaled_to_full_scale():
    x = (0.5 * np.sin(np.arange(RATE) * 0.1) * 32767).astype(np.int16)
    a = audio.prepare(x, RATE, remove_dc=False)
    assert np.max(np.abs(a.samples)) == pytest.approx(0.5, abs=1e-3)
    u = (128 + 64 * np.sin(np.arange(RATE) * 0.1)).astype(np.uint8)
    assert np.max(np.abs(audio.prepare(u, RATE).samples)) == pytest.approx(0.5, abs=0.02)


def test_n_out_matches_a_video_frame_count():
    x = 0.1 * np.sin(np.arange(RATE) * 0.2)  # 1 s
    a = audio.prepare(x, RATE)
    full = audio.extract(a, fps=25.0, features="prosody")
    longer = audio.extract(a, fps=25.0, features="prosody", n_out=30)
    shorter = audio.extract(a, fps=25.0, features="prosody", n_out=10)
    assert len(full) == 25 and len(longer) == 30 and len(shorter) == 10
    assert np.all(np.isfinite(longer.values))
    np.testing.assert_allclose(longer.column("log_energy")[28:], -100.0, atol=1e-6)
    np.testing.assert_allclose(shorter.column("log_energy"), full.column("log_energy")[:10])
    with pytest.raises(ValueError, match="n_out"):
        audio.extract(a, n_out=0)
