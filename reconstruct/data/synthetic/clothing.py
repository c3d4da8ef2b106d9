"""Clothing painted in the body's UV atlas by body part, with patterns that differ front and back.

Each texel of a dense positional UV map knows its canonical position, normal and body part, so
patterns are laid out on the body (stripes around the chest, a chest emblem, a checker on the
back, ...) and then written into the atlas; texels outside the UV charts take the colour of the
nearest chart texel so that filtered lookups near seams do not bleed background in.
"""

from __future__ import annotations

import colorsys

import numpy as np
from scipy import ndimage

from ...body.base import BodyModel
from ...body.parts import PART_INDEX
from ...body.uv_map import build_uv_map


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _color(rng: np.random.Generator, sat=(0.45, 0.85), val=(0.45, 0.9)) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(*sat), rng.uniform(*val)))


def paint_texture(body: BodyModel, rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """A (size,size,3) uint8 albedo atlas for ``body``."""
    uv = build_uv_map(body, size)
    p = uv.positions.numpy()
    n = uv.normals.numpy()
    parts = uv.parts
    is_part = lambda *names: np.isin(parts, [PART_INDEX[x] for x in names])
    front = _smoothstep(0.05, -0.05, n[:, 1])  # 1 where the surface faces the front (-Y)

    skin = np.array(colorsys.hsv_to_rgb(rng.uniform(0.04, 0.09), rng.uniform(0.3, 0.55), rng.uniform(0.45, 0.95)))
    hair = np.array(colorsys.hsv_to_rgb(rng.uniform(0.03, 0.12), rng.uniform(0.3, 0.8), rng.uniform(0.08, 0.45)))
    shirt, shirt2, shirt_back = _color(rng), _color(rng), _color(rng)
    pants, pants_back = _color(rng, sat=(0.2, 0.6), val=(0.2, 0.6)), _color(rng, sat=(0.2, 0.6), val=(0.2, 0.6))
    shoes, emblem = _color(rng, val=(0.1, 0.35)), _color(rng, sat=(0.7, 1.0), val=(0.8, 1.0))
    long_sleeves = bool(rng.uniform() < 0.5)

    joints = body.canonical_joints.numpy()
    L = body.bone_labels
    hip_z = float(joints[L.index("upperleg01.L"), 2]) + 0.06
    neck_z = float(joints[L.index("neck01"), 2])
    chest = joints[L.index("spine02")]
    head = joints[L.index("head")]

    col = np.tile(skin, (len(p), 1))
    # --- shirt: torso above the hips and the upper arms (and lower arms with long sleeves)
    shirt_mask = (is_part("torso") & (p[:, 2] > hip_z)) | is_part("upperarm.L", "upperarm.R")
    if long_sleeves:
        shirt_mask |= is_part("lowerarm.L", "lowerarm.R")
    stripes = _smoothstep(-0.15, 0.15, np.sin(p[:, 2] * 2 * np.pi / 0.07))
    front_col = shirt * (1 - stripes[:, None]) + shirt2 * stripes[:, None]
    d_emblem = np.linalg.norm((p[:, [0, 2]] - chest[[0, 2]]) / np.array([1.0, 1.0]), axis=1)
    em = _smoothstep(0.075, 0.065, d_emblem)[:, None] * front[:, None]
    front_col = front_col * (1 - em) + emblem * em
    checker = ((np.floor(p[:, 0] / 0.09) + np.floor(p[:, 2] / 0.09)) % 2)[:, None]
    back_col = shirt_back * (1 - 0.35 * checker) + shirt * 0.35 * checker
    cloth = front_col * front[:, None] + back_col * (1 - front[:, None])
    col[shirt_mask] = cloth[shirt_mask]
    # --- pants: hips down to the ankles, pockets in front, darker seat patches behind
    pants_mask = (is_part("torso") & (p[:, 2] <= hip_z)) | is_part("thigh.L", "thigh.R", "shin.L", "shin.R")
    seam = _smoothstep(0.012, 0.006, np.abs(np.abs(p[:, 0]) - 0.17))[:, None] * front[:, None]
    pf = pants * (1 - 0.5 * seam)
    patch = (_smoothstep(0.09, 0.08, np.abs(np.abs(p[:, 0]) - 0.1)) *
             _smoothstep(0.10, 0.09, np.abs(p[:, 2] - (hip_z - 0.12))))[:, None]
    pb = pants_back * (1 - 0.6 * patch) + pants * 0.6 * patch
    pcol = pf * front[:, None] + pb * (1 - front[:, None])
    col[pants_mask] = pcol[pants_mask]
    # --- shoes
    feet = is_part("foot.L", "foot.R")
    toe = _smoothstep(0.0, -0.08, p[:, 1] - (joints[L.index("foot.L"), 1]))[:, None]
    col[feet] = (shoes * (1 - 0.5 * toe) + 0.8 * toe)[feet]
    # --- head: hair on the back and top, face skin in front with eyebrows and a mouth
    on_head = is_part("head")
    rel = p - head
    hairline = (n[:, 1] > -0.35) | (rel[:, 2] > 0.13)
    col[on_head & hairline] = hair
    brows = on_head & ~hairline & (np.abs(rel[:, 2] - 0.085) < 0.008) & (np.abs(np.abs(rel[:, 0]) - 0.035) < 0.022)
    col[brows] = hair * 0.8
    mouth = on_head & ~hairline & (np.abs(rel[:, 2] + 0.0) < 0.008) & (np.abs(rel[:, 0]) < 0.025)
    col[mouth] = np.array([0.6, 0.25, 0.25])
    # neck above the collar: skin (default)
    col[is_part("neck") & (p[:, 2] < neck_z - 0.02) & (front < 0.5)] = shirt_back

    atlas = np.zeros((size, size, 3))
    atlas[uv.texel_rc[:, 0], uv.texel_rc[:, 1]] = np.clip(col, 0, 1)
    # fill texels outside the charts with their nearest chart texel
    _, (ri, ci) = ndimage.distance_transform_edt(~uv.mask, return_indices=True)
    atlas = atlas[ri, ci]
    return (atlas * 255 + 0.5).astype(np.uint8)
