"""Pose panel: the video's poses or a novel sequence, a frame scrubber, play / pause."""

from __future__ import annotations

from imgui_bundle import imgui

from ..view_state import POSE_LABELS, POSE_SOURCES
from .context import PanelContext


def draw(ui: PanelContext) -> None:
    view = ui.view
    ch, idx = imgui.combo("poses", POSE_SOURCES.index(view.pose_source), [POSE_LABELS[p] for p in POSE_SOURCES])
    if ch:
        ui.actions.set_pose_source(POSE_SOURCES[idx])
    n = ui.num_pose_frames
    current = view.frame_index if view.pose_source == "video" else view.novel_index
    changed, i = imgui.slider_int("frame", current, 0, n - 1)
    ui.mark("frame")
    if changed:
        ui.actions.set_pose_frame(i)
    if imgui.button("Pause##play" if view.playing else "Play"):
        ui.actions.toggle_play()
    ui.mark("play")
    imgui.same_line()
    imgui.text(f"{ui.scene.fps:g} fps, {n} frames")
