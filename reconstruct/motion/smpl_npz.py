"""SMPL / SMPL-H / SMPL-X pose sequences in ``.npz`` files (AMASS and similar), read as data.

Keys: ``poses`` (T, 3K) axis-angles with the root first (72 for SMPL, 156 for SMPL-H, 165 for
SMPL-X; ``smpl_poses`` as AIST++ names it), or ``root_orient`` (T,3) with ``pose_body`` (T,63), or
``global_orient`` with ``body_pose`` as the smplx library names them (axis-angles or rotation
matrices, SMPL-X's 21 body joints or SMPL's 23); ``trans`` (T,3) in metres (``transl``, or AIST++'s
``smpl_trans`` divided by its ``smpl_scaling``; zero when missing); the frame rate in
``mocap_framerate``, ``mocap_frame_rate``, ``fps`` or ``frame_rate``.
The first 22 joints (the body) are used; hands, jaw and eyes are ignored, as are ``betas``,
``gender`` and anything else. Files are opened with ``allow_pickle=False``: pickled objects are
refused.

The sequence carries no body shape. Its rest skeleton is a nominal SMPL T-pose (approximate joint
positions of the mean shape, in SMPL's own axes: Y up, facing +Z, +X the body's left); retargeting
onto an SMPL body uses that body's own rest joints instead (``MotionClip.with_rest_offsets``).
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from ..body.smpl_backend import SMPL_JOINT_NAMES, SMPL_TO_BODY
from .axes import frame_to_body, snap_to_axis
from .clip import MotionClip, MotionFileError, SourceSkeleton
from .rotations import rotvec_to_matrix

NUM_BODY_JOINTS = 22
SMPL_PARENTS = np.array([-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19])
# Approximate rest joint positions of the mean SMPL body (metres, SMPL axes), pelvis at its place.
NOMINAL_JOINTS = np.array([
    [0.0, -0.22, 0.02],                                         # pelvis
    [0.06, -0.31, 0.01], [-0.06, -0.31, 0.01], [0.0, -0.11, 0.0],  # hips, spine1
    [0.10, -0.69, 0.01], [-0.10, -0.69, 0.01], [0.0, 0.03, 0.03],  # knees, spine2
    [0.09, -1.09, -0.03], [-0.09, -1.09, -0.03], [0.0, 0.08, 0.03],  # ankles, spine3
    [0.12, -1.15, 0.09], [-0.12, -1.15, 0.09], [0.0, 0.29, -0.01],  # feet (toes), neck
    [0.08, 0.20, 0.0], [-0.08, 0.20, 0.0], [0.0, 0.36, 0.04],       # collars, head
    [0.17, 0.23, -0.01], [-0.17, 0.23, -0.01],                      # shoulders
    [0.43, 0.21, -0.03], [-0.43, 0.21, -0.03],                      # elbows
    [0.69, 0.22, -0.03], [-0.69, 0.22, -0.03],                      # wrists
])
END_SITES = {10: np.array([0.0, -0.01, 0.06]), 11: np.array([0.0, -0.01, 0.06]), 15: np.array([0.0, 0.2, 0.0]),
             20: np.array([0.09, 0.0, 0.0]), 21: np.array([-0.09, 0.0, 0.0])}
FPS_KEYS = ("mocap_framerate", "mocap_frame_rate", "fps", "frame_rate")
FORMATS = {72: "smpl", 156: "smplh", 165: "smplx", 162: "smplx", 159: "smplx"}


def nominal_skeleton(joints: np.ndarray = NOMINAL_JOINTS) -> SourceSkeleton:
    joints = np.asarray(joints, np.float64)[:NUM_BODY_JOINTS]
    offsets = joints.copy()
    offsets[1:] -= joints[SMPL_PARENTS[1:]]
    return SourceSkeleton(tuple(SMPL_JOINT_NAMES[:NUM_BODY_JOINTS]), SMPL_PARENTS.copy(), offsets,
                          {k: v.copy() for k, v in END_SITES.items()}, naming="smpl")


def _load_arrays(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise MotionFileError(f"{path}: no such file")
    if not zipfile.is_zipfile(path):
        raise MotionFileError(f"{path}: not an .npz archive" + (" (it holds pickled data, which is refused: "
                              "save the arrays with numpy.savez)" if path.read_bytes()[:1] == b"\x80" else ""))
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {}
            for key in z.files:
                try:
                    out[key] = z[key]
                except ValueError as exc:
                    if "pickle" in str(exc).lower():
                        raise MotionFileError(f"{path}: array {key!r} holds pickled Python objects; such files "
                                              f"are refused (they can run code when loaded). Save plain numeric "
                                              f"arrays with numpy.savez instead.") from None
                    raise
    except MotionFileError:
        raise
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise MotionFileError(f"{path}: cannot be read as an .npz file: {exc}") from None
    return out


def _array(path: Path, arrays: dict, key: str, shape_tail: tuple[int, ...] | None = None) -> np.ndarray:
    a = arrays[key]
    if a.dtype.kind not in "fiu":
        raise MotionFileError(f"{path}: {key!r} must be numeric, found dtype {a.dtype}")
    a = a.astype(np.float64)
    if shape_tail is not None and (a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail):
        raise MotionFileError(f"{path}: {key!r} has shape {a.shape}, expected (T, {', '.join(map(str, shape_tail))})")
    if not np.all(np.isfinite(a)):
        raise MotionFileError(f"{path}: {key!r} contains non-finite values")
    return a


def _rotations(path: Path, arrays: dict, key: str, joints: tuple[int, ...]) -> np.ndarray:
    """(T, J, 3, 3) rotation matrices of ``arrays[key]``, whose J is one of ``joints``: axis-angles
    (T, 3J) or (T, J, 3), or rotation matrices (T, J, 3, 3) (and for one joint (T, 3) or (T, 3, 3)),
    as the smplx library's ``global_orient`` / ``body_pose`` and the tools built on it store them."""
    a = _array(path, arrays, key)
    T = a.shape[0] if a.ndim else 0
    for J in joints:
        if a.shape in ((T, 3 * J), (T, J, 3)):
            return rotvec_to_matrix(a.reshape(T, J, 3))
        if a.shape == (T, J, 3, 3) or (J == 1 and a.shape == (T, 3, 3)):
            R = a.reshape(T, J, 3, 3)
            err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(initial=0.0)
            if err > 1e-3 or (np.linalg.det(R) < 0).any():
                raise MotionFileError(f"{path}: {key!r} holds 3x3 matrices that are not rotations "
                                      f"(R Rt differs from I by {err:.3g})")
            return R
    shapes = " or ".join(f"(T, {3 * J}), (T, {J}, 3), (T, {J}, 3, 3)" for J in joints)
    raise MotionFileError(f"{path}: {key!r} has shape {a.shape}, expected {shapes}")


