"""Where the live frames go besides JSON lines: a WebSocket server with its viewer page, OSC
messages, and the textured face the viewer draws (``voicepuppet live --websocket``, ``--osc``,
``--face``). See docs/streaming.md.
"""

from __future__ import annotations

import asyncio
import json
import os
import threading
from http import HTTPStatus
from importlib import resources

import numpy as np

from voicepuppet import render
from voicepuppet.render.head import HEAD_SUFFIXES

__all__ = ["FaceDriver", "OscOut", "WebSocketOut", "host_port", "viewer_page"]


def host_port(text: str, what: str) -> tuple:
    """Parse an address given as ``HOST:PORT`` (an empty host is 127.0.0.1).

    Parameters
    ----------
    text : str
        The address, e.g. ``127.0.0.1:8765``.
    what : str
        The option it came from (``websocket``, ``osc``), named in the error.

    Returns
    -------
    (host, port) : tuple of (str, int)

    Raises
    ------
    ValueError
        Not ``HOST:PORT`` with a port in 1..65535.
    """
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not (0 < int(port) < 65536):
        raise ValueError(f"--{what} must be HOST:PORT (e.g. 127.0.0.1:8765), got {text!r}")
    return host or "127.0.0.1", int(port)


class WebSocketOut:
    """A WebSocket server on a local address broadcasting frames (JSON text messages) to every
    connected client; a GET of ``/`` serves the viewer page, and with a face (``files``:
    ``/mesh.json`` and ``/face.png``, :meth:`FaceDriver.files`) the files the page draws it from.
    Runs in its own thread; clients come and go without disturbing the stream.

    Parameters
    ----------
    host : str
        Local address to serve on.
    port : int
        Port to serve on (0: any free port; :attr:`port` says which).
    files : dict, optional
        ``{path: (bytes, content type)}`` served besides the viewer page.

    Raises
    ------
    ValueError
        The address cannot be served (in use, not local).
    """

    def __init__(self, host: str, port: int, files: dict | None = None):
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
        from websockets.asyncio.server import serve

        page = viewer_page()

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
        """Broadcast one text message to the clients connected now.

        Parameters
        ----------
        message : str
            A frame as a JSON text message.
        """
        from websockets.asyncio.server import broadcast

        def _do():
            if self._server is not None:
                conns = list(self._server.connections)
                self.clients = len(conns)
                broadcast(conns, message)  # skips closed or closing clients
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(_do)

    def close(self) -> None:
        """Stop serving and wait (up to 5 s) for the server's thread to end."""
        if self._server is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._server.close)
        self._thread.join(5)


class FaceDriver:
    """The viewer's textured face (``live --face``): the face mesh of a photo or video
    (:func:`voicepuppet.render.faces.load_face`) and, per frame, its vertices as ``render`` drives
    them (:func:`voicepuppet.render.retargeting.mesh_animation`, mode "vertex"), retargeted from ``rest``,
    the face the puppet makes in silence (``Puppet.rest_face``, which ``render`` takes from the
    animation), or without it from the stream's first frame.

    Parameters
    ----------
    face : str
        A photo, or a video (its frame nearest ``rest`` is used).
    points : str or None
        The face's landmarks (JSON, CSV or a landmarks ``.npz``); None detects 68 with dlib.
    n_points : int
        Landmarks per frame of the stream.
    rest : ndarray, shape (P, 2), optional
        The puppet's face in silence.

    Raises
    ------
    ValueError
        A 3-D head instead of a photo or video, or a face whose landmark count is not
        ``n_points``.
    """

    def __init__(self, face: str, points: str | None, n_points: int, rest: np.ndarray | None = None):
        if os.path.splitext(face)[1].lower() in HEAD_SUFFIXES:
            raise ValueError(f"live --face {face!r}: the viewer page paints a photo's mesh over the photo, not a 3-D "
                             "head's thousands of textured triangles; give a photo or a video (render and export "
                             "take the head)")
        self.mesh = render.resolve_face(face, points, rest=rest)
        if self.mesh.n_landmarks != n_points:
            raise ValueError(f"the face {face!r} has {self.mesh.n_landmarks} points and the puppet's "
                             f"landmarks {n_points}; give --face-points in the puppet's layout")
        self._M = self.mesh.interpolation_matrix()  # the thin-plate spline, before the stream starts
        self.reference = None if rest is None else np.array(rest, dtype=np.float64)
        self._sR = None if rest is None else render.similarity(self.reference, self.mesh.landmarks)

    def vertices(self, points: np.ndarray) -> np.ndarray:
        """Image positions of the mesh's vertices for one frame's landmarks, as
        ``render.mesh_animation`` gives them (its retargeting found once).

        Parameters
        ----------
        points : ndarray, shape (P, 2)
            One frame's landmarks.

        Returns
        -------
        ndarray, shape (V, 2)
        """
        if self.reference is None:
            self.reference = np.array(points, dtype=np.float64)
            self._sR = render.similarity(self.reference, self.mesh.landmarks)
        return self.mesh.vertices[:, :2] + self._M @ ((points - self.reference) @ self._sR)

    def files(self) -> dict:
        """``/mesh.json`` (the photo's size, the triangles, which of them are the mouth cavity, the
        flat colour of the mouth's interior (cavity, tongue, teeth; null for the textured skin), the order to draw
        them in (``FaceMesh.draw_order``), texture coordinates as ``FaceMesh.uv``) and
        ``/face.png`` for the viewer.

        Returns
        -------
        dict
            ``{path: (bytes, content type)}``, as :class:`WebSocketOut` takes them.
        """
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


def viewer_page() -> str:
    """The viewer page.

    Returns
    -------
    str
        ``voicepuppet/live/web/index.html``.
    """
    return resources.files("voicepuppet.live").joinpath("web", "index.html").read_text("utf-8")


class OscOut:
    """Frames sent as OSC messages ``/voicepuppet/frame`` (frame, time, then the points' x, y)
    over UDP; a port nobody listens on is not an error.

    Parameters
    ----------
    host : str
    port : int
    """

    def __init__(self, host: str, port: int):
        from pythonosc.udp_client import SimpleUDPClient

        self.client = SimpleUDPClient(host, port)

    def send(self, frame: int, t: float, points: np.ndarray) -> None:
        """Send one frame.

        Parameters
        ----------
        frame : int
            Output index of the frame.
        t : float
            Time in seconds of the sound it shows.
        points : ndarray, shape (P, 2)
        """
        try:
            self.client.send_message("/voicepuppet/frame",
                                     [int(frame), float(t)] + [float(v) for v in points.ravel()])
        except OSError:  # UDP: nobody listening is not an error worth stopping for
            pass

    def close(self) -> None:
        """Close the UDP socket."""
        sock = getattr(self.client, "_sock", None)
        if sock is not None:
            sock.close()
