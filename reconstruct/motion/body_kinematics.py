"""Batched forward kinematics of a ``BodyModel`` in numpy, for many frames at once.

The body's reference is its zero pose (all joint rotations zero; for Anny this is its reference
pose, which differs slightly from the rest mesh). ``BodyPose`` composes as: each bone's rotation
relative to the zero pose is ``E_c = E_parent @ exp(r_c)``, its head moves with its parent,
``p_c = p_parent + E_parent (z_c - z_parent)`` (``z``: zero-pose heads), and the root turns about its
own head; global_orient/transl then move everything about the world origin. ``check_against_body``
in the tests compares this with the body's own ``bone_transforms``.
"""

from __future__ import annotations

import numpy as np

from ..body.pose import BodyPose
from .rotations import rotvec_to_matrix

FOOT_PARTS = ("foot.L", "foot.R")


class BodySkeleton:
    """A body's zero-pose skeleton, bone order and foot surface points."""

    def __init__(self, body, *, foot_points_per_side: int = 300, influences: int = 4) -> None:
        self.body = body
        self.labels = list(body.bone_labels)
        self.parents = np.asarray(body.bone_parents, np.int64)
        J = len(self.labels)
        T0 = body.bone_transforms(BodyPose.zeros(J)).numpy()
        rest = np.asarray(body.rest_joints, np.float64)
        self.zero_heads = np.einsum("jab,jb->ja", T0[:, :3, :3], rest) + T0[:, :3, 3]
        self.order = self._topological_order()
        self._foot_setup(body, T0, foot_points_per_side, influences)

    @property
    def num_bones(self) -> int:
        return len(self.labels)

    def _topological_order(self) -> list[int]:
        children: dict[int, list[int]] = {}
        roots = []
        for j, p in enumerate(self.parents):
            (roots if p < 0 else children.setdefault(int(p), [])).append(j)
        order, stack = [], roots[::-1]
        while stack:
            j = stack.pop()
            order.append(j)
            stack.extend(children.get(j, [])[::-1])
        return order

    def _foot_setup(self, body, T0: np.ndarray, per_side: int, K: int) -> None:
        from ..body.parts import PART_INDEX

        parts = np.asarray(body.vertex_parts)
        W = np.asarray(body.skin_weights, np.float64)
        V = np.asarray(body.rest_vertices, np.float64)
        idx = []
        for part in FOOT_PARTS:
            sel = np.nonzero(parts == PART_INDEX[part])[0]
            if len(sel) > per_side:
                sel = sel[np.linspace(0, len(sel) - 1, per_side).round().astype(np.int64)]
            idx.append(sel)
        idx = np.concatenate(idx) if idx else np.zeros(0, np.int64)
        if len(idx) == 0:  # no foot part: the lowest vertices of the zero pose
            zpos = np.einsum("vj,jab,vb->va", W, T0[:, :3, :3], V) + W @ T0[:, :3, 3]
            idx = np.argsort(zpos[:, 2])[:per_side]
        w = W[idx]
        bones = np.argsort(-w, axis=1)[:, :K]
        wk = np.take_along_axis(w, bones, 1)
        wk /= wk.sum(1, keepdims=True)
        self.foot_vertices = idx
        self.foot_bones = bones  # (N,K)
        self.foot_weights = wk  # (N,K)
        # each point as carried by each of its bones into the zero pose
        self.foot_zero = np.einsum("nkab,nb->nka", T0[bones, :3, :3], V[idx]) + T0[bones, :3, 3]

    # ----- kinematics ----------------------------------------------------------------------------
    def forward(self, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T,J,3,3) local rotations -> (T,J,3,3) rotations relative to the zero pose and (T,J,3)
        head positions, without the global motion."""
        T, J = local.shape[:2]
        E = np.empty_like(local)
        p = np.empty((T, J, 3))
        z = self.zero_heads
        for j in self.order:
            par = self.parents[j]
            if par < 0:
                E[:, j] = local[:, j]
                p[:, j] = z[j]
            else:
                E[:, j] = E[:, par] @ local[:, j]
                p[:, j] = p[:, par] + E[:, par] @ (z[j] - z[par])
        return E, p

    def forward_poses(self, poses: list[BodyPose]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """E, p of ``forward`` plus each pose's global rotation (T,3,3) and translation (T,3)."""
        rot = rotvec_to_matrix(np.stack([p.joint_rotations for p in poses]))
        E, p = self.forward(rot)
        G = rotvec_to_matrix(np.stack([q.global_orient for q in poses]))
        t = np.stack([q.transl for q in poses])
        return E, p, G, t

    def foot_heights(self, E: np.ndarray, p: np.ndarray, up: np.ndarray, G: np.ndarray | None = None,
                     t: np.ndarray | None = None, chunk: int = 128) -> np.ndarray:
        """(T,) height along ``up`` of the lowest foot surface point in each frame."""
        T = E.shape[0]
        up = np.asarray(up, np.float64)
        b, w, y = self.foot_bones, self.foot_weights, self.foot_zero
        zb = self.zero_heads[b]  # (N,K,3)
        out = np.empty(T)
        for s in range(0, T, chunk):
            Ec, pc = E[s:s + chunk], p[s:s + chunk]
            # x = sum_k w_k (E_k (y_k - z_k) + p_k)
            x = np.einsum("tnkab,nkb->tnka", Ec[:, b], y - zb) + pc[:, b]
            x = np.einsum("nk,tnka->tna", w, x)
            if G is not None:
                x = np.einsum("tab,tnb->tna", G[s:s + chunk], x)
            h = x @ up
            if t is not None:
                h = h + (t[s:s + chunk] @ up)[:, None]
            out[s:s + chunk] = h.min(1)
        return out
