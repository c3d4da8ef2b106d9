"""A garment layer of Gaussians for loose clothes (optional: ``AvatarConfig.garment_layer``).

The avatar's Gaussians are one per body texel, each with its texel's skinning weights and a bounded
offset: cloth that spans the gap between the legs or stands off the body has no Gaussians of its
own, and Gaussians pulled there from the inner thighs would be torn apart by the legs' skinning.
This layer adds Gaussians where the silhouette says there is something:

* geometry: a tube of Gaussians on a regular grid (rows down from the top ring, columns round),
  swept round the hips-and-legs region of the canonical body: at each height the ring follows the
  convex hull of the body slice (torso above the hips; torso, thighs and shins below them; its
  polar radius round the slice's centre, ``body.slices.hull_polar_radii``: the convex envelope, so
  one ring spans both legs; rows past the covered body's end take the nearest full row's ring)
  plus a standoff growing from the top to the hem, never narrowing below the hips (cloth hangs);
  rows every 1 cm (``AvatarConfig.garment_layer_step``), every 5 mm over the last 3 cm,
  reaching 1 cm below the hint's hem (``row_heights``: the hem is an open edge);
* skinning: each Gaussian takes a Gaussian-weighted average of the weights of the nearest body
  points (relative to the nearest), then the weights are diffused over the grid (a Gaussian filter,
  wrapping round), so the cloth between the legs blends the two legs' bones and the layer moves as
  one piece: continuous weights cannot open a gap, only stretch the cloth (``max_neighbour_stretch``);
* the volume hint: ``volume_hint_from_masks`` reads the hem height and the flare from the
  front-view frames: image rows where the posed body's own silhouette leaves a gap between the
  projected leg axes and the mask covers that gap are cloth; the lowest such row is the hem; the
  mask's width beyond the body's there is the flare; the top is the waist, or the chest
  (``torso_top_height``) when the mask also stands out past the torso's sides by 1 cm or more
  (``frame_torso_evidence``: a coat, a dress), the standoff there read from it. Without cloth in the
  gap, each lower leg's mask run is compared with the body's own (``frame_leg_evidence``): legs
  that stand out by 2.5 cm or more over 10 cm of height are wide trousers, and the layer is two
  tubes, one round each leg (``VolumeHint.two_legs``; the grid's columns hold both, each wrapping
  round on itself). Failing both, a side of the mask standing 4 cm or more past the body from the
  chest down (``frame_flap_evidence``: an open coat's or jacket's flap) gives a layer over the
  torso whose rings are stretched sideways towards that side (``flap_hint``). Tight clothing gives
  no hint (None): no layer;
* the sides, row by row: where the posed rings of a one-tube layer stop short of the masks on one
  side (a skirt swung to one side, a coat cut wider than the flare read above its hem), each
  ring's half on that side is stretched out to them (``layer_profile.fit_side_profile``,
  ``VolumeHint.side_profile``), and the stretched cloth's weights move towards its ring's mean.

``AvatarModel(..., layer=...)`` appends the layer's Gaussians after the body's (its own feature map
over the grid, the shared decoder, a learned opacity); ``garment_layer_for`` builds the layer a
training run asks for (``off`` / ``auto`` / ``on``); ``GarmentLayer.to_state`` / ``from_state``
carry its geometry through checkpoints as plain tensors and numbers. ``GarmentLayer.gaussians``
poses the bare layer (given colours, one opacity) for the measurements of
``benchmarks/loose_clothing.py``. See docs/loose_clothing.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from scipy.ndimage import binary_closing, binary_dilation, gaussian_filter, gaussian_filter1d
from scipy.spatial import cKDTree

from ..body.base import BodyModel
from ..body.lbs import Skinning
from ..body.parts import PART_INDEX, PART_NAMES
from ..body.pose import BodyPose
from ..body.slices import hull_polar_radii, ring_directions
from .config import GARMENT_LAYER_MODES, GARMENT_LAYER_STEP, ONE_TUBE_FILTER

_COVERED = ("torso", "thigh.L", "thigh.R", "shin.L", "shin.R")

# the layer's Gaussians are one more part after the body's (``AvatarModel.parts``)
GARMENT_PART_NAME = "garment"
GARMENT_PART = len(PART_NAMES)
AVATAR_PART_NAMES: tuple[str, ...] = (*PART_NAMES, GARMENT_PART_NAME)
_HINT_FIELDS = ("top_z", "hem_z", "standoff_top", "standoff_hem")
# metres per metre of height: the most a side profile's stretch falls from one height to the next
# (``VolumeHint.side_reach``). A swung skirt's profile read row by row can drop to 0 within a row
# where its slanted hem ends on that side, or where a row read nothing: the long-skirt photo's
# left side fell from 32 cm to 0 between two rows 1.9 cm apart, and the discs of those rows, whose
# scale follows the grid's step, spanned the 31 cm jump as 9 cm needles, drawn as dark spikes past
# the hem from the side. Cloth hangs from where it was: the rows below fall back at most
# ``SIDE_PROFILE_FALL`` (45°) and the learned opacity empties those past the cloth; the rows above a
# knot at most ``SIDE_PROFILE_SLOPE``. Measured rises on the swung skirts reach 5 (the grey-skirt
# photo's waist, 7 cm over 1.4 cm) and are kept. Below a knot, a fall of 5 made a shelf: on the long
# skirt the hem's 5 mm rows under the flare's 29 cm tip each fell 2.5 cm, a ledge of discs lying
# almost flat under the cloth, hidden in the photo's view (so never emptied) and drawn from the side
# as dark streaks; at 45° the same rows hang, and the training view's fit after Stage I's finish
# is 21.49 -> 22.62 dB (grey-skirt photo: 22.71 -> 22.57). Held flat below a knot (no fall), the
# grey skirt's swung side hung a half-transparent sheet below its hem that 450 steps did not empty
SIDE_PROFILE_SLOPE = 5.0
SIDE_PROFILE_FALL = 1.0
# metres either side of a row's height: the body slice its ring is read from (``_tube_rings``). Rows
# whose slab reaches past the covered body's end take the nearest row's ring that does not: the
# long-skirt photo's hem rows reach 1 cm below the shins' end, their slices held 213, 114, 51 and 17
# points against ~350 above, and the ring's centre, their mean, ran 1, 3 and 6 cm sideways and 7 cm
# back within 5 mm of height, the hem's discs spanning the jumps as needles
_SLAB = 0.012
_HINT_SIDE_FIELDS = ("side_left", "side_right")  # absent in checkpoints from before flaps: 0


def _roll_columns(a, shift: int, tubes: int):
    """``a`` (R, T*C, ...) rolled by ``shift`` along the columns of each of its ``tubes`` blocks of
    C columns (each tube wraps round on itself); numpy arrays or torch tensors."""
    R, TC = a.shape[:2]
    b = a.reshape(R, tubes, TC // tubes, *a.shape[2:])
    if isinstance(a, torch.Tensor):
        return b.roll(shift, dims=2).reshape(a.shape)
    return np.roll(b, shift, axis=2).reshape(a.shape)


def grid_steps(points: torch.Tensor, grid_shape: tuple[int, int], tubes: int) -> torch.Tensor:
    """(R*C, 2) the length of one step round the ring and one down the column at each point of a
    layer's grid, ``points`` (R*C, 3) in the grid's order (row by row): central differences, each
    tube wrapping round on itself, one-sided at the top and the hem rows (as ``np.gradient``)."""
    R, C = grid_shape
    P = points.reshape(R, C, 3)
    side = (_roll_columns(P, -1, tubes) - _roll_columns(P, 1, tubes)).norm(dim=-1) / 2
    if R == 1:
        down = torch.zeros_like(side)
    else:
        d = torch.empty_like(P)
        d[1:-1] = (P[2:] - P[:-2]) / 2
        d[0], d[-1] = P[1] - P[0], P[-1] - P[-2]
        down = d.norm(dim=-1)
    return torch.stack([side, down], -1).reshape(R * C, 2)


@dataclass(frozen=True)
class VolumeHint:
    """Where the garment layer goes, in the body's canonical heights (metres)."""

    top_z: float
    hem_z: float
    standoff_top: float = 0.012
    standoff_hem: float = 0.06
    two_legs: bool = False  # one tube round each leg (trousers) instead of one round both
    # metres the cloth stands out sideways past the body at the body's left (+X) and right (-X):
    # each ring's half on that side is stretched sideways by as much (``build_garment_layer``): an open coat's or
    # jacket's flap hanging off one side (``frame_flap_evidence``); 0 for a layer round the body
    side_left: float = 0.0
    side_right: float = 0.0
    # (canonical height, metres at the left, metres at the right) knots, heights decreasing: how far
    # the cloth reaches sideways past the ring at each height as the masks read it
    # (``layer_profile.fit_side_profile``: a skirt swung to one side, a coat cut wider than the flare);
    # added to ``side_left`` / ``side_right`` row by row (interpolated, 0 outside the knots, and
    # never falling faster than ``SIDE_PROFILE_SLOPE`` metres per metre of height: ``side_reach``)
    side_profile: tuple[tuple[float, float, float], ...] = ()

    @property
    def tubes(self) -> int:
        """How many tubes the layer has (2 for trousers: left leg, then right)."""
        return 2 if self.two_legs else 1

    def __post_init__(self) -> None:
        if not self.hem_z < self.top_z:
            raise ValueError(f"volume hint: hem ({self.hem_z:.3f} m) must be below the top ({self.top_z:.3f} m)")
        if min(self.standoff_top, self.standoff_hem, self.side_left, self.side_right) < 0:
            raise ValueError("volume hint: standoffs must be >= 0")
        if self.side_profile:
            k = np.asarray(self.side_profile, dtype=float)
            if k.ndim != 2 or k.shape[1] != 3 or not np.isfinite(k).all():
                raise ValueError(f"volume hint: side_profile must be (height, left, right) triples of numbers, "
                                 f"found {self.side_profile!r}")
            if (k[:, 1:] < 0).any() or (np.diff(k[:, 0]) >= 0).any():
                raise ValueError("volume hint: side_profile needs heights decreasing and reaches >= 0")

    def side_reach(self, zs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Metres each ring at canonical heights ``zs`` is stretched towards the body's left (+X) and
        right: ``side_left`` / ``side_right`` plus ``side_profile`` interpolated (0 outside it), raised
        (inside and outside it) where it would fall faster than ``SIDE_PROFILE_SLOPE`` per metre of
        height above a knot or ``SIDE_PROFILE_FALL`` below it (the upper envelope of cones of those
        slopes on the knots)."""
        zs = np.asarray(zs, float)
        if not self.side_profile:
            return np.full(zs.shape, self.side_left), np.full(zs.shape, self.side_right)
        k = np.asarray(self.side_profile, float)[::-1]  # increasing heights for np.interp
        dz = zs.reshape(-1, 1) - k[None, :, 0]  # (Z, K) metres of height above each knot
        # (Z, K) what each knot's reach loses by each height: SIDE_PROFILE_SLOPE per metre above it,
        # SIDE_PROFILE_FALL below it
        loss = np.where(dz >= 0, SIDE_PROFILE_SLOPE * dz, -SIDE_PROFILE_FALL * dz)
        out = []
        for col, flap in ((1, self.side_left), (2, self.side_right)):
            lin = np.interp(zs, k[:, 0], k[:, col], left=0.0, right=0.0)
            cone = np.clip((k[None, :, col] - loss).max(1), 0.0, None).reshape(zs.shape)
            out.append(flap + np.maximum(lin, cone))
        return out[0], out[1]


@dataclass
class GarmentLayer:
    """Canonical Gaussians of the layer on a (rows, cols) grid (row-major). The columns are
    ``tubes`` blocks side by side (one tube round both legs; two, left then right, for trousers),
    each wrapping round on itself."""

    positions: torch.Tensor  # (N,3) float32 canonical centres
    normals: torch.Tensor  # (N,3) outward
    tangents: torch.Tensor  # (N,3) round the tube
    weights: torch.Tensor  # (N,J) skinning weights (sum 1)
    spacing: torch.Tensor  # (N,) metres: distance to the grid neighbours (initial scale)
    grid_shape: tuple[int, int]
    hint: VolumeHint
    # (N,) metres each point was moved along +Y after training (``layer_depth.match_layer_depth``,
    # the end of Stage I); None: not moved. ``positions`` include the move
    depth_shift: torch.Tensor | None = None

    @property
    def num_gaussians(self) -> int:
        return int(self.positions.shape[0])

    @property
    def tubes(self) -> int:
        """How many tubes the columns hold (``VolumeHint.tubes``)."""
        return self.hint.tubes

    def edges(self) -> np.ndarray:
        """(E,2) grid neighbours: down each column and round each tube's ring (wrapping)."""
        R, C = self.grid_shape
        idx = np.arange(R * C).reshape(R, C)
        down = np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1)
        side = np.stack([idx.ravel(), _roll_columns(idx, -1, self.tubes).ravel()], 1)
        return np.concatenate([down, side])

    def grid_neighbours(self) -> np.ndarray:
        """(N,4) each Gaussian's grid neighbours in the order of ``texel_neighbours`` (next column,
        next row, previous column, previous row): columns wrap round their tube, -1 past the top and
        the hem."""
        R, C = self.grid_shape
        idx = np.arange(R * C).reshape(R, C)
        out = np.full((R, C, 4), -1, np.int64)
        out[..., 0] = _roll_columns(idx, -1, self.tubes)
        out[:-1, :, 1] = idx[1:]
        out[..., 2] = _roll_columns(idx, 1, self.tubes)
        out[1:, :, 3] = idx[:-1]
        return out.reshape(R * C, 4)

    def steps(self) -> torch.Tensor:
        """(N,2) float32 metres: the 3D length of one grid step round the ring (the tangent's
        direction) and one down the column (central differences; one-sided at the top and hem):
        a disc's in-plane scale, like ``texel_frames``' steps of the body's texels."""
        return grid_steps(self.positions.double(), self.grid_shape, self.tubes).float()

    def same_as(self, other: "GarmentLayer | None") -> bool:
        """The same geometry (grid, positions, weights, normals, tangents, spacing)."""
        if other is None or tuple(other.grid_shape) != tuple(self.grid_shape):
            return False
        return all(torch.equal(getattr(self, k), getattr(other, k))
                   for k in ("positions", "normals", "tangents", "weights", "spacing"))

    def to_state(self) -> dict:
        """Plain tensors and numbers (what a checkpoint holds; ``from_state`` rebuilds the layer)."""
        return {"positions": self.positions.detach().cpu().clone(), "normals": self.normals.detach().cpu().clone(),
                "tangents": self.tangents.detach().cpu().clone(), "weights": self.weights.detach().cpu().clone(),
                "spacing": self.spacing.detach().cpu().clone(),
                **({} if self.depth_shift is None else {"depth_shift": self.depth_shift.detach().cpu().clone()}),
                "grid_shape": [int(self.grid_shape[0]), int(self.grid_shape[1])],
                "hint": {**{k: float(getattr(self.hint, k)) for k in _HINT_FIELDS + _HINT_SIDE_FIELDS},
                         "two_legs": bool(self.hint.two_legs),
                         "side_profile": [[float(v) for v in knot] for knot in self.hint.side_profile]}}

    @staticmethod
    def from_state(d, source: str = "checkpoint", num_joints: int | None = None) -> "GarmentLayer":
        """The layer of ``to_state``'s dict; ValueError naming ``source`` and what was expected."""
        what = f"{source}: garment layer"
        if not isinstance(d, dict):
            raise ValueError(f"{what}: expected a dict of tensors and numbers, found {type(d).__name__}")
        missing = sorted({"positions", "normals", "tangents", "weights", "spacing", "grid_shape", "hint"} - set(d))
        if missing:
            raise ValueError(f"{what}: missing entries {missing}")
        shape = d["grid_shape"]
        if (not isinstance(shape, (list, tuple)) or len(shape) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in shape)):
            raise ValueError(f"{what}: grid_shape must be two positive integers, found {shape!r}")
        hint = d["hint"]
        if not isinstance(hint, dict) or not all(isinstance(hint.get(k), (int, float)) for k in _HINT_FIELDS):
            raise ValueError(f"{what}: hint must hold the numbers {', '.join(_HINT_FIELDS)}, found {hint!r}")
        two_legs = hint.get("two_legs", False)  # absent in checkpoints from before trousers: one tube
        if not isinstance(two_legs, bool):
            raise ValueError(f"{what}: hint two_legs must be true or false, found {two_legs!r}")
        sides = {k: hint.get(k, 0.0) for k in _HINT_SIDE_FIELDS}
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in sides.values()):
            raise ValueError(f"{what}: hint {' and '.join(_HINT_SIDE_FIELDS)} must be numbers, found {sides!r}")
        profile = hint.get("side_profile", [])  # absent in checkpoints from before it: none
        if (not isinstance(profile, (list, tuple)) or not all(
                isinstance(k, (list, tuple)) and len(k) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in k) for k in profile)):
            raise ValueError(f"{what}: hint side_profile must be a list of [height, left, right] numbers, "
                             f"found {profile!r}")
        if two_legs and int(shape[1]) % 2:
            raise ValueError(f"{what}: a two-legged layer needs an even number of columns, found {shape[1]}")
        n = int(shape[0]) * int(shape[1])
        want = {"positions": (n, 3), "normals": (n, 3), "tangents": (n, 3), "spacing": (n,)}
        out = {}
        for k, sh in want.items():
            t = d[k]
            if not isinstance(t, torch.Tensor) or tuple(t.shape) != sh or not torch.is_floating_point(t):
                found = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
                raise ValueError(f"{what}: {k} must be a float tensor of shape {sh}, found {found}")
            out[k] = t.float()
        w = d["weights"]
        if (not isinstance(w, torch.Tensor) or w.dim() != 2 or w.shape[0] != n or not torch.is_floating_point(w)
                or (num_joints is not None and w.shape[1] != num_joints)):
            found = tuple(w.shape) if isinstance(w, torch.Tensor) else type(w).__name__
            raise ValueError(f"{what}: weights must be a float tensor of shape ({n}, "
                             f"{num_joints if num_joints is not None else 'joints'}), found {found}")
        try:
            volume = VolumeHint(**{k: float(hint[k]) for k in _HINT_FIELDS}, two_legs=two_legs,
                                **{k: float(v) for k, v in sides.items()},
                                side_profile=tuple(tuple(float(v) for v in k) for k in profile))
        except ValueError as exc:
            raise ValueError(f"{what}: {exc}") from None
        shift = d.get("depth_shift")  # absent in checkpoints from before layer_depth_match, and before Stage I ends
        if shift is not None and (not isinstance(shift, torch.Tensor) or tuple(shift.shape) != (n,)
                                  or not torch.is_floating_point(shift)):
            found = tuple(shift.shape) if isinstance(shift, torch.Tensor) else type(shift).__name__
            raise ValueError(f"{what}: depth_shift must be a float tensor of shape ({n},), found {found}")
        return GarmentLayer(out["positions"], out["normals"], out["tangents"], w.float(), out["spacing"],
                            (int(shape[0]), int(shape[1])), volume,
                            None if shift is None else shift.float())

    def describe(self) -> str:
        R, C = self.grid_shape
        h = self.hint
        tubes = " in two tubes (one per leg)" if self.tubes == 2 else ""
        sides = "".join(f", {name} side +{100 * v:.1f} cm" for name, v in (("left", h.side_left), ("right", h.side_right))
                        if v > 0)
        if h.side_profile:
            k = np.asarray(h.side_profile)
            sides += f", reaching out up to {100 * k[:, 1].max():.1f} cm left and {100 * k[:, 2].max():.1f} cm right"
        return (f"garment layer: {self.num_gaussians:,} Gaussians ({R} rows x {C} columns{tubes}), top {h.top_z:.3f} m, "
                f"hem {h.hem_z:.3f} m, flare {100 * h.standoff_hem:.1f} cm{sides}")

    def skinning(self, body: BodyModel) -> Skinning:
        return body.skinning(self.weights.to(torch.float64))

    def posed(self, body: BodyModel, pose: BodyPose) -> tuple[torch.Tensor, torch.Tensor]:
        """(N,3) centres and (N,3) normals in ``pose`` (float64)."""
        means, normals = self.skinning(body)(body.bone_transforms(pose), self.positions.to(torch.float64),
                                             self.normals.to(torch.float64))
        return means, normals

    def gaussians(self, body: BodyModel, pose: BodyPose, colors: torch.Tensor | None = None,
                  opacity: float = 0.95, scale_factor: float = 0.75):
        """The layer posed as PosedGaussians (flat discs in the cloth's tangent plane, sized by the
        grid spacing), grey unless ``colors`` (N,3) are given."""
        from .gaussian_sets import PosedGaussians, frame_quaternions

        means, normals = self.posed(body, pose)
        M = self.skinning(body).matrices(body.bone_transforms(pose))
        tangents = (M[:, :3, :3] @ self.tangents.to(torch.float64)[..., None])[..., 0]
        quats = frame_quaternions(tangents, normals)
        s = self.spacing.to(torch.float64) * scale_factor
        scales = torch.stack([s, s, 0.1 * s], 1)
        n = self.num_gaussians
        col = torch.full((n, 3), 0.6, dtype=torch.float64) if colors is None else colors.to(torch.float64)
        f32 = lambda t: t.to(torch.float32).contiguous()
        return PosedGaussians(f32(means), f32(normals), f32(col), f32(scales), f32(quats),
                              torch.full((n,), float(opacity)))

    def max_neighbour_stretch(self, body: BodyModel, poses) -> float:
        """The largest ratio posed / canonical distance between grid neighbours over ``poses``."""
        e = self.edges()
        p0 = self.positions.numpy().astype(np.float64)
        l0 = np.linalg.norm(p0[e[:, 0]] - p0[e[:, 1]], axis=1)
        worst = 1.0
        for pose in poses:
            p = self.posed(body, pose)[0].numpy()
            l1 = np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1)
            worst = max(worst, float((l1 / np.maximum(l0, 1e-9)).max()))
        return worst


