"""A live session: a puppet driven by a file played at real-time pace or by raw PCM on standard
input, its frames written as JSON lines and optionally sent over a WebSocket (with a viewer page
on the same port) or OSC (``voicepuppet live PUPPET [--input FILE|-] [--lag-ms 150]``). See
docs/streaming.md.
"""

from __future__ import annotations

import gc
import json
import sys
import time

import numpy as np

from voicepuppet.audio import load_audio
from voicepuppet.audio.conditioning import speech_level_db
from voicepuppet.live.outputs import FaceDriver, OscOut, WebSocketOut, host_port
from voicepuppet.live.puppet import ANALYSIS_RATE, LiveFrames, LivePuppet

#: Audio pushed per step by ``voicepuppet live`` (ms). A frame waits up to one chunk for its audio
#: to be read; with ~0.04 ms of compute per frame, small chunks cost nothing.
CHUNK_MS = 5.0

__all__ = ["CHUNK_MS", "run_live"]


def _read_pcm(stream, fmt: str, channels: int, block_bytes: int):
    """Yield sample arrays (n, channels) from raw PCM; a trailing partial sample is reported."""
    dtype = {"s16le": "<i2", "f32le": "<f4", "s32le": "<i4"}[fmt]
    width = np.dtype(dtype).itemsize * channels
    rest = b""
    first = True
    while True:
        data = stream.read(block_bytes) if hasattr(stream, "read") else b""
        if first and data[:4] == b"RIFF":
            raise ValueError("standard input looks like a WAV file; give it as --input FILE, or "
                             "send raw PCM, e.g. ffmpeg -i IN -f s16le -ac 1 -ar 16000 -")
        first = False
        if not data:
            if rest:
                print(f"voicepuppet live: warning: the stream stopped mid-sample; {len(rest)} "
                      f"trailing byte(s) ignored", file=sys.stderr)
            return
        data = rest + data
        n = len(data) // width
        rest = data[n * width:]
        if n:
            a = np.frombuffer(data[:n * width], dtype=dtype).reshape(n, channels)
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                raise ValueError("malformed PCM: NaN or infinite float samples; check --format "
                                 "(s16le, s32le or f32le) and --channels")
            yield a


