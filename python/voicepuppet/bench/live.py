"""``voicepuppet bench live``: live puppetry, per-frame compute and end-to-end latency.

Cases (medians of interleaved repeats; per-frame percentiles over every frame of a run):

- ``features_stream``: the streaming front end (:class:`voicepuppet.audio.stream.StreamingFeatures`,
  the C++ ``StreamingAudioFeatures``, default "puppet" set, 5 ms chunks) against the numpy
  reference of the offline front end (``reference_extract``) on the same audio (``agree``:
  largest relative difference of the exact-mode features);
- ``puppet_stream_cpp``: ``voicepuppet::StreamingPuppet`` fed one feature frame per push, against
  the offline C++ ``Puppet.animate`` (``agree``: with lags covering the stream);
- ``puppet_stream_cpp_projected``: the same stream of a puppet trained on the same clip with
  ``vocal_features="projected", vocal_covariance="tied"`` (±5 frames, exact look-ahead), against
  the unprojected puppet's stream (``agree``: its exact stream against its offline animate;
  ``frame_ms_p50_10x``: per-frame compute on the clip's features repeated 10 times);
- ``live_lag{L}ms``: :class:`voicepuppet.live.puppet.LivePuppet` end to end (audio chunks of 5 ms in,
  face frames out) for several latency budgets. A frame's end-to-end latency is the audio
  time between the frame's moment and the end of the chunk that completed it, plus the compute
  time of that push: ``latency = lag + compute`` measured, not assumed.

``python -m voicepuppet.bench.live --table`` prints the accuracy table of docs/streaming.md
(streamed vs offline animation for each latency budget, Err of eq. 7 and landmark RMSE / IOD);
``--projection-table`` the price of a projected puppet's shorter projection look-ahead,
``--guide-table`` the price of a guided puppet's shorter guide look-ahead.
"""

from __future__ import annotations

import gc
import hashlib
import json
import math
import os
import statistics
import time

import numpy as np

from voicepuppet import _core
from voicepuppet.audio import extract, load_audio, prepare
from voicepuppet.audio.extract import reference_extract
from voicepuppet.audio.stream import StreamingFeatures
from voicepuppet.audio.conditioning import speech_level_db
from voicepuppet.bench.runner import case, print_table, rel_diff, timeit_interleaved
from voicepuppet.data import cache_dir
from voicepuppet.evaluation.metrics import err, landmark_rmse_iod
from voicepuppet.live.puppet import LivePuppet
from voicepuppet.puppet import TRAIN_DEFAULTS, Puppet, load
from voicepuppet.puppet.guide import GUIDE_WEIGHT, GUIDE_WEIGHTS
from voicepuppet.synth import make_corpus

LAGS_MS = (0, 50, 100, 150, 250, 330)
CHUNK = 80  # 5 ms at 16 kHz: the ``voicepuppet live`` default (live.CHUNK_MS)


def _corpus(quick: bool):
    """Training clip and held-out clips of the synthetic performer (cached), and a puppet."""
    secs = 20 if quick else 60
    c = make_corpus(os.path.join(cache_dir(), f"bench-live-{secs}s"), train_seconds=secs, n_test=3,
                    seed=0, progress=False)
    return c, _cached_puppet(c, quick)


def _projected(corpus, quick: bool):
    """The puppet of ``_corpus`` trained with the projection (cached beside it)."""
    return _cached_puppet(corpus, quick, vocal_features="projected", vocal_covariance="tied")


def _cached_puppet(corpus, quick: bool, **options):
    """The bench's puppet of ``corpus`` with training ``options``, cached in the corpus folder
    under the corpus's key (from its ``corpus.json``): a rebuilt corpus trains it again."""

    with open(os.path.join(corpus.out_dir, "corpus.json")) as fh:
        key = json.load(fh)["key"]
    opts = dict(n_states=12 if quick else 26, n_iter=10 if quick else 20, **options)
    # new training defaults (the guide's weight and its choices among them) train it again
    tag = hashlib.sha256(json.dumps([key, {**TRAIN_DEFAULTS, **opts}, GUIDE_WEIGHT, GUIDE_WEIGHTS],
                                    sort_keys=True, default=str).encode()).hexdigest()[:12]
    path = os.path.join(corpus.out_dir, f"puppet-{tag}.vpp")
    if os.path.exists(path):
        return load(path)
    p = Puppet.train([corpus.train.points], [corpus.train.audio], fps=corpus.train.fps, **opts)
    p.save(path)
    return p


