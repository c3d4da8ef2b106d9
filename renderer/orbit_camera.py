"""Orbit / trackball viewer camera in the project's conventions.

World Z is up and the avatar faces -Y (DESIGN.md). The eye sits at
``orbit_position(azimuth, elevation, distance, target)`` (``reconstruct.camera``): azimuth 0 is
in front of the avatar (on -Y), +90 on its left side (+X), 180 behind; elevation is measured up
from the horizontal. The camera looks at ``target`` with no roll (image up = world +Z projected).

Intrinsics come either from a vertical field of view or from a reference ``Camera`` (e.g. a
training camera) whose K is rescaled to the requested image size keeping square pixels: the
focal lengths and principal point scale by ``height / ref.height`` and the extra (or missing)
width is split evenly left and right, so a window with the reference's aspect ratio gets exactly
``ref.scaled(width, height)``.

``snap_to(camera)`` shows exactly that camera (its R, t and K, even with roll) until the next
orbit / zoom / pan, which continue from the closest orbit parameters (target on the camera's
optical axis at the current orbit distance or the distance to ``pivot``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from reconstruct.camera import Camera, orbit_position


def _fit_intrinsics(ref: Camera, width: int, height: int) -> np.ndarray:
    s = height / ref.height
    K = ref.K.copy()
    K[0, 0] *= s
    K[1, 1] *= s
    K[0, 1] *= s
    K[0, 2] = ref.cx * s + 0.5 * (width - ref.width * s)
    K[1, 2] = ref.cy * s
    return K


@dataclass
class OrbitCamera:
    azimuth: float = 0.0  # degrees
    elevation: float = 0.0  # degrees, clamped to +-max_elevation
    distance: float = 3.0  # metres from target
    target: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.9]))
    fov_y_deg: float = 30.0
    near: float = 0.01
    far: float = 100.0
    intrinsics: Camera | None = None  # reference camera for K (None: from fov_y_deg)
    min_distance: float = 0.05
    max_distance: float = 1e3
    max_elevation: float = 89.0
    _exact: Camera | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.target = np.asarray(self.target, np.float64).reshape(3).copy()
        self._clamp()

    # ----- state --------------------------------------------------------------------------
    def _clamp(self) -> None:
        if not all(math.isfinite(v) for v in (self.azimuth, self.elevation, self.distance)) or not np.all(
                np.isfinite(self.target)):
            raise ValueError(f"OrbitCamera: non-finite state az={self.azimuth} el={self.elevation} "
                             f"d={self.distance} target={self.target}")
        self.azimuth = (self.azimuth + 180.0) % 360.0 - 180.0
        self.elevation = float(np.clip(self.elevation, -self.max_elevation, self.max_elevation))
        self.distance = float(np.clip(self.distance, self.min_distance, self.max_distance))

    @property
    def eye(self) -> np.ndarray:
        return orbit_position(self.azimuth, self.elevation, self.distance, self.target)

    @property
    def is_snapped(self) -> bool:
        return self._exact is not None

    def _leave_snap(self) -> None:
        self._exact = None

    # ----- interaction ----------------------------------------------------------------------
    def orbit(self, d_azimuth: float, d_elevation: float) -> None:
        """Rotate around the target by degrees (positive azimuth: towards the avatar's left)."""
        self._leave_snap()
        self.azimuth += float(d_azimuth)
        self.elevation += float(d_elevation)
        self._clamp()

    def zoom(self, factor: float) -> None:
        """Multiply the distance by ``factor`` (< 1 moves closer)."""
        if not (factor > 0 and math.isfinite(factor)):
            raise ValueError(f"OrbitCamera.zoom: factor must be positive and finite, found {factor}")
        self._leave_snap()
        self.distance *= float(factor)
        self._clamp()

    def pan(self, dx: float, dy: float) -> None:
        """Move target and eye in the image plane by fractions of the view height at the target
        (dx > 0: the scene moves right on screen; dy > 0: it moves down)."""
        cam = self.to_camera(64, 64)
        self._leave_snap()
        span = 2.0 * self.distance * math.tan(math.radians(self._fov_y()) / 2.0)
        right, down = cam.R[0], cam.R[1]
        self.target = self.target - right * (dx * span) - down * (dy * span)
        self._clamp()

    def drag(self, dx_px: float, dy_px: float, button: str = "left", viewport_height: int = 512,
             degrees_per_pixel: float = 0.3) -> None:
        """Mouse drag in pixels: left = orbit (the avatar turns as if grabbed: dragging right spins it
        to the right, dragging down tips its top towards the viewer), right/middle = pan."""
        if button == "left":
            self.orbit(-dx_px * degrees_per_pixel, dy_px * degrees_per_pixel)
        else:
            self.pan(dx_px / max(1, viewport_height), dy_px / max(1, viewport_height))

    def scroll(self, steps: float, per_step: float = 0.9) -> None:
        """Mouse wheel: each step up moves closer by ``per_step``."""
        self.zoom(per_step ** float(steps))

    def look_at_bounds(self, points: np.ndarray, margin: float = 1.15) -> None:
        """Centre the target on the bounding box of ``points`` (finite rows) and back off so it fits."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        if p.shape[0] == 0:
            return
        self._leave_snap()
        lo, hi = p.min(0), p.max(0)
        self.target = 0.5 * (lo + hi)
        radius = 0.5 * float(np.linalg.norm(hi - lo))
        self.distance = max(self.min_distance, margin * radius / math.sin(math.radians(self._fov_y()) / 2.0))
        self._clamp()

    # ----- cameras ------------------------------------------------------------------------------
    def _fov_y(self) -> float:
        if self.intrinsics is not None:
            return math.degrees(self.intrinsics.fov_y)
        return self.fov_y_deg

    def intrinsic_matrix(self, width: int, height: int) -> np.ndarray:
        if self.intrinsics is not None:
            return _fit_intrinsics(self.intrinsics, width, height)
        return Camera.intrinsics(width, height, self.fov_y_deg)

    def to_camera(self, width: int, height: int, name: str = "orbit") -> Camera:
        """The ``Camera`` for an image of ``width x height`` pixels."""
        if self._exact is not None:
            ex = self._exact
            return Camera(_fit_intrinsics(ex, width, height), ex.R, ex.t, width, height, ex.near, ex.far,
                          ex.name or name, dict(ex.meta))
        return Camera.look_at(self.eye, self.target, width=width, height=height,
                              K=self.intrinsic_matrix(width, height), near=self.near, far=self.far, name=name,
                              meta={"azimuth": self.azimuth, "elevation": self.elevation,
                                    "distance": self.distance})

    def snap_to(self, camera: Camera, pivot=None, use_intrinsics: bool = True) -> None:
        """Show ``camera`` exactly; subsequent orbiting pivots around a point on its optical axis
        (at the distance of ``pivot`` along the axis if given, else the current distance)."""
        c = camera.center
        fwd = camera.forward
        if pivot is not None:
            d = float(np.dot(np.asarray(pivot, np.float64) - c, fwd))
            if not (d > self.min_distance):
                d = self.distance
        else:
            d = self.distance
        self.target = c + fwd * d
        off = c - self.target
        dist = float(np.linalg.norm(off))
        self.distance = dist
        self.elevation = math.degrees(math.asin(max(-1.0, min(1.0, off[2] / dist))))
        self.azimuth = math.degrees(math.atan2(off[0], -off[1]))
        if use_intrinsics:
            self.intrinsics = camera
        self.near, self.far = camera.near, camera.far
        self._clamp()
        self._exact = camera
