"""Runs libespeak-ng once in its own process (started by voicepuppet.synth.speech).

libespeak-ng keeps state from one utterance to the next (a repeated sentence comes out a few
samples different), and re-initialising it in-process can hang; a fresh process per utterance
is deterministic. Reads a JSON request on stdin; writes one JSON line (sample rate, version,
phoneme events as [sample, label]) followed by the int16 PCM on stdout. Standard library only.
"""

import ctypes
import ctypes.util
import json
import sys

_EVENT_PHONEME, _EVENT_LIST_TERMINATED = 7, 0


class _EventId(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    _fields_ = [("type", ctypes.c_int), ("unique_identifier", ctypes.c_uint),
                ("text_position", ctypes.c_int), ("length", ctypes.c_int),
                ("audio_position", ctypes.c_int), ("sample", ctypes.c_int),
                ("user_data", ctypes.c_void_p), ("id", _EventId)]


_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int,
                             ctypes.POINTER(_Event))


def main() -> int:
    """Serve the request on standard input (see the module's docstring); returns the exit code."""
    req = json.loads(sys.stdin.read())
    lib = ctypes.CDLL(ctypes.util.find_library("espeak-ng") or "libespeak-ng.so.1")
    lib.espeak_Info.restype = ctypes.c_char_p
    # synchronous output, phoneme events on, do not exit the process on errors
    rate = lib.espeak_Initialize(2, 0, None, 0x0001 | 0x8000)
    head = {"rate": rate, "version": lib.espeak_Info(None).decode(), "events": []}
    if rate <= 0:
        head["error"] = f"espeak_Initialize returned {rate}"
    if req.get("info") or "error" in head:
        sys.stdout.write(json.dumps(head) + "\n")
        return 0
    pcm = bytearray()

    def collect(wav, n, events):
        if n > 0 and wav:
            pcm.extend(ctypes.string_at(wav, 2 * n))
        i = 0
        while events[i].type != _EVENT_LIST_TERMINATED:
            ev = events[i]
            if ev.type == _EVENT_PHONEME:
                label = bytes(ev.id.string).split(b"\0")[0].decode("ascii", "replace")
                head["events"].append([int(ev.sample), label])
            i += 1
        return 0

    cb = _CALLBACK(collect)
    lib.espeak_SetSynthCallback(cb)
    if lib.espeak_SetVoiceByName(req["voice"].encode()) != 0:
        head["error"] = "voice"
    else:
        for param, key in ((1, "rate"), (3, "pitch"), (4, "pitch_range")):
            lib.espeak_SetParameter(param, int(req[key]), 0)
        data = req["text"].encode("utf-8")
        err = lib.espeak_Synth(data, len(data) + 1, 0, 1, 0, 1, None, None)
        lib.espeak_Synchronize()
        if err != 0:
            head["error"] = f"espeak_Synth returned {err}"
    out = sys.stdout.buffer
    out.write((json.dumps(head) + "\n").encode())
    out.write(bytes(pcm))
    out.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
