"""``voicepuppet info``: versions, build type, compiler and SIMD of the compiled core."""

from __future__ import annotations

import platform


def collect() -> dict:
    """Versions of voicepuppet, its compiled core and its main dependencies, and the BLAS numpy
    uses with its current thread count, as a dict.

    Returns
    -------
    dict of str to str
        ``voicepuppet``, ``python``, ``numpy``, ``platform``, the core's build information
        (keys ``core_*``) and ``blas``.
    """
    import numpy

    from voicepuppet import _core
    from voicepuppet._version import __version__

    info = {"voicepuppet": __version__, "python": platform.python_version(),
            "numpy": numpy.__version__, "platform": platform.platform()}
    info.update({f"core_{k}": v for k, v in _core.build_info().items()})
    from threadpoolctl import threadpool_info

    blas = [lib for lib in threadpool_info() if lib.get("user_api") == "blas"]
    info["blas"] = ", ".join(f"{lib['internal_api']} {lib['version']}, {lib['num_threads']} "
                             f"thread{'s' if lib['num_threads'] != 1 else ''}"
                             for lib in blas) or "none found"
    return info


def describe_puppet(path) -> list[str]:
    """What a puppet file holds, as lines of text: who wrote it, its face and audio, each part's
    state machine and the guide (with the errors its weight was chosen by).

    Parameters
    ----------
    path : str or os.PathLike
        The puppet file (``.vpp``).

    Returns
    -------
    list of str
        The description, one line per item.

    Raises
    ------
    ValueError
        A file that is not a readable puppet (:func:`voicepuppet.puppet.model.load`).
    """
    from voicepuppet.puppet.model import load

    p = load(path)
    m, t = p.metadata, p.metadata.get("training", {})
    opt = t.get("options", {})
    n_seq = t.get("sequences")
    lines = [f"{path}: written by {m.get('created_by', 'an unknown version')}; {p.n_points} points at "
             f"{p.fps:g} fps, part{'s' if len(p.part_names) > 1 else ''} {', '.join(p.part_names)}"]
    if "frames" in t:
        lines.append(f"trained on {t['frames']} frames ({n_seq} sequence{'s' if n_seq != 1 else ''}), "
                     f"{'conventional Baum-Welch' if opt.get('prior') == 'ml' else 'entropic prior'}, "
                     f"seed {opt.get('seed', '?')}")
    for part in t.get("parts", []):
        lines.append(f"part {part['part']}: {part['states']} states, {part['arcs']} arcs, "
                     f"{part['face_dims']} face dims, perplexity {part['perplexity']:.3g}, context memory "
                     f"{part['context_memory']:.3g} frames")
    vocal = (f"the learned projection of the audio (±{p._core.projection_context} frames)"
             if p._core.projected else "the audio features")
    band, level = p.feature_set.settings()["band_hz"], p.feature_set.settings()["level_db"]
    lines.append(f"audio: feature set {p.feature_set.name} ({p._core.n_features} features, deltas "
                 f"±{p._core.delta_width}" + (f", band-limited to {band:g} Hz" if band else "")
                 + (f", speech brought to {level:g} dBFS" if level is not None else ", levels as recorded")
                 + f"); vocal Gaussians on {vocal}, {opt.get('vocal_covariance', 'full')} covariances")
    if not p.guided:
        lines.append("guide: none (Brand's trajectory solve alone)")
        return lines
    guide = t.get("guide", {})
    line = f"guide: the ridge's face over ±{p._core.guide_context} frames, weight {p.guide_weight:g}"
    cv = guide.get("weight_cv")
    if cv:
        errors = ", ".join(f"{w:g}: {e:.4g}" for w, e in zip(cv["weights"], cv["mse"]))
        line += f", chosen by cross-validation (error of the face's motion per frame at each weight: {errors})"
    lines.append(line)
    return lines


def _run(args) -> int:
    if args.puppet:
        for path in args.puppet:
            print("\n".join(describe_puppet(path)))
        return 0
    for key, value in collect().items():
        print(f"{key:>16}: {value}")
    return 0


def add_parser(sub) -> None:
    """Register the ``info`` verb.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The sub-command parsers of the ``voicepuppet`` command line.
    """
    p = sub.add_parser("info", help="show versions, build type and compiler, or what a puppet file holds",
                       description="Show versions, build type, compiler and SIMD of the core; with puppet "
                                   "files, what each holds (training, state machines, audio, the guide "
                                   "and its weight).")
    p.add_argument("puppet", nargs="*", metavar="PUPPET.vpp", help="puppet files to describe")
    p.set_defaults(func=_run)
