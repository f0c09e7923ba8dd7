"""``voicepuppet render``: a landmark animation drawn on a face mesh off screen (:mod:`voicepuppet.render`),
as video, ``.png`` frames, or the driven mesh itself (``.pvd`` / ``.glb``, through ``export``)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from voicepuppet.animation import load_animation
from voicepuppet.cli._controls import add_control_arguments, apply_control_arguments
from voicepuppet.cli.export import print_summary
from voicepuppet.render import check_size, default_size, render, resolve_face
from voicepuppet.render.export import export
from voicepuppet.render.video import even


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must look like 640x480, got {text!r}") from None
    return check_size((w, h), "--size")


def _turn(text: str) -> tuple[float, float]:
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2):
        raise ValueError(f"--turn must look like 30 or 30,-10 (yaw[,pitch] in degrees), got {text!r}")
    return parts[0], parts[1] if len(parts) == 2 else 0.0


def _cli(args: argparse.Namespace) -> int:
    original = load_animation(args.animation)
    anim = apply_control_arguments(original, args)
    truth = load_animation(args.truth) if args.truth else None
    face = resolve_face(args.face, args.face_points, args.palette, original.rest, not args.quiet) \
        if args.face else None
    suffix = Path(args.output).suffix.lower()
    t0 = time.perf_counter()
    if suffix in (".pvd", ".glb"):
        export(anim, args.output, face=face, mode=args.mode, report=print_summary)
    else:
        if face is not None and args.size is None and args.renderer == "mesh":
            (W, H), (w, h) = face.size, default_size(*face.size)
            if (w, h) != (even(W), even(H)):
                print(f"rendering the {W}x{H} face image at {w}x{h} (--size WxH for another size)")
        render(anim, args.output, audio=args.audio, face=face, mode=args.mode or "vertex", truth=truth,
               renderer=args.renderer, size=_size(args.size) if args.size else None, shading=args.shading,
               progress=not args.quiet, turn=_turn(args.turn) if args.turn else None, beside=args.beside)
    dt = time.perf_counter() - t0
    print(f"{args.animation}: {anim.n_frames} frames at {anim.fps:g} fps -> {args.output} "
          f"({dt:.1f} s, {anim.n_frames / max(dt, 1e-9):.1f} frames/s)")
    return 0


def add_parser(sub) -> None:
    """Registers ``voicepuppet render``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        the command line's sub-commands.
    """
    p = sub.add_parser("render", help="render a landmark animation (mp4 with audio, gif, png frames)",
                       description="Render a landmark animation on a textured face mesh off screen: .mp4 "
                                   "(with --audio muxed in sync), .gif, a folder of .png frames (an output "
                                   "name without suffix), or the mesh as .pvd / .glb.")
    p.add_argument("animation", help="landmark animation (.npz or .csv)")
    p.add_argument("-o", "--output", required=True, help="out.mp4, out.gif, a new folder, out.pvd or out.glb")
    p.add_argument("--audio", help="sound to mux into the .mp4 (wav, flac, mp3, or a video's audio)")
    p.add_argument("--face", help="face photo at rest (mouth closed), a video (e.g. the puppet's training "
                                  "video: its frame nearest the animation's rest face), a textured 3-D head (.obj; "
                                  "its 68 points in 3-D with --face-points), or a face name with "
                                  "--palette (default: a drawn portrait on the animation's rest face)")
    p.add_argument("--palette", help="folder of faces (NAME.png + NAME.json points) to pick --face from")
    p.add_argument("--face-points", help="the photo's points: JSON {\"points\": [[x, y], ...]}, CSV, or .npz "
                                         "(a video's: its frames', e.g. track's landmarks; default: "
                                         "detect 68 landmarks with dlib); for an .obj head, JSON "
                                         "{\"points\": [[x, y, z], ...]} or menpo .ljson (default: "
                                         "detected on its front view)")
    p.add_argument("--truth", help="ground-truth animation: render side by side (prediction | truth)")
    p.add_argument("--beside", metavar="VIDEO",
                   help="a video shown on the left, frame for frame (video | prediction), e.g. the recording "
                        "whose sound drove the animation; it needs at least the animation's frames")
    p.add_argument("--mode", choices=["vertex", "au"], default=None,
                   help="drive vertices directly (default) or through the action-unit basis")
    p.add_argument("--renderer", choices=["mesh", "2d"], default="mesh",
                   help="textured mesh (default) or a fast 2-D landmark drawing")
    p.add_argument("--size", help="output size WxH (default: the face image's, scaled down to fit 1920x1080, "
                                  "or 1080x1920 for a portrait image)")
    p.add_argument("--shading", action="store_true", help="light the mesh to show its depth")
    p.add_argument("--turn", metavar="YAW[,PITCH]",
                   help="degrees to turn the face from the front (positive yaw turns it to its left, "
                        "positive pitch lifts the chin), e.g. 30 for a three-quarter view of a 3-D head")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_control_arguments(p)
    p.set_defaults(func=_cli)
