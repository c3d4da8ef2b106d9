"""SMPL as a ``BodyModel``, from model files the user supplies (they cannot ship with the program).

Files (looked for, in order, in ``smpl_dir`` given explicitly, ``$WONDERHUMAN_SMPL_DIR``, and
``<cache_dir>/smpl``; each folder also through its ``smpl/`` subfolder):

- the model: ``SMPL_{NEUTRAL,FEMALE,MALE}.pkl|.npz`` or the official release names
  (``basicmodel_neutral_lbs_10_207_0_v1.1.0.pkl``, ``basicModel_f_lbs_10_207_0_v1.0.0.pkl``, ...).
  Official ``.pkl`` files hold chumpy objects; they are read without chumpy by a restricted
  unpickler (``reconstruct.safe_pickle``'s plain-data one, extended) that only admits numpy,
  scipy.sparse matrices and a stand-in for chumpy's array classes: a crafted file cannot run code.
- the UV layout: ``smpl_uv.obj`` (``v``/``vt``/``f a/ta b/tb c/tc``, the SMPL mesh's vertex order).

Frames: SMPL's own space is Y up, facing +Z. The project's body space is Z up, facing -Y
(DESIGN.md), so the backend presents the SMPL body rotated by ``SMPL_TO_BODY`` (+90 degrees about
X). A dataset's SMPL parameters map to a ``BodyPose`` with ``smpl_body_pose``: joint rotations are
SMPL's axis-angles (parent-relative; SMPL's rest frames are axis-aligned, so they are rotations
about each joint in the body's axes) expressed in the rotated axes, and the global rotation
carries the rotation back into the dataset's world.

Left out: SMPL's pose-dependent corrective blend shapes (``posedirs``). The BodyModel interface
is pure skinning of one rest mesh (the Gaussians' offsets learn what the correctives would add).
Shape blend shapes (``betas``) are applied once, to make the rest mesh.
"""

from __future__ import annotations

import copyreg
import math
import os
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from ..safe_pickle import RestrictedUnpickler, SafeLoadError, restricted_loads
from .base import BodyModel
from .pose import BodyPose, axis_angle_to_matrix

ENV_VAR = "WONDERHUMAN_SMPL_DIR"
NUM_JOINTS = 24
SMPL_JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)
# Labels in the naming that reconstruct.body.parts understands (.L is the body's left, as in Anny).
BONE_LABELS = (
    "pelvis", "upperleg.L", "upperleg.R", "spine01", "lowerleg.L", "lowerleg.R", "spine02", "foot.L",
    "foot.R", "spine03", "toe.L", "toe.R", "neck", "clavicle.L", "clavicle.R", "head",
    "upperarm.L", "upperarm.R", "lowerarm.L", "lowerarm.R", "wrist.L", "wrist.R", "finger.L", "finger.R",
)
# SMPL space (Y up, facing +Z) -> body space (Z up, facing -Y): +90 degrees about X.
SMPL_TO_BODY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
GENDERS = ("neutral", "female", "male")
UV_FILE_NAMES = ("smpl_uv.obj", "SMPL_UV.obj", "smpl_uv_map.obj")
REQUIRED_KEYS = ("v_template", "f", "weights", "kintree_table", "J_regressor", "shapedirs")
# SMPL's pelvis in its own space for the mean shape (about): used where a loader needs the body's
# centre without the model files (seen/unseen azimuths of evaluation views).
NOMINAL_PELVIS_SMPL = np.array([0.0, -0.22, 0.02])


class SMPLFilesError(FileNotFoundError):
    """SMPL model or UV files missing or unreadable: names the file and every place looked."""


def _model_file_names(gender: str) -> list[str]:
    short = {"neutral": "neutral", "female": "f", "male": "m"}[gender]
    return [f"SMPL_{gender.upper()}.pkl", f"SMPL_{gender.upper()}.npz",
            f"basicmodel_{short}_lbs_10_207_0_v1.1.0.pkl", f"basicModel_{short}_lbs_10_207_0_v1.0.0.pkl",
            f"basicmodel_{short}_lbs_10_207_0_v1.0.0.pkl"]


