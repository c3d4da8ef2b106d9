"""Retargeting a ``MotionClip`` onto a body (Anny or SMPL) by joint roles.

For every source joint that plays a role the body also has (``roles.py``), the joint's world
rotation relative to the source's rest pose is carried onto the body's bone relative to the body's
zero pose, after a fixed rest alignment ``B`` per bone: the smallest rotation taking the bone's
zero-pose direction (head to the next role's head) onto the source bone's rest direction. So a
T-posed source frame puts Anny's arms straight out, and in every frame the mapped bones point where
the source's bones point. Bones without a reliable direction (hips, head, hands, toes) take their
parent's alignment. Body bones the source lacks keep their zero-pose rotation relative to their
parent; source joints the body lacks are dropped (their rotation still reaches the mapped joints
below them, since rotations are carried over in world axes).

The root translation is scaled by the ratio of leg lengths (body / source). The clip is turned about
the vertical so that its first frame faces like ``base_pose`` (or -Y), moved so its hips start above
``base_pose``'s hips (or the body's own), and shifted vertically so that its lowest foot point over the
whole clip touches the floor: the lowest foot point over ``floor_poses`` (or ``base_pose``, or the
body's canonical pose).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np

from ..body.pose import BodyPose
from .axes import leg_length
from .body_kinematics import BodySkeleton
from .clip import MotionClip
from .roles import (
    INHERIT_ALIGNMENT,
    TIP_ROLE,
    body_naming,
    find_roles,
    match_spines,
    spine_chain,
)
from .rotations import matrix_to_rotvec, rotation_between, yaw_about_z
from .timing import sample

_SKELETONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class BoneMapping:
    """One source joint driving one body bone, with its rest alignment (3,3)."""

    role: str
    source_joint: str
    body_bone: str
    alignment: np.ndarray


@dataclass
class RetargetResult:
    """The retargeted motion: one ``BodyPose`` per output frame at ``fps``.

    mapping: the source joint behind each driven body bone. dropped: source joints with no role on
    the body. scale: metres of body translation per file unit (leg-length ratio). floor: the floor's
    height along the up direction the clip was grounded on. notes: what was assumed or left out.
    """

    poses: list[BodyPose]
    fps: float
    notes: list[str] = field(default_factory=list)
    mapping: list[BoneMapping] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)
    scale: float = 1.0
    floor: float = 0.0
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    @property
    def num_frames(self) -> int:
        return len(self.poses)

    @property
    def duration(self) -> float:
        return self.num_frames / self.fps


def body_skeleton(body) -> BodySkeleton:
    """The (cached) numpy kinematics of ``body``."""
    try:
        sk = _SKELETONS.get(body)
    except TypeError:
        return BodySkeleton(body)
    if sk is None:
        sk = BodySkeleton(body)
        _SKELETONS[body] = sk
    return sk


def _children_mean(positions: np.ndarray, parents: np.ndarray, j: int, end_site: np.ndarray | None = None
                   ) -> np.ndarray | None:
    kids = np.nonzero(parents == j)[0]
    pts = [positions[k] for k in kids if np.linalg.norm(positions[k] - positions[j]) > 1e-6]
    if pts:
        return np.mean(pts, 0)
    if end_site is not None and np.linalg.norm(end_site) > 1e-9:
        return positions[j] + end_site
    return None


def _matches(clip: MotionClip, sk: BodySkeleton, src_rest: np.ndarray) -> tuple[list[tuple[str, int, int]], dict, dict]:
    names = clip.skeleton.names
    src_roles = find_roles(names, clip.skeleton.naming)
    body_roles = find_roles(sk.labels, body_naming(sk.labels))
    if "hips" not in body_roles:
        raise ValueError(f"retarget: the body {getattr(sk.body, 'name', '?')} has no hips/root bone among "
                         f"{sk.labels[:8]}...")
    if "hips" not in src_roles:
        src_roles["hips"] = 0  # the root joint plays the hips
    matches = [(role, src_roles[role], body_roles[role]) for role in src_roles if role in body_roles]
    s_chain, s_frac = spine_chain(clip.skeleton.parents, src_rest, src_roles)
    b_chain, b_frac = spine_chain(sk.parents, sk.zero_heads, body_roles)
    taken_src = {m[1] for m in matches}
    taken_body = {m[2] for m in matches}
    k = 0
    for _, s, b in match_spines(s_chain, s_frac, b_chain, b_frac):
        if s in taken_src or b in taken_body:
            continue
        matches.append((f"spine{k}", s, b))
        k += 1
    return matches, src_roles, body_roles


def _alignments(clip: MotionClip, sk: BodySkeleton, matches, src_rest_body: np.ndarray) -> dict[int, np.ndarray]:
    """Body bone -> rest alignment B (3,3)."""
    by_role = {role: (s, b) for role, s, b in matches}
    spines = sorted((role for role in by_role if role.startswith("spine")), key=lambda r: int(r[5:]))
    tips = dict(TIP_ROLE)
    for i, role in enumerate(spines):
        nxt = spines[i + 1] if i + 1 < len(spines) else ("neck" if "neck" in by_role else "head")
        tips[role] = nxt
    src_par = clip.skeleton.parents
    end_sites = {j: clip.skeleton.end_sites[j] @ clip.rest_to_body.T for j in clip.skeleton.end_sites}
    own: dict[int, np.ndarray | None] = {}
    for role, (s, b) in by_role.items():
        if role in INHERIT_ALIGNMENT:
            own[b] = None
            continue
        tip = tips.get(role)
        if tip in by_role:
            ds = src_rest_body[by_role[tip][0]] - src_rest_body[s]
            db = sk.zero_heads[by_role[tip][1]] - sk.zero_heads[b]
        else:
            ts = _children_mean(src_rest_body, src_par, s, end_sites.get(s))
            tb = _children_mean(sk.zero_heads, sk.parents, b)
            if ts is None or tb is None:
                own[b] = None
                continue
            ds, db = ts - src_rest_body[s], tb - sk.zero_heads[b]
        if np.linalg.norm(ds) < 1e-9 or np.linalg.norm(db) < 1e-9:
            own[b] = None
            continue
        own[b] = rotation_between(db, ds)
    out: dict[int, np.ndarray] = {}
    current: dict[int, np.ndarray] = {}
    for j in sk.order:  # inherit along the body's hierarchy
        p = sk.parents[j]
        parent_B = current[p] if p >= 0 else np.eye(3)
        if j in own:
            B = own[j] if own[j] is not None else parent_B
            out[j] = B
            current[j] = B
        else:
            current[j] = parent_B
    return out


def _heading(R: np.ndarray) -> float | None:
    """Yaw (rad) of the facing direction R @ -Y, measured so that facing -Y is 0."""
    f = R @ np.array([0.0, -1.0, 0.0])
    if math.hypot(f[0], f[1]) < 1e-6:
        return None
    return math.atan2(f[0], -f[1])


def _placement(sk: BodySkeleton, hips: int, base_pose: BodyPose | None, floor_poses: list[BodyPose] | None
               ) -> tuple[np.ndarray, np.ndarray]:
    """(P, b): rotation from the clip's body space into the world, and the world hips position.

    Up is the mean up direction of the hips over the base pose and the floor poses (the scene's
    world need not be Z up: dataset SMPL poses may live in camera axes); the heading is the base
    pose's."""
    if base_pose is None:
        return np.eye(3), sk.zero_heads[hips].copy()
    poses = [base_pose] + list(floor_poses or [])
    E, p, G, t = sk.forward_poses(poses)
    M = np.einsum("tab,tbc->tac", G, E[:, hips])
    up = (M @ np.array([0.0, 0.0, 1.0])).mean(0)
    up /= np.linalg.norm(up)
    front = M[0] @ np.array([0.0, -1.0, 0.0])
    front -= (front @ up) * up
    if np.linalg.norm(front) < 1e-6:
        front = M[0] @ np.array([0.0, 0.0, -1.0])
        front -= (front @ up) * up
    front /= np.linalg.norm(front)
    y = -front
    x = np.cross(y, up)
    P = np.stack([x, y, up], 1)
    return P, G[0] @ p[0, hips] + t[0]


