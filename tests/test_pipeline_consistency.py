"""End-to-end consistency of body model, LBS, cameras, scene generator and rasterizer: the
ground-truth-textured body, splatted as one Gaussian per UV texel, must reproduce the mesh-rendered
ground truth of every camera of a synthetic scene."""

import numpy as np
import torch

from reconstruct.body.uv_map import build_uv_map, texel_spacing
from reconstruct.metrics import psnr
from reconstruct.raster import rasterization


def textured_gaussians(scene, body, resolution):
    uv = build_uv_map(body, resolution)
    tex = scene.meta["texture"]
    T = tex.shape[0]
    rows = np.clip(((uv.texel_rc[:, 0] + 0.5) / resolution * T).astype(int), 0, T - 1)
    cols = np.clip(((uv.texel_rc[:, 1] + 0.5) / resolution * T).astype(int), 0, T - 1)
    return uv, torch.as_tensor(tex[rows, cols, :3] / 255.0).float(), texel_spacing(uv)


def subpixel_offset(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(dx, dy) shift of ``a`` relative to ``b`` from the peak of their cross-correlation, refined by
    a parabola through the integer shifts -1, 0, 1 on each axis."""
    score = lambda dx, dy: float((np.roll(a, (-dy, -dx), axis=(0, 1)) * b).sum())  # noqa: E731
    out = []
    for axis in range(2):
        s = [score(d, 0) if axis == 0 else score(0, d) for d in (-1, 0, 1)]
        out.append(0.5 * (s[0] - s[2]) / (s[0] - 2 * s[1] + s[2]))
    return np.array(out)


def test_subpixel_offset_detects_a_shift():
    y, x = np.mgrid[:64, :64]
    blob = np.exp(-((x - 30.3) ** 2 + (y - 33.0) ** 2) / 40.0)
    shifted = np.exp(-((x - 31.0) ** 2 + (y - 32.6) ** 2) / 40.0)
    assert np.allclose(subpixel_offset(shifted, blob), [0.7, -0.4], atol=0.05)


def test_textured_body_splats_reproduce_mesh_ground_truth():
    from reconstruct.data.synthetic.generator import SyntheticConfig, build_synthetic_scene

    small_scene = build_synthetic_scene(SyntheticConfig(seed=5, num_frames=2, image_size=256, num_eval_azimuths=8,
                                                        eval_frames=1), progress=False)
    body = small_scene.body_model()
    uv, colors, spacing = textured_gaussians(small_scene, body, 192)
    skin = body.skinning(uv.weights)
    n = len(uv)
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1
    scales = (0.6 * spacing).float()[:, None].expand(n, 3).contiguous()
    values, ious = [], []
    views = [(f.camera, f) for f in small_scene.frames[:2]] + [(v.camera, v) for v in small_scene.eval_views]
    for cam, gt in views:
        pose = small_scene.frames[getattr(gt, "frame_index", getattr(gt, "index", 0))].pose
        means, _ = skin(body.bone_transforms(pose), uv.positions)
        out = rasterization(means.float(), quats, scales, torch.ones(n), colors, cam)
        values.append(float(psnr(out.image, torch.as_tensor(gt.image))))
        # silhouettes agree: the splats' alpha correlates best with the mesh mask within half a pixel
        # of zero shift (splat outlines are blurred by the 0.3 px^2 low-pass and the Gaussians' extent,
        # not quite symmetrically where the camera sees the tops of surfaces), and
        # nothing of the mesh is left uncovered
        a = out.alpha.numpy()
        offset = subpixel_offset(a, gt.mask)
        assert np.abs(offset).max() < 0.5, (cam.name, offset)
        assert np.clip(gt.mask - a, 0, None).sum() / gt.mask.sum() < 0.02
        ious.append(((a > 0.5) & (gt.mask > 0.5)).sum() / ((a > 0.5) | (gt.mask > 0.5)).sum())
    print("PSNR", np.round(values, 2), "IoU", np.round(ious, 3))
    assert min(ious) > 0.75, ious
    assert min(values) > 22.0, values
