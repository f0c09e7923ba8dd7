"""Live voice puppetry: audio in as it is heard, face frames out with a latency you choose.

:class:`LivePuppet` composes the streaming front end (:mod:`voicepuppet.audio.stream`) and the
C++ streaming puppet (``voicepuppet::StreamingPuppet``, ``cpp/include/voicepuppet/streaming.hpp``:
fixed-lag Viterbi or posteriors, then the fixed-lag trajectory solve):

>>> live = LivePuppet(voicepuppet.load("me.vpp"), lag_ms=150)     # doctest: +SKIP
>>> frames = live.push(chunk)          # any number of samples -> LiveFrames (M frames, M >= 0)
>>> frames.points.shape                # (M, P, 2) pixel landmarks                # doctest: +SKIP
>>> rest = live.flush()                # end of the stream: the frames still held back

Latency. A face frame ``k`` shows the sound at time ``k / fps``. It can be emitted once the
analysis windows around that time are full (``window_s``: about 17 ms after it for the spectra,
26 ms for the formants), plus the look-ahead given to the formant tracker, the audio deltas, a
projected puppet's vocal features (``vocal_features="projected"``: ±k frames of audio), the state
decoder and the trajectory solve. A guided puppet's guide (the ridge's prediction of the face from
±k_g frames of audio, docs/puppet.md) looks ahead alongside the projection and the decoder, so
its look-ahead up to theirs costs no latency. ``lag_ms`` is the budget for all of it: the windows
take what they need and the rest (whole frames) is split between the look-aheads (see
:func:`split_lag`).
Below the windows' own look-ahead (``lag_ms`` under ~26 ms) nothing is left to split and the
latency is the windows'.

``voicepuppet live PUPPET [--input FILE|-] [--lag-ms 150]`` runs it on a file played at real-time
pace or on raw PCM from standard input, writes JSON lines and optionally sends the frames over a
WebSocket (with a viewer page on the same port) or OSC. See docs/streaming.md.
"""

from __future__ import annotations

import gc
import json
import math
import os
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

from voicepuppet.audio.stream import StreamingFeatures, StreamResampler, pcm_to_float

#: Sample rate of the analysis (the rate puppets are trained at: load_audio's default).
ANALYSIS_RATE = 16000
#: Audio pushed per step by ``voicepuppet live`` (ms). A frame waits up to one chunk for its audio
#: to be read; with ~0.04 ms of compute per frame, small chunks cost nothing.
CHUNK_MS = 5.0

__all__ = ["LivePuppet", "LiveFrames", "split_lag", "add_parser"]


@dataclass
class LiveFrames:
    """Face frames emitted by :meth:`LivePuppet.push` or :meth:`LivePuppet.flush`.

    Attributes
    ----------
    first_frame : int
        Output index of the first frame.
    points : ndarray, shape (M, P, 2)
        Pixel landmarks (x, y) at the training mean pose.
    face : ndarray, shape (M, K)
        Face coordinates (parts side by side).
    fps : float
        Output frame rate; frame ``k`` shows the sound at ``k / fps`` seconds.
    """

    first_frame: int
    points: np.ndarray
    face: np.ndarray
    fps: float

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def frames(self) -> np.ndarray:
        """Output indices, shape (M,)."""
        return np.arange(self.first_frame, self.first_frame + len(self))

    @property
    def times(self) -> np.ndarray:
        """Times in seconds of the sound each frame shows, shape (M,)."""
        return self.frames / self.fps


#: A guide weighted at least this much (a puppet that trusts the ridge over its vocal HMM, as the
#: training's cross-validation decides for real speech) gets one frame more of the budget in
#: :func:`split_lag`, from the trajectory (docs/streaming.md, "The split for a puppet that
#: trusts its guide").
TRUSTED_GUIDE_WEIGHT = 8.0


