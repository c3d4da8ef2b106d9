"""OpenGL contexts: a headless EGL context for tests and exports, or the current window's.

A window's GLX context must be created before any EGL context in the same process (the other
order crashes Mesa); ``create_offscreen_context`` is therefore only for processes without a
window, and the studio reuses its window context for offscreen passes (framebuffers).
"""

from __future__ import annotations

import threading

import moderngl

_lock = threading.Lock()
_shared: moderngl.Context | None = None


class GLUnavailableError(RuntimeError):
    """No OpenGL 3.3+ context could be created."""


def create_offscreen_context(require: int = 330) -> moderngl.Context:
    """A new standalone context through EGL (Mesa llvmpipe on a machine without a GPU)."""
    try:
        return moderngl.create_context(standalone=True, backend="egl", require=require)
    except Exception as exc:  # moderngl raises plain Exception subclasses from several layers
        raise GLUnavailableError(
            "could not create a headless OpenGL context through EGL "
            f"({type(exc).__name__}: {exc}). On Debian install: apt-get install libegl1 libgl1 libgl1-mesa-dri"
        ) from exc


def shared_offscreen_context() -> moderngl.Context:
    """One process-wide EGL context, created on first use (not thread-safe to *use* from two
    threads at once; callers that render from several threads create their own)."""
    global _shared
    with _lock:
        if _shared is None:
            _shared = create_offscreen_context()
        return _shared


def context_info(ctx: moderngl.Context) -> dict:
    info = ctx.info
    return {
        "renderer": info.get("GL_RENDERER", "?"),
        "version": info.get("GL_VERSION", "?"),
        "vendor": info.get("GL_VENDOR", "?"),
    }
