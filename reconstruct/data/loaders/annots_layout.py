"""The multi-view ``annots.npy`` layout shared by ZJU-MoCap (Instant-NVR) and MonoCap.

    FOLDER/annots.npy        dict: cams {K, D, R, T (millimetres)} lists, one entry per camera;
                             ims: one {'ims': [image path per camera]} per frame, paths relative to FOLDER
    FOLDER/images/<cam>/...  (or any folder the ims paths name)
    FOLDER/mask/<cam>/...    same relative path with images -> mask (.png, or .jpg); also looked up:
                             mask/<ims path>, mask_cihp/<ims path>, schp/<cam>/... (part labels: 0 = background)
    FOLDER/<params>/<n>.npy  EasyMocap SMPL parameters {poses (1,72), Rh (1,3), Th (1,3), shapes (1,10)} of
                             frame n, the number in the image's file name (so 1-based names use 1-based files;
                             CoreView_313/315 names carry it in their fifth '_' field)

The posed body in the world is ``R(Rh) @ SMPL(poses, shapes) + Th`` (EasyMocap), cameras map world
points by ``x_cam = R x + T / 1000``. Frames whose image, mask or parameters are missing are left
out (listed in ``scene.meta['skipped']``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...body.smpl_backend import smpl_body_pose
from ...body.spec import smpl_body_spec
from ...safe_pickle import SafeLoadError, load_npy_object
from ..scene import Scene
from .common import (LoaderError, Protocol, check_size, finish_frame, frame_number, make_eval_view, opencv_camera,
                     read_mask, read_rgb, smpl_shape_error, undistort, warn_skipped, azimuth_about_body, wrap_deg)

FPS = 30.0


def read_annots(folder: Path) -> dict:
    path = folder / "annots.npy"
    if not path.is_file():
        raise LoaderError(f"{path}: missing (camera parameters and per-frame image lists of a ZJU-MoCap/MonoCap "
                          f"folder: a dict with 'cams' {{K, D, R, T}} and 'ims')")
    try:  # a pickled dict: read as plain data only (a crafted file must not run code)
        annots = load_npy_object(path)
    except SafeLoadError as exc:
        raise LoaderError(f"{exc} (reading the camera parameters and image lists of a ZJU-MoCap/MonoCap "
                          f"folder)") from exc
    if not isinstance(annots, dict) or "cams" not in annots or "ims" not in annots:
        found = sorted(annots) if isinstance(annots, dict) else type(annots).__name__
        raise LoaderError(f"{path}: expected a dict with keys 'cams' and 'ims', found {found}")
    cams = annots["cams"]
    if not isinstance(cams, dict):
        raise LoaderError(f"{path}: 'cams' should be a dict {{K, D, R, T}}, found {type(cams).__name__}")
    missing = [k for k in ("K", "R", "T") if k not in cams]
    if missing:
        raise LoaderError(f"{path}: 'cams' is missing {missing}; found keys {sorted(cams)}")
    for key in ("K", "R", "T", "D", "ims"):
        value = annots["ims"] if key == "ims" else cams.get(key, [])
        if not isinstance(value, (list, tuple, np.ndarray)):
            raise LoaderError(f"{path}: {key!r} should be a list (one entry per {'frame' if key == 'ims' else 'camera'}), "
                              f"found {type(value).__name__}")
    n = len(cams["K"])
    for key in ("K", "R", "T", "D"):
        if key in cams and len(cams[key]) != n:
            raise LoaderError(f"{path}: cams[{key!r}] lists {len(cams[key])} cameras, cams['K'] lists {n}")
    for c in range(n):
        for key, shapes in (("K", [(3, 3)]), ("R", [(3, 3)]), ("T", [(3, 1), (3,), (1, 3)])):
            shape = np.shape(cams[key][c])
            if shape not in shapes:
                raise LoaderError(f"{path}: cams[{key!r}][{c}] has shape {shape}, expected {' or '.join(map(str, shapes))}")
    for i, row in enumerate(annots["ims"]):
        if not isinstance(row, dict) or "ims" not in row:
            raise LoaderError(f"{path}: ims[{i}] should be a dict with an 'ims' list, found {type(row).__name__}")
        if len(row["ims"]) != n:
            raise LoaderError(f"{path}: ims[{i}] lists {len(row['ims'])} images, expected one per camera ({n})")
    if not len(annots["ims"]):
        raise LoaderError(f"{path}: 'ims' lists no frames")
    return annots


def camera_names(annots: dict) -> list[str]:
    first = annots["ims"][0]["ims"]
    names = [Path(p).parent.name or str(i) for i, p in enumerate(first)]
    return names if len(set(names)) == len(names) else [str(i) for i in range(len(first))]


def mask_candidates(folder: Path, rel: str) -> list[Path]:
    p = Path(rel)
    stems = []
    if p.parts and p.parts[0] == "images":
        stems.append(Path("mask", *p.parts[1:]))
    stems += [Path("mask") / p, Path("mask_cihp") / p]
    if p.parts and p.parts[0] == "images":
        stems.append(Path("schp", *p.parts[1:]))
    return [folder / s.with_suffix(ext) for s in stems for ext in (".png", ".jpg")]


def params_candidates(folder: Path, params_dir: str, n: int) -> list[Path]:
    return [folder / params_dir / f"{n}.npy", folder / params_dir / f"{n:06d}.npy"]


def read_params(path: Path):
    try:  # a pickled dict: read as plain data only (a crafted file must not run code)
        d = load_npy_object(path)
    except SafeLoadError as exc:
        raise LoaderError(f"{exc} (reading EasyMocap SMPL parameters {{poses, Rh, Th, shapes}})") from exc
    if not isinstance(d, dict):
        raise LoaderError(f"{path}: expected a dict {{poses, Rh, Th, shapes}}, found {type(d).__name__}")
    missing = [k for k in ("poses", "Rh", "Th") if k not in d]
    if missing:
        raise LoaderError(f"{path}: missing SMPL parameters {missing}; found keys {sorted(d)}")
    try:
        poses, Rh, Th = (np.asarray(d[k], np.float64) for k in ("poses", "Rh", "Th"))
    except (TypeError, ValueError) as exc:
        raise LoaderError(f"{path}: 'poses', 'Rh' and 'Th' should be arrays of numbers: {exc}") from exc
    if poses.size != 72:
        raise smpl_shape_error(path, "poses", "(1, 72): SMPL's 24 joints x 3 axis-angle values", poses)
    for key, v in (("Rh", Rh), ("Th", Th)):
        if v.size != 3:
            raise smpl_shape_error(path, key, "(1, 3)", v)
    shapes = np.asarray(d.get("shapes", np.zeros(10)), np.float64).reshape(-1)
    return poses.reshape(72), Rh.reshape(3), Th.reshape(3), shapes


def _pick(key, names: list[str], path: Path, what: str) -> int:
    if isinstance(key, int) or (isinstance(key, str) and key.isdigit() and key not in names):
        idx = int(key)
        if not 0 <= idx < len(names):
            raise LoaderError(f"{path}: {what} {idx} does not exist; the folder has cameras 0..{len(names) - 1} ({names})")
        return idx
    if key not in names:
        raise LoaderError(f"{path}: {what} {key!r} is not among the cameras {names}")
    return names.index(key)


def load_annots_layout(folder: Path, protocol: Protocol, params_dir: str, layout: str) -> Scene:
    folder = Path(folder)
    annots = read_annots(folder)
    annots_path = folder / "annots.npy"
    cams = annots["cams"]
    names = camera_names(annots)
    ti = _pick(0 if protocol.train_camera is None else protocol.train_camera, names, annots_path, "training camera")
    sizes: dict[int, tuple[tuple[int, int], Path]] = {}

    def load_view(row: int, c: int):
        """(rgb, mask, camera) of camera c in frame row, or a reason it is missing."""
        rel = str(annots["ims"][row]["ims"][c])
        img_path = folder / rel
        if not img_path.is_file():
            return f"{rel}: image missing"
        masks = [p for p in mask_candidates(folder, rel) if p.is_file()]
        if not masks:
            return f"{rel}: no mask among {[str(p.relative_to(folder)) for p in mask_candidates(folder, rel)[:4]]}"
        rgb = read_rgb(img_path, f"camera {names[c]} frame {row}")
        mask = read_mask(masks[0], f"mask of {rel}")
        hw = rgb.shape[:2]
        if c in sizes:
            check_size(rgb, sizes[c][0], img_path, "the image", f"the size of {sizes[c][1].name}, the first image of camera {names[c]}")
        else:
            sizes[c] = (hw, img_path)
        check_size(mask, hw, masks[0], "the mask", f"the size of its image {img_path.name}")
        K = np.asarray(cams["K"][c], np.float64)
        D = np.asarray(cams["D"][c], np.float64) if "D" in cams else np.zeros(5)
        if np.any(D):
            rgb, mask = undistort(rgb, K, D), np.clip(undistort(mask, K, D), 0.0, 1.0)
        cam = opencv_camera(K, cams["R"][c], np.asarray(cams["T"][c], np.float64).reshape(3) / 1000.0, hw[1], hw[0],
                            names[c], str(annots_path), {"layout": layout, "distortion": D.reshape(-1).tolist()})
        return rgb, mask, cam

    rows = protocol.select(len(annots["ims"]))
    if not rows:
        raise LoaderError(f"{annots_path}: frames={protocol.frames} selects none of its {len(annots['ims'])} frames")
    frames, poses, betas, numbers, kept_rows, skipped = [], [], [], [], [], []
    fps = FPS / protocol.frames[2]
    for row in rows:
        rel = str(annots["ims"][row]["ims"][ti])
        n = frame_number(rel)
        if n is None:
            raise LoaderError(f"{annots_path}: ims[{row}] image {rel!r} has no frame number in its name")
        ppath = next((p for p in params_candidates(folder, params_dir, n) if p.is_file()), None)
        if ppath is None:
            skipped.append(f"{rel}: no {params_dir}/{n}.npy")
            continue
        view = load_view(row, ti)
        if isinstance(view, str):
            skipped.append(view)
            continue
        full_pose, Rh, Th, shapes = read_params(ppath)
        pose = smpl_body_pose(full_pose, transl=Th, Rh=Rh)
        rgb, mask, cam = view
        if mask.max() <= 0:
            skipped.append(f"{rel}: empty mask")
            continue
        frames.append(finish_frame(len(frames), rgb, mask, cam, pose, fps, protocol.scale))
        poses.append(pose)
        betas.append(shapes)
        numbers.append(n)
        kept_rows.append(row)
    warn_skipped(folder, skipped)
    if not frames:
        raise LoaderError(f"{folder}: none of the {len(rows)} selected frames of camera {names[ti]} has its image, mask "
                          f"and {params_dir}/<n>.npy; e.g. {skipped[:3]}")
    train_cam = opencv_camera(np.asarray(cams["K"][ti]), cams["R"][ti], np.asarray(cams["T"][ti], np.float64).reshape(3) / 1000.0,
                              sizes[ti][0][1], sizes[ti][0][0], names[ti], str(annots_path))

    # evaluation cameras
    others = [c for c in range(len(names)) if c != ti]
    ev = protocol.eval_cameras
    if ev is None:
        eval_cams = others
    elif isinstance(ev, int):
        def az(c):
            cam = opencv_camera(np.asarray(cams["K"][c]), cams["R"][c], np.asarray(cams["T"][c], np.float64).reshape(3) / 1000.0,
                                1, 1, names[c], str(annots_path))
            return wrap_deg(azimuth_about_body(cam, poses[0]) - azimuth_about_body(train_cam, poses[0])) % 360.0
        azs = {c: az(c) for c in others}
        eval_cams = []
        for k in range(min(ev, len(others))):
            target = 360.0 * (k + 1) / (ev + 1)
            free = [c for c in others if c not in eval_cams]
            eval_cams.append(min(free, key=lambda c: abs(wrap_deg(azs[c] - target))))
        eval_cams.sort()
    else:
        eval_cams = [_pick(k, names, annots_path, "evaluation camera") for k in ev]
        if ti in eval_cams:
            raise LoaderError(f"{annots_path}: evaluation camera {names[ti]} is also the training camera")
    views, eval_skipped = [], []
    for pos in range(0, len(frames), protocol.eval_every):
        for c in eval_cams:
            view = load_view(kept_rows[pos], c)
            if isinstance(view, str):
                eval_skipped.append(view)
                continue
            rgb, mask, cam = view
            views.append(make_eval_view(pos, rgb, mask, cam, train_cam, poses[pos], protocol.scale))
    warn_skipped(folder, eval_skipped)
    body = smpl_body_spec(np.mean(betas, axis=0), protocol.gender or "neutral", protocol.smpl_dir)
    meta = {"layout": layout, "source": str(folder), "train_camera": names[ti], "source_frames": numbers,
            "eval_cameras": [names[c] for c in eval_cams], "skipped": skipped + eval_skipped}
    return Scene(f"{layout}-{folder.name}-cam{names[ti]}", body, frames, views, fps, meta)
