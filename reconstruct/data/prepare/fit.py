"""Fit the body model's pose per frame and one pinhole camera to detected keypoints and silhouettes.

Unknowns: per frame the rotations of the bones mediapipe observes (``FIT_BONES``), a global
orientation and a translation; for the whole video the focal length (from a field-of-view guess,
refined once, with a prior). The camera stands at the world origin's front (-Y, looking +Y, Z up,
like the synthetic scenes' training camera) at a distance estimated from the torso's size in pixels.

Losses (all frames at once, Adam):
  keypoints   confidence-weighted robust reprojection error of the body's points for the landmarks
              (``keypoints.LANDMARK_TARGETS``), in units of the image height;
  directions  1 - cos between the body's limb directions in camera space and mediapipe's 3D world
              landmarks (they resolve part of the depth ambiguity of 2D keypoints);
  silhouette  1 - soft IoU between the body's alpha, splatted from a subset of posed mesh vertices as
              small Gaussians with the differentiable rasterizer at low resolution, and the person mask;
  prior       L2 on the bone rotations (heavier on spine and neck, on the off-axis parts of knees
              and elbows), a penalty on knees and elbows bending backwards;
  smoothness  squared second differences over time of rotations, orientation and translation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ...body.base import BodyModel
from ...body.lbs import apply_points, blend
from ...body.pose import BodyPose, axis_angle_to_matrix, rigid
from ...camera import Camera
from .detector import Detections
from .keypoints import SEGMENTS, KeypointMap
from .silhouette import mesh_silhouette

FIT_BONES = ("spine03", "spine01", "neck01", "head", "upperarm01.L", "upperarm01.R", "lowerarm01.L",
             "lowerarm01.R", "upperleg01.L", "upperleg01.R", "lowerleg01.L", "lowerleg01.R")
# per-bone prior weight on (x, y, z) of the axis-angle (world-aligned: x is the hinge of knees/elbows)
_PRIOR = {"spine03": (40, 40, 40), "spine01": (40, 40, 40), "neck01": (2, 2, 2), "head": (2, 2, 2),
          "lowerarm01.L": (0.5, 4, 4), "lowerarm01.R": (0.5, 4, 4),
          "lowerleg01.L": (0.5, 4, 4), "lowerleg01.R": (0.5, 4, 4)}
# hinge direction: knees bend with +x, elbows with -x (see synthetic/motion.py)
_HINGE_SIGN = {"lowerleg01.L": 1.0, "lowerleg01.R": 1.0, "lowerarm01.L": -1.0, "lowerarm01.R": -1.0}
CAMERA_NAME = "video"


@dataclass
class FitConfig:
    fov_y_deg: float = 50.0  # field-of-view guess for the focal length (refined with a prior)
    refine_focal: bool = True
    keypoint_iters: int = 300
    silhouette_iters: int = 30
    lr: float = 0.03
    silhouette_size: int = 64  # longer side of the silhouette images during the fit
    splat_vertices: int = 2500
    w_keypoints: float = 1.0
    w_directions: float = 0.1
    w_silhouette: float = 0.02
    w_prior: float = 2e-4
    w_smooth: float = 0.3
    w_focal: float = 1e-3  # prior on log(focal / guess)
    min_visibility: float = 0.5  # landmarks below this confidence count as unseen in the reported error
    seed: int = 0
    threads: int = 1  # torch threads during the fit (its tensors are small: one thread is fastest)


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

    def _fast(self, rot: torch.Tensor) -> torch.Tensor:
        T = rot.shape[0]
        D = axis_angle_to_matrix(rot)  # (T,B,3,3)
        A = rigid(D, self.q - (D @ self.q[..., None])[..., 0])  # rotations about the zero-pose heads
        E: list[torch.Tensor | None] = [None] * len(self.ids)
        for k in self.order:
            p = self.parent_slot[k]
            E[k] = A[:, k] if p < 0 else E[p] @ A[:, k]
        eye = torch.eye(4, dtype=rot.dtype).expand(T, 1, 4, 4)
        stack = torch.cat([eye, torch.stack(E, dim=1)], dim=1)  # (T,1+B,4,4)
        return stack[:, self.gather] @ self.T0

    def __call__(self, rot: torch.Tensor) -> torch.Tensor:
        """rot (T,B,3) rotations of ``bones`` -> (T,J,4,4)."""
        if self.fast:
            return self._fast(rot)
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


def _splat_subset(body: BodyModel, count: int, seed: int) -> tuple[torch.Tensor, float]:
    """Indices of ``count`` mesh vertices spread over the surface and a Gaussian scale that covers it."""
    V = body.canonical_vertices
    rng = np.random.default_rng(seed)
    idx = torch.as_tensor(np.sort(rng.choice(V.shape[0], size=min(count, V.shape[0]), replace=False)))
    pts = V[idx].float()
    d = torch.cdist(pts, pts)
    d.fill_diagonal_(float("inf"))
    spacing = float(d.min(1).values.median())
    return idx, spacing


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

    def __init__(self, body: BodyModel, det: Detections, config: FitConfig) -> None:
        self.body, self.det, self.cfg = body, det, config
        self.kmap = KeypointMap.build(body)
        self.fit_ids = torch.as_tensor([body.bone_labels.index(b) for b in FIT_BONES])
        T = det.num_frames
        self.T = T
        self.width, self.height = det.width, det.height
        f64 = torch.float64
        self.R0 = torch.as_tensor(camera_rotation(), dtype=f64)
        self.f_guess = self.height / (2.0 * math.tan(math.radians(config.fov_y_deg) / 2.0))
        self.cx, self.cy = self.width / 2.0, self.height / 2.0
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
        self._init_params()

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

    # ----- forward -----------------------------------------------------------------------------
    @property
    def focal(self) -> torch.Tensor:
        return self.f_guess * torch.exp(self.log_focal)

    def fitted_rotations(self) -> torch.Tensor:
        return self.base_rot + self.rot

    def full_rotations(self) -> torch.Tensor:
        full = torch.zeros(self.T, self.body.num_joints, 3, dtype=torch.float64)
        return full.index_copy(1, self.fit_ids, self.fitted_rotations())

    def transforms(self) -> torch.Tensor:
        G = rigid(axis_angle_to_matrix(self.orient), self.transl)  # (T,4,4)
        return G[:, None] @ self.kin(self.fitted_rotations())

    def to_camera(self, pts: torch.Tensor) -> torch.Tensor:
        return pts @ self.R0.T + self.t0

    def project(self, pc: torch.Tensor, focal: torch.Tensor) -> torch.Tensor:
        z = pc[..., 2:3].clamp_min(1e-3)
        return torch.cat([focal * pc[..., 0:1] / z + self.cx, focal * pc[..., 1:2] / z + self.cy], dim=-1)

    def camera(self, width: int | None = None, height: int | None = None) -> Camera:
        f = float(self.focal.detach())
        K = np.array([[f, 0.0, self.cx], [0.0, f, self.cy], [0.0, 0.0, 1.0]])
        cam = Camera(K, camera_rotation(), self.t0.numpy().copy(), self.width, self.height, name=CAMERA_NAME)
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


def render_alpha(body: BodyModel, transforms: torch.Tensor, camera: Camera, vertex_ids: torch.Tensor,
                 sigma: float, *, dtype=torch.float32) -> torch.Tensor:
    """Differentiable alpha (H,W) of the posed body: its vertices ``vertex_ids`` splatted as isotropic
    Gaussians of standard deviation ``sigma`` (metres), for one frame's transforms (J,4,4)."""
    from ...raster import rasterization

    M = blend(body.skin_weights[vertex_ids], transforms)
    means = apply_points(M, body.rest_vertices[vertex_ids]).to(dtype)
    N = means.shape[0]
    quats = torch.zeros(N, 4, dtype=dtype)
    quats[:, 0] = 1.0
    scales = torch.full((N, 3), sigma, dtype=dtype)
    opac = torch.full((N,), 0.95, dtype=dtype)
    feats = torch.ones(N, 1, dtype=dtype)
    return rasterization(means, quats, scales, opac, feats, camera).alpha


