"""Build the real recordings that ship inside the package (``python/voicepuppet/recordings``)
from ``../shared/data/real`` (its SOURCES.md gives provenance and licences: all public domain or
CC BY 4.0). Usage:

    python benchmarks/make_recordings.py [REAL_DIR]

Copies every clip that has a reference, and writes ``index.json`` (speaker, session, file, frame
rate, frames, source, licence per clip) and ``reference.npz``: per clip, the independent
reference's layout-free measures per frame (MediaPipe Face Mesh 0.10.21, 478 points, run on
every frame): the inter-ocular distance in pixels (outer eye corners, p33-p263), and the mouth's
opening (inner lips' middles, p13-p14) and width (mouth corners, p61-p291) over it.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
OUT = HERE / "python" / "voicepuppet" / "recordings"
#: speaker folder -> (who, source repository, licence)
SPEAKERS = {
    "obama": ("Barack Obama", "US federal government work (presidential addresses)", "public domain"),
    "reagan": ("Ronald Reagan", "US federal government work (presidential address)", "public domain"),
    "grid": ("GRID corpus speakers", "The GRID audio-visual sentence corpus, Cooke et al. 2006", "CC BY 4.0"),
}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    real = Path(argv[0]) if argv else HERE.parent / "shared" / "data" / "real"
    if not (real / "reference").is_dir():
        print(f"no reference in {real}", file=sys.stderr)
        return 2
    clips, arrays = {}, {}
    for index in sorted((real / "reference").rglob("index.json")):
        folder = index.parent.relative_to(real / "reference")
        speaker = folder.parts[0]
        who, source, licence = SPEAKERS[speaker]
        for name, info in json.loads(index.read_text())["clips"].items():
            # clips in a subfolder are cuts of one kind of session; others are a session each,
            # except GRID, whose speakers are one studio session each
            session = folder.parts[1] if len(folder.parts) > 1 else name
            key = f"{speaker}/{name}"
            dst = OUT / speaker / info["file"]
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(real / folder / info["file"], dst)
            ref = np.load(index.parent / f"{name}.npy").astype(np.float64)
            iod = np.linalg.norm(ref[:, 33] - ref[:, 263], axis=1)
            arrays[f"{key}/iod"] = iod.astype(np.float32)
            arrays[f"{key}/opening"] = (np.linalg.norm(ref[:, 13] - ref[:, 14], axis=1) / iod).astype(np.float32)
            arrays[f"{key}/width"] = (np.linalg.norm(ref[:, 61] - ref[:, 291], axis=1) / iod).astype(np.float32)
            clips[key] = {"speaker": who, "session": session, "file": f"{speaker}/{info['file']}",
                          "fps": info["fps"], "frames": info["frames"], "seconds": info["duration_s"],
                          "source": source, "licence": licence}
    (OUT / "index.json").write_text(json.dumps({"clips": clips}, indent=1) + "\n")
    np.savez_compressed(OUT / "reference.npz", **arrays)
    print(f"{len(clips)} clips into {OUT}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
