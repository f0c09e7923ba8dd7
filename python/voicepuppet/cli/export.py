"""``voicepuppet export``: a landmark animation in interchange formats (:mod:`voicepuppet.render.export`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from voicepuppet.animation import load_animation
from voicepuppet.cli._controls import add_control_arguments, apply_control_arguments
from voicepuppet.render import resolve_face
from voicepuppet.render.export import FORMATS, export


def print_summary(summary: dict) -> None:
    """Prints the summary of :func:`voicepuppet.render.export.write_glb`: the action units'
    landmark error, or how closely the morph targets reproduce the vertex motion.

    Parameters
    ----------
    summary : dict
        as :func:`voicepuppet.render.export.write_glb` returns it.
    """
    if "au_rms_error_iod" in summary:
        print(f"action-unit projection: {summary['targets']} units, landmark error "
              f"{summary['au_rms_error_iod']:.4f} IOD (RMS per coordinate, mean over frames)")
    else:
        print(f"{summary['targets']} morph targets reproduce the vertex motion within "
              f"{summary['max_error_m'] * 1000:.3f} mm")


def _cli(args: argparse.Namespace) -> int:
    original = load_animation(args.animation)
    anim = apply_control_arguments(original, args)
    fmt = args.format
    out = args.output
    if out is None:
        if fmt is None:
            raise ValueError("give --format or -o with a suffix")
        out = str(Path(args.animation).with_suffix("")) + ("_arkit" if fmt.startswith("arkit") else "") + \
            ("_cues" if fmt.startswith("rhubarb") else "") + FORMATS[fmt]
        if Path(out).exists() and Path(out).samefile(args.animation):
            raise ValueError(f"exporting {args.animation} as {fmt} without -o would overwrite it; give -o "
                             "another file: voicepuppet never overwrites its input")
    face = resolve_face(args.face, args.face_points, args.palette, original.rest) if args.face else None
    export(anim, out, fmt, face=face, mode=args.mode, sound_file=args.sound_file or "", report=print_summary)
    print(f"{args.animation}: {anim.n_frames} frames at {anim.fps:g} fps -> {out}")
    return 0


def add_parser(sub) -> None:
    """Registers ``voicepuppet export``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        the command line's sub-commands.
    """
    p = sub.add_parser("export", help="landmarks, VTK series, glTF, ARKit weights, Rhubarb mouth cues",
                       description="Export a landmark animation: csv/npz landmarks, pvd (VTK time series for "
                                   "ParaView), gltf (animated .glb with morph targets), arkit / arkit-json "
                                   "(ARKit 52 blendshape weights), rhubarb / rhubarb-tsv (mouth cues A-F, X).")
    p.add_argument("animation", help="landmark animation (.npz or .csv)")
    p.add_argument("--format", choices=sorted(FORMATS), help="output format (default: from the -o suffix)")
    p.add_argument("-o", "--output", help="output file (default: next to the animation)")
    p.add_argument("--face", help="face photo, a textured 3-D head (.obj) or a name with --palette, for pvd/gltf "
                                  "(default: a drawn portrait)")
    p.add_argument("--palette", help="folder of faces (NAME.png + NAME.json points) to pick --face from")
    p.add_argument("--face-points",
                   help="the photo's points (JSON, CSV or .npz; an .obj head's in 3-D: JSON or .ljson)")
    p.add_argument("--mode", choices=["vertex", "au"], help="mesh driving: vertex (pvd default) or au (gltf default)")
    p.add_argument("--sound-file", help="sound file name recorded in Rhubarb json metadata")
    add_control_arguments(p)
    p.set_defaults(func=_cli)
