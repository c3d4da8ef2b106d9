"""Motion files (BVH, SMPL-family .npz) retargeted onto the avatar's body: ``docs/motion.md``.

    clip = load_motion("walk.bvh")                       # MotionClip
    result = retarget(clip, body, fps=30, base_pose=scene.frames[0].pose,
                      floor_poses=[f.pose for f in scene.frames])
    result.poses                                           # list[BodyPose], result.fps, result.notes
"""

from .clip import MotionClip, MotionFileError, SourceSkeleton
from .io import MOTION_SUFFIXES, load_motion
from .retarget import BoneMapping, RetargetResult, retarget

__all__ = [
           "MOTION_SUFFIXES",
           "BoneMapping",
           "MotionClip",
           "MotionFileError",
           "RetargetResult",
           "SourceSkeleton",
           "load_motion",
           "retarget",
]
