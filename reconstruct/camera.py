"""Pinhole camera shared by the data loaders, the training rasterizer and the GL renderer.

Conventions (DESIGN.md, "Coordinates"):
- World space is the body model's: metres, +Z up; the avatar faces -Y in its canonical pose.
- Cameras follow OpenCV: camera +X right, +Y down, +Z forward (looking direction).
  A world point maps to camera space as ``x_cam = R @ x_world + t``.
- Pixel coordinates are continuous with the centre of pixel (row i, column j) at
  ``(j + 0.5, i + 0.5)``; ``u = fx * x/z + cx``, ``v = fy * y/z + cy``. A centred camera has
  ``cx = width / 2``. This is the convention of 3DGS and gsplat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def _as_matrix(value, shape, name) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"Camera.{name}: expected shape {shape}, found {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"Camera.{name}: contains non-finite values: {arr.tolist()}")
    return arr


@dataclass(frozen=True)
class Camera:
    """Intrinsics ``K`` (3x3, pixels), world-to-camera rotation ``R`` and translation ``t``."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    near: float = 0.01
    far: float = 100.0
    name: str = ""
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", _as_matrix(self.K, (3, 3), "K"))
        object.__setattr__(self, "R", _as_matrix(self.R, (3, 3), "R"))
        object.__setattr__(self, "t", _as_matrix(self.t, (3,), "t"))
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"Camera {self.name!r}: image size must be positive, found {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if not (0.0 < self.near < self.far):
            raise ValueError(f"Camera {self.name!r}: need 0 < near < far, found near={self.near}, far={self.far}")
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise ValueError(f"Camera {self.name!r}: focal lengths must be positive, found K={self.K.tolist()}")
        orth = self.R @ self.R.T
        if not np.allclose(orth, np.eye(3), atol=1e-5) or np.linalg.det(self.R) < 0:
            raise ValueError(f"Camera {self.name!r}: R is not a rotation matrix (R R^T = {orth.round(4).tolist()})")

    # ----- derived quantities -------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> np.ndarray:
        """Viewing direction (camera +Z) in world coordinates."""
        return self.R[2].copy()

    @property
    def viewmat(self) -> np.ndarray:
        """4x4 world-to-camera matrix (OpenCV axes)."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    @property
    def fov_y(self) -> float:
        return 2.0 * math.atan(self.height / (2.0 * self.fy))

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, np.float64) @ self.R.T + self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N,2) and camera depth (N,) of world points."""
        pc = self.world_to_camera(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], axis=1)
        return uv, z

    def gl_projection(self) -> np.ndarray:
        """4x4 OpenGL clip matrix for camera-space points in *OpenGL* axes (x right, y up, -z forward),
        matching K exactly (including an off-centre principal point), row-major."""
        w, h, n, f = self.width, self.height, self.near, self.far
        P = np.zeros((4, 4))
        P[0, 0] = 2.0 * self.fx / w
        P[1, 1] = 2.0 * self.fy / h
        P[0, 2] = 1.0 - 2.0 * self.cx / w
        P[1, 2] = 2.0 * self.cy / h - 1.0
        P[2, 2] = -(f + n) / (f - n)
        P[2, 3] = -2.0 * f * n / (f - n)
        P[3, 2] = -1.0
        return P

    def gl_view(self) -> np.ndarray:
        """4x4 world-to-camera matrix in OpenGL axes (flip Y and Z of the OpenCV camera)."""
        flip = np.diag([1.0, -1.0, -1.0, 1.0])
        return flip @ self.viewmat

    # ----- construction ------------------------------------------------------------------
    def scaled(self, width: int, height: int) -> "Camera":
        """Same camera for another image size (intrinsics scaled per axis)."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0] *= sx
        K[1] *= sy
        return Camera(K, self.R, self.t, width, height, self.near, self.far, self.name, dict(self.meta))

    @staticmethod
    def intrinsics(width: int, height: int, fov_y_deg: float) -> np.ndarray:
        fy = height / (2.0 * math.tan(math.radians(fov_y_deg) / 2.0))
        return np.array([[fy, 0.0, width / 2.0], [0.0, fy, height / 2.0], [0.0, 0.0, 1.0]])

    @classmethod
    def look_at(
        cls,
        eye,
        target,
        up=(0.0, 0.0, 1.0),
        *,
        width: int = 512,
        height: int = 512,
        fov_y_deg: float = 30.0,
        K: np.ndarray | None = None,
        near: float = 0.01,
        far: float = 100.0,
        name: str = "",
        meta: dict | None = None,
    ) -> "Camera":
        eye = np.asarray(eye, np.float64)
        target = np.asarray(target, np.float64)
        up = np.asarray(up, np.float64)
        fwd = target - eye
        if np.linalg.norm(fwd) < 1e-12:
            raise ValueError(f"Camera.look_at {name!r}: eye and target coincide at {eye.tolist()}")
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, up)
        if np.linalg.norm(right) < 1e-8:  # looking along up: pick any perpendicular
            alt = np.array([0.0, 1.0, 0.0]) if abs(fwd[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
            right = np.cross(fwd, alt)
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        R = np.stack([right, down, fwd])
        t = -R @ eye
        if K is None:
            K = cls.intrinsics(width, height, fov_y_deg)
        return cls(K, R, t, width, height, near, far, name, dict(meta or {}))

    @classmethod
    def orbit(
        cls,
        azimuth_deg: float,
        elevation_deg: float,
        distance: float,
        target=(0.0, 0.0, 0.0),
        **kwargs,
    ) -> "Camera":
        """Camera on a sphere around ``target`` looking at it (see ``orbit_position``)."""
        eye = orbit_position(azimuth_deg, elevation_deg, distance, target)
        return cls.look_at(eye, target, **kwargs)

    def to_dict(self) -> dict:
        return {
            "K": self.K.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "width": self.width,
            "height": self.height,
            "near": self.near,
            "far": self.far,
            "name": self.name,
            "meta": self.meta,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        missing = [k for k in ("K", "R", "t", "width", "height") if k not in d]
        if missing:
            raise ValueError(f"camera entry is missing keys {missing}; found keys {sorted(d)}")
        return cls(
            np.asarray(d["K"]), np.asarray(d["R"]), np.asarray(d["t"]), int(d["width"]), int(d["height"]),
            float(d.get("near", 0.01)), float(d.get("far", 100.0)), str(d.get("name", "")), dict(d.get("meta", {})),
        )


def orbit_position(azimuth_deg: float, elevation_deg: float, distance: float, target=(0.0, 0.0, 0.0)) -> np.ndarray:
    """World position at the given azimuth/elevation around ``target`` (Z up).

    Azimuth 0 places the eye on -Y, in front of an avatar facing -Y; +90 places it on +X, which
    is the avatar's left side; 180 is behind it. Elevation is measured up from the horizontal."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    offset = np.array([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)])
    return np.asarray(target, np.float64) + distance * offset


def angle_between_views(a: Camera, b: Camera, target) -> float:
    """Angle in degrees between the directions from ``target`` to the two camera centres."""
    target = np.asarray(target, np.float64)
    da = a.center - target
    db = b.center - target
    cos = float(np.dot(da, db) / (np.linalg.norm(da) * np.linalg.norm(db)))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))
