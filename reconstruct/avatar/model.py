"""The animatable Gaussian avatar: canonical feature map S, decoder G, LBS to observation space.

One Gaussian sits on each valid texel of the canonical positional UV map (paper A.1.1). The
decoder's input is [S(uv), S(uv), uv] in Stage I and [S(uv), P(uv), uv] in Stage II (Eq. 1, 12),
the feature maps sampled bilinearly at the UV of a decode node. Outputs: x_c = x + Δx,
n_c = n + Δn (renormalised), colour, scale.

Decode nodes. With ``decode_resolution`` equal to the Gaussians' map (the paper), each Gaussian is
its own node. With a coarser one, the nodes are the cells of the coarse grid around the Gaussians'
texels, and each Gaussian takes the bilinear blend of its four nodes' raw outputs (Δx, Δn, colour
logit, scale logit) at its own texel centre, applied to its own surface point and normal: the
decoder runs 4x fewer times than there are Gaussians. A per-Gaussian colour residual (a logit
offset, ``color_residual``) carries detail finer than the decode grid. ``canonical(index=...)``
decodes only the nodes that the chosen Gaussians need (a training step skips the Gaussians that
face away from its camera).

Shape. ``splat="sphere"`` is the paper's: isotropic, identity rotation, opacity 1. ``"disc"``:
a flat Gaussian in the tangent plane of the decoded normal, its in-plane axes along the UV map's
u and v steps with standard deviations ``m * (step_u, step_v)`` and ``disc_thickness`` times the
smaller along the normal; ``m`` in [scale_floor, scale_range] from the scale head, so that with the
floor neighbours always overlap. Posed, the frame follows the LBS matrix: the normal by its
cofactor, the u axis by the matrix itself, re-orthogonalised. Scales are relative to each
Gaussian's own texel step, which varies by a factor of three over the body (the atlas gives the
head more texels per area than the shins).

Garment layer (optional, ``layer``: a ``garment_layer.GarmentLayer``; docs/loose_clothing.md). Its
M Gaussians come AFTER the N body Gaussians, so body indices are unchanged: every per-Gaussian
buffer (positions, normals, skinning weights, canonical inverses, spacing, tangents, steps) and the
colour residual have N + M rows, and ``canonical(index=...)``, ``facing``, ``lbs_matrices``,
``pose_with`` and ``splats`` take indices into N + M. The layer has its own feature map
``layer_features`` (1, C, rows, cols) over its grid (one feature vector per grid point), decoded by the same
decoder with the same input width: [L, L, uv] where the layer's "uv" lies on an annulus of radius
1.5-2.5 round the origin (angle = the column's angle round the tube, radius = the row), outside the
body's [-1, 1] square and continuous across the seam -- so the decoder can tell layer from body and
the body's inputs are exactly today's. Stage II's pose features are the body's (a map over its UV
atlas): the layer decodes [L, L, uv] in both stages. Layer Gaussians have a learned opacity
(``sigmoid(garment_opacity_gain * layer_opacity)``); body Gaussians stay opaque. Posed, the layer's
Gaussians are kept ``garment_clearance`` outside the posed body (``layer_clearance``), and its discs
grow round the ring and down the column as far as the pose stretches its grid there
(``layer_stretch_of``, ``garment_stretch_scales``): skinned with weights blended across the legs,
the cloth stretches where they part, and discs sized for the canonical grid let the background
through between its rows. Without a layer
nothing of this exists and the model is the one before the layer (same parameters, same outputs).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..body.base import BodyModel
from ..body.lbs import apply_normals, apply_points, blend, safe_normalize
from ..body.uv_map import UVMap, build_uv_map, texel_frames, texel_neighbours, texel_spacing
from .config import AvatarConfig
from .decoder import GaussianDecoder
from .garment_layer import GARMENT_PART, GarmentLayer, grid_steps, interpolation_matrix
from .gaussian_sets import CanonicalGaussians, PosedGaussians, frame_quaternions
from .layer_clearance import covered_ids, push_out
from .layer_nodes import layer_nodes
from .pose_encoder import PoseEncoder

LAYER_SKIN_SUPPORT = 1e-3  # bones the garment layer's learned skinning may reweight: weight above this somewhere on it


def _bilinear_nodes(texel_rc: np.ndarray, fine: int, coarse: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For texels of a ``fine`` map, their four surrounding cells of a ``coarse`` grid over the same
    UV square and bilinear weights at the texel centre: (nodes (M,2) row, col of the cells used;
    (N,4) indices into them; (N,4) weights summing to 1)."""
    pos = (texel_rc.astype(np.float64) + 0.5) * coarse / fine - 0.5  # (row, col) in coarse cell units
    base = np.floor(pos).astype(np.int64)
    frac = pos - base
    rows, cols, ws = [], [], []
    for dr in (0, 1):
        for dc in (0, 1):
            rows.append(np.clip(base[:, 0] + dr, 0, coarse - 1))
            cols.append(np.clip(base[:, 1] + dc, 0, coarse - 1))
            ws.append((frac[:, 0] if dr else 1 - frac[:, 0]) * (frac[:, 1] if dc else 1 - frac[:, 1]))
    flat = np.stack(rows, 1) * coarse + np.stack(cols, 1)
    ids, inverse = np.unique(flat, return_inverse=True)
    return np.stack([ids // coarse, ids % coarse], 1), inverse.reshape(flat.shape), np.stack(ws, 1)


def _edge_lengths(points: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """(E,) lengths of the grid edges ``edges`` (E,2) between ``points`` (the layer's rest lengths)."""
    return (points[edges[:, 0]] - points[edges[:, 1]]).norm(dim=1)


def _layer_uv(rows: int, cols: int) -> torch.Tensor:
    """(rows*cols, 2) the layer's positional decoder input: column angle round an annulus whose radius
    goes from 1.5 (top row) to 2.5 (hem), outside the body's [-1, 1]^2 (max(|x|, |y|) >= 1.5 / sqrt 2)."""
    r = torch.arange(rows, dtype=torch.float64)[:, None].expand(rows, cols)
    theta = (torch.arange(cols, dtype=torch.float64) * (2 * math.pi / cols))[None].expand(rows, cols)
    radius = 1.5 + r / max(rows - 1, 1)
    return torch.stack([radius * torch.cos(theta), radius * torch.sin(theta)], -1).reshape(-1, 2).float()


class AvatarModel(nn.Module):
    def __init__(self, body: BodyModel, config: AvatarConfig | None = None, uv_map: UVMap | None = None,
                 layer: GarmentLayer | None = None) -> None:
        super().__init__()
        self.config = config = config or AvatarConfig()
        uv = uv_map or build_uv_map(body, config.gaussian_resolution)
        if uv.resolution != config.gaussian_resolution:
            raise ValueError(f"UV map resolution {uv.resolution} != AvatarConfig.gaussian_resolution {config.gaussian_resolution}")
        self.uv_map = uv
        self.body_name = body.name
        R = uv.resolution
        grid_of = lambda rc, res: torch.stack([(rc[:, 1] + 0.5) / res * 2 - 1, (rc[:, 0] + 0.5) / res * 2 - 1], dim=1)
        rc = torch.as_tensor(uv.texel_rc, dtype=torch.float32)
        self.register_buffer("uv_grid", grid_of(rc, R))  # (N,2) grid_sample coordinates (x = column, y = row)
        Rd = config.decoded_resolution
        self.interpolated = Rd != R
        if self.interpolated:
            nodes, idx, w = _bilinear_nodes(uv.texel_rc, R, Rd)
            self.register_buffer("node_grid", grid_of(torch.as_tensor(nodes, dtype=torch.float32), Rd), persistent=False)
            self.register_buffer("node_index", torch.as_tensor(idx), persistent=False)
            self.register_buffer("node_weights", torch.as_tensor(w, dtype=torch.float32), persistent=False)
        else:
            self.register_buffer("node_grid", self.uv_grid.clone(), persistent=False)
        # the garment layer's rows follow the body's in every per-Gaussian buffer
        self.layer = layer
        self.num_body = len(uv)
        if layer is not None and layer.weights.shape[1] != uv.weights.shape[1]:
            raise ValueError(f"garment layer: skinning weights over {layer.weights.shape[1]} bones, the body "
                             f"{self.body_name!r} has {uv.weights.shape[1]}")

        def with_layer(body_rows: torch.Tensor, layer_rows) -> torch.Tensor:
            """The body's rows, then the layer's (``layer_rows()``) when there is a layer."""
            return body_rows if layer is None else torch.cat([body_rows, layer_rows().to(body_rows.dtype)])

        self.register_buffer("base_positions", with_layer(uv.positions.float(), lambda: layer.positions))
        self.register_buffer("base_normals", with_layer(uv.normals.float(), lambda: layer.normals))
        self.register_buffer("skin_weights", with_layer(uv.weights.float(), lambda: layer.weights))
        canonical_inverse = torch.linalg.inv(blend(uv.weights, body.canonical_transforms))
        canonical_inverse = with_layer(canonical_inverse, lambda: torch.linalg.inv(
            blend(layer.weights.to(uv.weights.dtype), body.canonical_transforms)))
        self.register_buffer("canonical_inverse", canonical_inverse.float())
        spacing = texel_spacing(uv).float()
        self.register_buffer("texel_spacing", with_layer(spacing, lambda: layer.spacing))
        if config.splat == "disc":
            tangent, steps = texel_frames(uv)
            tangent = with_layer(tangent.float(), lambda: layer.tangents)
            steps = with_layer(steps.float(), layer.steps if layer is not None else None)
            self.register_buffer("base_tangents", tangent.float(), persistent=False)
            self.register_buffer("texel_steps", steps.float(), persistent=False)  # (N,2) 3D length of one texel step along u, v
        C, Rf = config.feature_channels, config.feature_resolution
        self.features = nn.Parameter(torch.randn(1, C, Rf, Rf) * config.feature_init_std)
        self.decoder = GaussianDecoder(2 * C + 2, config.hidden, config.trunk_layers, config.skip_layer, config.head_layers,
                                       init=config.decoder_init)
        if config.color_residual:
            # per Gaussian, trained with the decoder (it lives in the decoder's parameter group)
            self.decoder.color_residual = nn.Parameter(torch.zeros(self.num_gaussians, 3))
        init = (config.init_scale_factor - config.scale_floor) / (config.scale_range - config.scale_floor)
        with torch.no_grad():
            self.decoder.heads["scale"][-1].bias.fill_(math.log(init / (1 - init)))
        self.pose_encoder: nn.Module | None = None
        if layer is not None:  # created after everything above: the body's initial values are the same
            rows, cols = layer.grid_shape
            # the layer's decoder runs at its nodes (layer_nodes.py: every garment_decode_every-th row
            # and column; every Gaussian at 1), its feature map holds one feature per node
            nodes = layer_nodes(rows, cols, layer.tubes, config.garment_decode_every)
            self.layer_features = nn.Parameter(torch.randn(1, C, *nodes.shape) * config.feature_init_std)
            logit = math.log(config.garment_opacity_init / (1 - config.garment_opacity_init))
            self.layer_opacity = nn.Parameter(torch.full((layer.num_gaussians,), logit / config.garment_opacity_gain))
            # (M,) layer Gaussians taken out of the garment for good (``trim_layer``: under the hem,
            # where the layer drew the legs): opacity 0 whatever their parameter, no gradient
            self.register_buffer("layer_trimmed", torch.zeros(layer.num_gaussians, dtype=torch.bool))
            # (M,) layer Gaussians the person's outline cut away: training made them transparent where
            # they stood past the silhouette (a side of the layer wider than the photo's skirt). Still
            # the cloth's place: the body under them takes its colour (``layer_cover``); set by Stage
            # I's finish (``mark_outline_cut``), kept in checkpoints
            self.register_buffer("layer_outline_cut", torch.zeros(layer.num_gaussians, dtype=torch.bool))
            rc = torch.stack(torch.meshgrid(torch.arange(rows), torch.arange(cols), indexing="ij"), -1).reshape(-1, 2)
            self.register_buffer("layer_rc", rc, persistent=False)  # (M,2) row, column of each grid point
            node_rc = torch.as_tensor(nodes.grid_rc)
            self.register_buffer("layer_node_rc", torch.stack(torch.meshgrid(
                torch.arange(nodes.shape[0]), torch.arange(nodes.shape[1]), indexing="ij"), -1).reshape(-1, 2),
                persistent=False)  # (K,2) row, column of each node on the feature map
            self.register_buffer("layer_uv", _layer_uv(rows, cols)[node_rc[:, 0] * cols + node_rc[:, 1]],
                                 persistent=False)  # (K,2) the nodes' annulus coordinates
            self.layer_interpolated = config.garment_decode_every > 1
            if self.layer_interpolated:
                self.register_buffer("layer_node_index", torch.as_tensor(nodes.index), persistent=False)  # (M,4)
                self.register_buffer("layer_node_weights", torch.as_tensor(nodes.weights, dtype=torch.float32),
                                     persistent=False)  # (M,4)
            edges = torch.as_tensor(layer.edges())
            self.register_buffer("layer_edges", edges + self.num_body, persistent=False)  # (E,2) Gaussian ids
            self.register_buffer("layer_rest", _edge_lengths(layer.positions.float(), edges), persistent=False)
            # learned skinning (see layer_skin_weights): log-factors per bone the layer follows, per
            # tube, at knots down the layer every garment_skin_knot_step (rows interpolate them);
            # zero = the layer's built weights
            support = torch.nonzero(layer.weights.amax(0) > LAYER_SKIN_SUPPORT)[:, 0]
            row_z = layer.positions[::cols, 2].double().numpy()  # each row is at one canonical height
            knots = np.linspace(row_z[0], row_z[-1], max(2, int(np.ceil(
                (row_z[0] - row_z[-1]) / config.garment_skin_knot_step - 1e-9)) + 1))
            self.register_buffer("layer_skin_support", support, persistent=False)  # (S,) bone ids
            self.register_buffer("layer_skin_rows", torch.as_tensor(interpolation_matrix(knots, row_z),
                                                                     dtype=torch.float32), persistent=False)  # (R,K)
            # and round each tube at garment_skin_sectors sector centres (columns interpolate the two
            # nearest, wrapping round): each Gaussian mixes two (row, tube, sector) cells
            per_tube = cols // layer.tubes
            sectors = min(config.garment_skin_sectors, per_tube)  # at most one per column
            theta = (rc[:, 1] % per_tube).double() * sectors / per_tube  # in sector units
            p0 = theta.floor().long()
            frac = (theta - p0).float() if sectors > 1 else torch.zeros(len(rc))  # one sector: one cell
            first = rc[:, 0] * (layer.tubes * sectors) + (rc[:, 1] // per_tube) * sectors
            self.register_buffer("layer_skin_cells", torch.stack([first + p0 % sectors, first + (p0 + 1) % sectors], 1),
                                 persistent=False)  # (M,2) the two (row, tube, sector) cells of each Gaussian
            self.register_buffer("layer_skin_mix", torch.stack([1 - frac, frac], 1), persistent=False)  # (M,2)
            self.register_buffer("canonical_transforms", body.canonical_transforms.float(), persistent=False)
            self.layer_skin_sectors = sectors
            self.layer_skin_logit = nn.Parameter(torch.zeros(len(knots), layer.tubes * sectors, len(support)))
            # the body Gaussians the layer is kept clear of (layer_clearance.py)
            self.register_buffer("layer_clear_ids", torch.as_tensor(covered_ids(uv.parts)), persistent=False)  # (U,)

    @property
    def num_gaussians(self) -> int:
        return int(self.base_positions.shape[0])

    @property
    def num_layer(self) -> int:
        """How many garment-layer Gaussians follow the body's (0 without a layer)."""
        return 0 if self.layer is None else self.layer.num_gaussians

    @property
    def num_nodes(self) -> int:
        """How many decoder evaluations decode every Gaussian."""
        return int(self.node_grid.shape[0]) + (0 if self.layer is None else int(self.layer_node_rc.shape[0]))

    def layer_param_groups(self, lr_features: float, lr_opacity: float, lr_skinning: float = 0.0) -> list[dict]:
        """Adam parameter groups of the garment layer (its feature map, at the body feature map's rate;
        its opacity parameters; with ``lr_skinning`` > 0 its learned skinning, ``layer_skin_logit``)
        for a stage plan; [] without a layer. The skinning factors are frozen (no gradient) when
        ``lr_skinning`` is 0, so that the plan's steps reuse the layer's weights (``_layer_skinning``)."""
        if self.layer is None:
            return []
        self.layer_skin_logit.requires_grad_(lr_skinning > 0)
        groups = [{"params": [self.layer_features], "lr": lr_features, "name": "layer_features"},
                  {"params": [self.layer_opacity], "lr": lr_opacity, "name": "layer_opacity"}]
        if lr_skinning > 0:
            groups.append({"params": [self.layer_skin_logit], "lr": lr_skinning, "name": "layer_skinning"})
        return groups

    def sample(self, feature_map: torch.Tensor, grid: torch.Tensor | None = None) -> torch.Tensor:
        """(1,C,H,W) map sampled bilinearly at every Gaussian's texel (or at ``grid``) -> (N,C)."""
        grid = self.uv_grid if grid is None else grid
        out = F.grid_sample(feature_map, grid[None, None], mode="bilinear", align_corners=False)
        return out[0, :, 0].T

    def decoder_input(self, pose_features: torch.Tensor | None = None, grid: torch.Tensor | None = None) -> torch.Tensor:
        """[S, S, uv] (Stage I) or [S, P, uv] with P = S + ``pose_features`` (Stage II, Eq. 12) at
        the decode nodes (or at ``grid``)."""
        grid = self.node_grid if grid is None else grid
        s = self.sample(self.features, grid)
        second = s if pose_features is None else self.sample(self.features + pose_features, grid)
        return torch.cat([s, second, grid], dim=1)

    # ----- pose feature injection (Stage II) ------------------------------------------------
    def enable_pose_injection(self, width: int = 16) -> PoseEncoder:
        if self.pose_encoder is None:
            self.pose_encoder = PoseEncoder(self.config.feature_channels, self.config.feature_resolution,
                                            width).to(self.features.device)
        return self.pose_encoder

    def pose_map(self, articulation: torch.Tensor) -> torch.Tensor:
        """(3,R,R) posed positional map (Eq. 13's P_uv) for bone transforms ``articulation`` of a pose
        without its global rotation and translation: the displacement of each texel's surface point
        from its canonical position (zero in the canonical pose)."""
        body = slice(0, self.num_body)  # a map over the body's UV atlas: the garment layer is not in it
        M = self.lbs_matrices(articulation)[body]
        return self.uv_map.scatter(apply_points(M, self.base_positions[body]) - self.base_positions[body])

    def pose_features(self, articulation: torch.Tensor) -> torch.Tensor | None:
        """E(P_uv), the pose-dependent part of P, or None without pose injection."""
        if self.pose_encoder is None:
            return None
        return self.pose_encoder(self.pose_map(articulation)[None])

    # ----- decoding -------------------------------------------------------------------------
    def layer_decoder_input(self, index: torch.Tensor | None = None) -> torch.Tensor:
        """[L, L, uv] of the garment layer's decode nodes (all, or those of ``index``): its own
        feature map at the nodes and their annulus coordinates (``_layer_uv``). Without
        interpolation (``garment_decode_every`` 1) node i is layer Gaussian i."""
        rc = self.layer_node_rc if index is None else self.layer_node_rc[index]
        uv = self.layer_uv if index is None else self.layer_uv[index]
        s = self.layer_features[0][:, rc[:, 0], rc[:, 1]].T  # each node sits on a point of the map
        return torch.cat([s, s, uv], dim=1)

    def _layer_nodes(self, index: torch.Tensor | None):
        """(decoder input at the nodes the layer Gaussians ``index`` (0..M-1) need, the function from
        the decoder's outputs there to those Gaussians' raw outputs)."""
        if not self.layer_interpolated:
            return self.layer_decoder_input(index), (lambda out: out)
        node_index = self.layer_node_index if index is None else self.layer_node_index[index]
        weights = self.layer_node_weights if index is None else self.layer_node_weights[index]
        needed = None
        if index is not None:
            needed, node_index = torch.unique(node_index, return_inverse=True)
        return (self.layer_decoder_input(needed),
                lambda out: {k: (v[node_index] * weights[..., None]).sum(1) for k, v in out.items()})

    def _body_nodes(self, pose_features: torch.Tensor | None, index: torch.Tensor | None):
        """(decoder input at the decode nodes the body Gaussians ``index`` need, the function from the
        decoder's outputs there to those Gaussians' raw outputs)."""
        if not self.interpolated:
            grid = None if index is None else self.node_grid[index]
            return self.decoder_input(pose_features, grid), (lambda out: out)
        node_index = self.node_index if index is None else self.node_index[index]
        weights = self.node_weights if index is None else self.node_weights[index]
        if index is None:
            grid = None
        else:
            needed, node_index = torch.unique(node_index, return_inverse=True)
            grid = self.node_grid[needed]
        return (self.decoder_input(pose_features, grid),
                lambda out: {k: (v[node_index] * weights[..., None]).sum(1) for k, v in out.items()})

    def decode_raw(self, pose_features: torch.Tensor | None = None,
                   index: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The decoder's raw outputs per Gaussian (all, or those of ``index``): evaluated at the
        decode nodes those Gaussians need, interpolated to them when the nodes are coarser. With a
        garment layer its Gaussians' inputs join the body nodes' in one decoder call."""
        if self.layer is None:
            x, finish = self._body_nodes(pose_features, index)
            return finish(self.decoder(x))
        N = self.num_body
        if index is None:
            body_index, layer_index, is_layer = None, None, None
        else:
            is_layer = index >= N
            body_index, layer_index = index[~is_layer], index[is_layer] - N
        parts, finish, n_body = [], None, 0
        if body_index is None or len(body_index):
            x, finish = self._body_nodes(pose_features, body_index)
            parts.append(x)
            n_body = len(x)
        layer_finish = None
        if layer_index is None or len(layer_index):
            x, layer_finish = self._layer_nodes(layer_index)
            parts.append(x)
        out = self.decoder(torch.cat(parts))
        body_out = finish({k: v[:n_body] for k, v in out.items()}) if finish is not None else None
        layer_out = {k: v[n_body:] for k, v in out.items()}
        if layer_finish is not None:
            layer_out = layer_finish(layer_out)
        if body_out is None:
            return layer_out
        merged = {k: torch.cat([body_out[k], layer_out[k]]) for k in out}
        if index is None:
            return merged
        # back to the order of ``index``: the body's rows came first, then the layer's
        order = torch.cat([torch.nonzero(~is_layer)[:, 0], torch.nonzero(is_layer)[:, 0]])
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(len(order), device=order.device)
        return {k: v[inverse] for k, v in merged.items()}

    def opacities(self, index: torch.Tensor | None = None) -> torch.Tensor | None:
        """(N+M,) opacities (of ``index``): 1 for the body, the learned ones for the garment layer;
        None without a layer (every Gaussian opaque)."""
        if self.layer is None:
            return None
        layer = torch.sigmoid(self.config.garment_opacity_gain * self.layer_opacity)
        layer = layer.masked_fill(self.layer_trimmed, 0.0)
        full = torch.cat([torch.ones(self.num_body, dtype=layer.dtype, device=layer.device), layer])
        return full if index is None else full[index]

    def canonical(self, pose_features: torch.Tensor | None = None,
                  index: torch.Tensor | None = None) -> CanonicalGaussians:
        """The canonical Gaussians (all, or those of ``index``: then only their decode nodes run)."""
        out = self.decode_raw(pose_features, index)
        cfg = self.config
        pick = (lambda t: t) if index is None else (lambda t: t[index])
        means = pick(self.base_positions) + cfg.offset_scale * out["offset"]
        normals = F.normalize(pick(self.base_normals) + out["normal_offset"], dim=1, eps=1e-8)
        logit = out["color"]
        if cfg.color_residual:
            logit = logit + cfg.color_residual_gain * pick(self.decoder.color_residual)
        colors = torch.sigmoid(logit)
        rel = torch.sigmoid(out["scale"])
        if cfg.splat == "sphere":
            scales = ((cfg.scale_floor + (cfg.scale_range - cfg.scale_floor) * rel)
                      * pick(self.texel_spacing)[:, None]).expand(-1, 3)
            tangents = None
        else:
            m = cfg.scale_floor + (cfg.scale_range - cfg.scale_floor) * rel  # (n,1)
            steps = pick(self.texel_steps)
            scales = m * torch.cat([steps, cfg.disc_thickness * steps.min(1, keepdim=True).values], 1)
            tangents = pick(self.base_tangents)
        return CanonicalGaussians(means, normals, colors, scales, out["offset"], self.features, tangents, index,
                                  self.opacities(index))

    # ----- posing ---------------------------------------------------------------------------
    def layer_skin_weights(self) -> torch.Tensor:
        """(M,J) the garment layer's skinning weights as trained: its built weights (the body's,
        carried out and diffused over the layer's grid) with each bone of their support scaled by
        ``exp(logit)``, then normalised; ``logit`` is ``layer_skin_logit`` (knots x tubes *
        sectors x bones) interpolated linearly in height to the Gaussian's row and, with more than
        one sector (``AvatarConfig.garment_skin_sectors``), linearly round the tube between the
        two nearest sector centres. With one sector a factor per height and bone is shared round
        the tube, so that what the views teach the front (how far the hem follows the knees rather
        than the hips) holds behind too, where no view reaches; sectors let the front and the
        back differ (an open coat's panels each follow their own thigh). The knots
        (``AvatarConfig.garment_skin_knot_step`` apart) keep neighbouring rows together."""
        w = self.skin_weights[self.num_body:]
        K, cells, S = self.layer_skin_logit.shape
        per_cell = (self.layer_skin_rows @ self.layer_skin_logit.reshape(K, -1)).reshape(-1, S)  # (R*cells, S)
        c, mix = self.layer_skin_cells, self.layer_skin_mix
        factor = per_cell[c[:, 0]] * mix[:, :1] + per_cell[c[:, 1]] * mix[:, 1:]
        scaled = w[:, self.layer_skin_support] * factor.exp()
        w = w.index_copy(1, self.layer_skin_support, scaled)
        return w / w.sum(1, keepdim=True)

    def layer_skinning_prior(self) -> torch.Tensor:
        """Mean squared log-factor of the layer's learned skinning plus the mean squared change
        between neighbouring knots and, with sectors, between neighbouring sectors round each tube:
        the weights stay near the built ones and change smoothly over the cloth."""
        logit = self.layer_skin_logit
        prior = logit.square().mean() + (logit[1:] - logit[:-1]).square().mean()
        if self.layer_skin_sectors > 1:
            K, cells, S = logit.shape
            ring = logit.reshape(K, -1, self.layer_skin_sectors, S)
            prior = prior + (ring - ring.roll(1, dims=2)).square().mean()
        return prior

    def _layer_skinning(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The layer's (M,J) learned weights and (M,4,4) canonical inverses. Where no gradient is
        wanted (evaluation, export, the viewer's snapshots, or frozen factors) they are kept until
        the factors change (``_version`` counts in-place updates: an optimiser's step, a loaded
        checkpoint; ``.to()`` / ``.double()`` give them new storage)."""
        logit = self.layer_skin_logit
        fresh = torch.is_grad_enabled() and logit.requires_grad
        key = (logit.data_ptr(), logit._version, logit.device, logit.dtype)
        if not fresh and getattr(self, "_layer_skin_cache", (None,))[0] == key:
            return self._layer_skin_cache[1]
        w = self.layer_skin_weights()
        inv = torch.linalg.inv(blend(w, self.canonical_transforms.to(w)))
        if not fresh:
            self._layer_skin_cache = (key, (w, inv))
        return w, inv

    def lbs_matrices(self, pose_transforms: torch.Tensor, index: torch.Tensor | None = None) -> torch.Tensor:
        """Per-Gaussian canonical -> observation matrices (N,4,4) for bone transforms (J,4,4) (of
        the Gaussians ``index`` when given). The garment layer's use its learned weights
        (``layer_skin_weights``), and their canonical inverse from those."""
        T = pose_transforms.to(self.skin_weights)
        if self.layer is None:
            w = self.skin_weights if index is None else self.skin_weights[index]
            inv = self.canonical_inverse if index is None else self.canonical_inverse[index]
            return blend(w, T) @ inv
        # the body's rows from the fixed buffers, the layer's from its learned weights (only these
        # carry a gradient to layer_skin_logit)
        nb = self.num_body
        if index is None:
            body, layer = slice(None, nb), slice(None)
        else:
            on_layer = index >= nb
            body, layer = index[~on_layer], index[on_layer] - nb
        w_all, inv_all = self._layer_skinning()
        wl = w_all[layer]
        M_layer = blend(wl, T) @ inv_all[layer]
        M_body = blend(self.skin_weights[body], T) @ self.canonical_inverse[body]
        if index is None:
            return torch.cat([M_body, M_layer])
        M = torch.empty(len(index), 4, 4, dtype=T.dtype, device=T.device)
        return M.index_put((~on_layer,), M_body).index_put((on_layer,), M_layer)

    def facing(self, matrices: torch.Tensor, camera_center, cos_margin: float = 0.25) -> torch.Tensor:
        """Indices of the Gaussians whose posed body-surface normal (LBS ``matrices`` of all the
        Gaussians) does not point away from the camera by more than ``cos_margin`` (cosine of the
        angle past grazing): the ones a view can show. The rest sit on the far side of a closed
        body; a step from that view can skip them."""
        with torch.no_grad():
            M = matrices.detach()
            x = apply_points(M, self.base_positions)
            n = apply_normals(M, self.base_normals)
            c = torch.as_tensor(np.asarray(camera_center), dtype=x.dtype, device=x.device)
            view = safe_normalize(x - c)
            keep = (view * n).sum(1) < cos_margin
            # the garment layer is an open, see-through sheet, not the far side of a closed body:
            # its back shows through wherever its front fades, so every view keeps all of it
            keep[self.num_body:] = True
            return torch.nonzero(keep)[:, 0]

    def layer_seen_from_inside(self, matrices: torch.Tensor, camera_center, index: torch.Tensor | None = None) -> torch.Tensor:
        """(K,) bool over the Gaussians ``index`` (all N+M when None; LBS ``matrices`` of all of
        them): the garment-layer ones whose posed surface normal -- the layer's own, not the learned
        one -- points away from the camera, so that the view sees them from inside the garment."""
        with torch.no_grad():
            ids = torch.arange(self.num_gaussians, device=matrices.device) if index is None else index
            out = torch.zeros(len(ids), dtype=torch.bool, device=matrices.device)
            layer = ids >= self.num_body
            if not bool(layer.any()):
                return out
            lid = ids[layer]
            M = matrices.detach()[lid]
            x = apply_points(M, self.base_positions[lid])
            n = apply_normals(M, self.base_normals[lid])
            c = torch.as_tensor(np.asarray(camera_center), dtype=x.dtype, device=x.device)
            out[layer] = ((c - x) * n).sum(1) < 0
            return out

    def pose(self, canon: CanonicalGaussians, pose_transforms: torch.Tensor) -> PosedGaussians:
        if canon.index is not None and self._holds_layer(canon):
            # a subset's matrices lack the body Gaussians the layer is kept clear of and the rest of
            # the layer's grid, whose stretch sizes its discs: all N+M hold them
            full = self.lbs_matrices(pose_transforms)
            return self.pose_with(canon, full[canon.index], self.clearance_matrices(full), self.layer_stretch_of(full))
        return self.pose_with(canon, self.lbs_matrices(pose_transforms, canon.index))

    def clearance_matrices(self, matrices: torch.Tensor) -> torch.Tensor | None:
        """The LBS matrices of the body Gaussians the layer is kept clear of, from those of all
        N+M Gaussians (``lbs_matrices``); None without a layer or with ``garment_clearance`` 0."""
        if self.layer is None or self.config.garment_clearance <= 0:
            return None
        return matrices[self.layer_clear_ids]

    def layer_stretch_of(self, matrices: torch.Tensor) -> torch.Tensor | None:
        """(M,2) how far a pose stretches the garment layer's grid round the ring and down the
        column at each of its Gaussians, from the LBS ``matrices`` of all N+M Gaussians
        (``lbs_matrices``): the built grid posed, its steps (``garment_layer.grid_steps``) over the
        canonical ones, over ``garment_stretch_slack``, from 1 (never shrunk) to
        ``garment_max_stretch``; no gradient. None without a layer or with ``garment_stretch_scales``
        off."""
        if self.layer is None or self.num_layer == 0 or not self.config.garment_stretch_scales:
            return None
        nb = self.num_body
        with torch.no_grad():
            M = matrices.detach()[nb:]
            posed = grid_steps(apply_points(M, self.base_positions[nb:].to(M)), self.layer.grid_shape, self.layer.tubes)
            ratio = posed / self.texel_steps[nb:].to(posed).clamp_min(1e-9) / float(self.config.garment_stretch_slack)
            return ratio.clamp(1.0, float(self.config.garment_max_stretch))

    def _holds_layer(self, canon: CanonicalGaussians) -> bool:
        """Whether ``canon`` holds garment-layer Gaussians: all of the model's, or a subset with some."""
        return self.layer is not None and (canon.index is None or bool((canon.index >= self.num_body).any()))

    def _clears(self, canon: CanonicalGaussians) -> bool:
        return self.config.garment_clearance > 0 and self._holds_layer(canon)

    def pose_with(self, canon: CanonicalGaussians, matrices: torch.Tensor,
                  clearance: torch.Tensor | None = None, stretch: torch.Tensor | None = None) -> PosedGaussians:
        """The Gaussians moved by per-Gaussian LBS ``matrices`` (N,4,4) (``lbs_matrices``). A garment
        layer's are then kept ``garment_clearance`` outside the posed body (``layer_clearance``),
        which takes ``clearance``, the matrices of the body Gaussians it is kept clear of
        (``clearance_matrices``; read from ``matrices`` when these are all N+M Gaussians'), and its
        discs grow with the pose's stretch of its grid, ``stretch`` (``layer_stretch_of`` the
        matrices of all N+M Gaussians; read from ``matrices`` when these are all of them)."""
        tangents = None if canon.tangents is None else matrices[:, :3, :3] @ canon.tangents[..., None]
        means = apply_points(matrices, canon.means)
        if self._clears(canon):
            if clearance is None:
                if canon.index is not None:
                    raise ValueError("pose_with: a subset with garment-layer Gaussians needs the clearance "
                                     "matrices of the body Gaussians it is kept clear of (clearance_matrices)")
                clearance = self.clearance_matrices(matrices)
            means = self._clear_layer(canon, means, clearance)
        canon = self._stretched(canon, matrices, stretch)
        return self.splats(canon, means, apply_normals(matrices, canon.normals),
                           None if tangents is None else tangents[..., 0])

    def _stretched(self, canon: CanonicalGaussians, matrices: torch.Tensor,
                   stretch: torch.Tensor | None) -> CanonicalGaussians:
        """``canon`` with its garment-layer discs' in-plane scales times the pose's stretch."""
        if canon.tangents is None or not self.config.garment_stretch_scales or not self._holds_layer(canon):
            return canon
        if stretch is None:
            if canon.index is not None:
                raise ValueError("pose_with: a subset with garment-layer Gaussians needs the layer's stretch "
                                 "from the matrices of all Gaussians (layer_stretch_of)")
            stretch = self.layer_stretch_of(matrices)
        nb = self.num_body
        rows = self._layer_rows(canon)
        layer_ids = rows - nb if canon.index is None else canon.index[rows] - nb
        factor = torch.ones_like(canon.scales)
        factor[rows, :2] = stretch[layer_ids].to(factor)
        return dataclasses.replace(canon, scales=canon.scales * factor)

    def _layer_rows(self, canon: CanonicalGaussians) -> torch.Tensor:
        """The rows of ``canon`` that are garment-layer Gaussians."""
        nb = self.num_body
        return (torch.arange(nb, len(canon.means), device=canon.means.device) if canon.index is None
                else torch.nonzero(canon.index >= nb)[:, 0])

    def _clear_layer(self, canon: CanonicalGaussians, means: torch.Tensor, clearance: torch.Tensor) -> torch.Tensor:
        rows = self._layer_rows(canon)
        ids = self.layer_clear_ids
        points = apply_points(clearance, self.base_positions[ids].to(clearance))
        normals = lambda j: apply_normals(clearance[j], self.base_normals[ids[j]].to(clearance))  # noqa: E731
        pushed = push_out(means[rows], points, normals, self.config.garment_clearance)
        return means.index_put((rows,), pushed)

    @staticmethod
    def splats(canon: CanonicalGaussians, means: torch.Tensor | None = None, normals: torch.Tensor | None = None,
               tangents: torch.Tensor | None = None) -> PosedGaussians:
        """Renderable Gaussians at ``means``/``normals``/``tangents`` (default: the canonical ones,
        i.e. canonical space), opacity 1 (a garment layer's: its learned ones); spheres with the
        identity rotation (paper A.1), discs rotated into their tangent frame."""
        means = canon.means if means is None else means
        normals = canon.normals if normals is None else normals
        n = means.shape[0]
        if canon.tangents is None:
            quats = torch.zeros(n, 4, dtype=means.dtype, device=means.device)
            quats[:, 0] = 1.0
        else:
            quats = frame_quaternions(canon.tangents if tangents is None else tangents, normals)
        opacities = (torch.ones(n, dtype=means.dtype, device=means.device) if canon.opacities is None
                     else canon.opacities)
        return PosedGaussians(means, normals, canon.colors, canon.scales, quats, opacities)

    @torch.no_grad()
    def trim_layer(self, flags) -> int:
        """Take the garment layer's Gaussians ``flags`` ((M,) bool) out of the garment for good: their
        opacity is 0 from now on (``opacities``), in this stage and the next, and in checkpoints.
        Returns how many were not trimmed before."""
        flags = torch.as_tensor(flags, dtype=torch.bool, device=self.layer_trimmed.device)
        if flags.shape != self.layer_trimmed.shape:
            raise ValueError(f"trim_layer: flags must have shape {tuple(self.layer_trimmed.shape)}, "
                             f"found {tuple(flags.shape)}")
        new = int((flags & ~self.layer_trimmed).sum())
        self.layer_trimmed |= flags
        return new

    @torch.no_grad()
    def mark_outline_cut(self, flags) -> int:
        """Record the garment layer's Gaussians ``flags`` ((M,) bool) as cut away by the person's
        outline (``layer_outline_cut``; replaces the earlier record). Returns how many are marked."""
        flags = torch.as_tensor(flags, dtype=torch.bool, device=self.layer_outline_cut.device)
        if flags.shape != self.layer_outline_cut.shape:
            raise ValueError(f"mark_outline_cut: flags must have shape {tuple(self.layer_outline_cut.shape)}, "
                             f"found {tuple(flags.shape)}")
        self.layer_outline_cut.copy_(flags)
        return int(flags.sum())

    @torch.no_grad()
    def move_layer(self, delta: torch.Tensor) -> None:
        """Move the garment layer's built points by ``delta`` (M,3), after training
        (``layer_depth.match_layer_depth``): the layer's positions, the model's base positions and
        what the model derives from them (the discs' grid steps, the grid edges' rest lengths), as a
        model built on the moved layer has them."""
        nb = self.num_body
        self.base_positions[nb:] += delta.to(self.base_positions)
        self.layer.positions = self.layer.positions + delta.to(self.layer.positions)
        if self.config.splat == "disc":
            self.texel_steps[nb:] = self.layer.steps().to(self.texel_steps)
        self.layer_rest.copy_(_edge_lengths(self.layer.positions.to(self.layer_rest), self.layer_edges - nb))

    def layer_grid(self) -> tuple[int, int, int] | None:
        """(rows, cols, tubes) of the garment layer's grid (its Gaussians follow the body's,
        row-major), or None without a layer."""
        if self.layer is None or self.num_layer == 0:
            return None
        R, C = self.layer.grid_shape
        return int(R), int(C), int(self.layer.tubes)

    def parts(self) -> np.ndarray:
        """(N+M,) part index per Gaussian: the body texels' parts, then ``GARMENT_PART`` for the
        garment layer's (``garment_layer.AVATAR_PART_NAMES`` names them)."""
        if self.layer is None:
            return self.uv_map.parts
        return np.concatenate([self.uv_map.parts, np.full(self.num_layer, GARMENT_PART, self.uv_map.parts.dtype)])

    def neighbours(self) -> np.ndarray:
        """(N+M,4) each Gaussian's grid neighbours (``texel_neighbours`` order, -1 where none): the
        body texels' in the UV atlas, the garment layer's on its own grid (columns wrapping round);
        body and layer are not neighbours of each other. What erosion, grow / shrink and the
        appearance fills' smoothing walk over."""
        nb = texel_neighbours(self.uv_map.texel_rc, self.uv_map.resolution)
        if self.layer is None:
            return nb
        lay = self.layer.grid_neighbours()
        return np.concatenate([nb, np.where(lay >= 0, lay + self.num_body, -1)])

    def layer_edge_rows(self, index: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The garment layer's grid edges as rows of decoded Gaussians (all, or those of ``index``:
        edges with both ends decoded) and their canonical rest lengths: ((E,2), (E,))."""
        if self.layer is None:
            empty = torch.zeros(0, 2, dtype=torch.long, device=self.base_positions.device)
            return empty, self.base_positions.new_zeros(0)
        if index is None:
            return self.layer_edges, self.layer_rest
        row = torch.full((self.num_gaussians,), -1, dtype=torch.long, device=index.device)
        row[index] = torch.arange(len(index), device=index.device)
        e = row[self.layer_edges]
        ok = (e >= 0).all(1)
        return e[ok], self.layer_rest[ok]
