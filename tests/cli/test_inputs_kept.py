"""No verb overwrites what it reads, a stray temporary-looking file of the user's survives, and
SIGTERM stops a verb as Ctrl-C does, leaving nothing half-written."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from voicepuppet.animation import procedural_animation, save_animation
from voicepuppet.cli.main import main


def test_export_without_output_does_not_overwrite_its_input(tmp_path, capsys):
    src = tmp_path / "t.npz"
    save_animation(procedural_animation(10, 10.0), src)
    np.savez(src, **dict(np.load(src)), params=np.arange(3))  # the user's extra array
    before = src.read_bytes()
    assert main(["export", str(src), "--format", "npz"]) == 2
    assert "never overwrites its input" in capsys.readouterr().err
    assert src.read_bytes() == before


def test_an_output_that_names_an_input_is_refused(tmp_path, capsys):
    anim = tmp_path / "a.npz"
    save_animation(procedural_animation(10, 10.0), anim)
    before = anim.read_bytes()
    assert main(["render", str(anim), "--renderer", "2d", "-o", str(anim)]) == 2
    err = capsys.readouterr().err
    assert "-o" in err and str(anim) in err and "never overwrites its input" in err
    assert anim.read_bytes() == before
    assert main(["export", str(anim), "--format", "npz", "-o", str(tmp_path / "." / "a.npz")]) == 2
    assert anim.read_bytes() == before


def test_features_leaves_a_users_file_beside_its_output(tmp_path):
    import soundfile as sf

    rng = np.random.default_rng(0)
    sf.write(tmp_path / "x.wav", 0.1 * rng.normal(size=16000), 16000)
    mine = tmp_path / "g.tmp.npz"
    mine.write_bytes(b"the user's")
    assert main(["features", str(tmp_path / "x.wav"), "-o", str(tmp_path / "g.npz")]) == 0
    assert mine.read_bytes() == b"the user's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.npz", "g.tmp.npz", "x.wav"]


def test_sigterm_stops_a_render_and_leaves_nothing_half_written(tmp_path):
    anim = tmp_path / "long.npz"
    save_animation(procedural_animation(3000, 30.0), anim)
    out = tmp_path / "out.mp4"
    proc = subprocess.Popen([sys.executable, "-m", "voicepuppet.cli.main", "render", str(anim), "-o", str(out),
                             "--renderer", "2d"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while time.time() < deadline and not any(p.name.endswith(".partial.mp4") for p in tmp_path.iterdir()):
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143 and "terminated" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.npz"]


def test_landmarks_without_a_frame_rate_are_refused(tmp_path, capsys):
    import soundfile as sf

    pts = np.random.default_rng(0).normal(100, 5, (50, 68, 2))
    np.savez(tmp_path / "nofps.npz", points=pts)
    np.savez(tmp_path / "zero.npz", points=pts, fps=0.0)
    sf.write(tmp_path / "a.wav", 0.1 * np.random.default_rng(1).normal(size=16000), 16000)
    for name, what in (("nofps.npz", "no 'fps'"), ("zero.npz", "fps is 0")):
        assert main(["train", "--landmarks", str(tmp_path / name), "--audio", str(tmp_path / "a.wav"),
                     "-o", str(tmp_path / "p.vpp")]) == 2
        assert what in capsys.readouterr().err
    assert not (tmp_path / "p.vpp").exists()


def test_temporaries_of_killed_runs_are_removed_by_the_next_write(tmp_path):
    """A run killed with SIGKILL leaves its temporary; the next write to that output removes it
    (its process is gone), and leaves a running process's temporary alone."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead = int(done.stdout)
    stale = tmp_path / f".a.npz.{dead}.x1y2.partial.npz"
    live = tmp_path / f".a.npz.{os.getpid()}.z3w4.partial.npz"
    other = tmp_path / f".b.npz.{dead}.q5r6.partial.npz"  # another output's: not this write's business
    for f in (stale, live, other):
        f.write_bytes(b"half")
    save_animation(procedural_animation(4, 10.0), tmp_path / "a.npz")
    assert not stale.exists() and live.exists() and other.exists()
    assert (tmp_path / "a.npz").exists()
    # what a killed run leaves now carries its process id
    proc = subprocess.Popen([sys.executable, "-c",
                             "import time, sys\n"
                             "from voicepuppet._files import atomic_path\n"
                             f"with atomic_path({str(tmp_path / 'c.npz')!r}) as t:\n"
                             "    print(t.name, flush=True); time.sleep(60)\n"], stdout=subprocess.PIPE, text=True)
    name = proc.stdout.readline().strip()
    assert name.startswith(f".c.npz.{proc.pid}.") and (tmp_path / name).exists()
    proc.kill()
    proc.wait()
    proc.stdout.close()
    save_animation(procedural_animation(4, 10.0), tmp_path / "c.npz")
    assert not (tmp_path / name).exists()


def test_ctrl_c_stops_a_long_cpp_call_inside_it():
    """A signal's Python handler runs inside a long C++ kernel (interrupt.hpp), not after it: the
    feature front end, pushed ten minutes of audio at once, stops part-way with the handler's
    exception (before, the handler ran once all ten minutes were done)."""
    from voicepuppet.audio.stream import StreamingFeatures

    class Stop(Exception):
        pass

    def stop(signum, frame):
        raise Stop()

    x = np.random.default_rng(0).normal(0, 0.1, 16000 * 600)
    stream = StreamingFeatures("puppet", fps=29.97, rate=16000)
    previous = signal.signal(signal.SIGALRM, stop)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.02)
        try:
            stream.push(x)
        except Stop:
            pass
        else:
            raise AssertionError("the push finished before the alarm: it never saw the signal")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert stream.samples_in < len(x) // 2, stream.samples_in  # stopped early, by the handler


def test_a_signal_held_back_while_a_temporary_is_named_still_cleans_it(tmp_path, monkeypatch):
    """SIGTERM sent while atomic_path creates its temporary is answered when the name is kept, so
    the interruption that follows removes the file (before, a signal between the creation and the
    try block left it)."""
    from voicepuppet import _files

    seen = []

    def terminate(*_):
        seen.append("term")
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        real_close = os.close

        def close_then_signal(fd):  # the signal arrives right after the file was created
            real_close(fd)
            os.kill(os.getpid(), signal.SIGTERM)
            assert seen == []  # held back while the name is not yet kept

        monkeypatch.setattr(_files.os, "close", close_then_signal)
        with pytest.raises(KeyboardInterrupt):
            with _files.atomic_path(tmp_path / "a.npz"):
                pytest.fail("the held signal is answered before the body runs")
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert seen == ["term"] and list(tmp_path.iterdir()) == []
