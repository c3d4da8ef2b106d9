"""What ``prepare`` accepts: a video, one image (jpg/png/webp/...), or a folder of images (in the
order of their names, numbers by value).
Images are read upright (their EXIF orientation applied) and cut-outs over a light wall
(``CUTOUT_BACKGROUND``); videos are turned by their display rotation (``video.read_video``).

``read_input`` returns a ``Video`` (frames at most ``max_side`` pixels on the longer side; the person crop
comes later) and names every problem with the path: no such file, unreadable file, empty folder,
images of different sizes in a folder.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .alpha_video import CUTOUT_BACKGROUND
from .video import VIDEO_SUFFIXES, Video, VideoError, read_video, resize_frame, working_size

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp", ".bmp", ".tif", ".tiff", ".heic", ".heif", ".avif")
HEIF_SUFFIXES = (".heic", ".heif")  # a phone's photos (read through pillow-heif's opener)
STILL_FPS = 25.0  # frame rate given to images (scene time stamps)


class InputError(VideoError):
    """An input that cannot be used (names the path, what was expected and what was found)."""


def input_kind(path: str | os.PathLike) -> str:
    """"video", "image" or "folder"; raises FileNotFoundError / InputError."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such video, image or folder (expected a video file, an image or a folder of images)")
    if path.is_dir():
        return "folder"
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return "image"
    return "video"


# single-channel modes wider than 8 bits (a 16-bit grayscale PNG or TIFF, 32-bit integer or float
# TIFFs): Pillow's convert("RGB") clips them at 255, so a 16-bit photo came out white
WIDE_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I", "F")


def wide_to_rgb(im) -> np.ndarray:
    """(H,W,3) uint8 grey of a single-channel image in one of ``WIDE_MODES``, scaled by the range its
    type implies: 16-bit modes by 65535; 32-bit integers by 255 or 65535, whichever their largest
    value fits; floats by 1 when they lie in [0, 1] (a linear 0-1 image), else as the integers."""
    a = np.asarray(im).astype(np.float64)
    top = float(np.nanmax(a)) if a.size else 0.0
    if im.mode.startswith("I;16"):
        full = 65535.0
    elif im.mode == "F" and top <= 1.0:
        full = 1.0
    else:
        full = 255.0 if top <= 255.0 else 65535.0
    grey = np.clip(np.nan_to_num(a) / full * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=-1)


def _to_srgb(im):
    """``im`` with its embedded ICC profile's colours converted to sRGB, which everything after
    (training, the renders, the viewer) takes pixels to be: an iPhone's Display P3 photo, a camera's
    Adobe RGB JPEG, a print CMYK JPEG. Read as sRGB numbers, P3 and Adobe RGB colours came out
    duller than the photo. Without a profile, or with one that cannot be applied, ``im`` as it is."""
    icc = im.info.get("icc_profile")
    if not icc or im.mode not in ("RGB", "RGBA", "L", "CMYK"):
        return im
    try:
        from io import BytesIO

        from PIL import ImageCms

        source = ImageCms.ImageCmsProfile(BytesIO(icc))
        if "srgb" in ImageCms.getProfileDescription(source).lower().replace(" ", ""):
            return im
        out_mode = "RGBA" if im.mode == "RGBA" else "RGB"
        return ImageCms.profileToProfile(im, source, ImageCms.createProfile("sRGB"), outputMode=out_mode)
    except Exception:  # noqa: BLE001 - a profile littlecms cannot use: the pixels as stored
        return im


def has_transparency(im) -> bool:
    """Whether a PIL image carries an alpha channel (or a transparent palette entry)."""
    return im.mode in ("RGBA", "LA", "PA", "RGBa", "La") or (im.mode == "P" and "transparency" in im.info)


def _as_rgb(im) -> np.ndarray:
    """(H,W,3) uint8 of an upright PIL image: its colours in sRGB (``_to_srgb``) and, when it has
    transparency (a cut-out PNG), laid over ``CUTOUT_BACKGROUND``."""
    from PIL import Image

    im = _to_srgb(im)
    if im.mode in WIDE_MODES:
        return wide_to_rgb(im)
    if has_transparency(im):
        rgba = im.convert("RGBA")
        base = Image.new("RGBA", rgba.size, CUTOUT_BACKGROUND + (255,))
        return np.asarray(Image.alpha_composite(base, rgba).convert("RGB"))
    return np.asarray(im.convert("RGB"))


