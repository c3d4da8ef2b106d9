"""Clothing painted in the body's UV atlas by body part.

Each texel of a dense positional UV map knows its canonical position, normal and body part, so
patterns are laid out on the body (stripes around the chest, a chest emblem, seat patches, ...) and
then written into the atlas; texels outside the UV charts take the colour of the nearest chart
texel so that filtered lookups near seams do not bleed background in.

Two clothing models (``CLOTHING_MODELS``):

* ``garment`` (the default): like real clothes, each garment has ONE base colour and pattern family
  all round (a solid colour, stripes that wrap round the torso, or checks), plus a front-only
  detail (a chest emblem on the shirt; a fly and pocket seams on the trousers) and a back-only
  detail (a yoke or a back print on the shirt; seat patches or a seat yoke on the trousers) drawn
  from the seed. The hair on the back of the head is the hair of the crown and sides (a short cut
  shows skin at the nape); the face is only in front. The back is inferable from the front, up to
  the back-only details.
* ``independent`` (the original benchmark): the backs of the shirt and trousers are painted in an
  independent random colour with their own pattern. Kept bit-for-bit: the same seed paints the same
  atlas as before the garment model existed.

``hair="long"`` (``SyntheticConfig.hair``; garment model only) paints hair worn down on top of the
cut: the back of the neck and the upper back to ``LONG_HAIR_FALL`` below the neck's joint, and two
strands over the shoulders in front, in the hair's colour -- what a photo shows of long hair and
what its back should take (``appearance/long_hair.py``). It draws nothing.

Both models consume the same 28 draws of the scene generator's random stream (so the body's motion,
drawn afterwards, is the same for a seed in either model); the garment model draws its extra choices
from a jumped copy of that stream, which leaves the stream where it was.

Besides the atlas, painting returns where each FRONT-ONLY detail would land if it were mirrored
onto the back (``PaintedClothing.leak_atlas``), the input of the front-leak ("tattoo") metric
(reconstruct.metrics.front_leak): for the chest emblem, the back of the torso behind it; for the
face, the back of the head behind it. A texel is in a region when it faces backwards, its mirror
partner (``mirror_partners``: the forward-facing texel of the same part at the nearest left-right
and height coordinates) shows the detail, and its own true colour is far from the detail's colour
(where the truth itself has the detail's colour, painting it there is no leak).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ...body.base import BodyModel
from ...body.parts import PART_INDEX
from ...body.uv_map import build_uv_map

CLOTHING_MODELS = ("garment", "independent")
LEAK_DETAILS = ("emblem", "face")  # channel k of the leak atlas is the region of LEAK_DETAILS[k]
_LEAK_MIN_DISTANCE = 0.2  # RGB distance from the detail's colour below which a back texel is left out of the region
_EMBLEM_MIN_DISTANCE = 0.45  # garment model: the emblem's colour keeps at least this far from the shirt's colours


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _color(rng: np.random.Generator, sat=(0.45, 0.85), val=(0.45, 0.9)) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(*sat), rng.uniform(*val)))


@dataclass
class PaintedClothing:
    """An albedo atlas plus where its front-only details would land on the back."""

    texture: np.ndarray  # (S,S,3) uint8 albedo atlas
    leak_atlas: np.ndarray  # (S,S,3) uint8: channel k is 255 in the back region of LEAK_DETAILS[k], 0 elsewhere
    leak_colors: dict[str, np.ndarray]  # detail name -> (n,3) float albedo colours of the front-only detail
    texel_colors: np.ndarray  # (N,3) float albedo of each valid texel of the UV map (before 8-bit rounding)
    leak_texels: dict[str, np.ndarray]  # detail name -> (N,) bool: the texels of its back region
    description: dict = field(default_factory=dict)  # the choices made (pattern family, details, ...)


class _Geometry:
    """Per-texel positions, normals and parts of the UV map, and the landmarks patterns use."""

    def __init__(self, body: BodyModel, size: int) -> None:
        self.uv = build_uv_map(body, size)
        self.p = self.uv.positions.numpy()
        self.n = self.uv.normals.numpy()
        self.parts = self.uv.parts
        self.front = _smoothstep(0.05, -0.05, self.n[:, 1])  # 1 where the surface faces the front (-Y)
        joints = body.canonical_joints.numpy()
        L = body.bone_labels
        self.joints, self.labels = joints, L
        self.hip_z = float(joints[L.index("upperleg01.L"), 2]) + 0.06
        self.neck_z = float(joints[L.index("neck01"), 2])
        self.chest = joints[L.index("spine02")]
        self.head = joints[L.index("head")]
        self.foot_y = float(joints[L.index("foot.L"), 1])

    def is_part(self, *names: str) -> np.ndarray:
        return np.isin(self.parts, [PART_INDEX[x] for x in names])


def _draw_palette(rng: np.random.Generator) -> dict:
    """The 28 draws of the original painter, in its order."""
    skin = np.array(colorsys.hsv_to_rgb(rng.uniform(0.04, 0.09), rng.uniform(0.3, 0.55), rng.uniform(0.45, 0.95)))
    hair = np.array(colorsys.hsv_to_rgb(rng.uniform(0.03, 0.12), rng.uniform(0.3, 0.8), rng.uniform(0.08, 0.45)))
    shirt, shirt2, shirt_back = _color(rng), _color(rng), _color(rng)
    pants, pants_back = _color(rng, sat=(0.2, 0.6), val=(0.2, 0.6)), _color(rng, sat=(0.2, 0.6), val=(0.2, 0.6))
    shoes, emblem = _color(rng, val=(0.1, 0.35)), _color(rng, sat=(0.7, 1.0), val=(0.8, 1.0))
    long_sleeves = bool(rng.uniform() < 0.5)
    return {"skin": skin, "hair": hair, "shirt": shirt, "shirt2": shirt2, "shirt_back": shirt_back, "pants": pants,
            "pants_back": pants_back, "shoes": shoes, "emblem": emblem, "long_sleeves": long_sleeves}


def _paint_independent(g: _Geometry, pal: dict) -> tuple[np.ndarray, dict, dict]:
    """The original painter (independent random backs); arithmetic kept as it was."""
    p, n, front, is_part = g.p, g.n, g.front, g.is_part
    skin, hair, shirt, shirt2, shirt_back = pal["skin"], pal["hair"], pal["shirt"], pal["shirt2"], pal["shirt_back"]
    pants, pants_back, shoes, emblem = pal["pants"], pal["pants_back"], pal["shoes"], pal["emblem"]
    hip_z, neck_z, chest, head = g.hip_z, g.neck_z, g.chest, g.head

    col = np.tile(skin, (len(p), 1))
    # --- shirt: torso above the hips and the upper arms (and lower arms with long sleeves)
    shirt_mask = (is_part("torso") & (p[:, 2] > hip_z)) | is_part("upperarm.L", "upperarm.R")
    if pal["long_sleeves"]:
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
    toe = _smoothstep(0.0, -0.08, p[:, 1] - g.foot_y)[:, None]
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

    details = {"emblem": shirt_mask & (d_emblem < 0.07) & (front >= 0.5), "face": on_head & ~hairline}
    colors = {"emblem": emblem[None], "face": skin[None]}
    return col, details, colors


def _distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.asarray(a, float) - np.asarray(b, float), axis=-1)


def _contrasting(base: np.ndarray, avoid: list[np.ndarray], rng: np.random.Generator, sat=(0.75, 1.0),
                 val=(0.8, 1.0), tries: int = 64) -> np.ndarray:
    """``base`` when it is at least _EMBLEM_MIN_DISTANCE from every colour of ``avoid``, else the
    farthest of ``tries`` vivid colours drawn from ``rng`` (the first one far enough)."""
    best, best_d = base, min(_distance(base, a) for a in avoid)
    for _ in range(tries):
        if best_d >= _EMBLEM_MIN_DISTANCE:
            break
        c = _color(rng, sat=sat, val=val)
        d = min(_distance(c, a) for a in avoid)
        if d > best_d:
            best, best_d = c, d
    return best


HAIR_STYLES = ("drawn", "long")
# metres below the neck's joint that long hair falls on the back, its half-width there, and the
# strands over the shoulders in front: from the neck's side out to STRAND_OUT, down to STRAND_FALL
LONG_HAIR_FALL = 0.22
LONG_HAIR_HALF_WIDTH = 0.12
STRAND_IN, STRAND_OUT, STRAND_FALL = 0.045, 0.11, 0.16


def check_hair(hair: str, clothing: str, where: str = "") -> None:
    """ValueError (prefixed ``where``) unless ``hair`` is one of ``HAIR_STYLES`` and, when it is not
    the drawn cut, the clothing is the garment model's."""
    if hair not in HAIR_STYLES or (hair != "drawn" and clothing != "garment"):
        raise ValueError(f"{where}hair must be one of {', '.join(HAIR_STYLES)} (long: with clothing=garment), "
                         f"found hair={hair!r} with clothing={clothing!r}")


