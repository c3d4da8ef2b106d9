"""Cut-out videos: a video whose frames carry an alpha channel (a background remover's WebM, an
editor's ProRes 4444 or PNG/Animation QuickTime export).

ffmpeg's own VP8/VP9 decoders drop the alpha that WebM stores beside each frame (``alpha_mode`` 1 on
the stream), so those are decoded with libvpx, which keeps it; the other codecs decode it
themselves (ProRes 4444: ``yuva444p12le``, QuickTime Animation: ``argb``, PNG: ``rgba``).
``rgba_frames`` yields the frames as RGBA; ``video.read_video`` lays them over the light wall a
cut-out photo is shown on and keeps their alpha beside them (``Video.alpha``, decoded once with the
colour), which ``user_masks`` takes as the person mask.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

# what a cut-out's transparent pixels are shown over (a light, neutral wall): whatever colour they
# hold (often black, or the colour the background had before it was cut away) is not the scene's
CUTOUT_BACKGROUND = (209, 209, 204)

# pixel formats with an alpha plane (ffmpeg's names: yuva420p, yuva444p12le, argb, rgba64le, gbrap, ya8, ...)
ALPHA_FORMAT_PARTS = ("yuva", "rgba", "bgra", "argb", "abgr", "gbrap", "ya8", "ya16")


def alpha_decoder(path: str | os.PathLike) -> str | None:
    """The decoder that gives the alpha of ``path``'s video stream ("libvpx-vp9", "libvpx" or the
    stream's own codec), or None when its frames carry no alpha (or it cannot be opened: read_video
    reports that)."""
    import av

    try:
        with av.open(str(path)) as c:
            if not c.streams.video:
                return None
            st = c.streams.video[0]
            name = st.codec_context.name
            if name in ("vp8", "vp9") and str(st.metadata.get("alpha_mode", "")) == "1":
                return "libvpx-vp9" if name == "vp9" else "libvpx"
            pix = st.codec_context.pix_fmt or ""
            return name if any(part in pix for part in ALPHA_FORMAT_PARTS) else None
    except Exception:  # noqa: BLE001 - not a video av can open: no alpha to read here
        return None


def rgba_frames(path: str | os.PathLike, decoder: str) -> Iterator[np.ndarray]:
    """The (H,W,4) uint8 RGBA frames of ``path``'s first video stream, decoded by ``decoder``
    (``alpha_decoder``), as stored (no display rotation)."""
    import av

    with av.open(str(Path(path))) as c:
        st = c.streams.video[0]
        ctx = st.codec_context if decoder == st.codec_context.name else av.CodecContext.create(decoder, "r")
        if ctx is st.codec_context:
            for frame in c.decode(st):
                yield frame.to_ndarray(format="rgba")
            return
        for packet in c.demux(st):
            if packet.size == 0:  # the demuxer's last, empty packet
                continue
            for frame in ctx.decode(packet):
                yield frame.to_ndarray(format="rgba")
        try:
            for frame in ctx.decode(None):
                yield frame.to_ndarray(format="rgba")
        except av.error.EOFError:
            pass


def over_wall(rgba: np.ndarray) -> np.ndarray:
    """(H,W,3) uint8: an RGBA frame laid over ``CUTOUT_BACKGROUND`` (as a cut-out photo is read)."""
    a = rgba[..., 3:4].astype(np.float32) / 255.0
    wall = np.asarray(CUTOUT_BACKGROUND, np.float32)
    return np.clip(rgba[..., :3].astype(np.float32) * a + wall * (1.0 - a) + 0.5, 0, 255).astype(np.uint8)


__all__ = ["CUTOUT_BACKGROUND", "alpha_decoder", "over_wall", "rgba_frames"]
