"""The project's own scene folder layout (version 1), written atomically and read with checks.

    SCENE/scene.json          format, name, fps, body spec, cameras, frame and evaluation-view lists
    SCENE/poses.npz           joint_rotations (T,J,3), global_orient (T,3), transl (T,3), float64
    SCENE/frames/{rgb,mask,normal}/NNNNNN.png
    SCENE/eval/CAMERA/{rgb,mask,normal}_NNNNNN.png
    SCENE/eval/CAMERA/leak_NNNNNN.png   (optional: front-leak regions, see reconstruct.metrics.front_leak)
    SCENE/texture.png         (synthetic scenes: the ground-truth albedo atlas)

Images are 8-bit RGB over a black background; masks 8-bit gray coverage; normal maps store
camera-space unit normals (OpenCV axes: x right, y down, z forward) as 0.5 * (n + 1), black
outside the mask. See docs/scene_format.md.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from ..body.pose import BodyPose
from ..camera import Camera
from .scene import BodySpec, EvalView, Frame, Scene

FORMAT = "wonderhuman-scene"
VERSION = 1


class SceneFormatError(ValueError):
    """A scene folder that cannot be read: names the file and what was wrong."""


def _to_u8(img: np.ndarray) -> np.ndarray:
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _encode_normals(normal: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return _to_u8(0.5 * (normal + 1.0)) * (mask[..., None] > 0).astype(np.uint8)


def _decode_normals(encoded: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return (2.0 * encoded - 1.0) * (mask[..., None] > 0)


def _json_safe(value):
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items() if not isinstance(v, np.ndarray) or v.size < 64}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def _write_front_leak(info, folder: Path, rel: str) -> dict:
    """The regions as one 8-bit RGB image (channel k: region k's coverage; at most 3 regions)."""
    regions = np.asarray(info.regions, np.float32)
    K = regions.shape[-1]
    if K > 3:
        raise ValueError(f"front-leak information with {K} regions: a scene folder stores at most 3")
    img = np.zeros(regions.shape[:2] + (3,), np.float32)
    img[..., :K] = regions
    iio.imwrite(folder / rel, _to_u8(img))
    return {"regions": rel, "details": [{"name": n, "colors": np.asarray(c, float).round(6).tolist()}
                                        for n, c in zip(info.names, info.colors)]}


def _read_front_leak(entry: dict, folder: Path, shape: tuple[int, int], path: Path, j: int):
    from ..metrics.front_leak import FrontLeakInfo

    what = f"evaluation view {j} front-leak regions"
    try:
        details = list(entry["details"])
        names = [str(d["name"]) for d in details]
        colors = [np.asarray(d["colors"], np.float64).reshape(-1, 3) for d in details]
        rel = entry["regions"]
    except (KeyError, TypeError, ValueError) as exc:
        raise SceneFormatError(f"{path}: evaluation view {j}: bad 'front_leak' entry ({exc!r})") from exc
    if not 1 <= len(details) <= 3:
        raise SceneFormatError(f"{path}: evaluation view {j}: 'front_leak' needs 1 to 3 details, found {len(details)}")
    regions = _read_image(folder / rel, shape, what, 3)[..., :len(details)]
    return FrontLeakInfo(tuple(names), regions, tuple(colors))


def write_scene(scene: Scene, folder: str | os.PathLike) -> Path:
    """Write ``scene`` to ``folder`` atomically: into a temporary sibling, then renamed over it."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        cameras: dict[str, dict] = {}

        def cam_name(cam: Camera) -> str:
            name = cam.name or f"camera{len(cameras)}"
            cameras.setdefault(name, cam.to_dict())
            return name

        frames = []
        for sub in ("rgb", "mask", "normal"):
            (tmp / "frames" / sub).mkdir(parents=True)
        for f in scene.frames:
            stem = f"{f.index:06d}.png"
            iio.imwrite(tmp / "frames" / "rgb" / stem, _to_u8(f.image))
            iio.imwrite(tmp / "frames" / "mask" / stem, _to_u8(f.mask))
            entry = {"index": f.index, "camera": cam_name(f.camera), "time": f.time,
                     "image": f"frames/rgb/{stem}", "mask": f"frames/mask/{stem}"}
            if f.normal is not None:
                iio.imwrite(tmp / "frames" / "normal" / stem, _encode_normals(f.normal, f.mask))
                entry["normal"] = f"frames/normal/{stem}"
            frames.append(entry)
        views = []
        for v in scene.eval_views:
            name = cam_name(v.camera)
            d = tmp / "eval" / name
            d.mkdir(parents=True, exist_ok=True)
            entry = {"camera": name, "frame": v.frame_index, "seen": bool(v.seen), "azimuth_deg": v.azimuth_deg}
            normal = None if v.normal is None else _encode_normals(v.normal, v.mask)
            for key, img in (("image", v.image), ("mask", v.mask), ("normal", normal)):
                if img is not None:
                    rel = f"eval/{name}/{ {'image': 'rgb', 'mask': 'mask', 'normal': 'normal'}[key]}_{v.frame_index:06d}.png"
                    iio.imwrite(tmp / rel, img if img.dtype == np.uint8 else _to_u8(img))
                    entry[key] = rel
            if getattr(v, "front_leak", None) is not None:
                entry["front_leak"] = _write_front_leak(v.front_leak, tmp, f"eval/{name}/leak_{v.frame_index:06d}.png")
            views.append(entry)
        poses = [f.pose for f in scene.frames]
        np.savez(tmp / "poses.npz",
                 joint_rotations=np.stack([p.joint_rotations for p in poses]),
                 global_orient=np.stack([p.global_orient for p in poses]),
                 transl=np.stack([p.transl for p in poses]))
        meta = {k: v for k, v in scene.meta.items() if k != "texture"}
        if "texture" in scene.meta:
            iio.imwrite(tmp / "texture.png", np.asarray(scene.meta["texture"], np.uint8))
            meta["texture"] = "texture.png"
        doc = {"format": FORMAT, "version": VERSION, "name": scene.name, "fps": scene.fps,
               "body": scene.body.to_dict(), "cameras": cameras, "frames": frames, "eval_views": views,
               "meta": _json_safe(meta)}
        (tmp / "scene.json").write_text(json.dumps(doc, indent=1))
        if folder.exists():
            old = folder.with_name(f".{folder.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            folder.rename(old)
            tmp.rename(folder)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return folder


def read_image_file(path: Path, what: str, error: type[Exception] = SceneFormatError, as_what: str = "an image"):
    """The array stored in an image file, or ``error`` naming the file when it is missing or unreadable."""
    if not path.is_file():
        raise error(f"{path}: missing ({what})")
    try:
        return iio.imread(path)
    except Exception as exc:
        raise error(f"{path}: cannot be read as {as_what} ({what}): {exc}") from exc


def image_to_float(img: np.ndarray) -> np.ndarray:
    """8- or 16-bit image values to float32 in [0, 1]."""
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img.astype(np.float32) / scale


def _read_image(path: Path, shape: tuple[int, int], what: str, channels: int) -> np.ndarray:
    img = read_image_file(path, what)
    if channels == 1 and img.ndim == 3:
        img = img[..., 0]
    if channels == 3 and img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if channels == 3:
        img = img[..., :3]
    if img.shape[:2] != shape:
        raise SceneFormatError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, the camera expects {shape[1]}x{shape[0]} ({what})")
    return image_to_float(img)


def read_scene(folder: str | os.PathLike) -> Scene:
    folder = Path(folder)
    if not folder.exists():
        raise SceneFormatError(f"{folder}: no such scene folder")
    path = folder / "scene.json"
    if not path.is_file():
        raise SceneFormatError(f"{folder}: not a WonderHuman scene folder (expected {path.name}; found "
                               f"{sorted(p.name for p in folder.iterdir())[:8]})")
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise SceneFormatError(f"{path}: not valid JSON ({exc})") from exc
    if doc.get("format") != FORMAT:
        raise SceneFormatError(f"{path}: format is {doc.get('format')!r}, expected {FORMAT!r}")
    if doc.get("version") != VERSION:
        raise SceneFormatError(f"{path}: version {doc.get('version')!r} is not supported (expected {VERSION})")
    for key in ("cameras", "frames", "body"):
        if key not in doc:
            raise SceneFormatError(f"{path}: missing key {key!r}")
    try:
        cameras = {name: Camera.from_dict(d) for name, d in doc["cameras"].items()}
    except ValueError as exc:
        raise SceneFormatError(f"{path}: bad camera: {exc}") from exc

    def camera(name: str, where: str) -> Camera:
        if name not in cameras:
            raise SceneFormatError(f"{path}: {where} refers to camera {name!r}, not among {sorted(cameras)}")
        return cameras[name]

    pose_path = folder / "poses.npz"
    if not pose_path.is_file():
        raise SceneFormatError(f"{pose_path}: missing (body poses)")
    with np.load(pose_path) as z:
        missing = {"joint_rotations", "global_orient", "transl"} - set(z.files)
        if missing:
            raise SceneFormatError(f"{pose_path}: missing arrays {sorted(missing)}; found {z.files}")
        jr, go, tr = z["joint_rotations"], z["global_orient"], z["transl"]
    n = len(doc["frames"])
    if n == 0:
        raise SceneFormatError(f"{path}: the scene has no frames")
    if not (jr.shape[0] == go.shape[0] == tr.shape[0] == n):
        raise SceneFormatError(f"{pose_path}: {jr.shape[0]} poses for {n} frames listed in scene.json")
    frames = []
    for i, e in enumerate(doc["frames"]):
        cam = camera(e["camera"], f"frame {i}")
        shape = (cam.height, cam.width)
        image = _read_image(folder / e["image"], shape, f"frame {i} image", 3)
        mask = _read_image(folder / e["mask"], shape, f"frame {i} mask", 1)
        normal = _decode_normals(_read_image(folder / e["normal"], shape, f"frame {i} normal map", 3), mask) if e.get("normal") else None
        pose = BodyPose(jr[i], go[i], tr[i])
        frames.append(Frame(int(e.get("index", i)), image, mask, cam, pose, normal, float(e.get("time", i / doc.get("fps", 20.0)))))
    views = []
    for j, e in enumerate(doc.get("eval_views", [])):
        cam = camera(e["camera"], f"evaluation view {j}")
        shape = (cam.height, cam.width)
        fi = int(e["frame"])
        if not 0 <= fi < n:
            raise SceneFormatError(f"{path}: evaluation view {j} refers to frame {fi}, but the scene has {n} frames")
        vmask = _read_image(folder / e["mask"], shape, f"evaluation view {j} mask", 1)
        vnormal = (_decode_normals(_read_image(folder / e["normal"], shape, f"evaluation view {j} normal map", 3), vmask)
                   if e.get("normal") else None)
        leak = _read_front_leak(e["front_leak"], folder, shape, path, j) if e.get("front_leak") else None
        views.append(EvalView(cam, fi, _read_image(folder / e["image"], shape, f"evaluation view {j} image", 3),
                              vmask, vnormal, bool(e.get("seen", False)), float(e.get("azimuth_deg", 0.0)), leak))
    meta = dict(doc.get("meta", {}))
    if meta.get("texture"):
        tex_path = folder / meta["texture"]
        if tex_path.is_file():
            meta["texture"] = iio.imread(tex_path)
    return Scene(str(doc.get("name", folder.name)), BodySpec.from_dict(doc["body"]), frames, views,
                 float(doc.get("fps", 20.0)), meta)
