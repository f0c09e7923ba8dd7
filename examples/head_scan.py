"""A voice puppet's animation on a real textured 3-D head scan (docs/rendering.md, "A textured
3-D head"): menpo3d's ``james`` at rest, driven at two frames of the animation, and the first
of them lit (``--shading``), side by side; with ``--video``, the whole animation as an mp4.

    voicepuppet demo --out voicepuppet-demo
    python examples/head_scan.py voicepuppet-demo/animation.npz --frames 742 529 --out docs/img/head_james.jpg
"""

from __future__ import annotations

import argparse

import numpy as np
from PIL import Image

from voicepuppet.render import head
from voicepuppet import render
from voicepuppet.animation import load_animation


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("animation", help="a landmark animation (.npz) in the 68-point layout")
    ap.add_argument("--frames", type=int, nargs=2, default=(0, 1), help="the two frames to show")
    ap.add_argument("--out", default="head_james.jpg", help="the picture")
    ap.add_argument("--video", help="also render the whole animation to this .mp4 (with --audio)")
    ap.add_argument("--audio", help="the animation's sound, muxed into --video")
    args = ap.parse_args()

    mesh_path, points_path = head.sample_head()
    mesh = head.load_head(mesh_path, points_path)
    anim = load_animation(args.animation)
    verts = render.mesh_animation(anim, mesh)["vertices"]
    a, b = args.frames
    with render.FaceRenderer(mesh) as r:
        shots = [r.frame(mesh.vertices), r.frame(verts[a]), r.frame(verts[b])]
    with render.FaceRenderer(mesh, shading=True) as r:
        shots.append(r.frame(verts[a]))
    # the face, without most of the canvas's margin, at 280 x 300 each
    H, W = shots[0].shape[:2]
    y0, x0 = H // 12, (W - int(0.78 * H)) // 2
    tiles = [Image.fromarray(s[y0:H - y0, x0:W - x0]).resize((280, 300), Image.LANCZOS) for s in shots]
    Image.fromarray(np.hstack([np.asarray(t) for t in tiles])).save(args.out, quality=85)
    print(f"wrote {args.out}")
    if args.video:
        render.render(anim, args.video, audio=args.audio, face=mesh, progress=True)
        print(f"wrote {args.video}")


if __name__ == "__main__":
    main()
