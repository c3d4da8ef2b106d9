"""Coverage of an avatar in novel poses, against a synthetic scene's ground truth in those poses.

The held-out views of ``evaluate.py`` show the person in the video's own poses. What a user does
with an avatar is animate it (``export --novel walk``, motion files), and that is where a garment
layer can tear: the legs swing further than in the video and cloth between them may open. A
synthetic scene knows its person in any pose (the body and its loose garment, skinned by the
benchmark's own weights: ``generator.render_truth_masks``), so coverage can be scored there:

* the novel sequence (``novel_poses``: a walk cycle by default) placed on the video's first frame,
  seen from the evaluation orbit (the scene's distance and elevation) at ``NOVEL_AZIMUTHS``;
* per view, the hole fraction (``evaluate.hole_fraction``: ground-truth pixels 2 px inside the
  silhouette with rendered alpha < 0.9), the alpha IoU, and -- in a loose-clothing scene -- the
  hole fraction inside the garment's own silhouette (``garment_hole_fraction``: the gaps the issue
  asks about, cloth opening between the legs);
* their means over the views (``novel_hole_fraction``, ``novel_alpha_iou``,
  ``novel_garment_hole_fraction``) and the worst view's holes (``novel_hole_fraction_max``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..avatar.state import AvatarState
from ..body.novel_poses import novel_pose_sequence
from ..body.pose import BodyPose
from ..camera import Camera
from ..data.scene import Scene
from .evaluate import alpha_iou, hole_fraction, upsample
from .render import render_avatar

NOVEL_AZIMUTHS = (0.0, 90.0, 180.0, 270.0)  # front (the video's side), both sides, the back


@dataclass(frozen=True)
class NovelView:
    """One ground-truth view of a novel pose: ``index`` into the sequence, the camera's azimuth
    round the person (0 = the video's camera side), the (H,W) float masks of the whole person and
    of the garment alone (None in a tight scene)."""

    index: int
    azimuth_deg: float
    pose: BodyPose
    camera: Camera
    mask: np.ndarray
    garment_mask: np.ndarray | None


def novel_views(scene: Scene, body, name: str = "walk", frames: int = 8,
                azimuths=NOVEL_AZIMUTHS) -> list[NovelView]:
    """Ground truth of the novel sequence ``name`` (``frames`` poses of ``body``, the scene's body,
    placed on the video's first frame) at each of ``azimuths`` on the evaluation orbit."""
    from ..data.synthetic.generator import render_truth_masks, synthetic_config_of

    config = synthetic_config_of(scene)
    if frames < 2:
        raise ValueError(f"novel-pose coverage needs at least 2 frames, found {frames}")
    target = np.asarray(scene.meta["target"], np.float64)
    poses = novel_pose_sequence(body, name, frames, base=scene.frames[0].pose)
    cams = [Camera.orbit(float(az), config.elevation_deg, config.distance, target, name=f"novel_az{az:03.0f}",
                         width=config.image_size, height=config.image_size, fov_y_deg=config.fov_y_deg)
            for az in azimuths]
    pairs = [(i, c) for i in range(len(poses)) for c in range(len(cams))]
    masks, garment_masks = render_truth_masks(scene, [poses[i] for i, _ in pairs], [cams[c] for _, c in pairs])
    return [NovelView(i, float(azimuths[c]), poses[i], cams[c], masks[k],
                      None if garment_masks is None else garment_masks[k])
            for k, (i, c) in enumerate(pairs)]


def _mean(rows: list[dict], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return float(np.mean(vals)) if vals else None


@torch.no_grad()
def novel_coverage(state: AvatarState, views: list[NovelView], background: torch.Tensor, *,
                   scale: int = 1) -> tuple[list[dict], dict]:
    """Per view and summary coverage of the avatar ``state`` posed at each view's pose, rendered at
    ``scale`` x the view's resolution (masks upsampled bilinearly, thresholded at 0.5)."""
    scale = int(scale)
    if scale < 1:
        raise ValueError(f"evaluation scale must be a positive integer, found {scale}")
    device = background.device
    posed_at: dict[int, object] = {}
    rows = []
    for v in views:
        if v.index not in posed_at:
            posed_at[v.index] = state.posed_at(v.pose)
        cam = v.camera if scale == 1 else v.camera.scaled(v.camera.width * scale, v.camera.height * scale)
        alpha = render_avatar(posed_at[v.index], cam, background, normals=False).alpha
        mask = upsample(v.mask, scale, device) > 0.5
        row = {"index": v.index, "azimuth_deg": v.azimuth_deg, "hole_fraction": hole_fraction(alpha, mask),
               "alpha_iou": alpha_iou(alpha, mask), "garment_hole_fraction": None}
        if v.garment_mask is not None:
            row["garment_hole_fraction"] = hole_fraction(alpha, upsample(v.garment_mask, scale, device) > 0.5)
        rows.append(row)
    holes = [r["hole_fraction"] for r in rows if r["hole_fraction"] is not None]
    summary = {"novel_hole_fraction": _mean(rows, "hole_fraction"), "novel_alpha_iou": _mean(rows, "alpha_iou"),
               "novel_garment_hole_fraction": _mean(rows, "garment_hole_fraction"),
               "novel_hole_fraction_max": max(holes) if holes else None}
    for az in sorted({r["azimuth_deg"] for r in rows}):
        summary[f"novel_hole_fraction_az{az:03.0f}"] = _mean([r for r in rows if r["azimuth_deg"] == az],
                                                             "hole_fraction")
    return rows, summary
