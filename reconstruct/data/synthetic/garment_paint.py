"""Colours of the loose garments, after the garment colour model of clothing.py: ONE base colour and
pattern family all round (solid, horizontal stripes or checks, functions of the height and the
distance round the garment, so the back continues the front), a front-only detail and a back-only
detail, and a darker lining (inside, hem and the coat's opening edges).

* front-only details: buttons down the front (skirt, dress: on the centre line; coat: along both
  edges of the opening), a crease down the front of each trouser leg;
* back-only details: a back seam (skirt, dress, trousers) or a half-belt across the back (coat).

The body under the garment is painted with clothing.py's garment model first; then what a person
wearing the garment shows is repainted (``dress_body_texels``): a coat's sleeves in the coat's
colour, bare legs or tights under a skirt or a dress, bare arms with a dress, the trouser colour
on the legs under wide trousers.

The garment's draws come from their own generator (seeded by the scene seed and the garment), so
the scene's main random stream -- and with it the body and its motion -- is the one of the
``garment`` scene of the same seed.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ...body.base import BodyModel
from ...body.parts import PART_INDEX
from ...body.uv_map import build_uv_map
from .clothing import PaintedClothing, _smoothstep, _to_atlas
from .garment_mesh import LOOSE_GARMENTS, GarmentMesh, landmarks


@dataclass
class GarmentColours:
    base: np.ndarray
    second: np.ndarray
    detail: np.ndarray
    lining: np.ndarray
    pattern: str
    period: float
    legs: str  # what shows on the legs: "skin", "tights", "trousers" or "unchanged"
    description: dict = field(default_factory=dict)


def garment_rng(seed: int, kind: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), 7919, LOOSE_GARMENTS.index(kind)])


def draw_colours(rng: np.random.Generator, kind: str) -> GarmentColours:
    hsv = lambda h, s, v: np.array(colorsys.hsv_to_rgb(h, s, v))
    h = rng.uniform(0, 1)
    base = hsv(h, rng.uniform(0.35, 0.8), rng.uniform(0.35, 0.85))
    second = hsv((h + rng.uniform(0.3, 0.7)) % 1.0, rng.uniform(0.3, 0.7), rng.uniform(0.5, 0.95))
    detail = hsv((h + 0.5) % 1.0, rng.uniform(0.7, 1.0), rng.uniform(0.8, 1.0))
    if np.linalg.norm(detail - base) < 0.35:
        detail = np.where(base.mean() > 0.5, np.array([0.08, 0.08, 0.1]), np.array([0.95, 0.92, 0.85]))
    pattern = str(rng.choice(["solid", "stripes", "checks"]))
    period = float(rng.uniform(0.06, 0.12))
    if kind in ("skirt", "dress"):
        legs = str(rng.choice(["skin", "tights"]))
    elif kind == "wide_trousers":
        legs = "trousers"
    else:
        legs = "unchanged"
    desc = {"kind": kind, "pattern": pattern, "period_m": round(period, 4), "base": base.round(4).tolist(),
            "legs": legs, "front_detail": "crease" if kind == "wide_trousers" else "buttons",
            "back_detail": "half_belt" if kind == "coat" else "back_seam"}
    return GarmentColours(base, second, detail, base * 0.5, pattern, period, legs, desc)


def _outer_grid(garment: GarmentMesh, tube: int) -> np.ndarray:
    """(R,C+1,3) outer positions of ``tube`` on its grid (welded seams filled from column 0)."""
    R, C1 = garment.grid_shapes[tube]
    G = np.full((R, C1, 3), np.nan)
    on = np.flatnonzero(garment.outer & (garment.tube == tube))
    G[garment.grid_index[on, 0], garment.grid_index[on, 1]] = garment.vertices[on]
    miss = np.isnan(G[:, -1, 0])
    G[miss, -1] = G[miss, 0]
    return G


def paint_garment(garment: GarmentMesh, colours: GarmentColours, size: int = 512) -> np.ndarray:
    """(size,size,3) uint8 atlas of ``garment`` (layout of GarmentMesh.corner_uvs)."""
    atlas = np.tile(colours.lining, (size, size, 1))
    n_tubes = len(garment.grid_shapes)
    rows = np.arange(size // 2)
    c = colours
    for k in range(n_tubes):
        R, C1 = garment.grid_shapes[k]
        C = C1 - 1
        G = _outer_grid(garment, k)
        c0, c1 = int(round(size * k / n_tubes)), int(round(size * (k + 1) / n_tubes))
        cols = np.arange(c0, c1)
        u0, u1 = k / n_tubes, (k + 1) / n_tubes
        rr = np.clip(((rows + 0.5) / size - 0.002) / 0.496 * (R - 1), 0, R - 1)
        cc = np.clip((((cols + 0.5) / size - u0) / (u1 - u0) - 0.002) / 0.996 * C, 0, C)
        RR, CC = np.meshgrid(rr, cc, indexing="ij")
        pos = np.stack([ndimage.map_coordinates(G[..., d], [RR, CC], order=1, mode="nearest") for d in range(3)], -1)
        theta = CC / C * 2 * np.pi  # 0 in front, pi behind
        z = pos[..., 2]
        s = theta * 0.22  # distance round the garment (about), metres
        if c.pattern == "stripes":
            t = _smoothstep(-0.15, 0.15, np.sin(z * 2 * np.pi / c.period))
        elif c.pattern == "checks":
            t = 0.5 * (_smoothstep(0.3, 0.5, np.sin(z * 2 * np.pi / c.period))
                       + _smoothstep(0.3, 0.5, np.sin(s * 2 * np.pi / c.period)))
        else:
            t = np.zeros_like(z)
        col = c.base * (1 - t[..., None]) + c.second * t[..., None]
        ang = np.angle(np.exp(1j * theta))  # (-pi, pi], 0 in front
        top = z.max()
        kind = garment.kind
        # front-only detail
        if kind == "wide_trousers":
            front = _smoothstep(0.012, 0.006, np.abs(ang) * 0.2) * (z < top - 0.15)
        else:
            if kind == "coat":  # buttons along both edges of the opening (and above it)
                xs = [np.abs(ang) * 0.2 - 0.03]
            else:
                xs = [np.abs(ang) * 0.2]
            zz = (z - top) % 0.1 - 0.05
            front = np.zeros_like(z)
            for dx in xs:
                front = np.maximum(front, _smoothstep(0.016, 0.012, np.hypot(dx, zz)))
            front = front * (z < top - 0.04) * (z > top - (0.45 if kind != "coat" else 0.75))
        # back-only detail
        back_ang = np.abs(np.abs(ang) - np.pi) * 0.2
        if kind == "coat":
            belt_z = top - 0.42
            back = _smoothstep(0.035, 0.03, np.abs(z - belt_z)) * _smoothstep(0.14, 0.12, back_ang)
        else:
            back = _smoothstep(0.006, 0.003, back_ang) * (z > top - 0.3)
        col = col * (1 - front[..., None]) + c.detail * front[..., None]
        col = col * (1 - back[..., None]) + (c.base * 0.55) * back[..., None]
        atlas[: size // 2, c0:c1] = col
    return (np.clip(atlas, 0, 1) * 255 + 0.5).astype(np.uint8)


def dress_body_texels(body: BodyModel, painted: PaintedClothing, colours: GarmentColours, kind: str,
                      size: int) -> np.ndarray:
    """The body atlas of ``painted`` with what the garment ``kind`` changes on the body repainted
    (skin: the painted colour of the hands)."""
    uv = build_uv_map(body, size)
    col = _dressed_texel_colours(body, uv, painted, colours, kind)
    return _texel_atlas(uv, col, size)


def _texel_atlas(uv, col: np.ndarray, size: int) -> np.ndarray:
    _, fill_index = ndimage.distance_transform_edt(~uv.mask, return_indices=True)
    atlas = _to_atlas(uv, np.clip(col, 0, 1), size, fill_index)
    return (atlas * 255 + 0.5).astype(np.uint8)


def _outer_surface_samples(garment: GarmentMesh, per_edge: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points spread over the garment's outer faces (``per_edge`` steps along each triangle edge):
    (P,3) positions, (P,2) atlas coordinates interpolated from the faces' corner UVs, (P,3) the
    faces' outward unit normals."""
    outer_faces = garment.outer[garment.faces].all(1)
    faces, uvs = garment.faces[outer_faces], garment.corner_uvs[outer_faces]
    tri = garment.vertices[faces]  # (F,3,3)
    i, j = np.meshgrid(np.arange(per_edge + 1), np.arange(per_edge + 1), indexing="ij")
    keep = (i + j) <= per_edge
    b = np.stack([i[keep], j[keep], per_edge - i[keep] - j[keep]], 1) / per_edge  # (S,3) barycentric
    pos = np.einsum("sk,fkd->fsd", b, tri).reshape(-1, 3)
    uv = np.einsum("sk,fkd->fsd", b, uvs.astype(np.float64)).reshape(-1, 2)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    return pos, uv, np.repeat(nrm, len(b), axis=0)