def read_smpl_npz(path: str | os.PathLike, *, default_fps: float = 30.0) -> MotionClip:
    """Reads an SMPL-family ``.npz`` sequence into a ``MotionClip`` (22 body joints)."""
    path = Path(path)
    arrays = _load_arrays(path)
    notes = []
    poses_key = next((k for k in ("poses", "smpl_poses") if k in arrays), None)
    if poses_key is not None:
        poses = _array(path, arrays, poses_key)
        if poses.ndim != 2 or poses.shape[1] % 3 or poses.shape[1] < 3 * NUM_BODY_JOINTS:
            raise MotionFileError(f"{path}: {poses_key!r} has shape {poses.shape}, expected (T, 3K) with K >= "
                                  f"{NUM_BODY_JOINTS} joints (72 SMPL, 156 SMPL-H, 165 SMPL-X)")
        fmt = FORMATS.get(poses.shape[1], "smpl-family")
        local = rotvec_to_matrix(poses[:, : 3 * NUM_BODY_JOINTS].reshape(-1, NUM_BODY_JOINTS, 3))
        if poses.shape[1] > 3 * NUM_BODY_JOINTS:
            notes.append(f"{poses.shape[1] // 3 - NUM_BODY_JOINTS} hand/face joints ignored")
    elif "root_orient" in arrays and "pose_body" in arrays:
        root = _array(path, arrays, "root_orient", (3,))
        pb = _array(path, arrays, "pose_body", (3 * (NUM_BODY_JOINTS - 1),))
        if root.shape[0] != pb.shape[0]:
            raise MotionFileError(f"{path}: 'root_orient' has {root.shape[0]} frames, 'pose_body' {pb.shape[0]}")
        local, fmt = rotvec_to_matrix(np.concatenate([root, pb], 1).reshape(-1, NUM_BODY_JOINTS, 3)), "smplh"
    elif "global_orient" in arrays and "body_pose" in arrays:
        root = _rotations(path, arrays, "global_orient", (1,))
        rest = _rotations(path, arrays, "body_pose", (NUM_BODY_JOINTS - 1, 23))
        if root.shape[0] != rest.shape[0]:
            raise MotionFileError(f"{path}: 'global_orient' has {root.shape[0]} frames, 'body_pose' {rest.shape[0]}")
        if rest.shape[1] > NUM_BODY_JOINTS - 1:
            notes.append(f"{rest.shape[1] - (NUM_BODY_JOINTS - 1)} hand joints of 'body_pose' ignored (SMPL's)")
        local, fmt = np.concatenate([root, rest[:, : NUM_BODY_JOINTS - 1]], 1), "smpl-family"
    else:
        raise MotionFileError(f"{path}: no SMPL pose arrays: expected 'poses' or 'smpl_poses' (T, 72|156|165), "
                              f"'root_orient' with 'pose_body', or 'global_orient' with 'body_pose'; found keys "
                              f"{sorted(arrays)}")
    T = local.shape[0]
    if T == 0:
        raise MotionFileError(f"{path}: empty motion (0 frames)")
    trans_key = next((k for k in ("trans", "transl", "smpl_trans") if k in arrays), None)
    if trans_key is not None:
        trans = _array(path, arrays, trans_key)
        trans = trans.reshape(trans.shape[0], -1) if trans.ndim == 3 and trans.shape[1] == 1 else trans
        if trans.ndim != 2 or trans.shape[1:] != (3,):
            raise MotionFileError(f"{path}: {trans_key!r} has shape {trans.shape}, expected (T, 3)")
        if trans.shape[0] != T:
            raise MotionFileError(f"{path}: {trans_key!r} has {trans.shape[0]} frames, the poses {T}")
        if trans_key == "smpl_trans" and "smpl_scaling" in arrays:
            # AIST++: the translation is in the units of a body scaled by smpl_scaling
            scale = np.asarray(arrays["smpl_scaling"], np.float64).reshape(-1)
            if scale.size != 1 or not np.isfinite(scale[0]) or scale[0] <= 0:
                raise MotionFileError(f"{path}: 'smpl_scaling' must be one positive number, "
                                      f"found {arrays['smpl_scaling']!r}")
            trans = trans / scale[0]
            notes.append(f"'smpl_trans' divided by 'smpl_scaling' ({scale[0]:g})")
    else:
        trans = np.zeros((T, 3))
        notes.append("no 'trans': the root stays in place")
    fps = None
    for key in FPS_KEYS:
        if key in arrays:
            v = np.asarray(arrays[key]).reshape(-1)
            if v.size != 1 or v.dtype.kind not in "fiu" or not np.isfinite(v[0]) or v[0] <= 0:
                raise MotionFileError(f"{path}: {key!r} must be one positive number, found {arrays[key]!r}")
            fps = float(v[0])
            break
    if fps is None:
        fps = float(default_fps)
        notes.append(f"no frame rate in the file ({', '.join(FPS_KEYS)}): assumed {fps:g} fps")
    skeleton = nominal_skeleton()
    root_positions = trans + skeleton.offsets[0]
    clip = MotionClip(skeleton, local, root_positions, fps, SMPL_TO_BODY.copy(), np.eye(3), 1.0, str(path), fmt,
                      tuple(notes))
    return clip.with_(world_to_body=_world_axes(clip))


def _world_axes(clip: MotionClip) -> np.ndarray:
    """The sequence's world up (mean feet -> neck direction) and facing, snapped to axes."""
    Q, P = clip.world()
    up = snap_to_axis((P[:, 12] - 0.5 * (P[:, 7] + P[:, 8])).mean(0))
    facing = (Q[:, 0] @ np.array([0.0, 0.0, 1.0])).mean(0)  # SMPL faces +Z at rest
    facing -= (facing @ up) * up
    if np.linalg.norm(facing) < 1e-6:
        facing = np.roll(up, 1)
    return frame_to_body(up, snap_to_axis(facing, exclude=up))
