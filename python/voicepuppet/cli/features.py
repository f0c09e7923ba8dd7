"""``voicepuppet features AUDIO_OR_VIDEO -o feats.npz --fps 29.97``: the audio front end.

Writes an ``.npz`` with ``features`` (T, D), ``names`` (D,), ``times`` (T,), ``fps``,
``duration``, ``feature_set`` (JSON) and ``voiced`` (T,) when F0 was computed, or a ``.csv``
(``frame,time,<names>``). ``--puppet P.vpp`` computes the puppet's own features at its rate.
"""

from __future__ import annotations


def _run(args) -> int:
    from voicepuppet import audio
    from voicepuppet.cli.main import UserError

    if args.features and args.set:
        raise UserError("give either --set or --features, not both")
    if not args.output.lower().endswith((".npz", ".csv")):
        raise UserError(f"output must end in .npz or .csv, got {args.output!r}")
    puppet = None
    if args.puppet:
        given = [o for o, v in (("--set", args.set), ("--features", args.features), ("--deltas", args.deltas),
                                ("--fps", args.fps), ("--rate", args.rate)) if v]
        if given:
            raise UserError(f"--puppet fixes the features and their rate; drop {', '.join(given)}")
        from voicepuppet.puppet.model import load

        puppet = load(args.puppet)
        fset, fps = puppet.feature_set, puppet.fps
    else:
        fset = audio.as_feature_set(args.features or args.set or audio.DEFAULT_SET)
        fps = 29.97 if args.fps is None else args.fps
    if args.deltas and "mfcc_deltas" not in fset.features:
        feats = fset.features + (() if "mfcc" in fset.features else ("mfcc",)) + ("mfcc_deltas",)
        fset = audio.FeatureSet(feats, fset.options, fset.name)
    sound = audio.load_audio(args.input, rate=args.rate or audio.loading.DEFAULT_RATE)
    if puppet is not None:
        feats = puppet.extract(sound, n_out=args.frames, progress=not args.quiet)
    else:
        feats = audio.extract(sound, fps=fps, features=fset, n_out=args.frames, progress=not args.quiet)
    feats.save(args.output)
    print(f"{args.input}: {sound.duration:.2f} s at {sound.source_rate} Hz "
          f"({sound.channels} ch) -> {len(feats)} frames x {len(feats.names)} features "
          f"at {feats.fps:g} fps [{fset.name}: {', '.join(fset.features)}] -> {args.output}")
    return 0


def add_parser(sub) -> None:
    """Register the ``features`` verb.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The sub-command parsers of the ``voicepuppet`` command line.
    """
    from voicepuppet.audio import FEATURE_SETS, FEATURES

    p = sub.add_parser("features", help="audio features at a video frame rate",
                       description="Compute audio features (LPC, RASTA-PLP, MFCC, formants, band "
                                   "energies, F0, energy) centred on video frame times.")
    p.add_argument("input", help="audio file (wav, flac, ogg, mp3) or video with sound "
                                 "(mp4, mov, mkv, avi)")
    p.add_argument("-o", "--output", required=True,
                   help="output .npz, or .csv (frame,time,features: what examples/cpp reads)")
    p.add_argument("--puppet", metavar="PUPPET.vpp",
                   help="the features a puppet reads, at its frame rate (its feature set and options, e.g. its "
                        "band): what to feed its C++ Puppet::animate")
    p.add_argument("--fps", type=float, default=None, help="output frame rate (default 29.97)")
    p.add_argument("--set", choices=sorted(FEATURE_SETS),
                   help="named feature set (default: puppet)")
    p.add_argument("--features", help=f"comma-separated features from: {', '.join(FEATURES)}")
    p.add_argument("--deltas", action="store_true", help="add MFCC deltas")
    p.add_argument("--frames", type=int, default=None,
                   help="number of output frames (e.g. the video's frame count; default: "
                        "ceil(duration * fps))")
    p.add_argument("--rate", type=int, default=None,
                   help="analysis sample rate in Hz (default 16000)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)
