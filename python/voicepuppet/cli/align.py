"""The ``align`` verb: phone labels of speech by pocketsphinx (see
:func:`voicepuppet.phonemes.labels.align` for what it drives)."""

from __future__ import annotations

import os


def _run(args) -> int:
    from voicepuppet.phonemes.labels import SIL, align, write_hts, write_textgrid

    transcript = args.transcript
    if args.transcript_file:
        if transcript:
            raise ValueError("give --transcript or --transcript-file, not both")
        with open(args.transcript_file, encoding="utf-8") as fh:
            transcript = fh.read()
    out = os.fspath(args.output)
    low = out.lower()
    if not (low.endswith(".textgrid") or low.endswith(".lab")):
        raise ValueError(f"the output must be a .TextGrid or a .lab (HTS) file, got {out!r}")
    pron = {}
    for item in args.pronounce or []:
        word, sep, phones = item.partition("=")
        if not sep:
            raise ValueError(f"--pronounce takes WORD='PH PH ...', got {item!r}")
        pron[word] = phones
    segs = align(args.audio, transcript, pronunciations=pron)
    if low.endswith(".lab"):
        write_hts(segs, out)
    else:
        write_textgrid(segs, out)
    n = sum(s.label != SIL for s in segs)
    print(f"{n} phones over {segs[-1].end:.2f} s ({'forced alignment' if transcript else 'phone recognition'})"
          f"; wrote {out}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("align", help="phone labels of speech (pocketsphinx forced alignment)",
                       description="Phone segments of speech with pocketsphinx's US English model: "
                                   "forced alignment to a transcript, or phone recognition without one. "
                                   "Writes a Praat TextGrid or an HTS label file.")
    p.add_argument("audio", help="sound file or video with sound")
    p.add_argument("-t", "--transcript", help="the words spoken")
    p.add_argument("--transcript-file", metavar="FILE", help="read the words from a text file")
    p.add_argument("--pronounce", action="append", metavar="WORD='PH PH ...'",
                   help="phones (ARPAbet) of a word the dictionary lacks, e.g. churl='CH ER L'; repeatable")
    p.add_argument("-o", "--output", required=True, metavar="OUT.TextGrid|OUT.lab",
                   help="output: .TextGrid (Praat) or .lab (HTS, 100 ns units)")
    p.set_defaults(func=_run)
