"""Live: a puppet driven by streamed audio with bounded latency
(:mod:`~voicepuppet.live.puppet`), its frames served to a browser page over WebSocket or sent as
OSC (:mod:`.outputs`), and a session run from a file or standard input (:mod:`.server`)."""

from voicepuppet.live.outputs import FaceDriver, OscOut, WebSocketOut, host_port, viewer_page
from voicepuppet.live.puppet import ANALYSIS_RATE, TRUSTED_GUIDE_WEIGHT, LiveFrames, LivePuppet, split_lag
from voicepuppet.live.server import CHUNK_MS, run_live

__all__ = ["ANALYSIS_RATE", "CHUNK_MS", "TRUSTED_GUIDE_WEIGHT", "FaceDriver", "LiveFrames", "LivePuppet",
           "OscOut", "WebSocketOut", "host_port", "run_live", "split_lag", "viewer_page"]
