"""The orbit camera driven by this frame's mouse and keys, shared by the studio and the .ply viewer:
drag orbits, right- or middle-drag pans, the wheel zooms, H toggles the panels. Input over a panel
is the panel's; any input wakes the frame pacer."""

from __future__ import annotations

from imgui_bundle import imgui


def apply_mouse(orbit, pacer, framebuffer_height: int) -> bool:
    """Move ``orbit`` by the mouse unless imgui wants it; True when H asks to toggle the panels."""
    io = imgui.get_io()
    d = io.mouse_delta
    if d.x or d.y or io.mouse_wheel or imgui.is_any_mouse_down() or imgui.is_any_item_active():
        pacer.note_input()
    if io.want_capture_mouse:
        return False
    fh = max(1, int(framebuffer_height))
    if imgui.is_mouse_dragging(imgui.MouseButton_.left) and (d.x or d.y):
        orbit.drag(d.x, d.y, "left", fh)
    elif (imgui.is_mouse_dragging(imgui.MouseButton_.right) or imgui.is_mouse_dragging(
            imgui.MouseButton_.middle)) and (d.x or d.y):
        orbit.drag(d.x, d.y, "right", fh)
    if io.mouse_wheel:
        orbit.scroll(io.mouse_wheel)
    return imgui.is_key_pressed(imgui.Key.h) and not io.want_text_input
