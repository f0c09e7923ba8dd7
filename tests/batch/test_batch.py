"""voicepuppet.batch: folders tracked and animated on a Dask LocalCluster, outputs equal to the
one-by-one outputs, resumable through the checksum manifest, per-file failures (unreadable,
undecodable, full disk) reported without stopping the rest, clear errors for bad arguments."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest

from voicepuppet import batch
from voicepuppet.batch import engine, jobs
from voicepuppet.hmm.distributed import connect

cv2 = pytest.importorskip("cv2", reason="pip install opencv-contrib-python-headless")
pytest.importorskip("skimage", reason="pip install scikit-image")

from voicepuppet.bench.tracker import ASTRONAUT_POINTS, planted_face_sequence  # noqa: E402

N_FRAMES = 8


@pytest.fixture(scope="module")
def client():
    with connect(workers=2, timeout=60) as c:
        yield c


@pytest.fixture(scope="module")
def videos(tmp_path_factory, write_avi):
    """Three short videos (one in a sub-folder), a file that is not a video, a dangling link,
    and the first-frame points."""
    root = tmp_path_factory.mktemp("videos")
    frames, _, _ = planted_face_sequence(3 * N_FRAMES, seed=1, occlusion=None, blur=None)
    write_avi(root / "a.avi", frames[:N_FRAMES])
    write_avi(root / "b.avi", frames[N_FRAMES:2 * N_FRAMES])
    write_avi(root / "sub" / "c.avi", frames[2 * N_FRAMES:])
    (root / "broken.mp4").write_bytes(b"this is not a video\n" * 10)
    os.symlink(root / "missing.avi", root / "gone.avi")
    init = tmp_path_factory.mktemp("init") / "points.json"
    init.write_text(json.dumps({"points": ASTRONAUT_POINTS.tolist()}))
    return root, init


GOOD = ["a.avi", "b.avi", "sub/c.avi"]


def assert_same_file(a: Path, b: Path) -> None:
    """Byte-identical (landmark and animation .npz files are written with fixed zip timestamps)."""
    assert a.read_bytes() == b.read_bytes(), a


@pytest.fixture(scope="module")
def one_by_one(videos, tmp_path_factory):
    """The reference: each video tracked on its own with the one-file code path."""
    root, init = videos
    ref = tmp_path_factory.mktemp("ref")
    for rel in GOOD:
        out = ref / Path(rel).with_suffix(".npz")
        out.parent.mkdir(parents=True, exist_ok=True)
        batch.track_file(root / rel, out, init=str(init), passes=1)
    return ref


def outputs(out: Path) -> list[str]:
    return sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())


def test_track_folder_equals_one_by_one_and_reports_failures(client, videos, one_by_one, tmp_path):
    root, init = videos
    out = tmp_path / "out"
    s = batch.track_folder(root, out, init=str(init), passes=1, client=client, progress=False)
    status = {f.input: f.status for f in s.files}
    assert status == {"a.avi": "done", "b.avi": "done", "broken.mp4": "failed", "gone.avi": "failed",
                      "sub/c.avi": "done"}
    errors = {f.input: f.error for f in s.failed}
    assert "cannot read the input" in errors["gone.avi"]
    assert "broken.mp4" in errors["broken.mp4"] or "decod" in errors["broken.mp4"] or "open" in errors["broken.mp4"]
    assert outputs(out) == sorted([batch.MANIFEST_NAME, batch.SUMMARY_NAME, batch.LOCK_NAME, "a.csv", "a.npz",
                                   "b.csv", "b.npz", "sub/c.csv", "sub/c.npz"])  # nothing half-written
    for rel in ["a.npz", "a.csv", "b.npz", "b.csv", "sub/c.npz", "sub/c.csv"]:
        assert_same_file(out / rel, one_by_one / rel)
    summary = json.loads((out / batch.SUMMARY_NAME).read_text())
    assert (summary["done"], summary["skipped"], summary["failed"]) == (3, 0, 2)
    assert summary["media_seconds_done"] == pytest.approx(3 * N_FRAMES / 25.0)
    assert {f["input"] for f in summary["files"] if f["status"] == "failed"} == {"broken.mp4", "gone.avi"}


def test_rerun_skips_verified_outputs_and_redoes_damaged_ones(client, videos, one_by_one, tmp_path):
    root, init = videos
    out = tmp_path / "out"
    batch.track_folder(root, out, init=str(init), passes=1, client=client, progress=False)
    again = batch.track_folder(root, out, init=str(init), passes=1, client=client, progress=False)
    assert (again.count("done"), again.count("skipped"), again.count("failed")) == (0, 3, 2)
    # damage one output, delete another: exactly those inputs are redone, correctly
    with open(out / "a.csv", "ab") as fh:
        fh.write(b"0")
    (out / "sub" / "c.npz").unlink()
    third = batch.track_folder(root, out, init=str(init), passes=1, client=client, progress=False)
    assert {f.input for f in third.files if f.status == "done"} == {"a.avi", "sub/c.avi"}
    assert third.count("skipped") == 1
    for rel in ["a.npz", "a.csv", "sub/c.npz", "sub/c.csv"]:
        assert_same_file(out / rel, one_by_one / rel)
    # other settings: everything is redone
    fourth = batch.track_folder(root, out, init=str(init), passes=2, client=client, progress=False)
    assert fourth.count("done") == 3


def test_a_points_file_warning_is_said_once_not_per_file(client, videos, tmp_path):
    import shutil

    root, _ = videos
    folder = tmp_path / "two"
    folder.mkdir()
    for n in ("a.avi", "b.avi"):
        shutil.copy(root / n, folder / n)
    from voicepuppet.animation import neutral_landmarks

    pts = np.round(neutral_landmarks() + [130.0, 0.0])  # 68 points on the face's box, whole pixels
    pts[[67, 66, 65]] = pts[[61, 62, 63]]  # a closed mouth: the inner lips share positions
    init = tmp_path / "closed.json"
    init.write_text(json.dumps({"points": pts.tolist(), "names": [f"p{i}" for i in range(len(pts))]}))
    with pytest.warns(UserWarning, match="share positions") as seen:
        s = batch.track_folder(folder, tmp_path / "out", init=str(init), passes=1, client=client, progress=False)
    assert sum("share positions" in str(w.message) for w in seen) == 1
    assert s.count("done") == 2
    assert not any("share positions" in w for f in s.files for w in f.warnings)
    ref = tmp_path / "ref.npz"
    with pytest.warns(UserWarning, match="share positions"):
        batch.track_file(folder / "b.avi", ref, init=str(init), passes=1)
    assert_same_file(tmp_path / "out" / "b.npz", ref)  # the same points and names as one by one
    from voicepuppet.tracking.tracker import track_video

    with pytest.raises(ValueError, match="not with a points file"):
        track_video(folder / "a.avi", str(init), names=["x"] * 68, passes=1, progress=False)


def test_full_disk_is_reported_per_file_and_leaves_nothing_half_written(client, videos, monkeypatch, tmp_path):
    root, init = videos
    out = tmp_path / "out"
    real = engine.write_file

    def full_for_b(path, data):
        if path.name.startswith("b."):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, data)

    monkeypatch.setattr(engine, "write_file", full_for_b)
    s = batch.track_folder(root, out, init=str(init), passes=1, client=client, progress=False)
    b = next(f for f in s.files if f.input == "b.avi")
    assert b.status == "failed" and "no space left on device" in b.error
    assert {f.input for f in s.files if f.status == "done"} == {"a.avi", "sub/c.avi"}
    assert not any(n.startswith("b.") or ".partial" in n for n in outputs(out))
    monkeypatch.setattr(engine, "write_file", real)  # space freed: the re-run completes it
    s2 = batch.track_folder(root, out, init=str(init), passes=1, client=client, progress=False)
    assert [f.input for f in s2.files if f.status == "done"] == ["b.avi"]


def test_inputs_that_would_overwrite_each_other_are_reported(client, videos, tmp_path):
    import shutil

    root, init = videos
    folder = tmp_path / "clash"
    folder.mkdir()
    shutil.copy(root / "a.avi", folder / "x.avi")
    shutil.copy(root / "a.avi", folder / "x.mkv")
    s = batch.track_folder(folder, tmp_path / "out", init=str(init), passes=1, client=client, progress=False)
    assert [(f.input, f.status) for f in s.files] == [("x.avi", "done"), ("x.mkv", "failed")]
    assert "would overwrite those of x.avi" in s.files[1].error


def test_a_second_run_into_the_same_folder_is_refused(client, videos, tmp_path):
    import fcntl

    root, init = videos
    out = tmp_path / "out"
    out.mkdir()
    with open(out / batch.LOCK_NAME, "a") as fh:  # as a run in progress holds it
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(ValueError, match="another voicepuppet batch run is writing"):
            batch.track_folder(root, out, init=str(init), passes=1, client=client, progress=False)
    assert not (out / batch.MANIFEST_NAME).exists()


def test_manifest_ignores_a_damaged_line(tmp_path):
    m = batch.Manifest(tmp_path)
    (tmp_path / "x.npz").write_bytes(b"abc")
    m.record("x.wav", "in", "settings", {"x.npz": batch.sha256_file(tmp_path / "x.npz")})
    with open(m.path, "a") as fh:
        fh.write('{"input": "y.wav", "input_sha')  # an append cut short
    m2 = batch.Manifest(tmp_path)
    assert set(m2.entries) == {"x.wav"}
    assert m2.finished("x.wav", "in", "settings", tmp_path)
    assert not m2.finished("x.wav", "other input", "settings", tmp_path)
    assert not m2.finished("x.wav", "in", "other settings", tmp_path)


def test_cli_batch_track_reports_and_exits_nonzero_on_failure(videos, tmp_path, capfd):
    from voicepuppet.cli.main import main

    root, init = videos
    out = tmp_path / "out"
    rc = main(["batch", "track", str(root), "-o", str(out), "--init", str(init), "--passes", "1",
               "--workers", "1"])
    captured = capfd.readouterr()  # file descriptors: the worker processes' logs too
    assert rc == 1
    assert "3 done, 0 skipped" in captured.out and "2 failed" in captured.out
    assert "FAILED broken.mp4" in captured.out and "FAILED gone.avi" in captured.out
    assert "batch track" in captured.err  # the progress bar
    # A refused input is the input's fault: listed in the summary, no worker traceback.
    assert "Traceback" not in captured.err and "Compute Failed" not in captured.err
    assert (out / "sub" / "c.npz").is_file()


def test_bad_arguments_are_clear_errors(videos, tmp_path, capsys):
    from voicepuppet.cli.main import main

    root, init = videos
    assert main(["batch", "track", str(tmp_path / "nope"), "-o", str(tmp_path / "o"), "--init", str(init),
                 "--workers", "1"]) == 2
    assert "does not exist" in capsys.readouterr().err
    bad_init = tmp_path / "bad.json"
    bad_init.write_text("{}")
    assert main(["batch", "track", str(root), "-o", str(tmp_path / "o"), "--init", str(bad_init)]) == 2
    assert "points" in capsys.readouterr().err
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert main(["batch", "track", str(root), "-o", str(tmp_path / "o"), "--init", str(init),
                 "--scheduler", f"tcp://127.0.0.1:{port}", "--timeout", "2"]) == 2
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown export format"):
        jobs._format_tags(["npz", "mp3"])
    with pytest.raises(ValueError, match="same file twice"):
        jobs._format_tags(["arkit", "arkit"])


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_real_cluster_with_a_worker_killed_mid_run(tmp_path, write_avi):
    """A real `dask scheduler` and two `dask worker` processes on loopback; one worker is killed
    (SIGKILL) while it holds tasks. Every output is produced exactly once and equals the
    one-by-one output."""
    import signal
    import subprocess
    import sys
    import threading
    import time

    root = tmp_path / "videos"
    frames, _, _ = planted_face_sequence(8 * 16, seed=2, occlusion=None, blur=None)
    names = [f"v{i}.avi" for i in range(8)]
    for i, n in enumerate(names):
        write_avi(root / n, frames[16 * i:16 * (i + 1)])
    init = tmp_path / "points.json"
    init.write_text(json.dumps({"points": ASTRONAUT_POINTS.tolist()}))
    env = dict(os.environ)
    if env.get("PYTHONPATH"):
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) for p in env["PYTHONPATH"].split(os.pathsep))
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    log = open(tmp_path / "cluster.log", "w")
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], stdout=log, stderr=log, env=env)]
    try:
        for i in range(2):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--no-nanny",
                 "--no-dashboard", "--name", f"w{i}", "--local-directory", str(tmp_path / f"w{i}"),
                 "--death-timeout", "60"], stdout=log, stderr=log, env=env))
        out = tmp_path / "out"
        with connect(address, workers=2, timeout=60) as client:
            result = {}

            def run():
                result["summary"] = batch.track_folder(root, out, init=str(init), passes=1, client=client,
                                                       progress=False)

            t = threading.Thread(target=run)
            t.start()
            pids = client.run(os.getpid)  # worker address -> process id
            victim = None
            deadline = time.time() + 120
            while victim is None and time.time() < deadline and t.is_alive():
                busy = [w for w, keys in client.processing().items() if keys]
                started = (out / batch.MANIFEST_NAME).is_file()
                if started and busy:
                    victim = busy[0]
                    break
                time.sleep(0.05)
            assert victim is not None, "the batch finished before a worker could be killed; make it longer"
            os.kill(pids[victim], signal.SIGKILL)
            t.join(timeout=300)
            assert not t.is_alive()
            assert victim not in client.nthreads()  # the worker really died
            # Then the scheduler dies during a second run (other settings: all files redone): the
            # run returns promptly, reporting the unfinished files, with nothing half-written.
            out2 = tmp_path / "out2"

            def kill_scheduler():
                while not (out2 / batch.MANIFEST_NAME).is_file() and t2.is_alive():
                    time.sleep(0.02)
                procs[0].send_signal(signal.SIGKILL)

            def run2():
                result["second"] = batch.track_folder(root, out2, init=str(init), passes=2, client=client,
                                                      progress=False)

            t2 = threading.Thread(target=run2)
            t2.start()
            kill_scheduler()
            t2.join(timeout=120)
            assert not t2.is_alive(), "the run hung after losing its scheduler"
        second = result["second"]
        assert second.count("done") + second.count("failed") == 8 and second.count("failed") >= 1
        assert all("lost its Dask scheduler" in f.error for f in second.failed)
        assert not any(".partial" in n for n in outputs(tmp_path / "out2"))
        s = result["summary"]
        assert [f.status for f in s.files] == ["done"] * 8, s.text()
        lines = (out / batch.MANIFEST_NAME).read_text().splitlines()
        assert sorted(json.loads(x)["input"] for x in lines) == names  # each input recorded exactly once
        assert outputs(out) == sorted([batch.MANIFEST_NAME, batch.SUMMARY_NAME, batch.LOCK_NAME]
                                      + [n.replace(".avi", e) for n in names for e in (".npz", ".csv")])
        ref = tmp_path / "ref"
        ref.mkdir()
        for n in names:
            batch.track_file(root / n, ref / n.replace(".avi", ".npz"), init=str(init), passes=1)
            for e in (".npz", ".csv"):
                assert_same_file(out / n.replace(".avi", e), ref / n.replace(".avi", e))
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=30)
        log.close()



# ----------------------------------------------------------------------------- batch animate

FORMATS = ["npz", "csv", "arkit", "rhubarb"]


@pytest.fixture(scope="module")
def puppet_and_audio(tmp_path_factory):
    """A small puppet trained on the synthetic performer, three spoken lines (one in a
    sub-folder) and a file that is not audio."""
    import soundfile as sf

    from voicepuppet import synth
    from voicepuppet.puppet.model import Puppet

    if not synth.espeak_available():
        pytest.fail("the batch animate tests need espeak-ng (apt-get install espeak-ng; .ci/setup installs it)")
    work = tmp_path_factory.mktemp("puppet")
    corpus = synth.make_corpus(work / "corpus", train_seconds=10, n_test=0, seed=0, real_test=False,
                               progress=False)
    clip = corpus.train
    puppet = Puppet.train([clip.points], [clip.audio], fps=clip.fps, n_states=8, n_iter=10, seed=0)
    puppet_path = work / "performer.vpp"
    puppet.save(puppet_path)
    audio = tmp_path_factory.mktemp("lines")
    for rel, text in (("one.wav", "Peter bought a map of the bay."),
                      ("two.wav", "We will meet at noon under the old oak tree."),
                      ("scene2/three.flac", "Nobody knew why the violin played by itself.")):
        utt = synth.speak(text)
        (audio / rel).parent.mkdir(parents=True, exist_ok=True)
        sf.write(audio / rel, utt.samples, utt.rate)
    (audio / "noise.wav").write_bytes(b"RIFF\x00\x00\x00\x00WAVEjunk" * 4)
    return puppet_path, audio


def test_animate_folder_equals_one_by_one(client, puppet_and_audio, tmp_path):
    from voicepuppet.puppet.model import load

    puppet_path, audio = puppet_and_audio
    out = tmp_path / "out"
    s = batch.animate_folder(puppet_path, audio, out, FORMATS, client=client, progress=False)
    assert {f.input: f.status for f in s.files} == {"noise.wav": "failed", "one.wav": "done",
                                                    "scene2/three.flac": "done", "two.wav": "done"}
    assert "noise.wav" in s.failed[0].input and s.failed[0].error
    ref = tmp_path / "ref"
    puppet = load(puppet_path)
    for rel in ("one.wav", "two.wav", "scene2/three.flac"):
        stem = ref / Path(rel).with_suffix("")
        stem.parent.mkdir(parents=True, exist_ok=True)
        written = batch.animate_file(puppet, audio / rel, stem, FORMATS)
        assert [p.name for p in written] == [stem.name + t for t in (".npz", ".csv", "_arkit.csv", "_cues.json")]
        for p in written:
            assert_same_file(out / p.relative_to(ref), p)
    done = [f for f in s.files if f.status == "done"]
    assert all(f.media_seconds > 1.0 for f in done)
    again = batch.animate_folder(puppet_path, audio, out, FORMATS, client=client, progress=False)
    assert (again.count("skipped"), again.count("done"), again.count("failed")) == (3, 0, 1)
    fewer = batch.animate_folder(puppet_path, audio, out, ["npz"], client=client, progress=False)
    assert fewer.count("done") == 3  # other settings: redone


def test_what_a_worker_warned_about_reaches_the_summary(client, puppet_and_audio, tmp_path):
    import shutil

    import soundfile as sf

    puppet_path, audio = puppet_and_audio
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(audio / "one.wav", folder / "one.wav")
    sf.write(folder / "quiet.wav", np.zeros(16000), 16000)
    s = batch.animate_folder(puppet_path, folder, tmp_path / "out", ["npz"], client=client, progress=False)
    by_name = {f.input: f for f in s.files}
    assert by_name["quiet.wav"].status == "done" and by_name["one.wav"].warnings == []
    assert len(by_name["quiet.wav"].warnings) == 1 and "the recording is silent" in by_name["quiet.wav"].warnings[0]
    assert "  warning quiet.wav: audio in " in s.text()
    summary = json.loads((tmp_path / "out" / batch.SUMMARY_NAME).read_text())
    assert [f["warnings"] for f in summary["files"]] == [[], by_name["quiet.wav"].warnings]


def test_cli_batch_animate(puppet_and_audio, tmp_path, capsys):
    from voicepuppet.cli.main import main

    puppet_path, audio = puppet_and_audio
    out = tmp_path / "out"
    rc = main(["batch", "animate", str(puppet_path), str(audio), "-o", str(out), "--format", "npz,csv,rhubarb",
               "--workers", "2", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 1 and "3 done" in text and "FAILED noise.wav" in text and "real time" in text
    assert (out / "scene2" / "three.npz").is_file() and (out / "one_cues.json").is_file()
    # the same as the one-file verb, `voicepuppet animate PUPPET AUDIO -o ...`
    for suffix in (".csv", ".npz"):
        ref = tmp_path / f"ref{suffix}"
        assert main(["animate", str(puppet_path), str(audio / "scene2" / "three.flac"), "-o", str(ref),
                     "--quiet"]) == 0
        assert_same_file(out / "scene2" / f"three{suffix}", ref)
    assert main(["batch", "animate", str(tmp_path / "missing.vpp"), str(audio), "-o", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["batch", "animate", str(puppet_path), str(audio), "-o", str(out), "--format", "npz,wav"]) == 2
    assert "unknown export format" in capsys.readouterr().err
    # a damaged puppet stops the batch once, before any file, not once per file
    damaged = tmp_path / "damaged.vpp"
    data = bytearray(puppet_path.read_bytes())
    data[-1] ^= 0xFF
    damaged.write_bytes(bytes(data))
    fresh = tmp_path / "fresh"
    assert main(["batch", "animate", str(damaged), str(audio), "-o", str(fresh), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "checksum mismatch" in err and "damaged.vpp" in err, err
    assert not fresh.exists()
    assert main(["batch", "animate", str(puppet_path), str(audio), "-o", str(fresh), "--fps", "1e9"]) == 2
    assert "output fps = 1e+09 is outside [1, 1000]" in capsys.readouterr().err