def search_dirs(smpl_dir: str | os.PathLike | None = None) -> list[tuple[Path, str]]:
    """The folders searched for SMPL files, each with where it came from."""
    out: list[tuple[Path, str]] = []
    if smpl_dir:
        out.append((Path(smpl_dir).expanduser(), "smpl_dir"))
    if os.environ.get(ENV_VAR):
        out.append((Path(os.environ[ENV_VAR]).expanduser(), f"${ENV_VAR}"))
    root = Path(os.environ.get("WONDERHUMAN_CACHE_DIR", str(Path.home() / ".cache" / "wonderhuman")))
    out.append((root / "smpl", "the cache folder"))
    return out


def _find(names: list[str], smpl_dir, what: str) -> Path:
    tried = []
    for folder, origin in search_dirs(smpl_dir):
        for sub in (folder, folder / "smpl"):
            for name in names:
                p = sub / name
                if p.is_file():
                    return p
            tried.append(f"{sub} ({origin})")
    raise SMPLFilesError(
        f"SMPL {what} not found: looked for {' / '.join(names)} in " + "; ".join(tried) +
        f". SMPL files cannot ship with the program: download them from https://smpl.is.tue.mpg.de "
        f"and pass their folder as smpl_dir=... in the scene spec, or set ${ENV_VAR}, or copy them to the cache folder.")


def find_model_file(gender: str = "neutral", smpl_dir=None) -> Path:
    if gender not in GENDERS:
        raise ValueError(f"SMPL gender must be one of {GENDERS}, found {gender!r}")
    return _find(_model_file_names(gender), smpl_dir, f"{gender} model file")


def find_uv_file(smpl_dir=None) -> Path:
    return _find(list(UV_FILE_NAMES), smpl_dir, "UV layout file")


# ----- reading model files ----------------------------------------------------------------------
class _ChumpyStandIn:
    """Takes the place of chumpy's array classes while unpickling: keeps their state dict."""

    def __init__(self, *args, **kwargs) -> None:
        pass

    def __setstate__(self, state) -> None:
        if isinstance(state, dict):
            self.__dict__.update(state)
        else:
            self.__dict__["_state"] = state

    def value(self) -> np.ndarray:
        for key in ("x", "r", "a"):
            v = self.__dict__.get(key)
            if isinstance(v, np.ndarray):
                return v
            if isinstance(v, _ChumpyStandIn):
                return v.value()
        raise ValueError(f"a chumpy object without an array value (fields {sorted(self.__dict__)})")


_SPARSE_CLASSES = frozenset(f"{fmt}_{kind}" for fmt in ("csc", "csr", "coo", "bsr", "dia", "dok", "lil")
                            for kind in ("matrix", "array"))


class _ModelUnpickler(RestrictedUnpickler):
    """The plain-data unpickler of ``reconstruct.safe_pickle`` extended with what SMPL model pickles
    need: scipy.sparse matrix classes (any ``scipy.sparse.*`` module spelling, e.g. the official
    files' ``scipy.sparse.csc.csc_matrix``, resolved to the class in ``scipy.sparse``), chumpy's
    classes (become ``_ChumpyStandIn``), and ``copyreg._reconstructor`` / ``object`` with which
    Python 2 pickled those objects. Everything else is refused (``RefusedGlobalError``)."""

    allowed = "only numpy, scipy.sparse or chumpy data (an SMPL model's arrays)"

    def resolve(self, module: str, name: str):
        if module.split(".")[0] == "chumpy":
            return _ChumpyStandIn
        if (module, name) == ("copyreg", "_reconstructor"):
            return copyreg._reconstructor
        if (module, name) == ("builtins", "object"):
            return object
        if (module == "scipy.sparse" or module.startswith("scipy.sparse.")) and name in _SPARSE_CLASSES:
            import scipy.sparse

            cls = getattr(scipy.sparse, name, None)
            return cls if isinstance(cls, type) else None
        return super().resolve(module, name)


