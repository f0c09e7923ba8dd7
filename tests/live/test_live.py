"""Live voice puppetry (voicepuppet.live, voicepuppet::StreamingPuppet): the stream against the
offline puppet, latency bounds, the ``live`` verb (file, raw PCM on stdin, WebSocket, viewer in
headless Chromium) and bad input.

The test puppet is trained on CMU ARCTIC a0009 (real speech) with a face whose mouth and jaw
follow the speech's loudness (a planted audio-visual link), small enough to train in seconds.
"""

import io
import json
import math
import os
import socket
import sys
import threading
import time

import numpy as np
import pytest

from voicepuppet.animation import neutral_landmarks
from voicepuppet import data as samples
from voicepuppet.audio import load_audio, prepare
from voicepuppet.audio.conditioning import speech_level_db
from voicepuppet.live.puppet import TRUSTED_GUIDE_WEIGHT, LivePuppet, split_lag

SEED = 20261123
FPS = 30000 / 1001


@pytest.fixture(scope="module")
def speech():
    """0.2 s of silence, a0009, 0.4 s of silence, a0009 again (two passes for training)."""
    x = load_audio(samples.arctic_a0009()).samples
    return np.concatenate([np.zeros(3200), x, np.zeros(6400), x])


def planted_face(speech):
    """The audio and a face whose mouth and jaw follow its loudness: (Audio, points [T, 68, 2])."""
    from voicepuppet.audio import extract

    rng = np.random.default_rng(SEED)
    au = prepare(speech, 16000, target_rate=None, remove_dc=False)
    energy = extract(au, fps=FPS, features="prosody").column("log_energy")
    T = energy.shape[0]
    open_ = np.clip((energy - energy.min()) / (np.ptp(energy) + 1e-9), 0, 1)
    open_ = np.convolve(open_, np.ones(3) / 3, mode="same")
    base = neutral_landmarks()
    pts = np.repeat(base[None], T, axis=0)
    pts[:, 57:60, 1] += 14 * open_[:, None]   # lower lip down
    pts[:, 65:68, 1] += 10 * open_[:, None]
    pts[:, 6:11, 1] += 8 * open_[:, None]     # jaw
    pts[:, 48, 0] += 3 * open_                # mouth corners in
    pts[:, 54, 0] -= 3 * open_
    pts += rng.normal(0, 0.3, pts.shape)
    return au, pts


@pytest.fixture(scope="module")
def puppet(speech, tmp_path_factory):
    from voicepuppet.puppet.model import Puppet

    au, pts = planted_face(speech)
    p = Puppet.train([pts], [au], fps=FPS, n_states=8, n_iter=8, seed=0)
    assert p._core.guided and p._core.guide_context == 5  # the default: guided by the ridge
    path = tmp_path_factory.mktemp("live") / "test.vpp"
    p.save(path)
    return p, path


def stream_all(live, x, chunks):
    out = []
    first = None
    for a, b in chunks:
        f = live.push(x[a:b])
        if len(f):
            assert first is None or f.first_frame == first
            first = f.first_frame + len(f)
            out.append(f.points)
    f = live.flush()
    assert first is None or f.first_frame == first
    out.append(f.points)
    return np.concatenate(out)