def _long_hair(g: _Geometry, col: np.ndarray, hair: np.ndarray) -> None:
    """Hair worn down painted into ``col``: the back of the neck and of the upper back, and two
    strands over the shoulders in front (module docstring)."""
    p, is_part = g.p, g.is_part
    x, z = p[:, 0] - g.head[0], p[:, 2]
    back = g.front < 0.5
    below = g.neck_z - z
    neck = is_part("neck")
    sheet = (is_part("torso") | neck) & back & (np.abs(x) <= LONG_HAIR_HALF_WIDTH) & (below <= LONG_HAIR_FALL)
    strands = (is_part("torso") | neck) & ~back & (np.abs(x) >= STRAND_IN) & (np.abs(x) <= STRAND_OUT) & (below <= STRAND_FALL)
    col[sheet | strands] = hair  # the sheet holds the whole back of the neck (it lies within its fall and width)


def _paint_garment(g: _Geometry, pal: dict, rng: np.random.Generator,
                   hair_style: str = "drawn") -> tuple[np.ndarray, dict, dict, dict]:
    """One base colour / pattern family per garment all round, front-only and back-only details."""
    p, n, front, is_part = g.p, g.n, g.front, g.is_part
    x, z = p[:, 0], p[:, 2]
    fw, bw = front[:, None], 1 - front[:, None]
    skin, hair, shirt, shirt2 = pal["skin"], pal["hair"], pal["shirt"], pal["shirt2"]
    pants, shoes = pal["pants"], pal["shoes"]
    hip_z, neck_z, chest, head = g.hip_z, g.neck_z, g.chest, g.head
    desc: dict = {"model": "garment", "long_sleeves": pal["long_sleeves"]}

    col = np.tile(skin, (len(p), 1))
    # --- shirt: one pattern family all round (functions of left-right x and height z only, so the
    # pattern of the back continues the front's round the sides)
    shirt_mask = (is_part("torso") & (z > hip_z)) | is_part("upperarm.L", "upperarm.R")
    if pal["long_sleeves"]:
        shirt_mask |= is_part("lowerarm.L", "lowerarm.R")
    pattern = str(rng.choice(["solid", "stripes", "checks"]))
    period = float(rng.uniform(0.05, 0.1))
    desc["shirt_pattern"] = pattern
    if pattern == "stripes":
        t = _smoothstep(-0.15, 0.15, np.sin(z * 2 * np.pi / period))
        base = shirt * (1 - t[:, None]) + shirt2 * t[:, None]
        shirt_colors = [shirt, shirt2]
    elif pattern == "checks":
        a = _smoothstep(0.3, 0.5, np.sin(z * 2 * np.pi / period))
        b = _smoothstep(0.3, 0.5, np.sin(x * 2 * np.pi / period))
        t = 0.5 * (a + b)
        base = shirt * (1 - t[:, None]) + shirt2 * t[:, None]
        shirt_colors = [shirt, shirt2, 0.5 * (shirt + shirt2)]
    else:
        base = np.tile(shirt, (len(p), 1))
        shirt_colors = [shirt]
    # back-only detail: a yoke (a darker band across the shoulders) or a print in the middle of the back
    back_detail = str(rng.choice(["yoke", "back_print"]))
    desc["shirt_back_detail"] = back_detail
    if back_detail == "yoke":
        yoke_col = shirt * 0.6
        detail = _smoothstep(neck_z - 0.13, neck_z - 0.11, z)  # a band 11-13 cm deep below the neck
    else:
        yoke_col = _color(rng, sat=(0.5, 0.9), val=(0.5, 0.95))
        half_w, half_h = float(rng.uniform(0.06, 0.1)), float(rng.uniform(0.04, 0.07))
        cz = chest[2] + float(rng.uniform(-0.12, 0.04))
        detail = (_smoothstep(half_w + 0.005, half_w - 0.005, np.abs(x)) *
                  _smoothstep(half_h + 0.005, half_h - 0.005, np.abs(z - cz)))
    detail = detail * is_part("torso")  # not on the sleeves
    back_colors = shirt_colors + [yoke_col]
    # front-only detail: a chest emblem (disc, square or diamond), in a colour far from the shirt's
    shape = str(rng.choice(["disc", "square", "diamond"]))
    radius = float(rng.uniform(0.05, 0.08))
    cx = float(rng.choice([0.0, -0.07, 0.07]))
    cz = chest[2] + float(rng.uniform(0.0, 0.08))
    dx, dz = np.abs(x - cx) / radius, np.abs(z - cz) / radius
    s = {"disc": np.hypot(dx, dz), "square": np.maximum(dx, dz) * 1.15, "diamond": (dx + dz) / 1.3}[shape]
    emblem = _contrasting(pal["emblem"], back_colors, rng)
    desc["emblem"] = {"shape": shape, "radius_m": round(radius, 4), "centre_x_m": cx, "colour": emblem.round(4).tolist()}
    em = _smoothstep(1.07, 0.93, s)[:, None]
    # front: the base with the emblem over it; back: the base with the back-only detail over it
    cloth = (base * (1 - em) + emblem * em) * fw + (base * (1 - detail[:, None]) + yoke_col * detail[:, None]) * bw
    col[shirt_mask] = cloth[shirt_mask]
    # --- trousers: one colour all round (an optional belt all round), a fly and pocket seams in
    # front, seat patches or a seat yoke behind
    pants_mask = (is_part("torso") & (z <= hip_z)) | is_part("thigh.L", "thigh.R", "shin.L", "shin.R")
    pcol = np.tile(pants, (len(p), 1))
    seams = np.maximum(_smoothstep(0.012, 0.006, np.abs(np.abs(x) - 0.17)) * _smoothstep(hip_z - 0.2, hip_z - 0.15, z),
                       _smoothstep(0.01, 0.005, np.abs(x)) * _smoothstep(hip_z - 0.17, hip_z - 0.14, z))
    pf = pcol * (1 - 0.45 * seams[:, None])
    seat = str(rng.choice(["seat_patches", "seat_yoke"]))
    desc["trousers_back_detail"] = seat
    if seat == "seat_patches":
        patch = (_smoothstep(0.07, 0.06, np.abs(np.abs(x) - 0.1)) * _smoothstep(0.07, 0.06, np.abs(z - (hip_z - 0.12))))
    else:
        patch = _smoothstep(0.012, 0.006, np.abs(z - (hip_z - 0.08 + 0.25 * np.abs(x))))
    pb = pcol * (1 - 0.4 * patch[:, None])
    pcol = pf * fw + pb * bw
    if rng.uniform() < 0.5:
        belt = _smoothstep(hip_z - 0.045, hip_z - 0.04, z)  # the top 4 cm of the trousers, all round
        pcol = pcol * (1 - belt[:, None]) + shoes * belt[:, None]
        desc["belt"] = True
    col[pants_mask] = pcol[pants_mask]
    # --- shoes, as in the original
    feet = is_part("foot.L", "foot.R")
    toe = _smoothstep(0.0, -0.08, p[:, 1] - g.foot_y)[:, None]
    col[feet] = (shoes * (1 - 0.5 * toe) + 0.8 * toe)[feet]
    # --- head: the hair of the crown and sides goes on round the back; the face only in front
    on_head = is_part("head")
    rel = p - head
    brow_z = 0.13 + float(rng.uniform(-0.015, 0.01))
    short = bool(rng.uniform() < 0.5)
    nape = float(rng.uniform(-0.04, 0.0)) if short else -np.inf
    desc["hair"] = {"hairline_m": round(brow_z, 4), "short": short}
    face = (n[:, 1] <= -0.35) & (rel[:, 2] <= brow_z)
    hairy = ~face & ~((n[:, 1] > 0.2) & (rel[:, 2] < nape))
    col[on_head & hairy] = hair
    brows = on_head & face & (np.abs(rel[:, 2] - 0.085) < 0.008) & (np.abs(np.abs(rel[:, 0]) - 0.035) < 0.022)
    col[brows] = hair * 0.8
    mouth = on_head & face & (np.abs(rel[:, 2]) < 0.008) & (np.abs(rel[:, 0]) < 0.025)
    col[mouth] = np.array([0.6, 0.25, 0.25])
    # a collar of the shirt's base colour round the back of the neck
    col[is_part("neck") & (z < neck_z - 0.02) & (front < 0.5)] = shirt
    if hair_style == "long":
        _long_hair(g, col, hair)
        desc["hair"]["long"] = True

    details = {"emblem": shirt_mask & (s < 1.0) & (front >= 0.5), "face": on_head & face}
    return col, details, {"emblem": emblem[None], "face": skin[None]}, desc


