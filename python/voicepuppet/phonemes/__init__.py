"""Phones and the phoneme-driven peers: the phone set, label files and forced alignment
(:mod:`.labels`), and the models of Englebienne, Cootes & Rattray (2007): the shared base
(:mod:`.base`), the per-phone means, Brand's trajectory with phone states and the SLDS
(:mod:`.models`), the DPDS (:mod:`~voicepuppet.phonemes.dpds`), and a puppet driven by phones
(:mod:`~voicepuppet.phonemes.puppet`)."""

from voicepuppet.phonemes.base import PhonemeModel, check_labels, observations, stack_sequences
from voicepuppet.phonemes.dpds import DPDS, DPDSStream
from voicepuppet.phonemes.labels import (BREATH, N_PHONES, PHONE_INDEX, PHONES, SIL, AlignmentError, Segment, align,
                                         frame_labels, label_intervals, normalize, read_hts, read_textgrid, segments,
                                         to_phone, write_hts, write_textgrid)
from voicepuppet.phonemes.models import MODELS, SLDS, PhonemeMeans, PhonemeTrajectory
from voicepuppet.phonemes.puppet import PhonemePuppet

__all__ = ["BREATH", "DPDS", "DPDSStream", "MODELS", "N_PHONES", "PHONES", "PHONE_INDEX", "SIL", "SLDS",
           "AlignmentError", "PhonemeMeans", "PhonemeModel", "PhonemePuppet", "PhonemeTrajectory", "Segment",
           "align", "check_labels", "frame_labels", "label_intervals", "normalize", "observations", "read_hts",
           "read_textgrid", "segments", "stack_sequences", "to_phone", "write_hts", "write_textgrid"]