def random_chunks(n, rng, hi=3000):
    edges = np.minimum(np.cumsum(rng.integers(0, hi, size=n // (hi // 2) + 20)), n)
    edges = np.concatenate([[0], edges, [n]])
    return list(zip(edges[:-1], edges[1:]))


@pytest.mark.parametrize("posterior,fps", [(False, None), (True, None), (False, 60.0),
                                           (True, 25.0)])
def test_large_lags_give_the_offline_animation(puppet, speech, posterior, fps):
    """Lags covering the stream and exact formant decisions: the streamed animation is the
    offline one (same frames, same points), whatever the chunking."""
    p, _ = puppet
    x = speech[:40000]  # 2.5 s: silence, speech
    ref = p.animate(full_motion=False, audio=prepare(x, 16000, target_rate=None, remove_dc=False), fps=fps,
                    posterior=posterior).animation.points
    live = LivePuppet(p, fps=fps, posterior=posterior, formant_lag=-1, delta_lag=-1,
                      decode_lag=2000, trajectory_lag=2000, input_level_db=speech_level_db(x, 16000))
    assert p.feature_set.settings()["level_db"] == -20.0  # training's default: levels brought to -20 dBFS
    assert live.delta_lag == p._core.delta_width == 2
    assert (live.guide_lag, live.guide_weight) == (5, p.guide_weight)  # the exact guide at the file's λ, as offline
    assert math.isinf(live.latency_s)
    got = stream_all(live, x, random_chunks(x.shape[0], np.random.default_rng(SEED)))
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-8 * np.abs(ref).max())


def test_bounded_lag_emits_within_the_latency(puppet, speech):
    p, _ = puppet
    live = LivePuppet(p, lag_ms=150)
    assert live.latency_s <= 0.150 + 1e-9
    # budget 3 frames: formants 0, deltas 1, decoder 1 + 1 from the trajectory (the fixture's
    # cross-validation trusts its guide: λ >= TRUSTED_GUIDE_WEIGHT), trajectory 0
    assert p.guide_weight >= TRUSTED_GUIDE_WEIGHT
    assert (live.formant_lag, live.delta_lag, live.decode_lag, live.trajectory_lag) == \
        (0, 1, 2, 0)
    assert live.guide_lag == 2  # the decoder's look-ahead, shared at no cost
    n_out = 0
    x = speech[:48000]
    frames = []
    for a in range(0, x.shape[0], 160):
        f = live.push(x[a:a + 160])
        frames.append(f.points)
        n_out += len(f)
        t = (a + 160) / 16000
        # every frame whose sound plus the latency has been heard is out
        assert n_out >= max(0, math.floor((t - live.latency_s) * FPS + 1e-9) + 1), (t, n_out)
    frames.append(live.flush().points)
    got = np.concatenate(frames)
    ref = p.animate(full_motion=False, audio=prepare(x, 16000, target_rate=None, remove_dc=False)).animation.points
    assert got.shape == ref.shape
    assert np.all(np.isfinite(got))
    # the mouth moves with the speech in both
    lip = lambda P: P[:, 57, 1] - P[:, 51, 1]  # noqa: E731
    assert np.corrcoef(lip(got), lip(ref))[0, 1] > 0.5


def test_split_lag():
    # (formant, delta, projection, guide, decode, trajectory); budget = floor((0.150 - 0.026) *
    # 29.97) = 3 frames
    assert split_lag(150, FPS, 0.026, True) == (0, 0, 0, 0, 2, 1)
    assert split_lag(150, FPS, 0.026, True, 2) == (0, 1, 0, 0, 1, 1)
    # budget 9: formants 2, deltas min(2, 7 // 3) = 2, decoder 3, trajectory 2
    assert split_lag(330, FPS, 0.026, True, 2) == (2, 2, 0, 0, 3, 2)
    assert split_lag(330, FPS, 0.017, False) == (0, 0, 0, 0, 5, 4)
    assert split_lag(0, FPS, 0.026, True, 2) == (0, 0, 0, 0, 0, 0)
    # a projection of +-5 frames: half what the formants leave, rounded up (at most 5), then
    # the deltas
    assert split_lag(150, FPS, 0.026, True, 0, 5) == (0, 0, 2, 0, 1, 0)
    assert split_lag(330, FPS, 0.026, True, 2, 5) == (2, 1, 4, 0, 1, 1)
    assert split_lag(1000, FPS, 0.026, True, 0, 5) == (2, 0, 5, 0, 11, 11)
    # a guide of +-5 frames takes the projection's and the decoder's look-ahead (at most 5),
    # leaving the rest of the split as it was
    assert split_lag(150, FPS, 0.026, True, 2, 0, 5) == (0, 1, 0, 1, 1, 1)
    assert split_lag(330, FPS, 0.026, True, 2, 0, 5) == (2, 2, 0, 3, 3, 2)
    assert split_lag(330, FPS, 0.026, True, 2, 5, 5) == (2, 1, 4, 5, 1, 1)
    assert split_lag(1000, FPS, 0.026, True, 2, 0, 3) == (2, 2, 0, 3, 13, 12)
    # a guide weighted >= 8 takes one frame of the trajectory's share for the decoder (and itself)
    assert split_lag(150, FPS, 0.026, True, 2, 0, 5, 4.0) == (0, 1, 0, 1, 1, 1)
    assert split_lag(150, FPS, 0.026, True, 2, 0, 5, 8.0) == (0, 1, 0, 2, 2, 0)
    assert split_lag(330, FPS, 0.026, True, 2, 0, 5, 32.0) == (2, 2, 0, 4, 4, 1)
    assert split_lag(150, FPS, 0.026, True, 0, 5, 5, 64.0) == (0, 0, 2, 3, 1, 0)  # no frame to take
    assert split_lag(330, FPS, 0.026, True, 0, 5, 5, 64.0) == (2, 0, 4, 5, 2, 1)  # projected: as at λ < 8
    assert split_lag(330, FPS, 0.026, True, 2, 0, 0, 64.0) == (2, 2, 0, 0, 3, 2)  # no guide
    with pytest.raises(ValueError, match="lag_ms"):
        split_lag(-5, FPS, 0.026, True)


def test_other_input_rate_is_resampled_on_the_stream(puppet, speech):
    from scipy.signal import resample_poly

    p, _ = puppet
    y = resample_poly(speech[:24000], 3, 1)  # 48 kHz
    au = prepare(y, 48000, remove_dc=False)
    ref = p.animate(full_motion=False, audio=au).animation.points
    live = LivePuppet(p, rate=48000, formant_lag=-1, delta_lag=-1, decode_lag=1000,
                      trajectory_lag=1000, input_level_db=speech_level_db(au.samples, 16000))
    got = stream_all(live, y, random_chunks(y.shape[0], np.random.default_rng(SEED + 1)))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6 * np.abs(ref).max())


def test_bad_input(puppet, tmp_path):
    p, _ = puppet
    with pytest.raises(ValueError, match="lag_ms"):
        LivePuppet(p, lag_ms=-1)
    with pytest.raises(ValueError, match="decode_lag"):
        LivePuppet(p, decode_lag=-2)
    with pytest.raises(ValueError, match="delta width"):
        LivePuppet(p, delta_lag=3)
    with pytest.raises(ValueError, match="rate"):
        LivePuppet(p, rate=1000)
    with pytest.raises(ValueError, match="puppet"):
        LivePuppet(object())
    with pytest.raises(ValueError, match="does not exist"):
        LivePuppet(str(tmp_path / "missing.vpp"))
    live = LivePuppet(p)
    with pytest.raises(ValueError, match="NaN"):
        live.push(np.array([0.1, np.inf]))
    assert len(live.flush()) == 0  # nothing pushed


# ------------------------------------------------------------------ the guide on the stream
def test_guide_weight_zero_streams_brands_trajectory(puppet, speech):
    """guide_weight=0: the stream is the offline animate(guide_weight=0), and the guide moved
    the face (so the guided comparisons above test the guide's stream)."""
    p, _ = puppet
    x = speech[:40000]
    au = prepare(x, 16000, target_rate=None, remove_dc=False)
    ref0 = p.animate(full_motion=False, audio=au, guide_weight=0).animation.points
    guided = p.animate(full_motion=False, audio=au).animation.points
    assert np.abs(guided - ref0).max() > 0.05
    level = speech_level_db(x, 16000)
    live = LivePuppet(p, guide_weight=0, formant_lag=-1, delta_lag=-1, decode_lag=2000,
                      trajectory_lag=2000, input_level_db=level)
    assert (live.guide_lag, live.guide_weight) == (0, 0.0)  # nothing waits for an unused guide
    got = stream_all(live, x, random_chunks(x.shape[0], np.random.default_rng(SEED + 5)))
    np.testing.assert_allclose(got, ref0, rtol=0, atol=1e-8 * np.abs(ref0).max())
    # another weight is the offline solve with that weight
    ref2 = p.animate(full_motion=False, audio=au, guide_weight=2.5).animation.points
    live = LivePuppet(p, guide_weight=2.5, posterior=False, formant_lag=-1, delta_lag=-1,
                      decode_lag=2000, trajectory_lag=2000, input_level_db=level)
    got = stream_all(live, x, random_chunks(x.shape[0], np.random.default_rng(SEED + 6)))
    np.testing.assert_allclose(got, ref2, rtol=0, atol=1e-8 * np.abs(ref2).max())


def test_guide_lag_and_latency(puppet):
    """The guide's look-ahead up to the decoder's is free; beyond it, it is latency."""
    p, _ = puppet
    window = LivePuppet(p).features.lookahead_s()
    live = LivePuppet(p, lag_ms=150)  # deltas 1, decoder 2, trajectory 0, guide 2 (λ >= 8)
    assert live.latency_s == pytest.approx(window + 3 / FPS, abs=1e-12)
    exact = LivePuppet(p, lag_ms=150, guide_lag=-1)
    assert exact.guide_lag == 5
    # delta 1 + max(decoder 2, guide 5) + trajectory 0
    assert exact.latency_s == pytest.approx(window + 6 / FPS, abs=1e-12)
    assert LivePuppet(p, lag_ms=150, guide_lag=0).latency_s == pytest.approx(live.latency_s)
    # an explicit decoder lag carries the free guide look-ahead with it
    assert LivePuppet(p, lag_ms=150, decode_lag=3).guide_lag == 3
    assert LivePuppet(p, lag_ms=150, decode_lag=9).guide_lag == 5
    with pytest.raises(ValueError, match="guide context 5"):
        LivePuppet(p, guide_lag=6)
    with pytest.raises(ValueError, match="guide_lag must be a whole number"):
        LivePuppet(p, guide_lag=-2)
    for bad in (-1.0, math.nan, math.inf, "1"):
        with pytest.raises(ValueError, match="guide_weight must be a finite number"):
            LivePuppet(p, guide_weight=bad)


def test_unguided_puppet_streams_without_a_guide(speech):
    from voicepuppet.puppet.model import Puppet

    au, pts = planted_face(speech[:48000])
    p = Puppet.train([pts], [au], fps=FPS, n_states=4, n_iter=4, seed=0, guide="none")
    live = LivePuppet(p, lag_ms=150)
    assert (live.guide_lag, live.guide_weight) == (0, 0.0)
    with pytest.raises(ValueError, match="needs a guided puppet"):
        LivePuppet(p, guide_weight=1)
    with pytest.raises(ValueError, match="guide context 0"):
        LivePuppet(p, guide_lag=1)


def test_puppet_with_a_feature_set_the_stream_cannot_make(speech):
    from voicepuppet.puppet.model import Puppet

    rng = np.random.default_rng(SEED)
    au = prepare(speech[:32000], 16000, target_rate=None, remove_dc=False)
    T = math.ceil(32000 / 16000 * FPS)
    pts = neutral_landmarks()[None] + rng.normal(0, 1, (T, 68, 2))
    p = Puppet.train([pts], [au], fps=FPS, n_states=3, n_iter=2, feature_set="prosody")
    with pytest.raises(ValueError, match="cannot be computed on a stream"):
        LivePuppet(p)


# ------------------------------------------------------------------------------ the verb
class _Result:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def run_cli(args, stdin=b""):
    """``voicepuppet live ARGS`` in this process with ``stdin`` as raw bytes on standard input."""
    import contextlib

    from voicepuppet.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    old_in = sys.stdin
    sys.stdin = io.TextIOWrapper(io.BytesIO(stdin or b""))
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(["live", *args])
    finally:
        sys.stdin = old_in
    return _Result(code, out.getvalue().encode(), err.getvalue().encode())


def test_cli_file_json_lines(puppet, speech, tmp_path):
    p, path = puppet
    import soundfile

    wav = tmp_path / "in.wav"
    x = speech[:32000]
    soundfile.write(wav, x, 16000, subtype="DOUBLE")
    r = run_cli([str(path), "--input", str(wav), "--no-realtime", "--lag-ms", "150"])
    assert r.returncode == 0, r.stderr.decode()
    lines = r.stdout.decode().splitlines()
    recs = [json.loads(s) for s in lines]
    x_loaded = load_audio(str(wav)).samples
    ref = p.animate(full_motion=False, audio=prepare(x_loaded, 16000, target_rate=None, remove_dc=False)).animation.points
    assert [r_["frame"] for r_ in recs] == list(range(ref.shape[0]))
    pts = np.array([r_["points"] for r_ in recs])
    assert pts.shape == ref.shape
    level = speech_level_db(x_loaded, 16000)  # a file's level is known before it plays
    live = LivePuppet(p, lag_ms=150, input_level_db=level)
    own = stream_all(live, x_loaded, [(a, a + 160) for a in range(0, x_loaded.shape[0], 160)])
    np.testing.assert_allclose(pts, own, atol=0.006)  # JSON rounds to 0.01 px
    summary = json.loads(r.stderr.decode().split("voicepuppet live: ", 1)[1])
    assert summary["frames"] == ref.shape[0]
    assert summary["algorithmic_latency_ms"] <= 150
    assert (summary["guide_lag"], summary["guide_weight"]) == (2, p.guide_weight)  # λ >= 8: decoder 2
    # --guide-weight 0: Brand's unguided stream; --guide-lag -1: the exact guide, reported
    for extra, want in ((["--guide-weight", "0"], dict(guide_weight=0.0)),
                        (["--guide-lag", "-1"], dict(guide_lag=-1)),
                        (["--decode-lag", "1", "--trajectory-lag", "1"],
                         dict(decode_lag=1, trajectory_lag=1))):
        r = run_cli([str(path), "--input", str(wav), "--no-realtime", "--lag-ms", "150", *extra])
        assert r.returncode == 0, r.stderr.decode()
        got = np.array([json.loads(s)["points"] for s in r.stdout.decode().splitlines()])
        own = stream_all(LivePuppet(p, lag_ms=150, input_level_db=level, **want), x_loaded,
                         [(a, a + 160) for a in range(0, x_loaded.shape[0], 160)])
        np.testing.assert_allclose(got, own, atol=0.006)
        assert np.abs(got - pts).max() > 0.05  # not the default stream
        summary = json.loads(r.stderr.decode().split("voicepuppet live: ", 1)[1])
        assert summary["guide_lag"] == {"guide_weight": 0, "guide_lag": 5, "decode_lag": 1}[next(iter(want))]
        # unguided (λ = 0) the trajectory keeps its frame; the trusted guide's split gives it away
        kind = next(iter(want))
        assert (summary["decode_lag"], summary["trajectory_lag"]) == \
            {"guide_weight": (1, 1), "guide_lag": (2, 0), "decode_lag": (1, 1)}[kind]


def test_cli_raw_pcm_on_stdin(puppet, speech):
    _, path = puppet
    pcm = np.round(speech[:16000] * 20000).astype("<i2").tobytes() + b"\x01"  # stops mid-sample
    r = run_cli([str(path), "--input", "-", "--lag-ms", "100"], stdin=pcm)
    assert r.returncode == 0, r.stderr.decode()
    assert "stopped mid-sample; 1 trailing byte(s) ignored" in r.stderr.decode()
    n = len(r.stdout.decode().splitlines())
    assert n == math.ceil(16000 / 16000 * FPS)
    # --input-level: the stream scaled from the first sample by the level given, as a LivePuppet
    # told the same level (standard input's own level is otherwise estimated as it comes)
    x = np.frombuffer(pcm[:-1], dtype="<i2") / 32768.0
    level = speech_level_db(x, 16000) - 6.0
    r = run_cli([str(path), "--input", "-", "--lag-ms", "100", "--input-level", str(level)], stdin=pcm)
    assert r.returncode == 0, r.stderr.decode()
    got = np.array([json.loads(s_)["points"] for s_ in r.stdout.decode().splitlines()])
    own = stream_all(LivePuppet(path, lag_ms=100, input_level_db=level), x, [(a, a + 80) for a in range(0, x.size, 80)])
    np.testing.assert_allclose(got, own, atol=0.006)
    estimated = np.array([json.loads(s_)["points"] for s_ in
                          run_cli([str(path), "--input", "-", "--lag-ms", "100"], stdin=pcm).stdout.decode().splitlines()])
    assert np.abs(estimated - got).max() > 0.05  # the level given is not the one estimated
    # stereo float PCM at 48 kHz
    st = np.repeat(speech[:48000:3, None], 2, axis=1)
    from scipy.signal import resample_poly

    st = resample_poly(st, 3, 1, axis=0).astype("<f4")
    r = run_cli([str(path), "--rate", "48000", "--format", "f32le", "--channels", "2"],
                stdin=st.tobytes())
    assert r.returncode == 0, r.stderr.decode()
    assert len(r.stdout.decode().splitlines()) == math.ceil(st.shape[0] / 48000 * FPS)


def test_cli_bad_input(puppet, tmp_path):
    _, path = puppet
    r = run_cli([str(path)], stdin=b"RIFF\x24\x00\x00\x00WAVEfmt ")
    assert r.returncode == 2 and b"looks like a WAV file" in r.stderr
    bad = np.array([0.1, np.nan, 0.2], dtype="<f4").tobytes()
    r = run_cli([str(path), "--format", "f32le"], stdin=bad)
    assert r.returncode == 2 and b"malformed PCM" in r.stderr
    r = run_cli([str(tmp_path / "nope.vpp")], stdin=b"")
    assert r.returncode == 2 and b"does not exist" in r.stderr
    r = run_cli([str(path), "--websocket", "localhost"], stdin=b"")
    assert r.returncode == 2 and b"HOST:PORT" in r.stderr
    r = run_cli([str(path), "--input", str(tmp_path / "none.wav")])
    assert r.returncode == 2 and b"does not exist" in r.stderr
    r = run_cli([str(path)], stdin=b"")  # empty stream: no frames, clean exit
    assert r.returncode == 0 and r.stdout == b""


# ------------------------------------------------------------------- WebSocket and the viewer
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_live(argv):
    """``voicepuppet live ARGV`` in a thread: (thread, its stdout, {"code": exit code} when done)."""
    from voicepuppet.cli.live import _run
    from voicepuppet.cli.main import build_parser

    args = build_parser().parse_args(argv)
    out = io.StringIO()
    result = {}
    th = threading.Thread(target=lambda: result.setdefault("code", _run(args, out)), daemon=True)
    th.start()
    return th, out, result


def connect_frames(port: int):
    """A WebSocket client of ``live --websocket`` on ``port``, once its server is up."""
    from websockets.sync.client import connect

    for _ in range(200):
        try:
            return connect(f"ws://127.0.0.1:{port}/frames", open_timeout=2)
        except OSError:
            time.sleep(0.05)
    pytest.fail("WebSocket server did not come up")


def chromium():
    """Headless Chromium through selenium (the Debian chromium and chromedriver when installed)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--window-size=520,560"):
        opts.add_argument(a)
    if os.path.exists("/usr/bin/chromium"):
        opts.binary_location = "/usr/bin/chromium"
    service = Service("/usr/bin/chromedriver") if os.path.exists("/usr/bin/chromedriver") else Service()
    return webdriver.Chrome(options=opts, service=service)


def test_websocket_stream_and_viewer_in_headless_chromium(puppet, speech, tmp_path):
    """A real-time run serving WebSocket: a client that connects and disconnects mid-stream
    does not disturb it; the viewer page, loaded in headless Chromium, draws the frames."""
    import soundfile
    from PIL import Image
    from selenium.webdriver.support.ui import WebDriverWait

    _, path = puppet
    wav = tmp_path / "in.wav"
    # 10 s played in real time: room for a slow browser start on a busy machine
    audio = np.tile(speech, 2)[:160000]
    soundfile.write(wav, audio, 16000, subtype="DOUBLE")
    port = free_port()
    th, out, result = start_live(["live", str(path), "--input", str(wav), "--websocket", f"127.0.0.1:{port}",
                                  "--lag-ms", "100"])
    # a client that takes a few frames and leaves
    got = []
    with connect_frames(port) as ws:
        for _ in range(5):
            got.append(json.loads(ws.recv(timeout=5)))
    assert [g["frame"] for g in got] == list(range(got[0]["frame"], got[0]["frame"] + 5))
    assert np.array(got[0]["points"]).shape == (68, 2)
    # the viewer page in headless Chromium
    driver = chromium()
    try:
        driver.set_page_load_timeout(20)
        driver.get(f"http://127.0.0.1:{port}/")
        WebDriverWait(driver, 30).until(
            lambda d: int(d.execute_script("return document.body.dataset.frames || 0")) >= 10)
        shot = tmp_path / "viewer.png"
        driver.save_screenshot(str(shot))
        status = driver.execute_script("return document.getElementById('status').textContent")
    finally:
        driver.quit()
    assert status == "connected"
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    # the face is drawn in dark red on the light canvas
    red = (img[..., 0] > 90) & (img[..., 0] < 160) & (img[..., 1] < 80) & (img[..., 2] < 80)
    assert red.sum() > 300, f"no face drawn in {shot}"
    th.join(60)
    assert not th.is_alive() and result["code"] == 0
    lines = out.getvalue().splitlines()
    assert len(lines) == math.ceil(160000 / 16000 * FPS)


def test_viewer_draws_the_textured_face_as_render_does(puppet, speech, tmp_path):
    """``live --face``: the server gives the viewer the face's mesh and photo and each frame's
    vertices (those ``render`` drives the mesh to, from the puppet's face in silence); the page,
    in headless Chromium, warps the photo triangle by triangle, and the frame it drew matches the
    offline pyvista render of the same vertices."""
    import base64
    import urllib.request

    import soundfile
    from PIL import Image
    from selenium.webdriver.support.ui import WebDriverWait

    from voicepuppet import render
    from voicepuppet.animation import Animation

    p, path = puppet
    # a face of the puppet's layout: the drawn portrait of its rest shape, moved into a 320x300 photo
    pts = neutral_landmarks() + [0.0, -20.0]
    img = render.portrait_image(pts, 320, 300)
    Image.fromarray(img).save(tmp_path / "face.png")
    (tmp_path / "face.json").write_text(json.dumps({"points": pts.tolist()}))
    wav = tmp_path / "in.wav"
    soundfile.write(wav, np.tile(speech, 2)[:160000], 16000, subtype="DOUBLE")
    port = free_port()
    th, out, result = start_live(["live", str(path), "--input", str(wav), "--websocket", f"127.0.0.1:{port}",
                                  "--face", str(tmp_path / "face.png"), "--face-points", str(tmp_path / "face.json")])
    with connect_frames(port) as ws:
        msg = json.loads(ws.recv(timeout=5))
    mesh = render.load_face(tmp_path / "face.png", tmp_path / "face.json")
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/mesh.json", timeout=5) as r:
        assert r.headers["Content-Type"] == "application/json"
        doc = json.loads(r.read())
    assert (doc["width"], doc["height"]) == (320, 300)
    np.testing.assert_array_equal(doc["triangles"], mesh.faces)
    np.testing.assert_array_equal(doc["mouth"], mesh.mouth)
    # the cavity and the teeth in their colours, the skin textured; back to front
    assert mesh.teeth.sum() == 64
    assert [c is None for c in doc["colours"]] == (~mesh.flat).tolist()
    np.testing.assert_array_equal([c for c in doc["colours"] if c is not None], mesh.colours[mesh.flat])
    np.testing.assert_array_equal(doc["order"], mesh.draw_order())
    np.testing.assert_allclose(doc["uv"], mesh.uv, atol=1e-7)
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/face.png", timeout=5) as r:
        assert r.headers["Content-Type"] == "image/png"
        np.testing.assert_array_equal(np.asarray(Image.open(io.BytesIO(r.read())).convert("RGB")), img)
    assert np.array(msg["vertices"]).shape == (len(mesh.vertices), 2)
    driver = chromium()
    try:
        driver.set_page_load_timeout(20)
        driver.get(f"http://127.0.0.1:{port}/")
        WebDriverWait(driver, 30).until(
            lambda d: d.execute_script("return document.body.dataset.face") == "yes"
            and int(d.execute_script("return document.body.dataset.frames || 0")) >= 10)
        # the frame drawn and the canvas at one moment (the page's script runs between events)
        drawn, url = driver.execute_script(
            "return [document.body.dataset.drawn, document.getElementById('face').toDataURL('image/png')];")
    finally:
        driver.quit()
    th.join(60)
    assert not th.is_alive() and result["code"] == 0
    lines = [json.loads(x) for x in out.getvalue().splitlines()]
    stream = np.array([x["points"] for x in lines])
    # the vertices sent are render's, from the puppet's rest face (stdout's points: 0.01 px)
    rest_face = p.rest_face()
    assert np.abs(rest_face - stream[0]).max() > 0.5
    want = render.mesh_animation(Animation(stream, FPS, neutral=rest_face), mesh)["vertices"]
    np.testing.assert_allclose(msg["vertices"], want[msg["frame"], :, :2], atol=0.05)
    shot = np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB")).astype(int)
    assert shot.shape == (300, 320, 3)
    with render.FaceRenderer(mesh, size=(320, 300)) as r:
        ref = r.frame(want[int(drawn)]).astype(int)
        rest = r.frame(mesh.vertices).astype(int)
    diff = np.abs(shot - ref).mean()
    assert diff < 2.0, f"the viewer's frame {drawn} differs from render's by {diff:.2f} grey levels"
    # no seams between the triangles: where render's frame is flat, the page's is too
    from scipy.ndimage import maximum_filter, minimum_filter

    grey = ref.sum(axis=2)
    flat = maximum_filter(grey, 5) == minimum_filter(grey, 5)
    assert flat.mean() > 0.5 and (np.abs(shot - ref).max(axis=2)[flat] > 12).mean() < 0.002
    # and the drawn frame is that frame, not the photo at rest: where they differ, it is render's
    moved = np.abs(ref - rest).max(axis=2) > 40
    assert moved.sum() > 30
    assert np.abs(shot - ref)[moved].mean() < 0.5 * np.abs(shot - rest)[moved].mean()


def test_face_options_are_checked_before_the_stream(puppet, speech, tmp_path, capsys):
    """--face without --websocket, --face-points without --face, a face of another layout: each
    refused by name before any frame is written (exit code 2)."""
    import soundfile
    from PIL import Image

    from voicepuppet import render
    from voicepuppet.cli.main import main

    _, path = puppet
    wav = tmp_path / "in.wav"
    soundfile.write(wav, speech[:8000], 16000, subtype="DOUBLE")
    pts = neutral_landmarks()
    face = tmp_path / "face.png"
    Image.fromarray(render.portrait_image(pts, 320, 320)).save(face)
    few = tmp_path / "few.json"
    few.write_text(json.dumps({"points": pts[:10].tolist()}))
    common = ["live", str(path), "--input", str(wav), "--no-realtime"]
    cases = [(["--face", str(face)], "give --websocket"),
             (["--websocket", f"127.0.0.1:{free_port()}", "--face-points", str(few)], "give --face too"),
             (["--websocket", f"127.0.0.1:{free_port()}", "--face", str(face), "--face-points", str(few)],
              "has 10 points and the puppet's landmarks 68")]
    capsys.readouterr()
    for extra, msg in cases:
        assert main(common + extra) == 2
        got = capsys.readouterr()
        assert msg in got.err and got.out == ""  # refused before any frame


def test_osc_messages(puppet, speech, tmp_path):
    """--osc sends one /voicepuppet/frame message per frame (frame, time, x0, y0, ...) over UDP."""
    import soundfile
    from pythonosc.osc_message import OscMessage

    _, path = puppet
    wav = tmp_path / "in.wav"
    soundfile.write(wav, speech[:16000], 16000, subtype="DOUBLE")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(5)
    port = sock.getsockname()[1]
    try:
        r = run_cli([str(path), "--input", str(wav), "--no-realtime", "--osc",
                     f"127.0.0.1:{port}"])
        assert r.returncode == 0, r.stderr.decode()
        lines = [json.loads(s) for s in r.stdout.decode().splitlines()]
        msgs = []
        for _ in range(len(lines)):
            msgs.append(OscMessage(sock.recv(65536)))
    finally:
        sock.close()
    assert all(m.address == "/voicepuppet/frame" for m in msgs)
    assert [m.params[0] for m in msgs] == [rec["frame"] for rec in lines]
    first = np.array(msgs[0].params[2:], dtype=np.float64).reshape(68, 2)
    np.testing.assert_allclose(first, np.array(lines[0]["points"]), atol=0.006)


# ------------------------------------------------------------------ a projected puppet on the stream
@pytest.fixture(scope="module")
def projected(speech, tmp_path_factory):
    """The test puppet's face and audio, trained with the option for voices never heard: vocal
    Gaussians (one tied covariance) on a projection of +-5 standardised frames."""
    from voicepuppet.puppet.model import Puppet

    au, pts = planted_face(speech)
    p = Puppet.train([pts], [au], fps=FPS, n_states=8, n_iter=8, seed=0, vocal_features="projected",
                     vocal_covariance="tied")
    assert p._core.guided
    assert p._core.projected and p._core.projection_context == 5 and p._core.delta_width == 2
    path = tmp_path_factory.mktemp("live_projected") / "projected.vpp"
    p.save(path)
    return p, path


def test_projected_puppet_core_stream_is_the_offline_projection_and_animation(projected, speech):
    """The C++ stream on feature frames: every frame's vocal features (the first and last 5
    included) are Puppet::project of the whole sequence's standardised frames, and the face the
    offline animation, for pushes of 1, 7 and all frames."""
    from voicepuppet import _core
    from voicepuppet.audio import extract

    p, _ = projected
    au = prepare(speech[:40000], 16000, target_rate=None, remove_dc=False)
    feats = np.ascontiguousarray(extract(au, fps=FPS, features=p.feature_set).values)
    core = p._core
    v_ref = np.asarray(core.project(core.standardize(feats)))
    for posterior, fps in ((False, 0.0), (True, 25.0)):
        ref = np.asarray(core.animate(feats, fps, posterior)["points"])
        sp = _core.StreamingPuppet(core, 2000, 2000, fps, posterior)
        assert (sp.delta_lag, sp.projection_lag) == (0, 5)  # the projection reads no deltas
        for chunk in (1, 7, feats.shape[0]):
            got = [sp.push(feats[a:a + chunk]) for a in range(0, feats.shape[0], chunk)]
            got.append(sp.flush())
            assert [g.first_vocal for g in got] == list(np.cumsum([0] + [g.vocal.shape[0]
                                                                         for g in got])[:-1])
            v = np.vstack([g.vocal for g in got])
            assert v.shape == v_ref.shape
            np.testing.assert_allclose(v, v_ref, rtol=0, atol=1e-12 * (1 + np.abs(v_ref).max()))
            pts = np.vstack([g.points for g in got])
            assert pts.shape == ref.shape
            np.testing.assert_allclose(pts, ref, rtol=0, atol=1e-8 * np.abs(ref).max())


@pytest.mark.parametrize("posterior,fps", [(False, None), (True, 60.0)])
def test_projected_puppet_large_lags_give_the_offline_animation(projected, speech, posterior, fps):
    p, _ = projected
    x = speech[:40000]
    ref = p.animate(full_motion=False, audio=prepare(x, 16000, target_rate=None, remove_dc=False), fps=fps,
                    posterior=posterior).animation.points
    live = LivePuppet(p, fps=fps, posterior=posterior, formant_lag=-1, delta_lag=-1,
                      projection_lag=-1, decode_lag=2000, trajectory_lag=2000,
                      input_level_db=speech_level_db(x, 16000))
    assert (live.delta_lag, live.projection_lag) == (0, 5)
    got = stream_all(live, x, random_chunks(x.shape[0], np.random.default_rng(SEED + 3)))
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-8 * np.abs(ref).max())


def test_projected_puppet_latency(projected, puppet):
    p, _ = projected
    window = LivePuppet(p).features.lookahead_s()
    # the budget: 3 frames at 150 ms, the projection takes two of them
    live = LivePuppet(p, lag_ms=150)
    assert (live.formant_lag, live.delta_lag, live.projection_lag, live.decode_lag,
            live.trajectory_lag) == (0, 0, 2, 1, 0)
    assert live.guide_lag == 3  # the projection's and the decoder's look-ahead: no latency
    assert live.latency_s == pytest.approx(window + 3 / FPS, abs=1e-12)
    # exact vocal features: 5 frames (167 ms) on top of the decoder's; the guide follows
    exact = LivePuppet(p, lag_ms=150, projection_lag=-1)
    assert (exact.projection_lag, exact.guide_lag) == (5, 5)
    assert exact.latency_s == pytest.approx(window + 6 / FPS, abs=1e-12)
    with pytest.raises(ValueError, match="projection context 5"):
        LivePuppet(p, projection_lag=6)
    with pytest.raises(ValueError, match="projection_lag must be a whole number"):
        LivePuppet(p, projection_lag=-2)
    with pytest.raises(ValueError, match="projection context 0"):  # a puppet without one
        LivePuppet(puppet[0], projection_lag=1)
    assert LivePuppet(puppet[0]).projection_lag == 0


def test_cli_projected_puppet(projected, speech, tmp_path):
    import soundfile

    p, path = projected
    wav = tmp_path / "in.wav"
    soundfile.write(wav, speech[:24000], 16000, subtype="DOUBLE")
    n = math.ceil(24000 / 16000 * FPS)
    window = LivePuppet(p).features.lookahead_s()
    summaries = {}
    for extra in ([], ["--projection-lag", "-1"]):
        r = run_cli([str(path), "--input", str(wav), "--no-realtime", "--lag-ms", "150", *extra])
        assert r.returncode == 0, r.stderr.decode()
        assert len(r.stdout.decode().splitlines()) == n
        summaries[len(extra)] = json.loads(r.stderr.decode().split("voicepuppet live: ", 1)[1])
    budget, exact = summaries[0], summaries[2]
    assert budget["projection_lag"] == 2 and exact["projection_lag"] == 5
    assert budget["algorithmic_latency_ms"] == pytest.approx((window + 3 / FPS) * 1e3, abs=0.01)
    assert budget["algorithmic_latency_ms"] <= 150
    # the exact projection reports its 3 more frames of look-ahead
    assert exact["algorithmic_latency_ms"] == pytest.approx((window + 6 / FPS) * 1e3, abs=0.01)