def _stream_live(live, x):
    """Push x in 5 ms chunks; returns points [T, P, 2], per-frame compute (s), latency (s)."""
    pts, comp, lat = [], [], []
    rate = live.rate
    for a in range(0, x.shape[0], CHUNK):
        c0 = time.perf_counter()
        f = live.push(x[a:a + CHUNK])
        dt = time.perf_counter() - c0
        if len(f):
            heard = min(a + CHUNK, x.shape[0]) / rate  # audio time when this push ran
            pts.append(f.points)
            comp += [dt / len(f)] * len(f)
            lat += list(heard - f.times + dt)
    c0 = time.perf_counter()
    f = live.flush()
    dt = time.perf_counter() - c0
    pts.append(f.points)
    comp += [dt / max(len(f), 1)] * len(f)
    return np.concatenate(pts), np.array(comp), np.array(lat)


def run(quick: bool = False, repeats: int = 3) -> list:
    """The live suite's cases (see the module's docstring).

    Parameters
    ----------
    quick : bool
        Small sizes, for a smoke run.
    repeats : int
        Timed repeats per case (median).

    Returns
    -------
    list of dict
        Rows made by :func:`voicepuppet.bench.runner.case`.
    """
    corpus, puppet = _corpus(quick)
    clip = corpus.test[0]
    x = load_audio(clip.audio).samples
    audio = prepare(x, 16000, target_rate=None, remove_dc=False)
    secs = x.shape[0] / 16000
    cases = []

    # 1. streaming features vs offline extract
    per_frame = []

    level = speech_level_db(audio.samples, 16000)  # a file's level, known before it plays (as `live --input`)

    def stream_features():
        s = StreamingFeatures(puppet.feature_set, fps=puppet.fps, input_level_db=level)
        rows = []
        for a in range(0, x.shape[0], CHUNK):
            c0 = time.perf_counter()
            r = s.push(x[a:a + CHUNK])
            dt = time.perf_counter() - c0
            if r.shape[0]:
                per_frame.extend([dt / r.shape[0]] * r.shape[0])
            rows.append(r)
        rows.append(s.flush())
        return np.vstack(rows)

    med, res = timeit_interleaved({"ours": stream_features,
                                   "peer": lambda: reference_extract(
                                       audio, fps=puppet.fps, features=puppet.feature_set).values},
                                  repeats)
    pf = np.array(per_frame) * 1e3
    cases.append(case("features_stream", f"{secs:.1f} s, 5 ms chunks", med["ours"],
                      "numpy reference (offline)", med["peer"], rel_diff(res["ours"], res["peer"]),
                      frame_ms_p50=float(np.percentile(pf, 50)),
                      frame_ms_p99=float(np.percentile(pf, 99)),
                      realtime_factor=secs / med["ours"]))

    # 2. the C++ streaming puppet, one feature frame per push
    feats = extract(audio, fps=puppet.fps, features=puppet.feature_set).values
    T = feats.shape[0]
    cpp_frames = []

    def stream_frames(core, dl, tl, x, times, guide_weight=-1.0):
        """Push x one feature frame at a time; returns the points, appends each push's time."""
        sp = _core.StreamingPuppet(core, dl, tl, 0.0, False, guide_weight=guide_weight)
        out = []
        for t in range(x.shape[0]):
            c0 = time.perf_counter()
            r = sp.push(x[t:t + 1])
            times.append(time.perf_counter() - c0)
            out.append(np.asarray(r.points))
        out.append(np.asarray(sp.flush().points))
        return np.vstack(out)

    def cpp_stream(dl=2, tl=1):
        return stream_frames(puppet._core, dl, tl, feats, cpp_frames)

    med, res = timeit_interleaved({"ours": cpp_stream,
                                   "peer": lambda: np.asarray(puppet._core.animate(
                                       np.ascontiguousarray(feats), 0.0, False)["points"])},
                                  repeats)
    exact = cpp_stream(T + 1, T + 1)
    cf = np.array(cpp_frames) * 1e3
    cases.append(case("puppet_stream_cpp", f"T={T}, N={puppet.n_states(0)}, lags 2+1",
                      med["ours"], "offline C++ animate", med["peer"],
                      rel_diff(exact, res["peer"]),
                      frame_ms_p50=float(np.percentile(cf, 50)),
                      frame_ms_p99=float(np.percentile(cf, 99))))

    # 2a. the guide's cost: the guided stream (ŷ from +-5 frames, its evidence in the trajectory)
    #     against the same puppet streamed unguided (guide_weight 0), same lags
    guided_frames = []
    med, _ = timeit_interleaved({"ours": lambda: stream_frames(puppet._core, 2, 1, feats,
                                                               guided_frames),
                                 "peer": lambda: stream_frames(puppet._core, 2, 1, feats, [],
                                                               guide_weight=0.0)},
                                repeats)
    gf = np.array(guided_frames) * 1e3
    cases.append(case("puppet_stream_cpp_guided_vs_unguided",
                      f"T={T}, N={puppet.n_states(0)}, k_g=5, lags 2+1",
                      med["ours"], "the same StreamingPuppet with guide_weight 0", med["peer"],
                      rel_diff(stream_frames(puppet._core, T + 1, T + 1, feats, [], guide_weight=0.0),
                               np.asarray(puppet._core.animate(np.ascontiguousarray(feats), 0.0, False,
                                                               guide_weight=0.0)["points"])),
                      frame_ms_p50=float(np.percentile(gf, 50)),
                      frame_ms_p99=float(np.percentile(gf, 99))))

    # 2b. a projected puppet's stream (the projection's +-5 frames computed per frame) against
    #     the unprojected one's, both one feature frame per push
    proj = _projected(corpus, quick)
    proj_frames = []

    def cpp_stream_projected(dl=2, tl=1, x=feats, record=True):
        return stream_frames(proj._core, dl, tl, x, proj_frames if record else [])

    med, _ = timeit_interleaved({"ours": cpp_stream_projected, "peer": cpp_stream}, repeats)
    exact = cpp_stream_projected(T + 1, T + 1, record=False)
    offline = np.asarray(proj._core.animate(np.ascontiguousarray(feats), 0.0, False)["points"])
    pf = np.array(proj_frames) * 1e3
    n_short = len(proj_frames)
    cpp_stream_projected(x=np.ascontiguousarray(np.tile(feats, (10, 1))))
    long = np.array(proj_frames[n_short:]) * 1e3
    cases.append(case("puppet_stream_cpp_projected",
                      f"T={T}, N={proj.n_states(0)}, k=5, lags 5+2+1",
                      med["ours"], "unprojected StreamingPuppet", med["peer"],
                      rel_diff(exact, offline),
                      frame_ms_p50=float(np.percentile(pf, 50)),
                      frame_ms_p99=float(np.percentile(pf, 99)),
                      frame_ms_p50_10x=float(np.percentile(long, 50)),
                      algorithmic_latency_ms=_core.StreamingPuppet(
                          proj._core, 2, 1, 0.0, False).latency_seconds * 1e3))

    # 3. end to end, per latency budget, with the collector's scans frozen as the live verb does
    gc.freeze()
    for lag in ((50, 150) if quick else (0, 50, 150, 330)):
        comps, lats, times = [], [], []
        for _ in range(max(1, repeats)):
            live = LivePuppet(puppet, lag_ms=lag, input_level_db=level)
            c0 = time.perf_counter()
            _, comp, lat = _stream_live(live, x)
            times.append(time.perf_counter() - c0)
            comps.append(comp)
            lats.append(lat)
        comp = np.concatenate(comps) * 1e3
        lat = np.concatenate(lats) * 1e3
        cases.append(case(f"live_lag{lag}ms", f"{secs:.1f} s, 5 ms chunks",
                          statistics.median(times), None, None, None,
                          lag_ms=lag, algorithmic_latency_ms=live.latency_s * 1e3,
                          frame_ms_p50=float(np.percentile(comp, 50)),
                          frame_ms_p99=float(np.percentile(comp, 99)),
                          latency_ms_p50=float(np.percentile(lat, 50)),
                          latency_ms_p99=float(np.percentile(lat, 99)),
                          realtime_factor=secs / statistics.median(times)))
    return cases