def mirror_partners(uv) -> np.ndarray:
    """For each texel of ``uv`` facing backwards (normal y > 0), the index of the texel facing
    forwards on the same body part whose left-right and height coordinates (x, z) are nearest:
    where the front would land if it were mirrored onto the back (seen from behind, the front
    image flipped left-right). -1 for texels facing forwards."""
    from scipy.spatial import cKDTree

    p, n = uv.positions.numpy(), uv.normals.numpy()
    out = np.full(len(p), -1, np.int64)
    for part in np.unique(uv.parts):
        on = uv.parts == part
        fr, bk = np.flatnonzero(on & (n[:, 1] < 0)), np.flatnonzero(on & (n[:, 1] >= 0))
        if len(fr) and len(bk):
            out[bk] = fr[cKDTree(p[fr][:, [0, 2]]).query(p[bk][:, [0, 2]])[1]]
    return out


def _to_atlas(uv, values: np.ndarray, size: int, fill_index) -> np.ndarray:
    atlas = np.zeros((size, size, values.shape[1]))
    atlas[uv.texel_rc[:, 0], uv.texel_rc[:, 1]] = values
    ri, ci = fill_index
    return atlas[ri, ci]


def paint_clothing(body: BodyModel, rng: np.random.Generator, size: int = 512,
                   clothing: str = "garment", hair: str = "drawn") -> PaintedClothing:
    """Paint ``body``'s atlas with the clothing model ``clothing`` (one of CLOTHING_MODELS),
    drawing from ``rng`` exactly as the original painter did (28 draws); ``hair``: one of
    ``HAIR_STYLES`` (``long``: the garment model only)."""
    if clothing not in CLOTHING_MODELS:
        raise ValueError(f"unknown clothing model {clothing!r}; available: {', '.join(CLOTHING_MODELS)}")
    check_hair(hair, clothing)
    g = _Geometry(body, size)
    pal = _draw_palette(rng)
    if clothing == "independent":
        col, details, colors = _paint_independent(g, pal)
        desc = {"model": "independent", "long_sleeves": pal["long_sleeves"]}
    else:
        extra = np.random.Generator(rng.bit_generator.jumped())  # leaves ``rng`` where it is
        col, details, colors, desc = _paint_garment(g, pal, extra, hair)
    col = np.clip(col, 0, 1)
    # the back region of a front-only detail: the backward-facing texels (front weight < 1/2) whose
    # mirror partner shows the detail; a texel whose true colour is (nearly) the detail's own is no
    # place to detect a leak
    partner = mirror_partners(g.uv)
    behind = (partner >= 0) & (g.front < 0.5)
    regions = {k: behind & d[np.maximum(partner, 0)]
               & (np.min([_distance(col, c) for c in colors[k]], axis=0) > _LEAK_MIN_DISTANCE)
               for k, d in details.items()}
    _, fill_index = ndimage.distance_transform_edt(~g.uv.mask, return_indices=True)  # nearest chart texel
    atlas = _to_atlas(g.uv, col, size, fill_index)
    leak = np.stack([regions[k] for k in LEAK_DETAILS] + [np.zeros(len(col), bool)] * (3 - len(LEAK_DETAILS)), 1)
    leak_atlas = _to_atlas(g.uv, leak.astype(float), size, fill_index)
    return PaintedClothing((atlas * 255 + 0.5).astype(np.uint8), (leak_atlas * 255 + 0.5).astype(np.uint8),
                           colors, col, regions, desc)


def paint_texture(body: BodyModel, rng: np.random.Generator, size: int = 512, clothing: str = "independent") -> np.ndarray:
    """A (size,size,3) uint8 albedo atlas for ``body`` (the original independent-backs painter by default)."""
    return paint_clothing(body, rng, size, clothing).texture
