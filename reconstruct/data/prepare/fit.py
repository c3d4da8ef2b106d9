"""Fit the body model's pose per frame and one pinhole camera to detected keypoints and silhouettes.

Unknowns: per frame the rotations of the bones mediapipe observes (``FIT_BONES``), a global
orientation and a translation; for the whole video the focal length (from a field-of-view guess and the
crop, ``CameraGuess``, with a prior), the camera's pitch and, with a ``ShapeBasis``, Anny's phenotype.
The camera stands at the world origin's front (-Y, looking +Y, Z up, like the synthetic scenes' training
camera) at a distance estimated from the torso's size in pixels; at the end the world is levelled
(``_level``) so the body stands upright on average.

Losses (all frames at once, Adam):
  keypoints   confidence-weighted robust reprojection error of the body's points for the landmarks
              (``keypoints.LANDMARK_TARGETS``), in units of the image height;
  directions  1 - cos between the body's limb directions in camera space and mediapipe's 3D world
              landmarks (they resolve part of the depth ambiguity of 2D keypoints);
  silhouette  1 - soft IoU between the body's alpha, splatted from points spread evenly over the posed
              surface as small Gaussians with the differentiable rasterizer at 128 px, and the person mask
              grown by one pixel (the splats reach that far beyond the mesh's edge); the focal length is
              held during this stage;
  prior       L2 on the bone rotations (heavier on spine and neck, on the off-axis parts of knees
              and elbows), a penalty on knees and elbows bending backwards; a limb bone whose far-end
              landmark an edge of the frame cuts off is held near its rest rotation (``w_cut``), and
              so is a wrist whose hand has no knuckle landmarks in the frame (``hands.py``);
  smoothness  squared second differences over time of rotations, orientation and translation;
  upright     where one view cannot tell depth (the body barely turns; the person barely moves), a
              prior that keeps the body's up axis vertical and the legs under the hips (no common
              forward/backward swing of both legs; for a static person no swing at all);
  shape       with a ``ShapeBasis`` the Anny phenotype is fitted jointly (linearised rest geometry,
              Gaussian prior around the base phenotype).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from ...body.base import BodyModel
from ...body.lbs import apply_points, blend
from ...body.pose import BodyPose, axis_angle_to_matrix, rigid
from ...camera import Camera
from .detector import Detections
from .keypoints import LANDMARK_NAMES, SEGMENTS, KeypointMap, require_bones
from .shape import ShapeBasis
from .silhouette import mesh_silhouette

FIT_BONES = ("spine03", "spine01", "neck01", "head", "upperarm01.L", "upperarm01.R", "lowerarm01.L",
             "lowerarm01.R", "wrist.L", "wrist.R", "upperleg01.L", "upperleg01.R", "lowerleg01.L",
             "lowerleg01.R")
# per-bone prior weight on (x, y, z) of the axis-angle (world-aligned: x is the hinge of knees/elbows)
# The thighs' turn about the vertical (z: about their own axis while they hang) weighs 40: a straight
# leg's keypoints do not see it, and at 1 it drifted to 0.4-1.0 rad on five of the seven photos of
# shared/real (a knee turned 58 degrees out on the grey-skirt photo), so that the photo's front of
# the thigh was fitted onto its side; at 40 it stays within 0.14 rad (docs/prepare.md)
_PRIOR = {"spine03": (40, 40, 40), "spine01": (40, 40, 40), "neck01": (2, 2, 2), "head": (2, 2, 2),
          "upperleg01.L": (1, 1, 40), "upperleg01.R": (1, 1, 40),
          "lowerarm01.L": (0.5, 4, 4), "lowerarm01.R": (0.5, 4, 4),
          "lowerleg01.L": (0.5, 4, 4), "lowerleg01.R": (0.5, 4, 4)}
# hinge direction: knees bend with +x, elbows with -x (see synthetic/motion.py)
_HINGE_SIGN = {"lowerleg01.L": 1.0, "lowerleg01.R": 1.0, "lowerarm01.L": -1.0, "lowerarm01.R": -1.0}
# the landmark at the far end of each limb bone: the bone is held straight in a frame whose edge cuts it off
_LIMB_ENDS = {"upperarm01.L": "left_elbow", "upperarm01.R": "right_elbow", "lowerarm01.L": "left_wrist",
              "lowerarm01.R": "right_wrist", "wrist.L": "left_index", "wrist.R": "right_index",
              "upperleg01.L": "left_knee", "upperleg01.R": "right_knee",
              "lowerleg01.L": "left_ankle", "lowerleg01.R": "right_ankle"}
# the knuckle landmarks that turn each hand (``keypoints.LANDMARK_TARGETS``)
_KNUCKLES = {"wrist.L": ("left_index", "left_pinky"), "wrist.R": ("right_index", "right_pinky")}
# a video frame whose hand has no knuckles is left to the smoothness term, not held, when a frame this
# close has them: held there, a hand found in every other frame would jump between its fitted turn and rest
HAND_GAP = 3


def _hand_unseen(vis: np.ndarray, gap: int = HAND_GAP) -> np.ndarray:
    """(T,) bool: frames whose hand has no knuckles ((T,K) visibility all 0) and no frame within ``gap``
    that has them."""
    seen = (np.asarray(vis) > 0).any(1)
    return ~binary_dilation(seen, iterations=gap) if gap > 0 else ~seen


CAMERA_NAME = "video"


@dataclass
class FitConfig:
    fov_y_deg: float = 50.0  # field-of-view guess for the focal length (refined with a prior)
    refine_focal: bool = True
    keypoint_iters: int = 300
    silhouette_iters: int = 60
    lr: float = 0.03
    silhouette_size: int = 128  # longer side of the silhouette images during the fit
    # pixels (at silhouette_size) the person mask is grown by for the silhouette term: the splatted
    # body reaches past the exact mesh silhouette by about 1 px at 128 px and 2 px at 256 (soft IoU
    # against the mesh silhouette grown by 0 / 1 / 2 / 3 px: 0.76 / 0.91 / 0.80 / 0.68 at 128, 0.77 /
    # 0.87 / 0.91 / 0.86 at 256; synthetic body, 4,000 samples). Fitting the body inside the outline
    # (256 px, grown by 1) was tried and not kept: docs/prepare.md, "The body inside the outline"
    mask_growth: int = 1
    splat_vertices: int = 4000  # surface points splatted for the silhouette
    w_keypoints: float = 1.0
    w_directions: float = 0.1
    w_silhouette: float = 0.1
    w_prior: float = 2e-4
    w_smooth: float = 0.3
    w_focal: float = 1e-3  # prior on log(focal / guess)
    min_visibility: float = 0.5  # landmarks below this confidence count as unseen in the reported error
    seed: int = 0
    threads: int = 1  # torch threads during the fit (its tensors are small: one thread is fastest)
    fit_shape: bool = True  # fit Anny's phenotype jointly with the poses
    w_shape: float = 2e-4  # prior on the phenotype offsets (in units of their prior std)
    w_upright: float = 1.0  # keeps the body's up axis vertical where depth is ambiguous
    w_legs: float = 0.2  # keeps the legs under the hips where depth is ambiguous
    # holds a limb bone at its rest rotation (a straight limb) in a frame whose edge cuts off the
    # landmark at its far end (``Detections.cut``): nothing but the priors sees it, and at
    # ``w_prior`` they let it drift. A photo cut at the knees with room above the head: the silhouette
    # bent a shin whose ankle was cut off sideways at the knee by 63 degrees (seen from the side, a
    # leg kicked back: lean -10.9 degrees, against +0.6 held). The spine's prior is 40 times
    # ``w_prior``; this is 50. (That thigh, its knee in view, also turned 105 degrees about its own
    # axis: the thighs' prior on that turn, ``_PRIOR``)
    w_cut: float = 0.01
    upright: str = "auto"  # auto (from how much the body turns and moves), on, off
    stature_m: float | None = None  # the person's height if known (else a population prior)
    w_pitch: float = 0.02  # prior toward a level camera (on the pitch in radians, squared)

    def __post_init__(self) -> None:
        if self.mask_growth < 0:
            raise ValueError(f"FitConfig: mask_growth must be >= 0 pixels, found {self.mask_growth}")


@dataclass
class CameraGuess:
    """Intrinsics guess for the fitted images: focal length and principal point in pixels (a crop of a
    larger frame moves the principal point off the image centre and scales the focal length)."""

    focal_px: float
    cx: float
    cy: float


@dataclass
class FitResult:
    poses: list[BodyPose]
    camera: Camera
    keypoint_px_error: np.ndarray  # (T,) mean pixel error of the visible landmarks
    iou: np.ndarray  # (T,) IoU of the fitted body's silhouette with the person mask
    fit_masks: np.ndarray  # (T,H,W) bool fitted silhouettes
    focal_guess: float
    seconds: float
    history: dict = field(default_factory=dict)
    phenotype: dict | None = None  # fitted Anny phenotype (None: the body was kept)
    depth_ambiguity: dict = field(default_factory=dict)  # how strongly the upright prior was applied


def camera_rotation() -> np.ndarray:
    """World-to-camera rotation of a camera on -Y looking at +Y with Z up (OpenCV axes)."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