def split_lag(lag_ms: float, fps: float, window_s: float, formants: bool,
              delta_width: int = 0, projection_context: int = 0, guide_context: int = 0,
              guide_weight: float = 0.0) -> tuple:
    """Split a latency budget into look-aheads (frames at ``fps``).

    The analysis windows take ``window_s``; the whole frames left, ``B = floor((lag_ms / 1000 -
    window_s) fps)``, are shared: if the feature set has formants, one frame in four (at most
    2) to the formant tracker; if the puppet's vocal features are a projection of ±k frames,
    half the rest, rounded up (at most ``projection_context`` k), to its look-ahead (measured
    better than a third, docs/streaming.md); if they read audio deltas (``delta_width`` w > 0),
    a third of the rest (at most w) to theirs; the remainder to the state decoder and the
    trajectory solve, half each (the decoder gets the odd frame). A guided puppet's guide
    (``guide_context`` k_g > 0) reads the audio alongside the projection and the decoder, so it
    gets their look-ahead for free: ``guide_lag = min(k_g, projection_lag + decode_lag)``
    (giving it more of the budget was measured not to pay at λ = 4, docs/streaming.md). A guide
    weighted ``guide_weight`` >= :data:`TRUSTED_GUIDE_WEIGHT` takes one frame of the trajectory's
    share (when it has one) for the decoder, and so for itself, in a puppet without a projection
    (measured better for puppets of real speech, λ 32–64, on readers they never heard).

    Returns
    -------
    (formant_lag, delta_lag, projection_lag, guide_lag, decode_lag, trajectory_lag) : tuple of int
    """
    if not (isinstance(lag_ms, (int, float)) and math.isfinite(lag_ms) and lag_ms >= 0):
        raise ValueError(f"lag_ms must be a non-negative number of milliseconds, got {lag_ms!r}")
    budget = max(0, int(math.floor((lag_ms / 1000.0 - window_s) * fps + 1e-9)))
    f = min(2, budget // 4) if formants else 0
    rest = budget - f
    pl = min(int(projection_context), (rest + 1) // 2)
    rest -= pl
    dl = min(int(delta_width), rest // 3)
    rest -= dl
    decode = (rest + 1) // 2
    if guide_context > 0 and guide_weight >= TRUSTED_GUIDE_WEIGHT and not projection_context \
            and rest - decode > 0:  # (measured on puppets without a projection)
        decode += 1
    gl = min(int(guide_context), pl + decode)
    return f, dl, pl, gl, decode, rest - decode


class LivePuppet:
    """A voice puppet driven live: push audio chunks, get face frames.

    Parameters
    ----------
    puppet : voicepuppet.puppet.model.Puppet or str
        The puppet (or the path of a ``.vpp`` file). Its feature set must be streamable
        (``voicepuppet.audio.stream.STREAMABLE``: every named set except those with F0).
    lag_ms : float
        Latency budget in milliseconds (see :func:`split_lag`); ignored for the look-aheads given
        explicitly below.
    fps : float, optional
        Output frame rate (default: the puppet's).
    posterior : bool
        Posterior-weighted synthesis (fixed-lag smoothed posteriors) instead of the fixed-lag
        Viterbi path.
    rate : int
        Sample rate of the pushed audio; other rates than 16000 are resampled on the stream with
        ``resample_poly``'s filter.
    formant_lag, delta_lag, projection_lag, guide_lag, decode_lag, trajectory_lag : int, optional
        Explicit look-aheads in frames. ``formant_lag=-1`` waits for the formant tracker's
        exact decisions (unbounded latency), ``delta_lag=-1`` uses the delta look-ahead the
        vocal features need to be exact (the puppet's delta width; 0 when they are a projection
        of the features alone, as ``vocal_features="projected"`` trains them),
        ``projection_lag=-1`` a projected puppet's full context k (0 .. k; missing future frames
        repeat the newest one), ``guide_lag=-1`` a guided puppet's full guide context k_g (0 ..
        k_g, likewise); with all four at -1 and large decode and trajectory lags the output is
        exactly ``puppet.animate`` of the same audio.
    guide_weight : float, optional
        λ of a guided puppet's guide (default: the file's, chosen at training); 0 streams Brand's unguided
        trajectory, as ``animate(guide_weight=0)``.
    input_level_db : float, optional
        For a puppet that brings audio to a speech level (feature option ``level_db``, the
        default of training): the live audio's speech level in dBFS, if known
        (:func:`voicepuppet.audio.stream.speech_level_db` of a recording of the same source),
        so the stream is scaled as ``animate`` scales it from the first sample; without it the
        level is estimated from what has been heard (the first second as it comes).
    """

    def __init__(self, puppet, lag_ms: float = 150.0, *, fps: float | None = None,
                 posterior: bool = False, rate: int = ANALYSIS_RATE, formant_lag: int | None = None,
                 delta_lag: int | None = None, projection_lag: int | None = None,
                 guide_lag: int | None = None, guide_weight: float | None = None,
                 decode_lag: int | None = None, trajectory_lag: int | None = None,
                 input_level_db: float | None = None):
        from voicepuppet import _core

        if isinstance(puppet, (str, os.PathLike)):
            from voicepuppet.puppet.model import load

            puppet = load(puppet)
        core = getattr(puppet, "_core", None)
        if core is None or not hasattr(puppet, "feature_set"):
            raise ValueError(f"puppet must be a voicepuppet Puppet or a .vpp path, got "
                             f"{type(puppet).__name__}")
        self.puppet = puppet
        fset = puppet.feature_set
        names = list(puppet.metadata.get("feature_names", []))
        self.features = StreamingFeatures(fset, fps=puppet.fps, rate=ANALYSIS_RATE, input_level_db=input_level_db)
        if names and list(self.features.names) != names:
            raise ValueError(f"this puppet was trained on features the stream cannot compute "
                             f"(columns {names[:3]}...; the stream makes "
                             f"{list(self.features.names)[:3]}...): train it from audio with a "
                             "streamable feature set")
        if int(core.n_features) != self.features.n_features:
            raise ValueError(f"puppet expects {core.n_features} audio features, its feature set "
                             f"gives {self.features.n_features}; the puppet file is inconsistent")
        has_formants = "formants" in fset.features
        window = self.features.lookahead_s()
        width = int(core.delta_width)
        k = int(core.projection_context)
        if guide_weight is None:
            lam = float(core.guide_weight) if core.guided else 0.0
        elif not (isinstance(guide_weight, (int, float, np.number)) and math.isfinite(guide_weight)
                  and guide_weight >= 0):
            raise ValueError(f"guide_weight must be a finite number >= 0, got {guide_weight!r}")
        else:
            lam = float(guide_weight)
        kg = int(core.guide_context) if lam > 0 else 0  # (a positive λ for an unguided puppet:
        # StreamingPuppet says it needs a guided one)
        # the delta look-ahead the vocal features need (none for a projection of the features
        # alone, a projected puppet's default with context)
        f, dl, pl, gl, d, t = split_lag(float(lag_ms), puppet.fps, window, has_formants,
                                        int(core.vocal_delta_width), k, kg, lam)
        f = f if formant_lag is None else formant_lag
        dl = dl if delta_lag is None else delta_lag
        pl = pl if projection_lag is None else projection_lag
        d = d if decode_lag is None else decode_lag
        t = t if trajectory_lag is None else trajectory_lag
        if guide_lag is not None:
            gl = guide_lag
        elif projection_lag is not None or decode_lag is not None:
            # the free look-ahead follows explicit projection / decoder lags
            gl = min(kg, max(0, (k if pl < 0 else pl) + d))
        for name, v in (("formant_lag", f), ("delta_lag", dl), ("projection_lag", pl),
                        ("guide_lag", gl), ("decode_lag", d), ("trajectory_lag", t)):
            if not isinstance(v, (int, np.integer)) or v < (-1 if name in ("formant_lag",
                                                                          "delta_lag",
                                                                          "projection_lag",
                                                                          "guide_lag")
                                                             else 0):
                raise ValueError(f"{name} must be a whole number of frames >= 0, got {v!r}")
        if dl > width:
            raise ValueError(f"delta_lag must be at most the puppet's delta width {width}, got "
                             f"{dl}")
        if pl > k:
            raise ValueError(f"projection_lag must be at most the puppet's projection context "
                             f"{k} (frames of audio on each side its vocal features read), got "
                             f"{pl}")
        if guide_lag is not None and guide_lag > int(core.guide_context):
            raise ValueError(f"guide_lag must be at most the puppet's guide context "
                             f"{int(core.guide_context)} (frames of audio on each side its guide "
                             f"reads; 0 for a puppet without a guide), got {guide_lag}")
        self.formant_lag = None if f < 0 else int(f)
        if has_formants:
            self.features = StreamingFeatures(fset, fps=puppet.fps, rate=ANALYSIS_RATE,
                                              formant_lag=self.formant_lag, input_level_db=input_level_db)
        out_fps = 0.0 if fps is None else float(fps)
        if fps is not None and not (math.isfinite(out_fps) and out_fps > 0):
            raise ValueError(f"fps must be positive, got {fps!r}")
        self.core = _core.StreamingPuppet(core, int(d), int(t), out_fps, bool(posterior), int(dl),
                                          int(pl), int(gl), lam)
        self.fps = float(self.core.output_fps)
        try:
            rate_i = int(rate)
        except (TypeError, ValueError):
            raise ValueError(f"rate must be a whole number of Hz, got {rate!r}") from None
        if rate_i != rate or rate_i < 8000:
            raise ValueError(f"rate must be a whole number of Hz >= 8000, got {rate!r}")
        self.rate = rate_i
        puppet.check_band(rate_i, "the live audio", stacklevel=2)
        self.resampler = None if rate_i == ANALYSIS_RATE else StreamResampler(rate_i, ANALYSIS_RATE)
        self.lag_ms = float(lag_ms)
        self.samples_in = 0
        self._n_points = int(core.n_points)
        self._n_dims = int(core.n_dims)

    @property
    def n_points(self) -> int:
        """Landmarks per frame (P of :attr:`LiveFrames.points`)."""
        return self._n_points

    @property
    def delta_lag(self) -> int:
        return int(self.core.delta_lag)

    @property
    def projection_lag(self) -> int:
        return int(self.core.projection_lag)

    @property
    def guide_lag(self) -> int:
        """The guide's look-ahead (0 for an unguided stream)."""
        return int(self.core.guide_lag)

    @property
    def guide_weight(self) -> float:
        """λ of the guide on this stream (0: unguided)."""
        return float(self.core.guide_weight)

    @property
    def decode_lag(self) -> int:
        return int(self.core.decode_lag)

    @property
    def trajectory_lag(self) -> int:
        return int(self.core.trajectory_lag)

    @property
    def latency_s(self) -> float:
        """Algorithmic latency in seconds: analysis windows + formant tracker bound + delta
        look-ahead + the longer of (projection + decoder) and the guide's look-ahead + the
        trajectory's (compute time not included). Unbounded
        (inf) when the formant tracker waits for exact decisions."""
        if self.formant_lag is None and "formants" in self.puppet.feature_set.features:
            return math.inf
        return self.features.lookahead_s() + self.core.latency_seconds

    def push(self, samples) -> LiveFrames:
        """Feed audio samples (any number, at ``rate``; floats in full scale or integer PCM).

        Returns
        -------
        LiveFrames
            The face frames completed by this chunk (possibly none).
        """
        x = pcm_to_float(samples)
        self.samples_in += x.shape[0]
        if self.resampler is not None:
            x = self.resampler.push(x)
        feats = self.features.push(x)
        if feats.shape[0] == 0:  # no new feature frame: nothing can be decided
            return LiveFrames(int(self.core.frames_emitted), np.zeros((0, self._n_points, 2)),
                              np.zeros((0, self._n_dims)), self.fps)
        return self._frames(self.core.push(feats))

    def flush(self) -> LiveFrames:
        """End of the stream: every frame still held back (windows past the end see silence,
        as offline). Then the puppet is ready for a new stream."""
        if self.resampler is not None:
            tail = self.resampler.flush()
            rows = [self.features.push(tail)] if tail.size else []
        else:
            rows = []
        rows.append(self.features.flush())
        a = self.core.push(np.vstack(rows))
        b = self.core.flush()
        self.samples_in = 0
        out_a, out_b = self._frames(a), self._frames(b)
        return LiveFrames(out_a.first_frame, np.concatenate([out_a.points, out_b.points]),
                          np.concatenate([out_a.face, out_b.face]), self.fps)

    def _frames(self, r) -> LiveFrames:
        pts = np.asarray(r.points)
        return LiveFrames(int(r.first_frame), pts.reshape(pts.shape[0], pts.shape[1] // 2, 2),
                          np.asarray(r.face), self.fps)


# ------------------------------------------------------------------------------------ CLI
def _host_port(text: str, what: str) -> tuple:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not (0 < int(port) < 65536):
        raise ValueError(f"--{what} must be HOST:PORT (e.g. 127.0.0.1:8765), got {text!r}")
    return host or "127.0.0.1", int(port)


class _WebSocketOut:
    """A WebSocket server on a local address broadcasting frames (JSON text messages) to every
    connected client; a GET of ``/`` serves the viewer page, and with a face (``files``:
    ``/mesh.json`` and ``/face.png``, :meth:`_FaceDriver.files`) the files the page draws it from.
    Runs in its own thread; clients come and go without disturbing the stream."""

    def __init__(self, host: str, port: int, files: dict | None = None):
        import asyncio

        self._files = dict(files or {})
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error = None
        self._server = None
        self.clients = 0
        self._thread = threading.Thread(target=self._run, args=(host, port), daemon=True)
        self._thread.start()
        self._ready.wait(10)
        if self._error is not None:
            raise ValueError(f"cannot serve WebSocket on {host}:{port}: {self._error}")
        self.port = self._server.sockets[0].getsockname()[1] if self._server else port

    def _run(self, host, port):
        import asyncio
        from http import HTTPStatus

        from websockets.asyncio.server import serve

        page = _viewer_page()

        def respond(connection, body: bytes, kind: str):
            resp = connection.respond(HTTPStatus.OK, "")
            resp.body = body
            for name, value in (("Content-Type", kind), ("Content-Length", str(len(body)))):
                del resp.headers[name]  # websockets' headers keep every value set: replace, not add
                resp.headers[name] = value
            return resp

        def process_request(connection, request):
            if request.headers.get("Upgrade", "").lower() == "websocket":
                return None
            if request.path in ("/", "/index.html"):
                return respond(connection, page.encode("utf-8"), "text/html; charset=utf-8")
            if request.path in self._files:
                return respond(connection, *self._files[request.path])
            return connection.respond(HTTPStatus.NOT_FOUND, "not found\n")

        async def handler(ws):
            try:
                await ws.wait_closed()
            finally:
                pass

        async def main():
            try:
                self._server = await serve(handler, host, port, process_request=process_request)
            except OSError as exc:
                self._error = exc
                self._ready.set()
                return
            self._ready.set()
            await self._server.wait_closed()

        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(main())
        finally:
            self._loop.close()

    def send(self, message: str) -> None:
        from websockets.asyncio.server import broadcast

        def _do():
            if self._server is not None:
                conns = list(self._server.connections)
                self.clients = len(conns)
                broadcast(conns, message)  # skips closed or closing clients
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(_do)

    def close(self) -> None:
        if self._server is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._server.close)
        self._thread.join(5)


class _FaceDriver:
    """The viewer's textured face (``live --face``): the face mesh of a photo or video
    (:func:`voicepuppet.render.faces.load_face`) and, per frame, its vertices as ``render`` drives
    them (:func:`voicepuppet.render.retargeting.mesh_animation`, mode "vertex"), retargeted from ``rest``,
    the face the puppet makes in silence (``Puppet.rest_face``, which ``render`` takes from the
    animation), or without it from the stream's first frame."""

    def __init__(self, face: str, points: str | None, n_points: int, rest: np.ndarray | None = None):
        from voicepuppet import render
        from voicepuppet.render.head import HEAD_SUFFIXES

        if os.path.splitext(face)[1].lower() in HEAD_SUFFIXES:
            raise ValueError(f"live --face {face!r}: the viewer page paints a photo's mesh over the photo, not a 3-D "
                             "head's thousands of textured triangles; give a photo or a video (render and export "
                             "take the head)")
        self._render = render
        self.mesh = render.resolve_face(face, points, rest=rest)
        if self.mesh.n_landmarks != n_points:
            raise ValueError(f"the face {face!r} has {self.mesh.n_landmarks} points and the puppet's "
                             f"landmarks {n_points}; give --face-points in the puppet's layout")
        self._M = self.mesh.interpolation_matrix()  # the thin-plate spline, before the stream starts
        self.reference = None if rest is None else np.array(rest, dtype=np.float64)
        self._sR = None if rest is None else render.similarity(self.reference, self.mesh.landmarks)

    def vertices(self, points: np.ndarray) -> np.ndarray:
        """(V, 2) image positions of the mesh's vertices for one frame's landmarks (P, 2), as
        ``render.mesh_animation`` gives them (its retargeting found once)."""
        if self.reference is None:
            self.reference = np.array(points, dtype=np.float64)
            self._sR = self._render.similarity(self.reference, self.mesh.landmarks)
        return self.mesh.vertices[:, :2] + self._M @ ((points - self.reference) @ self._sR)

    def files(self) -> dict:
        """``/mesh.json`` (the photo's size, the triangles, which of them are the mouth cavity, the
        flat colour of the mouth's interior (cavity, tongue, teeth; null for the textured skin), the order to draw
        them in (``FaceMesh.draw_order``), texture coordinates as ``FaceMesh.uv``) and
        ``/face.png`` for the viewer."""
        import cv2

        m = self.mesh
        ok, png = cv2.imencode(".png", np.ascontiguousarray(m.image[:, :, ::-1]))
        if not ok:
            raise ValueError("cannot encode the face image as PNG")
        doc = {"width": m.size[0], "height": m.size[1], "triangles": m.faces.tolist(),
               "mouth": m.mouth.tolist(),
               "colours": [c if flat else None for c, flat in zip(m.colours.tolist(), m.flat.tolist())],
               "order": m.draw_order().tolist(), "uv": np.round(m.uv, 7).tolist()}
        return {"/mesh.json": (json.dumps(doc, separators=(",", ":")).encode(), "application/json"),
                "/face.png": (png.tobytes(), "image/png")}


def _viewer_page() -> str:
    from importlib import resources

    return resources.files("voicepuppet.live").joinpath("web", "index.html").read_text("utf-8")


class _OscOut:
    def __init__(self, host: str, port: int):
        from pythonosc.udp_client import SimpleUDPClient

        self.client = SimpleUDPClient(host, port)

    def send(self, frame: int, t: float, points: np.ndarray) -> None:
        try:
            self.client.send_message("/voicepuppet/frame",
                                     [int(frame), float(t)] + [float(v) for v in points.ravel()])
        except OSError:  # UDP: nobody listening is not an error worth stopping for
            pass

    def close(self) -> None:
        sock = getattr(self.client, "_sock", None)
        if sock is not None:
            sock.close()


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


def run_live(args, out=None) -> int:
    """The ``live`` verb (see ``add_parser``)."""
    out = out or sys.stdout
    recording = None
    level = getattr(args, "input_level", None)
    if args.input != "-":
        from voicepuppet.audio import load_audio
        from voicepuppet.audio.stream import speech_level_db

        recording = load_audio(args.input).samples
        if level is None:  # a file's level is known before it plays: scaled as animate scales it
            level = speech_level_db(recording, ANALYSIS_RATE)
    live = LivePuppet(args.puppet, lag_ms=args.lag_ms, fps=args.fps, posterior=args.posterior,
                      rate=args.rate if args.input == "-" else ANALYSIS_RATE, input_level_db=level,
                      projection_lag=getattr(args, "projection_lag", None),
                      guide_lag=getattr(args, "guide_lag", None),
                      guide_weight=getattr(args, "guide_weight", None),
                      decode_lag=getattr(args, "decode_lag", None),
                      trajectory_lag=getattr(args, "trajectory_lag", None))
    face = None
    if getattr(args, "face", None):
        if not args.websocket:
            raise ValueError("--face draws the face in the viewer page of --websocket: give --websocket HOST:PORT")
        face = _FaceDriver(args.face, args.face_points, live.n_points, live.puppet.rest_face())
    elif getattr(args, "face_points", None):
        raise ValueError("--face-points are the points of --face: give --face too")
    ws = _WebSocketOut(*_host_port(args.websocket, "websocket"), files=face.files() if face else None) \
        if args.websocket else None
    osc = _OscOut(*_host_port(args.osc, "osc")) if args.osc else None
    if ws is not None:
        print(f"voicepuppet live: viewer at http://{args.websocket.rpartition(':')[0] or '127.0.0.1'}"
              f":{ws.port}/ (WebSocket on the same port)", file=sys.stderr)
    chunk = max(1, int(round(args.chunk_ms / 1000.0 * live.rate)))
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
                if face is not None:  # the viewer draws the textured face from the mesh's vertices
                    rec["vertices"] = np.round(face.vertices(pts), 2).tolist()
                    line = json.dumps(rec, separators=(",", ":"))
                ws.send(line)
            if osc is not None:
                osc.send(int(k), float(t), pts)
        n_frames += len(frames)
        try:
            out.flush()
        except BrokenPipeError:
            raise SystemExit(0)

    def source():
        if args.input == "-":
            pcm = _read_pcm(sys.stdin.buffer, args.format, args.channels,
                            chunk * args.channels * 4)
            for a in pcm:
                yield a, False
        else:
            for i in range(0, recording.shape[0], chunk):
                yield recording[i:i + chunk], not args.no_realtime

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
    if osc is not None:
        osc.close()
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


def add_parser(sub) -> None:
    p = sub.add_parser("live", help="animate live audio with a bounded latency (JSON lines, "
                       "WebSocket, OSC)", description=__doc__.split("\n\n")[0])
    p.add_argument("puppet", help="puppet file (.vpp)")
    p.add_argument("--input", default="-", metavar="FILE|-",
                   help="audio or video file played at real-time pace, or - for raw PCM on "
                        "standard input (default -)")
    p.add_argument("--lag-ms", type=float, default=150.0,
                   help="latency budget in ms (analysis windows + look-aheads; default 150)")
    p.add_argument("--fps", type=float, default=None, help="output frame rate (default: the "
                   "puppet's)")
    p.add_argument("--projection-lag", type=int, default=None, metavar="FRAMES",
                   help="look-ahead of a projected puppet's vocal features (0 .. its context k, "
                        "-1 for k: exact); default: its share of --lag-ms")
    p.add_argument("--guide-lag", type=int, default=None, metavar="FRAMES",
                   help="look-ahead of a guided puppet's guide (0 .. its guide context, -1 for "
                        "all of it: exact); default: the projection's and decoder's look-ahead, "
                        "which it shares at no cost")
    p.add_argument("--guide-weight", type=float, default=None, metavar="LAMBDA",
                   help="weight of a guided puppet's guide (default: the puppet's, chosen at training; "
                        "0: Brand's unguided trajectory)")
    p.add_argument("--decode-lag", type=int, default=None, metavar="FRAMES",
                   help="look-ahead of the state decoder (default: its share of --lag-ms; a guided "
                        "puppet's guide shares it)")
    p.add_argument("--trajectory-lag", type=int, default=None, metavar="FRAMES",
                   help="look-ahead of the trajectory solve, frames at the output rate (default: its "
                        "share of --lag-ms)")
    p.add_argument("--posterior", action="store_true",
                   help="posterior-weighted synthesis instead of the fixed-lag Viterbi path")
    p.add_argument("--input-level", type=float, default=None, metavar="DBFS",
                   help="speech level of the live audio in dBFS, for a puppet that brings audio to a "
                        "level (the default of train): scaled from the first sample as animate scales "
                        "a recording of that level (default: a file's own; on standard input "
                        "estimated from what has been heard)")
    p.add_argument("--rate", type=int, default=ANALYSIS_RATE,
                   help="sample rate of the PCM on standard input (default 16000)")
    p.add_argument("--format", choices=["s16le", "s32le", "f32le"], default="s16le",
                   help="sample format of the PCM on standard input (default s16le)")
    p.add_argument("--channels", type=int, default=1, help="interleaved channels on standard "
                   "input, averaged (default 1)")
    p.add_argument("--chunk-ms", type=float, default=CHUNK_MS,
                   help=f"audio pushed per step, in ms (default {CHUNK_MS:g}): the wait for a "
                        "chunk to fill adds up to this much to the latency")
    p.add_argument("--no-realtime", action="store_true",
                   help="with --input FILE: process as fast as possible instead of at real-time "
                        "pace")
    p.add_argument("--websocket", metavar="HOST:PORT",
                   help="serve the frames over WebSocket (and a viewer page) on a local address")
    p.add_argument("--face", metavar="IMAGE|VIDEO",
                   help="with --websocket: the viewer page draws this face (a photo at rest, or a video's "
                        "frame nearest the puppet's rest face, e.g. the puppet's training video) moved by "
                        "the frames, as render does (default: the landmarks as lines)")
    p.add_argument("--face-points", metavar="POINTS",
                   help="the points of --face: JSON, CSV or a landmarks .npz (default: detect 68 with dlib)")
    p.add_argument("--osc", metavar="HOST:PORT",
                   help="send each frame as an OSC message /voicepuppet/frame to this address")
    p.set_defaults(func=_check_and_run)


def _check_and_run(args) -> int:
    if args.channels < 1:
        raise ValueError(f"--channels must be >= 1, got {args.channels}")
    if not (args.chunk_ms > 0 and math.isfinite(args.chunk_ms)):
        raise ValueError(f"--chunk-ms must be positive, got {args.chunk_ms}")
    if args.input != "-" and not os.path.exists(args.input):
        raise FileNotFoundError(f"--input {args.input!r} does not exist")
    return run_live(args)
