"""The ``phoneme-puppet`` verbs: ``train`` and ``animate`` a phoneme-driven face model (see
:class:`voicepuppet.phonemes.puppet.PhonemePuppet` for what they drive)."""

from __future__ import annotations


def _read_labels(path, alphabet: str):
    from voicepuppet.phonemes import labels as phonemes

    low = str(path).lower()
    if low.endswith(".textgrid"):
        return phonemes.read_textgrid(path, alphabet=alphabet)
    if low.endswith(".lab"):
        return phonemes.read_hts(path, alphabet=alphabet)
    raise ValueError(f"phone labels must be a .TextGrid or an HTS .lab file, got {str(path)!r}")


def _run_train(args) -> int:
    from voicepuppet.animation import load_animation
    from voicepuppet.phonemes.puppet import PhonemePuppet

    if len(args.landmarks) != len(args.labels):
        raise ValueError(f"give one label file per landmark file: {len(args.landmarks)} landmark files, "
                         f"{len(args.labels)} label files")
    anims = [load_animation(p) for p in args.landmarks]
    fps = anims[0].fps
    for p, a in zip(args.landmarks, anims):
        if abs(a.fps - fps) > 1e-6:
            raise ValueError(f"all landmark files must share one frame rate; {p} has {a.fps}, "
                             f"{args.landmarks[0]} has {fps}")
    phones = [_read_labels(p, args.alphabet) for p in args.labels]
    n_comp = float(args.components) if "." in args.components else int(args.components)
    pp = PhonemePuppet.train([a.points for a in anims], phones, fps=fps, model=args.model,
                             alphabet=args.alphabet, n_components=n_comp, progress=not args.quiet)
    pp.save(args.output)
    n = sum(len(a.points) for a in anims)
    print(f"{args.model} on {n} frames of {len(anims)} sequences ({pp.face_space.n_dims} face dims); "
          f"wrote {args.output}")
    return 0


def _run_animate(args) -> int:
    from voicepuppet.animation import save_animation
    from voicepuppet.phonemes.puppet import PhonemePuppet

    pp = PhonemePuppet.load(args.puppet)
    if (args.audio is None) == (args.labels is None):
        raise ValueError("give AUDIO (with --transcript, or phone recognition without) or --labels FILE")
    if args.labels is not None:
        anim = pp.animate(_read_labels(args.labels, args.alphabet))
    else:
        anim = pp.animate(audio=args.audio, transcript=args.transcript)
    save_animation(anim, args.output)
    print(f"{len(anim.points)} frames at {anim.fps:g} fps; wrote {args.output}")
    return 0


def add_parser(sub) -> None:
    from voicepuppet.phonemes.models import MODELS

    p = sub.add_parser("phoneme-puppet", help="train or animate a phoneme-driven face model (DPDS, SLDS, ...)",
                       description="Phoneme-driven peers of the voice puppet: train a model on landmark "
                                   "sequences with their phone labels, animate it from phone labels or "
                                   "from speech and its transcript (pocketsphinx alignment).")
    ss = p.add_subparsers(dest="action", metavar="ACTION")
    ss.required = True
    t = ss.add_parser("train", help="train on landmarks (.npz/.csv) and phone labels (.TextGrid/.lab)")
    t.add_argument("--landmarks", nargs="+", required=True, metavar="FILE", help="landmark animations, one per sequence")
    t.add_argument("--labels", nargs="+", required=True, metavar="FILE", help="phone labels, one per sequence")
    t.add_argument("--model", choices=list(MODELS), default="dpds", help="which model (default dpds)")
    t.add_argument("--alphabet", choices=["arpabet", "espeak"], default="arpabet",
                   help="alphabet of the phone labels: ARPAbet or espeak-ng's mnemonics (default arpabet)")
    t.add_argument("--components", default="0.98",
                   help="face-space size: integer or variance fraction (default 0.98)")
    t.add_argument("-o", "--output", required=True, metavar="MODEL.npz", help="the model file written")
    t.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    t.set_defaults(func=_run_train)
    a = ss.add_parser("animate", help="landmarks from speech + transcript, or from phone labels")
    a.add_argument("puppet", help="a model written by 'phoneme-puppet train'")
    a.add_argument("audio", nargs="?", help="speech to align (sound file)")
    a.add_argument("-t", "--transcript", help="the words of AUDIO (phone recognition without)")
    a.add_argument("--labels", metavar="FILE", help="phone labels (.TextGrid/.lab) instead of AUDIO")
    a.add_argument("--alphabet", choices=["arpabet", "espeak"], default="arpabet",
                   help="alphabet of --labels: ARPAbet or espeak-ng's mnemonics (default arpabet)")
    a.add_argument("-o", "--output", required=True, metavar="ANIM.npz|.csv", help="the landmark animation written")
    a.set_defaults(func=_run_animate)