def _dense_body(body: BodyModel, parts=_COVERED) -> tuple[np.ndarray, np.ndarray]:
    """Canonical points on the covered parts' triangles (vertices, centroids, edge midpoints) and
    the skinning weights there."""
    v = body.canonical_vertices.numpy()
    w = body.skin_weights.numpy()
    f = body.faces.numpy()
    keep = np.isin(body.vertex_parts[f[:, 0]], [PART_INDEX[p] for p in parts])
    f = f[keep]
    bary = np.array([[1, 1, 1], [2, 1, 0], [1, 2, 0], [0, 2, 1], [0, 1, 2], [1, 0, 2], [2, 0, 1]], float) / 3.0
    pts = np.einsum("sk,fkd->fsd", bary, v[f]).reshape(-1, 3)
    wts = np.einsum("sk,fkj->fsj", bary, w[f]).reshape(-1, w.shape[1])
    return pts, wts


def landmark_heights(body: BodyModel) -> dict[str, float]:
    J = body.canonical_joints.numpy()
    L = body.bone_labels
    z = lambda n: float(J[L.index(n), 2])
    return {"waist": z("spine03"), "hips": z("upperleg01.L") + 0.06,
            "knee": 0.5 * (z("lowerleg01.L") + z("lowerleg01.R")), "ankle": 0.5 * (z("foot.L") + z("foot.R"))}