def error_table(quick: bool = False) -> str:
    """Markdown table: streamed vs offline animation per latency budget, both synthesis modes,
    over the held-out clips of the synthetic performer (3 espeak-ng utterances and CMU ARCTIC
    a0009). Err is eq. 7 on landmarks (mean-subtracted motion), RMSE is landmark RMSE over the
    inter-ocular distance; 'vs truth' columns compare with the performer's real landmarks.

    Parameters
    ----------
    quick : bool
        The quick suite's smaller corpus and puppet.

    Returns
    -------
    str
    """
    corpus, puppet = _corpus(quick)
    rows = ["| lag budget (ms) | latency (ms) | look-aheads (formant, deltas, guide, decoder, trajectory) | mode "
            "| Err vs offline | RMSE/IOD vs offline | Err vs truth | RMSE/IOD vs truth |",
            "|---|---|---|---|---|---|---|---|"]
    clips = corpus.test
    sounds = {c.audio: load_audio(c.audio).samples for c in clips}
    levels = {a: speech_level_db(x, 16000) for a, x in sounds.items()}  # as `live --input` knows them
    for posterior in (False, True):
        offline = {}
        for c in clips:
            offline[c.audio] = puppet.animate(load_audio(c.audio), posterior=posterior
                                              ).animation.points
        base = []
        for c in clips:
            o = offline[c.audio]
            n = min(len(o), len(c.points))
            base.append((err(o[:n], c.points[:n]), landmark_rmse_iod(o[:n], c.points[:n])))
        for lag in LAGS_MS:
            e_off, r_off, e_tr, r_tr = [], [], [], []
            for c in clips:
                live = LivePuppet(puppet, lag_ms=lag, posterior=posterior, input_level_db=levels[c.audio])
                pts, _, _ = _stream_live(live, sounds[c.audio])
                o = offline[c.audio]
                e_off.append(err(pts, o))
                r_off.append(landmark_rmse_iod(pts, o))
                n = min(len(pts), len(c.points))
                e_tr.append(err(pts[:n], c.points[:n]))
                r_tr.append(landmark_rmse_iod(pts[:n], c.points[:n]))
            la = (live.formant_lag, live.delta_lag, live.guide_lag, live.decode_lag,
                  live.trajectory_lag)
            rows.append(f"| {lag} | {live.latency_s * 1e3:.0f} | {la} | "
                        f"{'posterior' if posterior else 'Viterbi'} | {np.mean(e_off):.4f} | "
                        f"{np.mean(r_off):.4f} | {np.mean(e_tr):.3f} | {np.mean(r_tr):.4f} |")
        rows.append(f"| offline | - | - | {'posterior' if posterior else 'Viterbi'} | 0 | 0 | "
                    f"{np.mean([b[0] for b in base]):.3f} | {np.mean([b[1] for b in base]):.4f} |")
    return "\n".join(rows)


