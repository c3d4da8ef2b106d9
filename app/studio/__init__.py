"""The interactive studio window: training in a background thread, the live avatar drawn with the
SplatRenderer, imgui panels for training, rendering and pose."""

from .trainer_thread import Controls, HistoryRow, TrainerThread

__all__ = ["Controls", "HistoryRow", "TrainerThread"]
