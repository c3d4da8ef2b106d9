"""A skeleton given as a node hierarchy (glTF, FBX) turned into the ``MotionClip`` convention.

Files from scene tools give each joint a rest transform that need not be the identity and nodes
above the skeleton (an armature turned to Y up, scaled from centimetres) that place it in the scene.
With R0 the rest world rotations and L(t) a joint's animated local rotation, the clip's local
rotation is ``R0_parent L(t) R0_joint^T`` (identity at rest), and a joint's offset is its rest world
position less its parent's; the root's parent is the nodes above it as they stand in each frame.

Also what the FBX, glTF and BVH readers share: which joints above the first branch are the
armature (``first_branch``, ``role_joints``), and whether a baked channel moves at all (``varies``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .axes import skeleton_axes
from .clip import MotionClip, SourceSkeleton


def rotation_part(M: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations of affine matrices (..., >=3, >=3) whose scale acts first (``R S``)."""
    A = M[..., :3, :3]
    norms = np.linalg.norm(A, axis=-2, keepdims=True)
    return A / np.where(norms > 0, norms, 1.0)


def first_branch(root, kids, keep=frozenset()) -> tuple[object, list]:
    """(the skeleton's working root, the joints above it): where a tree starts with a chain of
    single-child joints that ends in a joint with two or more children (an armature exported as a
    joint, a game rig's 'root' bone above the pelvis), that joint is the root and the chain goes
    above it with the armature, its motion carried into the root's; a tree that never branches keeps
    its root. The chain stops at a joint in ``keep`` (one that plays a role, e.g. the hips), which
    then is the root. ``kids(j)``: j's child joints."""
    path = [root]
    while path[-1] not in keep and len(kids(path[-1])) == 1:
        path.append(kids(path[-1])[0])
    end = path[-1]
    return (end, path[:-1]) if end in keep or len(kids(end)) >= 2 else (root, [])


def role_joints(nodes, names) -> frozenset:
    """The ``nodes`` (in the order of their ``names``) that play a role by name (``roles.py``):
    never read as part of the armature."""
    from .roles import find_roles

    return frozenset(nodes[i] for i in find_roles(list(names), "bvh").values())


def wrapper_note(wrappers: list[str], root: str) -> str:
    names = ", ".join(repr(n) for n in wrappers)
    whose = "its" if len(wrappers) == 1 else "their"
    return f"{names} above {root!r} read as the armature: {whose} motion is the root's"


def varies(values) -> bool:
    """Whether keyed values (K, ...) change along their keys by more than float32 rounding: exporters
    bake every channel of every joint, most of them constant."""
    v = np.asarray(values, np.float64)
    return v.shape[0] > 1 and float(np.ptp(v, axis=0).max()) > 1e-5 * max(1.0, float(np.abs(v).max()))


def rig_clip(path: Path, names, parents: np.ndarray, rest_world: np.ndarray, local_rotations: np.ndarray,
             above: np.ndarray, root_translation: np.ndarray, fps: float, *, up: str | None, forward: str | None,
             metres_per_unit: float, fmt: str, notes: list[str]) -> MotionClip:
    """``rest_world`` (J,4,4): each joint's world matrix at rest (parents first, the root first);
    ``local_rotations`` (T,J,3,3): each joint's animated rotation relative to its parent node;
    ``above`` (T,4,4): the nodes above the root in each frame; ``root_translation`` (T,3): the root's
    animated position in their frame. Units are the file's scene units (``metres_per_unit``)."""
    J = len(names)
    rot0 = rotation_part(rest_world)
    positions = rest_world[:, :3, 3]
    offsets = np.stack([positions[0]] + [positions[k] - positions[parents[k]] for k in range(1, J)])
    above_rot = rotation_part(above)
    local_out = np.empty_like(local_rotations)
    for k in range(J):
        outer = above_rot if parents[k] < 0 else rot0[parents[k]]
        local_out[:, k] = outer @ local_rotations[:, k] @ rot0[k].T
    root = np.einsum("tij,tj->ti", above[:, :3, :3], root_translation) + above[:, :3, 3]
    skeleton = SourceSkeleton(tuple(names), parents, offsets, {}, naming="bvh")
    _, _, how, C = skeleton_axes(path, names, skeleton.rest_positions(), up, forward)
    notes = list(notes) + [f"{fmt}: {J} joints, {local_rotations.shape[0]} frames at {fps:g} fps; axes {how}"]
    return MotionClip(skeleton, local_out, root, fps, C, C, float(metres_per_unit), str(path), fmt.lower(),
                      tuple(notes))
