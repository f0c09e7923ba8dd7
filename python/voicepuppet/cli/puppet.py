"""The ``train`` and ``animate`` verbs (see :mod:`voicepuppet.puppet.model` for what they drive)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

#: A frame whose share of lost points exceeds this is not used for training.
MAX_LOST_SHARE = 0.3
#: Shortest run of usable frames kept for training.
MIN_SEGMENT = 10
#: A face and its audio whose durations differ by more than this (s) are warned about: they may
#: not belong together.
MAX_AV_MISMATCH_S = 0.5


def usable_segments(points, lost=None, audio=None, fps: float = 29.97, where: str = ""):
    """Split a tracked sequence where the face was lost; returns ``[(points, audio), ...]``.

    Frames with more than :data:`MAX_LOST_SHARE` of their points flagged lost are dropped, and
    runs shorter than :data:`MIN_SEGMENT` frames too; a warning says how much was dropped. A NaN
    or infinite point (another tool's mark for a point it lost) counts as lost; one on a frame
    that is kept is refused, with its frame. The audio of each kept run is cut to match
    (``audio`` is an :class:`voicepuppet.audio.Audio`).
    """
    from dataclasses import replace

    T = len(points)
    missing = ~np.isfinite(np.asarray(points, dtype=np.float64)).reshape(T, -1, 2).all(axis=2)
    if lost is None and not missing.any():
        return [(points, audio)]
    lost = missing if lost is None else np.asarray(lost, dtype=bool).reshape(T, -1) | missing
    bad = lost.mean(axis=1) > MAX_LOST_SHARE
    if missing[~bad].any():
        t, p = np.argwhere(missing & ~bad[:, None])[0]
        raise ValueError(f"{where}point {p} of frame {t} is NaN or infinite on a frame where the face is found "
                         f"(at most {100 * MAX_LOST_SHARE:g}% of its points lost); fill it in (interpolate) or "
                         "drop the frame")
    if not bad.any():
        return [(points, audio)]
    runs, start = [], None
    for t in range(T + 1):
        ok = t < T and not bad[t]
        if ok and start is None:
            start = t
        elif not ok and start is not None:
            if t - start >= MIN_SEGMENT:
                runs.append((start, t))
            start = None
    kept = sum(b - a for a, b in runs)
    if not runs:
        raise ValueError(f"{where}the face is lost in {int(bad.sum())} of {T} frames, leaving no run of "
                         f"{MIN_SEGMENT} usable frames; check the video or the tracker's init points")
    warnings.warn(f"{where}the face was lost in {int(bad.sum())} of {T} frames; training on the "
                  f"{len(runs)} stretch(es) where it was found ({kept} frames)", stacklevel=2)
    out = []
    for a, b in runs:
        s0, s1 = int(round(a / fps * audio.rate)), int(round(b / fps * audio.rate))
        out.append((points[a:b], replace(audio, samples=audio.samples[s0:s1])))
    return out


def _train(args) -> int:
    from voicepuppet import audio as vaudio
    from voicepuppet._files import check_output_path
    from voicepuppet.puppet.model import TRAIN_DEFAULTS, Puppet
    from voicepuppet.tracking.landmarks import load_landmarks, on_uniform_grid
    from voicepuppet.tracking.tracker import VariableFrameRateWarning, track_video

    out = check_output_path(args.output, (".vpp",), "puppet file")
    videos, marks, audios = list(args.video), list(args.landmarks or []), list(args.audio or [])
    if not videos and not marks:
        raise ValueError("give training videos, or --landmarks with --audio")
    if marks and videos and len(marks) != len(videos):
        raise ValueError(f"{len(marks)} --landmarks files for {len(videos)} videos; give one per video")
    if audios and len(audios) != max(len(videos), len(marks)):
        raise ValueError(f"{len(audios)} --audio files for {max(len(videos), len(marks))} sequences; give one each")
    if marks and not videos and not audios:
        raise ValueError("--landmarks needs --audio (or the videos they were tracked from)")
    feature_set = args.feature_set
    if args.audio_band is not None:  # checked here, before any tracking
        from voicepuppet.audio.stream import BandLimiter

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
    n = max(len(videos), len(marks))
    # Every sound before any tracking: a video without an audio track fails in a second, not
    # after minutes of tracking it (and the ones before it).
    sounds = [vaudio.load_audio(audios[i] if audios else videos[i]) for i in range(n)]
    points_list, audio_list, fps = [], [], None
    for i in range(n):
        if marks:
            data = load_landmarks(marks[i])
            if "points" not in data:
                raise ValueError(f"{marks[i]}: no 'points' array; expected landmarks from voicepuppet track")
            pts, f = data["points"], float(np.asarray(data.get("fps", 29.97)).reshape(-1)[0])
            lost, times = data.get("lost"), data.get("times")
            where = f"{marks[i]}: "
        else:
            print(f"tracking {videos[i]} ...")
            with warnings.catch_warnings():  # the resampling below says it, with what it did
                warnings.simplefilter("ignore", VariableFrameRateWarning)
                res = track_video(videos[i], init=args.init, progress=not args.quiet)
            pts, f, lost, times, where = res.points, res.fps, res.lost, res.times, f"{videos[i]}: "
        if fps is None:
            fps = f
        elif times is None and abs(f - fps) > 1e-3:
            raise ValueError(f"sequence {i} runs at {f:g} fps but the first at {fps:g}; use one frame rate")
        pts, lost = on_uniform_grid(pts, lost, times, fps, where)
        seen, heard = len(pts) / fps, sounds[i].duration
        if abs(seen - heard) > MAX_AV_MISMATCH_S:
            warnings.warn(f"{where}the face runs {seen:.2f} s and its audio {heard:.2f} s ("
                          f"{audios[i] if audios else videos[i]}): "
                          + ("the frames after the audio ends are trained on silence" if seen > heard else
                             "the audio after the last frame is not used")
                          + "; check that the two belong together", stacklevel=2)
        for seg in usable_segments(pts, lost, sounds[i], fps, where):
            points_list.append(seg[0])
            audio_list.append(seg[1])
    options = {k: v for k, v in {"n_states": args.states, "n_iter": args.iterations, "parts": args.parts,
                                  "prior": args.prior, "feature_set": feature_set, "noise_snrs": noise_snrs,
                                  "vocal_features": args.vocal_features,
                                  "vocal_covariance": args.vocal_covariance,
                                  "guide": args.guide, "guide_context": args.guide_context,
                                  "guide_weight": _guide_weight_option(args.guide_weight),
                                  "seed": args.seed}.items() if v is not None}
    if args.audio_level is not None:
        options["audio_level"] = level
    if args.guide == "none" and (args.guide_context is not None or args.guide_weight is not None):
        raise ValueError("--guide-context and --guide-weight set the guide: drop them with --guide none")
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
              f"(face error per frame {min(cv['mse']):.4g}; unguided {cv['mse'][0]:.4g})")
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


def save_states(path, states: np.ndarray, fps: float) -> Path:
    """Write a state sequence as CSV ``frame,time,part0[,part1...]``, atomically."""
    from voicepuppet._files import atomic_path

    T, n_parts = states.shape
    table = np.column_stack([np.arange(T), np.arange(T) / fps, states])
    with atomic_path(path, (".csv",), "states file") as tmp:
        np.savetxt(tmp, table, fmt=["%d", "%.9g"] + ["%d"] * n_parts, delimiter=",",
                   header="frame,time," + ",".join(f"part{k}" for k in range(n_parts)), comments="")
    return Path(path)


def load_states(path) -> tuple[np.ndarray, float]:
    """Read a states CSV written by :func:`save_states` (possibly edited): ``(states, fps)``."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"states file {str(p)!r} does not exist")
    try:
        table = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"states file {str(p)!r} is not a 'frame,time,part0,...' CSV: {exc}") from None
    if table.shape[0] < 2 or table.shape[1] < 3:
        raise ValueError(f"states file {str(p)!r} needs at least 2 rows of frame,time,part0[,...]")
    states = table[:, 2:]
    if not np.all(states == np.round(states)):
        raise ValueError(f"states file {str(p)!r} holds non-integer states")
    fps = 1.0 / float(np.median(np.diff(table[:, 1])))
    return states.astype(np.int64), fps


