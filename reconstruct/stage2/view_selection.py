"""View selection (paper Eq. 8-10, Appendix A.2.2): render the visibility map of candidate views
and keep as *unseen* those whose visible share of the foreground is at most the threshold.

Candidates: ``num_azimuths`` cameras evenly around the avatar at elevation 0 and one overhead
view, all looking at the body centre from ``distance`` (the paper's 5 units; here in metres, or
the scene's own camera distance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..camera import Camera
from ..raster import rasterization


@dataclass(frozen=True)
class ViewSelectionConfig:
    num_azimuths: int = 100
    elevation_deg: float = 0.0
    overhead_elevation_deg: float = 80.0  # "one overhead view with a high elevation angle"
    distance: float = 5.0
    fov_y_deg: float = 30.0
    size: int = 128  # visibility maps need no detail
    threshold: float = 0.5  # unseen when VR / FR <= threshold (Eq. 10)

    def __post_init__(self) -> None:
        if not 0.0 < self.threshold < 1.0:
            raise ValueError(f"view selection threshold must be in (0, 1), found {self.threshold}")
        if self.num_azimuths < 1:
            raise ValueError(f"view selection needs at least one azimuth, found {self.num_azimuths}")


@dataclass
class CandidateView:
    camera: Camera
    azimuth_deg: float
    elevation_deg: float
    visibility: float  # VR / FR (Eq. 9)
    unseen: bool  # Eq. 10: visibility <= threshold


def candidate_cameras(target, config: ViewSelectionConfig, azimuth_offset_deg: float = 0.0,
                      ) -> list[tuple[Camera, float, float]]:
    """(camera, azimuth, elevation) of every candidate. Azimuths are relative to
    ``azimuth_offset_deg`` (the reference view's own azimuth: 0 = the reference view's side)."""
    kw = dict(width=config.size, height=config.size, fov_y_deg=config.fov_y_deg)
    views = [(Camera.orbit(az + azimuth_offset_deg, config.elevation_deg, config.distance, target,
                           name=f"select_az{az:05.1f}", **kw), az, config.elevation_deg)
             for az in np.linspace(0.0, 360.0, config.num_azimuths, endpoint=False)]
    views.append((Camera.orbit(azimuth_offset_deg, config.overhead_elevation_deg, config.distance, target,
                               name="select_overhead", **kw), 0.0, config.overhead_elevation_deg))
    return views


def visibility_ratio(means, quats, scales, opacities, seen: torch.Tensor, camera: Camera) -> tuple[float, torch.Tensor]:
    """Eq. 8-9: the visibility map I_v (Gaussians carry psi = 1 if seen else 0) and VR(I_v) / FR(I_v),
    the visible share of the rendered foreground (alpha-weighted)."""
    psi = seen.to(device=means.device, dtype=means.dtype)[:, None]  # the flags live on the CPU
    out = rasterization(means, quats, scales, opacities, psi, camera)
    foreground = float(out.alpha.sum())
    if foreground <= 0:
        return 0.0, out.image[..., 0]
    return float(out.image[..., 0].sum()) / foreground, out.image[..., 0]


@torch.no_grad()
def select_views(means, quats, scales, opacities, seen: torch.Tensor, target,
                 config: ViewSelectionConfig = ViewSelectionConfig(), azimuth_offset_deg: float = 0.0,
                 ) -> list[CandidateView]:
    """All candidate views with their visibility; ``[v for v in result if v.unseen]`` are the views
    Stage II refines."""
    views = []
    for cam, az, el in candidate_cameras(target, config, azimuth_offset_deg):
        ratio, _ = visibility_ratio(means, quats, scales, opacities, seen, cam)
        views.append(CandidateView(cam, float(az), float(el), ratio, ratio <= config.threshold))
    return views


def azimuth_of(camera: Camera, target) -> float:
    """The azimuth (degrees, ``orbit_position``'s convention) of a camera's centre around ``target``."""
    d = camera.center - np.asarray(target, np.float64)
    return float(np.degrees(np.arctan2(d[0], -d[1])))


def elevation_of(camera: Camera, target) -> float:
    d = camera.center - np.asarray(target, np.float64)
    return float(np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1]))))