class _Kinematics:
    """Rest -> pose transforms (T,J,4,4) when only ``bones`` rotate, fast.

    With every other bone at zero rotation, each bone's transform is T_c = E_a T0_c: T0 the transforms
    of the zero pose, a the nearest rotated bone among c and its ancestors, and E_a = E_b [D_a about
    q_a] the chained rotations D (world-aligned axis-angle) of the rotated ancestors about their heads
    q in the zero pose. This is checked against the body model's own transforms at construction; a body
    for which it does not hold uses ``rest_to_pose_transforms`` frame by frame."""

    def __init__(self, body: BodyModel, bones: tuple[str, ...]) -> None:
        self.body = body
        J = body.num_joints
        par = np.asarray(body.bone_parents)
        self.ids = [body.bone_labels.index(b) for b in bones]
        fitted = set(self.ids)
        self.order = sorted(range(len(self.ids)), key=lambda k: _depth(par, self.ids[k]))

        def fitted_ancestor(c: int) -> int:
            while c >= 0 and c not in fitted:
                c = int(par[c])
            return c

        self.parent_slot = [self.ids.index(fitted_ancestor(int(par[i]))) if par[i] >= 0 and fitted_ancestor(int(par[i])) >= 0
                            else -1 for i in self.ids]
        anc = [fitted_ancestor(c) for c in range(J)]
        # slot 0 of the gathered stack is the identity
        self.gather = torch.as_tensor([0 if a < 0 else 1 + self.ids.index(a) for a in anc])
        with torch.no_grad():
            self.T0 = body.rest_to_pose_transforms(torch.zeros(J, 3, dtype=torch.float64))
            self.q = apply_points(self.T0, body.rest_joints)[self.ids]
            rng = torch.Generator().manual_seed(0)
            test = 0.4 * torch.randn(1, len(self.ids), 3, generator=rng, dtype=torch.float64)
            full = torch.zeros(J, 3, dtype=torch.float64)
            full[self.ids] = test[0]
            self.fast = bool((self._fast(test)[0] - body.rest_to_pose_transforms(full)).abs().max() < 1e-8)

    def _fast(self, rot: torch.Tensor, T0: torch.Tensor | None = None, q: torch.Tensor | None = None) -> torch.Tensor:
        T = rot.shape[0]
        T0 = self.T0 if T0 is None else T0
        q = self.q if q is None else q
        D = axis_angle_to_matrix(rot)  # (T,B,3,3)
        A = rigid(D, q - (D @ q[..., None])[..., 0])  # rotations about the zero-pose heads
        E: list[torch.Tensor | None] = [None] * len(self.ids)
        for k in self.order:
            p = self.parent_slot[k]
            E[k] = A[:, k] if p < 0 else E[p] @ A[:, k]
        eye = torch.eye(4, dtype=rot.dtype).expand(T, 1, 4, 4)
        stack = torch.cat([eye, torch.stack(E, dim=1)], dim=1)  # (T,1+B,4,4)
        return stack[:, self.gather] @ T0

    def with_rest(self, zero_pose: torch.Tensor, rest_joints: torch.Tensor):
        """(T0, q) for another rest geometry (zero-pose transforms (J,4,4), rest joints (J,3))."""
        return zero_pose, apply_points(zero_pose, rest_joints)[self.ids]

    def __call__(self, rot: torch.Tensor, rest=None) -> torch.Tensor:
        """rot (T,B,3) rotations of ``bones`` -> (T,J,4,4); ``rest`` = ``with_rest(...)`` for another shape."""
        if self.fast:
            return self._fast(rot) if rest is None else self._fast(rot, *rest)
        J = self.body.num_joints
        out = []
        for r in rot:
            full = torch.zeros(J, 3, dtype=rot.dtype).index_copy(0, torch.as_tensor(self.ids), r)
            out.append(self.body.rest_to_pose_transforms(full))
        return torch.stack(out)


