"""``voicepuppet track VIDEO -o landmarks.npz``: the spring-mesh SSD tracker (:mod:`voicepuppet.tracking`).

Writes the landmarks ``.npz`` and its ``.csv`` twin (:func:`voicepuppet.tracking.landmarks.save_landmarks`),
and with ``--overlay`` a video with the tracked mesh drawn on it.
"""

from __future__ import annotations

from pathlib import Path

from tqdm.auto import tqdm

from voicepuppet.tracking.detect import AUTO_INIT_SCAN_S
from voicepuppet.tracking.scale import LARGE_FACE_IOD, LARGE_FACE_RMS_RADIUS, WORKING_IOD, WORKING_RMS_RADIUS


def _cli(args) -> int:
    from voicepuppet.tracking import video
    from voicepuppet.tracking.landmarks import save_landmarks
    from voicepuppet.tracking.tracker import track_video

    init = args.init
    if init != "auto" and not Path(init).is_file():
        raise ValueError(f"--init {init!r} is neither 'auto' nor an existing points file")
    out = Path(args.output)
    if out.suffix.lower() != ".npz":
        raise ValueError(f"-o must name a .npz file, got {str(out)!r}")
    working_scale = args.working_scale
    if working_scale != "auto":
        try:
            working_scale = float(working_scale)
        except ValueError:
            working_scale = float("nan")
        if not 0.0 < working_scale <= 1.0:
            raise ValueError(f"--working-scale must be 'auto' or a number in (0, 1] (the factor the frames are "
                             f"resized by; 1 tracks at full resolution), got {args.working_scale!r}")
    result = track_video(args.video, init, passes=args.passes, progress=not args.quiet,
                         patch_radius=args.patch_radius, levels=args.levels, working_scale=working_scale,
                         reacquire=not args.no_reacquire,
                         detector_anchors=False if args.no_detector_anchors else None)
    written = save_landmarks(out, result)
    if args.overlay:
        # Every frame once, at the video's average rate: as long as the video (a variable-rate
        # video's nominal fps would play it faster).
        T = len(result.points)
        rate = result.fps if result.times is None or T < 2 else (T - 1) / float(result.times[-1])
        with tqdm(total=T, desc="overlay", unit="frame", disable=args.quiet, leave=False) as bar:
            video.write_overlay(args.overlay, video.iter_frames(args.video, grey=False), result.points,
                                result.lost, rate, result.edges, progress=bar.update)
        written.append(Path(args.overlay))
    T, P, _ = result.points.shape
    for row in result.passes:
        change = row["max_length_change"]
        moved = row["mean_point_change"]
        print(f"pass {row['pass']}: lost {100 * row['lost_fraction']:.1f}% of point-frames"
              + (f", points moved {moved:.3f} px on average from the previous pass" if moved is not None else "")
              + (f", spring lengths re-estimated (largest change {change:.2f} px)" if change is not None else ""))
    if result.reacquired:
        print(f"face lost and found again (mesh restarted) at frame{'s' if len(result.reacquired) > 1 else ''} "
              + ", ".join(f"{t} ({t / result.fps:.2f} s)" for t in result.reacquired))
    if result.working_scale != 1.0:
        print(f"large face: tracked on frames resized by {result.working_scale:.4f} "
              f"(--working-scale; points written in full-resolution pixels)")
    print(f"tracked {P} points through {T} frames; wrote {', '.join(str(w) for w in written)}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("track", help="track facial landmarks through a video (spring-mesh SSD tracker)",
                       description="Track facial landmarks through a video with the spring-mesh SSD "
                                   "tracker of Voice Puppetry §4.1; writes landmarks.npz and a .csv twin.")
    p.add_argument("video", help="input video (anything OpenCV decodes)")
    p.add_argument("-o", "--output", required=True, metavar="LANDMARKS.npz", help="output landmarks (.npz; a .csv twin is written beside it)")
    p.add_argument("--init", default="auto", metavar="POINTS.json|auto",
                   help='first-frame points: JSON {"points": [[x, y], ...]} or CSV x,y rows, or "auto" '
                        "(dlib 68-point detector on the first frame with a face, looked for in the first "
                        f"{AUTO_INIT_SCAN_S:g} s). Default: auto")
    p.add_argument("--overlay", metavar="OUT.mp4", help="also write a video with the tracked mesh drawn on it")
    p.add_argument("--passes", type=int, default=2, help="tracking passes with spring re-estimation between them (default 2)")
    p.add_argument("--patch-radius", type=int, default=6, help="SSD patch radius in pixels (default 6: 13x13)")
    p.add_argument("--levels", type=int, default=3, help="image pyramid levels (default 3)")
    p.add_argument("--working-scale", default="auto", metavar="auto|F",
                   help="track a large face on frames resized down by F in (0, 1]; auto (default): a face "
                        f"with outer eye corners more than {LARGE_FACE_IOD:g} px apart is resized so that they "
                        f"are {WORKING_IOD:g} px apart (other layouts: the RMS radius of the init points, "
                        f"{LARGE_FACE_RMS_RADIUS:.1f} and {WORKING_RMS_RADIUS:.1f} px), smaller faces are tracked "
                        "at full resolution. Points are written in full-resolution pixels; --patch-radius is "
                        "in pixels of the resized frames")
    p.add_argument("--no-reacquire", action="store_true",
                   help="do not search the whole frame for a face lost for a few frames (by default the "
                        "mesh is restarted where the face is found again)")
    p.add_argument("--no-detector-anchors", action="store_true",
                   help="with --init auto, track the lips by their patches and springs alone (by default "
                        "dlib's lips on every frame bound their drift)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cli)