def _to_array(value, key: str, path: Path) -> np.ndarray:
    if isinstance(value, _ChumpyStandIn):
        try:
            value = value.value()
        except ValueError as exc:
            raise SMPLFilesError(f"{path}: {key!r}: {exc}") from exc
    if hasattr(value, "toarray"):  # scipy.sparse (J_regressor in the official files)
        value = value.toarray()
    return np.asarray(value)


def load_model_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of an SMPL model file (.pkl, chumpy or not, or .npz), checked for shape."""
    path = Path(path)
    if not path.is_file():
        raise SMPLFilesError(f"{path}: no such SMPL model file")
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                raw = {k: z[k] for k in z.files}
        else:
            raw = restricted_loads(path.read_bytes(), source=path, unpickler=_ModelUnpickler,
                                   what="a pickled SMPL model (a dict of arrays)")
    except SafeLoadError as exc:
        raise SMPLFilesError(f"{exc} (reading an SMPL model file)") from exc
    except (ValueError, EOFError, OSError) as exc:
        raise SMPLFilesError(f"{path}: cannot be read as an SMPL model file: {exc}") from exc
    if not isinstance(raw, dict):
        raise SMPLFilesError(f"{path}: expected a dict of arrays, found {type(raw).__name__}")
    missing = [k for k in REQUIRED_KEYS if k not in raw]
    if missing:
        raise SMPLFilesError(f"{path}: missing arrays {missing}; found keys {sorted(raw)}")
    arrays = {k: _to_array(raw[k], k, path) for k in REQUIRED_KEYS + ("posedirs",) if k in raw}
    V = arrays["v_template"].shape[0]
    expect = {"v_template": (V, 3), "weights": (V, NUM_JOINTS), "kintree_table": (2, NUM_JOINTS),
              "J_regressor": (NUM_JOINTS, V)}
    for k, shape in expect.items():
        if arrays[k].shape != shape:
            raise SMPLFilesError(f"{path}: {k!r} has shape {arrays[k].shape}, expected {shape} for an SMPL model "
                                 f"with {V} vertices and {NUM_JOINTS} joints")
    f = arrays["f"]
    if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= V:
        raise SMPLFilesError(f"{path}: 'f' must be (F, 3) vertex indices below {V}, found shape {f.shape}")
    sd = arrays["shapedirs"]
    if sd.ndim != 3 or sd.shape[:2] != (V, 3):
        raise SMPLFilesError(f"{path}: 'shapedirs' has shape {sd.shape}, expected ({V}, 3, B)")
    out = {k: v.astype(np.float64) for k, v in arrays.items() if k not in ("f", "kintree_table")}
    out["f"] = f.astype(np.int64)
    parents = arrays["kintree_table"][0].astype(np.int64)
    parents[0] = -1  # stored as 2**32 - 1 in the official files
    if np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, NUM_JOINTS)):
        raise SMPLFilesError(f"{path}: 'kintree_table' parents {parents.tolist()} are not a tree in joint order")
    out["parents"] = parents
    return out


def read_uv_obj(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``vt`` (T,2), vertex faces (F,3), UV faces (F,3) and the vertex count of an .obj file."""
    path = Path(path)
    vt, faces, face_uv, nv = [], [], [], 0
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SMPLFilesError(f"{path}: cannot be read as an .obj file: {exc}") from exc
    for lineno, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            nv += 1
        elif parts[0] == "vt":
            vt.append((float(parts[1]), float(parts[2])))
        elif parts[0] == "f":
            corners = parts[1:]
            if any("/" not in c for c in corners) or len(corners) < 3:
                raise SMPLFilesError(f"{path}:{lineno}: face {line.strip()!r} has no UV indices (expected a/ta b/tb c/tc)")
            idx = [(int(c.split("/")[0]) - 1, int(c.split("/")[1]) - 1) for c in corners]
            for k in range(1, len(idx) - 1):  # fan-triangulate polygons
                tri = (idx[0], idx[k], idx[k + 1])
                faces.append([t[0] for t in tri])
                face_uv.append([t[1] for t in tri])
    if not vt or not faces:
        raise SMPLFilesError(f"{path}: expected 'vt' and 'f a/ta b/tb c/tc' lines, found {len(vt)} vt and {len(faces)} faces")
    return np.asarray(vt, np.float64), np.asarray(faces, np.int64), np.asarray(face_uv, np.int64), nv


