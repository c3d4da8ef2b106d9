"""Loose garments with geometry for the synthetic benchmark: a knee-length skirt, a long coat, a
dress and wide trousers, built around an Anny body in its canonical pose.

Construction (a swept profile). A garment is one or two *tubes*. Each tube is a stack of
horizontal rings from its top (waist, armpits or shoulders) down to its hem. At the height of a
ring, the canonical body vertices of the parts the tube covers (the torso above the hips; the
torso, thighs and shins below them; only one side for a trouser leg) are cut out in a thin slab
and their 2-D convex hull is taken: the hull of BOTH legs spans the gap between them, which is what
cloth does. The ring's radius in each direction is the hull's plus a standoff that grows from
about a centimetre at the top to the garment's flare at the hem; hanging garments (skirt, dress,
coat) never get narrower going down below the hips. The outer surface is doubled by an inner one
(the lining, ``thickness`` inside) and the two are joined at the top, the hem and, for the coat,
along the edges of its front opening (a slit in the front below the waist that widens towards
the hem), so every garment is a closed shell with volume.

The mesh is a regular grid per tube (rows down, columns round), which the skinning
(garment_skinning.py) and the colouring (garment_paint.py) use: ``rows``/``cols``/``grid_index``
give, for every outer-surface vertex, its place in the grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ...body.base import BodyModel
from ...body.parts import PART_INDEX
from ...body.slices import hull_polar_radii

LOOSE_GARMENTS = ("skirt", "coat", "dress", "wide_trousers")

_TROUSER_OVERLAP = 0.03  # metres past the midline that each trouser leg's tube reaches at the top
_BELOW_HIPS = ("torso", "thigh.L", "thigh.R", "shin.L", "shin.R")


@dataclass(frozen=True)
class GarmentProfile:
    """The shape parameters of one garment kind (heights relative to body landmarks, metres)."""

    kind: str
    top: str  # landmark of the top ring: "waist", "armpits" or "shoulders"
    hem: str  # landmark of the hem: "above_knee", "below_knee", "mid_calf", "ankle"
    standoff_top: float  # gap between the body's hull and the cloth at the top
    standoff_hem: float  # ... at the hem (the flare)
    hanging: bool  # radius never decreases below the hips (skirts, coats, dresses)
    two_legs: bool = False  # one tube per leg (trousers) instead of one round both
    opening_m: float = 0.0  # coat: half-width of the front opening at the hem (0 = closed)
    thickness: float = 0.01


PROFILES = {
    "skirt": GarmentProfile("skirt", "waist", "above_knee", 0.012, 0.075, hanging=True),
    "coat": GarmentProfile("coat", "shoulders", "mid_calf", 0.022, 0.07, hanging=True, opening_m=0.055),
    "dress": GarmentProfile("dress", "armpits", "below_knee", 0.012, 0.08, hanging=True),
    "wide_trousers": GarmentProfile("wide_trousers", "waist", "ankle", 0.012, 0.06, hanging=False, two_legs=True),
}


@dataclass
class GarmentMesh:
    """A closed garment shell in the body's canonical space.

    vertices (V,3) canonical positions; faces (F,3) oriented outwards ((b-a)x(c-a) points out of the
    shell, as the body's); corner_uvs (F,3,2) into the garment atlas (top half: the outside of the
    cloth, bottom half: the lining, hem and edges); outer (V,) True for vertices of the outer
    surface; tube (V,) which tube a vertex belongs to; grid_index (V,2) (row, column) in its tube's
    grid; grid_shapes [(rows, cols)] per tube; theta/height (V,) the angle round the tube (0 in
    front, +pi/2 on the body's left) and the canonical height; edges (E,2) unique mesh edges.
    """

    kind: str
    vertices: np.ndarray
    faces: np.ndarray
    corner_uvs: np.ndarray
    outer: np.ndarray
    tube: np.ndarray
    grid_index: np.ndarray
    grid_shapes: list
    theta: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def edges(self) -> np.ndarray:
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        return np.unique(np.sort(e, axis=1), axis=0)

    @property
    def height(self) -> np.ndarray:
        return self.vertices[:, 2]


def landmarks(body: BodyModel) -> dict[str, float]:
    """Heights (canonical z, metres) the garments are laid out by."""
    J = body.canonical_joints.numpy()
    L = body.bone_labels
    z = lambda name: float(J[L.index(name), 2])
    knee = 0.5 * (z("lowerleg01.L") + z("lowerleg01.R"))
    ankle = 0.5 * (z("foot.L") + z("foot.R"))
    return {
        "hips": z("upperleg01.L") + 0.06,
        "waist": z("spine03"),
        "armpits": z("upperarm01.L") - 0.09,
        "shoulders": z("neck01") - 0.035,
        "above_knee": knee + 0.06,
        "below_knee": knee - 0.08,
        "mid_calf": knee - 0.2,
        "ankle": ankle + 0.04,
    }


def _dense_surface(body: BodyModel) -> tuple[np.ndarray, np.ndarray]:
    """Canonical points sampled densely on the body's triangles (vertices plus 9 barycentric
    points per face) and their parts (of the face's first vertex): the body's vertex rings on the
    limbs are 2-3 cm apart, too sparse for thin horizontal slices."""
    v = body.canonical_vertices.numpy()
    f = body.faces.numpy()
    b = np.array([[i, j, 6 - i - j] for i in range(1, 5) for j in range(1, 6 - i)], float)
    b = b[(b > 0).all(1)][:9] / 6.0
    pts = np.einsum("sk,fkd->fsd", b, v[f]).reshape(-1, 3)
    parts = np.repeat(body.vertex_parts[f[:, 0]], len(b))
    return np.concatenate([v, pts]), np.concatenate([body.vertex_parts, parts])


def _slice_points(verts: np.ndarray, sel: np.ndarray, z: float, dz: float) -> np.ndarray:
    for w in (dz, 2 * dz, 4 * dz):
        on = sel & (np.abs(verts[:, 2] - z) < w)
        if on.sum() >= 8:
            return verts[on][:, :2]
    raise ValueError(f"garment: no body vertices near height {z:.3f} m for the garment's profile")


def _tube_grid(body: BodyModel, prof: GarmentProfile, side: str | None, marks: dict, n_theta: int,
               row_step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Outer and inner ring positions (R,C+1,3) of one tube, the column angles (R,C+1) and which
    rows are closed (no front opening) (R,)."""
    verts, parts = _dense_surface(body)
    z_top, z_hem = marks[prof.top], marks[prof.hem]
    if z_hem >= z_top:
        raise ValueError(f"garment {prof.kind}: hem ({z_hem:.3f} m) is not below the top ({z_top:.3f} m)")
    rows = max(8, int(math.ceil((z_top - z_hem) / row_step)) + 1)
    zs = np.linspace(z_top, z_hem, rows)
    torso = parts == PART_INDEX["torso"]
    below = np.isin(parts, [PART_INDEX[p] for p in _BELOW_HIPS])
    if side is not None:
        sgn = 1.0 if side == "L" else -1.0  # +X is the body's left
        keep = verts[:, 0] * sgn > -_TROUSER_OVERLAP  # the two legs' tubes overlap at the seat and fly
        torso, below = torso & keep, below & keep
    fine = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    radii = np.zeros((rows, len(fine)))
    centres = np.zeros((rows, 2))
    for i, z in enumerate(zs):
        pts = _slice_points(verts, below if z <= marks["hips"] else torso, z, 0.012)
        centres[i] = pts.mean(0)
    centres = gaussian_filter1d(centres, 2.0, axis=0, mode="nearest")
    for i, z in enumerate(zs):
        pts = _slice_points(verts, below if z <= marks["hips"] else torso, z, 0.012)
        try:
            radii[i] = hull_polar_radii(pts, centres[i], fine)
        except ValueError:  # the smoothed centre fell outside this slice's hull: use the slice's own
            centres[i] = pts.mean(0)
            radii[i] = hull_polar_radii(pts, centres[i], fine)
    radii = gaussian_filter1d(gaussian_filter1d(radii, 1.5, axis=0, mode="nearest"), 2.0, axis=1, mode="wrap")
    # standoff: small at the top, growing to the flare at the hem (from the hips down)
    flare_from = marks["hips"] if not prof.two_legs else marks["hips"] - 0.1
    t = np.clip((flare_from - zs) / max(flare_from - z_hem, 1e-6), 0.0, 1.0) ** 1.3
    radii = radii + (prof.standoff_top + (prof.standoff_hem - prof.standoff_top) * t)[:, None]
    if prof.hanging:  # cloth hangs: no narrowing below the hips
        start = int(np.argmin(np.abs(zs - marks["hips"])))
        radii[start:] = np.maximum.accumulate(radii[start:], axis=0)
    # the coat's front opening: a slit below the waist, widening to the hem
    half = np.zeros(rows)
    if prof.opening_m > 0:
        z_open = marks["hips"] - 0.04
        u = np.clip((z_open - zs) / max(z_open - z_hem, 1e-6), 0.0, 1.0)
        r_front = radii[:, 0]
        half = np.where(zs < z_open, prof.opening_m * u ** 0.8 / r_front, 0.0)
    cols = np.arange(n_theta + 1) / n_theta
    theta = half[:, None] + cols[None] * (2 * np.pi - 2 * half[:, None])  # (R,C+1)
    r_at = np.stack([np.interp(theta[i], np.append(fine, 2 * np.pi), np.append(radii[i], radii[i, 0]))
                     for i in range(rows)])
    d = np.stack([np.sin(theta), -np.cos(theta)], -1)
    ring = lambda r: np.concatenate([centres[:, None, :] + r[..., None] * d,
                                     np.broadcast_to(zs[:, None, None], (rows, n_theta + 1, 1))], -1)
    return ring(r_at), ring(r_at - prof.thickness), theta, half == 0


def build_garment(body: BodyModel, kind: str, *, n_theta: int = 96, row_step: float = 0.015) -> GarmentMesh:
    """The garment ``kind`` (one of LOOSE_GARMENTS) around ``body``'s canonical pose."""
    if kind not in PROFILES:
        raise ValueError(f"unknown loose garment {kind!r}; available: {', '.join(LOOSE_GARMENTS)}")
    prof = PROFILES[kind]
    marks = landmarks(body)
    sides = ("L", "R") if prof.two_legs else (None,)
    V, F, UV, OUT, TUBE, GI, TH, shapes = [], [], [], [], [], [], [], []
    n_v = 0
    n_tubes = len(sides)
    for k, side in enumerate(sides):
        outer, inner, theta, closed = _tube_grid(body, prof, side, marks, n_theta, row_step)
        R, C1 = theta.shape
        C = C1 - 1
        # vertex ids: a closed row's last column is its first (welded seam)
        ids = np.arange(R * C1).reshape(R, C1)
        ids[closed, C] = ids[closed, 0]
        used, remap = np.unique(ids, return_inverse=True)
        ids = remap.reshape(R, C1)
        n_one = len(used)
        flat_o, flat_i = outer.reshape(-1, 3)[used], inner.reshape(-1, 3)[used]
        rr, cc = np.divmod(used, C1)
        oid, iid = ids + n_v, ids + n_v + n_one
        V += [flat_o, flat_i]
        OUT += [np.ones(n_one, bool), np.zeros(n_one, bool)]
        TUBE += [np.full(2 * n_one, k)]
        GI += [np.stack([rr, cc], 1)] * 2
        TH += [theta.reshape(-1)[used]] * 2
        shapes.append((R, C1))
        # texture coordinates: atlas columns split between tubes, top half outside, bottom half lining
        u0, u1 = k / n_tubes, (k + 1) / n_tubes
        uv_out = lambda r, c: np.stack([u0 + (u1 - u0) * (0.002 + 0.996 * c / C), 1.0 - (0.002 + 0.496 * r / (R - 1))], -1)
        uv_in = lambda r, c: np.stack([u0 + (u1 - u0) * (0.002 + 0.996 * c / C), 0.498 - 0.496 * r / (R - 1)], -1)
        r0, c0 = np.meshgrid(np.arange(R - 1), np.arange(C), indexing="ij")
        r0, c0 = r0.reshape(-1), c0.reshape(-1)
        quads = [(r0, c0), (r0 + 1, c0), (r0, c0 + 1), (r0 + 1, c0 + 1)]

        def add_grid(vid, uvf, want_out: bool):
            a, b, c, d = (vid[r, cidx] for r, cidx in quads)
            ua, ub, uc, ud = (uvf(r, cidx) for r, cidx in quads)
            tris = np.concatenate([np.stack([a, b, c], 1), np.stack([c, b, d], 1)])
            uvs = np.concatenate([np.stack([ua, ub, uc], 1), np.stack([uc, ub, ud], 1)])
            if not want_out:
                tris, uvs = tris[:, ::-1], uvs[:, ::-1]
            F.append(tris)
            UV.append(uvs)

        add_grid(oid, uv_out, True)
        add_grid(iid, uv_in, False)
        # bands joining outside and lining: top ring, hem ring (normals up / down), opening edges
        c = np.arange(C)
        lin = lambda n: np.tile(np.array([[0.5 * (u0 + u1), 0.25]]), (n, 1))
        for r, sign in ((0, 1.0), (R - 1, -1.0)):
            a, b, cc_, d = oid[r, c], oid[r, c + 1], iid[r, c], iid[r, c + 1]
            tris = np.concatenate([np.stack([a, cc_, b], 1), np.stack([b, cc_, d], 1)])
            F.append(tris if sign < 0 else tris[:, ::-1])
            UV.append(np.stack([lin(len(tris))] * 3, 1))
        open_rows = np.flatnonzero(~closed)
        if len(open_rows):
            rs = open_rows[open_rows > 0] - 1  # quads between row r and r+1 where r+1 is open
            for col in (0, C):
                a, b, cc_, d = oid[rs, col], oid[rs + 1, col], iid[rs, col], iid[rs + 1, col]
                tris = np.concatenate([np.stack([a, b, cc_], 1), np.stack([cc_, b, d], 1)])
                tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])]
                F.append(tris)
                UV.append(np.stack([lin(len(tris))] * 3, 1))
        n_v += 2 * n_one
    vertices = np.concatenate(V)
    faces = np.concatenate(F).astype(np.int64)
    corner_uvs = np.concatenate(UV).astype(np.float32)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces, corner_uvs = faces[keep], corner_uvs[keep]
    mesh = GarmentMesh(kind, vertices, faces, corner_uvs, np.concatenate(OUT), np.concatenate(TUBE),
                       np.concatenate(GI), shapes, np.concatenate(TH),
                       info={"top_m": marks[prof.top], "hem_m": marks[prof.hem], "profile": prof.__dict__})
    _orient_outwards(mesh)
    return mesh


def _orient_outwards(mesh: GarmentMesh) -> None:
    """The grid faces are wound consistently; flip a whole tube whose signed volume comes out
    negative (faces pointing into the shell) so that every face points out, as the body's do."""
    v, f = mesh.vertices, mesh.faces
    for k in np.unique(mesh.tube):
        on = mesh.tube[f[:, 0]] == k
        a, b, c = v[f[on, 0]], v[f[on, 1]], v[f[on, 2]]
        vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
        if vol < 0:
            f[on] = f[on][:, ::-1]
            mesh.corner_uvs[on] = mesh.corner_uvs[on][:, ::-1]
