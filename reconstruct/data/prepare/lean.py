"""How far the fitted body leans when seen from the side: render it from its left (its own facing
direction turned away, so the view is a true profile), take the centre of the head's silhouette (top
12 % of its height) and of the feet's (bottom 8 %), and measure the line between them against the
vertical. A person standing upright gives ~0; a body whose legs swing back gives the lean seen in the
avatar."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...body.base import BodyModel
from ...body.pose import BodyPose
from ...camera import Camera
from .silhouette import mesh_silhouette


@dataclass
class SideView:
    silhouette: np.ndarray  # (H,W) bool, the body seen from its left (it faces the image's left)
    lean_deg: float  # signed: > 0 the head is ahead of the feet (toward where the body faces)
    head: tuple[float, float]  # silhouette centres (x, y) in pixels
    feet: tuple[float, float]


def _yaw(pose: BodyPose) -> float:
    from scipy.spatial.transform import Rotation

    fwd = Rotation.from_rotvec(pose.global_orient).apply([0.0, -1.0, 0.0])  # the body faces -Y at rest
    return math.atan2(fwd[0], -fwd[1])


def side_view(body: BodyModel, pose: BodyPose, size: int = 160) -> SideView:
    verts = body.posed_vertices(pose).numpy()
    c, s = math.cos(-_yaw(pose)), math.sin(-_yaw(pose))
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    centre = verts.mean(0)
    v = (verts - centre) @ Rz.T  # the body now faces -Y
    extent = float(np.abs(v[:, 1:]).max()) * 1.15
    dist = 30.0
    f = size / 2 * dist / extent
    # camera on +X looking -X (sees the body's left side), Z up: x_cam = +Y, y_cam = -Z, z_cam = -X
    R = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
    t = -R @ np.array([dist, 0.0, 0.0])
    cam = Camera(np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]]), R, t, size, size, name="side",
                 near=1.0, far=100.0)
    sil = mesh_silhouette(v, body.faces.numpy(), cam)
    ys, xs = np.nonzero(sil)
    top, bottom = ys.min(), ys.max()
    h = max(bottom - top, 1)
    head = ys <= top + 0.12 * h
    feet = ys >= bottom - 0.08 * h
    hx, hy = xs[head].mean() + 0.5, ys[head].mean() + 0.5
    fx, fy = xs[feet].mean() + 0.5, ys[feet].mean() + 0.5
    # the body faces -Y = the image's -x: a head left of the feet leans forward
    lean = math.degrees(math.atan2(fx - hx, fy - hy))
    return SideView(sil, lean, (float(hx), float(hy)), (float(fx), float(fy)))
