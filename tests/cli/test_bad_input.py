"""docs/errors.md's bad-input table, row by row: each command exits with code 2 and one line
``voicepuppet VERB: error: ...`` containing the row's text, and writes nothing. The table is the
test's data, so the page and the behaviour cannot drift apart."""
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from voicepuppet.animation import procedural_animation, save_animation
from voicepuppet.cli.main import main
from voicepuppet.puppet.model import Puppet

from support import FPS, RATE, performance

DOC = Path(__file__).resolve().parents[2] / "docs" / "errors.md"
MARK = "<!-- bad-input table: read by tests/cli/test_bad_input.py -->"


def _rows() -> list[tuple[str, str]]:
    text = DOC.read_text()
    assert MARK in text, f"{DOC} lost its table marker"
    rows = []
    for line in text.split(MARK, 1)[1].strip().splitlines()[2:]:
        if not line.startswith("|"):
            break
        command, says = (c.strip() for c in line.strip("|").split("|"))
        rows.append((command.strip("`"), says))
    return rows


ROWS = _rows()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The files the table names, made once."""
    d = tmp_path_factory.mktemp("bad_input")
    pts, audio, _ = performance(np.random.default_rng(3), 300)
    sf.write(d / "speech.wav", audio, RATE)
    Puppet.train([pts], [str(d / "speech.wav")], fps=FPS, n_states=4, n_iter=5).save(d / "puppet.vpp")
    damaged = bytearray((d / "puppet.vpp").read_bytes())
    damaged[-1] ^= 0xFF
    (d / "damaged.vpp").write_bytes(bytes(damaged))
    sf.write(d / "nan.wav", np.full(RATE, np.nan, dtype=np.float32), RATE, subtype="FLOAT")
    for name in ("empty.wav", "empty.npz"):
        (d / name).write_bytes(b"")
    for name in ("text.wav", "text.mp4"):
        (d / name).write_text("hello\n")
    save_animation(procedural_animation(20, 25.0), d / "anim.npz")
    (d / "folder").mkdir()
    (d / "folder" / "speech.wav").write_bytes((d / "speech.wav").read_bytes())
    return d


def _listing(d: Path) -> dict:
    return {str(p.relative_to(d)): p.stat().st_mtime_ns for p in sorted(d.rglob("*"))}


def test_the_table_covers_every_verb_that_reads_files():
    verbs = {shlex.split(c)[0] for c, _ in ROWS}
    assert verbs >= {"info", "track", "train", "animate", "features", "render", "export", "batch", "live",
                     "align", "phoneme-puppet", "evaluate"}, verbs
    assert len(ROWS) >= 30


@pytest.mark.filterwarnings("default")  # warnings before the error are the user's news, printed as lines
@pytest.mark.parametrize("command, says", ROWS, ids=[c for c, _ in ROWS])
def test_bad_input_is_one_line_and_exit_2(inputs, command, says, capsys, monkeypatch):
    monkeypatch.chdir(inputs)
    argv = [a.replace("LONG", "n" * 300) for a in shlex.split(command)]
    before = _listing(inputs)
    assert main(argv) == 2, command
    err = capsys.readouterr().err
    lines = [line for line in re.split(r"[\r\n]", err) if line.startswith("voicepuppet ") and ": warning: " not in line]
    assert len(lines) == 1 and lines[0].startswith(f"voicepuppet {argv[0]}: error: "), err
    assert "Traceback" not in err, err
    assert says in lines[0], (says, err)
    assert _listing(inputs) == before, "the command wrote or changed a file"


@pytest.mark.parametrize("raised, code, says", [
    (RuntimeError("the trajectory normal equations are numerically singular"), 2, "error: the trajectory normal"),
    (OSError(28, "No space left on device"), 2, "error: [Errno 28] No space left on device"),
    (MemoryError(), 2, "error: not enough memory for this input"),
    (TypeError("unsupported operand"), 1, "internal error: this is a bug in voicepuppet"),
    (RecursionError("maximum recursion depth exceeded"), 1, "internal error: this is a bug in voicepuppet"),
])
def test_expected_failures_are_one_line_and_bugs_a_traceback(inputs, monkeypatch, capsys, raised, code, says):
    import voicepuppet.cli.info as info

    def fail(args):
        raise raised

    monkeypatch.setattr(info, "_run", fail)
    assert main(["info"]) == code
    err = capsys.readouterr().err
    assert says in err, err
    assert ("Traceback" in err) == (code == 1), err