def run_live(puppet, *, input_file: str = "-", lag_ms: float = 150.0, fps: float | None = None,
             posterior: bool = False, rate: int = ANALYSIS_RATE, pcm_format: str = "s16le",
             channels: int = 1, chunk_ms: float = CHUNK_MS, realtime: bool = True,
             input_level_db: float | None = None, projection_lag: int | None = None,
             guide_lag: int | None = None, guide_weight: float | None = None,
             decode_lag: int | None = None, trajectory_lag: int | None = None,
             websocket: str | None = None, face: str | None = None, face_points: str | None = None,
             osc: str | None = None, out=None) -> int:
    """Run a live session (the ``live`` verb) until its audio ends.

    Each frame is written to ``out`` as a JSON line (``frame``, ``time``, ``latency_ms``,
    ``points``); a summary (frames, latencies, compute per frame, the look-aheads) goes to
    standard error at the end.

    Parameters
    ----------
    puppet : voicepuppet.puppet.model.Puppet or str
        The puppet, or the path of its ``.vpp`` file.
    input_file : str
        An audio or video file, played at real-time pace unless ``realtime`` is False; ``"-"``
        reads raw PCM from standard input.
    lag_ms : float
        Latency budget in milliseconds (see :func:`voicepuppet.live.puppet.split_lag`).
    fps : float, optional
        Output frame rate (default: the puppet's).
    posterior : bool
        Posterior-weighted synthesis instead of the fixed-lag Viterbi path.
    rate : int
        Sample rate of the PCM on standard input.
    pcm_format : {"s16le", "s32le", "f32le"}
        Sample format of the PCM on standard input.
    channels : int
        Interleaved channels of the PCM on standard input (averaged).
    chunk_ms : float
        Audio pushed per step, in ms.
    realtime : bool
        Play ``input_file`` at real-time pace (False: as fast as possible).
    input_level_db : float, optional
        Speech level of the live audio in dBFS (default: a file's own; on standard input
        estimated from what has been heard).
    projection_lag, guide_lag, decode_lag, trajectory_lag : int, optional
        Explicit look-aheads in frames, as :class:`voicepuppet.live.puppet.LivePuppet` takes them.
    guide_weight : float, optional
        λ of a guided puppet's guide (default: the puppet's).
    websocket : str, optional
        ``HOST:PORT`` to serve the frames (and the viewer page) on over WebSocket.
    face : str, optional
        With ``websocket``: a photo or video the viewer page draws, moved by the frames.
    face_points : str, optional
        The points of ``face`` (JSON, CSV or a landmarks ``.npz``; default: detected with dlib).
    osc : str, optional
        ``HOST:PORT`` to send each frame to as an OSC message ``/voicepuppet/frame``.
    out : text file, optional
        Where the JSON lines go (default: standard output).

    Returns
    -------
    int
        The exit code: 0.

    Raises
    ------
    ValueError
        Bad settings (see :class:`voicepuppet.live.puppet.LivePuppet`), ``face`` without
        ``websocket`` or ``face_points`` without ``face``, a bad ``HOST:PORT``, malformed PCM
        (raised after the frames heard so far are flushed and the summary printed).
    """
    out = out or sys.stdout
    recording = None
    level = input_level_db
    if input_file != "-":
        recording = load_audio(input_file).samples
        if level is None:  # a file's level is known before it plays: scaled as animate scales it
            level = speech_level_db(recording, ANALYSIS_RATE)
    live = LivePuppet(puppet, lag_ms=lag_ms, fps=fps, posterior=posterior,
                      rate=rate if input_file == "-" else ANALYSIS_RATE, input_level_db=level,
                      projection_lag=projection_lag, guide_lag=guide_lag, guide_weight=guide_weight,
                      decode_lag=decode_lag, trajectory_lag=trajectory_lag)
    driver = None
    if face:
        if not websocket:
            raise ValueError("--face draws the face in the viewer page of --websocket: give --websocket HOST:PORT")
        driver = FaceDriver(face, face_points, live.n_points, live.puppet.rest_face())
    elif face_points:
        raise ValueError("--face-points are the points of --face: give --face too")
    ws = WebSocketOut(*host_port(websocket, "websocket"), files=driver.files() if driver else None) \
        if websocket else None
    osc_out = OscOut(*host_port(osc, "osc")) if osc else None
    if ws is not None:
        print(f"voicepuppet live: viewer at http://{websocket.rpartition(':')[0] or '127.0.0.1'}"
              f":{ws.port}/ (WebSocket on the same port)", file=sys.stderr)
    chunk = max(1, int(round(chunk_ms / 1000.0 * live.rate)))
    # Everything allocated so far (modules, the puppet) leaves the cyclic collector's scans: a full
    # collection over it took ~2 ms, the largest compute spikes of the stream (docs/streaming.md).
    gc.freeze()
    latencies, computes = [], []
    t0 = None
    n_frames = 0

    def emit(frames: LiveFrames, now: float, compute: float):
        nonlocal n_frames
        if len(frames) == 0:
            return
        per = compute / len(frames)
        for k, t, pts in zip(frames.frames, frames.times, frames.points):
            lat = now - (t0 + t)  # wall time since the sound of this frame was delivered
            latencies.append(lat)
            computes.append(per)
            rec = {"frame": int(k), "time": round(float(t), 6), "latency_ms": round(lat * 1e3, 3),
                   "points": np.round(pts, 2).tolist()}
            line = json.dumps(rec, separators=(",", ":"))
            try:
                out.write(line + "\n")
            except BrokenPipeError:
                raise SystemExit(0)
            if ws is not None:
                if driver is not None:  # the viewer draws the textured face from the mesh's vertices
                    rec["vertices"] = np.round(driver.vertices(pts), 2).tolist()
                    line = json.dumps(rec, separators=(",", ":"))
                ws.send(line)
            if osc_out is not None:
                osc_out.send(int(k), float(t), pts)
        n_frames += len(frames)
        try:
            out.flush()
        except BrokenPipeError:
            raise SystemExit(0)

    def source():
        if input_file == "-":
            pcm = _read_pcm(sys.stdin.buffer, pcm_format, channels, chunk * channels * 4)
            for a in pcm:
                yield a, False
        else:
            for i in range(0, recording.shape[0], chunk):
                yield recording[i:i + chunk], realtime

    pushed = 0
    err = None
    try:
        for samples, pace in source():
            if t0 is None:
                t0 = time.perf_counter()
            if pace:  # play the file at real-time pace: this chunk is "heard" when it ends
                wait = t0 + (pushed + samples.shape[0]) / live.rate - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
            pushed += samples.shape[0]
            c0 = time.perf_counter()
            frames = live.push(samples)
            c1 = time.perf_counter()
            emit(frames, c1, c1 - c0)
    except ValueError as exc:
        err = exc
    if t0 is None:
        t0 = time.perf_counter()
    c0 = time.perf_counter()
    frames = live.flush()
    c1 = time.perf_counter()
    emit(frames, c1, c1 - c0)
    if ws is not None:
        time.sleep(0.05)
        ws.close()
    if osc_out is not None:
        osc_out.close()
    lat = np.array(latencies) * 1e3 if latencies else np.zeros(1)
    comp = np.array(computes) * 1e3 if computes else np.zeros(1)
    summary = {"frames": n_frames, "audio_s": round(pushed / live.rate, 3),
               "lag_ms": live.lag_ms,
               "algorithmic_latency_ms": round(live.latency_s * 1e3, 2),
               "formant_lag": live.formant_lag, "delta_lag": live.delta_lag,
               "projection_lag": live.projection_lag, "guide_lag": live.guide_lag,
               "guide_weight": live.guide_weight, "decode_lag": live.decode_lag,
               "trajectory_lag": live.trajectory_lag,
               "latency_ms_p50": round(float(np.percentile(lat, 50)), 2),
               "latency_ms_p99": round(float(np.percentile(lat, 99)), 2),
               "compute_ms_per_frame_p50": round(float(np.percentile(comp, 50)), 4),
               "compute_ms_per_frame_p99": round(float(np.percentile(comp, 99)), 4)}
    print("voicepuppet live: " + json.dumps(summary), file=sys.stderr)
    if err is not None:
        raise err
    return 0