def _depth(parents: np.ndarray, c: int) -> int:
    d = 0
    while parents[c] >= 0:
        c, d = int(parents[c]), d + 1
    return d


@dataclass
class SurfaceSamples:
    """Points spread evenly over the mesh surface (area-weighted), fixed in barycentric coordinates of
    their triangles so they follow any rest geometry and the skinning: corners (N,3) vertex ids,
    bary (N,3), and a splat scale (metres) that covers the surface without gaps."""

    corners: torch.Tensor
    bary: torch.Tensor
    spacing: float

    @classmethod
    def build(cls, body: BodyModel, count: int, seed: int) -> "SurfaceSamples":
        V = body.canonical_vertices.numpy()
        F = body.faces.numpy()
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        rng = np.random.default_rng(seed)
        f = rng.choice(len(F), size=count, p=area / area.sum())
        u, v = rng.random(count), rng.random(count)
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        bary = np.stack([1 - u - v, u, v], 1)
        spacing = float(np.sqrt(area.sum() / count))
        return cls(torch.as_tensor(F[f]), torch.as_tensor(bary), spacing)

    def weights(self, body: BodyModel) -> torch.Tensor:
        return (body.skin_weights[self.corners] * self.bary[..., None]).sum(1)

    def rest(self, vertices: torch.Tensor) -> torch.Tensor:
        """(N,3) rest positions from rest vertices (V,3)."""
        return (vertices[self.corners] * self.bary[..., None].to(vertices.dtype)).sum(1)


