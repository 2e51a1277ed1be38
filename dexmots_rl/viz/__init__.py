"""Visualisation, on top of everything else: matplotlib figures (:mod:`.plots`: objective landscape, learning
curves; :mod:`.table_plots`: ``dexmots-table``'s figures) and the viser replay viewer (:mod:`.viewer`) of the
MCAP recordings of :mod:`dexmots_rl.recording`, whose API is re-exported here."""

from __future__ import annotations

from ..recording import EpisodeRecorder, Recording, RecordingFormatError, read_recording, record_simulation

__all__ = ["EpisodeRecorder", "Recording", "RecordingFormatError", "read_recording", "record_simulation"]
