"""FramePacer: when the studio draws a frame.

At most ``max_fps`` while the user interacts (input in the last ``active_s`` seconds), playback
runs or an export renders; ``idle_fps`` otherwise, and an idle window draws only when something
changed (or once every ``idle_refresh_s``). glfw wakes the loop at once on input, so the GUI
answers input at the full rate while an idle window costs training little (benchmarks/studio.py).
The glfw input callbacks only note the time of the last input on the pacer (imgui's backend
chains to them), so an idle loop that skips frames still wakes up to full speed on the first event.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class FramePacer:
    def __init__(self, *, max_fps: float = 30.0, idle_fps: float = 5.0, active_s: float = 1.5,
                 idle_refresh_s: float = 1.0) -> None:
        self.max_fps = max_fps
        self.idle_fps = idle_fps
        self.active_s = active_s
        self.idle_refresh_s = idle_refresh_s
        self.last_input = time.perf_counter()
        self.fps = 0.0
        self._next = time.perf_counter()
        self._last_frame = self._next
        self._last_changes = None

    def note_input(self, *_args) -> None:
        self.last_input = time.perf_counter()

    def watch(self, glfw, window) -> None:
        """Note input events of ``window`` (call before imgui's glfw backend installs its own)."""
        for setter in (glfw.set_cursor_pos_callback, glfw.set_mouse_button_callback, glfw.set_scroll_callback,
                       glfw.set_key_callback, glfw.set_char_callback, glfw.set_window_size_callback):
            setter(window, self.note_input)

    def active(self, busy: bool) -> bool:
        return busy or time.perf_counter() - self.last_input < self.active_s

    def wait(self, wait_events: Callable[[float], None], poll_events: Callable[[], None], *, busy: bool,
             changes=None, always: bool = False) -> bool:
        """Sleep until the next frame is due (waking on input) and say whether to draw it: always
        while active; idle, only when ``changes`` differ from the last drawn frame's or the
        refresh interval has passed."""
        active = self.active(busy)
        cap = self.max_fps if active else self.idle_fps
        self._next += 1.0 / cap if cap else 0.0
        delay = self._next - time.perf_counter()
        if delay > 0:
            wait_events(delay)  # sleeps (freeing the GIL); returns at once on input
        else:
            poll_events()
        now = time.perf_counter()
        self._next = max(self._next, now) if now - self._next < 1.0 / max(cap, 1) else now
        if not (always or self.active(busy)):  # idle (input during the wait counts as active)
            if changes == self._last_changes and now - self._last_frame < self.idle_refresh_s:
                return False
        self._last_changes = changes
        dt = max(now - self._last_frame, 1e-6)
        self._last_frame = now
        self.fps = 1.0 / dt if self.fps == 0 else 0.9 * self.fps + 0.1 / dt
        return True
