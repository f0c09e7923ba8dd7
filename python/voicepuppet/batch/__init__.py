"""Batch: folders of audio or video animated or tracked, resumably, locally or on Dask."""

from voicepuppet.batch.jobs import animate_folder, run_batch, track_folder

__all__ = ["animate_folder", "run_batch", "track_folder"]
