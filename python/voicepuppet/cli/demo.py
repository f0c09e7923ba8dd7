"""``voicepuppet demo``: the whole system on embedded data, end to end.

1. The synthetic performer (:mod:`voicepuppet.synth`) speaks a training video (default 180 s,
   several voices) and held-out utterances (new sentences and voices, and a real recording).
2. The spring-mesh tracker follows the training video from the first frame's points and is
   measured against the ground truth.
3. A puppet is trained on the video's sound and the tracked landmarks (as on a user's video; or
   on the performer's ground truth with ``--train-on truth``), by entropic estimation; a
   conventionally trained one (Baum-Welch) beside it for comparison.
4. Both animate the held-out audio; :func:`voicepuppet.evaluation.split.evaluate_split` measures them
   against the ground truth with the baselines (mean face; ridge regression fitted on the same
   training landmarks as the puppet).
5. The held-out utterances are rendered in a row, side by side with their ground truth, sound
   muxed in, and the prediction alone on a textured 3-D head scan (:mod:`voicepuppet.render.head`).

Everything lands in ``--out`` (default ``voicepuppet-demo/``): ``puppet.vpp``, ``animation.npz``,
``demo.mp4``, ``head.mp4``, ``metrics.json`` and ``results.md``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np


def run(out_dir="voicepuppet-demo", *, train_seconds: float = 180.0, n_test: int = 10, seed: int = 0,
        n_states: int = 40, train_on: str = "tracked", compare_conventional: bool = True,
        render_video: bool = True, progress: bool = True, log=print, speech: str = "espeak") -> dict:
    """Run the demo; returns the metrics (also written to ``out_dir/metrics.json``).

    Parameters
    ----------
    out_dir : str or os.PathLike
        Output folder (default ``"voicepuppet-demo"``), created if missing; the corpus is cached
        in it.
    train_seconds : float
        Length of the training video in seconds (default 180).
    n_test : int
        Number of held-out utterances (default 10).
    seed : int
        Seed of the corpus and of training (default 0).
    n_states : int
        Initial facial states of the puppets (default 40).
    train_on : {"tracked", "truth"}
        The training landmarks: ``"tracked"`` (what the spring-mesh tracker found, the default)
        or ``"truth"`` (the performer's ground truth; the tracker is still run and measured).
    compare_conventional : bool
        Also train and measure a conventionally trained puppet (Baum-Welch; default True).
    render_video : bool
        Render ``demo.mp4`` and ``head.mp4`` (default True).
    progress : bool
        Show progress bars (default True).
    log : callable
        Called with each progress message (default :func:`print`).
    speech : {"espeak", "real"}
        ``"real"``: the performer speaks the real recordings that ship inside packages
        (:func:`voicepuppet.synth.make_real_corpus`: 80 s of two LibriVox readers, tested on two
        CMU ARCTIC speakers; ``train_seconds`` and ``n_test`` are then not used), in
        ``out_dir/corpus-real``; a third puppet for voices it never heard (``vocal_features=
        "projected"``, ``vocal_covariance="tied"``) is measured beside the default there.
        Default ``"espeak"``: espeak-ng sentences.

    Returns
    -------
    dict
        ``train_frames``, ``test_frames``, ``tracker_rmse_iod`` and ``tracker_lips_rmse_iod``
        (the tracker's error over the inter-ocular distance), ``trained_on``, ``models`` (per
        puppet, :func:`voicepuppet.evaluation.split.evaluate_split`'s result), ``timings``
        (seconds per stage) and ``test_clips``.

    Raises
    ------
    ValueError
        ``train_on`` or ``speech`` not one of their values.
    """
    if train_on not in ("truth", "tracked"):
        raise ValueError(f"train_on must be 'truth' or 'tracked', got {train_on!r}")
    if speech not in ("espeak", "real"):
        raise ValueError(f"speech must be 'espeak' or 'real', got {speech!r}")
    from voicepuppet import synth
    from voicepuppet.evaluation import report
    from voicepuppet.evaluation import split as evaluation
    from voicepuppet.evaluation import metrics
    from voicepuppet.tracking import tracker as tracking
    from voicepuppet.animation import Animation, save_animation
    from voicepuppet._files import atomic_path
    from voicepuppet.face import shape_distance
    from voicepuppet.puppet.model import Puppet

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    t0 = time.perf_counter()
    if speech == "real":
        log(f"[1/5] the synthetic performer speaking real recordings: two LibriVox readers to learn from, "
            f"two CMU ARCTIC speakers held out (cached in {out / 'corpus-real'})")
        corpus = synth.make_real_corpus(out / "corpus-real", seed=seed, progress=progress)
    else:
        log(f"[1/5] the synthetic performer: {train_seconds:g} s of training video and {n_test} held-out "
            f"utterances (cached in {out / 'corpus'})")
        corpus = synth.make_corpus(out / "corpus", train_seconds=train_seconds, n_test=n_test, seed=seed,
                                   progress=progress)
    train, tests = corpus.train, corpus.test
    timings["corpus_s"] = time.perf_counter() - t0

    t = time.perf_counter()
    log(f"[2/5] tracking {train.n_frames} frames of {Path(train.video).name} from the first frame's points")
    tracked = tracking.track_video(train.video, init=train.points[0], progress=progress)
    n = min(len(tracked.points), train.n_frames)
    track_err = metrics.landmark_rmse_iod(tracked.points[:n], train.points[:n])
    timings["track_s"] = time.perf_counter() - t
    lips = list(metrics.IBUG68_MOUTH)
    lip_err = metrics.landmark_rmse_iod(tracked.points[:n, lips], train.points[:n, lips],
                                        iod=metrics.inter_ocular(train.points[:n]))
    log(f"      tracker error against ground truth: {track_err:.4f} of the inter-ocular distance "
        f"(lips {lip_err:.4f})")
    landmarks = train.points[:n] if train_on == "truth" else tracked.points[:n]

    t = time.perf_counter()
    log(f"[3/5] training the puppet on the {'ground-truth' if train_on == 'truth' else 'tracked'} "
        f"landmarks ({n_states} initial states, entropic estimation)")
    puppet = Puppet.train([landmarks], [train.audio], fps=tracked.fps, n_states=n_states,
                          seed=seed, progress=progress)
    puppet.save(out / "puppet.vpp")
    timings["train_s"] = time.perf_counter() - t
    models = {"entropic": puppet}
    if compare_conventional:
        log("      and a conventionally trained one (Baum-Welch, no prior) for comparison")
        models["conventional"] = Puppet.train([landmarks], [train.audio], fps=tracked.fps,
                                              n_states=n_states, seed=seed, prior="ml", progress=progress)
    if speech == "real":
        # The test speakers are voices it never heard: the option for them beside the default.
        log("      and one for voices it never heard (vocal Gaussians on the learned projection, tied)")
        models["projected"] = Puppet.train([landmarks], [train.audio], fps=tracked.fps, n_states=n_states,
                                           seed=seed, vocal_features="projected", vocal_covariance="tied",
                                           progress=progress)

    t = time.perf_counter()
    log(f"[4/5] animating {len(tests)} held-out utterances and measuring against ground truth")
    cache: dict = {}
    # Measured against the ground truth; the ridge baseline learns from what the puppet learnt from.
    from voicepuppet.evaluation.corpus import bilabial_frames

    results = {name: evaluation.evaluate_split(m, [(train.points[:n], train.audio, bilabial_frames(train)[:n])],
                                               [(c.points, c.audio, bilabial_frames(c)) for c in tests],
                                               fit_points=[landmarks], cache=cache)
               for name, m in models.items()}
    timings["evaluate_s"] = time.perf_counter() - t

    # All held-out utterances in a row: the prediction with the performer's head pose re-applied
    # (the puppet models the face; the pose is its own track), the truth and the sound.
    import soundfile

    pred, true, sound = [], [], []
    for clip in tests:
        r = puppet.animate(clip.audio)
        T = min(r.animation.n_frames, clip.n_frames)
        _, pose = puppet.face_space.encode(clip.points)
        pred.append(puppet.face_space.decode(r.face[:T], pose[:T]))
        true.append(clip.points[:T])
        sound.append(np.pad(clip.samples, (0, max(0, int(round(T / clip.fps * clip.rate)) - len(clip.samples))))
                     [: int(round(T / clip.fps * clip.rate))])
    # The face is the training video's frame nearest the puppet's silent face: the performer at
    # rest, whose landmarks (the video's coordinates, as the prediction's) both sides move from.
    rest = int(np.argmin(shape_distance(train.points, puppet.rest_face())))
    anim = Animation(np.concatenate(pred), puppet.fps, neutral=train.points[rest])
    save_animation(anim, out / "animation.npz")
    with atomic_path(out / "heldout.wav", (".wav",), "audio file") as tmp:
        soundfile.write(tmp, np.concatenate(sound), tests[0].rate, format="WAV")
    if render_video:
        t = time.perf_counter()
        log(f"[5/5] rendering {out / 'demo.mp4'} (prediction | ground truth) with the sound")
        from voicepuppet import render
        from voicepuppet.tracking import video

        photo = video.frame_at(train.video, rest, grey=False)[..., ::-1]
        mesh = render.build_face_mesh(np.ascontiguousarray(photo), train.points[rest])
        render.render(anim, out / "demo.mp4", audio=str(out / "heldout.wav"), face=mesh,
                      truth=Animation(np.concatenate(true), puppet.fps), neutral=anim.neutral, progress=progress)
        timings["render_s"] = time.perf_counter() - t
        t = time.perf_counter()
        from voicepuppet.render import head

        try:
            scan = head.sample_head()
        except RuntimeError as exc:  # offline: the scan is fetched from PyPI once
            log(f"      no head.mp4: {exc}")
        else:
            log(f"      and {out / 'head.mp4'}: the prediction on a textured 3-D head scan (menpo3d's james)")
            face = head.load_head(*scan, height=480)  # 500 x 480: 13 MB for the 31 s (at 750 x 720, 25 MB)
            render.render(anim, out / "head.mp4", audio=str(out / "heldout.wav"), face=face, progress=progress)
            timings["render_head_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - t0

    summary = {"train_frames": int(n), "test_frames": int(sum(c.n_frames for c in tests)),
               "tracker_rmse_iod": track_err, "tracker_lips_rmse_iod": lip_err, "trained_on": train_on,
               "models": results, "timings": timings,
               "test_clips": [c.source for c in tests]}
    with atomic_path(out / "metrics.json", (".json",), "metrics file") as tmp:
        tmp.write_text(json.dumps(summary, indent=2))
    tables = [report.format_split(res, f"{name} puppet") for name, res in results.items()]
    text = ("# voicepuppet demo\n\n" + f"{n} training frames, {summary['test_frames']} held-out frames "
            f"({len(tests)} utterances). Trained on the {train_on} landmarks. Tracker error "
            f"{track_err:.4f} IOD (lips {lip_err:.4f}).\n\n" + "\n\n".join(tables) + "\n")
    with atomic_path(out / "results.md", (".md",), "results file") as tmp:
        tmp.write_text(text)
    return summary


def _cli(args) -> int:
    from voicepuppet.evaluation import report

    s = run(args.out, train_seconds=args.train_seconds, n_test=args.n_test, seed=args.seed,
            n_states=args.states, train_on=args.train_on, compare_conventional=not args.no_conventional,
            render_video=not args.no_render, progress=not args.quiet, speech=args.speech)
    print()
    for name, res in s["models"].items():
        print(report.format_split(res, f"{name} puppet"))
        print()
    print("err: Voice Puppetry eq. 7 (0 perfect, 1 = no motion); rmse_iod: landmark RMSE / inter-ocular "
          "distance; lve: lip vertex error (px^2); closed: share of the b, p, m whose lips close (truth 1). "
          "Rows: states = reconstruction from the facial state "
          "sequence; voice = driven by the audio alone; mean-face and ridge = baselines.")
    videos = "".join(f"{v}, " for v in ("demo.mp4", "head.mp4") if (Path(args.out) / v).is_file() and not args.no_render)
    print(f"done in {s['timings']['total_s']:.0f} s; wrote {args.out}/ (puppet.vpp, animation.npz, "
          f"heldout.wav, {videos}metrics.json, results.md)")
    return 0


def add_parser(sub) -> None:
    """Register the ``demo`` verb.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The sub-command parsers of the ``voicepuppet`` command line.
    """
    p = sub.add_parser("demo", help="the whole system on embedded data: train, animate, evaluate, render",
                       description="Generate the synthetic performer's training video and held-out speech, "
                                   "track it, train a puppet, animate the held-out audio, measure it "
                                   "against ground truth and render an mp4.")
    p.add_argument("--out", default="voicepuppet-demo", help="output folder (default voicepuppet-demo)")
    p.add_argument("--train-seconds", type=float, default=180.0, help="training video length (default 180)")
    p.add_argument("--train-on", choices=["tracked", "truth"], default="tracked",
                   help="train on the tracked landmarks (default, as on your own video) or on the "
                        "performer's ground truth (the tracker is still run and measured)")
    p.add_argument("--n-test", type=int, default=10, help="held-out utterances (default 10)")
    p.add_argument("--speech", choices=["espeak", "real"], default="espeak",
                   help="what the performer speaks: espeak-ng sentences (default) or the real recordings "
                        "that ship inside packages (80 s of two LibriVox readers; held out: two CMU ARCTIC "
                        "speakers; --train-seconds and --n-test then unused)")
    p.add_argument("--states", type=int, default=40, help="initial facial states (default 40)")
    p.add_argument("--seed", type=int, default=0, help="seed of the corpus and of training (default 0)")
    p.add_argument("--no-conventional", action="store_true", help="skip the Baum-Welch comparison puppet")
    p.add_argument("--no-render", action="store_true", help="skip the mp4s")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cli)
