"""A body wearing a loose garment, as one mesh for the ground-truth renderer.

The body and the garment shell are concatenated into one triangle mesh (depth-tested together by
renderer/mesh_renderer.py) with one albedo atlas twice as wide as the body's: the body's atlas on
the left half, the garment's on the right (each mesh's texture coordinates squeezed into its
half). ``LooseOutfit.posed`` poses both with LBS (the garment with its own blended weights,
garment_skinning.py); ``renderer`` builds a MeshRenderer for it, optionally with other atlases
(the front-leak regions: the leak atlas on the body and black on the garment, which then hides
what it covers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...body.base import BodyModel, vertex_normals
from ...body.pose import BodyPose
from .clothing import PaintedClothing
from .garment_mesh import GarmentMesh, build_garment
from .garment_paint import GarmentColours, draw_colours, dress_body_texels, garment_rng, paint_garment
from .garment_skinning import garment_weights, pose_garment

GARMENT_VERSION = 1  # bump when the loose garments' geometry, skinning or colours change


@dataclass
class LooseOutfit:
    body: BodyModel
    garment: GarmentMesh
    weights: np.ndarray  # (Vg,J) garment skinning weights
    body_texture: np.ndarray  # (S,S,3) uint8, the dressed body
    garment_texture: np.ndarray  # (S,S,3) uint8
    colours: GarmentColours

    @property
    def num_body_vertices(self) -> int:
        return int(self.body.rest_vertices.shape[0])

    @property
    def faces(self) -> np.ndarray:
        return np.concatenate([self.body.faces.numpy(), self.garment.faces + self.num_body_vertices])

    @property
    def garment_face_mask(self) -> np.ndarray:
        nb = int(self.body.faces.shape[0])
        return np.r_[np.zeros(nb, bool), np.ones(len(self.garment.faces), bool)]

    @property
    def corner_uvs(self) -> np.ndarray:
        body_uv = self.body.uv_coords.numpy()[self.body.face_uv_indices.numpy()].astype(np.float32).copy()
        body_uv[..., 0] *= 0.5
        g = self.garment.corner_uvs.copy()
        g[..., 0] = 0.5 + 0.5 * g[..., 0]
        return np.concatenate([body_uv, g])

    def atlas(self, body_texture: np.ndarray | None = None, garment_texture: np.ndarray | None = None) -> np.ndarray:
        b = self.body_texture if body_texture is None else np.asarray(body_texture, np.uint8)[..., :3]
        g = self.garment_texture if garment_texture is None else np.asarray(garment_texture, np.uint8)[..., :3]
        if g.shape != b.shape:
            raise ValueError(f"outfit atlas: garment atlas {g.shape} and body atlas {b.shape} differ in size")
        return np.concatenate([b, g], axis=1)

    def posed(self, pose: BodyPose) -> tuple[np.ndarray, np.ndarray]:
        """(V,3) vertices and (V,3) normals of body + garment in ``pose``."""
        vb = self.body.posed_vertices(pose).numpy()
        vg = pose_garment(self.body, self.garment, self.weights, pose)
        v = np.concatenate([vb, vg])
        n = vertex_normals(torch.as_tensor(v), torch.as_tensor(self.faces)).numpy()
        return v, n

    def renderer(self, ctx, *, supersample: int = 2, ambient: float = 0.85, body_texture=None,
                 garment_texture=None, garment_only: bool = False):
        from renderer.mesh_renderer import MeshRenderer

        faces, uvs = self.faces, self.corner_uvs
        if garment_only:
            keep = self.garment_face_mask
            faces, uvs = faces[keep], uvs[keep]
        return MeshRenderer(ctx, faces, uvs, self.atlas(body_texture, garment_texture),
                            supersample=supersample, ambient=ambient)


def garment_pattern(body: BodyModel, kind: str, seed: int, texture_size: int) -> tuple[GarmentMesh, GarmentColours, np.ndarray]:
    """The loose garment ``kind`` of scene ``seed`` on ``body``, unskinned: its mesh, its colours and
    its (S,S,3) uint8 atlas. What ``dress`` and the ``fit=painted`` scenes (which wear no mesh) share."""
    garment = build_garment(body, kind)
    colours = draw_colours(garment_rng(seed, kind), kind)
    return garment, colours, paint_garment(garment, colours, texture_size)


def dress(body: BodyModel, kind: str, painted: PaintedClothing, seed: int, texture_size: int) -> LooseOutfit:
    """``body`` (painted with clothing.py's garment model) wearing the loose garment ``kind``."""
    garment, colours, garment_texture = garment_pattern(body, kind, seed, texture_size)
    weights = garment_weights(body, garment)
    body_tex = dress_body_texels(body, painted, colours, kind, texture_size)
    return LooseOutfit(body, garment, weights, body_tex, garment_texture, colours)