def _register_heif(path: Path) -> None:
    try:
        from pillow_heif import register_heif_opener
    except ImportError as exc:
        raise InputError(f"{path}: a HEIF/HEIC photo needs the pillow-heif package (pip install pillow-heif), "
                         f"which is not installed here; or export the photo as JPEG") from exc
    register_heif_opener()


def open_upright(path: Path, what: str = "an image"):
    """The PIL image of ``path`` (loaded; an animation's first frame, a TIFF as stored) as it is meant
    to be seen: turned by its EXIF orientation (a phone stores a portrait photo sideways and says so in
    the tag). InputError naming the path when it cannot be read as ``what``."""
    from PIL import Image, ImageOps, UnidentifiedImageError

    if path.suffix.lower() in HEIF_SUFFIXES:
        _register_heif(path)
    try:
        with Image.open(path) as im:
            im.load()
            if getattr(im, "n_frames", 1) > 1 and path.suffix.lower() not in (".tif", ".tiff"):
                im.seek(0)
                im.load()
            try:
                up = ImageOps.exif_transpose(im) or im
            except Exception:  # noqa: BLE001 - a broken EXIF block: the pixels as stored, not a refused photo
                up = im
            return up if up is not im else im.copy()
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read as {what} (expected {', '.join(IMAGE_SUFFIXES)}): "
                         f"{type(exc).__name__}: {exc}") from exc


def _read_image(path: Path) -> np.ndarray:
    return _as_rgb(open_upright(path))


def natural_key(name: str) -> list:
    """Sort key that orders the numbers in a name by value: frame2 before frame10 (exporters often
    number frames without leading zeros)."""
    import re

    return [(0, int(t), t) if t.isdigit() else (1, 0, t.lower()) for t in re.split(r"(\d+)", name) if t]


def list_images(folder: Path) -> list[Path]:
    """The images of a folder in frame order (``natural_key``), hidden files left out (a copy from a
    Mac leaves ``._IMG_0001.JPG`` beside each photo: metadata, not a picture)."""
    files = sorted((p for p in folder.iterdir()
                    if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")),
                   key=lambda p: natural_key(p.name))
    if not files:
        others = sorted(p.name for p in folder.iterdir())[:5]
        raise InputError(f"{folder}: the folder holds no images (expected files ending in "
                         f"{', '.join(IMAGE_SUFFIXES)}; found {others if others else 'nothing'})")
    return files


def read_input(path: str | os.PathLike, *, max_side: int | None = 1920, every: int = 1,
               max_frames: int | None = None, transform=None, turns: int = 0) -> tuple[Video, list[str]]:
    """(frames, a name per frame) of a video, an image or a folder of images, each turned ``turns``
    quarter turns counter-clockwise after its own orientation is applied. ``transform`` (frame at the
    file's size -> frame) replaces the resize to ``max_side`` and runs frame by frame (see ``read_video``)."""
    path = Path(path)
    kind = input_kind(path)
    if every < 1:
        raise ValueError(f"every must be at least 1, found {every}")
    if kind == "video":
        v = read_video(path, max_size=max_side, every=every, max_frames=max_frames, transform=transform, turns=turns)
        return v, [f"{path.name} frame {i}" for i in v.indices]
    files = [path] if kind == "image" else list_images(path)[::every]
    if max_frames:
        files = files[:max_frames]
    # each image transformed or resized as it is read: a folder of phone photos held at their own size
    # (12 megapixels each) would not fit in memory
    frames = []
    for f in files:
        im = np.ascontiguousarray(np.rot90(_read_image(f), turns % 4))
        if not frames:
            h, w = im.shape[:2]
            size = working_size(w, h, max_side)
        if im.shape[:2] != (h, w):
            raise InputError(f"{f}: is {im.shape[1]}x{im.shape[0]} pixels, the folder's first image {files[0].name} "
                             f"is {w}x{h}; expected images of one size (frames of one camera)")
        frames.append(transform(im) if transform is not None else resize_frame(im, *size))
    frames = np.stack(frames).astype(np.uint8)
    return Video(frames, STILL_FPS, (w, h), np.arange(len(files)) * every), [f.name for f in files]


__all__ = ["IMAGE_SUFFIXES", "InputError", "VIDEO_SUFFIXES", "input_kind", "list_images", "read_input"]


def probe_input(path: str | os.PathLike) -> str:
    """Check that ``path`` can be read (without decoding all of it); returns its kind."""
    path = Path(path)
    kind = input_kind(path)
    if kind == "video":
        read_video(path, max_size=None, max_frames=1)
    elif kind == "image":
        _read_image(path)
    else:
        _read_image(list_images(path)[0])
    return kind