# ----- poses ------------------------------------------------------------------------------------
def _rotvec(matrix: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(matrix).as_rotvec()


def _rotmat(rotvec) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(rotvec, np.float64).reshape(3)).as_matrix()


def smpl_body_pose(full_pose, transl=None, Rh=None) -> BodyPose:
    """A BodyPose for the SMPL backend from SMPL parameters.

    ``full_pose`` (72,): SMPL's axis-angles, root first (smplx: ``[global_orient, body_pose]``).
    The posed body in the dataset's world is ``R(Rh) @ SMPL(full_pose) + transl``; without ``Rh``
    (smplx/InstantAvatar/GaussianAvatar) that is smplx's ``SMPL(global_orient, body_pose) + transl``,
    with it (EasyMocap/ZJU-MoCap: ``Rh``, ``Th``) the rotation is about the world origin, applied
    after SMPL's own pose.
    """
    full_pose = np.asarray(full_pose, np.float64).reshape(-1)
    if full_pose.shape[0] != 3 * NUM_JOINTS:
        raise ValueError(f"SMPL pose: expected {3 * NUM_JOINTS} values (24 joints x 3), found {full_pose.shape[0]}")
    rot = np.eye(3) if Rh is None else _rotmat(Rh)
    joint_rotations = full_pose.reshape(NUM_JOINTS, 3) @ SMPL_TO_BODY.T
    glob = _rotvec(rot @ SMPL_TO_BODY.T)
    return BodyPose(joint_rotations, glob, np.zeros(3) if transl is None else np.asarray(transl, np.float64).reshape(3))


