"""Raw video -> scene folder: frames, person masks, keypoints (mediapipe), fitted body poses and camera.

See ``pipeline.prepare_video`` and docs/prepare.md."""

from .detector import DetectorError, Detections, MediapipeDetector, PersonDetector, parse_mediapipe_output
from .fit import FitConfig, FitResult, fit_poses
from .pipeline import NoPersonError, format_report, prepare_video
from .video import VideoError, read_video

__all__ = ["DetectorError", "Detections", "FitConfig", "FitResult", "MediapipeDetector", "NoPersonError",
           "PersonDetector", "VideoError", "fit_poses", "format_report", "parse_mediapipe_output",
           "prepare_video", "read_video"]
