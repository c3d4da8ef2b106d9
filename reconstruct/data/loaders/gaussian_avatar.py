"""The GaussianAvatar layout (``scene/dataset_mono.py``): a folder (or its ``train/`` split) with

    images/<name>.png|jpg     frames; pose row k belongs to the k-th image in sorted name order
    masks/<name>.<ext>        same base names; 0/255 images (thresholded at 128)
    cam_parms.npz             intrinsic (3,3), extrinsic (4,4) world-to-camera (static camera), or
    cam_parms/<name>.npz      the same per frame
    smpl_parms.pth            torch.save'd dict of tensors: beta (1,10), body_pose (T,72) =
                              [global_orient, body_pose], trans (T,3)

The body in the world is smplx's ``SMPL(body_pose[:3], body_pose[3:], beta) + trans``. More pose
rows than images are allowed (GaussianAvatar uses the first ones); fewer are an error. As for
PeopleSnapshot, evaluation views are the training camera's own frames.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ...body.smpl_backend import smpl_body_pose
from ...body.spec import smpl_body_spec
from ..scene import EvalView, Scene
from .common import (IMAGE_EXTS, LoaderError, Protocol, check_size, finish_frame, opencv_camera, read_mask_array,
                     read_rgb, smpl_shape_error)

NAME = "gaussian_avatar"
NEEDS = "images/, masks/, cam_parms.npz (or cam_parms/) and smpl_parms.pth (in the folder or its train/)"
FPS = 30.0


def data_folder(folder: Path) -> Path | None:
    for d in (folder, folder / "train"):
        if (d / "smpl_parms.pth").is_file() and ((d / "cam_parms.npz").is_file() or (d / "cam_parms").is_dir()):
            return d
    return None


def matches(folder: Path) -> bool:
    return data_folder(folder) is not None


def read_smpl_parms(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import torch

    try:
        d = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise LoaderError(f"{path}: cannot be read as a torch file of SMPL parameters: {exc}") from exc
    if not isinstance(d, dict):
        raise LoaderError(f"{path}: expected a dict {{beta, body_pose, trans}}, found {type(d).__name__}")
    missing = [k for k in ("body_pose", "trans") if k not in d]
    if missing:
        raise LoaderError(f"{path}: missing {missing}; found keys {sorted(d)}")
    arr = lambda v: (v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)).astype(np.float64)
    pose, trans = arr(d["body_pose"]), arr(d["trans"])
    if pose.ndim != 2 or pose.shape[1] != 72:
        hint = " (165 values per frame is SMPL-X, which is not supported)" if pose.ndim == 2 and pose.shape[1] == 165 else ""
        raise smpl_shape_error(path, "body_pose", "(T, 72): per frame SMPL's global_orient and 23 joints x 3" + hint, pose)
    if trans.shape != (pose.shape[0], 3):
        raise smpl_shape_error(path, "trans", f"({pose.shape[0]}, 3), one per pose", trans)
    beta = arr(d.get("beta", np.zeros((1, 10))))
    beta = beta[0] if beta.ndim == 2 else beta
    if beta.ndim != 1:
        raise smpl_shape_error(path, "beta", "(1, 10)", beta)
    return pose, trans, beta


def _camera(path: Path, W: int, H: int, name: str):
    if not path.is_file():
        raise LoaderError(f"{path}: missing (camera parameters)")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except Exception as exc:
        raise LoaderError(f"{path}: cannot be read as an .npz file: {exc}") from exc
    if "intrinsic" not in d or "extrinsic" not in d:
        raise LoaderError(f"{path}: expected 'intrinsic' and 'extrinsic'; found keys {sorted(d)}")
    K, E = np.asarray(d["intrinsic"], np.float64), np.asarray(d["extrinsic"], np.float64)
    if K.size != 9 or E.shape not in ((4, 4), (3, 4)):
        raise LoaderError(f"{path}: intrinsic {K.shape} / extrinsic {E.shape}, expected (3, 3) / (4, 4)")
    return opencv_camera(K.reshape(3, 3), E[:3, :3], E[:3, 3], W, H, name, str(path), {"layout": NAME})


def load(folder: str | Path, protocol: Protocol | None = None) -> Scene:
    folder = Path(folder)
    protocol = protocol or Protocol()
    root = data_folder(folder)
    if root is None:
        raise LoaderError(f"{folder}: not a GaussianAvatar folder (needs {NEEDS})")
    if protocol.train_camera not in (None, 0, "0"):
        raise LoaderError(f"{root}: the GaussianAvatar layout has one camera (0), train_camera={protocol.train_camera!r}")
    img_dir, mask_dir = root / "images", root / "masks"
    for d in (img_dir, mask_dir):
        if not d.is_dir():
            raise LoaderError(f"{d}: missing folder")
    images = sorted(p for p in img_dir.iterdir() if p.suffix.lower() in IMAGE_EXTS)
    masks = {p.stem: p for p in mask_dir.iterdir() if p.suffix.lower() in IMAGE_EXTS + (".npy",)}
    if not images:
        raise LoaderError(f"{img_dir}: no images")
    no_mask = [p.name for p in images if p.stem not in masks]
    if len(masks) != len(images) or no_mask:
        raise LoaderError(f"{img_dir} and {mask_dir}: mismatched frames: {len(images)} images, {len(masks)} masks"
                          + (f"; images without a mask of the same name: {no_mask[:5]}" if no_mask else ""))
    smpl_path = root / "smpl_parms.pth"
    pose, trans, beta = read_smpl_parms(smpl_path)
    if pose.shape[0] < len(images):
        raise LoaderError(f"{smpl_path}: mismatched frame counts: {pose.shape[0]} poses for {len(images)} images in {img_dir}")
    if pose.shape[0] > len(images):
        warnings.warn(f"{smpl_path}: {pose.shape[0]} poses for {len(images)} images; using the first {len(images)}", stacklevel=2)
    chosen = protocol.select(len(images))
    if not chosen:
        raise LoaderError(f"{root}: frames={protocol.frames} selects none of its {len(images)} frames")
    static = root / "cam_parms.npz"
    fps = FPS / protocol.frames[2]
    frames, size = [], None
    for k in chosen:
        rgb = read_rgb(images[k], f"frame {k}")
        if size is None:
            size = (rgb.shape[:2], images[k].name)
        check_size(rgb, size[0], images[k], "the image", f"the size of {size[1]}, the first image")
        mpath = masks[images[k].stem]
        raw = np.asarray(read_mask_array(mpath, f"mask of frame {k}"), np.float32)
        raw = raw[..., :3].max(axis=2) if raw.ndim == 3 else raw
        mask = (raw >= 128).astype(np.float32) if raw.max() > 1 else (raw >= 0.5).astype(np.float32)
        check_size(mask, size[0], mpath, "the mask", f"the size of its image {images[k].name}")
        H, W = size[0]
        cam_file = static if static.is_file() else root / "cam_parms" / f"{images[k].stem}.npz"
        camera = _camera(cam_file, W, H, "camera0" if static.is_file() else f"camera{k}")
        frames.append(finish_frame(len(frames), rgb, mask, camera, smpl_body_pose(pose[k], transl=trans[k]), fps, protocol.scale))
    views = [EvalView(f.camera, f.index, f.image, f.mask, None, True, 0.0) for f in frames[:: protocol.eval_every]]
    body = smpl_body_spec(beta, protocol.gender or "neutral", protocol.smpl_dir)
    meta = {"layout": NAME, "source": str(root), "train_camera": "camera0", "source_frames": [images[k].stem for k in chosen],
            "eval_cameras": [], "eval_note": "monocular data: evaluation on the training camera's frames", "skipped": []}
    return Scene(f"{NAME}-{folder.name}", body, frames, views, fps, meta)
