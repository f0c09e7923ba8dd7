"""The voice puppet: training (facial HMM, remap), its guide (ridge regression, projection)
and the puppet file (Voice Puppetry §4)."""

from voicepuppet.puppet.long import AnimatedFiles
from voicepuppet.puppet.model import Animated, Puppet, load
from voicepuppet.puppet.training import TRAIN_DEFAULTS, TrainOptions, remap, training_feature_set

__all__ = ["TRAIN_DEFAULTS", "TrainOptions", "Animated", "AnimatedFiles", "Puppet", "load", "remap", "training_feature_set"]