_LEG_OVERLAP = 0.03  # metres past the midline that each leg's tube takes in at the seat
MIN_LEG_FLARE = 0.025  # metres the mask must stand out round each lower leg for wide trousers
MIN_TORSO_STANDOFF = 0.01  # metres the mask must stand out past the torso for the layer to cover it
_TORSO_CHAIN = ("spine03", "spine02", "spine01", "neck01")  # waist up to the neck


def torso_top_height(body: BodyModel) -> float:
    """The canonical height the layer may reach over the torso: 6 cm below the shoulder joints,
    where the upper arms leave the chest (a layer round the shoulders would have to follow the arms)."""
    J = body.canonical_joints.numpy()
    L = body.bone_labels
    return float(0.5 * (J[L.index("upperarm01.L"), 2] + J[L.index("upperarm01.R"), 2])) - 0.06


def _tube_rings(pts: np.ndarray, zs: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slice centres (R,2) and hull polar radii (R,C) of ``pts`` at heights ``zs`` (a slab of
    ``_SLAB`` metres either side, widened to 2.5 and 5 cm where it holds fewer than 16 points). Rows
    whose slab reaches past the end of ``pts`` (a floor-length skirt's hem rows below the shins) take
    the ring of the nearest row whose slab does not: a slice through the body's cut-off end holds a
    few points on one side, and its mean runs off the ring's axis."""
    centres, radii = np.zeros((len(zs), 2)), np.zeros((len(zs), len(theta)))
    inside = np.flatnonzero((zs - _SLAB > pts[:, 2].min()) & (zs + _SLAB < pts[:, 2].max()))
    read = inside if inside.size else np.arange(len(zs))  # the rows whose slice is read
    for i in read:
        z = zs[i]
        for width in (_SLAB, 0.025, 0.05):
            on = np.abs(pts[:, 2] - z) < width
            if on.sum() >= 16:
                break
        else:
            raise ValueError(f"garment layer: no body surface near height {z:.3f} m")
        sl = pts[on, :2]  # torso, thighs and shins only: the arms are not in _dense_body
        centres[i] = sl.mean(0)  # inside the slice's convex hull
        radii[i] = hull_polar_radii(sl, centres[i], theta)
    near = read[np.abs(np.arange(len(zs))[:, None] - read[None]).argmin(1)]  # each row's nearest read row
    return centres[near], radii[near]


def row_heights(top_z: float, bottom_z: float, row_step: float, hem_band: float = 0.0,
                hem_step: float = 0.005) -> np.ndarray:
    """The canonical heights of the layer's rows, top down: about every ``row_step`` (at least 4
    rows), then every ``hem_step`` over the last ``hem_band`` metres (none when the layer is too
    short for a band below a coarse row)."""
    band = hem_band if hem_band > 0 and top_z - bottom_z > hem_band + row_step else 0.0
    coarse_end = bottom_z + band
    rows = max(4, int(np.ceil((top_z - coarse_end) / row_step)) + 1)
    zs = np.linspace(top_z, coarse_end, rows)
    if band:
        fine = np.linspace(coarse_end, bottom_z, int(np.ceil(band / hem_step)) + 1)[1:]
        zs = np.concatenate([zs, fine])
    return zs


def interpolation_matrix(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(len(dst), len(src)) the matrix of linear interpolation from rows at heights ``src`` to
    heights ``dst`` (both decreasing; clamped at the ends): ``np.interp`` of each unit vector."""
    x, z = -np.asarray(src, float), -np.asarray(dst, float)  # increasing, as np.interp wants
    return np.stack([np.interp(z, x, e) for e in np.eye(len(x))], axis=1)


def build_garment_layer(body: BodyModel, hint: VolumeHint, *, cols: int | None = None,
                        row_step: float = GARMENT_LAYER_STEP,
                        hem_margin: float = 0.01, hem_band: float = 0.03, hem_step: float = 0.005,
                        k: int = 24, sigma: float = 0.04, diffusion: tuple[float, float] | None = None,
                        stretch_blend: float = 0.10, one_tube_filter: float = ONE_TUBE_FILTER) -> GarmentLayer:
    """The garment layer of ``body`` in the region of ``hint`` (see the module docstring): one tube of
    ``cols`` columns (by default ``layer_columns(row_step)``), or with ``hint.two_legs`` one per
    leg (left then right, ``cols // 2`` each; each takes the torso and legs on its side of the midline, overlapping by 3 cm at the seat, and does
    not hang: it follows its leg). ``diffusion``: the weight filter's sigma in rows of ``row_step``
    and in columns; by default ``weight_diffusion(row_step, cols)``, the same width in metres and
    round the tube whatever the grid's spacing, times ``one_tube_filter`` for a one-tube layer
    (``AvatarConfig.garment_filter_one_tube``: a coat, a skirt or a dress moves as one piece across
    both legs; a trouser tube follows its own leg).

    The hem is an open edge inside the person's silhouette (the legs below it): a disc's scale is
    at least ``AvatarConfig.scale_floor`` times its grid step, so rows every 2 cm end the cloth in a
    soft band of alpha < 0.9 some 2 cm high, which the eval counts as holes (seen from behind, where
    no leg fills it). The layer therefore reaches ``hem_margin`` below the hint's hem (what the masks
    read, a little high on the benchmark) with rows every ``hem_step`` over its last ``hem_band``:
    small discs there give a sharp edge, and the learned opacity cuts the rows below the cloth.

    Rings stretched sideways by the side profile (``VolumeHint.side_profile``) blend each point's
    weights towards the mean of its ring's, in proportion to how far the profile moved it, fully
    from ``stretch_blend`` metres."""
    tubes = hint.tubes
    cols = layer_columns(row_step) if cols is None else cols
    if diffusion is None:
        diffusion = weight_diffusion(row_step, cols, one_tube_filter if tubes == 1 else 1.0)
    if cols < 8 * tubes:
        raise ValueError(f"garment layer: need at least {8 * tubes} columns, found {cols}")
    if hem_margin < 0 or hem_band < 0 or hem_step <= 0:
        raise ValueError(f"garment layer: need hem_margin >= 0, hem_band >= 0 and hem_step > 0, found "
                         f"{hem_margin}, {hem_band} and {hem_step}")
    cols //= tubes
    pts, wts = _dense_body(body)
    marks = landmark_heights(body)
    zs = row_heights(hint.top_z, hint.hem_z - hem_margin, row_step, hem_band, hem_step)
    rows = len(zs)
    theta = np.arange(cols) * 2 * np.pi / cols
    d = ring_directions(theta)  # 0 = front (-Y), +pi/2 = the body's left (+X)
    t = np.clip((marks["hips"] - zs) / max(marks["hips"] - hint.hem_z, 1e-6), 0, 1) ** 1.3
    standoff = hint.standoff_top + (hint.standoff_hem - hint.standoff_top) * t
    start = int(np.argmin(np.abs(zs - marks["hips"])))
    grids, stretch = [], []  # per tube: (R,C,3) centres, (R,C) metres moved sideways
    for sign in ((1.0, -1.0) if hint.two_legs else (None,)):  # +X is the body's left
        side = slice(None) if sign is None else pts[:, 0] * sign > -_LEG_OVERLAP
        centres, radii = _tube_rings(pts[side], zs, theta)
        radii = gaussian_filter1d(radii, 1.0, axis=0, mode="nearest") + standoff[:, None]
        if not hint.two_legs:
            radii[start:] = np.maximum.accumulate(radii[start:], axis=0)  # cloth hangs: no narrowing
        xy = centres[:, None, :] + radii[..., None] * d[None]
        # a flap standing out sideways, a skirt swung to one side: each ring's half on that side
        # stretched in x about the ring's centre so that its outermost point moves out by the
        # row's reach on that side (front and back stay)
        moved = np.zeros((rows, cols))  # metres each point moved by the side profile (not by a flap)
        for side, flap, sgn in zip(hint.side_reach(zs), (hint.side_left, hint.side_right), (1.0, -1.0)):
            if (side > 0).any():
                rel = (xy[..., 0] - centres[:, None, 0]) * sgn  # (R,C) metres towards that side
                frac = np.where(rel > 0, rel / np.maximum(rel.max(1, keepdims=True), 1e-3), 0.0)
                moved += frac * (side - flap)[:, None]
                xy[..., 0] += frac * side[:, None] * sgn
        stretch.append(moved)
        grids.append(np.concatenate([xy, np.broadcast_to(zs[:, None, None], (rows, cols, 1))], -1))
    P = np.concatenate(grids, axis=1)  # (rows, tubes*cols, 3)
    # normals and tangents from the grid (round each tube)
    tang = _roll_columns(P, -1, tubes) - _roll_columns(P, 1, tubes)
    down = np.gradient(P, axis=0)
    nrm = np.cross(down, tang)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    tang /= np.linalg.norm(tang, axis=-1, keepdims=True)
    # spacing: mean distance to the ring and column neighbours
    side_len = np.linalg.norm(_roll_columns(P, -1, tubes) - P, axis=-1)
    spacing = 0.5 * (side_len + np.linalg.norm(down, axis=-1))
    # weights: transfer from the nearest body points, diffused over each tube's grid
    dist, idx = cKDTree(pts).query(P.reshape(-1, 3), k=k)
    g = np.exp(-(dist ** 2 - dist[:, :1] ** 2) / (2 * sigma ** 2))
    g /= g.sum(1, keepdims=True)
    W = np.einsum("nk,nkj->nj", g, wts[idx]).reshape(rows, tubes, cols, -1)
    # diffused on rows every row_step (the fine hem rows resampled there and back)
    zu = np.linspace(zs[0], zs[-1], max(2, int(round((zs[0] - zs[-1]) / row_step)) + 1))
    uniform = len(zu) == rows and np.allclose(zu, zs)
    if not uniform:
        W = np.einsum("ur,rtcj->utcj", interpolation_matrix(zs, zu), W)
    W = gaussian_filter(W, (diffusion[0], 0, diffusion[1], 0), mode=("nearest", "nearest", "wrap", "nearest"))
    if not uniform:
        W = np.einsum("ru,utcj->rtcj", interpolation_matrix(zu, zs), W)
    W = np.clip(W, 0, None)
    W /= W.sum(-1, keepdims=True)
    # cloth the side profile stretched far off the body follows the ring's mean weights (for a ring
    # round both legs, the thighs' swings cancel), not the nearest limb's: a point 30 cm out along a
    # thigh's weights would rise and fall with the thigh's smallest turn. A flap's stretch keeps its
    # weights (blended, the green-jacket photo's flap fitted worse: alpha IoU 0.927 -> 0.910)
    share = np.clip(np.stack(stretch, axis=1) / stretch_blend, 0.0, 1.0)[..., None]  # (R,T,C,1)
    W = ((1.0 - share) * W + share * W.mean(2, keepdims=True)).reshape(rows, tubes * cols, -1)
    n = rows * tubes * cols
    f32 = lambda a: torch.as_tensor(np.ascontiguousarray(a.reshape(n, *a.shape[2:])), dtype=torch.float32)
    return GarmentLayer(f32(P), f32(nrm), f32(tang), f32(W), f32(spacing), (rows, tubes * cols), hint)


def _leg_axis_x(J2: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """x of the polyline hip -> knee -> ankle (image points (3,2)) at image rows ``rows``."""
    y, x = J2[:, 1], J2[:, 0]
    order = np.argsort(y)
    return np.interp(rows, y[order], x[order])


def _body_silhouette(body: BodyModel, pose: BodyPose, camera, shape: tuple[int, int], grow: int = 1) -> np.ndarray:
    """(H,W) bool: the posed body alone, splatted from points on its triangles and closed."""
    v = body.posed_vertices(pose).numpy()
    f = body.faces.numpy()
    bary = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4]], float) / np.array([[3.0], [6.0], [6.0], [6.0]])
    pts = np.concatenate([v, np.einsum("sk,fkd->fsd", bary, v[f]).reshape(-1, 3)])
    uv, z = camera.project(pts)
    H, W = shape
    ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    sil = np.zeros(shape, bool)
    sil[uv[ok, 1].astype(int), uv[ok, 0].astype(int)] = True
    sil = binary_closing(sil, iterations=2)
    return binary_dilation(sil, iterations=grow) if grow else sil


def body_silhouette(body: BodyModel, frame) -> np.ndarray:
    """(H,W) bool: the posed body alone in ``frame``'s camera (not grown), what the hint's evidence
    compares the mask with."""
    return _body_silhouette(body, frame.pose, frame.camera, np.asarray(frame.mask).shape[:2], grow=0)


@dataclass(frozen=True)
class HintEvidence:
    """What one front-view frame says about loose clothing (``frame_hint_evidence``).

    ``testable``: the posed body leaves a gap between its legs wide enough to test (at least
    ``min_gap`` metres over ``min_span`` metres of height); ``cloth``: the mask covers that gap in
    one run that starts at the crotch and reaches at least ``min_drop`` metres down the legs;
    ``hem_z``: the canonical height of the run's lowest row; ``flare``: metres the cloth stands out
    past the body at each side just above the hem (see ``frame_hint_evidence``)."""

    testable: bool
    cloth: bool
    hem_z: float | None = None
    flare: float | None = None
    drop: float = 0.0  # metres from the first tested row (the crotch) down to the run's lowest row
    rows: tuple[int, int] | None = None  # image rows: the first tested one, the run's lowest
    legs: "LegEvidence | None" = None  # what the same frame says about wide trouser legs
    torso: "TorsoEvidence | None" = None  # what the same frame says about cloth off the torso
    flaps: "FlapEvidence | None" = None  # what the same frame says about cloth hanging off one side


@dataclass(frozen=True)
class TorsoEvidence:
    """What one front-view frame says about cloth standing off the torso above the waist
    (``frame_torso_evidence``). ``testable``: enough image rows between the waist and the chest in
    which the mask's run across the torso and the body's own can be compared; ``standoff``: metres
    the mask stands out past the body on each side (the median over those rows)."""

    testable: bool
    standoff: float = 0.0


@dataclass(frozen=True)
class FlapEvidence:
    """What one front-view frame says about cloth standing out sideways past the body from the
    chest down (``frame_flap_evidence``): an open coat's or jacket's flap. ``testable``: enough
    image rows between the chest and the knees read on both sides; per side of the body (``left``
    = +X, ``right``), None or (standoff metres, top canonical height, lowest canonical height) of
    its flap."""

    testable: bool
    left: tuple[float, float, float] | None = None
    right: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class LegEvidence:
    """What one front-view frame says about wide trouser legs (``frame_leg_evidence``).

    ``testable``: enough image rows from the knees down in which each leg stands apart from the
    other in both the mask and the body's own silhouette; ``wide``: over a run of such rows reaching
    down from the knees the mask is wider than the body's leg by at least ``min_flare`` on each side
    (on average over the two legs; the longest such run); ``hem_z``: the canonical height of the run's lowest row;
    ``flare``: metres the mask stands out on each side near that row; ``span``: metres of height
    the wide run covers."""

    testable: bool
    wide: bool
    hem_z: float | None = None
    flare: float | None = None
    span: float = 0.0


def _front_legs(body: BodyModel, frame, depth_bone: str) -> tuple[np.ndarray, dict, np.ndarray, float]:
    """What both kinds of evidence read from a front-view frame: the mask (H,W) bool, the projected
    leg chains ``{"L"|"R": (3,2)}`` (hip, knee, ankle image points), the chain's canonical heights
    (3,) and metres per pixel at the depth of ``depth_bone``."""
    L = body.bone_labels
    marks = landmark_heights(body)
    cz = np.array([marks["hips"] - 0.06, marks["knee"], marks["ankle"]])
    J = body.posed_joints(frame.pose).numpy()
    uv = {s: frame.camera.project(J[[L.index(f"{n}.{s}") for n in ("upperleg01", "lowerleg01", "foot")]])[0]
          for s in "LR"}
    depth = float(frame.camera.project(J[[L.index(depth_bone)]])[1][0])
    return np.asarray(frame.mask) > 0.5, uv, cz, depth / float(frame.camera.fx)


def frame_hint_evidence(body: BodyModel, frame, *, min_cover: float = 0.9, min_gap: float = 0.015,
                        min_span: float = 0.05, min_drop: float = 0.10, max_break: float = 0.03,
                        max_start: float = 0.08, flare_window: float = 0.06,
                        silhouette: np.ndarray | None = None) -> HintEvidence:
    """One frame's evidence (``HintEvidence``). Image rows run from the projected hip joints down to
    the ankles; in each, the pixels between the two leg axes that the posed body's own silhouette
    leaves as background are the gap; a row is tested when its gap is at least ``min_gap`` wide (in
    metres at the legs' depth: a body fitted a little thinner than the person leaves slivers that
    say nothing) and covered when the mask covers ``min_cover`` of it. Cloth is one run of covered
    rows that begins within ``max_start`` metres of the first tested row (cloth hangs from the hips:
    a skirt covers the crotch), with breaks of at most ``max_break``, and reaches ``min_drop``
    metres below the first tested row (the fitted body's crotch): trousers whose fitted crotch sits
    a little high, or feet touching at the ankles, are not cloth. The flare: over the covered rows
    within ``flare_window`` metres above the hem, half the width of the mask's run round the legs'
    midpoint (a hand apart from the cloth is not in it) less the body's extent inside that run; the
    90th percentile of those rows (the hem's lowest row is the front of the hem's ellipse in the
    image, narrower than the cloth above it)."""
    mask, uv, cz, metres_per_px = _front_legs(body, frame, "upperleg01.L")
    top = int(np.ceil(max(uv["L"][0, 1], uv["R"][0, 1])))
    bottom = int(np.floor(min(uv["L"][2, 1], uv["R"][2, 1])))
    rows = np.arange(max(top, 0), min(bottom, mask.shape[0]))
    if len(rows) < 4:
        return HintEvidence(False, False)
    body_only = silhouette if silhouette is not None else body_silhouette(body, frame)  # for widths
    sil = binary_dilation(body_only)  # for the gap: grown by a pixel, a body fitted a little thin
    xl, xr = _leg_axis_x(uv["L"], rows), _leg_axis_x(uv["R"], rows)
    tested, covered = [], []
    for r, a, b in zip(rows, np.minimum(xl, xr), np.maximum(xl, xr)):
        a, b = max(int(np.ceil(a)), 0), min(int(np.floor(b)), mask.shape[1] - 1)
        gap = ~sil[r, a:b + 1]  # between the leg axes, where the body leaves the background
        if gap.sum() * metres_per_px < min_gap:
            continue
        tested.append(r)
        if mask[r, a:b + 1][gap].mean() >= min_cover:
            covered.append(r)
    tested = _without_isolated_top(tested, max_break / metres_per_px)
    covered = [r for r in covered if r >= tested[0]] if tested else []
    if len(tested) < 2 or (tested[-1] - tested[0]) * metres_per_px < min_span:
        return HintEvidence(False, False)
    if not covered or (covered[0] - tested[0]) * metres_per_px > max_start:
        return HintEvidence(True, False)
    hem_row = covered[0]
    for r in covered[1:]:
        if (r - hem_row) * metres_per_px > max_break:
            break
        hem_row = r
    drop = (hem_row - tested[0]) * metres_per_px
    if drop < min_drop:
        return HintEvidence(True, False, drop=drop, rows=(tested[0], hem_row))
    hem_z = float(np.interp(hem_row, uv["L"][:, 1], cz))  # along hip -> knee -> ankle
    widths = []  # the cloth's width beyond the body's over the window above the hem
    for r in [c for c in covered if 0 <= hem_row - c <= flare_window / metres_per_px]:
        centre = int(round(0.5 * (np.interp(r, rows, xl) + np.interp(r, rows, xr))))
        run = _run_around(mask[r], centre)  # the cloth's run (hands apart from it are not cloth)
        inside = np.flatnonzero(body_only[r, run[0]:run[1] + 1]) if run is not None else []
        if len(inside):
            widths.append(max(0.0, ((run[1] - run[0]) - (inside.max() - inside.min())) / 2) * metres_per_px)
    flare = float(np.percentile(widths, 90)) if widths else None
    return HintEvidence(True, True, hem_z, flare, drop, (tested[0], hem_row))


def _without_isolated_top(tested: list[int], max_break_rows: float) -> list[int]:
    """The tested rows less a first run of them that ends more than ``max_break_rows`` above the
    next tested row and spans less than that itself: a notch in the fitted body's crotch, with the
    thighs touching below it (no gap, nothing tested), says nothing about where cloth begins. On the
    green-coat photo with the body fitted a little inside the outline, a 2-row notch 8.7 cm above
    the first gap between the thighs made the coat's cloth begin past ``max_start``."""
    for i in range(1, len(tested)):
        if tested[i] - tested[i - 1] > max_break_rows:
            return tested[i:] if tested[i - 1] - tested[0] < max_break_rows else tested
    return tested


def _run_around(row: np.ndarray, x: int) -> tuple[int, int] | None:
    """The run of True pixels of ``row`` that contains column ``x`` (first, last), or None."""
    if not 0 <= x < len(row) or not row[x]:
        return None
    off = np.flatnonzero(~row)
    left, right = off[off < x], off[off > x]
    return (int(left.max()) + 1 if len(left) else 0, int(right.min()) - 1 if len(right) else len(row) - 1)


def frame_leg_evidence(body: BodyModel, frame, *, min_flare: float = MIN_LEG_FLARE, min_span: float = 0.10,
                       max_break: float = 0.03, min_rows: float = 0.5,
                       silhouette: np.ndarray | None = None) -> LegEvidence:
    """One frame's evidence about wide trouser legs (``LegEvidence``). Image rows run from the lower
    projected knee down to the higher ankle; in each, for each leg, the run of mask pixels that holds
    the projected leg axis is compared with the run of the posed body's own silhouette that holds it
    (a row counts only where the two legs' runs are apart, in the mask and in the body: legs
    together, or a skirt, say nothing about each leg). The row's flare is half the difference of the
    widths in metres at the legs' depth, averaged over the two legs. Testable: at least ``min_rows``
    of the rows count. Wide: the flare reaches ``min_flare`` in a run of counted rows (breaks of at
    most ``max_break``; the longest run) that spans ``min_span``: the mask stands out round the lower
    legs over a length, which a body fitted a little thin (a pixel or two) does not do. The hem is
    the run's lowest row, the flare the 90th percentile of the rows' flares in the 5 cm above it."""
    mask, uv, cz, metres_per_px = _front_legs(body, frame, "lowerleg01.L")
    top = int(np.ceil(max(uv["L"][1, 1], uv["R"][1, 1])))
    bottom = int(np.floor(min(uv["L"][2, 1], uv["R"][2, 1])))
    rows = np.arange(max(top, 0), min(bottom, mask.shape[0]))
    if len(rows) * metres_per_px < min_span:
        return LegEvidence(False, False)
    sil = silhouette if silhouette is not None else body_silhouette(body, frame)
    axis = {s: _leg_axis_x(uv[s], rows) for s in "LR"}
    counted, flares = [], []
    for i, r in enumerate(rows):
        per_leg = []
        for s, o in (("L", "R"), ("R", "L")):
            x, other = int(round(axis[s][i])), axis[o][i]
            m, b = _run_around(mask[r], x), _run_around(sil[r], x)
            if m is None or b is None or m[0] <= other <= m[1] or b[0] <= other <= b[1]:
                break
            per_leg.append(((m[1] - m[0]) - (b[1] - b[0])) / 2 * metres_per_px)
        if len(per_leg) == 2:
            counted.append(r)
            flares.append(float(np.mean(per_leg)))
    if len(counted) < min_rows * len(rows):
        return LegEvidence(False, False)
    wide_rows = [r for r, f in zip(counted, flares) if f >= min_flare]
    runs: list[list[int]] = []
    for r in wide_rows:  # runs of wide rows, with breaks of at most max_break
        if runs and (r - runs[-1][-1]) * metres_per_px <= max_break:
            runs[-1].append(r)
        else:
            runs.append([r])
    run = max(runs, key=lambda rr: rr[-1] - rr[0], default=None)
    span = 0.0 if run is None else (run[-1] - run[0]) * metres_per_px
    if run is None or span < min_span:
        return LegEvidence(True, False, span=span)
    hem_row = run[-1]
    near = [f for r, f in zip(counted, flares) if 0 <= (hem_row - r) * metres_per_px <= 0.05]
    hem_z = float(np.interp(hem_row, uv["L"][:, 1], cz))
    return LegEvidence(True, True, hem_z, float(np.percentile(near, 90)), span)


def frame_torso_evidence(body: BodyModel, frame, *, rows_per_metre: float = 100.0, max_standoff: float = 0.08,
                         min_rows: float = 0.5, silhouette: np.ndarray | None = None) -> TorsoEvidence:
    """One frame's evidence about cloth off the torso (``TorsoEvidence``). Image rows at canonical
    heights from the waist up to ``torso_top_height`` (one every 1 / ``rows_per_metre`` metres),
    placed along the posed spine (``_TORSO_CHAIN``'s projected joints at their canonical heights);
    in each, the run of mask pixels that holds the spine is compared with the run of the posed
    body's own silhouette that holds it: half the difference of the widths, in metres at the
    spine's depth, is the row's standoff. A row counts when both runs exist and the standoff is
    below ``max_standoff`` (a hand or an arm against the torso in the mask but apart from it in the
    fitted body, or the reverse, is not cloth). Testable: at least ``min_rows`` of the rows count;
    the standoff is their median, so a few rows where an arm joins do not decide it."""
    J = body.canonical_joints.numpy()
    L = body.bone_labels
    idx = [L.index(n) for n in _TORSO_CHAIN]
    cz = J[idx, 2]
    uv, depth = frame.camera.project(body.posed_joints(frame.pose).numpy()[idx])
    mask = np.asarray(frame.mask) > 0.5
    sil = silhouette if silhouette is not None else body_silhouette(body, frame)
    metres_per_px = float(depth[0]) / float(frame.camera.fx)
    top = torso_top_height(body)
    heights = np.linspace(cz[0], top, max(2, int(round((top - cz[0]) * rows_per_metre)) + 1))
    standoffs = []
    for z in heights:
        r, x = int(round(np.interp(z, cz, uv[:, 1]))), int(round(np.interp(z, cz, uv[:, 0])))
        if not 0 <= r < mask.shape[0]:
            continue
        m, b = _run_around(mask[r], x), _run_around(sil[r], x)
        if m is None or b is None:
            continue
        s = ((m[1] - m[0]) - (b[1] - b[0])) / 2 * metres_per_px
        if s < max_standoff:
            standoffs.append(s)
    if not standoffs or len(standoffs) < min_rows * len(heights):
        return TorsoEvidence(False)
    return TorsoEvidence(True, float(np.median(standoffs)))


MIN_FLAP = 0.04  # metres a side of the mask must stand out past the body to be a flap


def frame_flap_evidence(body: BodyModel, frame, *, rows_per_metre: float = 100.0, min_flap: float = MIN_FLAP,
                        min_span: float = 0.15, max_break: float = 0.03, min_rows: float = 0.5,
                        silhouette: np.ndarray | None = None) -> FlapEvidence:
    """One frame's evidence about flaps (``FlapEvidence``). Image rows at canonical heights from
    ``torso_top_height`` down to the knees, one every 1 / ``rows_per_metre`` metres, placed along
    the posed spine and, below the hips, along the midpoint of the hips and then the knees. For
    each side of the body, the run of mask pixels that holds that side's anchor (the spine above
    the hips, that side's thigh axis below) is read against the posed body's own silhouette
    (arms included) inside that run: how far the mask's outer end lies past the body's outermost
    pixel on that side, in metres at the waist's depth. An arm or a hand against the side is in
    both and adds nothing. A side has a flap when its standoff reaches ``min_flap`` over a run of
    rows (breaks of at most ``max_break``; the longest run) spanning ``min_span`` of height: the
    symmetric standoff of a closed coat (``frame_torso_evidence``) is centimetres, a flap a hand
    or more. Its standoff is the 75th percentile of the run's rows (clipped to 30 cm)."""
    L = body.bone_labels
    J = body.canonical_joints.numpy()
    P = body.posed_joints(frame.pose).numpy()
    idx = lambda n: L.index(n)  # noqa: E731
    hips_c = 0.5 * (J[idx("upperleg01.L")] + J[idx("upperleg01.R")])
    knees_c = 0.5 * (J[idx("lowerleg01.L")] + J[idx("lowerleg01.R")])
    chain = [P[idx(n)] for n in reversed(_TORSO_CHAIN)] + [0.5 * (P[idx("upperleg01.L")] + P[idx("upperleg01.R")]),
                                                           0.5 * (P[idx("lowerleg01.L")] + P[idx("lowerleg01.R")])]
    cz = np.array([J[idx(n), 2] for n in reversed(_TORSO_CHAIN)] + [hips_c[2], knees_c[2]])  # decreasing
    uv, depth = frame.camera.project(np.array(chain))
    legs = {s: frame.camera.project(P[[idx(f"upperleg01.{s}"), idx(f"lowerleg01.{s}")]])[0] for s in "LR"}
    leg_z = np.array([hips_c[2], knees_c[2]])
    outward = {"L": np.sign(legs["L"][0, 0] - legs["R"][0, 0]) or 1.0}
    outward["R"] = -outward["L"]
    mask = np.asarray(frame.mask) > 0.5
    sil = silhouette if silhouette is not None else body_silhouette(body, frame)
    metres_per_px = float(depth[len(_TORSO_CHAIN) - 1]) / float(frame.camera.fx)  # at spine03, the waist
    top = torso_top_height(body)
    heights = np.linspace(top, knees_c[2], max(2, int(round((top - knees_c[2]) * rows_per_metre)) + 1))
    read = {"L": [], "R": []}  # (height, standoff) of the rows read on each side
    for z in heights:
        r = int(round(np.interp(-z, -cz, uv[:, 1])))
        if not 0 <= r < mask.shape[0]:
            continue
        for s in "LR":
            if z >= hips_c[2]:
                x = np.interp(-z, -cz, uv[:, 0])
            else:
                x = np.interp(-z, -leg_z, legs[s][:, 0])
            run = _run_around(mask[r], int(round(x)))
            if run is None:
                continue
            inside = np.flatnonzero(sil[r, run[0]:run[1] + 1])
            if not len(inside):
                continue
            past = (run[1] - run[0] - inside.max()) if outward[s] > 0 else inside.min()
            read[s].append((float(z), past * metres_per_px))
    if min(len(read["L"]), len(read["R"])) < min_rows * len(heights):
        return FlapEvidence(False)
    found = {}
    for s in "LR":
        runs: list[list[tuple[float, float]]] = []
        for z, v in read[s]:
            if v < min_flap:
                continue
            if runs and runs[-1][-1][0] - z <= max_break + 1.0 / rows_per_metre:
                runs[-1].append((z, v))
            else:
                runs.append([(z, v)])
        best = max(runs, key=lambda rr: rr[0][0] - rr[-1][0], default=None)
        if best is not None and best[0][0] - best[-1][0] >= min_span:
            found[s] = (float(min(np.percentile([v for _, v in best], 75), 0.30)), best[0][0], best[-1][0])
    return FlapEvidence(True, found.get("L"), found.get("R"))


def spread_frames(frames, max_frames: int = 8) -> list:
    """Up to ``max_frames`` of ``frames`` spread evenly over the sequence (first and last included),
    in order: the frames the layer's evidence is read from."""
    picks = np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).round().astype(int)
    return [frames[i] for i in sorted(set(picks.tolist()))]


def scene_hint_evidence(body: BodyModel, frames, *, max_frames: int = 8, silhouettes: list | None = None,
                        **thresholds) -> list[HintEvidence]:
    """``frame_hint_evidence`` (with its ``thresholds``), with ``frame_leg_evidence`` as its
    ``legs``, ``frame_torso_evidence`` as its ``torso`` and ``frame_flap_evidence`` as its
    ``flaps``, for the frames ``spread_frames`` picks. ``silhouettes``: the posed body's own in
    those frames (``body_silhouette``), when the caller has them."""
    picked = spread_frames(frames, max_frames)
    if silhouettes is None:
        silhouettes = [body_silhouette(body, f) for f in picked]
    return [replace(frame_hint_evidence(body, f, silhouette=sil, **thresholds),
                    legs=frame_leg_evidence(body, f, silhouette=sil),
                    torso=frame_torso_evidence(body, f, silhouette=sil),
                    flaps=frame_flap_evidence(body, f, silhouette=sil))
            for f, sil in zip(picked, silhouettes, strict=True)]


def torso_standoff(evidence: list[HintEvidence]) -> float | None:
    """The median torso standoff over the frames whose torso is testable, or None when none is."""
    vals = [e.torso.standoff for e in evidence if e.torso is not None and e.torso.testable]
    return float(np.median(vals)) if vals else None


def hint_from_evidence(body: BodyModel, evidence: list[HintEvidence], *, min_share: float = 0.5) -> VolumeHint | None:
    """A VolumeHint from the frames' evidence, or None for tight clothing. Cloth round both legs (a
    skirt, a dress, a coat) when at least ``min_share`` of the testable frames show cloth in the gap
    between the legs (a walk's frames with the legs together test nothing; one frame where trousers
    look like cloth does not make a skirt): the hem is the median over the cloth frames (canonical
    height along the legs), the flare the median of their flares (clipped to 2-15 cm), the top the
    waist; but when the cloth also stands off the torso (``torso_standoff`` of at least
    ``MIN_TORSO_STANDOFF``: a coat, a dress) the top is ``torso_top_height`` and the standoff there
    the torso's (clipped to 1.2-5 cm), so the layer covers the chest too. Otherwise wide trouser legs (``two_legs``) when at least ``min_share`` of the frames
    whose legs are testable show them wide (``LegEvidence``): hem and flare the medians the same
    way, the top the waist."""
    marks = landmark_heights(body)
    testable = [e for e in evidence if e.testable]
    cloth = [e for e in testable if e.cloth]
    if cloth and len(cloth) >= min_share * len(testable):
        hem = float(np.median([e.hem_z for e in cloth]))
        flares = [e.flare for e in cloth if e.flare is not None]
        flare = float(np.clip(np.median(flares) if flares else 0.05, 0.02, 0.15))
        hem = min(hem, marks["hips"] - 0.1)
        torso = torso_standoff(evidence)
        if torso is not None and torso >= MIN_TORSO_STANDOFF:
            top = float(np.clip(torso, 0.012, 0.05))
            return VolumeHint(top_z=torso_top_height(body), hem_z=hem, standoff_top=top, standoff_hem=max(flare, top))
        return VolumeHint(top_z=marks["waist"], hem_z=hem, standoff_hem=flare)
    legs = [e.legs for e in evidence if e.legs is not None and e.legs.testable]
    wide = [e for e in legs if e.wide]
    if not wide or len(wide) < min_share * len(legs):
        return flap_hint(body, evidence, min_share=min_share)
    hem = float(np.clip(np.median([e.hem_z for e in wide]), marks["ankle"] + 0.02, marks["hips"] - 0.1))
    flare = float(np.clip(np.median([e.flare for e in wide]), 0.02, 0.15))
    return VolumeHint(top_z=marks["waist"], hem_z=hem, standoff_hem=flare, two_legs=True)


def flap_hint(body: BodyModel, evidence: list[HintEvidence], *, min_share: float = 0.5) -> VolumeHint | None:
    """A layer for flaps (``FlapEvidence``) when nothing else is loose: per side of the body, a flap
    when at least ``min_share`` of the frames whose flaps are testable show one there, standing
    out by the median of their standoffs. The layer covers the torso from ``torso_top_height``
    (an open jacket's body; where it is open the learned opacity shows what is under it) down
    past the lowest flap's median hem, 1.2 cm off the body, bulging sideways by each side's
    standoff (``VolumeHint.side_left`` / ``side_right``). None without a flap."""
    flaps = [e.flaps for e in evidence if e.flaps is not None and e.flaps.testable]
    sides, hems = {}, []
    for name in ("left", "right"):
        shown = [getattr(f, name) for f in flaps if getattr(f, name) is not None]
        if shown and len(shown) >= min_share * len(flaps):
            sides[name] = float(np.median([v[0] for v in shown]))
            hems.append(float(np.median([v[2] for v in shown])))
    if not sides:
        return None
    marks = landmark_heights(body)
    top = torso_top_height(body)
    hem = float(np.clip(min(hems), marks["knee"], top - 0.15))
    return VolumeHint(top_z=top, hem_z=hem, standoff_top=0.012, standoff_hem=0.012,
                      side_left=sides.get("left", 0.0), side_right=sides.get("right", 0.0))


def volume_hint_from_masks(body: BodyModel, frames, *, max_frames: int = 8, min_share: float = 0.5,
                           silhouettes: list | None = None, **thresholds) -> VolumeHint | None:
    """A VolumeHint from front-view ``frames`` (each with ``mask``, ``camera``, ``pose``), or None
    for tight clothing: ``hint_from_evidence`` over ``scene_hint_evidence``."""
    evidence = scene_hint_evidence(body, frames, max_frames=max_frames, silhouettes=silhouettes, **thresholds)
    return hint_from_evidence(body, evidence, min_share=min_share)


def neighbour_strain(means: torch.Tensor, edges: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
    """The layer's sheet regulariser: mean over grid edges ``(E,2)`` (rows of ``means``) of
    ``(|x_i - x_j| / rest - 1)^2``, the squared relative change of each neighbour distance from its
    canonical ``rest`` length (E,). Zero at rest; stretching and squeezing both cost."""
    if len(edges) == 0:
        return means.sum() * 0.0
    d = (means[edges[:, 0]] - means[edges[:, 1]]).norm(dim=1)
    return ((d / rest - 1.0) ** 2).mean()


LAYER_BONES = (*_TORSO_CHAIN, "upperarm01.L", "upperarm01.R", "upperleg01.L", "upperleg01.R", "lowerleg01.L",
               "lowerleg01.R", "foot.L", "foot.R")


def missing_layer_bones(body: BodyModel) -> list[str]:
    """The bones the layer is placed along (``LAYER_BONES``) that ``body`` lacks ([] for Anny)."""
    return [b for b in LAYER_BONES if b not in body.bone_labels]


# the weight filter's sigma on the 1.4 cm grid it was tuned on (92 columns): 3 rows (4.2 cm) and 6
# columns (a fifteenth of the way round)
DIFFUSION_REFERENCE = (0.014, 92, 3.0, 6.0)


def weight_diffusion(row_step: float, cols: int, width: float = 1.0) -> tuple[float, float]:
    """The layer's weight filter sigma (rows of ``row_step``, columns of ``cols`` round the layer)
    that spans what it spans on the grid it was tuned on: kept in grid steps, rows every 1 cm
    instead of 1.4 cm narrowed the blend by a third, and the walk stretched the coat's layer by
    2.1 times instead of 1.6 (a chest-high layer; docs/loose_clothing.md, "Rows every centimetre").
    ``width``: that many times wider in rows and columns alike (a one-tube layer's
    ``AvatarConfig.garment_filter_one_tube``)."""
    step0, cols0, rows_sigma, cols_sigma = DIFFUSION_REFERENCE
    return rows_sigma * (step0 / row_step) * width, cols_sigma * (cols / cols0) * width


def layer_columns(row_step: float) -> int:
    """The columns of a layer whose rows are ``row_step`` apart: spaced alike round the hips (64 at
    2 cm), even (two tubes split them), at least 16."""
    return max(16, 2 * int(round(32 * 0.02 / row_step)))


def garment_layer_for(body: BodyModel, frames, mode: str, what: str = "scene",
                      row_step: float = GARMENT_LAYER_STEP,
                      one_tube_filter: float = ONE_TUBE_FILTER) -> GarmentLayer | None:
    """The layer a run asks for (``AvatarConfig.garment_layer``): ``off`` none; ``auto`` the layer of
    the masks' volume hint (``volume_hint_from_masks`` over ``frames``), none for tight clothing;
    ``on`` the same, an error when the masks show no loose clothing. A body without Anny's leg
    chain (``missing_layer_bones``: an SMPL body from a dataset loader) gets none with ``auto``
    and a clear error with ``on``. ``row_step``: metres between the layer's rows
    (``AvatarConfig.garment_layer_step``; ``layer_columns`` round it); ``one_tube_filter``: a
    one-tube layer's weight filter against ``weight_diffusion`` (``build_garment_layer``). A one-tube layer is then
    stretched sideways row by row where the masks reach past it (``layer_profile.fit_side_profile``)."""
    if mode not in GARMENT_LAYER_MODES:
        raise ValueError(f"avatar.garment_layer must be one of {', '.join(GARMENT_LAYER_MODES)}, found {mode!r}")
    if mode == "off":
        return None
    missing = missing_layer_bones(body)
    if missing:  # e.g. an SMPL body from a dataset loader: the layer is placed along Anny's leg chain
        if mode == "on":
            raise ValueError(f"avatar.garment_layer=on: {what}: its body model has no {', '.join(missing)} "
                             f"bones; the garment layer needs the Anny body's leg chain")
        return None
    picked = spread_frames(frames)
    silhouettes = [body_silhouette(body, f) for f in picked]  # read by the hint and the side profile
    hint = volume_hint_from_masks(body, picked, silhouettes=silhouettes)
    if hint is None:
        if mode == "on":
            raise ValueError(f"avatar.garment_layer=on: {what}: the masks of its {len(frames)} training frames show "
                             f"no loose clothing (in fewer than half of the frames that can show it does the mask "
                             f"cover the gap the body leaves between the legs, or stand out round each lower leg "
                             f"by {100 * MIN_LEG_FLARE:.1f} cm or more), so there is nowhere to put a garment layer; use "
                             f"avatar.garment_layer=auto to train without one in that case")
        return None
    from .layer_profile import fit_side_profile  # it builds layers: imported here, not at the top

    layer = build_garment_layer(body, hint, row_step=row_step, one_tube_filter=one_tube_filter)
    fitted = fit_side_profile(body, hint, picked, row_step=row_step, layer=layer, silhouettes=silhouettes,
                              one_tube_filter=one_tube_filter)
    return layer if fitted is hint else build_garment_layer(body, fitted, row_step=row_step,
                                                            one_tube_filter=one_tube_filter)
