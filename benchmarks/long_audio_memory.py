"""Peak memory and time of ``voicepuppet animate`` against the audio's length (docs/benchmarks.md,
"Long audio").

Makes speech recordings of each length (the puppet's held-out speech repeated, each copy at its
own level with a little noise, 16-bit PCM at 16 kHz) in a scratch folder, runs
``/usr/bin/time -v voicepuppet animate PUPPET AUDIO -o OUT.npz --quiet`` on each and prints a
Markdown table of the peak resident memory and the wall time. The recordings are deleted after.

    OPENBLAS_NUM_THREADS=1 python benchmarks/long_audio_memory.py PUPPET.vpp SPEECH.wav \\
        [--minutes 1,10,60,120] [--scratch /tmp/long-audio]
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import soundfile as sf


def make_recording(speech: np.ndarray, rate: int, minutes: float, path: Path, seed: int = 0) -> None:
    """``minutes`` of ``speech`` repeated (each copy at a random level, with noise at -60 dBFS),
    written block by block as 16-bit PCM."""
    rng = np.random.default_rng(seed)
    n = int(round(minutes * 60 * rate))
    with sf.SoundFile(path, "w", rate, 1, subtype="PCM_16") as f:
        done = 0
        while done < n:
            k = min(len(speech), n - done)
            block = speech[:k] * 10 ** (rng.uniform(-6, 3) / 20) + 1e-3 * rng.standard_normal(k)
            f.write(np.clip(block, -1, 1))
            done += k


def measure(cmd: list[str]) -> tuple[float, float]:
    """Peak RSS (MB) and wall time (s) of ``cmd`` by GNU time."""
    p = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True, check=True)
    rss = float(re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr).group(1)) / 1024
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", p.stderr).group(1)
    secs = sum(float(v) * 60 ** i for i, v in enumerate(reversed(wall.split(":"))))
    return rss, secs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("puppet")
    ap.add_argument("speech", help="speech to repeat (any rate: resampled to 16 kHz)")
    ap.add_argument("--minutes", default="1,10,60,120")
    ap.add_argument("--scratch", default="/tmp/long-audio")
    ap.add_argument("--cli", default=f"{sys.executable} -m voicepuppet.cli.main",
                    help="how to run voicepuppet (default: this Python's module)")
    args = ap.parse_args(argv)
    from voicepuppet.audio import load_audio

    speech = load_audio(args.speech).samples
    scratch = Path(args.scratch)
    scratch.mkdir(parents=True, exist_ok=True)
    print("| audio | peak RSS (MB) | wall (s) | realtime factor |")
    print("|---|---|---|---|")
    try:
        for minutes in [float(m) for m in args.minutes.split(",")]:
            wav = scratch / f"speech_{minutes:g}min.wav"
            make_recording(speech, 16000, minutes, wav)
            out = scratch / "anim.npz"
            rss, secs = measure([*args.cli.split(), "animate", args.puppet, str(wav), "-o", str(out), "--quiet"])
            print(f"| {minutes:g} min | {rss:.0f} | {secs:.1f} | {minutes * 60 / secs:.0f} |", flush=True)
            wav.unlink()
            out.unlink()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