def fit_poses(body: BodyModel, det: Detections, config: FitConfig = FitConfig(), *,
              log=None) -> FitResult:
    """Fit poses and camera to the detections of the frames where a person was found."""
    threads = torch.get_num_threads()
    torch.set_num_threads(max(1, config.threads))
    try:
        return _fit(body, det, config, log)
    finally:
        torch.set_num_threads(threads)


def _fit(body: BodyModel, det: Detections, config: FitConfig, log) -> FitResult:
    t_start = time.perf_counter()
    torch.manual_seed(config.seed)
    P = _Problem(body, det, config)
    H, W = det.height, det.width
    diag = float(H)
    hist: dict[str, list] = {"loss": []}

    def keypoint_terms(Tr: torch.Tensor, focal: torch.Tensor) -> torch.Tensor:
        pts = P.kmap.points(Tr)  # (T,K,3) world
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
        return config.w_prior * prior + config.w_smooth * smooth + config.w_focal * focal

    params = [P.rot, P.orient, P.transl]
    opt = torch.optim.Adam([{"params": params, "lr": config.lr}, {"params": [P.log_focal], "lr": 0.01}])
    # stage 1: global motion only, then everything, on keypoints
    for it in range(config.keypoint_iters):
        opt.zero_grad()
        warm = it < config.keypoint_iters // 5
        Tr = P.transforms()
        loss = keypoint_terms(Tr, P.focal if config.refine_focal else P.focal.detach()) + regularisers()
        loss.backward()
        if warm:
            P.rot.grad = None
            P.log_focal.grad = None
        if not config.refine_focal:
            P.log_focal.grad = None
        opt.step()
        hist["loss"].append(float(loss.detach()))
    # stage 2: add the silhouette
    if config.silhouette_iters > 0 and config.w_silhouette > 0:
        scale = config.silhouette_size / max(W, H)
        sw, sh = max(8, round(W * scale)), max(8, round(H * scale))
        targets = [_downsample(m, sw, sh) for m in det.masks]
        vid, spacing = _splat_subset(body, config.splat_vertices, config.seed)
        sigma = 0.6 * spacing
        for it in range(config.silhouette_iters):
            opt.zero_grad()
            focal = P.focal if config.refine_focal else P.focal.detach()
            Tr = P.transforms()
            loss = keypoint_terms(Tr, focal) + regularisers()
            cam = P.camera(sw, sh)
            sil = 0.0
            for i in range(P.T):
                alpha = render_alpha(body, Tr[i], cam, vid, sigma)
                sil = sil + (1.0 - _soft_iou(alpha, targets[i]))
            loss = loss + config.w_silhouette * sil / P.T
            loss.backward()
            opt.step()
            hist["loss"].append(float(loss.detach()))
            if log is not None and (it + 1) % 20 == 0:
                log(f"silhouette step {it + 1}/{config.silhouette_iters}: loss {float(loss.detach()):.4f}")
    # reported errors: keypoints in pixels, silhouette IoU at full resolution
    with torch.no_grad():
        Tr = P.transforms()
        uv = P.project(P.to_camera(P.kmap.points(Tr)), P.focal).numpy()
        err = np.linalg.norm(uv - P.kp.numpy(), axis=-1)  # (T,K)
        seen = det.visibility[:, P.kmap.landmark_ids] >= config.min_visibility
        px = np.array([err[i][seen[i]].mean() if seen[i].any() else float("nan") for i in range(P.T)])
        cam = P.camera()
        faces = body.faces.numpy()
        fit_masks, ious = [], []
        for i in range(P.T):
            verts = apply_points(blend(body.skin_weights, Tr[i]), body.rest_vertices).numpy()
            a = mesh_silhouette(verts, faces, cam)
            m = det.masks[i] > 0.5
            union = (a | m).sum()
            ious.append(float((a & m).sum() / union) if union else 0.0)
            fit_masks.append(a)
    return FitResult(P.poses(), P.camera(), px, np.asarray(ious), np.stack(fit_masks), P.f_guess,
                     time.perf_counter() - t_start, hist)
