"""The editor's input and overlay on the viewport (imgui, GL thread): left drags with a selection tool
make strokes (``EditController``) instead of orbiting, Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y undo and redo
when imgui does not want the keyboard, and the stroke being drawn (brush cursor, rectangle, lasso)
is outlined over the splats."""

from __future__ import annotations

from imgui_bundle import imgui

OUTLINE = 0xFF00A5FF  # ABGR: orange
OUTLINE_FAINT = 0x9000A5FF


class NoLeftDrag:
    """The orbit camera as ``orbit_input.apply_mouse`` sees it while a selection tool holds the left
    button: right / middle drags still pan and the wheel still zooms."""

    def __init__(self, orbit) -> None:
        self.orbit = orbit

    def drag(self, dx, dy, button, height) -> None:
        if button != "left":
            self.orbit.drag(dx, dy, button, height)

    def scroll(self, amount) -> None:
        self.orbit.scroll(amount)


def _view_pixel(view_size) -> tuple[float, float, bool]:
    """The mouse in viewport (framebuffer) pixels, and whether it is over the splat view."""
    io = imgui.get_io()
    sx, sy = io.display_framebuffer_scale.x or 1.0, io.display_framebuffer_scale.y or 1.0
    x, y = io.mouse_pos.x * sx, io.mouse_pos.y * sy
    vw, vh = view_size
    return x, y, 0 <= x < vw and 0 <= y < vh


def handle_mouse(edits, view_size) -> bool:
    """Strokes of the active selection tool. True while the left button is the tool's (the caller
    keeps the orbit's left drag off then)."""
    if not edits.tools.selecting or edits.session is None:
        if edits.stroke is not None:
            edits.cancel_stroke()
        return False
    io = imgui.get_io()
    left = imgui.MouseButton_.left
    x, y, inside = _view_pixel(view_size)
    if edits.stroke is None:
        if imgui.is_mouse_clicked(left) and inside and not io.want_capture_mouse:
            edits.begin_stroke(x, y, shift=io.key_shift, ctrl=io.key_ctrl)
            edits.stroke_by_mouse = True
        return True  # a selection tool never orbits with the left button
    if not edits.stroke_by_mouse:  # a stroke a script draws (benchmarks/edit_latency.py) ends itself
        return True
    if imgui.is_mouse_down(left):
        if io.mouse_delta.x or io.mouse_delta.y:
            edits.move_stroke(x, y)
        return True
    edits.finish_stroke(x, y)
    return True


def handle_keys(edits) -> None:
    """Ctrl+Z undo, Ctrl+Shift+Z and Ctrl+Y redo (not while typing into a field)."""
    io = imgui.get_io()
    if io.want_capture_keyboard or io.want_text_input or not io.key_ctrl:
        return
    if imgui.is_key_pressed(imgui.Key.z, False):
        edits.redo() if io.key_shift else edits.undo()
    elif imgui.is_key_pressed(imgui.Key.y, False):
        edits.redo()


def draw_overlay(edits, view_size) -> None:
    """The stroke in progress and the brush cursor, over the splats (under the panels)."""
    if not edits.tools.selecting:
        return
    io = imgui.get_io()
    sx, sy = io.display_framebuffer_scale.x or 1.0, io.display_framebuffer_scale.y or 1.0
    dl = imgui.get_background_draw_list()
    to_screen = lambda p: imgui.ImVec2(p[0] / sx, p[1] / sy)  # noqa: E731
    st = edits.stroke
    if st is not None and st.tool == "rect" and len(st.points) >= 2:
        (xa, ya), (xb, yb) = st.points[0], st.points[-1]
        dl.add_rect(to_screen((min(xa, xb), min(ya, yb))), to_screen((max(xa, xb), max(ya, yb))), OUTLINE, 0.0, 2.0)
    elif st is not None and st.tool == "lasso" and len(st.points) >= 2:
        pts = [to_screen(p) for p in st.points]
        dl.add_polyline(pts, OUTLINE, 2.0, 0)
        dl.add_line(pts[-1], pts[0], OUTLINE_FAINT, 1.0)
    x, y, inside = _view_pixel(view_size)
    if st is not None and st.tool == "brush" and st.points:  # where the brush paints
        dl.add_circle(to_screen(st.points[-1]), st.radius / sx, OUTLINE, 0, 1.5)
    elif edits.tools.tool == "brush" and inside and not io.want_capture_mouse:
        dl.add_circle(to_screen((x, y)), edits.tools.radius / sx, OUTLINE, 0, 1.5)
