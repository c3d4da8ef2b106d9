"""Person masks that the user made: a cut-out's own transparency, or mask files given with ``--masks``.

The segmenter's mask is soft and often wrong where the background shows through a small gap (the wall
between an arm and a skirt is called person, and the hole filling closes it; the avatar then wears a
patch of wall). A user who cut the person out with another tool (a background remover, a matting
network, a rotoscope, a painted fix) knows better, so ``prepare`` takes that mask instead of the
segmenter's, as it is: no refinement, no hole filling, nobody removed. The detector still finds the
keypoints.

Where masks come from, first found first:

* ``--masks PATH``: a mask video (a matting network's alpha output), one mask image (for a photo) or a
  folder of mask images. An image's or a video's mask is its alpha channel when it has transparency,
  else its brightness (white: person). A folder is matched to the input by name (a mask named as the frame's
  image, optionally with ``_mask``, ``-mask``, ``_alpha``, ``_matte`` after the name), else by order:
  its images in name order are the input's frames in order, every one of them (``--every`` and
  ``--max-frames`` pick from both alike). Or a scene folder ``prepare`` wrote from the same input, its
  ``frames/mask/`` fixed by the user (``scene_masks``): put back into the source frame by its crop.
* the input's own transparency: a cut-out PNG/WebP (or a folder of them), or a cut-out video (WebM
  with alpha, ProRes 4444, QuickTime Animation or PNG: ``alpha_video.py``), whose alpha is not opaque
  everywhere. ``--no-alpha`` gives such an input to the segmenter instead.

A mask must show the frame it belongs to: the same size after the frame's orientation (EXIF) and the
quarter turns ``prepare`` reads a lying person with, or the same shape at another resolution (then it
is resized). Anything else is an error naming the file and both sizes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .alpha_video import alpha_decoder, rgba_frames
from .crop import Crop
from .inputs import WIDE_MODES, InputError, has_transparency, input_kind, list_images, open_upright, wide_to_rgb
from .video import VideoError, display_rotation, read_video

# what may follow a frame's name in its mask's name (frame_0001.jpg -> frame_0001_mask.png)
MASK_NAME_SUFFIXES = ("", "_mask", "-mask", ".mask", "_alpha", "-alpha", "_matte", "-matte")
ASPECT_TOLERANCE = 0.01  # a mask of another resolution is taken when its aspect ratio is this close


def _alpha(im) -> np.ndarray | None:
    """(H,W) float32 in [0,1]: a PIL image's alpha, or None when it has none or it is opaque everywhere."""
    if not has_transparency(im):
        return None
    a = np.asarray(im.convert("RGBA"))[..., 3]
    if a.min() == 255:
        return None
    return a.astype(np.float32) / 255.0


def image_alpha(path: Path) -> np.ndarray | None:
    """(H,W) float32 in [0,1]: the image's alpha, or None when it has none or it is opaque everywhere."""
    return _alpha(open_upright(path, "an image"))


def mask_from_image(path: Path) -> np.ndarray:
    """(H,W) float32 in [0,1]: the alpha of an image with transparency, else its brightness (greys
    wider than 8 bits at their range, as ``prepare`` reads such photos)."""
    im = open_upright(path, "a mask image")
    alpha = _alpha(im)
    if alpha is not None:
        return alpha
    if im.mode in WIDE_MODES:
        return wide_to_rgb(im)[..., 0].astype(np.float32) / 255.0
    return np.asarray(im.convert("L")).astype(np.float32) / 255.0


def _matched_files(folder: Path, input_path: Path, kind: str, names: list[str], indices: np.ndarray) -> list[Path]:
    """The mask file of each frame used (``names``/``indices`` as ``read_input`` gave them)."""
    files = list_images(folder)
    if kind == "folder":
        by_name = {}
        for f in files:
            by_name.setdefault(f.stem.lower(), f)
        picked = []
        for n in names:
            stem = Path(n).stem.lower()
            hit = next((by_name[stem + s] for s in MASK_NAME_SUFFIXES if stem + s in by_name), None)
            if hit is None:
                break
            picked.append(hit)
        else:
            return picked
        total = len(list_images(input_path))
        if len(files) != total:
            raise InputError(f"{folder}: holds {len(files)} mask images and no mask named as the frame {names[len(picked)]}; "
                             f"expected masks named as {input_path.name}'s images, or one mask per image in the same "
                             f"order ({total})")
        return [files[int(i)] for i in indices]
    need = int(indices.max()) + 1
    if len(files) < need:
        raise InputError(f"{folder}: holds {len(files)} mask images; expected one per frame of {input_path.name} in "
                         f"order, at least {need} for the frames used")
    return [files[int(i)] for i in indices]


