"""Phones and the phoneme-driven peers: the phone set, label files and forced alignment
(:mod:`.labels`), and the models of Englebienne, Cootes & Rattray (2007) (:mod:`.models`)."""

from voicepuppet.phonemes.labels import PHONES, AlignmentError, Segment, align, frame_labels, normalize, to_phone

__all__ = ["PHONES", "AlignmentError", "Segment", "align", "frame_labels", "normalize", "to_phone"]
