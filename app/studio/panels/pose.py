"""Pose panel: the video's poses, a novel sequence or a motion file (BVH / SMPL-family .npz,
retargeted onto the avatar: docs/motion.md), a frame scrubber, play / pause."""

from __future__ import annotations

from imgui_bundle import imgui

from ..view_state import POSE_LABELS, POSE_SOURCES
from .common import error_text, wrapped_hint
from .context import PanelContext


def _label(ui: PanelContext, source: str) -> str:
    loaded = ui.view.motion.loaded
    if source == "motion" and loaded is not None:
        return f"motion: {loaded.name}"
    return POSE_LABELS[source]


def draw_motion_file(ui: PanelContext) -> None:
    """The motion file: path, loop, Open; what the retargeting said; the last error."""
    m = ui.view.motion
    imgui.separator_text("motion file (.bvh, .fbx, .glb, .npz)")
    ch, path = imgui.input_text("path##motion", m.path)
    ui.mark("motion_path")
    if ch:
        m.path = path
    ch, v = imgui.checkbox("loop", m.loop)
    if ch:
        m.loop = v
    imgui.same_line()
    imgui.begin_disabled(m.loading)
    if imgui.button("Open##motion"):
        ui.actions.open_motion()
    ui.mark("open_motion")
    imgui.end_disabled()
    if m.loading:
        imgui.same_line()
        imgui.text_disabled("reading and retargeting...")
    loaded = m.loaded
    if loaded is not None:
        imgui.text_disabled(f"{loaded.name}: {loaded.source_frames} frames at {loaded.source_fps:g} fps -> "
                            f"{len(loaded)} at {loaded.fps:g} fps ({loaded.seconds:.2f} s)")
        if loaded.notes and imgui.tree_node(f"retargeting notes ({len(loaded.notes)})##motion_notes"):
            for note in loaded.notes:
                wrapped_hint(f"- {note}")
            imgui.tree_pop()
    if m.message:
        error_text(m.message)


def draw(ui: PanelContext) -> None:
    view = ui.view
    labels = [_label(ui, p) for p in POSE_SOURCES]
    ch, idx = imgui.combo("poses", POSE_SOURCES.index(view.pose_source), labels)
    ui.mark("pose_source")
    if ch:
        ui.actions.set_pose_source(POSE_SOURCES[idx])
    n = max(1, ui.num_pose_frames)
    current = view.frame_index if view.pose_source == "video" else view.novel_index
    changed, i = imgui.slider_int("frame", min(current, n - 1), 0, n - 1)
    ui.mark("frame")
    if changed:
        ui.actions.set_pose_frame(i)
    if imgui.button("Pause##play" if view.playing else "Play"):
        ui.actions.toggle_play()
    ui.mark("play")
    imgui.same_line()
    loaded = view.motion.loaded
    fps = loaded.fps if view.pose_source == "motion" and loaded is not None else ui.scene.fps
    imgui.text(f"{fps:g} fps, {n} frames")
    draw_motion_file(ui)