def _lag_price_table(puppet, clips, settings, sweep=(None, (None,)), guide_weight=None) -> str:
    """Markdown table: the ``clips`` streamed under each ``(label, LivePuppet keywords)`` of
    ``settings``, for each value of the LivePuppet keyword ``sweep = (option, values)`` if given
    (and with ``guide_weight``, the offline animation too); Err / RMSE against the offline
    animation and the truth as in :func:`error_table`, Viterbi, means over the clips."""
    option, values = sweep

    offline = {c.audio: puppet.animate(load_audio(c.audio), guide_weight=guide_weight
                                       ).animation.points for c in clips}
    sounds = {c.audio: load_audio(c.audio).samples for c in clips}
    levels = {a: speech_level_db(x, 16000) for a, x in sounds.items()}  # as `live --input` knows them
    rows = ["| other look-aheads | look-aheads (formant, deltas, projection, guide, decoder, "
            "trajectory) | latency (ms) | Err vs offline | RMSE/IOD vs offline | Err vs truth | "
            "RMSE/IOD vs truth |",
            "|---|---|---|---|---|---|---|"]
    for label, kw in settings:
        for v in values:
            r = []
            for c in clips:
                swept = {} if option is None else {option: v}
                live = LivePuppet(puppet, **swept, **kw, guide_weight=guide_weight,
                                  input_level_db=levels[c.audio])
                pts, _, _ = _stream_live(live, sounds[c.audio])
                o = offline[c.audio]
                n = min(len(pts), len(c.points))
                r.append((err(pts, o), landmark_rmse_iod(pts, o), err(pts[:n], c.points[:n]),
                          landmark_rmse_iod(pts[:n], c.points[:n])))
            m = np.mean(r, axis=0)
            la = (live.formant_lag, live.delta_lag, live.projection_lag, live.guide_lag,
                  live.decode_lag, live.trajectory_lag)
            lat = f"{live.latency_s * 1e3:.0f}" if math.isfinite(live.latency_s) else "unbounded"
            rows.append(f"| {label} | {la} | {lat} | {m[0]:.4f} | {m[1]:.4f} | {m[2]:.3f} | "
                        f"{m[3]:.4f} |")
    base = []
    for c in clips:
        o = offline[c.audio]
        n = min(len(o), len(c.points))
        base.append((err(o[:n], c.points[:n]), landmark_rmse_iod(o[:n], c.points[:n])))
    rows.append(f"| offline | - | - | 0 | 0 | {np.mean([b[0] for b in base]):.3f} | "
                f"{np.mean([b[1] for b in base]):.4f} |")
    return "\n".join(rows)


