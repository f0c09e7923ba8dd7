"""Streaming audio features (voicepuppet.audio.stream) against the offline front end.

The reference is ``extract(prepare(x, rate, target_rate=None, remove_dc=False))`` on the whole
signal: the stream must give the same frames for any chunking, including one sample at a time,
zero-length chunks, chunks of seconds and stretches of silence.
"""

import math

import numpy as np
import pytest
from scipy.signal import resample_poly

from voicepuppet import data as samples
from voicepuppet.audio import AudioWarning, extract, load_audio, prepare
from voicepuppet.audio.extract import reference_extract
from voicepuppet.audio.conditioning import StreamResampler, pcm_to_float
from voicepuppet.audio.stream import STREAMABLE, StreamingFeatures

SEED = 20261123
RATE = 16000


@pytest.fixture(scope="module")
def speech():
    """CMU ARCTIC a0009 (3.4 s) with 0.5 s of silence inserted, and 0.3 s of silence in front
    (the formant tracker's leading gap)."""
    x = load_audio(samples.arctic_a0009()).samples
    return np.concatenate([np.zeros(4800), x[:20000], np.zeros(8000), x[20000:]])


def offline(x, fps=29.97, features="puppet", n_out=None):
    """The numpy reference (the oracle of the C++ front end) on the whole signal."""
    return reference_extract(prepare(x, RATE, target_rate=None, remove_dc=False), fps=fps,
                             features=features, n_out=n_out)


def stream(x, chunks, fps=29.97, features="puppet", **kw):
    s = StreamingFeatures(features, fps=fps, rate=RATE, **kw)
    out = [s.push(x[a:b]) for a, b in chunks]
    out.append(s.flush())
    for o in out:
        assert o.ndim == 2 and o.shape[1] == s.n_features
    return np.vstack(out), s


