"""Evaluation: error measures (:mod:`.metrics`), folds and confidence intervals (:mod:`.folds`),
one train/test split with baselines (:mod:`.split`) and k-fold cross-validation over a corpus
(:mod:`.crossval`)."""

from voicepuppet.evaluation.folds import kfold, mean_ci

__all__ = ["kfold", "mean_ci"]