def palette_puppet(palette, name: str) -> Path:
    """The puppet file called ``name`` (with or without ``.vpp``) in the folder ``palette``
    (Brand §6: the animator picks a character's manner from a palette of puppets)."""
    folder = Path(palette)
    if not folder.is_dir():
        raise ValueError(f"--palette {str(folder)!r} is not a folder of .vpp puppets")
    available = sorted(p.stem for p in folder.glob("*.vpp"))
    stem = name[:-4] if name.endswith(".vpp") else name
    if stem not in available:
        raise ValueError(f"no puppet {stem!r} in palette {str(folder)!r}; it holds: "
                         f"{', '.join(available) if available else 'no .vpp files'}")
    return folder / f"{stem}.vpp"


def _animate(args) -> int:
    from voicepuppet.animation import exaggerate, save_animation
    from voicepuppet._files import check_output_path
    from voicepuppet.puppet.model import load

    if Path(args.output).suffix.lower() in (".mp4", ".mov", ".mkv", ".webm", ".avi", ".gif"):
        raise ValueError(f"animate writes the landmark animation (.npz or .csv), not {args.output!r}; for a "
                         f"video, render it: voicepuppet animate ... -o anim.npz, then voicepuppet render "
                         f"anim.npz --audio AUDIO [--face PHOTO_OR_VIDEO] -o {args.output}")
    out = check_output_path(args.output, (".npz", ".csv"), "animation file")
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
                                guide_weight=args.guide_weight, progress=not args.quiet)
    else:
        if args.audio is None:
            raise ValueError("give the AUDIO to animate (or --states-in)")
        result = puppet.animate(args.audio, fps=args.fps, posterior=args.posterior, progress=not args.quiet,
                                guide_weight=args.guide_weight, **adapt)
    anim = result.animation
    if args.exaggerate is not None:
        anim = exaggerate(anim, args.exaggerate)
    save_animation(anim, out)
    written = [out]
    if args.states_out:
        written.append(save_states(args.states_out, result.states, result.states_fps))
    print(f"animated {anim.duration:.2f} s ({anim.n_frames} frame{'s' * (anim.n_frames != 1)} at "
          f"{anim.fps:g} fps); wrote {', '.join(str(w) for w in written)}")
    if anim.neutral is not None and Path(out).suffix.lower() == ".csv":
        print("note: a .csv holds the frames only, so render and export move the face from its first frame; "
              "write .npz to keep the puppet's face in silence as the rest (docs/rendering.md, \"Retargeting\")")
    return 0


