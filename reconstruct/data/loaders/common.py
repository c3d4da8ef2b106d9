"""What the dataset loaders share: the protocol, the spec syntax, image/mask reading, cameras and
the seen/unseen rule for evaluation views."""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...body.pose import BodyPose
from ...camera import Camera
from ..scene import EvalView, Frame
from ..scene_io import SceneFormatError, image_to_float, read_image_file

SEEN_ANGLE_DEG = 45.0  # as in the synthetic scene: evaluation views this close to the training camera are "seen"
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".webp")


class LoaderError(SceneFormatError):
    """A dataset folder that cannot be loaded: names the file, what was expected and what was found."""


@dataclass
class Protocol:
    """How a dataset becomes a monocular scene.

    train_camera: the one camera whose video trains the avatar (name or index; None: the first).
    frames: (start, stop, step) over the training camera's frame list (stop None: to the end).
    eval_cameras: the evaluation cameras: None for all other cameras, an int n for n of them spread
    evenly in azimuth around the body, or a tuple of names/indices.
    eval_every: every k-th selected frame is an evaluation frame (for every evaluation camera).
    scale: image scale factor (0.5 halves width and height; intrinsics follow).
    gender, smpl_dir: the SMPL body (gender None: the layout's guess, else neutral).
    """

    train_camera: str | int | None = None
    frames: tuple[int, int | None, int] = (0, None, 1)
    eval_cameras: int | tuple | None = None
    eval_every: int = 10
    scale: float = 1.0
    gender: str | None = None
    smpl_dir: str | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        start, stop, step = self.frames
        if step is None or int(step) < 1:
            raise ValueError(f"frames: the stride must be at least 1, found {step}")
        if int(start) < 0 or (stop is not None and int(stop) < int(start)):
            raise ValueError(f"frames: need 0 <= start <= stop, found {start}:{stop}")
        if int(self.eval_every) < 1:
            raise ValueError(f"eval_every must be at least 1, found {self.eval_every}")
        if not (0.0 < float(self.scale) <= 1.0):
            raise ValueError(f"scale must be in (0, 1], found {self.scale}")

    def select(self, n: int) -> list[int]:
        start, stop, step = self.frames
        return list(range(n))[int(start):(None if stop is None else int(stop)):int(step)]


def parse_frames(text: str) -> tuple[int, int | None, int]:
    """``"0:300:5"``, ``"0:300"``, ``"10:"`` or ``"::2"`` -> (start, stop, step)."""
    parts = text.split(":")
    if len(parts) > 3 or not all(re.fullmatch(r"\s*-?\d*\s*", p) for p in parts):
        raise ValueError(f"frames={text!r}: expected start:stop[:step] with integers, e.g. 0:300:5")
    parts += [""] * (3 - len(parts))
    start = int(parts[0]) if parts[0].strip() else 0
    stop = int(parts[1]) if parts[1].strip() else None
    step = int(parts[2]) if parts[2].strip() else 1
    return start, stop, step


def _camera_key(value: str) -> str | int:
    return int(value) if re.fullmatch(r"\d+", value) else value


def parse_options(spec: str, items: list[str]) -> Protocol:
    """key=value items of a loader spec -> Protocol."""
    kw: dict = {}
    known = ("train_camera", "frames", "eval_cameras", "eval_every", "scale", "gender", "smpl_dir")
    for item in items:
        if "=" not in item:
            raise ValueError(f"scene {spec!r}: expected key=value after the folder, found {item!r}")
        key, value = (s.strip() for s in item.split("=", 1))
        try:
            if key == "train_camera":
                kw[key] = _camera_key(value)
            elif key == "frames":
                kw[key] = parse_frames(value)
            elif key == "eval_cameras":
                if value in ("", "none"):
                    kw[key] = ()
                elif re.fullmatch(r"\d+", value):
                    kw[key] = int(value)
                else:
                    kw[key] = tuple(_camera_key(v) for v in value.split("+"))
            elif key == "eval_every":
                kw[key] = int(value)
            elif key == "scale":
                kw[key] = float(value)
            elif key in ("gender", "smpl_dir"):
                kw[key] = value
            else:
                raise ValueError(f"scene {spec!r}: unknown key {key!r}; known: {list(known)}")
        except ValueError as exc:
            if "unknown key" in str(exc) or str(exc).startswith("frames="):
                raise
            raise ValueError(f"scene {spec!r}: bad value {key}={value!r}: {exc}") from exc
    return Protocol(**kw)


