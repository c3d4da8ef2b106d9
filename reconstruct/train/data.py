"""What training compares against: the training frames (the video less its held-out validation
frames) cropped to the body's box (plus a margin), composited on the training background, with
their cropped cameras. Prepared once per run and shared by every stage."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ..camera import Camera
from ..data.scene import Scene
from .evaluate import inner_mask
from .render import crop_camera, mask_box


@dataclass
class FrameTarget:
    camera: Camera  # the frame's camera cropped to ``box``
    image: torch.Tensor  # (h,w,3) over the background
    mask: torch.Tensor  # (h,w)
    normal: torch.Tensor | None  # (h,w,3) camera-space normals stored as 0.5 (n + 1), or None
    box: tuple[int, int, int, int]
    _inner: dict = field(default_factory=dict, repr=False, compare=False)

    def inner_mask(self, inset: int) -> torch.Tensor:
        """(h,w) bool: the pixels at least ``inset`` px inside the mask (``evaluate.inner_mask``),
        eroded once per inset: the mask never changes, and a step asks for it every time."""
        if inset not in self._inner:
            self._inner[inset] = inner_mask(self.mask > 0.5, inset)
        return self._inner[inset]


def composite_on(target: FrameTarget, background: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """The target's image over ``background`` instead of ``current`` (the one it was composited on):
    the person's pixels are kept, the uncovered share (1 - mask) of every pixel changes colour."""
    return target.image + (1 - target.mask[..., None]) * (background - current)


class TrainingData:
    def __init__(self, scene: Scene, background: torch.Tensor, crop_margin: int,
                 frames: list[int] | None = None) -> None:
        self.scene = scene
        self.background = background
        self.use_normals = scene.has_normals
        self.frames = list(range(len(scene.frames))) if frames is None else list(frames)  # the training frames
        if not self.frames:
            raise ValueError(f"scene {scene.name}: no frame left to train on")
        self.targets = {i: self._prepare(i, crop_margin) for i in self.frames}

    def __len__(self) -> int:
        return len(self.frames)

    def _prepare(self, i: int, margin: int) -> FrameTarget:
        f = self.scene.frames[i]
        if f.mask.max() <= 0:
            raise ValueError(f"scene {self.scene.name}: frame {i} has an empty mask (no person to learn from)")
        box = mask_box(f.mask, margin)
        x0, y0, x1, y1 = box
        device = self.background.device
        as_t = lambda a: torch.as_tensor(np.ascontiguousarray(a[y0:y1, x0:x1]), dtype=torch.float32, device=device)
        mask = as_t(f.mask)
        image = as_t(f.image) + (1 - mask[..., None]) * self.background
        normal = as_t(f.normal) if f.normal is not None else None
        return FrameTarget(crop_camera(f.camera, box), image, mask, normal, box)
