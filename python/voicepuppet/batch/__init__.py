"""Batch: folders of audio or video animated or tracked (:mod:`.jobs`), resumably, locally or on
Dask (:mod:`.engine`)."""

from voicepuppet.batch.engine import (LOCK_NAME, MANIFEST_NAME, SUMMARY_NAME, BatchSummary, FileResult, Manifest,
                                      discover, output_names, refusals_reported, run_batch, sha256_file, write_file)
from voicepuppet.batch.jobs import AUDIO_SUFFIXES, VIDEO_SUFFIXES, animate_file, animate_folder, track_file, track_folder

__all__ = ["AUDIO_SUFFIXES", "VIDEO_SUFFIXES", "LOCK_NAME", "MANIFEST_NAME", "SUMMARY_NAME", "BatchSummary",
           "FileResult", "Manifest", "animate_file", "animate_folder", "discover", "output_names",
           "refusals_reported", "run_batch", "sha256_file", "track_file", "track_folder", "write_file"]