# ----- images and masks -------------------------------------------------------------------------
def read_rgb(path: Path, what: str) -> np.ndarray:
    img = read_image_file(path, what, LoaderError)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] < 3:
        raise LoaderError(f"{path}: expected an RGB image ({what}), found an array of shape {img.shape}")
    return image_to_float(img[..., :3])


def mask_from_array(arr: np.ndarray, path: Path) -> np.ndarray:
    """A person mask in [0,1] from the values datasets store: 0/1, 0/255, part labels (0 is the
    background), or a lossy .jpg of a 0/255 mask (thresholded at half)."""
    a = np.asarray(arr)
    if a.ndim == 3:
        a = a[..., :3].max(axis=2) if a.shape[2] >= 3 else a[..., 0]
    if a.ndim != 2:
        raise LoaderError(f"{path}: expected a 2D mask, found an array of shape {np.asarray(arr).shape}")
    if a.dtype == bool:
        return a.astype(np.float32)
    a = a.astype(np.float32)
    top = float(a.max()) if a.size else 0.0
    if path.suffix.lower() in (".jpg", ".jpeg"):
        return (a > (0.5 if top <= 1.0 else 127.5)).astype(np.float32)
    if top <= 1.0:
        return np.clip(a, 0.0, 1.0)
    return (a > 0).astype(np.float32)


def read_mask_array(path: Path, what: str) -> np.ndarray:
    """The stored values of a mask file (.npy or an image), or a LoaderError naming the file."""
    if path.suffix != ".npy":
        return read_image_file(path, what, LoaderError, "a mask")
    if not path.is_file():
        raise LoaderError(f"{path}: missing ({what})")
    try:
        return np.load(path, allow_pickle=False)
    except Exception as exc:
        raise LoaderError(f"{path}: cannot be read as a mask ({what}): {exc}") from exc


def read_mask(path: Path, what: str) -> np.ndarray:
    return mask_from_array(read_mask_array(path, what), path)


def check_size(arr: np.ndarray, expected_hw: tuple[int, int], path: Path, what: str, reference: str) -> None:
    if arr.shape[:2] != tuple(expected_hw):
        raise LoaderError(f"{path}: {what} is {arr.shape[1]}x{arr.shape[0]}, expected {expected_hw[1]}x{expected_hw[0]} "
                          f"({reference})")


def resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area-weighted resize of (H,W) or (H,W,C) float32 images (masks become coverage)."""
    from PIL import Image

    if img.shape[1] == width and img.shape[0] == height:
        return img
    if img.ndim == 2:
        return np.asarray(Image.fromarray(img.astype(np.float32), mode="F").resize((width, height), Image.BOX), np.float32)
    return np.stack([resize(img[..., c], width, height) for c in range(img.shape[2])], axis=2)


# ----- cameras ----------------------------------------------------------------------------------
def opencv_camera(K, R, t, width: int, height: int, name: str, source: str, meta: dict | None = None) -> Camera:
    """A Camera from OpenCV calibration (pixel centres at integers): the principal point moves by
    +0.5 px to the project's convention (pixel centres at +0.5)."""
    K = np.array(K, np.float64).reshape(3, 3)
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    try:
        return Camera(K, np.asarray(R, np.float64).reshape(3, 3), np.asarray(t, np.float64).reshape(3), width, height,
                      name=name, meta=dict(meta or {}))
    except ValueError as exc:
        raise LoaderError(f"{source}: camera {name!r}: {exc}") from exc


def undistort(img: np.ndarray, K: np.ndarray, D: np.ndarray, order: int = 1) -> np.ndarray:
    """Remove OpenCV radial-tangential distortion (k1, k2, p1, p2[, k3]) from an image in OpenCV
    pixel convention, as ``cv2.undistort(img, K, D)`` (bilinear sampling; black outside)."""
    from scipy.ndimage import map_coordinates

    d = np.zeros(5)
    flat = np.asarray(D, np.float64).reshape(-1)[:5]
    d[: flat.shape[0]] = flat
    if not np.any(d):
        return img
    k1, k2, p1, p2, k3 = d
    H, W = img.shape[:2]
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    src_u = K[0, 0] * xd + K[0, 2]
    src_v = K[1, 1] * yd + K[1, 2]
    coords = np.stack([src_v, src_u])
    if img.ndim == 2:
        return map_coordinates(img, coords, order=order, mode="constant", cval=0.0).astype(np.float32)
    return np.stack([map_coordinates(img[..., c], coords, order=order, mode="constant", cval=0.0)
                     for c in range(img.shape[2])], axis=2).astype(np.float32)


