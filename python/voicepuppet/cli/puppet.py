"""The ``train`` and ``animate`` verbs (see :mod:`voicepuppet.puppet.model` for what they drive)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# The library is imported when a verb runs, so that ``voicepuppet --help`` stays fast.


def _train(args) -> int:
    from voicepuppet import audio as vaudio
    from voicepuppet._files import check_output_path
    from voicepuppet.puppet.model import Puppet
    from voicepuppet.puppet.sources import training_sequences
    from voicepuppet.puppet.training import TRAIN_DEFAULTS, TrainOptions

    out = check_output_path(args.output, (".vpp",), "puppet file")
    feature_set = args.feature_set
    if args.audio_band is not None:  # checked here, before any tracking
        from voicepuppet.audio.conditioning import BandLimiter

        BandLimiter(args.audio_band, vaudio.loading.DEFAULT_RATE)
        named = vaudio.as_feature_set(feature_set)
        feature_set = vaudio.FeatureSet(named.features, {**named.options, "band_hz": args.audio_band}, named.name)
    noise_snrs = None
    if args.noise_snrs is not None:
        try:
            noise_snrs = tuple(float(v) for v in args.noise_snrs.split(",") if v.strip())
        except ValueError:
            noise_snrs = ()
        if not noise_snrs or not all(np.isfinite(noise_snrs)):
            raise ValueError(f"--noise-snrs takes SNRs in dB separated by commas (e.g. 20,10), got "
                             f"{args.noise_snrs!r}")
    level = None
    if args.audio_level is not None and args.audio_level.strip().lower() != "none":
        try:  # checked here, before any tracking
            level = vaudio.featureset.check_level_db(float(args.audio_level))
        except ValueError:
            raise ValueError(f"--audio-level takes a speech level in dBFS between -100 and 0 (e.g. -20) or "
                             f"'none', got {args.audio_level!r}") from None
    options = {k: v for k, v in {"n_states": args.states, "n_iter": args.iterations, "parts": args.parts,
                                  "max_components": args.max_components,
                                  "prior": args.prior, "feature_set": feature_set, "noise_snrs": noise_snrs,
                                  "vocal_features": args.vocal_features,
                                  "vocal_covariance": args.vocal_covariance,
                                  "guide": args.guide, "guide_context": args.guide_context,
                                  "guide_weight": _guide_weight_option(args.guide_weight),
                                  "guide_alpha": args.guide_alpha,
                                  "seed": args.seed}.items() if v is not None}
    if args.audio_level is not None:
        options["audio_level"] = level
    if args.guide == "none" and (args.guide_context is not None or args.guide_weight is not None
                                 or args.guide_alpha is not None):
        raise ValueError("--guide-context, --guide-weight and --guide-alpha set the guide: drop them with "
                         "--guide none")
    TrainOptions(**options)  # every option checked before any tracking
    points_list, audio_list, fps, _ = training_sequences(
        args.video, args.landmarks or [], args.audio or [], init=args.init, progress=not args.quiet,
        av_offset=None if args.av_offset is None else args.av_offset / 1000.0, report=print)
    if args.scheduler or args.workers:
        from voicepuppet.hmm import distributed

        with distributed.connect(args.scheduler, args.workers) as client:
            puppet = Puppet.train(points_list, audio_list, fps=fps, progress=not args.quiet, client=client,
                                  **options)
    else:
        puppet = Puppet.train(points_list, audio_list, fps=fps, progress=not args.quiet, **options)
    puppet.save(out)
    for part in puppet.metadata["training"]["parts"]:
        print(f"part {part['part']}: {part['states']} states (from {options.get('n_states', TRAIN_DEFAULTS['n_states'])}), "
              f"{part['arcs']} arcs, perplexity {part['perplexity']:.3g}, context memory "
              f"{part['context_memory']:.3g} frames, {part['face_dims']} face dims")
    guide = puppet.metadata["training"].get("guide", {})
    if "weight_cv" in guide:
        cv = guide["weight_cv"]
        print(f"guide weight {puppet.guide_weight:g}, chosen by cross-validation on the training audio "
              f"(error of the face's motion per frame {min(cv['mse']):.4g}; unguided {cv['mse'][0]:.4g})")
    print(f"trained on {sum(len(p) for p in points_list)} frames at {fps:g} fps; wrote {out}")
    return 0


def _guide_weight_option(text):
    """``--guide-weight`` of train: "cv" or a number >= 0 (None: not given)."""
    if text is None or text == "cv":
        return text
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--guide-weight must be 'cv' or a number >= 0, got {text!r}") from None


def _animate(args) -> int:
    from voicepuppet.animation import exaggerate, save_animation
    from voicepuppet._files import check_output_path
    from voicepuppet.puppet.model import load, palette_puppet
    from voicepuppet.puppet.states import load_states, save_states

    if Path(args.output).suffix.lower() in (".mp4", ".mov", ".mkv", ".webm", ".avi", ".gif"):
        raise ValueError(f"animate writes the landmark animation (.npz or .csv), not {args.output!r}; for a "
                         f"video, render it: voicepuppet animate ... -o anim.npz, then voicepuppet render "
                         f"anim.npz --audio AUDIO [--face PHOTO_OR_VIDEO] -o {args.output}")
    out = check_output_path(args.output, (".npz", ".csv"), "animation file")
    if args.sample:
        from voicepuppet.evaluation.real import sample_puppet

        if args.palette or (args.puppet and args.audio):
            raise ValueError("--sample is the puppet: give only the AUDIO (voicepuppet animate --sample "
                             "speech.wav -o anim.npz)")
        args.audio = args.audio or args.puppet
        puppet = sample_puppet(progress=not args.quiet)
    elif args.puppet is None:
        raise ValueError("give the PUPPET file (or --sample) and the AUDIO")
    else:
        puppet = load(palette_puppet(args.palette, args.puppet) if args.palette else args.puppet)
    adapt = {k: v for k, v in (("adapt", args.adapt), ("adapt_tau", args.adapt_tau),
                                ("adapt_iter", args.adapt_iter)) if v is not None}
    if adapt and args.adapt is None:
        raise ValueError("--adapt-tau and --adapt-iter set the adaptation: give --adapt full too")
    if args.states_in:
        if adapt:
            raise ValueError("--adapt changes how the audio is decoded; the states of --states-in are not "
                             "decoded: drop --adapt")
        if args.posterior:
            raise ValueError("--states-in gives one path: --posterior does not apply to it; drop --posterior")
        if args.audio is None and args.guide_weight is not None and args.guide_weight != 0:
            raise ValueError("--guide-weight weighs the guide's prediction from the audio; --states-in without "
                             "AUDIO is synthesised unguided: give the AUDIO the states go with, or drop --guide-weight")
        states, sfps = load_states(args.states_in)
        result = puppet.animate(args.audio, states=states, states_fps=sfps, fps=args.fps,
                                guide_weight=args.guide_weight, full_motion=not args.most_probable,
                                progress=not args.quiet)
        anim = result.animation
        if args.exaggerate is not None:
            anim = exaggerate(anim, args.exaggerate)
        save_animation(anim, out)
        done = (anim.duration, anim.n_frames, anim.fps, anim.neutral)
    else:
        if args.audio is None:
            raise ValueError("give the AUDIO to animate (or --states-in)")
        # long audio in bounded memory: the landmarks go to the file a block at a time (docs/puppet.md)
        result = puppet.animate_to(out, args.audio, fps=args.fps, posterior=args.posterior, progress=not args.quiet,
                                   guide_weight=args.guide_weight, full_motion=not args.most_probable,
                                   exaggerate=args.exaggerate, **adapt)
        done = (result.duration, result.n_frames, result.fps, result.neutral)
    written = [out]
    if args.states_out:
        written.append(save_states(args.states_out, result.states, result.states_fps))
    duration, n_frames, fps, neutral = done
    print(f"animated {duration:.2f} s ({n_frames} frame{'s' * (n_frames != 1)} at "
          f"{fps:g} fps); wrote {', '.join(str(w) for w in written)}")
    if neutral is not None and Path(out).suffix.lower() == ".csv":
        print("note: a .csv holds the frames only, so render and export move the face from its first frame; "
              "write .npz to keep the puppet's face in silence as the rest (docs/rendering.md, \"Retargeting\")")
    return 0


def add_parser(sub) -> None:
    """Register the ``train`` and ``animate`` verbs.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The sub-command parsers of the ``voicepuppet`` command line.
    """
    from voicepuppet.puppet.guide import GUIDE_ALPHAS, GUIDE_WEIGHTS

    p = sub.add_parser("train", help="train a voice puppet from video of a talking face",
                       description="Track the face (unless --landmarks are given), learn the facial "
                                   "state machine by entropic estimation, remap it to the audio "
                                   "(Voice Puppetry §4) and write the puppet file.")
    p.add_argument("video", nargs="*", help="training videos with sound (the face talking)")
    p.add_argument("-o", "--output", required=True, metavar="PUPPET.vpp", help="puppet file to write")
    p.add_argument("--landmarks", nargs="+", metavar="L.npz", help="landmarks (from voicepuppet track) instead of tracking")
    p.add_argument("--audio", nargs="+", metavar="AUDIO", help="the sound of each sequence (default: the video's)")
    p.add_argument("--init", default="auto", help="tracker init points for the videos (default: auto)")
    p.add_argument("--states", type=int, help="initial states of the facial HMM (default 40; entropic training trims)")
    p.add_argument("--iterations", type=int, help="EM iterations (default 40)")
    p.add_argument("--parts", choices=["upper_lower"], help="separate upper- and lower-face models (§5.1; 68-point landmarks; "
                   "default: one model of the whole face)")
    p.add_argument("--max-components", type=int, metavar="N",
                   help="at most N components of the face basis per part, which keeps 98 %% of the faces' "
                        "variance (default 12; a real face takes about 20: --max-components 40 with "
                        "--guide-alpha lips follows a real mouth better, docs/puppet.md)")
    p.add_argument("--prior", choices=["entropic", "ml"], help="entropic MAP (default) or conventional Baum-Welch")
    p.add_argument("--feature-set", help="audio feature set (default: puppet)")
    p.add_argument("--noise-snrs", metavar="DB[,DB...]",
                   help="also learn the vocal side from copies of the training audio with white noise at these "
                        "SNRs (dB), e.g. 20,10: a puppet for noisy recordings (default: none; docs/puppet.md)")
    p.add_argument("--audio-level", metavar="DBFS|none",
                   help="bring every recording the puppet hears, in training and after, to this speech level "
                        "(dBFS) and turn its frames 35 dB under that into dither, so pauses rest whatever the noise floor and quiet "
                        "recordings animate as loud ones (default -20; none: audio as recorded; docs/puppet.md)")
    p.add_argument("--av-offset", type=float, metavar="MS",
                   help="how late the sound runs against the face in every training recording (ms; negative: "
                        "early), corrected as given (default: estimated per recording from the mouth's opening "
                        "and the speech's loudness, and corrected when reliable and a frame or more; 0: none)")
    p.add_argument("--audio-band", type=float, metavar="HZ",
                   help="band-limit the training audio, and all audio the puppet animates, to HZ before analysis: "
                        "4000 for a puppet of telephone audio (sampled at 8 kHz; default: the whole band, or "
                        "the narrowest training audio's; docs/puppet.md)")
    p.add_argument("--vocal-features", choices=["audio", "projected"],
                   help="what the vocal Gaussians are fitted on: the audio features (default) or their learned "
                        "projection onto the face (live adds its 5-frame look-ahead; docs/puppet.md)")
    p.add_argument("--vocal-covariance", choices=["full", "diag", "tied"],
                   help="each state's vocal covariance: its own (full, default; or diag) or one for all (tied)")
    p.add_argument("--guide", choices=["ridge", "none"],
                   help="ridge (default): the ridge's prediction of the face from the audio joins the "
                        "trajectory solve as evidence, weighted by its residuals' inverse covariance; none: "
                        "Brand's solve alone (docs/puppet.md)")
    p.add_argument("--guide-context", type=int, metavar="K",
                   help="frames of audio on each side the guide's ridge reads (default 5)")
    p.add_argument("--guide-weight", metavar="cv|W",
                   help="the guide's weight written into the puppet: cv (default) chooses it from "
                        f"{', '.join(f'{w:g}' for w in GUIDE_WEIGHTS)} by cross-validation on the training "
                        "audio; a number fixes it")
    p.add_argument("--guide-alpha", choices=list(GUIDE_ALPHAS),
                   help="the guide's ridge regularisation, chosen by cross-validation: one for all face "
                        "coordinates on their error (shared, default), one per coordinate (per_coordinate) or "
                        "one for all on the error of the lips (lips; 68-point faces; docs/puppet.md)")
    p.add_argument("--seed", type=int, help="random seed (default 0)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run the HMM's E-steps on this Dask scheduler "
                   "(e.g. tcp://10.0.0.1:8786; docs/batch.md); same result as one process (default: all in "
                   "this process)")
    p.add_argument("--workers", type=int, help="run the E-steps on a local Dask cluster of this many processes "
                   "(with --scheduler: wait for that many workers; default: all in this process)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_train)

    a = sub.add_parser("animate", help="animate a puppet from audio",
                       description="Analyse the audio with the puppet's vocal HMM (Viterbi, or posteriors) "
                                   "and synthesise the most probable facial trajectory (§4.4-4.5), its motion "
                                   "widened as much as the puppet's animations of its training audio fell short.")
    a.add_argument("puppet", nargs="?", help="puppet file (.vpp), or a puppet's name with --palette")
    a.add_argument("--sample", action="store_true",
                   help="animate with the sample puppet instead of a PUPPET file: a real speaker (Barack "
                        "Obama) trained on the recordings inside voicepuppet, made on first use (about a minute) "
                        "and kept in the cache")
    a.add_argument("--palette", metavar="DIR", help="folder of puppets (NAME.vpp) to pick PUPPET from by name")
    a.add_argument("audio", nargs="?", help="audio file or video with sound")
    a.add_argument("-o", "--output", required=True, metavar="ANIM.npz", help="landmark animation (.npz or .csv)")
    a.add_argument("--fps", type=float, help="output frame rate (default: the puppet's)")
    a.add_argument("--posterior", action="store_true", help="posterior-weighted synthesis instead of the Viterbi path")
    a.add_argument("--most-probable", action="store_true",
                   help="the most probable trajectory as it is (default: its motion widened by the gains the "
                        "puppet learnt in training, per face coordinate, so that the mouth moves as much as "
                        "the speaker's did)")
    a.add_argument("--exaggerate", type=float, help="scale the motion about the mean face (default: as is, 1)")
    a.add_argument("--adapt", choices=["full"],
                   help="adapt the audio features to the puppet's vocal model before decoding (test-time "
                        "fMLLR-style EM, a full affine transform, for a voice far from the performer's; "
                        "default: none, the features as they are; docs/puppet.md)")
    a.add_argument("--adapt-tau", type=float, metavar="FRAMES",
                   help="the adaptation prior's weight in frames (default: puppet.ADAPT_DEFAULTS, 30)")
    a.add_argument("--adapt-iter", type=int, metavar="N",
                   help="adaptation EM iterations (default: puppet.ADAPT_DEFAULTS, 1)")
    a.add_argument("--guide-weight", type=float, metavar="W",
                   help="weight of a guided puppet's evidence (default: the puppet's, chosen at training; "
                        "0: Brand's unguided solve)")
    a.add_argument("--states-out", metavar="S.csv",
                   help="also write the facial state sequence, the Viterbi path (for editing: read it back with "
                        "--states-in and the same AUDIO)")
    a.add_argument("--states-in", metavar="S.csv",
                   help="synthesise from this (edited) state sequence instead of decoding the audio; with the AUDIO "
                        "it came from, guided by it as the animation was (unedited states give the same animation, "
                        "an edit changes the face where it is made); without AUDIO, Brand's unguided solve")
    a.add_argument("--quiet", action="store_true", help="no progress bars")
    a.set_defaults(func=_animate)