def _fit_to_frame(mask: np.ndarray, size: tuple[int, int], where: str, frame_what: str) -> np.ndarray:
    """``mask`` at the frame's ``size`` (W,H): as it is, or resized when only its resolution differs."""
    from PIL import Image

    W, H = size
    h, w = mask.shape
    if (w, h) == (W, H):
        return mask
    if abs((w / h) / (W / H) - 1.0) > ASPECT_TOLERANCE:
        raise InputError(f"{where}: the mask is {w}x{h} pixels, {frame_what} is {W}x{H}; expected a mask of the "
                         f"frame's size (or its shape at another resolution)")
    return np.asarray(Image.fromarray(mask, mode="F").resize((W, H), Image.Resampling.BILINEAR))


def video_alpha(path: Path, decoder: str, place, *, turns: int = 0, every: int = 1,
                max_frames: int | None = None) -> np.ndarray:
    """(T,H,W) float32: the alpha of a cut-out video given as the masks (every ``every``-th frame, at
    most ``max_frames``), upright (display rotation) and turned ``turns`` as ``read_video`` turns its
    frames, each passed through ``place`` (frame size check and crop). An input video's own alpha is
    read with its frames instead (``Video.alpha``)."""
    quarter = (display_rotation(path) + turns) % 4
    alphas = []
    for i, rgba in enumerate(rgba_frames(path, decoder)):
        if i % every:
            continue
        alphas.append(place(np.ascontiguousarray(np.rot90(rgba[..., 3], quarter)).astype(np.float32) / 255.0,
                            f"{path} frame {i}"))
        if max_frames and len(alphas) >= max_frames:
            break
    return np.stack(alphas) if alphas else np.zeros((0, 1, 1), np.float32)


def is_prepared_scene(path: Path) -> bool:
    """Whether ``path`` is a scene folder ``prepare`` wrote (its masks can be given back with --masks)."""
    return (path / "prepare_report.json").is_file() and (path / "frames" / "mask").is_dir()


def scene_masks(scene: Path, input_path: Path, *, indices: np.ndarray, source_size: tuple[int, int],
                crop: Crop | None, place) -> np.ndarray:
    """(T,H,W) float32: the masks of a scene folder ``prepare`` wrote from ``input_path`` (edited by
    the user, say), for the frames ``indices``: as they are where this prepare crops as that one did,
    else put back into the source frame by that scene's crop and passed through ``place``. A frame
    the scene dropped (no person) has an empty mask."""
    from PIL import Image

    report_path = scene / "prepare_report.json"
    try:
        report = json.loads(report_path.read_text())
        was = report["crop"]
        old = Crop(float(was["x0"]), float(was["y0"]), float(was["width"]), float(was["height"]),
                   int(was["out_width"]), int(was["out_height"]))
        W0, H0 = (int(v) for v in report["source_frame_size"])
        source = Path(str(report["video"])).name
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{report_path}: cannot be read as prepare's report ({type(exc).__name__}: {exc})") from exc
    if source != input_path.name:
        raise InputError(f"{scene}: was prepared from {source}, not {input_path.name}; expected the scene folder "
                         f"prepare wrote from this input")
    if (W0, H0) != tuple(source_size):
        raise InputError(f"{scene}: was prepared from frames of {W0}x{H0}, {input_path.name}'s frames are "
                         f"{source_size[0]}x{source_size[1]} (turned differently?); expected the same frames")
    same_crop = crop is not None and crop.to_dict() == old.to_dict()
    out = []
    for i in indices:
        f = scene / "frames" / "mask" / f"{int(i):06d}.png"
        m = (mask_from_image(f) if f.is_file() else np.zeros((old.out_height, old.out_width), np.float32))
        if m.shape != (old.out_height, old.out_width):
            raise InputError(f"{f}: is {m.shape[1]}x{m.shape[0]} pixels, its scene's frames are "
                             f"{old.out_width}x{old.out_height}; expected the mask at its scene's size")
        if same_crop:
            out.append(np.clip(m, 0.0, 1.0).astype(np.float32))
            continue
        x0, y0, w, h = int(old.x0), int(old.y0), int(old.width), int(old.height)
        big = np.asarray(Image.fromarray(m, mode="F").resize((w, h), Image.Resampling.BILINEAR))
        canvas = np.zeros((H0, W0), np.float32)
        sx0, sy0, sx1, sy1 = max(0, x0), max(0, y0), min(W0, x0 + w), min(H0, y0 + h)
        if sx1 > sx0 and sy1 > sy0:
            canvas[sy0:sy1, sx0:sx1] = big[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0]
        out.append(place(canvas, str(f)))
    return np.stack(out)


