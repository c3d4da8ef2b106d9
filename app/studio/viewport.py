"""The studio's viewport drawing (GL thread): the splat view's offscreen framebuffer, redrawn only when
what it shows changed and copied to the window every frame, and the ground-truth image beside it.

``SplatView.draw`` takes the snapshot (with the edit selection's highlight already set), the camera,
the mode and the background; the key of what was drawn is kept so an idle window does not render
the splats again. ``GroundTruthImage`` keeps one GL texture of the image shown beside the view."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

VIEW_CLEAR = (0.08, 0.08, 0.09)  # the window around a narrower splat view


def to_rgb8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        image = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(image[..., :3])


class SplatView:
    """The splats of one window in a cached offscreen framebuffer."""

    def __init__(self, ctx, renderer) -> None:
        self.ctx = ctx
        self.renderer = renderer
        self.fbo = None
        self._size = None
        self._key = None

    def draw(self, snap, camera, mode, background) -> bool:
        """Render ``snap`` into the framebuffer (the camera's size) when anything changed; True when
        it rendered."""
        size = (camera.width, camera.height)
        if self._size != size:
            if self.fbo is not None:
                self.fbo.release()
            self.fbo = self.ctx.simple_framebuffer(size, components=4)
            self._size, self._key = size, None
        key = (snap.version, id(snap), mode, size, camera.K.tobytes(), camera.R.tobytes(), camera.t.tobytes(),
               background)
        if key == self._key:
            return False
        self.renderer.set_snapshot(snap)
        self.renderer.render(camera, mode=mode, background=background, target=self.fbo)
        self._key = key
        return True

    def blit(self, window_size) -> None:
        """Copy the framebuffer to the window's bottom-left corner (cleared around it when narrower)."""
        if self.fbo is None:
            return
        self.ctx.screen.use()
        if self._size != tuple(window_size):
            self.ctx.clear(*VIEW_CLEAR)
        self.ctx.copy_framebuffer(self.ctx.screen, self.fbo)

    def release(self) -> None:
        if self.fbo is not None:
            self.fbo.release()
            self.fbo = None


class GroundTruthImage:
    """A GL texture of the ground-truth image shown beside the splat view (uploaded on change)."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx
        self.tex = None
        self._key = None

    def texture(self, image: np.ndarray | None):
        if image is None:
            return None
        key = (id(image), image.shape)
        if key != self._key:
            rgb = to_rgb8(image)
            h, w = rgb.shape[:2]
            if self.tex is None or self.tex.size != (w, h):
                if self.tex is not None:
                    self.tex.release()
                self.tex = self.ctx.texture((w, h), 3)
            self.tex.write(rgb.tobytes())
            self._key = key
        return self.tex

    def forget(self) -> None:
        """Upload again on the next ``texture`` (another scene's images)."""
        self._key = None

    def draw(self, image: np.ndarray | None, window_size, view_width: int) -> None:
        """``image`` right of the splat view (imgui background draw list), aspect kept."""
        tex = self.texture(image)
        if tex is None:
            return
        fw, fh = window_size
        w, h = tex.size
        s = min((fw - view_width) / w, fh / h)
        x0 = view_width + 0.5 * ((fw - view_width) - s * w)
        y0 = 0.5 * (fh - s * h)
        dl = imgui.get_background_draw_list()
        dl.add_image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(x0, y0), imgui.ImVec2(x0 + s * w, y0 + s * h))
        dl.add_text(imgui.ImVec2(view_width + 8, fh - 22), 0xFFFFFFFF, "ground truth")

    def release(self) -> None:
        if self.tex is not None:
            self.tex.release()
            self.tex = None