def azimuth_about_body(camera: Camera, pose: BodyPose) -> float:
    """Azimuth of a camera around the posed body (degrees, 0 in front of it, +90 at its left),
    measured in the plane perpendicular to the body's up axis."""
    from ...body.smpl_backend import body_frame

    centre, up, front = body_frame(pose)
    d = camera.center - centre
    d = d - up * np.dot(d, up)
    f = front - up * np.dot(front, up)
    left = np.cross(up, f)
    return math.degrees(math.atan2(float(np.dot(d, left)), float(np.dot(d, f))))


def wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def finish_frame(i: int, rgb: np.ndarray, mask: np.ndarray, camera: Camera, pose: BodyPose, fps: float,
                 scale: float) -> Frame:
    if scale != 1.0:
        camera, rgb, mask = scale_view(camera, rgb, mask, scale)
    return Frame(i, (rgb * mask[..., None]).astype(np.float32), mask.astype(np.float32), camera, pose, None, i / fps)


def scale_view(camera: Camera, rgb: np.ndarray, mask: np.ndarray, scale: float):
    w, h = max(1, round(camera.width * scale)), max(1, round(camera.height * scale))
    return camera.scaled(w, h), resize(rgb, w, h), np.clip(resize(mask, w, h), 0.0, 1.0)


def make_eval_view(frame_pos: int, rgb: np.ndarray, mask: np.ndarray, camera: Camera, train_camera: Camera,
                   pose: BodyPose, scale: float) -> EvalView:
    az = wrap_deg(azimuth_about_body(camera, pose) - azimuth_about_body(train_camera, pose))
    if scale != 1.0:
        camera, rgb, mask = scale_view(camera, rgb, mask, scale)
    return EvalView(camera, frame_pos, (rgb * mask[..., None]).astype(np.float32), mask.astype(np.float32), None,
                    seen=abs(az) <= SEEN_ANGLE_DEG, azimuth_deg=float(az))


def frame_number(name: str) -> int | None:
    """The frame number in a file name: ZJU-MoCap's ``CoreView_313_Camera_(1)_0001_<date>.jpg``
    (the fifth ``_`` field), else the last run of digits of the stem."""
    stem = Path(name).stem
    fields = stem.split("_")
    if stem.startswith("CoreView_") and len(fields) > 4 and fields[4].isdigit():
        return int(fields[4])
    runs = re.findall(r"\d+", stem)
    return int(runs[-1]) if runs else None


def numbered_files(folder: Path, exts: tuple[str, ...], what: str) -> dict[int, Path]:
    """{frame number: file} of a folder; two files with one number are an error."""
    if not folder.is_dir():
        raise LoaderError(f"{folder}: missing folder ({what})")
    out: dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() not in exts or not p.is_file():
            continue
        n = frame_number(p.name)
        if n is None:
            continue
        if n in out:
            raise LoaderError(f"{folder}: two {what} files for frame {n}: {out[n].name} and {p.name}")
        out[n] = p
    if not out:
        raise LoaderError(f"{folder}: no numbered {what} files (expected names with a frame number, "
                          f"extensions {list(exts)}); found {sorted(q.name for q in folder.iterdir())[:6]}")
    return out


def match_counts(images: dict[int, Path], masks: dict[int, Path], image_dir: Path, mask_dir: Path) -> None:
    if set(images) != set(masks):
        no_mask = sorted(set(images) - set(masks))[:5]
        no_image = sorted(set(masks) - set(images))[:5]
        raise LoaderError(f"{image_dir} and {mask_dir}: mismatched frames: {len(images)} images, {len(masks)} masks"
                          + (f"; images without a mask: {[images[n].name for n in no_mask]}" if no_mask else "")
                          + (f"; masks without an image: {[masks[n].name for n in no_image]}" if no_image else ""))


def warn_skipped(folder: Path, skipped: list[str]) -> None:
    if skipped:
        warnings.warn(f"{folder}: left out {len(skipped)} frame(s) with missing files, e.g. {skipped[:3]}", stacklevel=3)


def smpl_shape_error(path: Path, key: str, expected: str, found) -> LoaderError:
    return LoaderError(f"{path}: {key!r} has shape {tuple(np.shape(found))}, expected {expected}")