def read_user_masks(masks: str | os.PathLike | None, input_path: str | os.PathLike, *, names: list[str],
                    indices: np.ndarray, source_size: tuple[int, int], turns: int = 0, transform=None,
                    every: int = 1, max_frames: int | None = None, use_alpha: bool = True,
                    crop: Crop | None = None, alpha: np.ndarray | None = None) -> tuple[np.ndarray | None, str]:
    """(masks (T,H,W) float32 in [0,1] of the frames used, or None; where they came from: the masks
    path, "the input's transparency" or "segmenter"). ``names``/``indices``: the frames ``read_input``
    gave (indices into the file's frames or the folder's images); ``source_size`` (W,H): their size
    after the orientation and ``turns``; ``transform``: the crop applied to the frames, applied alike
    to each (H,W) mask; ``crop``: that crop, where a scene folder's masks may be taken as they are;
    ``alpha``: a video input's own alpha, read with its frames (``Video.alpha``: transformed alike)."""
    input_path = Path(input_path)
    kind = input_kind(input_path)
    indices = np.asarray(indices)
    T = len(names)

    def place(m: np.ndarray, where: str) -> np.ndarray:  # an upright, turned mask onto the frame used
        m = _fit_to_frame(m.astype(np.float32), source_size, where, f"the frame of {input_path.name}")
        if transform is not None:
            m = transform(m)
        return np.clip(m, 0.0, 1.0).astype(np.float32)

    def finish(raw: np.ndarray, where: str) -> np.ndarray:
        return place(np.ascontiguousarray(np.rot90(raw, turns % 4)), where)

    if masks is not None:
        path = Path(masks)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such mask video, image or folder (expected --masks to name a mask "
                                    f"video, a mask image or a folder of mask images)")
        if path.is_dir() and is_prepared_scene(path):  # a scene's own masks, fixed by the user, given back
            return scene_masks(path, input_path, indices=indices, source_size=source_size, crop=crop,
                               place=place), str(path)
        mkind = input_kind(path)
        decoder = alpha_decoder(path) if mkind == "video" else None
        if decoder is not None:  # a cut-out video given as the masks: its alpha, as a mask image's
            out = video_alpha(path, decoder, place, turns=turns, every=every, max_frames=max_frames)
            if len(out) != T:
                raise InputError(f"{path}: gives {len(out)} mask frames, {input_path.name} gives {T}; "
                                 f"expected one mask frame per frame")
            return out, str(path)
        if mkind == "video":
            def grey(frame: np.ndarray) -> np.ndarray:  # read_video has turned it already
                m = place(frame.astype(np.float32).mean(-1) / 255.0, f"{path}")
                return np.round(m * 255.0).astype(np.uint8)  # read_video stacks frames as uint8

            try:
                v = read_video(path, max_size=None, every=every, max_frames=max_frames, transform=grey, turns=turns)
            except VideoError as exc:
                if isinstance(exc.__cause__, InputError):
                    raise exc.__cause__ from None
                raise
            if len(v.frames) != T:
                raise InputError(f"{path}: gives {len(v.frames)} mask frames, {input_path.name} gives {T}; "
                                 f"expected one mask frame per frame")
            return v.frames.astype(np.float32) / 255.0, str(path)
        if mkind == "image":
            if T != 1:
                raise InputError(f"{path}: one mask image for {T} frames of {input_path.name}; expected a mask "
                                 f"video or a folder of mask images")
            files = [path]
        else:
            files = _matched_files(path, input_path, kind, names, indices)
        return np.stack([finish(mask_from_image(f), str(f)) for f in files]), str(path)
    if use_alpha and kind == "video":
        if alpha is None:
            return None, "segmenter"
        if len(alpha) != T:
            raise InputError(f"{input_path}: gave {len(alpha)} alpha frames and {T} colour frames; expected one "
                             f"alpha per frame")
        return np.clip(alpha, 0.0, 1.0).astype(np.float32), "the input's transparency"
    if use_alpha:
        files = [input_path] if kind == "image" else [input_path / n for n in names]
        alphas = []
        for f in files:
            a = image_alpha(f)
            if a is None:
                return None, "segmenter"
            alphas.append(finish(a, str(f)))
        return np.stack(alphas), "the input's transparency"
    return None, "segmenter"


__all__ = ["MASK_NAME_SUFFIXES", "image_alpha", "mask_from_image", "read_user_masks", "scene_masks", "video_alpha"]
