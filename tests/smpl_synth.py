"""A tiny synthetic SMPL-shaped model (tubes around a 24-joint skeleton) written in SMPL's own file
formats, an independent float64 SMPL forward pass, and writers of the dataset layouts' files.
Shared by tests/test_body_smpl.py and tests/test_loaders_*.py."""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path

import numpy as np

PARENTS = np.array([-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21])
# joint positions in SMPL space (Y up, facing +Z, +X the body's left), metres
JOINTS = np.array([
    [0.0, 0.0, 0.0], [0.07, -0.09, 0.0], [-0.07, -0.09, 0.0], [0.0, 0.11, -0.01], [0.1, -0.48, 0.0],
    [-0.1, -0.48, 0.0], [0.0, 0.24, 0.0], [0.1, -0.88, -0.02], [-0.1, -0.88, -0.02], [0.0, 0.30, 0.01],
    [0.11, -0.93, 0.1], [-0.11, -0.93, 0.1], [0.0, 0.52, -0.01], [0.08, 0.43, 0.0], [-0.08, 0.43, 0.0],
    [0.0, 0.62, 0.03], [0.18, 0.45, -0.01], [-0.18, 0.45, -0.01], [0.44, 0.45, -0.02], [-0.44, 0.45, -0.02],
    [0.68, 0.45, -0.01], [-0.68, 0.45, -0.01], [0.77, 0.45, -0.01], [-0.77, 0.45, -0.01],
])
LEAF_TIPS = {10: [0.11, -0.95, 0.2], 11: [-0.11, -0.95, 0.2], 15: [0.0, 0.85, 0.03], 22: [0.85, 0.45, -0.01],
             23: [-0.85, 0.45, -0.01]}
RINGS, SIDES = 4, 8


def _radius(bone: int) -> float:
    if bone in (0, 3, 6, 9):
        return 0.13
    if bone == 15:
        return 0.09
    if bone in (1, 2):
        return 0.075
    return 0.045


