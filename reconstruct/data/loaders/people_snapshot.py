"""PeopleSnapshot as processed by InstantAvatar (``scripts/peoplesnapshot/preprocess_PeopleSnapshot.py``):

    FOLDER/cameras.npz          intrinsic (3,3), extrinsic (4,4) world-to-camera, height, width
    FOLDER/images/image_NNNN.png  undistorted frames (N = frame number, from 0)
    FOLDER/masks/mask_NNNN.npy    uint8 masks (0/1; 0/255 also read)
    FOLDER/poses.npz            betas (10,) or (1,10), thetas (T,72) [global_orient, body_pose], transl (T,3)
                                (or InstantAvatar's refined global_orient (T,3), body_pose (T,69), transl)

The body in the world is smplx's ``SMPL(global_orient, body_pose, betas) + transl``; pose row n
belongs to frame n. A monocular dataset has no other camera: its evaluation views are the
training camera's own frames (every ``eval_every``-th selected frame, all "seen").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...body.smpl_backend import smpl_body_pose
from ...body.spec import smpl_body_spec
from ..scene import EvalView, Scene
from .common import (LoaderError, Protocol, check_size, finish_frame, match_counts, numbered_files, opencv_camera,
                     read_mask, read_rgb, smpl_shape_error)

NAME = "snapshot"
NEEDS = "cameras.npz, poses.npz, images/image_NNNN.png and masks/mask_NNNN.npy"
FPS = 30.0


def matches(folder: Path) -> bool:
    return (folder / "cameras.npz").is_file() and (folder / "poses.npz").is_file()


def _npz(path: Path, what: str) -> dict:
    if not path.is_file():
        raise LoaderError(f"{path}: missing ({what})")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception as exc:
        raise LoaderError(f"{path}: cannot be read as an .npz file ({what}): {exc}") from exc


def read_poses(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(full poses (T,72), transl (T,3), betas (B,))."""
    d = _npz(path, "SMPL parameters")
    if "thetas" in d:
        full = np.asarray(d["thetas"], np.float64)
        if full.ndim != 2 or full.shape[1] != 72:
            raise smpl_shape_error(path, "thetas", "(T, 72): per frame SMPL's 24 joints x 3 axis-angle values", full)
    elif "global_orient" in d and "body_pose" in d:
        go, bp = np.asarray(d["global_orient"], np.float64), np.asarray(d["body_pose"], np.float64)
        if go.ndim != 2 or go.shape[1] != 3:
            raise smpl_shape_error(path, "global_orient", "(T, 3)", go)
        if bp.ndim != 2 or bp.shape[1] != 69 or bp.shape[0] != go.shape[0]:
            raise smpl_shape_error(path, "body_pose", f"({go.shape[0]}, 69)", bp)
        full = np.concatenate([go, bp], axis=1)
    else:
        raise LoaderError(f"{path}: expected 'thetas' (or 'global_orient' and 'body_pose'), 'transl' and 'betas'; "
                          f"found keys {sorted(d)}")
    if "transl" not in d:
        raise LoaderError(f"{path}: missing 'transl'; found keys {sorted(d)}")
    transl = np.asarray(d["transl"], np.float64)
    if transl.shape != (full.shape[0], 3):
        raise smpl_shape_error(path, "transl", f"({full.shape[0]}, 3), one per pose", transl)
    betas = np.asarray(d.get("betas", np.zeros(10)), np.float64)
    if betas.ndim == 2:
        betas = betas[0]
    if betas.ndim != 1:
        raise smpl_shape_error(path, "betas", "(10,) or (1, 10)", betas)
    return full, transl, betas


def guess_gender(folder: Path) -> str:
    name = folder.name.lower()
    return "female" if name.startswith("female") else "male" if name.startswith("male") else "neutral"


def load(folder: str | Path, protocol: Protocol | None = None) -> Scene:
    folder = Path(folder)
    protocol = protocol or Protocol()
    if protocol.train_camera not in (None, 0, "0"):
        raise LoaderError(f"{folder}: PeopleSnapshot has one camera (0), train_camera={protocol.train_camera!r}")
    cam_path = folder / "cameras.npz"
    cam = _npz(cam_path, "camera")
    missing = [k for k in ("intrinsic", "extrinsic", "height", "width") if k not in cam]
    if missing:
        raise LoaderError(f"{cam_path}: missing {missing}; found keys {sorted(cam)}")
    K, E = np.asarray(cam["intrinsic"], np.float64), np.asarray(cam["extrinsic"], np.float64)
    if K.shape != (3, 3) or E.shape not in ((4, 4), (3, 4)):
        raise LoaderError(f"{cam_path}: intrinsic {K.shape} / extrinsic {E.shape}, expected (3, 3) / (4, 4)")
    H, W = int(cam["height"]), int(cam["width"])
    camera = opencv_camera(K, E[:3, :3], E[:3, 3], W, H, "camera0", str(cam_path), {"layout": NAME})

    images = numbered_files(folder / "images", (".png", ".jpg", ".jpeg"), "image")
    masks = numbered_files(folder / "masks", (".npy", ".png", ".jpg"), "mask")
    match_counts(images, masks, folder / "images", folder / "masks")
    pose_path = folder / "poses.npz"
    full, transl, betas = read_poses(pose_path)
    numbers = sorted(images)
    if numbers[-1] >= full.shape[0]:
        raise LoaderError(f"{pose_path}: mismatched frame counts: {full.shape[0]} poses, but {len(numbers)} images "
                          f"in {folder / 'images'} numbered up to {numbers[-1]} ({images[numbers[-1]].name}); "
                          f"pose row n belongs to image n")
    chosen = [numbers[i] for i in protocol.select(len(numbers))]
    if not chosen:
        raise LoaderError(f"{folder}: frames={protocol.frames} selects none of its {len(numbers)} frames")
    fps = FPS / protocol.frames[2]
    frames = []
    for n in chosen:
        rgb = read_rgb(images[n], f"frame {n}")
        check_size(rgb, (H, W), images[n], "the image", f"height/width in {cam_path.name}")
        mask = read_mask(masks[n], f"mask of frame {n}")
        check_size(mask, (H, W), masks[n], "the mask", f"height/width in {cam_path.name}")
        pose = smpl_body_pose(full[n], transl=transl[n])
        frames.append(finish_frame(len(frames), rgb, mask, camera, pose, fps, protocol.scale))
    views = [EvalView(f.camera, f.index, f.image, f.mask, None, True, 0.0) for f in frames[:: protocol.eval_every]]
    body = smpl_body_spec(betas, protocol.gender or guess_gender(folder), protocol.smpl_dir)
    meta = {"layout": NAME, "source": str(folder), "train_camera": "camera0", "source_frames": chosen,
            "eval_cameras": [], "eval_note": "monocular data: evaluation on the training camera's frames", "skipped": []}
    return Scene(f"{NAME}-{folder.name}", body, frames, views, fps, meta)
