"""Video, image or image folder -> scene folder: frames, person masks, keypoints (mediapipe), fitted body
shape, poses and camera.

See ``pipeline.prepare_video`` and docs/prepare.md."""

from .crop import Crop, person_crop
from .detector import (DetectorError, Detections, MediapipeDetector, PersonCandidate, PersonDetector,
                       parse_mediapipe_output)
from .fit import CameraGuess, FitConfig, FitResult, fit_poses
from .inputs import InputError, read_input
from .people import PersonChoiceError, choose_person
from .pipeline import NoPersonError, format_report, prepare, prepare_video
from .video import VideoError, read_video

__all__ = ["CameraGuess", "Crop", "DetectorError", "Detections", "FitConfig", "FitResult", "InputError",
           "MediapipeDetector", "NoPersonError", "PersonCandidate", "PersonChoiceError", "PersonDetector",
           "VideoError", "choose_person", "fit_poses", "format_report", "parse_mediapipe_output", "person_crop",
           "prepare", "prepare_video", "read_input", "read_video"]