def body_frame(pose: BodyPose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Approximate centre, up and front directions in the world of an SMPL ``BodyPose`` (from its
    root rotation and the nominal pelvis; no model files needed)."""
    G = _rotmat(pose.global_orient)
    R0 = _rotmat(pose.joint_rotations[0])
    centre = G @ (SMPL_TO_BODY @ NOMINAL_PELVIS_SMPL) + pose.transl
    up = G @ R0 @ np.array([0.0, 0.0, 1.0])
    front = G @ R0 @ np.array([0.0, -1.0, 0.0])
    return centre, up, front


# ----- the body model -----------------------------------------------------------------------------
class SMPLBody(BodyModel):
    """SMPL with a fixed shape (``betas``), in the project's body axes (Z up, facing -Y)."""

    name = "smpl"

    def __init__(self, arrays: dict[str, np.ndarray], uv: tuple[np.ndarray, np.ndarray, np.ndarray, int],
                 betas=(), *, gender: str = "neutral", leg_spread_deg: float = 15.0, arm_down_deg: float = 45.0,
                 source: str = "", uv_source: str = "") -> None:
        self.gender = gender
        self.source, self.uv_source = source, uv_source
        self.leg_spread_deg, self.arm_down_deg = float(leg_spread_deg), float(arm_down_deg)
        V = arrays["v_template"].shape[0]
        sd = arrays["shapedirs"]
        betas = np.asarray(betas, np.float64).reshape(-1)
        if betas.shape[0] > sd.shape[2]:
            if np.any(betas[sd.shape[2]:] != 0):
                raise ValueError(f"SMPL shape: {betas.shape[0]} betas given, the model {source} has {sd.shape[2]} shape components")
            betas = betas[: sd.shape[2]]
        self.betas = betas
        v_shaped = arrays["v_template"] + sd[:, :, : betas.shape[0]] @ betas
        joints = arrays["J_regressor"] @ v_shaped
        C = SMPL_TO_BODY
        self.rest_vertices = torch.as_tensor(v_shaped @ C.T, dtype=torch.float64)
        self.rest_joints = torch.as_tensor(joints @ C.T, dtype=torch.float64)
        self.bone_labels = list(BONE_LABELS)
        self.joint_names = list(SMPL_JOINT_NAMES)
        self.bone_parents = arrays["parents"].copy()
        w = np.clip(arrays["weights"], 0.0, None)
        self.skin_weights = torch.as_tensor(w / w.sum(1, keepdims=True), dtype=torch.float64)
        vt, faces, face_uv, nv = uv
        if nv and nv != V:
            raise SMPLFilesError(f"{uv_source}: the UV file has {nv} vertices, the SMPL model {source} has {V}")
        if faces.max() >= V or face_uv.max() >= len(vt) or faces.min() < 0 or face_uv.min() < 0:
            raise SMPLFilesError(f"{uv_source}: face indices out of range ({V} vertices, {len(vt)} UV coordinates)")
        self.faces = torch.as_tensor(faces, dtype=torch.long)
        self.uv_coords = torch.as_tensor(vt, dtype=torch.float64)
        self.face_uv_indices = torch.as_tensor(face_uv, dtype=torch.long)
        self._rel = (self.rest_joints - torch.cat([torch.zeros(1, 3, dtype=torch.float64),
                                                   self.rest_joints[self.bone_parents[1:]]], 0))

    def rest_to_pose_transforms(self, joint_rotations: torch.Tensor) -> torch.Tensor:
        J = self.num_joints
        if tuple(joint_rotations.shape) != (J, 3):
            raise ValueError(f"SMPL pose: expected joint rotations of shape ({J}, 3), found {tuple(joint_rotations.shape)}")
        R = axis_angle_to_matrix(joint_rotations.to(torch.float64))
        rot, trans = [R[0]], [self.rest_joints[0]]
        for j in range(1, J):
            p = int(self.bone_parents[j])
            rot.append(rot[p] @ R[j])
            trans.append(rot[p] @ self._rel[j] + trans[p])
        Rg = torch.stack(rot)
        tg = torch.stack(trans) - (Rg @ self.rest_joints[..., None])[..., 0]
        top = torch.cat([Rg, tg[..., None]], -1)
        bottom = torch.zeros(J, 1, 4, dtype=torch.float64)
        bottom[..., 3] = 1.0
        return torch.cat([top, bottom], -2)

    def canonical_joint_rotations(self) -> np.ndarray:
        """Star/A-pose: legs apart by ``leg_spread_deg`` each, arms lowered ``arm_down_deg`` from SMPL's
        T-pose (rotations about SMPL's forward axis, expressed in body axes)."""
        r = np.zeros((NUM_JOINTS, 3))
        leg, arm = math.radians(self.leg_spread_deg), math.radians(self.arm_down_deg)
        r[1, 2], r[2, 2] = leg, -leg  # hips: feet outwards
        r[16, 2], r[17, 2] = -arm, arm  # shoulders: arms down
        return r @ SMPL_TO_BODY.T


def format_betas(betas) -> str:
    return ",".join(repr(float(b)) for b in np.asarray(betas, np.float64).reshape(-1))


def parse_betas(text: str) -> np.ndarray:
    return np.array([float(s) for s in str(text).split(",") if s.strip()], np.float64)


@lru_cache(maxsize=8)
def _load_files(model_path: str, mtime: float, uv_path: str, uv_mtime: float):
    return load_model_arrays(model_path), read_uv_obj(uv_path)


def build_smpl_body(params: dict) -> SMPLBody:
    """An SMPLBody from BodySpec params: gender, betas (text list), smpl_dir, leg_spread_deg, arm_down_deg."""
    params = dict(params)
    gender = str(params.pop("gender", "neutral"))
    betas = parse_betas(params.pop("betas", ""))
    smpl_dir = params.pop("smpl_dir", None)
    leg = float(params.pop("leg_spread_deg", 15.0))
    arm = float(params.pop("arm_down_deg", 45.0))
    if params:
        raise ValueError(f"unknown SMPL body parameters {sorted(params)}; known: gender, betas, smpl_dir, "
                         "leg_spread_deg, arm_down_deg")
    model = find_model_file(gender, smpl_dir)
    uv = find_uv_file(smpl_dir)
    arrays, uvdata = _load_files(str(model), model.stat().st_mtime, str(uv), uv.stat().st_mtime)
    return SMPLBody(arrays, uvdata, betas, gender=gender, leg_spread_deg=leg, arm_down_deg=arm,
                    source=str(model), uv_source=str(uv))
