"""The voicepuppet command: --version, info, bench (JSON schema of DESIGN.md)."""

import json
import os
import subprocess
import sys

import pytest

from voicepuppet import __version__
from voicepuppet.cli.main import main


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "voicepuppet.cli.main", *args], capture_output=True, text=True,
                          env=dict(os.environ), timeout=300)


def test_version():
    r = run_cli("--version")
    assert r.returncode == 0
    assert r.stdout.strip() == f"voicepuppet {__version__}"


def test_info_reports_the_compiled_core(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for key in ("core_version", "core_build_type", "core_compiler", "core_eigen"):
        assert key in out
    assert "Release" in out


def test_info_describes_puppet_files(tmp_path, capsys):
    """``voicepuppet info PUPPET.vpp``: training, each part's state machine, the audio, the guide
    and the errors its weight was chosen by; an unguided puppet says so; a damaged file is a
    clear error."""
    import numpy as np

    from voicepuppet.puppet.model import Puppet

    rng = np.random.default_rng(0)
    T = 600
    states = np.repeat(rng.integers(0, 3, T // 20 + 1), 20)[:T]
    base = rng.normal(size=(68, 2)) * 40 + 160
    pts = base + rng.normal(size=(3, 68, 2))[states] * 2 + rng.normal(0, 0.1, (T, 68, 2))
    feats = rng.normal(size=(3, 4))[states] + rng.normal(0, 0.3, (T, 4))
    cuts = np.array_split(np.arange(T), 5)
    opts = dict(fps=25.0, n_states=3, n_iter=5, n_components=2, audio_deltas=1, guide_context=2)
    guided = Puppet.train([pts[c] for c in cuts], features_list=[feats[c] for c in cuts], **opts)
    plain = Puppet.train([pts[c] for c in cuts], features_list=[feats[c] for c in cuts], guide="none", **opts)
    g, n = guided.save(tmp_path / "g.vpp"), plain.save(tmp_path / "n.vpp")
    assert main(["info", str(g), str(n)]) == 0
    out = capsys.readouterr().out
    assert f"{g}: written by voicepuppet {__version__}; 68 points at 25 fps, part face" in out
    assert "trained on 600 frames (5 sequences), entropic prior, seed 0" in out
    assert f"part face: {guided.n_states(0)} states" in out
    assert ("audio: feature set puppet (4 features, deltas ±1, levels as recorded); vocal Gaussians on the "
            "audio features, full covariances") in out
    cv = guided.metadata["training"]["guide"]["weight_cv"]
    assert (f"guide: the ridge's face over ±2 frames, weight {guided.guide_weight:g}, chosen by "
            f"cross-validation (error of the face's motion per frame at each weight: 0: {cv['mse'][0]:.4g}, ") in out
    assert "guide: none (Brand's trajectory solve alone)" in out
    bad = tmp_path / "bad.vpp"
    bad.write_bytes(g.read_bytes()[:100])
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "voicepuppet info: error:" in err and "bad.vpp" in err


def _blas_line(out):
    return next(line for line in out.splitlines() if line.strip().startswith("blas:"))


def test_commands_run_blas_on_one_thread_unless_told(capsys, monkeypatch):
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads():
        return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]

    for var in ("VOICEPUPPET_BLAS_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    with threadpool_limits(limits=2, user_api="blas"):
        assert set(blas_threads()) == {2}
        assert main(["info"]) == 0
        assert _blas_line(capsys.readouterr().out).endswith(", 1 thread")
        assert set(blas_threads()) == {2}  # restored when the command returns
        monkeypatch.setenv("VOICEPUPPET_BLAS_THREADS", "2")
        assert main(["info"]) == 0
        assert _blas_line(capsys.readouterr().out).endswith(", 2 threads")
        monkeypatch.delenv("VOICEPUPPET_BLAS_THREADS")
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # the user's own setting is left alone
        assert main(["info"]) == 0
        assert _blas_line(capsys.readouterr().out).endswith(", 2 threads")
    monkeypatch.setenv("VOICEPUPPET_BLAS_THREADS", "many")
    assert main(["info"]) == 2
    assert "VOICEPUPPET_BLAS_THREADS must be a whole number >= 1, got 'many'" in capsys.readouterr().err


def test_training_runs_blas_on_one_thread_unless_told(monkeypatch):
    """``Puppet.train`` from Python limits numpy's BLAS as the commands do, and restores it."""
    import numpy as np
    from threadpoolctl import threadpool_info, threadpool_limits

    from voicepuppet.puppet import training as vpuppet
    from voicepuppet.puppet.model import Puppet

    def blas_threads():
        return {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

    seen = []
    remap = vpuppet.remap

    def recording_remap(*args, **kwargs):
        seen.append(blas_threads())
        return remap(*args, **kwargs)

    monkeypatch.setattr(vpuppet, "remap", recording_remap)
    for var in ("VOICEPUPPET_BLAS_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    rng = np.random.default_rng(0)
    states = np.repeat(rng.integers(0, 3, 31), 10)[:300]
    pts = rng.normal(size=(68, 2)) * 40 + 160 + rng.normal(size=(3, 68, 2))[states] * 2
    feats = rng.normal(size=(3, 3))[states] + rng.normal(0, 0.3, (300, 3))
    opts = dict(fps=25.0, n_states=3, n_iter=3, n_components=2, audio_deltas=0, guide_weight=1.0)
    with threadpool_limits(limits=2, user_api="blas"):
        Puppet.train([pts], features_list=[feats], **opts)
        assert seen and all(s == {1} for s in seen) and blas_threads() == {2}
        seen.clear()
        monkeypatch.setenv("VOICEPUPPET_BLAS_THREADS", "2")
        Puppet.train([pts], features_list=[feats], **opts)
        assert seen and all(s == {2} for s in seen)


def test_the_limit_reaches_scipys_own_blas_loaded_after_it():
    """scipy's wheels bundle a second OpenBLAS; a limit set before scipy.linalg is first imported
    must cover it too (a fresh interpreter, so scipy is not loaded yet)."""
    import json
    import os
    import subprocess
    import sys

    code = ("import json, sys\n"
            "assert 'scipy.linalg' not in sys.modules\n"
            "from threadpoolctl import threadpool_info\n"
            "from voicepuppet.blas import blas_threads\n"
            "with blas_threads():\n"
            "    from scipy.linalg import cho_factor\n"
            "    print(json.dumps([[lib['filepath'], lib['num_threads']] for lib in threadpool_info()\n"
            "                      if lib['user_api'] == 'blas']))\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("VOICEPUPPET_BLAS_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    libs = json.loads(out)
    assert libs and all(n == 1 for _, n in libs), libs


def test_the_evaluation_entry_points_run_blas_on_one_thread_from_python_too(monkeypatch):
    """The ridge baseline fitted from a user's Python limits BLAS as training does (its dense
    solves are where two threads thrash), and so do the harness's entry points."""
    import numpy as np
    from threadpoolctl import threadpool_info, threadpool_limits

    from voicepuppet.evaluation import crossval
    from voicepuppet.evaluation import crossval as evaluate
    from voicepuppet.evaluation import split as evaluation
    from voicepuppet.puppet.guide import RidgeBaseline

    seen = []
    solve = RidgeBaseline._solve

    def recording_solve(*args):
        seen.append({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"})
        return solve(*args)

    monkeypatch.setattr(RidgeBaseline, "_solve", staticmethod(recording_solve))
    for var in ("VOICEPUPPET_BLAS_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    rng = np.random.default_rng(0)
    with threadpool_limits(limits=2, user_api="blas"):
        RidgeBaseline().fit([rng.normal(size=(60, 3))], [rng.normal(size=(60, 2))])
    assert seen and all(s == {1} for s in seen)
    for entry in (evaluation.evaluate_split, crossval.compare_training, evaluate.cross_validate):
        assert entry.__wrapped__.__name__ == entry.__name__  # blas.limited, docs kept


def test_a_command_prints_warnings_as_one_line_for_the_user(capsys, monkeypatch):
    import warnings

    from voicepuppet.cli import info

    def collect():
        warnings.warn("the face was lost in 30 of 629 frames", UserWarning)
        return {"voicepuppet": __version__}

    monkeypatch.setattr(info, "collect", collect)
    before = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # pytest turns warnings into errors; a user's Python does not
        assert main(["info"]) == 0
    err = capsys.readouterr().err
    assert err == "voicepuppet info: warning: the face was lost in 30 of 629 frames\n"
    assert warnings.showwarning is before  # restored when the command returns


def test_bench_hmm_quick_writes_the_documented_schema(tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "hmm", "--quick", "--repeats", "1", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["suite"] == "hmm"
    assert "core" in doc["machine"]
    names = [c["name"] for c in doc["cases"]]
    assert names[:3] == ["score", "decode", "fit"]
    for c in doc["cases"][:3]:
        assert set(c) >= {"name", "size", "ours_s", "peer", "peer_s", "ratio", "agree"}
        assert c["peer"] == "hmmlearn"
        assert c["ratio"] == pytest.approx(c["peer_s"] / c["ours_s"])
        assert c["agree"] < 1e-6  # same answers as the peer
    assert not list(tmp_path.glob("*.tmp"))


def test_unknown_verb_and_suite_fail_cleanly():
    r = run_cli("dance")
    assert r.returncode == 2 and "invalid choice" in r.stderr
    r = run_cli("bench", "nosuch")
    assert r.returncode == 2 and "invalid choice" in r.stderr
