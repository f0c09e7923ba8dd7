"""Sizes a user or a file controls are checked at the command line's doors before anything is
allocated from them: each case below once hung, exhausted memory or wrote a 90 µs video, and is
now one line ``voicepuppet VERB: error: ...`` naming the field, the value and the range, exit 2,
with nothing written."""
import json

import numpy as np
import pytest
import soundfile as sf

from voicepuppet import _core
from voicepuppet.animation import procedural_animation, save_animation
from voicepuppet.cli.main import main
from voicepuppet.puppet.model import Puppet

from support import FPS, RATE, performance


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A puppet trained on audio, the same puppet at 1e9 fps (its checksum valid), a recording
    and an animation."""
    d = tmp_path_factory.mktemp("limits")
    pts, audio, _ = performance(np.random.default_rng(3), 300)
    sf.write(d / "x.wav", audio, RATE)
    puppet = Puppet.train([pts], [str(d / "x.wav")], fps=FPS, n_states=4, n_iter=5, guide="none")
    puppet.save(d / "p.vpp")
    text, arrays = _core.decode_puppet((d / "p.vpp").read_bytes())
    arrays["fps"] = np.array([1e9])
    meta = json.loads(text)
    meta["fps"] = 1e9
    (d / "fast.vpp").write_bytes(_core.encode_puppet(json.dumps(meta), arrays))
    save_animation(procedural_animation(20, 25.0), d / "a.npz")
    return d


def _refused(capsys, argv, *needles):
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and ": error: " in err, err
    for needle in needles:
        assert needle in err, err
    return err


def test_a_puppet_at_1e9_fps_is_refused_by_info_and_animate(files, tmp_path, capsys):
    d = files
    _refused(capsys, ["info", d / "fast.vpp"], "fast.vpp", "puppet fps = 1e+09 is outside [1, 1000]")
    _refused(capsys, ["animate", d / "fast.vpp", d / "x.wav", "-o", tmp_path / "a.npz"],
             "puppet fps = 1e+09 is outside [1, 1000]")
    assert list(tmp_path.iterdir()) == []


def test_animate_at_1e9_fps_is_refused(files, tmp_path, capsys):
    _refused(capsys, ["animate", files / "p.vpp", files / "x.wav", "-o", tmp_path / "a.npz", "--fps", "1e9"],
             "output fps = 1e+09 is outside [1, 1000]")
    assert list(tmp_path.iterdir()) == []
    assert main(["animate", str(files / "p.vpp"), str(files / "x.wav"), "-o", str(tmp_path / "a.npz"),
                 "--fps", "1000", "--quiet"]) == 0


def test_features_for_1e9_frames_or_at_1e9_fps_are_refused(files, tmp_path, capsys):
    out = tmp_path / "f.npz"
    _refused(capsys, ["features", files / "x.wav", "-o", out, "--frames", "1000000000"],
             "n_out (frames) = 1000000000 is outside [1, 10000000]")
    _refused(capsys, ["features", files / "x.wav", "-o", out, "--fps", "1e9"], "fps = 1e+09 is outside [1, 1000]")
    _refused(capsys, ["features", files / "x.wav", "-o", out, "--puppet", files / "p.vpp", "--frames", "10000001"],
             "n_out (frames) = 10000001 is outside")
    assert list(tmp_path.iterdir()) == []


def test_render_at_100000x100000_is_refused(files, tmp_path, capsys):
    out = tmp_path / "o.mp4"
    _refused(capsys, ["render", files / "a.npz", "-o", out, "--renderer", "2d", "--size", "100000x100000"],
             "--size width = 100000 is outside [16, 8192]")
    _refused(capsys, ["render", files / "a.npz", "-o", out, "--renderer", "2d", "--size", "640x9000"],
             "--size height = 9000 is outside [16, 8192]")
    _refused(capsys, ["render", files / "a.npz", "-o", out, "--renderer", "2d", "--size", "8x8"],
             "--size width = 8 is outside [16, 8192]")
    assert list(tmp_path.iterdir()) == []


def test_an_animation_at_1e9_fps_is_refused_by_render_and_export(files, tmp_path, capsys):
    anim = procedural_animation(20, 25.0)
    fast = tmp_path / "fast.npz"
    np.savez(fast, points=anim.points, fps=np.float64(1e9))
    out = tmp_path / "o.mp4"
    _refused(capsys, ["render", fast, "-o", out, "--renderer", "2d"], "animation fps = 1e+09 is outside [1, 1000]")
    _refused(capsys, ["export", fast, "--format", "csv", "-o", tmp_path / "o.csv"], "animation fps")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fast.npz"]


def test_an_animation_with_too_many_points_is_refused(tmp_path, capsys):
    big = tmp_path / "big.npz"
    np.savez(big, points=np.zeros((1, 10_001, 2)), fps=np.float64(25.0))
    _refused(capsys, ["render", big, "-o", tmp_path / "o.mp4", "--renderer", "2d"],
             "points per frame = 10001 is outside [1, 10000]")


def test_2d_landmarks_spanning_more_than_the_largest_picture_need_a_size(tmp_path, capsys):
    anim = procedural_animation(5, 25.0)
    pts = anim.points.copy()
    pts[:, 0] = [1e5, 1e5]
    wide = tmp_path / "wide.npz"
    np.savez(wide, points=pts, fps=np.float64(25.0))
    _refused(capsys, ["render", wide, "-o", tmp_path / "o.mp4", "--renderer", "2d"],
             "more than the largest picture (8192 px a side); give a size")
    assert main(["render", str(wide), "-o", str(tmp_path / "o.mp4"), "--renderer", "2d", "--size", "64x64",
                 "--quiet"]) == 0


def test_landmarks_with_too_many_points_are_refused_by_train(files, tmp_path, capsys):
    big = tmp_path / "big.npz"
    np.savez(big, points=np.zeros((300, 10_001, 2)), fps=np.float64(FPS))
    _refused(capsys, ["train", "--landmarks", big, "--audio", files / "x.wav", "-o", tmp_path / "p.vpp"],
             "big.npz: landmark points per frame = 10001 is outside [1, 10000]")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.npz"]