STANDING_TOLERANCE_DEG = 30.0


def rest_stance(rest_body: np.ndarray, roles: dict[str, int]) -> list[str]:
    """What keeps a source's rest skeleton (body axes, Z up) from standing: each thigh and shin, and
    the hips-to-neck line, more than ``STANDING_TOLERANCE_DEG`` from vertical, e.g. "left thigh 48°".
    The arms may be in any rest (T, A or down)."""
    down, up = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])
    segments = []
    for s, side in (("l", "left"), ("r", "right")):
        segments += [(f"{side} thigh", f"upperleg_{s}", f"lowerleg_{s}", down),
                     (f"{side} shin", f"lowerleg_{s}", f"foot_{s}", down)]
    segments.append(("spine", "hips", "neck" if "neck" in roles else "head", up))
    out = []
    for label, a, b, want in segments:
        if a not in roles or b not in roles:
            continue
        d = rest_body[roles[b]] - rest_body[roles[a]]
        n = np.linalg.norm(d)
        if n < 1e-9:
            continue
        angle = math.degrees(math.acos(float(np.clip(d @ want / n, -1.0, 1.0))))
        if angle > STANDING_TOLERANCE_DEG:
            out.append(f"{label} {angle:.0f}°")
    return out


def retarget(clip: MotionClip, body, *, fps: float | None = None, start: float | None = None,
             end: float | None = None, loop: bool = False, base_pose: BodyPose | None = None,
             floor_poses: list[BodyPose] | None = None, keep_heading: bool = False) -> RetargetResult:
    """Poses of ``body`` performing ``clip``.

    fps: output frame rate (default: the clip's). start, end: seconds into the clip. loop: make the
    frames loop seamlessly (``timing.sample``). base_pose: a pose of the body (e.g. the training
    video's first frame) whose hips position, up direction and heading the clip starts from.
    floor_poses: poses (e.g. the training video's) whose lowest foot point is the floor.
    keep_heading: keep the file's own facing instead of turning the first frame to the base's.
    """
    notes = list(clip.notes)
    sk = body_skeleton(body)
    if clip.skeleton.naming == "smpl" and body_naming(sk.labels) == "smpl_body":
        from ..body.smpl_backend import SMPL_TO_BODY
        from .smpl_npz import NUM_BODY_JOINTS, nominal_skeleton

        own = nominal_skeleton(np.asarray(body.rest_joints, np.float64)[:NUM_BODY_JOINTS] @ SMPL_TO_BODY)
        clip = clip.with_rest_offsets(own.offsets)
        notes.append("SMPL sequence on an SMPL body: the body's own rest joints are the source skeleton")
    Cr, Cw = clip.rest_to_body, clip.world_to_body
    src_rest = clip.skeleton.rest_positions()
    src_rest_body = src_rest @ Cr.T
    matches, src_roles, body_roles = _matches(clip, sk, src_rest)
    B = _alignments(clip, sk, matches, src_rest_body)
    names = clip.skeleton.names
    mapped_src = {s for _, s, _ in matches}
    dropped = [names[j] for j in range(len(names)) if j not in mapped_src]
    if dropped:
        notes.append(f"{len(dropped)} source joints have no bone on the {getattr(body, 'name', 'body')} body and "
                     f"are dropped: {', '.join(dropped[:12])}{' ...' if len(dropped) > 12 else ''}")
    bent = rest_stance(src_rest_body, src_roles)
    if bent:
        notes.append(f"the source's rest pose does not stand upright ({', '.join(bent)} from vertical): it is likely a "
                     "frame of the motion (an FBX without a bind pose keeps the pose of the frame it was exported "
                     "at), and every pose is read relative to it; export the motion with its mesh or at a T-pose "
                     "frame")
    missing = sorted(r for r in body_roles if r not in src_roles)
    if missing:
        notes.append(f"the source has no joint for {', '.join(missing)}: those bones stay at rest relative to their parent")

    # ----- scale ------------------------------------------------------------------------------
    leg_src = leg_length(src_rest, src_roles)
    leg_body = leg_length(sk.zero_heads, body_roles)
    if leg_src and leg_body:
        scale = leg_body / leg_src
        how = "leg length"
    else:
        hs = src_rest_body[:, 2]
        hb = sk.zero_heads[:, 2]
        scale = float(np.ptp(hb) / max(np.ptp(hs), 1e-9))
        how = "skeleton height (no legs to compare)"
    notes.append(f"root translation scaled by {scale:.4g} (body / source {how}; about "
                 f"{scale / clip.metres_per_unit:.2f} x the source size in metres)")

    # ----- motion -----------------------------------------------------------------------------
    sm = sample(clip, fps, start, end, loop)
    notes.extend(sm.notes)
    Q, P = clip.world(sm.local_rotations, sm.root_positions)
    T = Q.shape[0]
    hips_s, hips_b = src_roles["hips"], body_roles["hips"]
    targets = {b: np.einsum("ab,tbc,cd->tad", Cw, Q[:, s], Cr.T @ B[b]) for _, s, b in matches}
    # heading: turn the first frame to face -Y (the placement then turns it to the base's heading)
    H = np.eye(3)
    if not keep_heading:
        yaw = _heading(targets[hips_b][0])
        if yaw is not None:
            H = yaw_about_z(-yaw)
        else:
            notes.append("the first frame's facing is vertical: heading left as in the file")
    local = np.empty((T, sk.num_bones, 3, 3))
    E = np.empty_like(local)
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))
    for j in sk.order:
        p = sk.parents[j]
        Ep = E[:, p] if p >= 0 else eye
        if j in targets:
            E[:, j] = H @ targets[j]
        else:
            E[:, j] = Ep
        local[:, j] = np.swapaxes(Ep, -1, -2) @ E[:, j]
    E, heads = sk.forward(local)
    # root translation: the hips follow the source's hips, scaled, starting above the origin
    x = P[:, hips_s] @ Cw.T
    y = (x - x[0]) * scale @ H.T + sk.zero_heads[hips_b]
    transl = y - heads[:, hips_b]

    # ----- placement and floor ----------------------------------------------------------------
    Pw, b = _placement(sk, hips_b, base_pose, floor_poses)
    up = Pw[:, 2]
    lowest = float(sk.foot_heights(E, heads, np.array([0.0, 0.0, 1.0]), None, transl).min())
    if floor_poses:
        Ef, pf, Gf, tf = sk.forward_poses(list(floor_poses))
        floor = float(sk.foot_heights(Ef, pf, up, Gf, tf).min())
        where = f"the lowest foot point over {len(floor_poses)} floor poses"
    elif base_pose is not None:
        Ef, pf, Gf, tf = sk.forward_poses([base_pose])
        floor = float(sk.foot_heights(Ef, pf, up, Gf, tf).min())
        where = "the base pose's lowest foot point"
    else:
        c = body.canonical_pose()
        Ef, pf, Gf, tf = sk.forward_poses([c])
        floor = float(sk.foot_heights(Ef, pf, up, Gf, tf).min())
        where = "the canonical pose's lowest foot point"
    notes.append(f"grounded: the clip's lowest foot point touches {where}")
    horiz = np.eye(3) - np.outer(up, up)
    t_w = horiz @ (b - Pw @ y[0]) + (floor - lowest) * up
    glob = matrix_to_rotvec(Pw)
    world_t = transl @ Pw.T + t_w
    rotvecs = matrix_to_rotvec(local)
    poses = [BodyPose(rotvecs[i], glob, world_t[i]) for i in range(T)]
    mapping = [BoneMapping(role, names[s], sk.labels[b], B[b]) for role, s, b in matches]
    return RetargetResult(poses, sm.fps, notes, mapping, dropped, float(scale), floor, up)
