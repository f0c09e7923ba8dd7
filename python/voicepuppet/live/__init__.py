"""Live: a puppet driven by streamed audio with bounded latency, served to a browser page."""

from voicepuppet.live.server import LiveFrames, LivePuppet

__all__ = ["LiveFrames", "LivePuppet"]