def garment_on_body(body: BodyModel, garment: GarmentMesh, garment_atlas: np.ndarray, uv,
                    per_edge: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """What of the loose ``garment`` lies over each texel of ``body``'s UV map ``uv``: (N,) True
    for the texels inside the garment's shell (between its top and hem, behind the nearest point
    of its outer surface), and (N,3) the colour ``garment_atlas`` (``paint_garment``'s) has at that
    nearest point. The garment's pattern, front and back details, shrunk onto the body along the
    shortest way."""
    from scipy.spatial import cKDTree

    pos, tex_uv, nrm = _outer_surface_samples(garment, per_edge)
    p = uv.positions.numpy()
    _, idx = cKDTree(pos).query(p)
    z_out = garment.vertices[garment.outer, 2]
    inside = ((pos[idx] - p) * nrm[idx]).sum(1) >= -1e-3
    inside &= (p[:, 2] <= z_out.max()) & (p[:, 2] >= z_out.min())
    size = garment_atlas.shape[0]
    rows = (1.0 - tex_uv[idx, 1]) * size - 0.5
    cols = tex_uv[idx, 0] * garment_atlas.shape[1] - 0.5
    atlas = garment_atlas[..., :3].astype(np.float64) / 255.0
    colour = np.stack([ndimage.map_coordinates(atlas[..., d], [rows, cols], order=1, mode="nearest")
                       for d in range(3)], -1)
    return inside, colour


def painted_fit_texture(body: BodyModel, painted: PaintedClothing, garment: GarmentMesh, colours: GarmentColours,
                        garment_atlas: np.ndarray, size: int) -> np.ndarray:
    """The body atlas of the ``fit=painted`` scenes: the body dressed as under the garment
    (``dress_body_texels``), then every texel inside the garment's shell repainted with the
    garment's own colour there (``garment_on_body``): the loose garment's pattern worn tight."""
    uv = build_uv_map(body, size)
    col = _dressed_texel_colours(body, uv, painted, colours, garment.kind)
    inside, colour = garment_on_body(body, garment, garment_atlas, uv)
    col[inside] = colour[inside]
    return _texel_atlas(uv, col, size)


def _dressed_texel_colours(body: BodyModel, uv, painted: PaintedClothing, colours: GarmentColours,
                           kind: str) -> np.ndarray:
    col = painted.texel_colors.copy()
    if len(col) != len(uv.texel_rc):
        raise ValueError("garment painting: the body painting and the UV map disagree (different atlas sizes?)")
    parts = uv.parts
    skin = np.median(col[np.isin(parts, [PART_INDEX["hand.L"], PART_INDEX["hand.R"]])], axis=0)
    is_part = lambda *names: np.isin(parts, [PART_INDEX[n] for n in names])
    arms = is_part("upperarm.L", "upperarm.R", "lowerarm.L", "lowerarm.R")
    legs = is_part("thigh.L", "thigh.R", "shin.L", "shin.R")
    if kind == "coat":
        col[arms] = colours.base
    if kind == "dress":
        col[arms] = skin
    if colours.legs == "skin":
        col[legs] = skin
    elif colours.legs == "tights":
        col[legs] = np.array([0.12, 0.11, 0.13])
    elif colours.legs == "trousers":  # legs and seat: what shows between the trouser legs' tubes
        below_hips = is_part("torso") & (uv.positions.numpy()[:, 2] <= landmarks(body)["hips"])
        col[legs | below_hips] = colours.base
    return col
