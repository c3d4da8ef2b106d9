"""The scene every loader produces: frames of one monocular video, evaluation views, the body."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..body.base import BodyModel
from ..body.pose import BodyPose
from ..body.spec import BodySpec
from ..camera import Camera


@dataclass
class Frame:
    """One video frame: image (H,W,3) float32 in [0,1] over a black background, mask (H,W)
    float32 coverage, its camera and body pose, and an optional camera-space normal map."""

    index: int
    image: np.ndarray
    mask: np.ndarray
    camera: Camera
    pose: BodyPose
    normal: np.ndarray | None = None
    time: float = 0.0

    def __post_init__(self) -> None:
        H, W = self.camera.height, self.camera.width
        if self.image.shape != (H, W, 3):
            raise ValueError(f"frame {self.index}: image is {self.image.shape}, camera expects ({H}, {W}, 3)")
        if self.mask.shape != (H, W):
            raise ValueError(f"frame {self.index}: mask is {self.mask.shape}, camera expects ({H}, {W})")
        if self.normal is not None and self.normal.shape != (H, W, 3):
            raise ValueError(f"frame {self.index}: normal map is {self.normal.shape}, expected ({H}, {W}, 3)")


@dataclass
class EvalView:
    """A held-out view with ground truth: the body in the pose of ``frame_index`` seen by
    ``camera``. ``seen`` marks views close to the training camera."""

    camera: Camera
    frame_index: int
    image: np.ndarray
    mask: np.ndarray
    normal: np.ndarray | None
    seen: bool
    azimuth_deg: float
    front_leak: object | None = None  # reconstruct.metrics.front_leak.FrontLeakInfo (unseen views of synthetic scenes)


@dataclass
class Scene:
    name: str
    body: BodySpec
    frames: list[Frame]
    eval_views: list[EvalView] = field(default_factory=list)
    fps: float = 20.0
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.frames:
            raise ValueError(f"scene {self.name!r} has no frames")

    @property
    def image_size(self) -> tuple[int, int]:
        c = self.frames[0].camera
        return c.width, c.height

    @property
    def has_normals(self) -> bool:
        return all(f.normal is not None for f in self.frames)

    def body_model(self) -> BodyModel:
        return self.body.build()

    def pose(self, frame_index: int) -> BodyPose:
        return self.frames[frame_index].pose

    def summary(self) -> str:
        w, h = self.image_size
        seen = sum(v.seen for v in self.eval_views)
        return (f"scene {self.name}: {len(self.frames)} frames {w}x{h} at {self.fps:g} fps, body {self.body.model}, "
                f"{len(self.eval_views)} evaluation views ({seen} seen, {len(self.eval_views) - seen} unseen), "
                f"normal maps: {'yes' if self.has_normals else 'no'}")
