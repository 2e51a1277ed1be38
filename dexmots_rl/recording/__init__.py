"""Episodes as MCAP recordings: the format (:mod:`.format`), the writer (:class:`EpisodeRecorder`, which
evaluations and ``dexmots-record`` use) and the reader (:func:`read_recording`, which ``dexmots-view``
replays). Files open in Foxglove too (``foxglove.SceneUpdate`` / ``FrameTransforms`` messages).
"""

from __future__ import annotations

from .format import Recording, RecordingFormatError
from .reader import read_recording
from .recorder import EpisodeRecorder, record_simulation

__all__ = ["EpisodeRecorder", "Recording", "RecordingFormatError", "read_recording", "record_simulation"]