def _soft_iou(alpha: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    inter = (alpha * mask).sum()
    union = (alpha + mask - alpha * mask).sum().clamp_min(1e-6)
    return inter / union


def _downsample(mask: np.ndarray, width: int, height: int) -> torch.Tensor:
    m = torch.as_tensor(mask, dtype=torch.float32)[None, None]
    return torch.nn.functional.interpolate(m, size=(height, width), mode="area")[0, 0]


def _robust(r2: torch.Tensor, eps: float) -> torch.Tensor:
    return torch.sqrt(r2 + eps * eps) - eps


class _Problem:
    """The differentiable model: parameters -> keypoints, directions, vertices."""

    def __init__(self, body: BodyModel, det: Detections, config: FitConfig, shape: ShapeBasis | None = None,
                 guess: CameraGuess | None = None) -> None:
        self.body, self.det, self.cfg, self.shape = body, det, config, shape
        self.kmap = KeypointMap.build(body)
        require_bones(body, FIT_BONES)
        self.fit_ids = torch.as_tensor([body.bone_labels.index(b) for b in FIT_BONES])
        T = det.num_frames
        self.T = T
        self.width, self.height = det.width, det.height
        f64 = torch.float64
        self.R0 = torch.as_tensor(camera_rotation(), dtype=f64)
        if guess is None:
            self.f_guess = self.height / (2.0 * math.tan(math.radians(config.fov_y_deg) / 2.0))
            self.cx, self.cy = self.width / 2.0, self.height / 2.0
        else:
            self.f_guess, self.cx, self.cy = float(guess.focal_px), float(guess.cx), float(guess.cy)
        kp = torch.as_tensor(det.keypoints[:, self.kmap.landmark_ids], dtype=f64)  # (T,K,2)
        vis = torch.as_tensor(det.visibility[:, self.kmap.landmark_ids], dtype=f64).clamp(0, 1)
        self.kp, self.kp_w = kp, vis * torch.as_tensor(self.kmap.weights, dtype=f64)
        self.kin = _Kinematics(body, FIT_BONES)
        # start from the canonical pose (legs slightly apart); other bones stay at zero
        canon = body.canonical_joint_rotations()
        others = np.delete(canon, self.kin.ids, axis=0)
        if np.any(others):
            raise ValueError(f"body {body.name!r}: the canonical pose rotates bones the fit does not optimise")
        self.base_rot = torch.as_tensor(canon[self.kin.ids], dtype=f64)
        # segments for the direction loss, as (a, b) indices into the keypoint map
        self.segments = [(self.kmap.index_of(a), self.kmap.index_of(b)) for a, b in SEGMENTS]
        if det.world is not None:
            w = torch.as_tensor(det.world[:, self.kmap.landmark_ids], dtype=f64)
            a, b = zip(*self.segments)
            d = w[:, list(b)] - w[:, list(a)]
            self.world_dirs = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)
            self.world_w = torch.minimum(vis[:, list(a)], vis[:, list(b)])
        else:
            self.world_dirs = None
        prior = torch.ones(len(FIT_BONES), 3, dtype=f64)
        for i, name in enumerate(FIT_BONES):
            if name in _PRIOR:
                prior[i] = torch.as_tensor(_PRIOR[name], dtype=f64)
        self.prior_w = prior
        self.hinge = [(FIT_BONES.index(n), s) for n, s in _HINGE_SIGN.items()]
        self.legs = [FIT_BONES.index(n) for n in ("upperleg01.L", "upperleg01.R")]
        self.shins = [FIT_BONES.index(n) for n in ("lowerleg01.L", "lowerleg01.R")]
        # (T,B): the limb bones whose far-end landmark an edge of the frame cuts off, per frame
        # and the wrists of hands without knuckles in a frame (``hands.py`` found none it could take):
        # nothing but the silhouette sees them, and it turned a hand held at the head up into the hair
        held = np.zeros((T, len(FIT_BONES)))
        if det.cut is not None:
            for bone, landmark in _LIMB_ENDS.items():
                held[:, FIT_BONES.index(bone)] = det.cut[:, LANDMARK_NAMES.index(landmark)]
        for bone, knuckles in _KNUCKLES.items():
            held[:, FIT_BONES.index(bone)] = np.maximum(held[:, FIT_BONES.index(bone)], _hand_unseen(
                det.visibility[:, [LANDMARK_NAMES.index(n) for n in knuckles]]))
        self.held = torch.as_tensor(held, dtype=f64) if np.any(held) else None
        if shape is not None:
            if not self.kin.fast:
                raise ValueError(f"body {body.name!r}: fitting the shape needs the fast kinematics")
            self.z = torch.zeros(len(shape.keys), dtype=f64, requires_grad=True)
        else:
            self.z = None
        self._init_params()
        self.ambiguity = depth_ambiguity(det, self.orient.detach().numpy()[:, 2], config.upright)

    # ----- initial guess -----------------------------------------------------------------------
    def _init_params(self) -> None:
        det, f = self.det, self.f_guess
        T = self.T
        km = self.kmap
        rest_pts = km.points(self.kin(self.base_rot[None]))[0]
        ls, rs, lh, rh = (km.index_of(n) for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip"))
        torso3d = float((0.5 * (rest_pts[ls] + rest_pts[rs]) - 0.5 * (rest_pts[lh] + rest_pts[rh])).norm())
        kp = self.kp.numpy()
        torso_px = np.linalg.norm(0.5 * (kp[:, ls] + kp[:, rs]) - 0.5 * (kp[:, lh] + kp[:, rh]), axis=1)
        depth = f * torso3d / max(float(np.median(torso_px)), 1.0)
        self.depth0 = depth
        self.t0 = torch.as_tensor([0.0, 0.0, depth], dtype=torch.float64)  # camera at (0, -depth, 0)
        # yaw from mediapipe's 3D shoulders and hips (camera-aligned axes), else facing the camera
        yaw = np.zeros(T)
        if det.world is not None:
            w = det.world
            L = det.landmark_index
            across = (w[:, L("left_shoulder")] - w[:, L("right_shoulder")]) + (w[:, L("left_hip")] - w[:, L("right_hip")])
            yaw = np.unwrap(np.arctan2(across[:, 2], across[:, 0]))
        pelvis_rest = 0.5 * (rest_pts[lh] + rest_pts[rh]).numpy()
        mid = 0.5 * (kp[:, lh] + kp[:, rh])
        x = (mid[:, 0] - self.cx) / f * depth
        y = (mid[:, 1] - self.cy) / f * depth
        transl = np.stack([x, np.zeros(T), -y], axis=1) - pelvis_rest[None]
        f64 = torch.float64
        self.rot = torch.zeros(T, len(FIT_BONES), 3, dtype=f64, requires_grad=True)
        self.orient = torch.as_tensor(np.stack([np.zeros(T), np.zeros(T), yaw], 1), dtype=f64).requires_grad_(True)
        self.transl = torch.as_tensor(transl, dtype=f64).requires_grad_(True)
        self.log_focal = torch.zeros((), dtype=f64, requires_grad=True)
        # the camera's pitch (looking up or down at the person): without it a photo taken from above can
        # only be explained by tilting the body, which the upright prior then fights
        self.pitch = torch.zeros((), dtype=f64, requires_grad=True)

    # ----- forward -----------------------------------------------------------------------------
    @property
    def focal(self) -> torch.Tensor:
        return self.f_guess * torch.exp(self.log_focal)

    def fitted_rotations(self) -> torch.Tensor:
        return self.base_rot + self.rot

    def rest(self):
        """(kinematics rest, keypoint rest points) for the current shape, or (None, None) for the body's."""
        if self.z is None:
            return None, None
        joints, zero = self.shape.joints(self.z), self.shape.zero_pose(self.z)
        verts = self.shape.vertices(self.z)
        return self.kin.with_rest(zero, joints), self.kmap.rest_points(joints, verts)

    def rest_vertices(self, ids: torch.Tensor | None = None) -> torch.Tensor:
        if self.z is None:
            return self.body.rest_vertices if ids is None else self.body.rest_vertices[ids]
        return self.shape.vertices(self.z, ids)

    def full_rotations(self) -> torch.Tensor:
        full = torch.zeros(self.T, self.body.num_joints, 3, dtype=torch.float64)
        return full.index_copy(1, self.fit_ids, self.fitted_rotations())

    def transforms(self, rest=None) -> torch.Tensor:
        G = rigid(axis_angle_to_matrix(self.orient), self.transl)  # (T,4,4)
        return G[:, None] @ self.kin(self.fitted_rotations(), rest)

    def rotation(self) -> torch.Tensor:
        """World-to-camera rotation: the level camera ``R0`` pitched about the world's X axis."""
        c, s = torch.cos(self.pitch), torch.sin(self.pitch)
        one, zero = torch.ones_like(c), torch.zeros_like(c)
        Rx = torch.stack([torch.stack([one, zero, zero]), torch.stack([zero, c, -s]), torch.stack([zero, s, c])])
        return self.R0 @ Rx

    def to_camera(self, pts: torch.Tensor) -> torch.Tensor:
        return pts @ self.rotation().T + self.t0

    def project(self, pc: torch.Tensor, focal: torch.Tensor) -> torch.Tensor:
        z = pc[..., 2:3].clamp_min(1e-3)
        return torch.cat([focal * pc[..., 0:1] / z + self.cx, focal * pc[..., 1:2] / z + self.cy], dim=-1)

    def camera(self, width: int | None = None, height: int | None = None) -> Camera:
        f = float(self.focal.detach())
        K = np.array([[f, 0.0, self.cx], [0.0, f, self.cy], [0.0, 0.0, 1.0]])
        cam = Camera(K, self.rotation().detach().numpy(), self.t0.numpy().copy(), self.width, self.height,
                     name=CAMERA_NAME)
        return cam if width is None else cam.scaled(width, height)

    def poses(self) -> list[BodyPose]:
        full = self.full_rotations().detach().numpy()
        o, t = self.orient.detach().numpy(), self.transl.detach().numpy()
        return [BodyPose(full[i], o[i], t[i]) for i in range(self.T)]


def _second_diff(x: torch.Tensor) -> torch.Tensor:
    if x.shape[0] < 3:
        return x.new_zeros(())
    d = x[2:] - 2 * x[1:-1] + x[:-2]
    return (d * d).sum(dim=tuple(range(1, d.ndim))).mean()


def depth_ambiguity(det: Detections, yaw: np.ndarray, mode: str = "auto") -> dict:
    """How little the frames tell about depth: ``turn`` in [0, 1] is 1 when the body turns less than
    15 degrees over the clip (0 beyond 45: side views show a lean), ``static`` in [0, 1] is 1 when the
    keypoints barely move relative to the hips (a single image, a person standing still: 1)."""
    if mode not in ("auto", "on", "off"):
        raise ValueError(f"upright prior: expected auto, on or off, found {mode!r}")
    if mode != "auto":
        v = 1.0 if mode == "on" else 0.0
        return {"turn": v, "static": v, "yaw_range_deg": float("nan"), "motion": float("nan"), "mode": mode}
    yaw_range = float(np.degrees(np.ptp(yaw))) if len(yaw) > 1 else 0.0
    turn = float(np.clip(1.0 - (yaw_range - 15.0) / 30.0, 0.0, 1.0))
    L = det.landmark_index
    kp, vis = det.keypoints, det.visibility
    hips = 0.5 * (kp[:, L("left_hip")] + kp[:, L("right_hip")])
    sh = 0.5 * (kp[:, L("left_shoulder")] + kp[:, L("right_shoulder")])
    torso = max(float(np.median(np.linalg.norm(sh - hips, axis=1))), 1.0)
    motion = 0.0
    if len(kp) > 1:
        ids = [L(n) for n in ("left_wrist", "right_wrist", "left_knee", "right_knee", "left_ankle", "right_ankle")]
        rel = (kp[:, ids] - hips[:, None]) / torso
        seen = vis[:, ids] >= 0.5
        stds = [float(rel[seen[:, k], k].std(0).max()) for k in range(len(ids)) if seen[:, k].sum() > 1]
        motion = float(np.median(stds)) if stds else 0.0
    static = float(np.clip(1.0 - (motion - 0.05) / 0.15, 0.0, 1.0))
    return {"turn": turn, "static": static, "yaw_range_deg": yaw_range, "motion": motion, "mode": mode}


def _silhouette_grads(Tr: torch.Tensor, rv: torch.Tensor, frame_loss, weight: float):
    """(the sum over frames of ``frame_loss(i, Tr[i], rv)``, [(tensor, gradient)]): ``weight`` x that
    sum back-propagated one frame at a time into detached copies of ``Tr`` (T,J,4,4) and ``rv`` (N,3),
    paired with the tensors themselves for the caller's one backward through what they depend on.
    Each frame's render graph is freed after its own backward; held together until one backward, the
    frames' graphs grew with the clip (about 1 MB a frame at 128 px: prepare's peak on a 600-frame clip
    went from 6.59 to 6.00 GB)."""
    Tr_d = Tr.detach().requires_grad_(Tr.requires_grad)
    rv_d = rv.detach().requires_grad_(rv.requires_grad)
    total = 0.0
    for i in range(Tr.shape[0]):
        li = frame_loss(i, Tr_d[i], rv_d)
        if li.requires_grad:
            (weight * li).backward()
        total += float(li.detach())
    return total, [(t, d.grad) for t, d in ((Tr, Tr_d), (rv, rv_d)) if t.requires_grad and d.grad is not None]


def render_alpha(weights: torch.Tensor, rest: torch.Tensor, transforms: torch.Tensor, camera: Camera,
                 sigma: float, *, dtype=torch.float32, eps2d: float = 0.05, opacity: float = 0.95) -> torch.Tensor:
    """Differentiable alpha (H,W) of the posed body: surface points (skinning ``weights`` (N,J), ``rest``
    positions (N,3)) splatted as isotropic Gaussians of standard deviation ``sigma`` (metres), for one
    frame's transforms (J,4,4)."""
    from ...raster import rasterization

    M = blend(weights, transforms)
    means = apply_points(M, rest).to(dtype)
    N = means.shape[0]
    quats = torch.zeros(N, 4, dtype=dtype)
    quats[:, 0] = 1.0
    scales = torch.full((N, 3), sigma, dtype=dtype)
    opac = torch.full((N,), opacity, dtype=dtype)
    feats = torch.ones(N, 1, dtype=dtype)
    return rasterization(means, quats, scales, opac, feats, camera, eps2d=eps2d).alpha


def fit_poses(body: BodyModel, det: Detections, config: FitConfig = FitConfig(), *, shape: ShapeBasis | None = None,
              guess: CameraGuess | None = None, log=None, progress=None) -> FitResult:
    """Fit poses and camera (and, with ``shape``, Anny's phenotype) to the detections of the frames
    where a person was found. ``body`` is the body at ``shape``'s base phenotype. ``progress``, if
    given, is called as progress(stage, done, total) after each step of the keypoint fit
    ("keypoints") and of the silhouette fit ("silhouette")."""
    threads = torch.get_num_threads()
    torch.set_num_threads(max(1, config.threads))
    try:
        return _fit(body, det, config, shape if config.fit_shape else None, guess, log, progress)
    finally:
        torch.set_num_threads(threads)


def _up_axis(orient: torch.Tensor) -> torch.Tensor:
    return axis_angle_to_matrix(orient)[..., :, 2]  # (T,3) the body's +Z in the world


def _fit(body: BodyModel, det: Detections, config: FitConfig, shape: ShapeBasis | None, guess: CameraGuess | None,
         log, progress=None) -> FitResult:
    t_start = time.perf_counter()
    torch.manual_seed(config.seed)
    P = _Problem(body, det, config, shape, guess)
    H, W = det.height, det.width
    diag = float(H)
    hist: dict[str, list] = {"loss": []}
    amb = P.ambiguity

    def keypoint_terms(Tr: torch.Tensor, focal: torch.Tensor, kp_rest) -> torch.Tensor:
        pts = P.kmap.points(Tr, kp_rest)  # (T,K,3) world
        pc = P.to_camera(pts)
        uv = P.project(pc, focal)
        r2 = ((uv - P.kp) / diag).pow(2).sum(-1)
        loss = (P.kp_w * _robust(r2, 0.01)).sum() / P.kp_w.sum().clamp_min(1e-9)
        if P.world_dirs is not None and config.w_directions > 0:
            a, b = zip(*P.segments)
            d = pc[:, list(b)] - pc[:, list(a)]
            d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)
            cos = (d * P.world_dirs).sum(-1)
            loss = loss + config.w_directions * (P.world_w * (1 - cos)).sum() / P.world_w.sum().clamp_min(1e-9)
        return loss

    def regularisers() -> torch.Tensor:
        rot = P.rot
        prior = (P.prior_w * rot * rot).sum(dim=(1, 2)).mean()
        for i, sign in P.hinge:
            prior = prior + 10.0 * torch.relu(-sign * rot[:, i, 0]).pow(2).mean()
        smooth = _second_diff(rot) + _second_diff(P.orient) + 10.0 * _second_diff(P.transl)
        focal = (P.log_focal ** 2)
        total = config.w_prior * prior + config.w_smooth * smooth + config.w_focal * focal + config.w_pitch * P.pitch ** 2
        # gravity is never seen directly: a camera looking down and a body leaning forward look alike from
        # the front. The camera gets a prior toward level, the body toward upright (fully where the body
        # barely turns; a tenth of that where turning shows a lean from the side)
        tilt = (1.0 - _up_axis(P.orient)[:, 2]).mean()
        total = total + config.w_upright * max(0.1, amb["turn"]) * tilt
        if amb["turn"] > 0:
            # upright: the body's up axis stays vertical; legs: no common sagittal swing of both legs
            # (that is a lean seen from the side), and for a static person no swing at all
            swing = P.fitted_rotations()[:, P.legs, 0]
            knee = rot[:, P.shins, 0]
            common = swing.mean(1).pow(2).mean() + 0.5 * knee.mean(1).pow(2).mean()
            spine = rot[:, :2, 0].pow(2).mean()
            # (knees are left out here: they bend one way only, so their 2D shortening tells the bend)
            diff = (swing[:, 0] - swing[:, 1]).pow(2).mean()
            total = total + amb["turn"] * (config.w_legs * (common + spine)
                                           + config.w_legs * amb["static"] * diff)
        if P.held is not None and config.w_cut > 0:
            total = total + config.w_cut * (P.held[:, :, None] * rot * rot).sum(dim=(1, 2)).mean()
        if P.z is not None:
            total = total + config.w_shape * P.shape.prior(P.z)
        return total

    params = [P.rot, P.orient, P.transl]
    groups = [{"params": params, "lr": config.lr}, {"params": [P.log_focal, P.pitch], "lr": 0.01}]
    if P.z is not None:
        groups.append({"params": [P.z], "lr": 0.01})
    opt = torch.optim.Adam(groups)
    # stage 1: global motion only, then everything, on keypoints
    for it in range(config.keypoint_iters):
        if progress is not None and it % 10 == 0:
            progress("keypoints", it, config.keypoint_iters)
        opt.zero_grad()
        warm = it < config.keypoint_iters // 5
        kin_rest, kp_rest = P.rest()
        Tr = P.transforms(kin_rest)
        loss = keypoint_terms(Tr, P.focal if config.refine_focal else P.focal.detach(), kp_rest) + regularisers()
        loss.backward()
        if warm:
            P.rot.grad = None
            P.log_focal.grad = None
            if P.z is not None:
                P.z.grad = None
        if not config.refine_focal:
            P.log_focal.grad = None
        opt.step()
        hist["loss"].append(float(loss.detach()))
    # stage 2: add the silhouette
    if config.silhouette_iters > 0 and config.w_silhouette > 0:
        scale = config.silhouette_size / max(W, H)
        sw, sh = max(8, round(W * scale)), max(8, round(H * scale))
        # the splatted alpha reaches past the mesh's edge: compare it with the mask grown (``mask_growth``)
        g = config.mask_growth
        targets = [torch.nn.functional.max_pool2d(_downsample(m, sw, sh)[None, None], 2 * g + 1, 1, g)[0, 0]
                   for m in det.masks]
        samples = SurfaceSamples.build(body, config.splat_vertices, config.seed)
        sw_weights = samples.weights(body)
        sigma = 0.5 * samples.spacing
        for it in range(config.silhouette_iters):
            if progress is not None:
                progress("silhouette", it, config.silhouette_iters)
            opt.zero_grad()
            focal = P.focal.detach()  # the silhouette must not trade the body's size for the focal length
            kin_rest, kp_rest = P.rest()
            Tr = P.transforms(kin_rest)
            loss = keypoint_terms(Tr, focal, kp_rest) + regularisers()
            cam = P.camera(sw, sh)
            rv = samples.rest(P.rest_vertices())
            sil, ends = _silhouette_grads(Tr, rv, lambda i, Tr_i, rv_: 1.0 - _soft_iou(
                render_alpha(sw_weights, rv_, Tr_i, cam, sigma), targets[i]), config.w_silhouette / P.T)
            # one walk of the graph upstream of the transforms and the rest points for both terms
            torch.autograd.backward([loss] + [t for t, _ in ends], [torch.ones_like(loss)] + [g for _, g in ends])
            opt.step()
            loss = loss.detach() + config.w_silhouette * sil / P.T
            hist["loss"].append(float(loss))
            if log is not None and (it + 1) % 20 == 0:
                log(f"silhouette step {it + 1}/{config.silhouette_iters}: loss {float(loss.detach()):.4f}")
    with torch.no_grad():
        hist["level_deg"] = _level(P, weight=0.0 if amb["mode"] == "off" else 1.0)
    # reported errors: keypoints in pixels, silhouette IoU at full resolution
    with torch.no_grad():
        kin_rest, kp_rest = P.rest()
        Tr = P.transforms(kin_rest)
        uv = P.project(P.to_camera(P.kmap.points(Tr, kp_rest)), P.focal).numpy()
        err = np.linalg.norm(uv - P.kp.numpy(), axis=-1)  # (T,K)
        seen = det.visibility[:, P.kmap.landmark_ids] >= config.min_visibility
        px = np.array([err[i][seen[i]].mean() if seen[i].any() else float("nan") for i in range(P.T)])
        cam = P.camera()
        faces = body.faces.numpy()
        rest_v = P.rest_vertices()
        fit_masks, ious = [], []
        for i in range(P.T):
            verts = apply_points(blend(body.skin_weights, Tr[i]), rest_v).numpy()
            a = mesh_silhouette(verts, faces, cam)
            m = det.masks[i] > 0.5
            union = (a | m).sum()
            ious.append(float((a & m).sum() / union) if union else 0.0)
            fit_masks.append(a)
    phenotype = None if P.z is None else P.shape.phenotype(P.z)
    return FitResult(P.poses(), P.camera(), px, np.asarray(ious), np.stack(fit_masks), P.f_guess,
                     time.perf_counter() - t_start, hist, phenotype, amb)


