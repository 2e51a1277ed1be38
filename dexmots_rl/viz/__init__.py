"""Visualisation: matplotlib figures (:mod:`.plots`: objective landscape, learning curves); MCAP recordings
(:mod:`.recording` format, :mod:`.recorder`, :mod:`.reader`) and the viser replay viewer (:mod:`.viewer`)."""

from __future__ import annotations

from .reader import read_recording
from .recorder import EpisodeRecorder
from .recording import Recording, RecordingFormatError

__all__ = ["EpisodeRecorder", "Recording", "RecordingFormatError", "read_recording"]
