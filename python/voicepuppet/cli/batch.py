"""The ``batch`` verbs: ``batch animate`` and ``batch track`` (see :mod:`voicepuppet.batch.jobs`
for what they drive)."""

from __future__ import annotations

from pathlib import Path


def _finish(summary, out_dir) -> int:
    from voicepuppet.batch.engine import SUMMARY_NAME

    print(summary.text())
    done = [f for f in summary.files if f.status == "done"]
    if done and summary.wall_seconds > 0:
        media = sum(f.media_seconds for f in done)
        print(f"{media:.1f} s of media in {summary.wall_seconds:.1f} s wall "
              f"({media / summary.wall_seconds:.2f}x real time); summary in {Path(out_dir) / SUMMARY_NAME}")
    return 1 if summary.failed else 0


def _cli_animate(args) -> int:
    from voicepuppet.batch.jobs import animate_folder

    formats = [f.strip() for f in args.format.split(",") if f.strip()]
    summary = animate_folder(args.puppet, args.audio_dir, args.output, formats, fps=args.fps,
                             posterior=args.posterior, scheduler=args.scheduler, workers=args.workers,
                             timeout=args.timeout, progress=not args.quiet)
    return _finish(summary, args.output)


def _cli_track(args) -> int:
    from voicepuppet.batch.jobs import track_folder

    summary = track_folder(args.video_dir, args.output, init=args.init, passes=args.passes,
                           scheduler=args.scheduler, workers=args.workers, timeout=args.timeout,
                           progress=not args.quiet, patch_radius=args.patch_radius, levels=args.levels)
    return _finish(summary, args.output)


def _cluster_arguments(p) -> None:
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler to use, e.g. tcp://127.0.0.1:8786 (default: a local cluster)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local worker processes (default: one per CPU); with --scheduler, wait for N workers")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for the scheduler and workers (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def add_parser(sub) -> None:
    from voicepuppet.batch.jobs import AUDIO_SUFFIXES, VIDEO_SUFFIXES

    p = sub.add_parser("batch", help="animate or track whole folders in parallel (Dask; resumable)",
                       description="Batch work on a Dask cluster (local by default): resumable through a "
                                   "checksum manifest in the output folder, a failure in one file reported "
                                   "in the summary without stopping the others. See docs/batch.md.")
    verbs = p.add_subparsers(dest="batch_verb", metavar="WHAT")
    verbs.required = True
    a = verbs.add_parser("animate", help="animate every audio file of a folder with a puppet",
                         description="Animate every audio file under AUDIO_DIR (recursively) with PUPPET and "
                                     "export each in the given formats to OUT_DIR (same relative paths).")
    a.add_argument("puppet", help="puppet file (voicepuppet train)")
    a.add_argument("audio_dir", help="folder of audio files (" + ", ".join(AUDIO_SUFFIXES) + ")")
    a.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="output folder (created if missing)")
    a.add_argument("--format", default="npz",
                   help="comma-separated export formats: npz, csv, arkit, arkit-json, rhubarb, rhubarb-tsv, "
                        "gltf, pvd (default: npz)")
    a.add_argument("--fps", type=float, help="output frame rate (default: the puppet's)")
    a.add_argument("--posterior", action="store_true", help="posterior-weighted trajectories instead of Viterbi")
    _cluster_arguments(a)
    a.set_defaults(func=_cli_animate)
    t = verbs.add_parser("track", help="track facial landmarks in every video of a folder",
                         description="Track every video under VIDEO_DIR (recursively) with the spring-mesh "
                                     "tracker; writes OUT_DIR/<name>.npz and .csv per video.")
    t.add_argument("video_dir", help="folder of videos (" + ", ".join(VIDEO_SUFFIXES) + ")")
    t.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="output folder (created if missing)")
    t.add_argument("--init", default="auto", metavar="POINTS.json|auto",
                   help="first-frame points for every video, or auto (dlib detector per video; default)")
    t.add_argument("--passes", type=int, default=2, help="tracking passes (default 2)")
    t.add_argument("--patch-radius", type=int, default=6, help="SSD patch radius in pixels (default 6)")
    t.add_argument("--levels", type=int, default=3, help="image pyramid levels (default 3)")
    _cluster_arguments(t)
    t.set_defaults(func=_cli_track)