def chunking(n, kind, rng):
    if kind == "random":  # 0 .. 3000 samples, zero-length chunks included
        edges = np.cumsum(rng.integers(0, 3000, size=n // 1000 + 10))
    elif kind == "seconds":
        edges = np.arange(0, n + 40000, 40000)  # 2.5 s chunks
    else:
        edges = np.arange(0, n + kind, kind)
    edges = np.concatenate([[0], np.minimum(edges, n), [n]])
    return list(zip(edges[:-1], edges[1:]))


@pytest.mark.parametrize("kind", [160, 7, "random", "seconds"])
def test_puppet_set_equals_offline_for_any_chunking(speech, kind):
    rng = np.random.default_rng(SEED)
    print("seed", SEED)
    ref = offline(speech)
    got, s = stream(speech, chunking(speech.shape[0], kind, rng))
    assert s.names == ref.names
    assert got.shape == ref.values.shape
    # every feature of the default set, column by column
    for j, name in enumerate(ref.names):
        np.testing.assert_allclose(got[:, j], ref.values[:, j], rtol=1e-9, atol=1e-9,
                                   err_msg=name)


def test_one_sample_at_a_time(speech):
    x = speech[:12000]  # 0.75 s: silence, then speech onset
    ref = offline(x)
    got, _ = stream(x, [(i, i + 1) for i in range(x.shape[0])])
    np.testing.assert_allclose(got, ref.values, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("features,fps", [(list(STREAMABLE), 29.97), ("mfcc_deltas", 100.0),
                                          ("puppet", 25.0), ("puppet", 60.0)])
def test_every_streamable_feature_and_rates(speech, features, fps):
    rng = np.random.default_rng(SEED + 1)
    ref = offline(speech, fps, features)
    got, s = stream(speech, chunking(speech.shape[0], "random", rng), fps, features)
    assert s.names == ref.names
    np.testing.assert_allclose(got, ref.values, rtol=1e-9, atol=1e-9)


def test_frames_arrive_once_their_window_is_full(speech):
    """Without formants, every frame is out as soon as the right half of its window has
    arrived (bounded latency), whatever the signal."""
    s = StreamingFeatures("mfcc", fps=29.97, rate=RATE)
    la = s.lookahead_s()
    # window max(25 ms, 1 / fps) = 534 samples in a 540-point FFT frame centred on the frame time
    assert math.isclose(la, (540 - 270) / RATE)
    n_out = 0
    for a in range(0, speech.shape[0], 160):
        n_out += s.push(speech[a:a + 160]).shape[0]
        t = (a + 160) / RATE
        # frames k with k / fps + lookahead <= t must be out, and no frame beyond
        expect = math.floor((t - la) * 29.97 + 1e-9) + 1
        assert abs(n_out - expect) <= 1, (t, n_out, expect)


def test_bounded_formant_lag(speech):
    """formant_lag bounds the wait of the formant tracker: frames leave within the bound;
    columns other than the formants stay exact."""
    lag = 3
    s = StreamingFeatures("puppet", fps=29.97, rate=RATE, formant_lag=lag)
    la = s.lookahead_s()
    out = []
    for a in range(0, speech.shape[0], 160):
        out.append(s.push(speech[a:a + 160]))
        t = (a + 160) / RATE
        n_out = sum(o.shape[0] for o in out)
        assert n_out >= math.floor((t - la) * 29.97) - 1, (t, n_out)
    out.append(s.flush())
    got = np.vstack(out)
    ref = offline(speech)
    fcols = [ref.names.index(c) for c in ("f1", "f2", "f3")]
    other = [j for j in range(len(ref.names)) if j not in fcols]
    np.testing.assert_allclose(got[:, other], ref.values[:, other], rtol=1e-9, atol=1e-9)
    # formants: most frames agree exactly (the tracker usually converges within the bound)
    same = np.all(np.abs(got[:, fcols] - ref.values[:, fcols]) < 1e-6, axis=1)
    assert same.mean() > 0.7
    assert np.all(np.isfinite(got))


def test_exact_formants_wait_for_the_tracker(speech):
    """In exact mode (formant_lag=None) the formant columns may lag, but never emit a frame
    the offline tracker would assign differently (checked against offline above); here: the
    stream holds frames back in the leading silence until speech arrives."""
    s = StreamingFeatures("puppet", fps=29.97, rate=RATE)
    n = s.push(speech[:4000]).shape[0]  # 0.25 s of silence: no formant yet, nothing final
    assert n == 0
    n += s.push(speech[4000:16000]).shape[0]  # speech started at 0.3 s
    assert n > 0


def test_int16_chunks_equal_float(speech):
    pcm = np.round(speech[:16000] * 20000).astype(np.int16)
    a = StreamingFeatures("mfcc")
    b = StreamingFeatures("mfcc")
    ya = np.vstack([a.push(pcm[i:i + 500]) for i in range(0, 16000, 500)] + [a.flush()])
    xf = pcm.astype(np.float64) / 32768.0
    yb = np.vstack([b.push(xf)] + [b.flush()])
    np.testing.assert_allclose(ya, yb, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("rates", [(48000, 16000), (16000, 11000), (22050, 16000)])
def test_stream_resampler_equals_resample_poly(rates):
    rng = np.random.default_rng(SEED + 2)
    x = rng.standard_normal(30011)
    r = StreamResampler(*rates)
    edges = np.concatenate([[0], np.cumsum(rng.integers(0, 2000, size=40))])
    edges = np.minimum(np.concatenate([edges, [x.shape[0]]]), x.shape[0])
    got = np.concatenate([r.push(x[a:b]) for a, b in zip(edges[:-1], edges[1:])] + [r.flush()])
    from fractions import Fraction

    f = Fraction(rates[1], rates[0])
    ref = resample_poly(x, f.numerator, f.denominator)
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


def test_bad_input():
    with pytest.raises(ValueError, match="cannot be computed on a stream"):
        StreamingFeatures("prosody")
    with pytest.raises(ValueError, match="rate"):
        StreamingFeatures("mfcc", rate=4000)
    with pytest.raises(ValueError, match="formant_lag"):
        StreamingFeatures("puppet", formant_lag=-1)
    s = StreamingFeatures("mfcc")
    with pytest.raises(ValueError, match="NaN or infinite"):
        s.push(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="numbers"):
        s.push(np.array(["a", "b"]))
    with pytest.raises(ValueError, match="shape"):
        s.push(np.zeros((2, 2, 2)))
    assert s.flush().shape == (0, 13)  # nothing pushed: no frames
    s.push(np.zeros(100))
    assert s.flush().shape == (1, 13)  # a stream that stops mid-frame: its frame, zero padded
    with pytest.raises(ValueError, match="2 channels|channels"):
        pcm_to_float(np.zeros((3, 0)))


# --------------------------------------------------------------------------- the C++ front end
@pytest.fixture(scope="module")
def espeak_speech():
    """Two espeak-ng sentences (male, female voice; 16 kHz) with a silence between them."""
    from voicepuppet import synth

    if not synth.espeak_available():
        pytest.fail("these tests need espeak-ng (apt-get install espeak-ng; .ci/setup installs it)")
    a = synth.speak("The quick brown fox jumps over the lazy dog.", sample_rate=RATE)
    b = synth.speak("Shall we meet at noon, or later?", voice="en-us+f2", sample_rate=RATE)
    return np.concatenate([a.samples, np.zeros(3000), b.samples]).astype(np.float64)


@pytest.mark.parametrize("chunk", [1, 33, 441, 16000])
def test_every_streamable_feature_on_espeak_speech_any_chunk(espeak_speech, chunk):
    x = espeak_speech if chunk > 1 else espeak_speech[:16000]
    ref = offline(x, 29.97, list(STREAMABLE))
    got, s = stream(x, [(a, a + chunk) for a in range(0, x.shape[0], chunk)], 29.97,
                    list(STREAMABLE))
    assert s.names == ref.names
    for j, name in enumerate(ref.names):
        np.testing.assert_allclose(got[:, j], ref.values[:, j], rtol=1e-9, atol=1e-9,
                                   err_msg=name)


@pytest.mark.parametrize("fps", [24.0, 29.97, 50.0, 100.0])
def test_offline_extract_equals_reference_and_stream(speech, fps):
    """extract (DC removed, one push of the whole signal through the C++ stream) equals the
    numpy reference to 1e-9, and the stream pushed in chunks to rounding (same operations)."""
    a = prepare(speech + 0.01, RATE)  # a DC offset: extract sees it removed
    got = extract(a, fps=fps)
    ref = reference_extract(a, fps=fps)
    assert got.names == ref.names
    np.testing.assert_allclose(got.values, ref.values, rtol=1e-9, atol=1e-9)
    streamed, _ = stream(a.samples, chunking(a.samples.shape[0], 160, None), fps)
    np.testing.assert_allclose(streamed, got.values, rtol=0, atol=1e-12)


@pytest.mark.parametrize("n_out", [10, 200])
def test_extract_n_out_shorter_and_longer_than_the_audio(speech, n_out):
    """A frame count other than the audio's (a video's): the formant tracker decides over
    exactly n_out frames, frames past the end see silence, as the reference."""
    a = prepare(speech, RATE)
    got = extract(a, fps=29.97, features=list(STREAMABLE), n_out=n_out)
    ref = reference_extract(a, fps=29.97, features=list(STREAMABLE), n_out=n_out)
    assert got.values.shape == ref.values.shape == (n_out, len(ref.names))
    np.testing.assert_allclose(got.values, ref.values, rtol=1e-9, atol=1e-9)


def test_silence_and_empty_chunks_only():
    """All-zero input (and zero-length chunks) gives the floors and the reference formants,
    as the reference does."""
    x = np.zeros(9000)
    chunks = [(0, 0), (0, 4000), (4000, 4000), (4000, 9000), (9000, 9000)]
    got, _ = stream(x, chunks, 29.97, list(STREAMABLE))
    from voicepuppet.audio import AudioWarning

    with pytest.warns(AudioWarning, match="silent"):
        ref = offline(x, 29.97, list(STREAMABLE))
    np.testing.assert_allclose(got, ref.values, rtol=1e-9, atol=1e-9)
    f = ref.names.index("f1")
    assert np.all(got[:, f:f + 3] == [550.0, 1650.0, 2750.0])


def test_formant_lag_counts_forced_frames(speech):
    exact = StreamingFeatures("puppet", fps=29.97, rate=RATE)
    lagged = StreamingFeatures("puppet", fps=29.97, rate=RATE, formant_lag=0)
    for a in range(0, speech.shape[0], 160):
        exact.push(speech[a:a + 160])
        lagged.push(speech[a:a + 160])
    assert exact.formants_forced == 0
    assert lagged.formants_forced > 0


def test_bad_input_names_the_argument():
    from voicepuppet import _core

    s = StreamingFeatures("puppet")
    with pytest.raises(ValueError, match="NaN or infinite"):
        s.push(np.array([0.0, np.inf, 1.0]))
    with pytest.raises(ValueError, match="samples must be numbers"):
        s.push(np.array([b"x"]))
    with pytest.raises(ValueError, match=r"rate must be a whole number of Hz >= 8000, got 7999"):
        StreamingFeatures("puppet", rate=7999)
    with pytest.raises(ValueError, match="rate must be a whole number"):
        StreamingFeatures("puppet", rate=16000.5)
    with pytest.raises(ValueError, match="fps"):
        StreamingFeatures("puppet", fps=0)
    with pytest.raises(ValueError, match="formant_lag"):
        StreamingFeatures("puppet", formant_lag=1.5)
    with pytest.raises(ValueError, match="rate_in"):
        StreamResampler(0, 16000)
    # the core refuses inconsistent tables, naming the option
    o = _core.AudioFeatureOptions()
    o.features = ["log_energy"]
    o.n_fft = 400
    o.spectral_window = np.ones(400)
    o.parseval = np.ones(7)
    with pytest.raises(ValueError, match="parseval must have 201 entries, got 7"):
        _core.StreamingAudioFeatures(o)
    o.features = ["f0"]
    with pytest.raises(ValueError, match="unknown feature 'f0'"):
        _core.StreamingAudioFeatures(o)
    # a NaN pushed into the core directly (bypassing pcm_to_float) is refused, nothing consumed
    c = StreamingFeatures("mfcc")._core
    with pytest.raises(ValueError, match="samples contain NaN"):
        c.push(np.array([0.0, np.nan]))
    assert c.samples_in == 0


def test_core_pieces_against_numpy():
    """The C++ Levinson, autocorrelation, cepstrum and roots against the numpy definitions."""
    from voicepuppet import _core
    from voicepuppet.audio import lpc

    rng = np.random.default_rng(SEED + 3)
    print("seed", SEED + 3)
    x = rng.standard_normal(400) * np.hamming(400)
    r = _core.autocorrelation(x, 12)
    np.testing.assert_allclose(r, lpc.autocorrelation(x[None, :], 12)[0], rtol=1e-12, atol=1e-12)
    a, err = _core.levinson(r, 12)
    A, E = lpc.levinson(r[None, :], 12)
    np.testing.assert_allclose(a, A[0], rtol=1e-12, atol=1e-12)
    assert math.isclose(err, E[0], rel_tol=1e-12)
    np.testing.assert_allclose(_core.lpc_cepstrum(a, err, 14),
                               lpc.lpc_to_cepstrum(A, E, 14)[0], rtol=1e-11, atol=1e-12)
    roots = np.array(_core.lpc_roots(a))
    ref = lpc.lpc_roots(A)[0]
    np.testing.assert_allclose(np.sort_complex(roots), np.sort_complex(ref), rtol=1e-10)


@pytest.mark.parametrize("rate", [8000, 11025, 22050, 44100])
def test_other_analysis_rates(rate):
    """At 8 and 11.025 kHz (formants without resampling, or with 11025 -> 11000) every column
    within 1e-9 of the reference; at 22.05 and 44.1 kHz too, except the raw order-12 LPC
    coefficients, whose normal equations are ill-conditioned at high rates: two correct
    autocorrelations (direct sums, FFT) differing by rounding give coefficients ~1e-8 apart
    (the cepstra stay within 1e-9)."""
    x16 = load_audio(samples.arctic_a0009()).samples[:24000]
    x = resample_poly(x16, rate, 16000)
    a = prepare(x, rate, target_rate=None, remove_dc=False)
    ref = reference_extract(a, fps=29.97, features=list(STREAMABLE))
    s = StreamingFeatures(list(STREAMABLE), fps=29.97, rate=rate)
    got = np.vstack([s.push(x[i:i + 777]) for i in range(0, x.shape[0], 777)] + [s.flush()])
    for j, name in enumerate(ref.names):
        tol = 1e-7 if (rate > 16000 and name.startswith("lpc") and not name.startswith("lpcc")) \
            else 1e-9
        np.testing.assert_allclose(got[:, j], ref.values[:, j], rtol=tol, atol=tol, err_msg=name)


def test_push_releases_the_gil(speech):
    """While one thread is inside the C++ push, another runs Python: iterations of the main
    thread are seen strictly inside the call's time window (with the GIL held there would be
    none, whatever the machine's speed)."""
    import threading
    import time

    x = np.tile(speech, 40)  # ~2.5 min of audio: a long C++ call
    s = StreamingFeatures("puppet")
    window = {}

    def work():
        t0 = time.perf_counter()
        s._core.push(x)
        window["span"] = (t0, time.perf_counter())

    stamps = []
    th = threading.Thread(target=work)
    th.start()
    while th.is_alive():
        stamps.append(time.perf_counter())
    th.join()
    t0, t1 = window["span"]
    margin = 0.25 * (t1 - t0)
    inside = [t for t in stamps if t0 + margin < t < t1 - margin]
    assert len(inside) > 0, (t1 - t0, len(stamps))


@pytest.mark.parametrize("lag", [None, 0, 1, 3, 7])
def test_formant_tracker_equals_its_numpy_oracle(speech, lag):
    """The C++ tracker against the numpy one (tests/formant_tracker_reference.py, the Python
    stream's tracker before the port) on the reference candidates of real speech, pushed in
    random batches with a forced decision after each batch: the same rows, the same number of
    forced frames. With lag None this is the exact mode (also equal to the offline Viterbi)."""
    from formant_tracker_reference import FormantTrackerReference

    from voicepuppet import _core
    from voicepuppet.audio import lpc

    fs = 11000
    y = resample_poly(speech, 11, 16)
    T = math.ceil(speech.shape[0] * 29.97 / RATE - 1e-9)
    a, _ = lpc.lpc_frames(y, fs, 29.97, T, order=10, window_s=0.05,
                          preemph=math.exp(-2.0 * math.pi * 50.0 / fs), window="gaussian")
    f, b = lpc.formant_candidates(a, fs, max_bandwidth=1000.0)
    ref = FormantTrackerReference(3, fs / 2.0, 5, lag)
    core = _core.FormantTracker(lpc.reference_formants(fs / 2.0, 3), 5,
                                -1 if lag is None else lag)
    rng = np.random.default_rng(SEED + 4)
    print("seed", SEED + 4)
    edges = np.minimum(np.concatenate([[0], np.cumsum(rng.integers(1, 5, size=T))]), T)
    got, want = [], []
    for k0, k1 in zip(edges[:-1], edges[1:]):
        if k1 <= k0:
            continue
        want += ref.push(f[k0:k1], b[k0:k1]) + ref.force()
        got += list(core.push(f[k0:k1], b[k0:k1])) + list(core.force())
        assert len(got) == 3 * len(want)  # the same frames leave at the same push
    want += ref.finish()
    got += list(core.finish())
    want = np.vstack(want)
    np.testing.assert_allclose(np.reshape(got, (-1, 3)), want, rtol=1e-14, atol=0)
    assert want.shape == (T, 3)
    assert core.forced == ref.forced
    assert (core.forced > 0) == (lag is not None)  # the silences make every bound force
    if lag is None:
        np.testing.assert_allclose(want, lpc.track_formants(f, b, ceiling=fs / 2.0),
                                   rtol=1e-14)


def test_band_limiter_is_resample_poly_down_and_up_in_any_chunking():
    """band_hz=4000 at 16 kHz: scipy's resample_poly to 8 kHz and back, cut to the input's
    length, whole or pushed in random chunks (zero-length ones included); its stated delay is
    the two filters' half lengths; bad bands are refused."""
    from voicepuppet.audio.conditioning import BandLimiter

    rng = np.random.default_rng(SEED + 7)
    x = rng.standard_normal(20011)
    want = resample_poly(resample_poly(x, 1, 2), 2, 1)[:x.size]
    np.testing.assert_allclose(BandLimiter(4000, RATE).apply(x), want, rtol=0, atol=1e-12)
    lim = BandLimiter(4000, RATE)
    edges = np.minimum(np.concatenate([[0], np.cumsum(rng.integers(0, 3000, size=12)), [x.size]]), x.size)
    got = np.concatenate([lim.push(x[a:b]) for a, b in zip(edges[:-1], edges[1:])] + [lim.flush()])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert lim.delay_s == pytest.approx(20 / 16000 + 20 / 16000)  # half_len 10 max(up, down) each way
    t = np.arange(RATE) / RATE
    for hz, lo, hi in ((1000, -0.05, 0.05), (6000, -300, -40)):  # level (dB) after the limiter
        y = BandLimiter(4000, RATE).apply(np.sin(2 * np.pi * hz * t))[2000:-2000]
        level = 20 * np.log10(np.sqrt(np.mean(y ** 2)) / np.sqrt(0.5))
        assert lo <= level <= hi, (hz, level)
    for bad in (0, -1, 8000, 9000, 4000.25, "x"):
        with pytest.raises(ValueError, match="band_hz"):
            BandLimiter(bad, RATE)
    with pytest.raises(ValueError, match="band_hz must be a frequency"):
        extract(prepare(x, RATE), features=["bands"], band_hz=-5)


def test_a_band_limited_feature_set_hears_wide_audio_as_telephone_audio(speech):
    """The same speech at 16 kHz and as an 8 kHz recording (scipy's FIR decimate, another filter
    than the limiter's, then prepared as a loaded 8 kHz file is): without a band their puppet
    features differ (z-scored distance 0.65 on 2.5 s of ARCTIC a0009), with band_hz=4000 far less
    (0.10; on 3 s, ffmpeg's resampler instead: 0.70 and 0.14); the stream in chunks equals extract on the
    whole, and its look-ahead grows by the limiter's delay."""
    from scipy.signal import decimate

    x = speech[:40000]
    tel = prepare(decimate(x, 2, ftype="fir"), 8000)
    full = extract(prepare(x, RATE)).values
    scale = full.std(axis=0) + 1e-9
    before = np.mean(np.abs(full - extract(tel).values) / scale)
    after = np.mean(np.abs(extract(prepare(x, RATE), band_hz=4000.0).values - extract(tel, band_hz=4000.0).values)
                    / scale)
    print(f"z-distance, 16 kHz against 8 kHz features: whole band {before:.3f}, band_hz 4000 {after:.3f}")
    assert before > 0.5 and after < before / 5
    a = prepare(x, RATE, remove_dc=False)
    got, s = stream(a.samples, chunking(a.samples.size, "random", np.random.default_rng(SEED)), band_hz=4000.0)
    want = extract(a, band_hz=4000.0).values
    np.testing.assert_allclose(got[:len(want)], want, rtol=1e-9, atol=1e-9)
    assert s.lookahead_s() == pytest.approx(StreamingFeatures("puppet").lookahead_s() + 0.0025)


def test_level_db_brings_every_recording_to_one_level_and_its_pauses_to_one_floor(speech):
    """The level_db option: a recording is scaled so its speech level is level_db, and its frames
    more than GATE_BELOW_DB under that become dither DITHER_BELOW_DB under it (speech frames
    untouched), so a recording and the same 20 dB quieter give the same features (to rounding),
    digital silence and a quiet noise floor become the dither, a near-silent recording is raised
    by at most MAX_GAIN_DB, and the same input gives the same samples."""
    from voicepuppet.audio.conditioning import (DITHER_BELOW_DB, GATE_BELOW_DB, MAX_GAIN_DB, LevelNormalizer,
                                                speech_level_db)

    level = -20.0
    a, b = (prepare(g * speech, RATE, target_rate=None, remove_dc=False) for g in (1.0, 0.1))
    fa = extract(a, fps=29.97, features="puppet", level_db=level).values
    fb = extract(b, fps=29.97, features="puppet", level_db=level).values
    np.testing.assert_allclose(fa, fb, rtol=0, atol=1e-7 * np.abs(fa).max())
    assert not np.allclose(extract(a, fps=29.97).values, extract(b, fps=29.97).values, atol=1e-3)
    ref = reference_extract(a, fps=29.97, features="puppet", level_db=level).values
    np.testing.assert_allclose(fa, ref, rtol=0, atol=1e-9 * np.abs(ref).max())  # the oracle does the same
    norm = LevelNormalizer(level, RATE)
    y = norm.apply(speech)
    assert abs(speech_level_db(y, RATE) - level) < 0.1
    np.testing.assert_array_equal(y, norm.apply(speech))  # seeded: the same samples again
    gain = 10 ** ((level - speech_level_db(speech, RATE)) / 20)
    loudest = np.argmax(np.abs(speech))
    assert y[loudest] == pytest.approx(speech[loudest] * gain, rel=1e-12)  # speech as it was, scaled
    silent = norm.apply(np.zeros(RATE))
    dither_rms = 10 ** ((level - DITHER_BELOW_DB) / 20)
    assert np.sqrt(np.mean(silent ** 2)) == pytest.approx(dither_rms, rel=0.02)
    floor = 10 ** ((speech_level_db(speech, RATE) - GATE_BELOW_DB - 3) / 20)  # a floor just under the gate
    roomy = np.concatenate([speech, floor * np.random.default_rng(SEED).standard_normal(RATE)])
    pause = norm.apply(roomy)[speech.size + 160:]
    assert np.sqrt(np.mean(pause ** 2)) == pytest.approx(dither_rms, rel=0.05)  # the floor became the dither
    with pytest.warns(AudioWarning, match=r"speech level is -6\d dBFS, \d\d dB under the puppet's -20: raised by 30 dB"):
        quiet = norm.apply(10 ** (-50 / 20) * speech)  # speech 50 dB down: raised 30 dB, not ~37
    assert speech_level_db(quiet, RATE) == pytest.approx(speech_level_db(speech, RATE) - 50 + MAX_GAIN_DB, abs=0.1)
    with pytest.raises(ValueError, match="level_db must be a speech level in dBFS"):
        extract(a, fps=29.97, level_db=12)


def test_a_stream_at_a_known_level_is_the_recording_and_otherwise_estimates_it(speech):
    """Given the recording's level the stream is scaled as the recording is (the same frames for
    any chunking); without it the gain is 1 for the first LEVEL_SETTLE_S, then that of the
    LEVEL_PERCENTILE of what has been heard (to the histogram's 0.25 dB)."""
    from voicepuppet.audio.conditioning import LEVEL_SETTLE_S, LevelNormalizer, speech_level_db

    x = 0.1 * speech
    au = prepare(x, RATE, target_rate=None, remove_dc=False)
    ref = extract(au, fps=29.97, features="puppet", level_db=-20.0).values
    got, _ = stream(x, chunking(x.size, "random", np.random.default_rng(SEED)), level_db=-20.0,
                    input_level_db=speech_level_db(au.samples, RATE))
    np.testing.assert_array_equal(got, ref)
    whole = speech_level_db(x, RATE)
    known, heard = LevelNormalizer(-20.0, RATE, input_level_db=whole), LevelNormalizer(-20.0, RATE)
    g_known = known.gain(whole)
    step = 4000
    for start in range(0, x.size - step, step):
        chunk = x[start:start + step]
        fixed, est = known.push(chunk), heard.push(chunk)
        loud = np.abs(chunk * g_known) > 0.03  # in speech frames, left as they are but for the gain
        if not loud.any():
            continue
        gain = g_known * np.median(est[loud] / fixed[loud])
        if start < LEVEL_SETTLE_S * RATE:
            assert gain == pytest.approx(1.0, rel=1e-6)
        else:
            so_far = speech_level_db(x[:start], RATE)
            assert 20 * np.log10(gain) == pytest.approx(min(-20.0 - so_far, 30.0), abs=0.25)
