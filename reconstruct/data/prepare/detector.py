"""Person detectors for ``prepare``: 2D/3D keypoints and a person mask per frame.

``PersonDetector`` is the interface; ``MediapipeDetector`` runs mediapipe's legacy Pose solution
(``mediapipe==0.10.21``, the last release that ships its models in the wheel) in a subprocess, with
the interpreter of a virtualenv that has it (that release declares ``numpy<2``, the project uses
numpy 2): frames go in and results come back as ``.npz`` files (``mediapipe_worker.py``).

Which interpreter runs mediapipe, first match wins: ``--detector-python`` /
``MediapipeDetector(python=...)``, ``$WONDERHUMAN_DETECTOR_PYTHON``, the current interpreter when it
can import mediapipe, the project's ``.venv-video/bin/python`` (``bash scripts/bootstrap.sh video``).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
import threading
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .hand_crops import NUM_HAND_LANDMARKS
from .keypoints import LANDMARK_NAMES, NUM_LANDMARKS

WORKER = Path(__file__).with_name("mediapipe_worker.py")
PROJECT_ROOT = Path(__file__).resolve().parents[3]
VIDEO_VENV = PROJECT_ROOT / ".venv-video"
MEDIAPIPE_VERSION = "0.10.21"
INSTALL_HINT = ("install it with `bash scripts/bootstrap.sh video` (creates .venv-video with "
                f"mediapipe=={MEDIAPIPE_VERSION}) or pass --detector-python PATH of an interpreter that has it")


class DetectorError(RuntimeError):
    """The detector could not run (not installed, crashed, wrong output)."""


@dataclass
class Detections:
    """Per-frame detector output for T frames of W x H pixels.

    keypoints (T,33,2) pixel coordinates of mediapipe's landmarks (``keypoints.LANDMARK_NAMES``);
    visibility (T,33) confidence in [0,1]; world (T,33,3) or None: metric 3D landmarks, hip-centred,
    in camera-aligned axes (x right, y down, z away from the camera); masks (T,H,W) float32 person
    coverage in [0,1]; found (T,) whether a person was detected (rows of frames without one are 0).
    """

    keypoints: np.ndarray
    visibility: np.ndarray
    world: np.ndarray | None
    masks: np.ndarray
    found: np.ndarray
    source: str = ""
    info: dict = field(default_factory=dict)
    raw_masks: np.ndarray | None = None  # (T,H,W) the segmenter's masks before refinement, if refined
    refine_used: np.ndarray | None = None  # (T,) where the refinement was kept
    # (T,33) bool or None: landmarks an edge of the frame cuts off (past it, or at it with the
    # detector unsure; the pipeline sets the visibility of every landmark at such an edge to 0): the
    # fit holds the limbs that end there straight
    cut: np.ndarray | None = None
    # (T,2,21,2) pixels or None: mediapipe's hand model's 21 landmarks of the person's left and right
    # hand (``hand_crops.py``), where ``hands_found`` (T,2) says it found that hand; None: no hand model ran
    hands: np.ndarray | None = None
    hands_found: np.ndarray | None = None

    def __post_init__(self) -> None:
        T = len(self.found)
        checks = {"keypoints": (self.keypoints, (T, NUM_LANDMARKS, 2)),
                  "visibility": (self.visibility, (T, NUM_LANDMARKS))}
        if self.world is not None:
            checks["world"] = (self.world, (T, NUM_LANDMARKS, 3))
        for name, (arr, shape) in checks.items():
            if arr.shape != shape:
                raise DetectorError(f"detections from {self.source or 'the detector'}: {name} has shape "
                                    f"{arr.shape}, expected {shape}")
            if not np.all(np.isfinite(arr)):
                raise DetectorError(f"detections from {self.source or 'the detector'}: {name} has non-finite values")
        if self.cut is not None and np.shape(self.cut) != (T, NUM_LANDMARKS):
            raise DetectorError(f"detections from {self.source or 'the detector'}: cut has shape "
                                f"{np.shape(self.cut)}, expected {(T, NUM_LANDMARKS)}")
        if (self.hands is None) != (self.hands_found is None):
            raise DetectorError(f"detections from {self.source or 'the detector'}: hands and hands_found come together")
        if self.hands is not None:
            if np.shape(self.hands) != (T, 2, NUM_HAND_LANDMARKS, 2) or np.shape(self.hands_found) != (T, 2):
                raise DetectorError(f"detections from {self.source or 'the detector'}: hands have shape "
                                    f"{np.shape(self.hands)} and hands_found {np.shape(self.hands_found)}, expected "
                                    f"{(T, 2, NUM_HAND_LANDMARKS, 2)} and {(T, 2)}")
            if not np.all(np.isfinite(self.hands)):
                raise DetectorError(f"detections from {self.source or 'the detector'}: hands have non-finite values")
        if self.masks.ndim != 3 or self.masks.shape[0] != T:
            raise DetectorError(f"detections from {self.source or 'the detector'}: masks have shape "
                                f"{self.masks.shape}, expected ({T}, H, W)")

    @property
    def num_frames(self) -> int:
        return len(self.found)

    @property
    def height(self) -> int:
        return int(self.masks.shape[1])

    @property
    def width(self) -> int:
        return int(self.masks.shape[2])

    @staticmethod
    def landmark_index(name: str) -> int:
        return LANDMARK_NAMES.index(name)

    def select(self, keep: np.ndarray) -> "Detections":
        keep = np.asarray(keep)
        return Detections(self.keypoints[keep], self.visibility[keep], None if self.world is None else self.world[keep],
                          self.masks[keep], self.found[keep], self.source, dict(self.info),
                          None if self.raw_masks is None else self.raw_masks[keep],
                          None if self.refine_used is None else self.refine_used[keep],
                          None if self.cut is None else self.cut[keep],
                          None if self.hands is None else self.hands[keep],
                          None if self.hands_found is None else self.hands_found[keep])


@dataclass
class PersonCandidate:
    """One person found in one image: box (x0, y0, x1, y1) in pixels, their segmentation (H,W) bool,
    keypoints (33,2) pixels and visibility (33,)."""

    box: tuple[float, float, float, float]
    region: np.ndarray
    keypoints: np.ndarray
    visibility: np.ndarray

    @property
    def center(self) -> tuple[float, float]:
        return 0.5 * (self.box[0] + self.box[2]), 0.5 * (self.box[1] + self.box[3])

    @property
    def height(self) -> float:
        return float(self.box[3] - self.box[1])


class PersonDetector(ABC):
    name: str = "detector"
    # called as progress(stage, done, total) while frames are worked through, where the detector can
    # tell (``prepare_video`` sets it to log lines); None: nothing is reported
    progress = None

    @abstractmethod
    def detect(self, frames: np.ndarray) -> Detections:
        """Detections for frames (T,H,W,3) uint8 RGB."""

    def find_people(self, frames: np.ndarray) -> list[list[PersonCandidate]] | None:
        """Everyone in each of the frames (T,H,W,3) uint8, or None when the detector cannot tell people
        apart (then the whole frame is taken as one person's)."""
        return None

    def describe(self) -> dict:
        return {"name": self.name}


def parse_mediapipe_output(path: str | os.PathLike, width: int, height: int) -> Detections:
    """Detections from the worker's ``.npz`` (normalised landmarks -> pixels, 8-bit masks -> [0,1])."""
    path = Path(path)
    try:
        z = np.load(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable file
        raise DetectorError(f"{path}: the mediapipe worker's output cannot be read: {exc}") from exc
    with z:
        missing = {"found", "landmarks", "masks"} - set(z.files)
        if missing:
            raise DetectorError(f"{path}: the mediapipe worker's output lacks {sorted(missing)}; found {z.files}")
        found = z["found"].astype(bool)
        lm = z["landmarks"].astype(np.float64)
        world = z["world"].astype(np.float64) if "world" in z.files else None
        masks = z["masks"]
        version = str(z["version"]) if "version" in z.files else "unknown"
    T = len(found)
    if lm.shape != (T, NUM_LANDMARKS, 4):
        raise DetectorError(f"{path}: landmarks have shape {lm.shape}, expected ({T}, {NUM_LANDMARKS}, 4)")
    if masks.shape != (T, height, width):
        raise DetectorError(f"{path}: masks have shape {masks.shape}, expected ({T}, {height}, {width})")
    keypoints = lm[..., :2] * np.array([width, height], np.float64)
    visibility = np.clip(lm[..., 3], 0.0, 1.0) * found[:, None]
    if world is not None:
        if world.shape != (T, NUM_LANDMARKS, 4):
            raise DetectorError(f"{path}: world landmarks have shape {world.shape}, expected ({T}, {NUM_LANDMARKS}, 4)")
        world = world[..., :3]
        if not np.any(world[found]):
            world = None  # the worker got no 3D landmarks
    masks = masks.astype(np.float32) / (255.0 if masks.dtype == np.uint8 else 1.0)
    raw = used = hands = hands_found = None
    with np.load(path) as z:
        if "raw_masks" in z.files:
            raw = z["raw_masks"].astype(np.float32) / 255.0
            used = z["refine_used"].astype(bool)
        if "hands" in z.files:
            hands = z["hands"].astype(np.float64)
            hands_found = z["hands_found"].astype(bool) if "hands_found" in z.files else None
            if hands_found is None or hands.shape != (T, 2, NUM_HAND_LANDMARKS, 2):
                raise DetectorError(f"{path}: hands have shape {hands.shape} (expected "
                                    f"({T}, 2, {NUM_HAND_LANDMARKS}, 2)) and hands_found is "
                                    f"{'missing' if hands_found is None else hands_found.shape}")
            hands = hands * np.array([width, height], np.float64)
            hands_found = hands_found & found[:, None]
    return Detections(keypoints, visibility, world, masks, found, source=f"mediapipe {version}",
                      info={"mediapipe_version": version}, raw_masks=raw, refine_used=used, hands=hands,
                      hands_found=hands_found)


def _can_import_mediapipe(python: str) -> tuple[bool, str]:
    try:
        out = subprocess.run([python, "-c", "import mediapipe, sys; sys.stdout.write(mediapipe.__version__)"],
                             capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, str(exc)
    if out.returncode != 0:
        return False, (out.stderr.strip().splitlines() or ["import failed"])[-1]
    return True, out.stdout.strip()


def find_detector_python(explicit: str | os.PathLike | None = None) -> tuple[str, str]:
    """(interpreter, mediapipe version) that runs the worker; raises DetectorError naming what was tried."""
    tried = []
    candidates: list[tuple[str, str]] = []
    if explicit:
        candidates.append((str(explicit), "--detector-python"))
    elif os.environ.get("WONDERHUMAN_DETECTOR_PYTHON"):
        candidates.append((os.environ["WONDERHUMAN_DETECTOR_PYTHON"], "$WONDERHUMAN_DETECTOR_PYTHON"))
    else:
        if importlib.util.find_spec("mediapipe") is not None:
            candidates.append((sys.executable, "this interpreter"))
        candidates.append((str(VIDEO_VENV / "bin" / "python"), ".venv-video"))
    for python, where in candidates:
        if not Path(python).exists():
            tried.append(f"{where}: {python} does not exist")
            continue
        ok, detail = _can_import_mediapipe(python)
        if ok:
            return python, detail
        tried.append(f"{where}: {python} cannot import mediapipe ({detail})")
    raise DetectorError(f"no Python with mediapipe found ({'; '.join(tried)}); {INSTALL_HINT}")


class MediapipeDetector(PersonDetector):
    """mediapipe Pose (landmarks, 3D world landmarks, segmentation) in a subprocess."""

    name = "mediapipe"

    def __init__(self, python: str | os.PathLike | None = None, *, model_complexity: int = 1,
                 timeout_s: float | None = None, refine: bool = True) -> None:
        self.requested_python = python
        self.refine = bool(refine)
        self.model_complexity = int(model_complexity)
        self.timeout_s = timeout_s
        self._python: tuple[str, str] | None = None

    def resolve(self) -> tuple[str, str]:
        if self._python is None:
            self._python = find_detector_python(self.requested_python)
        return self._python

    def describe(self) -> dict:
        python, version = self.resolve()
        return {"name": self.name, "python": python, "mediapipe_version": version,
                "model_complexity": self.model_complexity, "mask_refinement": "grabcut" if self.refine else "none"}

    def _run(self, frames: np.ndarray, extra: list[str], parse):
        python, _ = self.resolve()
        if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
            raise ValueError(f"MediapipeDetector: expected frames (T,H,W,3) uint8, found {frames.shape} {frames.dtype}")
        T = frames.shape[0]
        with tempfile.TemporaryDirectory(prefix="wonderhuman-mediapipe-") as tmp:
            inp, out = Path(tmp) / "frames.npz", Path(tmp) / "detections.npz"
            np.savez(inp, images=frames)
            env = {**os.environ, "GLOG_minloglevel": "2", "TF_CPP_MIN_LOG_LEVEL": "2"}
            env.pop("PYTHONPATH", None)  # the worker must not see this venv's packages (numpy 2)
            err_path = Path(tmp) / "stderr.txt"
            with open(err_path, "w") as err:
                proc = subprocess.Popen([python, str(WORKER), str(inp), str(out), "--progress",
                                         "--model-complexity", str(self.model_complexity), *extra],
                                        stdout=subprocess.PIPE, stderr=err, text=True, env=env)
                timer, killed = None, threading.Event()
                if self.timeout_s is not None:
                    timer = threading.Timer(self.timeout_s, lambda: (killed.set(), proc.kill()))
                    timer.start()
                try:
                    for line in proc.stdout:  # 'progress STAGE DONE TOTAL' lines as frames are done
                        parts = line.split()
                        if len(parts) == 4 and parts[0] == "progress" and self.progress is not None:
                            self.progress(parts[1], int(parts[2]), int(parts[3]))
                    proc.wait()
                finally:
                    if timer is not None:
                        timer.cancel()
                    if proc.poll() is None:
                        proc.kill()
                        proc.wait()
            if killed.is_set():
                raise DetectorError(f"the mediapipe worker ({python}) did not finish {T} frames within "
                                    f"{self.timeout_s} s")
            if proc.returncode != 0 or not out.is_file():
                tail = "\n".join(err_path.read_text(errors="replace").strip().splitlines()[-8:])
                raise DetectorError(f"the mediapipe worker ({python} {WORKER.name}) failed with exit code "
                                    f"{proc.returncode}:\n{tail}")
            return parse(out)

    def detect(self, frames: np.ndarray) -> Detections:
        H, W = frames.shape[1:3]
        return self._run(frames, ["--refine"] if self.refine else [], lambda p: parse_mediapipe_output(p, W, H))

    def find_people(self, frames: np.ndarray) -> list[list[PersonCandidate]]:
        H, W = frames.shape[1:3]
        return self._run(frames, ["--mode", "people"], lambda p: parse_people_output(p, W, H))


def parse_people_output(path: str | os.PathLike, width: int, height: int) -> list[list[PersonCandidate]]:
    """The worker's ``--mode people`` output -> per frame, the people found."""
    path = Path(path)
    try:
        with np.load(path) as z:
            count, people, regions = z["count"], z["people"], z["regions"]
    except Exception as exc:  # noqa: BLE001 - any unreadable file
        raise DetectorError(f"{path}: the mediapipe worker's people output cannot be read: {exc}") from exc
    out = []
    for i in range(len(count)):
        frame = []
        for p in range(int(count[i])):
            lm = people[i, p].astype(np.float64)
            kp = lm[:, :2] * np.array([width, height])
            region = regions[i, p] > 127
            frame.append(PersonCandidate(_person_box(kp, lm[:, 3], region), region, kp, np.clip(lm[:, 3], 0, 1)))
        out.append(frame)
    return out


def _person_box(kp: np.ndarray, vis: np.ndarray, region: np.ndarray) -> tuple[float, float, float, float]:
    """A person's box: their landmarks (grown for head and feet) joined with their segmentation."""
    seen = vis >= 0.3
    pts = kp[seen] if seen.sum() >= 4 else kp
    x0, y0 = pts.min(0)
    x1, y1 = pts.max(0)
    h = max(y1 - y0, 1.0)
    x0, y0, x1, y1 = x0 - 0.1 * h, y0 - 0.2 * h, x1 + 0.1 * h, y1 + 0.06 * h
    if region.any():
        ys, xs = np.nonzero(region)
        x0, y0 = min(x0, xs.min()), min(y0, ys.min())
        x1, y1 = max(x1, xs.max() + 1), max(y1, ys.max() + 1)
    H, W = region.shape
    return float(max(0, x0)), float(max(0, y0)), float(min(W, x1)), float(min(H, y1))
