"""Report tables: the results of :mod:`voicepuppet.evaluation` as Markdown, and their files."""

from __future__ import annotations

import json

from voicepuppet._files import atomic_path
from voicepuppet.evaluation.crossval import COMPARE_KEPT, COMPARE_MEASURES, METRICS

__all__ = ["markdown_table", "format_interval", "format_difference", "format_split", "format_table",
           "format_comparison", "write_results"]


def markdown_table(header, rows, *, numeric_from: int = 1) -> list[str]:
    """A Markdown table's lines: ``header`` (column titles), then one line per row of cells.

    Parameters
    ----------
    header : sequence of str
        Column titles.
    rows : iterable of sequence of str
        Cells already formatted, as many as ``header``.
    numeric_from : int
        Columns from this one on are right-aligned (numbers).

    Returns
    -------
    list of str
        The header line, the alignment line, then one line per row.
    """
    header = list(header)
    lines = ["| " + " | ".join(header) + " |",
             "|" + "---|" * numeric_from + "---:|" * (len(header) - numeric_from)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def format_interval(v: dict, digits: int = 4) -> str:
    """A measure over folds: ``mean ± half-width`` of its 95% interval.

    Parameters
    ----------
    v : dict
        The measure's ``mean``, ``low`` and ``high`` (as :func:`voicepuppet.evaluation.folds.fold_summary`
        gives them).
    digits : int
        Significant digits of the mean (default 4; the half-width has 2).

    Returns
    -------
    str
        The table cell.
    """
    return f"{v['mean']:.{digits}g} ± {0.5 * (v['high'] - v['low']):.2g}"


def format_difference(d: dict) -> str:
    """A paired difference's cell: ``mean [low, high]`` of its 95% interval, signed.

    Parameters
    ----------
    d : dict
        The difference's ``mean``, ``low`` and ``high``.

    Returns
    -------
    str
        The table cell (3 significant digits each).
    """
    return f"{d['mean']:+.3g} [{d['low']:+.3g}, {d['high']:+.3g}]"


def format_split(result: dict, title: str = "") -> str:
    """A Markdown table of :func:`voicepuppet.evaluation.split.evaluate_split`'s rows and its model line.

    Parameters
    ----------
    result : dict
        What :func:`~voicepuppet.evaluation.split.evaluate_split` returns.
    title : str
        A bold title above the table (default: none).

    Returns
    -------
    str
        The table (one row per method, train and test columns per measure), then a line of the
        model's states, arcs, perplexity, context memory, decoding entropy rate, state coding
        and guide weight.
    """
    keys = ["err", "rmse_iod", "lve", "rms"]
    if any("closed" in r.get(split, {}) for r in result["rows"].values() for split in ("train", "test")):
        keys.append("closed")
    lines = []
    if title:
        lines += [f"**{title}**", ""]
    cells = ((name, *("" if row.get(split, {}).get(k) is None else f"{row[split][k]:.4g}"
                      for k in keys for split in ("train", "test"))) for name, row in result["rows"].items())
    lines += markdown_table(["method"] + [f"{k} {split}" for k in keys for split in ("train", "test")], cells)
    m = result["model"]
    guide = ""
    if m.get("guide_weight") is not None:
        guide = f", guide weight {m['guide_weight']:g}" + (" (chosen by cross-validation)"
                                                          if m.get("guide_weight_cv") else "")
    states, arcs = (" / ".join(str(n) for n in m[k]) for k in ("states", "arcs"))  # one per face part
    lines += ["", f"states {states}, arcs {arcs}, perplexity {m['perplexity']:.3g}, context "
              f"memory {m['context_memory']:.3g} frames, test decoding entropy rate "
              f"{m['entropy_rate_test']:.4g} nats/frame, state coding {m['bits_per_frame']:.3g} bits/frame"
              + guide]
    return "\n".join(lines)


def format_table(result: dict) -> str:
    """Markdown table: one row per model, ``mean ± half-width`` of the 95% interval per measure;
    then, where the result has them, the paired per-fold differences (``voice-puppet − ridge``,
    ``voice-puppet − mean-face``), ``mean [low, high]`` of the 95% interval.

    Parameters
    ----------
    result : dict
        What :func:`voicepuppet.evaluation.crossval.cross_validate` returns.

    Returns
    -------
    str
        The tables and a paragraph on how they were made, ending in a newline.
    """
    cols = [m for m in METRICS if any(m in e for e in result["models"].values())]
    rhubarb = result.get("rhubarb")

    def label(name):  # Rhubarb's row says which recogniser it is
        return f"rhubarb ({rhubarb['recognizer']})" if name == "rhubarb" and rhubarb else name

    lines = markdown_table(["model"] + [METRICS[m][0] for m in cols],
                           ((label(name), *(format_interval(e[m]) if m in e else "—" for m in cols))
                            for name, e in result["models"].items()))
    c = result["config"]
    diffs = result.get("differences") or {}
    dcols = [m for m in METRICS if any(m in d for by in diffs.values() for d in by.values())]
    if dcols:
        lines += [""] + markdown_table(
            ["paired difference (fold by fold)"] + [METRICS[m][0] for m in dcols],
            ((f"{a} − {label(b)}", *(format_difference(d[m]) if m in d else "—" for m in dcols))
             for a, by in diffs.items() for b, d in by.items()))
    if c.get("fold_labels"):
        lines += _per_fold(result["models"], c["fold_labels"], [m for m in ("err", "lve") if m in cols])
    if rhubarb:
        lines += [""] + _cue_tables(rhubarb)
    lines.append("")
    lines.append(f"{_how_folded(c)} ({c['sequences']} sequences, {c['frames']} "
                 f"frames at {c['fps']:.4g} fps, seed {c['seed']}); mean over folds ± half-width of the "
                 f"95% confidence interval (Student's t). Face coordinates: FaceSpace per fold "
                 f"(n_components={c['n_components']}). Log-likelihoods are per frame of the test data under "
                 f"each model (brand-phoneme's is of [y, Δy], 2K dims, not comparable; the puppet's "
                 f"face model is not conditioned on phones: —)."
                 + (" ridge: per-frame ridge regression over ±5 frames of the audio features as the fold's "
                    "voice puppet standardises them (regularisation by blocked cross-validation on the "
                    "training frames); mean-face: the fold's training mean face, every frame (Err 1 by "
                    "construction)." if "ridge" in result["models"] else "")
                 + (f" Paired differences: mean [95% interval] of the per-fold differences (Student's t, "
                    f"{c['k'] - 1} degrees of freedom); below 0: the voice puppet's error is lower." if dcols
                    else "")
                 + (" B/P/M closed: the share of the stretches of B, P, M whose lips the model closes (a gap of "
                    "at most 1 % of the inter-ocular distance in one of their frames; higher is better, the "
                    "truth 1), over the folds whose test sequences have one." if "closed" in cols else "")
                 + (f" rhubarb: Rhubarb Lip Sync's cues of each test sequence's audio, each shape mapped to the "
                    f"mean face coordinates of the fold's training frames under it (its best mapping); of its two "
                    f"recognisers the one of the lower mean Err ({rhubarb['recognizer']}; Err of both: "
                    + ", ".join(f"{r} {v['err']['mean']:.4g}" for r, v in rhubarb["recognizers"].items())
                    + "). Cue agreement: the share of test frames (pooled over folds) whose shape is the one "
                    "derived from the truth, by voicepuppet's cue rule on the true landmarks (geometry) or as "
                    "the nearest of the recogniser's shape means (centroid); export: voicepuppet's cue export "
                    "of the puppet's animation (both with the fold's training mean face as the rest face)."
                    if rhubarb else "")
                 + (" learned: a 1-D convolutional network (±6 frames, 32 channels) from the same standardised "
                    "features to the face coordinates, early-stopped on a fifth of the fold's training sequences."
                    if "learned" in result["models"] else "")
                 + (" Models and face spaces learnt from the sequences' separate training landmarks "
                    "(e.g. tracked); measured against the ground truth." if c.get("separate_training_landmarks")
                    else ""))
    return "\n".join(lines) + "\n"


def _cue_tables(rhubarb: dict) -> list[str]:
    """Cue agreement per recogniser and truth, then per shape (geometry) the table row's recall."""
    cues = rhubarb["cues"]
    lines = markdown_table(["cue agreement with the truth-derived cues", "geometry", "centroid"],
                           [(f"{who} ({rec})" if who == "rhubarb" else f"voicepuppet export (shapes of {rec})",
                             *(f"{cues[rec][how][who]['agreement']:.3f}" for how in ("geometry", "centroid")))
                            for rec in cues for who in ("rhubarb", "export")
                            if who == "rhubarb" or rec == rhubarb["recognizer"]])
    best = cues[rhubarb["recognizer"]]["geometry"]
    shapes = [s for s in best["rhubarb"]["confusion"]]
    frames = {s: sum(best["rhubarb"]["confusion"][s].values()) for s in shapes}
    lines += [""] + markdown_table(
        ["shape (geometry truth)", "frames", f"rhubarb ({rhubarb['recognizer']}) recall", "export recall"],
        [(s, str(frames[s]), f"{best['rhubarb']['recall'][s]:.3f}", f"{best['export']['recall'].get(s, 0.0):.3f}")
         for s in shapes])
    return lines


def _how_folded(config: dict) -> str:
    """How a cross-validation's folds were made, for the line under its tables."""
    if config.get("fold_labels"):
        return f"{config['k']} folds that leave a voice out ({'; '.join(config['fold_labels'])})"
    return f"{config['k']}-fold cross-validation by sequence"


def _per_fold(entries: dict, labels: list, measures: list) -> list[str]:
    """Tables of ``measures`` fold by fold (rows: the entries, columns: the folds' ``labels``)."""
    lines = []
    for m in measures:
        title = METRICS[m][0] if m in METRICS else m
        lines += [""] + markdown_table([f"{title}, fold by fold"] + list(labels),
                                       ((name, *(f"{v:.4g}" for v in e[m]["folds"]))
                                        for name, e in entries.items() if m in e and len(e[m]["folds"]) == len(labels)))
    return lines


def write_results(result: dict, md_path=None, json_path=None, command: str = "", text: str | None = None) -> None:
    """Write the table (Markdown) and the full result (JSON), each atomically.

    Parameters
    ----------
    result : dict
        What :func:`voicepuppet.evaluation.crossval.cross_validate` (or ``compare_training``) returns.
    md_path, json_path : path, optional
        Where to write the table and the result; None: not written.
    command : str
        The command line that reproduces the result, written above the table and into the JSON.
    text : str, optional
        The table (default :func:`format_table` of ``result``).
    """
    if md_path:
        with atomic_path(md_path, (".md",), "results table") as tmp:
            text = format_table(result) if text is None else text
            if command:
                text = f"```\n{command}\n```\n\n" + text
            tmp.write_text(text, encoding="utf-8")
    if json_path:
        with atomic_path(json_path, (".json",), "results JSON") as tmp:
            payload = dict(result, command=command)
            tmp.write_text(json.dumps(payload, indent=1) + "\n", encoding="utf-8")


def format_comparison(result: dict) -> str:
    """Markdown: each variant's measures (mean ± half-width of the 95% interval over folds), then
    each paired difference against the baseline with its interval.

    Parameters
    ----------
    result : dict
        What :func:`voicepuppet.evaluation.crossval.compare_training` returns.

    Returns
    -------
    str
        The two tables and a line on how they were made, ending in a newline.
    """
    measures = [m for m in COMPARE_MEASURES + COMPARE_KEPT if m in next(iter(result["variants"].values()))]
    lines = markdown_table(["variant"] + measures, ((name, *(format_interval(row[m]) for m in measures))
                                                    for name, row in result["variants"].items()))
    base = result["config"]["baseline"]
    lines += [""] + markdown_table(["paired difference (fold by fold)"] + measures,
                                   ((f"{name} − {base}", *(format_difference(row[m]) for m in measures))
                                    for name, row in result["differences"].items()))
    c = result["config"]
    if c.get("fold_labels"):
        lines += _per_fold(result["variants"], c["fold_labels"], [m for m in ("err", "lve") if m in measures])
    lines += ["", f"{_how_folded(c)} ({c['sequences']} sequences, {c['frames']} frames "
              f"at {c['fps']:.4g} fps, seed {c['seed']}); variants: mean over folds ± half-width of the 95% "
              f"interval; differences: mean [95% interval] of the per-fold differences (Student's t, "
              f"{c['k'] - 1} degrees of freedom). Lower is better for every measure; "
              f"{', '.join(m for m in COMPARE_KEPT if m in measures)}: what the puppets are."
              + (" Puppets and face spaces learnt from the sequences' separate training landmarks (e.g. "
                 "tracked); measured against the ground truth." if c.get("separate_training_landmarks") else "")]
    return "\n".join(lines) + "\n"
