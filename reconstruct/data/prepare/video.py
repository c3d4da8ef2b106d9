"""Read a video file (mp4, mov, anything ffmpeg decodes) into RGB frames, resized to a working size;
a cut-out video's frames (with alpha, ``alpha_video.py``) laid over a light wall."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .alpha_video import alpha_decoder, over_wall, rgba_frames

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm")


class VideoError(ValueError):
    """A video that cannot be used: names the file and what was expected."""


@dataclass
class Video:
    frames: np.ndarray  # (T,H,W,3) uint8 RGB at the working size
    fps: float
    source_size: tuple[int, int]  # (width, height) as shown: a rotated video's turned (``display_rotation``)
    indices: np.ndarray  # (T,) frame numbers in the file
    # (T,H,W) float32 in [0,1]: a cut-out video's alpha beside its frames (turned, transformed or resized
    # as they are); None when the frames carry no alpha or it is opaque everywhere
    alpha: np.ndarray | None = None


def resize_frame(frame: np.ndarray, width: int, height: int) -> np.ndarray:
    """(height,width,3) Lanczos resize of an RGB uint8 frame; the frame itself when it is that size."""
    from PIL import Image

    if (frame.shape[1], frame.shape[0]) == (width, height):
        return frame
    return np.asarray(Image.fromarray(frame).resize((width, height), Image.Resampling.LANCZOS))


def _resize_alpha(alpha: np.ndarray, width: int, height: int) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.fromarray(alpha, mode="F").resize((width, height), Image.Resampling.BILINEAR))


def working_size(width: int, height: int, max_size: int | None) -> tuple[int, int]:
    if not max_size or max(width, height) <= max_size:
        return width, height
    s = max_size / max(width, height)
    return max(2, round(width * s)), max(2, round(height * s))


def display_rotation(path: str | os.PathLike) -> int:
    """Quarter turns counter-clockwise (0-3) that show ``path``'s frames upright: the display matrix a
    phone writes instead of turning a portrait video's pixels (its first frame's; 0 when there is none,
    or when the file cannot be opened, which ``read_video`` reports). A rotation between quarter turns
    is taken to the nearest one."""
    try:
        import av

        with av.open(str(path)) as container:
            frame = next(container.decode(video=0))
            degrees = float(getattr(frame, "rotation", 0) or 0)
    except Exception:  # noqa: BLE001 - an unreadable file is read_video's to report
        return 0
    return int(round(degrees / 90.0)) % 4


def probe_video(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of the first frame; raises like ``read_video`` without decoding the whole file."""
    v = read_video(path, max_size=None, max_frames=1)
    return v.source_size


def read_video(path: str | os.PathLike, *, max_size: int | None = 512, every: int = 1,
               max_frames: int | None = None, transform=None, turns: int = 0) -> Video:
    """Frames of ``path`` (every ``every``-th, at most ``max_frames``), upright (``display_rotation``),
    then turned ``turns`` quarter turns counter-clockwise more, longer side at most ``max_size``;
    ``transform`` (frame at the file's size -> frame) replaces the resize and runs as each frame is decoded
    (a crop: only the cropped frames are held in memory). A cut-out video's frames (``alpha_video``)
    are laid over the light wall and their alpha is kept beside them (``Video.alpha``: turned and
    transformed or resized alike, decoded once with the colour).
    Raises FileNotFoundError for a missing file and VideoError for one that is not a decodable video."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such video file")
    if path.is_dir():
        raise VideoError(f"{path}: is a folder; expected a video file ({', '.join(VIDEO_SUFFIXES)})")
    if every < 1:
        raise ValueError(f"every must be at least 1, found {every}")
    import imageio.v3 as iio

    expected = f"expected a video file that ffmpeg can decode ({', '.join(VIDEO_SUFFIXES)})"
    frames, indices, alphas = [], [], []
    opaque = True
    fps = 0.0
    turns = (display_rotation(path) + turns) % 4
    decoder = alpha_decoder(path)
    try:
        meta = iio.immeta(path, plugin="pyav")
        fps = float(meta.get("fps") or 0.0)
        # a cut-out video (frames with alpha) is laid over the light wall, as a cut-out photo is
        decoded = (iio.imiter(path, plugin="pyav", format="rgb24") if decoder is None
                   else rgba_frames(path, decoder))
        for i, frame in enumerate(decoded):
            if i % every:
                continue
            if decoder is not None:
                a = frame[..., 3]
                opaque = opaque and bool(a.min() == 255)
                a = np.ascontiguousarray(np.rot90(a, turns)).astype(np.float32) / 255.0
                alphas.append(a if transform is None else np.clip(transform(a), 0.0, 1.0).astype(np.float32))
                frame = over_wall(frame)
            if turns:
                frame = np.ascontiguousarray(np.rot90(frame, turns))
            if not frames:
                first_size = frame.shape[:2]
                ww, wh = working_size(first_size[1], first_size[0], max_size)
            if transform is not None:
                frame = transform(frame)
            elif (ww, wh) != (frame.shape[1], frame.shape[0]):
                # resized as decoded: a long 4K clip held at its own size would not fit in memory
                frame = resize_frame(frame, ww, wh)
                if decoder is not None:
                    alphas[-1] = np.clip(_resize_alpha(alphas[-1], ww, wh), 0.0, 1.0)
            frames.append(frame)
            indices.append(i)
            if max_frames and len(frames) >= max_frames:
                break
    except Exception as exc:  # noqa: BLE001 - av/imageio raise many kinds for broken input
        raise VideoError(f"{path}: cannot be read as a video ({expected}): {type(exc).__name__}: {exc}") from exc
    if not frames:
        raise VideoError(f"{path}: holds no video frames ({expected})")
    h, w = first_size
    if not np.isfinite(fps) or fps <= 0:
        fps = 25.0
    alpha = None if not alphas or opaque else np.stack(alphas).astype(np.float32)
    return Video(np.stack(frames).astype(np.uint8), fps / every, (w, h), np.asarray(indices), alpha)