def build_model(seed: int = 0, num_betas: int = 10):
    """(arrays dict in SMPL's key names, uv obj text). Tubes from each joint's parent to it (skinned
    to the parent, blending into the grandparent near the start), plus tubes past the leaf joints."""
    rng = np.random.default_rng(seed)
    segments = [(int(PARENTS[j]), JOINTS[PARENTS[j]], JOINTS[j], j) for j in range(1, 24)]
    segments += [(j, JOINTS[j], np.asarray(tip), None) for j, tip in LEAF_TIPS.items()]
    verts, weights, faces, vts, face_uv = [], [], [], [], []
    ring_of_joint: dict[int, list[int]] = {}
    cols = 6
    for s, (bone, a, b, end_joint) in enumerate(segments):
        axis = b - a
        L = np.linalg.norm(axis)
        d = axis / L
        helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(d, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(d, e1)
        r = _radius(bone)
        base = len(verts)
        cu, cv = (s % cols) / cols, (s // cols) / cols
        vt_base = len(vts)
        for i in range(RINGS):
            t = i / (RINGS - 1)
            centre = a + t * axis
            for k in range(SIDES):
                ang = 2 * np.pi * k / SIDES
                verts.append(centre + r * (np.cos(ang) * e1 + np.sin(ang) * e2))
                w = np.zeros(24)
                parent = PARENTS[bone]
                if t == 0.0 and parent >= 0:
                    w[bone], w[parent] = 0.6, 0.4
                else:
                    w[bone] = 1.0
                weights.append(w)
            for k in range(SIDES + 1):
                vts.append((cu + 0.02 + 0.9 / cols * k / SIDES, cv + 0.02 + 0.9 / cols * t))
        for i in range(RINGS - 1):
            for k in range(SIDES):
                a0, a1 = base + i * SIDES + k, base + i * SIDES + (k + 1) % SIDES
                b0, b1 = a0 + SIDES, a1 + SIDES
                t0, t1 = vt_base + i * (SIDES + 1) + k, vt_base + i * (SIDES + 1) + k + 1
                u0, u1 = t0 + SIDES + 1, t1 + SIDES + 1
                faces += [[a0, a1, b1], [a0, b1, b0]]
                face_uv += [[t0, t1, u1], [t0, u1, u0]]
        if end_joint is not None:
            ring_of_joint[end_joint] = list(range(base + (RINGS - 1) * SIDES, base + RINGS * SIDES))
        if bone == 0 and end_joint == 3:
            ring_of_joint[0] = list(range(base, base + SIDES))
    V = len(verts)
    J_regressor = np.zeros((24, V))
    for j, ring in ring_of_joint.items():
        J_regressor[j, ring] = 1.0 / len(ring)
    arrays = {
        "v_template": np.asarray(verts),
        "f": np.asarray(faces, np.uint32),
        "weights": np.asarray(weights),
        "kintree_table": np.stack([np.where(PARENTS < 0, 2 ** 32 - 1, PARENTS), np.arange(24)]).astype(np.uint32),
        "J_regressor": J_regressor,
        "shapedirs": rng.normal(0, 0.01, (V, 3, num_betas)),
        "posedirs": rng.normal(0, 0.01, (V, 3, 207)),
    }
    obj = ["# synthetic SMPL-shaped UV layout"]
    obj += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in arrays["v_template"]]
    obj += [f"vt {u:.6f} {v:.6f}" for u, v in vts]
    obj += [f"f {a + 1}/{ta + 1} {b + 1}/{tb + 1} {c + 1}/{tc + 1}" for (a, b, c), (ta, tb, tc) in zip(faces, face_uv)]
    return arrays, "\n".join(obj) + "\n"


def write_model(folder: Path, gender: str = "NEUTRAL", fmt: str = "npz", seed: int = 0) -> Path:
    """Write SMPL_<gender>.<fmt> and smpl_uv.obj into ``folder``; ``fmt`` "npz", "pkl" (plain
    arrays, sparse J_regressor) or "chumpy" (.pkl whose shapedirs is a chumpy object)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arrays, obj = build_model(seed)
    (folder / "smpl_uv.obj").write_text(obj)
    if fmt == "npz":
        path = folder / f"SMPL_{gender}.npz"
        np.savez(path, **arrays)
        return path
    import scipy.sparse

    data = dict(arrays)
    data["J_regressor"] = scipy.sparse.csc_matrix(arrays["J_regressor"])
    data["bs_style"], data["bs_type"] = "lbs", "lrotmin"
    path = folder / f"SMPL_{gender}.pkl"
    if fmt == "chumpy":
        data["shapedirs"] = fake_chumpy_array(arrays["shapedirs"])
        with fake_chumpy_module():
            path.write_bytes(pickle.dumps(data, protocol=2))
    else:
        path.write_bytes(pickle.dumps(data, protocol=2))
    return path


class _FakeCh:  # pickled as chumpy.ch.Ch: its state dict holds the array in 'x', like chumpy's
    pass


def fake_chumpy_array(x: np.ndarray):
    ch = _FakeCh()
    ch.__dict__.update({"x": x, "_dirty_vars": set(), "_itr": None})
    return ch


class fake_chumpy_module:
    """Registers modules ``chumpy``/``chumpy.ch`` with ``Ch`` = _FakeCh while pickling, and
    removes them after (so loading must work without chumpy)."""

    def __enter__(self):
        self.saved = (_FakeCh.__module__, _FakeCh.__qualname__)
        pkg, mod = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")
        mod.Ch = _FakeCh
        pkg.ch = mod
        sys.modules["chumpy"], sys.modules["chumpy.ch"] = pkg, mod
        _FakeCh.__module__, _FakeCh.__qualname__, _FakeCh.__name__ = "chumpy.ch", "Ch", "Ch"
        return self

    def __exit__(self, *exc):
        _FakeCh.__module__, _FakeCh.__qualname__ = self.saved
        _FakeCh.__name__ = "_FakeCh"
        sys.modules.pop("chumpy", None)
        sys.modules.pop("chumpy.ch", None)


# ----- independent float64 SMPL (numpy) -----------------------------------------------------------
def rodrigues(r: np.ndarray) -> np.ndarray:
    r = np.asarray(r, np.float64)
    th = np.linalg.norm(r)
    if th < 1e-12:
        return np.eye(3)
    k = r / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx


def smpl_forward(arrays: dict, full_pose: np.ndarray, betas: np.ndarray, transl=np.zeros(3), posedirs: bool = False):
    """SMPL's vertices (V,3) in SMPL space (the textbook algorithm, float64, loops)."""
    betas = np.asarray(betas, np.float64)
    v = arrays["v_template"] + arrays["shapedirs"][:, :, : len(betas)] @ betas
    J = arrays["J_regressor"] @ v
    rots = [rodrigues(r) for r in np.asarray(full_pose, np.float64).reshape(24, 3)]
    if posedirs:
        feat = np.concatenate([(R - np.eye(3)).reshape(-1) for R in rots[1:]])
        v = v + arrays["posedirs"] @ feat
    G = [None] * 24
    for j in range(24):
        M = np.eye(4)
        M[:3, :3] = rots[j]
        M[:3, 3] = J[j] - (J[PARENTS[j]] if j else 0)
        G[j] = M if j == 0 else G[PARENTS[j]] @ M
    A = np.stack([g.copy() for g in G])
    for j in range(24):
        A[j, :3, 3] -= A[j, :3, :3] @ J[j]
    T = np.einsum("vj,jab->vab", arrays["weights"], A)
    return np.einsum("vab,vb->va", T[:, :3, :3], v) + T[:, :3, 3] + transl


def opencv_project(points: np.ndarray, K, R, t, D=None) -> np.ndarray:
    """cv2.projectPoints: pinhole with optional (k1, k2, p1, p2, k3) distortion, pixel centres at integers."""
    pc = points @ np.asarray(R).T + np.asarray(t).reshape(3)
    x, y = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
    if D is not None and np.any(D):
        k1, k2, p1, p2, k3 = np.asarray(D, np.float64).reshape(-1)[:5]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        x, y = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([x * K[0][0] + K[0][2], y * K[1][1] + K[1][2]], axis=1)


def look_at_opencv(eye, target=(0, 0, 0), up=(0, 0, 1)):
    """World-to-camera (R, t) of an OpenCV camera at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(x, np.float64) for x in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])
    return R, -R @ eye


def silhouette(points_uv: np.ndarray, H: int, W: int, radius: float = 2.5) -> np.ndarray:
    """A rough mask: pixels within ``radius`` of any projected point."""
    yy, xx = np.mgrid[0:H, 0:W]
    m = np.zeros((H, W), bool)
    for u, v in points_uv:
        m |= (xx - u) ** 2 + (yy - v) ** 2 <= radius ** 2
    return m


# ----- dataset fixtures ---------------------------------------------------------------------------
C_SMPL_TO_ZUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
SIZE = 64
FOCAL = 70.0


def _rotvec(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def motion(T: int, seed: int = 0) -> np.ndarray:
    """(T,72) small joint motions with the root left at zero (EasyMocap style)."""
    rng = np.random.default_rng(seed)
    full = rng.normal(0.0, 0.15, (T, 72))
    full[:, :3] = 0.0
    return full


def _image(mask: np.ndarray, colour, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    bg = rng.integers(0, 60, (*mask.shape, 3))
    img = np.where(mask[..., None], np.asarray(colour)[None, None, :], bg)
    return img.astype(np.uint8)


ZJU_AZIMUTHS = (0.0, 30.0, 90.0, 180.0, 270.0)  # camera azimuths around the body (0 = its front)


def write_annots_dataset(folder: Path, arrays: dict, kind: str = "zju", T: int = 6, distort_camera: int | None = 2):
    """A ZJU-MoCap (Instant-NVR) or MonoCap folder: 5 cameras, T frames, EasyMocap parameters.

    zju: images/NN/FFFFFF.jpg, mask/NN/FFFFFF.png (0/1 for even cameras, 0/255 for odd ones),
         smpl_params/F.npy, frames numbered from 0.
    monocap: 1-based frame files (images/NN/FFFFFF.jpg and params/F.npy from F=1), masks as .jpg 0/255.
    Returns a dict with what was written (cameras, params, world vertices per frame)."""
    import imageio.v3 as iio

    folder = Path(folder)
    betas = np.linspace(-0.5, 0.5, 10)
    yaw = np.radians(10.0)
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    Rh_mat = Rz @ C_SMPL_TO_ZUP  # SMPL (Y up, facing +Z) -> world (Z up, facing -Y rotated by yaw)
    Th = np.array([0.1, -0.05, 1.0])
    full = motion(T)
    centre = np.array([0.0, 0.0, 1.0])
    K = np.array([[FOCAL, 0, SIZE / 2 - 0.5], [0, FOCAL, SIZE / 2 - 0.5], [0, 0, 1.0]])
    cams = {"K": [], "D": [], "R": [], "T": []}
    for c, az in enumerate(ZJU_AZIMUTHS):
        a = np.radians(az) + yaw
        eye = centre + 3.2 * np.array([np.sin(a), -np.cos(a), 0.05])
        R, t = look_at_opencv(eye, centre)
        D = np.zeros((5, 1))
        if c == distort_camera:
            D[:, 0] = [-0.2, 0.05, 0.001, -0.001, 0.0]
        cams["K"].append(K.copy())
        cams["D"].append(D)
        cams["R"].append(R)
        cams["T"].append((t * 1000.0).reshape(3, 1))  # millimetres
    base = 1 if kind == "monocap" else 0
    params_dir = folder / ("params" if kind == "monocap" else "smpl_params")
    params_dir.mkdir(parents=True, exist_ok=True)
    ims, world = [], []
    for f in range(T):
        n = f + base
        p = {"poses": full[f][None].astype(np.float32), "Rh": _rotvec(Rh_mat)[None].astype(np.float32),
             "Th": Th[None].astype(np.float32), "shapes": betas[None].astype(np.float32)}
        np.save(params_dir / f"{n}.npy", p)
        Rh = p["Rh"][0].astype(np.float64)
        v = smpl_forward(arrays, p["poses"][0].astype(np.float64), p["shapes"][0].astype(np.float64)) @ rodrigues(Rh).T \
            + p["Th"][0].astype(np.float64)
        world.append(v)
        row = []
        for c in range(len(ZJU_AZIMUTHS)):
            rel = f"images/{c:02d}/{n:06d}.jpg"
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            uv = opencv_project(v, cams["K"][c], cams["R"][c], cams["T"][c] / 1000.0, cams["D"][c])
            m = silhouette(uv, SIZE, SIZE)
            iio.imwrite(folder / rel, _image(m, (200, 120 + 20 * c, 60), seed=100 * f + c), quality=95)
            mdir = folder / "mask" / f"{c:02d}"
            mdir.mkdir(parents=True, exist_ok=True)
            if kind == "monocap":
                iio.imwrite(mdir / f"{n:06d}.jpg", (m * 255).astype(np.uint8), quality=90)
            else:
                iio.imwrite(mdir / f"{n:06d}.png", (m * (1 if c % 2 == 0 else 255)).astype(np.uint8))
            row.append(rel)
        ims.append({"ims": row})
    np.save(folder / "annots.npy", {"cams": cams, "ims": ims})
    return {"cams": cams, "full": full, "Th": Th, "Rh": _rotvec(Rh_mat), "betas": betas, "world": world, "base": base}


def write_snapshot(folder: Path, arrays: dict, T: int = 5):
    """PeopleSnapshot as InstantAvatar writes it (camera at the origin looking down +Z)."""
    import imageio.v3 as iio

    folder = Path(folder)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    (folder / "masks").mkdir(parents=True, exist_ok=True)
    K = np.array([[FOCAL, 0, SIZE / 2 - 0.5], [0, FOCAL, SIZE / 2 - 0.5], [0, 0, 1.0]])
    E = np.eye(4)
    np.savez(folder / "cameras.npz", intrinsic=K, extrinsic=E, height=SIZE, width=SIZE)
    full = motion(T, seed=1)
    full[:, :3] = [np.pi, 0.0, 0.0]  # upright in the camera's Y-down world
    transl = np.tile([0.0, 0.1, 3.2], (T, 1)) + np.linspace(0, 0.05, T)[:, None]
    betas = np.linspace(0.3, -0.3, 10)
    np.savez(folder / "poses.npz", betas=betas.astype(np.float32), thetas=full.astype(np.float32),
             transl=transl.astype(np.float32))
    world = []
    for i in range(T):
        v = smpl_forward(arrays, full[i].astype(np.float32).astype(np.float64), betas.astype(np.float32).astype(np.float64),
                         transl[i].astype(np.float32).astype(np.float64))
        world.append(v)
        m = silhouette(opencv_project(v, K, E[:3, :3], E[:3, 3]), SIZE, SIZE)
        iio.imwrite(folder / "images" / f"image_{i:04d}.png", _image(m, (90, 180, 220), seed=i))
        np.save(folder / "masks" / f"mask_{i:04d}.npy", m.astype(np.uint8))
    return {"K": K, "E": E, "full": full, "transl": transl, "betas": betas, "world": world}


def write_gaussian_avatar(folder: Path, arrays: dict, T: int = 5):
    """The GaussianAvatar layout: folder/train/{images,masks,cam_parms.npz,smpl_parms.pth}."""
    import imageio.v3 as iio
    import torch

    root = Path(folder) / "train"
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "masks").mkdir(parents=True, exist_ok=True)
    K = np.array([[FOCAL, 0, SIZE / 2 - 0.5], [0, FOCAL, SIZE / 2 - 0.5], [0, 0, 1.0]])
    R, t = look_at_opencv([0.3, -3.0, 0.4], [0.0, 0.0, 0.0], up=[0, 0, 1])
    E = np.eye(4)
    E[:3, :3], E[:3, 3] = R, t
    np.savez(root / "cam_parms.npz", intrinsic=K, extrinsic=E)
    full = motion(T, seed=2)
    full[:, :3] = _rotvec(C_SMPL_TO_ZUP)  # stand up in a Z-up world, facing -Y
    trans = np.tile([0.0, 0.0, 0.1], (T, 1))
    beta = np.linspace(-0.2, 0.2, 10)[None]
    torch.save({"beta": torch.tensor(beta, dtype=torch.float32), "body_pose": torch.tensor(full, dtype=torch.float32),
                "trans": torch.tensor(trans, dtype=torch.float32)}, root / "smpl_parms.pth")
    world = []
    for i in range(T):
        v = smpl_forward(arrays, full[i].astype(np.float32).astype(np.float64), beta[0].astype(np.float32).astype(np.float64),
                         trans[i].astype(np.float32).astype(np.float64))
        world.append(v)
        m = silhouette(opencv_project(v, K, R, t), SIZE, SIZE)
        iio.imwrite(root / "images" / f"{i:05d}.png", _image(m, (230, 200, 40), seed=i))
        iio.imwrite(root / "masks" / f"{i:05d}.png", (m * 255).astype(np.uint8))
    return {"K": K, "E": E, "full": full, "trans": trans, "beta": beta, "world": world}


def train_and_evaluate(scene, config, steps: int = 2):
    """A Trainer on ``scene``: ``steps`` steps, then an evaluation; returns (losses, rows, summary)."""
    from reconstruct.train.trainer import Trainer

    trainer = Trainer(scene, config)
    losses = [trainer.step()["loss"] for _ in range(steps)]
    rows, summary = trainer.evaluate()
    return losses, rows, summary


def projection_error(scene, frame_pos: int, world_vertices: np.ndarray, K, R, t) -> float:
    """Max pixel distance between the scene's body projected by the scene's camera and the dataset's
    own convention (cv2.projectPoints of its SMPL vertices), after the +0.5 px pixel-centre shift."""
    f = scene.frames[frame_pos]
    body = scene.body_model()
    uv, _ = f.camera.project(body.posed_vertices(f.pose).numpy())
    return float(np.abs(uv - (opencv_project(world_vertices, K, R, t) + 0.5)).max())