def add_parser(sub) -> None:
    from voicepuppet.puppet.guide import GUIDE_WEIGHTS

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
    p.add_argument("--parts", choices=["upper_lower"], help="separate upper- and lower-face models (§5.1; 68-point landmarks)")
    p.add_argument("--prior", choices=["entropic", "ml"], help="entropic MAP (default) or conventional Baum-Welch")
    p.add_argument("--feature-set", help="audio feature set (default: puppet)")
    p.add_argument("--noise-snrs", metavar="DB[,DB...]",
                   help="also learn the vocal side from copies of the training audio with white noise at these "
                        "SNRs (dB), e.g. 20,10: a puppet for noisy recordings (on the demo's data: at 20 dB SNR Err "
                        "0.630 -> 0.489, +0.041 on clean audio; as much on pink noise, less under other voices; "
                        "docs/puppet.md)")
    p.add_argument("--audio-level", metavar="DBFS|none",
                   help="bring every recording the puppet hears, in training and after, to this speech level "
                        "(dBFS) and turn its frames 35 dB under that into dither, so pauses rest whatever the noise floor and quiet "
                        "recordings animate as loud ones (default -20; none: audio as recorded, as puppets "
                        "before 2026-12-04; docs/puppet.md)")
    p.add_argument("--audio-band", type=float, metavar="HZ",
                   help="band-limit the training audio, and all audio the puppet animates, to HZ before analysis: "
                        "4000 for a puppet of telephone audio (sampled at 8 kHz; default: the whole band, or "
                        "the narrowest training audio's; docs/puppet.md)")
    p.add_argument("--vocal-features", choices=["audio", "projected"],
                   help="what the vocal Gaussians are fitted on: the audio features (default) or their learned "
                        "projection onto the face (with --vocal-covariance tied: better on voices the puppet "
                        "never heard, worse on the training voice; live adds its 5-frame look-ahead; docs/puppet.md)")
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
                        "audio; a number fixes it (earlier versions fixed it at 4)")
    p.add_argument("--seed", type=int, help="random seed (default 0)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run the HMM's E-steps on this Dask scheduler "
                   "(e.g. tcp://10.0.0.1:8786; docs/batch.md); same result as one process")
    p.add_argument("--workers", type=int, help="run the E-steps on a local Dask cluster of this many processes")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_train)

    a = sub.add_parser("animate", help="animate a puppet from audio",
                       description="Analyse the audio with the puppet's vocal HMM (Viterbi, or posteriors) "
                                   "and synthesise the most probable facial trajectory (§4.4-4.5).")
    a.add_argument("puppet", help="puppet file (.vpp), or a puppet's name with --palette")
    a.add_argument("--palette", metavar="DIR", help="folder of puppets (NAME.vpp) to pick PUPPET from by name")
    a.add_argument("audio", nargs="?", help="audio file or video with sound")
    a.add_argument("-o", "--output", required=True, metavar="ANIM.npz", help="landmark animation (.npz or .csv)")
    a.add_argument("--fps", type=float, help="output frame rate (default: the puppet's)")
    a.add_argument("--posterior", action="store_true", help="posterior-weighted synthesis instead of the Viterbi path")
    a.add_argument("--exaggerate", type=float, help="scale the motion about the mean face (1: as is)")
    a.add_argument("--adapt", choices=["full"],
                   help="adapt the audio features to the puppet's vocal model before decoding (test-time "
                        "fMLLR-style EM, a full affine transform; for a voice far from the performer's, "
                        "docs/puppet.md)")
    a.add_argument("--adapt-tau", type=float, metavar="FRAMES",
                   help="the adaptation prior's weight in frames (default: puppet.ADAPT_DEFAULTS, 30)")
    a.add_argument("--adapt-iter", type=int, metavar="N",
                   help="adaptation EM iterations (default: puppet.ADAPT_DEFAULTS, 1)")
    a.add_argument("--guide-weight", type=float, metavar="W",
                   help="weight of a guided puppet's evidence (default: the puppet's, chosen at training; "
                        "0: Brand's unguided solve; lower: the lips close more fully on b, p, m, at some cost "
                        "in lip error elsewhere; docs/results.md)")
    a.add_argument("--states-out", metavar="S.csv",
                   help="also write the facial state sequence, the Viterbi path (for editing: read it back with "
                        "--states-in and the same AUDIO)")
    a.add_argument("--states-in", metavar="S.csv",
                   help="synthesise from this (edited) state sequence instead of decoding the audio; with the AUDIO "
                        "it came from, guided by it as the animation was (unedited states give the same animation, "
                        "an edit changes the face where it is made); without AUDIO, Brand's unguided solve")
    a.add_argument("--quiet", action="store_true", help="no progress bars")
    a.set_defaults(func=_animate)
