"""Mediapipe's 33 pose landmarks and where they sit on the body model.

Each landmark used by the fit maps to a bone head of the body (shoulders, elbows, wrists, the index
and little fingers' knuckles, hips, knees, ankles, eyes) or to one mesh vertex found from the rest
mesh (nose tip, ears). The ``*_index`` and ``*_pinky`` landmarks are the knuckles where those fingers
leave the palm (mediapipe's "knuckle #1"), the heads of Anny's ``finger2-1`` and ``finger5-1``; they
turn the hand at the wrist (``fit.FIT_BONES``). ``prepare`` puts the hand model's knuckles there, or
leaves them out where it has none (``hands.py``): the pose model's own hand points are too loose.
The thumb and the fingers beyond the knuckles, and the feet beyond the ankles, are not fitted (their
bones are not optimised). Mediapipe's left/right are the person's own; Anny's ``.L`` bones are the
person's left too (+X, the image's right side when the person faces the camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...body.base import BodyModel
from ...body.lbs import apply_points, blend

LANDMARK_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
    "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
NUM_LANDMARKS = len(LANDMARK_NAMES)

# landmark -> (kind, target, weight): a bone head or a vertex picked by a rule on the rest mesh
LANDMARK_TARGETS: dict[str, tuple[str, str, float]] = {
    "nose": ("vertex", "nose", 0.5),
    "left_eye": ("bone", "eye.L", 0.5),
    "right_eye": ("bone", "eye.R", 0.5),
    "left_ear": ("vertex", "ear.L", 0.5),
    "right_ear": ("vertex", "ear.R", 0.5),
    "left_shoulder": ("bone", "upperarm01.L", 1.0),
    "right_shoulder": ("bone", "upperarm01.R", 1.0),
    "left_elbow": ("bone", "lowerarm01.L", 1.0),
    "right_elbow": ("bone", "lowerarm01.R", 1.0),
    "left_wrist": ("bone", "wrist.L", 1.0),
    "right_wrist": ("bone", "wrist.R", 1.0),
    # the hand's knuckles (half a limb joint's weight: a hand is small and the hand model can be off)
    "left_index": ("bone", "finger2-1.L", 0.5),
    "right_index": ("bone", "finger2-1.R", 0.5),
    "left_pinky": ("bone", "finger5-1.L", 0.5),
    "right_pinky": ("bone", "finger5-1.R", 0.5),
    "left_hip": ("bone", "upperleg01.L", 1.0),
    "right_hip": ("bone", "upperleg01.R", 1.0),
    "left_knee": ("bone", "lowerleg01.L", 1.0),
    "right_knee": ("bone", "lowerleg01.R", 1.0),
    "left_ankle": ("bone", "foot.L", 1.0),
    "right_ankle": ("bone", "foot.R", 1.0),
}

# the 12 limb joints used for 3D errors (evaluation against known poses)
EVAL_JOINTS = ("upperarm01.L", "upperarm01.R", "lowerarm01.L", "lowerarm01.R", "wrist.L", "wrist.R",
               "upperleg01.L", "upperleg01.R", "lowerleg01.L", "lowerleg01.R", "foot.L", "foot.R")

# limb segments whose 3D directions are compared with mediapipe's world landmarks
SEGMENTS = (("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"), ("right_shoulder", "right_elbow"),
            ("right_elbow", "right_wrist"), ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
            ("right_hip", "right_knee"), ("right_knee", "right_ankle"), ("right_shoulder", "left_shoulder"),
            ("right_hip", "left_hip"))


def require_bones(body: BodyModel, names) -> None:
    """The bones ``prepare`` fits and reads keypoints from are named in the Anny skeleton; a body
    without them (an SMPL body, say) is refused with the names it lacks."""
    missing = sorted({n for n in names if n not in body.bone_labels})
    if missing:
        raise ValueError(f"prepare fits Anny bodies: body model {body.name!r} has no bones {', '.join(missing)} "
                         f"(SMPL bodies come with the dataset loaders' fitted poses, not from prepare)")


def _rest_vertex(body: BodyModel, rule: str) -> int:
    """Index of the rest-mesh vertex for ``rule`` among vertices driven mainly by the head bone."""
    V = body.canonical_vertices.numpy()
    head = np.where(body.skin_weights.argmax(1).numpy() == body.bone_labels.index("head"))[0]
    if len(head) == 0:
        raise ValueError(f"body model {body.name!r}: no vertices follow a 'head' bone")
    hv = V[head]
    if rule == "nose":
        return int(head[np.argmin(hv[:, 1])])  # the most frontal point (the body faces -Y)
    if rule == "ear.L":
        return int(head[np.argmax(hv[:, 0])])
    if rule == "ear.R":
        return int(head[np.argmin(hv[:, 0])])
    raise ValueError(f"unknown vertex rule {rule!r}")


@dataclass
class KeypointMap:
    """The body's points that stand for mediapipe landmarks.

    landmark_ids (K,) indices into the 33 landmarks; weights (K,); for each, either a bone index
    (``bone_ids`` >= 0) or skinning weights of one vertex (``vertex_weights`` rows, used where
    ``bone_ids`` == -1) and its rest position."""

    landmark_ids: np.ndarray
    weights: np.ndarray
    bone_ids: np.ndarray
    vertex_rest: torch.Tensor  # (K,3) rest positions (bone heads or vertices)
    vertex_weights: torch.Tensor  # (K,J) skinning weights (one-hot for bone heads)
    vertex_ids: np.ndarray  # (K,) mesh vertex of each landmark, -1 for bone heads

    @classmethod
    def build(cls, body: BodyModel) -> "KeypointMap":
        require_bones(body, ["head"] + [t for kind, t, _ in LANDMARK_TARGETS.values() if kind == "bone"])
        ids, weights, bones, rest, skin, verts = [], [], [], [], [], []
        J = body.num_joints
        for name, (kind, target, w) in LANDMARK_TARGETS.items():
            ids.append(LANDMARK_NAMES.index(name))
            weights.append(w)
            if kind == "bone":
                b = body.bone_labels.index(target)
                bones.append(b)
                rest.append(body.rest_joints[b])
                one = torch.zeros(J, dtype=torch.float64)
                one[b] = 1.0
                skin.append(one)
                verts.append(-1)
            else:
                v = _rest_vertex(body, target)
                bones.append(-1)
                rest.append(body.rest_vertices[v])
                skin.append(body.skin_weights[v])
                verts.append(v)
        return cls(np.asarray(ids), np.asarray(weights, np.float64), np.asarray(bones),
                   torch.stack(rest), torch.stack(skin), np.asarray(verts))

    def rest_points(self, joints: torch.Tensor, vertices: torch.Tensor) -> torch.Tensor:
        """(K,3) rest positions of the landmarks' points for another rest geometry of the same body
        (``joints`` (J,3), ``vertices`` (V,3)), e.g. another phenotype."""
        rows = []
        for b, v in zip(self.bone_ids, self.vertex_ids):
            rows.append(joints[int(b)] if b >= 0 else vertices[int(v)])
        return torch.stack(rows)

    def index_of(self, landmark: str) -> int:
        return int(np.nonzero(self.landmark_ids == LANDMARK_NAMES.index(landmark))[0][0])

    def points(self, transforms: torch.Tensor, rest: torch.Tensor | None = None) -> torch.Tensor:
        """(...,K,3) posed points from bone transforms (...,J,4,4) (rest -> pose); ``rest`` (K,3)
        replaces the rest positions (another phenotype, see ``rest_points``)."""
        return apply_points(blend(self.vertex_weights, transforms), self.vertex_rest if rest is None else rest)
