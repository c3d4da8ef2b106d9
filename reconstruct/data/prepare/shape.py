"""A differentiable, linearised Anny shape for the fit: rest geometry as a function of the phenotype.

Anny's phenotype (gender, age, muscle, weight, height, proportions, each in [0, 1]) changes the rest
mesh, the rest joints and the rest bone frames. The fit needs these inside its optimisation loop; building
an Anny body per step would be slow, so ``ShapeBasis`` builds the body once at a base phenotype and once
per fitted key at ``base + delta`` and blends linearly:

    X(base + z) = X(base) + sum_k z_k (X(base + delta_k e_k) - X(base)) / delta_k

for X the rest vertices, rest joints and zero-pose transforms. The fitted phenotype is then built as a
real Anny body (``BodySpec.anny``) for the scene and the reported errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...body.base import BodyModel

PHENOTYPE_KEYS = ("gender", "age", "muscle", "weight", "height", "proportions")
DEFAULT_PHENOTYPE = {k: 0.5 for k in PHENOTYPE_KEYS}
# one view cannot tell a tall person far away from a short one nearby: without a given height the
# stature gets a population prior (adults, both sexes: mean ~1.70 m, spread ~0.09 m)
STATURE_MEAN_M = 1.70
STATURE_STD_M = 0.09
# keys the fit changes (age stays at the base: it trades body size for depth, which one view cannot
# tell) and how far each may move from the base before the prior bites (std of the prior)
FIT_KEYS = {"height": 0.25, "weight": 0.25, "proportions": 0.2, "gender": 0.35, "muscle": 0.2}


@dataclass
class ShapeBasis:
    """Linear rest geometry around ``base``: ``*0`` at the base, ``d*`` per key (change per unit)."""

    keys: tuple[str, ...]
    base: dict[str, float]
    prior_std: np.ndarray  # (K,)
    vertices0: torch.Tensor  # (V,3)
    d_vertices: torch.Tensor  # (K,V,3)
    joints0: torch.Tensor  # (J,3)
    d_joints: torch.Tensor  # (K,J,3)
    zero_pose0: torch.Tensor  # (J,4,4) rest -> zero-rotation pose transforms
    d_zero_pose: torch.Tensor  # (K,J,4,4)
    height0: float = 0.0  # stature (m) at the base
    d_height: np.ndarray | None = None  # (K,) its change per unit of each key
    stature_m: float = STATURE_MEAN_M  # prior on the stature: the person's height if given
    stature_std_m: float = STATURE_STD_M

    @classmethod
    def build(cls, base: dict[str, float], leg_spread_deg: float, keys=tuple(FIT_KEYS), delta: float = 0.15,
              base_body: BodyModel | None = None, stature_m: float | None = None) -> "ShapeBasis":
        """``stature_m``: the person's known height in metres (a tight prior), else the population prior."""
        from ...body.anny_backend import AnnyBody

        base = {k: float(base.get(k, 0.5)) for k in PHENOTYPE_KEYS}
        body0 = base_body or AnnyBody(base, leg_spread_deg=leg_spread_deg)
        v0, j0, t0 = _rest(body0)
        dv, dj, dt, dh = [], [], [], []
        h0 = _height(v0)
        for k in keys:
            step = delta if base[k] + delta <= 1.0 else -delta
            b = AnnyBody({**base, k: base[k] + step}, leg_spread_deg=leg_spread_deg)
            v, j, t = _rest(b)
            dv.append((v - v0) / step)
            dj.append((j - j0) / step)
            dt.append((t - t0) / step)
            dh.append((_height(v) - h0) / step)
        std = np.array([FIT_KEYS.get(k, 0.2) for k in keys], np.float64)
        if stature_m is not None and not (0.5 <= stature_m <= 2.5):
            raise ValueError(f"height {stature_m} m: expected a person's height in metres (0.5 to 2.5)")
        return cls(tuple(keys), base, std, v0, torch.stack(dv), j0, torch.stack(dj), t0, torch.stack(dt), h0,
                   np.asarray(dh), STATURE_MEAN_M if stature_m is None else float(stature_m),
                   STATURE_STD_M if stature_m is None else 0.01)

    def _mix(self, x0: torch.Tensor, dx: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return x0 + torch.einsum("k,k...->...", z.to(dx.dtype), dx)

    def vertices(self, z: torch.Tensor, ids: torch.Tensor | None = None) -> torch.Tensor:
        if ids is None:
            return self._mix(self.vertices0, self.d_vertices, z)
        return self._mix(self.vertices0[ids], self.d_vertices[:, ids], z)

    def joints(self, z: torch.Tensor) -> torch.Tensor:
        return self._mix(self.joints0, self.d_joints, z)

    def zero_pose(self, z: torch.Tensor) -> torch.Tensor:
        return self._mix(self.zero_pose0, self.d_zero_pose, z)

    def phenotype(self, z: np.ndarray | torch.Tensor) -> dict[str, float]:
        """The phenotype for offsets ``z`` (clipped into Anny's [0, 1] with a small margin)."""
        z = np.asarray(torch.as_tensor(z).detach().numpy() if isinstance(z, torch.Tensor) else z, np.float64)
        out = dict(self.base)
        for k, v in zip(self.keys, z):
            out[k] = float(np.clip(self.base[k] + v, 0.02, 0.98))
        return out

    def prior(self, z: torch.Tensor) -> torch.Tensor:
        """Gaussian prior around the base plus a wall at Anny's [0, 1] range."""
        std = torch.as_tensor(self.prior_std, dtype=z.dtype)
        b = torch.as_tensor([self.base[k] for k in self.keys], dtype=z.dtype)
        v = b + z
        out = ((z / std) ** 2).sum() + 100.0 * (torch.relu(-v) ** 2 + torch.relu(v - 1.0) ** 2).sum()
        if self.d_height is not None:
            h = self.height0 + (z * torch.as_tensor(self.d_height, dtype=z.dtype)).sum()
            out = out + ((h - self.stature_m) / self.stature_std_m) ** 2
        return out


def _rest(body: BodyModel) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    J = body.num_joints
    with torch.no_grad():
        t0 = body.rest_to_pose_transforms(torch.zeros(J, 3, dtype=torch.float64))
    return body.rest_vertices.to(torch.float64), body.rest_joints.to(torch.float64), t0.to(torch.float64)


def _height(vertices: torch.Tensor) -> float:
    z = vertices[:, 2]
    return float(z.max() - z.min())


def body_height(body: BodyModel) -> float:
    """Standing height (metres) of the body's rest mesh."""
    return _height(body.rest_vertices)
