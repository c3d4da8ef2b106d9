"""ViewState: what the studio window shows, as plain data (nerfstudio's and splatviz's viewers keep
it the same way). Panels change it through the app's actions; the app hands the parts the trainer
needs (space, frame, pose sequence) to the trainer thread."""

from __future__ import annotations

from dataclasses import dataclass, field

from renderer.render_modes import RenderMode

from .motion_source import MotionPanelState
from .ply_source import PlyFileState

# where the live view's pose comes from: the video's poses, a built-in novel sequence, or the
# motion file opened in the Pose panel (retargeted onto the avatar)
POSE_SOURCES = ("video", "walk", "arms_up", "motion")
POSE_LABELS = {"video": "video poses", "walk": "novel: walk cycle", "arms_up": "novel: arms up",
               "motion": "motion file"}


@dataclass
class ViewState:
    mode: RenderMode = RenderMode.RGB
    space: str = "observation"  # observation or canonical
    frame_index: int = 0  # the video frame (pose) shown
    pose_source: str = "video"  # the video's poses, a novel sequence or the motion file (POSE_SOURCES)
    novel_index: int = 0  # frame of the novel sequence or motion clip
    playing: bool = False
    show_gui: bool = True
    show_ground_truth: bool = False
    gt_view: int | None = None  # evaluation view shown as ground truth (None: the training frame)
    motion: MotionPanelState = field(default_factory=MotionPanelState)  # the Pose panel's motion file
    beside: PlyFileState = field(default_factory=PlyFileState)  # a .ply shown beside the live avatar
    show_beside: bool = True
    edit_panel: bool = False  # the Edit panel takes the left column (Training, Stage II hidden meanwhile)
