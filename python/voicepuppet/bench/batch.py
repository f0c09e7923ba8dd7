"""Benchmark suite ``batch``: throughput of ``voicepuppet batch`` on a Dask LocalCluster with 1
and 2 workers beside the one-by-one loop in this process, and the engine's overhead per file.

Cases (``ours`` = the batch engine, ``peer`` = the same work file by file in this process, the
``animate_file`` / ``track_file`` reference the tests compare outputs against):

- ``animate, W workers``: a puppet trained on the synthetic performer animates ``F`` spoken
  audio files (espeak-ng sentences) to npz; ``realtime_factor`` = audio seconds per wall second,
  which is also audio hours per wall hour.
- ``track, W workers``: the spring-mesh tracker on ``F`` short planted-face videos (640x480).
- ``train Baum-Welch, W workers``: seconds per EM iteration with the E-step on the cluster
  (:class:`voicepuppet.hmm.distributed.DaskEStep`, data held on the workers) vs ``GaussianHMM.fit``
  in this process; ``agree`` is the largest absolute difference of the trained parameters.
- ``engine overhead``: a trivial task per file (read the input, return its bytes): the batch
  engine's cost per file (scheduling, checksums, manifest, atomic writes) against the same
  read-and-write-atomically loop without Dask; ``overhead_ms_per_file`` is the difference.

Cluster start-up and one untimed warm-up run per case (workers import the package, load the
puppet) are excluded from the timings; start-up is reported (``cluster_start_s``). Every batch
run writes into a fresh folder (a re-run into the same folder would only verify checksums).
``agree`` is 0 when every batch output equals the one-by-one output (npz members and other
files byte for byte), 1 otherwise.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from voicepuppet import batch, synth
from voicepuppet.bench.hmm import make_problem
from voicepuppet.bench.runner import case, timeit_interleaved
from voicepuppet.bench.tracker import ASTRONAUT_POINTS, planted_face_sequence
from voicepuppet.hmm.distributed import DaskEStep, connect
from voicepuppet.hmm.gaussian import GaussianHMM
from voicepuppet.puppet import Puppet, load

SENTENCES = [
    "Peter bought a map of the bay before the boats came back.",
    "The quick brown fox jumps over the lazy dog while we watch.",
    "She sells sea shells by the sea shore every summer morning.",
    "We will meet at noon under the old oak tree near the river.",
    "Bright lights flicker above the busy market in the evening.",
    "Please read the whole letter aloud before you sign your name.",
    "A gentle breeze carried the smell of bread through the street.",
    "Nobody knew why the violin played by itself after midnight.",
]


def _same(a: Path, b: Path) -> bool:
    if a.suffix == ".npz":
        with zipfile.ZipFile(a) as za, zipfile.ZipFile(b) as zb:
            return {n: za.read(n) for n in za.namelist()} == {n: zb.read(n) for n in zb.namelist()}
    return a.read_bytes() == b.read_bytes()


def _compare(out: Path, ref: Path) -> float:
    files = sorted(p.relative_to(ref) for p in ref.rglob("*") if p.is_file())
    ok = all((out / f).is_file() and _same(out / f, ref / f) for f in files)
    return 0.0 if ok and files else 1.0


def _cluster(n: int):
    t0 = time.perf_counter()
    ctx = connect(workers=n, timeout=120)
    client = ctx.__enter__()
    return ctx, client, time.perf_counter() - t0


def _make_puppet(work: Path, quick: bool):
    """A puppet trained on the synthetic performer (cached corpus), saved to work/puppet.vpp."""
    corpus = synth.make_corpus(work / "corpus", train_seconds=20 if quick else 60, n_test=0, seed=0,
                               real_test=False, progress=False)
    clip = corpus.train
    puppet = Puppet.train([clip.points], [clip.audio], fps=clip.fps, n_states=12 if quick else 40, seed=0)
    path = work / "puppet.vpp"
    puppet.save(path)
    return path


def _speech_files(folder: Path, n: int) -> float:
    """n spoken wav files (espeak-ng sentences); returns their total duration in seconds."""
    import soundfile as sf

    folder.mkdir(parents=True, exist_ok=True)
    total = 0.0
    for i in range(n):
        utt = synth.speak(" ".join(SENTENCES[(i + k) % len(SENTENCES)] for k in range(3)))
        sf.write(folder / f"line{i:03d}.wav", utt.samples, utt.rate)
        total += len(utt.samples) / utt.rate
    return total


def _videos(folder: Path, n: int, frames_each: int) -> float:
    import cv2

    frames, _, _ = planted_face_sequence(n * frames_each, seed=3, occlusion=None, blur=None)
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        w = cv2.VideoWriter(str(folder / f"v{i:03d}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (640, 480), False)
        for f in frames[i * frames_each:(i + 1) * frames_each]:
            w.write(f)
        w.release()
    return n * frames_each / 25.0


def _trivial_task(path: str, name: str) -> dict:
    data = Path(path).read_bytes()
    return {"files": {name: hashlib.sha256(data).hexdigest().encode()}, "media_seconds": 0.0}


def _engine_overhead(work: Path, client, n_files: int, repeats: int) -> dict:
    src = work / "trivial"
    src.mkdir(exist_ok=True)
    for i in range(n_files):
        (src / f"f{i:04d}.wav").write_bytes(np.random.default_rng(i).bytes(4096))
    jobs = [(p.name, p, (p.stem + ".txt",)) for p in sorted(src.iterdir())]

    def ours():
        out = Path(tempfile.mkdtemp(dir=work))
        s = batch.run_batch("trivial", jobs, _trivial_task, out, {"v": 1}, client, progress=False)
        shutil.rmtree(out)
        return s

    def peer():
        out = Path(tempfile.mkdtemp(dir=work))
        for rel, path, (name,) in jobs:
            value = _trivial_task(str(path), name)
            for n, data in value["files"].items():
                batch.write_file(out / n, data)
        shutil.rmtree(out)

    med, res = timeit_interleaved({"ours": ours, "peer": peer}, repeats)
    assert res["ours"].count("done") == n_files
    return case("engine overhead", f"{n_files} trivial files, {len(client.nthreads())} worker",
                med["ours"] / n_files, "same loop without Dask", med["peer"] / n_files, None,
                overhead_ms_per_file=1000 * (med["ours"] - med["peer"]) / n_files)


def _training_case(client, quick: bool, repeats: int) -> dict:
    """Baum-Welch with its E-steps on the cluster vs in this process (same data, same start)."""
    n, d, T, S, n_iter = (10, 20, 4000, 8, 3) if quick else (40, 40, 18000, 24, 5)
    _, X = make_problem(n, d, T, seed=4)
    lengths = np.full(S, T // S)
    lengths[-1] += T - lengths.sum()
    kw = dict(n_states=n, covariance="full", n_iter=n_iter, tol=-np.inf, random_state=0)
    with DaskEStep(client, X, lengths, "full", chunk_frames=int(np.ceil(T / 8))) as estep:
        GaussianHMM(**{**kw, "n_iter": 1}).fit(X, lengths, estep=estep)  # warm-up

        def ours():
            return GaussianHMM(**kw).fit(X, lengths, estep=estep)

        def peer():
            return GaussianHMM(**kw).fit(X, lengths)

        med, res = timeit_interleaved({"ours": ours, "peer": peer}, repeats)
    agree = max(float(np.max(np.abs(getattr(res["ours"], a) - getattr(res["peer"], a))))
                for a in ("startprob_", "transmat_", "means_", "covars_"))
    w = len(client.nthreads())
    return case(f"train Baum-Welch, {w} workers", f"N={n}, D={d}, T={T} in {S} sequences, {n_iter} it",
                med["ours"] / n_iter, "single process", med["peer"] / n_iter, agree,
                chunks=len(estep.bounds), unit="s per iteration", agree_is="max abs parameter difference")


def run(quick: bool = False, repeats: int = 3, animate: bool = True) -> list[dict]:
    """The batch suite's cases (see the module's docstring).

    Parameters
    ----------
    quick : bool
        Small sizes, for a smoke run.
    repeats : int
        Timed repeats per case (median).
    animate : bool
        False leaves out the animation cases (no puppet training).

    Returns
    -------
    list of dict
        Rows made by :func:`voicepuppet.bench.runner.case`.
    """
    rows = []
    work = Path(tempfile.mkdtemp(prefix="voicepuppet-bench-batch-"))
    try:
        # ---------------------------------------------------------------- tracking
        n_vid, frames_each = (4, 12) if quick else (8, 40)
        vid_dir = work / "videos"
        video_seconds = _videos(vid_dir, n_vid, frames_each)
        init = work / "points.json"
        init.write_text(json.dumps({"points": ASTRONAUT_POINTS.tolist()}))
        ref = work / "track-ref"

        def track_peer():
            shutil.rmtree(ref, ignore_errors=True)
            ref.mkdir()
            for p in sorted(vid_dir.iterdir()):
                batch.track_file(p, ref / (p.stem + ".npz"), init=str(init), passes=1)

        # ---------------------------------------------------------------- animation
        audio_dir = work / "audio"
        puppet_path = _make_puppet(work, quick) if animate else None
        audio_seconds = _speech_files(audio_dir, 3 if quick else 8) if animate else 0.0
        aref = work / "animate-ref"

        def animate_peer():
            shutil.rmtree(aref, ignore_errors=True)
            aref.mkdir()
            puppet = load(puppet_path)
            for p in sorted(audio_dir.iterdir()):
                batch.animate_file(puppet, p, aref / p.stem, ["npz"])

        for n_workers in (1, 2):
            ctx, client, start_s = _cluster(n_workers)
            try:
                def track_ours():
                    out = Path(tempfile.mkdtemp(dir=work))
                    batch.track_folder(vid_dir, out, init=str(init), passes=1, client=client, progress=False)
                    return out

                track_ours()  # warm-up: the workers import the package and OpenCV once
                med, res = timeit_interleaved({"ours": track_ours, "peer": track_peer}, repeats)
                rows.append(case(f"track, {n_workers} workers", f"{n_vid} videos x {frames_each} frames 640x480",
                                 med["ours"], "one by one in this process", med["peer"],
                                 _compare(res["ours"], ref), realtime_factor=video_seconds / med["ours"],
                                 peer_realtime_factor=video_seconds / med["peer"], cluster_start_s=start_s))
                if puppet_path is not None:
                    def animate_ours():
                        out = Path(tempfile.mkdtemp(dir=work))
                        batch.animate_folder(puppet_path, audio_dir, out, ["npz"], client=client, progress=False)
                        return out

                    animate_ours()  # warm-up: each worker loads the puppet once
                    med, res = timeit_interleaved({"ours": animate_ours, "peer": animate_peer}, repeats)
                    n_files = len(list(audio_dir.iterdir()))
                    rows.append(case(f"animate, {n_workers} workers",
                                     f"{n_files} files, {audio_seconds:.1f} s of speech", med["ours"],
                                     "one by one in this process", med["peer"], _compare(res["ours"], aref),
                                     realtime_factor=audio_seconds / med["ours"],
                                     audio_hours_per_wall_hour=audio_seconds / med["ours"],
                                     peer_realtime_factor=audio_seconds / med["peer"], cluster_start_s=start_s))
                rows.append(_training_case(client, quick, repeats))
                if n_workers == 1:
                    rows.append(_engine_overhead(work, client, 40 if quick else 200, repeats))
            finally:
                ctx.__exit__(None, None, None)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return rows
