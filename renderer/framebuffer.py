"""Offscreen render targets and readback.

``OffscreenTarget`` owns a colour texture (RGBA, float32 by default so that thousands of blended
splats do not accumulate 8-bit rounding), a depth renderbuffer (for the mesh overlay) and the
framebuffer holding them. ``read`` returns the image top row first (image convention), i.e. the
GL rows flipped, as a C-contiguous ``(H, W, 4)`` array.
"""

from __future__ import annotations

import moderngl
import numpy as np

_DTYPES = {"f4": np.float32, "f2": np.float16, "u1": np.uint8}


class OffscreenTarget:
    def __init__(self, ctx: moderngl.Context, width: int, height: int, dtype: str = "f4", depth: bool = True):
        if dtype not in _DTYPES:
            raise ValueError(f"OffscreenTarget dtype must be one of {list(_DTYPES)}, found {dtype!r}")
        self.ctx = ctx
        self.dtype = dtype
        self.has_depth = depth
        self.width = self.height = 0
        self.color = self.depth = self.fbo = None
        self.resize(width, height)

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    def resize(self, width: int, height: int) -> bool:
        """(Re)allocate for ``width x height``; returns True when it had to."""
        width, height = int(width), int(height)
        if width <= 0 or height <= 0:
            raise ValueError(f"render target size must be positive, found {width}x{height}")
        limit = int(self.ctx.info.get("GL_MAX_RENDERBUFFER_SIZE", 16384))
        if width > limit or height > limit:
            raise ValueError(f"render target {width}x{height} exceeds this GL's limit {limit}")
        if (width, height) == (self.width, self.height) and self.fbo is not None:
            return False
        self._free()
        self.color = self.ctx.texture((width, height), 4, dtype=self.dtype)
        self.color.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = self.ctx.depth_renderbuffer((width, height)) if self.has_depth else None
        self.fbo = self.ctx.framebuffer(color_attachments=[self.color], depth_attachment=self.depth)
        self.width, self.height = width, height
        return True

    def use(self) -> None:
        self.fbo.use()
        self.ctx.viewport = (0, 0, self.width, self.height)

    def clear(self, rgba=(0.0, 0.0, 0.0, 0.0)) -> None:
        r, g, b, a = (float(v) for v in rgba)
        self.fbo.clear(r, g, b, a, depth=1.0)

    def read(self, dtype=np.float32) -> np.ndarray:
        """The colour attachment as (H, W, 4), top image row first, in ``dtype``
        (float32 in [0,1] or uint8 rounded)."""
        return read_framebuffer(self.fbo, self.width, self.height, self.dtype, dtype)

    def _free(self) -> None:
        for obj in (self.fbo, self.color, self.depth):
            if obj is not None:
                obj.release()
        self.fbo = self.color = self.depth = None

    def release(self) -> None:
        self._free()
        self.width = self.height = 0


def read_framebuffer(fbo: moderngl.Framebuffer, width: int, height: int, stored: str = "f4",
                     dtype=np.float32) -> np.ndarray:
    """Read RGBA of ``fbo`` (its stored component type ``stored``) as (H, W, 4), top row first."""
    want = np.dtype(dtype)
    read_as = "u1" if (stored == "u1" and want == np.uint8) else "f4"
    raw = fbo.read(viewport=(0, 0, width, height), components=4, dtype=read_as, alignment=1)
    img = np.frombuffer(raw, dtype=np.uint8 if read_as == "u1" else np.float32).reshape(height, width, 4)
    img = img[::-1]
    if want == np.uint8 and read_as != "u1":
        return np.ascontiguousarray(np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8))
    if want != np.uint8 and read_as == "u1":
        return np.ascontiguousarray(img.astype(want) / 255.0)
    return np.ascontiguousarray(img.astype(want, copy=False))