def _level(P: _Problem, weight: float) -> float:
    """Stand the body up where one view cannot tell depth: rotate the fitted world about the camera's
    centre (about the world's X axis) so the mean line from the feet to the head is vertical, and turn the
    camera's pitch by as much. The images are unchanged by construction (the camera sees the same thing);
    only what is vertical changes: a camera looking down at an upright person instead of a level camera
    and a leaning person, which a keypoint fit cannot tell apart and Adam does not settle along its flat
    valley. Measured on the synthetic walk (true lean 0.0-0.5 degrees, camera 4 degrees down): with true
    keypoints the fit ends with the camera 9 degrees up and the body leaning 10 degrees, so even a turning
    clip does not pin gravity down; only the mean over the clip is levelled, a lean that changes over the
    clip keeps its changes. ``weight`` 0 (``--upright off``) keeps the fit as it is. Returns the rotation in
    degrees."""
    if weight <= 0:
        return 0.0
    kin_rest, _ = P.rest()
    Tr = P.transforms(kin_rest)
    rest = P.rest_vertices()
    z = rest[:, 2]
    h = float(z.max() - z.min())
    head = torch.nonzero(z > z.max() - 0.12 * h)[:, 0]
    feet = torch.nonzero(z < z.min() + 0.08 * h)[:, 0]
    W = P.body.skin_weights

    def centre(ids):
        return apply_points(blend(W[ids], Tr), rest[ids]).mean(-2)  # (T,3)

    d = centre(head) - centre(feet)
    alpha = weight * float(torch.atan2(d[:, 1], d[:, 2]).mean())
    c, s_ = math.cos(alpha), math.sin(alpha)
    Q = torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s_], [0.0, s_, c]], dtype=torch.float64)
    R = P.rotation()
    centre_cam = -(R.T @ P.t0)
    # bodies: x' = Q (x - c) + c  ->  orient' = Q R_o, transl' = Q (transl - c) + c
    Ro = axis_angle_to_matrix(P.orient)
    from scipy.spatial.transform import Rotation

    new_orient = Rotation.from_matrix((Q @ Ro).numpy()).as_rotvec()
    P.orient.copy_(torch.as_tensor(new_orient))
    P.transl.copy_((P.transl - centre_cam) @ Q.T + centre_cam)
    # camera: R' = R Q^T (the pitch turns by -alpha), same centre
    P.pitch.sub_(alpha)
    P.t0 = -(P.rotation() @ centre_cam)
    return math.degrees(alpha)


def measure_fit(body: BodyModel, poses: list[BodyPose], camera: Camera, det: Detections) -> tuple[np.ndarray, np.ndarray]:
    """(IoU (T,), fitted silhouettes (T,H,W)) of ``body`` in ``poses`` seen by ``camera`` vs. the masks."""
    faces = body.faces.numpy()
    ious, sils = [], []
    with torch.no_grad():
        for pose, mask in zip(poses, det.masks):
            a = mesh_silhouette(body.posed_vertices(pose).numpy(), faces, camera)
            m = mask > 0.5
            union = (a | m).sum()
            ious.append(float((a & m).sum() / union) if union else 0.0)
            sils.append(a)
    return np.asarray(ious), np.stack(sils)
