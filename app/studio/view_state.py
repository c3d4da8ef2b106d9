"""ViewState: what the studio window shows, as plain data (nerfstudio's and splatviz's viewers keep
it the same way). Panels change it through the app's actions; the app hands the parts the trainer
needs (space, frame, novel pose) to the trainer thread."""

from __future__ import annotations

from dataclasses import dataclass

from renderer.render_modes import RenderMode

POSE_SOURCES = ("video", "walk", "arms_up")
POSE_LABELS = {"video": "video poses", "walk": "novel: walk cycle", "arms_up": "novel: arms up"}


@dataclass
class ViewState:
    mode: RenderMode = RenderMode.RGB
    space: str = "observation"  # observation or canonical
    frame_index: int = 0  # the video frame (pose) shown
    pose_source: str = "video"  # the video's poses or a novel sequence (POSE_SOURCES)
    novel_index: int = 0  # frame of the novel sequence
    playing: bool = False
    show_gui: bool = True
    show_ground_truth: bool = False
    gt_view: int | None = None  # evaluation view shown as ground truth (None: the training frame)
