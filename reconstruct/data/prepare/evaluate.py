"""Errors of fitted poses against known poses (synthetic scenes): 3D joints and silhouettes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ...body.base import BodyModel
from ...body.pose import BodyPose
from ...camera import Camera
from .crop import Crop, apply_crop
from .keypoints import EVAL_JOINTS


def camera_space_joints(body: BodyModel, pose: BodyPose, camera: Camera, names=EVAL_JOINTS) -> np.ndarray:
    """(K,3) the named bone heads in ``camera``'s coordinates, minus the mid-hip point (pelvis-aligned)."""
    joints = body.posed_joints(pose).numpy()
    ids = [body.bone_labels.index(n) for n in names]
    pc = camera.world_to_camera(joints)
    hips = camera.world_to_camera(joints[[body.bone_labels.index("upperleg01.L"), body.bone_labels.index("upperleg01.R")]])
    return pc[ids] - hips.mean(0)


def joint_errors(fit_body: BodyModel, fit_poses: list[BodyPose], fit_camera: Camera, true_body: BodyModel,
                 true_poses: list[BodyPose], true_camera: Camera, *, scale_align: bool = False) -> np.ndarray:
    """(T,K) distances in metres between fitted and true limb joints (``EVAL_JOINTS``), each expressed
    in its own camera's coordinates with the mid-hip point subtracted: the error of the pose as seen
    from the camera, independent of the depth/focal ambiguity and of where the body stands.
    ``scale_align``: the fitted joints are first scaled by the least-squares factor per frame (as in
    N-MPJPE), which removes the body-size difference monocular video cannot resolve."""
    out = []
    for p, q in zip(fit_poses, true_poses):
        a = camera_space_joints(fit_body, p, fit_camera)
        b = camera_space_joints(true_body, q, true_camera)
        if scale_align:
            a = a * float((a * b).sum() / max((a * a).sum(), 1e-12))
        out.append(np.linalg.norm(a - b, axis=1))
    return np.stack(out)


def mask_iou(a: np.ndarray, b: np.ndarray, threshold: float = 0.5) -> float:
    a, b = a > threshold, b > threshold
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def prepared_crop(scene_folder: Path) -> Crop:
    """The crop ``prepare`` cut from the source video into ``scene_folder`` (its prepare_report.json)."""
    report = Path(scene_folder) / "prepare_report.json"
    try:
        return Crop(**json.loads(report.read_text())["crop"])
    except (OSError, KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{report}: expected prepare's report with a 'crop' entry ({err})") from err


def in_prepared_frame(image: np.ndarray, crop: Crop) -> np.ndarray:
    """(H,W) float: an (h,w) map of the source video's frame (a true mask, a true silhouette) cropped
    and resized as ``prepare`` cropped that video (``crop``: ``prepared_crop`` of its scene folder),
    bilinear. The map is of the frame as ``prepare`` read it: turned as the report's ``turned_deg``
    says when the person did not stand in the frames as stored."""
    return apply_crop(np.asarray(image, np.float32)[None], crop, resample="bilinear")[0]
