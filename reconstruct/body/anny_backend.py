"""The Anny body model (offline; assets ship in the ``anny`` wheel)."""

from __future__ import annotations

import math
import os
import sys
import threading
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from .base import BodyModel

PHENOTYPE_LABELS = ("gender", "age", "muscle", "weight", "height", "proportions")
_SEGMENTATION_EXCLUDED = ("eye_back.L", "eye_front.L", "eye_back.R", "eye_front.R",
                          "eye_cavity.R", "eye_cavity.L", "mouth_cavity", "tongue")


def anny_cache_dir() -> Path:
    return Path(os.environ.get("ANNY_CACHE_DIR", str(Path.home() / ".cache" / "anny")))


def _cache_is_built() -> bool:
    return any(anny_cache_dir().glob("v*/build_model_data_*.safetensors"))


class _Ticker:
    """Shows elapsed time on stderr while a one-time build runs (its length is not known)."""

    def __init__(self, message: str) -> None:
        self.message = message
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        from tqdm import tqdm

        with tqdm(desc=self.message, bar_format="{desc}: {elapsed}", file=sys.stderr) as bar:
            while not self._stop.wait(0.5):
                bar.refresh()

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


_load_lock = threading.Lock()


@lru_cache(maxsize=1)
def load_anny_model():
    """Anny's full-body model (float64, pure-torch LBS). The first call in a fresh cache builds
    ~800 MB of model data under ``$ANNY_CACHE_DIR`` (default ~/.cache/anny); it shows progress."""
    with _load_lock:
        import anny

        if not _cache_is_built():
            print(f"building the Anny body-model cache in {anny_cache_dir()} (one time, ~1-2 min; "
                  "set ANNY_CACHE_DIR to place it elsewhere)", file=sys.stderr)
            with _Ticker("anny cache"):
                model = anny.Anny(skinning_method="lbs")
        else:
            model = anny.Anny(skinning_method="lbs")
        model.eval()
        return model


@lru_cache(maxsize=1)
def _segmentation() -> tuple[np.ndarray, dict]:
    import imageio.v3 as iio
    import yaml  # anny depends on PyYAML

    import anny

    folder = Path(anny.__file__).parent / "data" / "segmentation"
    image = iio.imread(folder / "body_parts_segmentation.png")[..., :3]
    colors = yaml.safe_load((folder / "body_parts_segmentation.yaml").read_text())["colors"]
    return image, colors


def random_phenotype(rng: np.random.Generator) -> dict[str, float]:
    """An adult phenotype drawn from the middle of Anny's ranges (the synthetic scenes' default)."""
    return {
        "gender": float(rng.uniform(0.0, 1.0)),
        "age": float(rng.uniform(0.45, 0.75)),
        "muscle": float(rng.uniform(0.3, 0.7)),
        "weight": float(rng.uniform(0.3, 0.7)),
        "height": float(rng.uniform(0.35, 0.75)),
        "proportions": float(rng.uniform(0.4, 0.6)),
    }


class AnnyBody(BodyModel):
    """Anny with a fixed phenotype. ``leg_spread_deg`` opens the legs of the canonical pose."""

    name = "anny"

    def __init__(self, phenotype: dict[str, float] | None = None, *, leg_spread_deg: float = 12.0) -> None:
        phenotype = dict(phenotype or {})
        unknown = set(phenotype) - set(PHENOTYPE_LABELS)
        if unknown:
            raise ValueError(f"unknown Anny phenotype keys {sorted(unknown)}; expected some of {PHENOTYPE_LABELS}")
        for k, v in phenotype.items():
            if not (0.0 <= float(v) <= 1.0) or not math.isfinite(float(v)):
                raise ValueError(f"Anny phenotype {k}={v} is outside [0, 1]")
        self.phenotype = {k: float(phenotype.get(k, 0.5)) for k in PHENOTYPE_LABELS}
        self.leg_spread_deg = float(leg_spread_deg)
        self.model = load_anny_model()
        m = self.model
        with torch.no_grad():
            out = m(phenotype_kwargs=self.phenotype)
        self._rest_bone_poses = out["rest_bone_poses"].detach()
        self.rest_vertices = out["rest_vertices"][0].detach()
        self.rest_joints = self._rest_bone_poses[0, :, :3, 3].clone()
        self.bone_labels = list(m.bone_labels)
        self.bone_parents = np.asarray(m.bone_parents, np.int64)
        self.faces = m.get_triangular_faces().long()
        V, J = self.rest_vertices.shape[0], len(self.bone_labels)
        dense = torch.zeros(V, J, dtype=torch.float64)
        dense.scatter_add_(1, m.vertex_bone_indices.long(), m.vertex_bone_weights.to(torch.float64))
        self.skin_weights = dense / dense.sum(1, keepdim=True)
        self.uv_coords = m.texture_coordinates.to(torch.float64)
        self.face_uv_indices = m.face_texture_coordinate_indices.long()

    def rest_to_pose_transforms(self, joint_rotations: torch.Tensor) -> torch.Tensor:
        from .pose import axis_angle_to_matrix, rigid

        J = self.num_joints
        if joint_rotations.shape != (J, 3):
            raise ValueError(f"Anny pose: expected joint rotations of shape ({J}, 3), found {tuple(joint_rotations.shape)}")
        deltas = rigid(axis_angle_to_matrix(joint_rotations.to(torch.float64)), torch.zeros(J, 3, dtype=torch.float64))
        transforms, _ = self.model.get_bone_transforms(deltas[None], self._rest_bone_poses)
        return transforms[0]

    def anny_forward_vertices(self, joint_rotations: np.ndarray) -> torch.Tensor:
        """Anny's own forward pass for a pose (reference for tests)."""
        from .pose import axis_angle_to_matrix, rigid

        J = self.num_joints
        rot = torch.as_tensor(joint_rotations, dtype=torch.float64)
        deltas = rigid(axis_angle_to_matrix(rot), torch.zeros(J, 3, dtype=torch.float64))
        with torch.no_grad():
            return self.model(pose_parameters=deltas[None], phenotype_kwargs=self.phenotype)["vertices"][0]

    def canonical_joint_rotations(self) -> np.ndarray:
        rot = np.zeros((self.num_joints, 3))
        spread = math.radians(self.leg_spread_deg)
        rot[self.bone_labels.index("upperleg01.L"), 1] = -spread  # about +Y: left foot moves to +X
        rot[self.bone_labels.index("upperleg01.R"), 1] = +spread
        return rot

    def excluded_uv(self, uv: np.ndarray) -> np.ndarray:
        image, colors = _segmentation()
        H, W = image.shape[:2]
        col = np.clip((uv[:, 0] * W).astype(np.int64), 0, W - 1)
        row = np.clip(((1.0 - uv[:, 1]) * H).astype(np.int64), 0, H - 1)
        texel = image[row, col].astype(np.int64)
        bad = np.zeros(len(uv), bool)
        for name in _SEGMENTATION_EXCLUDED:
            bad |= np.all(np.abs(texel - np.asarray(colors[name])) <= 2, axis=1)
        return bad