#: Other look-aheads of the price tables: two budgets' splits, and exact formants with decoder
#: and trajectory lags covering the clips (the one look-ahead's price alone).
_PRICE_SETTINGS = (("150 ms budget", dict(lag_ms=150)), ("330 ms budget", dict(lag_ms=330)),
                   ("covering", dict(formant_lag=-1, delta_lag=-1, decode_lag=2000,
                                     trajectory_lag=2000)))


def projection_table(quick: bool = False) -> str:
    """Markdown table: the price of ``projection_lag`` < k for the projected puppet of
    ``_projected``, streamed without its guide (``guide_weight=0``, the table of
    docs/streaming.md was measured before guided puppets streamed): each projection look-ahead
    with the other look-aheads of the 150 ms and 330 ms budgets, and covering.

    Parameters
    ----------
    quick : bool
        The quick suite's smaller corpus and puppet.

    Returns
    -------
    str
    """
    corpus, _ = _corpus(quick)
    proj = _projected(corpus, quick)
    return _lag_price_table(proj, corpus.test, _PRICE_SETTINGS,
                            ("projection_lag", range(int(proj._core.projection_context) + 1)),
                            guide_weight=0)


def guide_table(quick: bool = False) -> str:
    """Markdown table: the price of ``guide_lag`` < k_g for the bench's (guided) puppet: each
    guide look-ahead with the other look-aheads of the 150 ms and 330 ms budgets (where the
    split gives the guide the decoder's look-ahead for free; more costs latency), and
    covering; then, at each budget's latency, splits that give the guide and the decoder more
    by taking from the trajectory and the deltas.

    Parameters
    ----------
    quick : bool
        The quick suite's smaller corpus and puppet.

    Returns
    -------
    str
    """
    corpus, puppet = _corpus(quick)
    kg = int(puppet._core.guide_context)
    table = _lag_price_table(puppet, corpus.test, _PRICE_SETTINGS, ("guide_lag", range(kg + 1)))
    # same latency, other splits: (deltas, decoder = guide, trajectory)
    resplit = []
    for label, lag, splits in (("150 ms, re-split", 150, ((0, 2, 1), (1, 2, 0), (0, 3, 0))),
                               ("330 ms, re-split", 330, ((1, 4, 2), (2, 4, 1), (1, 5, 1),
                                                          (0, 5, 2)))):
        for dl, d, t in splits:
            resplit.append((label, dict(lag_ms=lag, delta_lag=dl, decode_lag=d, trajectory_lag=t,
                                        guide_lag=min(kg, d))))
    extra = _lag_price_table(puppet, corpus.test, resplit)
    return table + "\n" + "\n".join(extra.splitlines()[2:-1])


if __name__ == "__main__":  # pragma: no cover
    import argparse

    ap = argparse.ArgumentParser(description="accuracy table of docs/streaming.md")
    ap.add_argument("--table", action="store_true")
    ap.add_argument("--projection-table", action="store_true",
                    help="the price of projection_lag < k for a projected puppet")
    ap.add_argument("--guide-table", action="store_true",
                    help="the price of guide_lag < k_g for the (guided) puppet, and other splits")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    if a.projection_table:
        print(projection_table(a.quick))
    elif a.guide_table:
        print(guide_table(a.quick))
    elif a.table:
        print(error_table(a.quick))
    else:
        print_table(run(a.quick, 3))
