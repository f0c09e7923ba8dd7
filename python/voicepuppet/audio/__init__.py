"""The audio front end: loading, features at a video frame rate, feature sets.

>>> from voicepuppet import audio
>>> feats = audio.extract("speech.wav", fps=29.97)            # the "puppet" set   # doctest: +SKIP
>>> feats.values.shape, feats.names[:3]                                          # doctest: +SKIP

See docs/audio.md for the features, their conventions and how they were checked against
librosa and Praat.
"""

from voicepuppet.audio.extract import extract
from voicepuppet.audio.featureset import (DEFAULT_OPTIONS, DEFAULT_SET, FEATURE_SETS, FEATURES, Features, FeatureSet,
                                          Standardizer, as_feature_set)
from voicepuppet.audio.framing import frame_centres, frame_times, n_frames
from voicepuppet.audio.loading import MIN_RATE, Audio, AudioWarning, load_audio, prepare

__all__ = ["Audio", "AudioWarning", "MIN_RATE", "load_audio", "prepare", "extract", "Features",
           "FeatureSet", "Standardizer", "FEATURES", "FEATURE_SETS", "DEFAULT_SET",
           "DEFAULT_OPTIONS", "as_feature_set", "frame_times", "frame_centres", "n_frames"]
