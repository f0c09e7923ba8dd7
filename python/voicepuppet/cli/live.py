"""Live voice puppetry: audio in as it is heard, face frames out with a latency you choose.

The ``live`` verb (see :func:`voicepuppet.live.server.run_live` for what it drives).
"""

from __future__ import annotations

import math
import os


def _run(args, out=None) -> int:
    from voicepuppet.live.server import run_live

    if args.channels < 1:
        raise ValueError(f"--channels must be >= 1, got {args.channels}")
    if not (args.chunk_ms > 0 and math.isfinite(args.chunk_ms)):
        raise ValueError(f"--chunk-ms must be positive, got {args.chunk_ms}")
    if args.input != "-" and not os.path.exists(args.input):
        raise FileNotFoundError(f"--input {args.input!r} does not exist")
    return run_live(args.puppet, input_file=args.input, lag_ms=args.lag_ms, fps=args.fps,
                    posterior=args.posterior, rate=args.rate, pcm_format=args.format,
                    channels=args.channels, chunk_ms=args.chunk_ms, realtime=not args.no_realtime,
                    input_level_db=args.input_level, projection_lag=args.projection_lag,
                    guide_lag=args.guide_lag, guide_weight=args.guide_weight, decode_lag=args.decode_lag,
                    trajectory_lag=args.trajectory_lag, websocket=args.websocket, face=args.face,
                    face_points=args.face_points, osc=args.osc, out=out)


def add_parser(sub) -> None:
    from voicepuppet.live.puppet import ANALYSIS_RATE
    from voicepuppet.live.server import CHUNK_MS

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
    p.set_defaults(func=_run)
