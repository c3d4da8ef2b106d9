"""The garment layer's hem (docs/loose_clothing.md, "The hem's edge"): rows every 5 mm over the
last 3 cm, a margin below the masks' hem, weights diffused in metres, and the sharp edge this gives
where nothing stands behind the cloth (seen from behind)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from reconstruct.avatar import AvatarConfig, AvatarModel
from reconstruct.avatar.garment_layer import (VolumeHint, interpolation_matrix, build_garment_layer, landmark_heights,
                                              row_heights)
from reconstruct.avatar.gaussian_sets import PosedGaussians
from reconstruct.camera import Camera
from reconstruct.train.render import render_avatar


@pytest.fixture(scope="module")
def body(tiny_scene):
    return tiny_scene.body_model()


def _hint(body) -> VolumeHint:
    m = landmark_heights(body)
    return VolumeHint(top_z=m["waist"], hem_z=m["knee"] + 0.08, standoff_hem=0.05)


def test_row_heights_coarse_then_fine_to_the_bottom():
    zs = row_heights(0.2, -0.3, 0.02, hem_band=0.03, hem_step=0.005)
    assert zs[0] == 0.2 and zs[-1] == pytest.approx(-0.3, abs=1e-12)
    step = -np.diff(zs)
    assert (step > 0).all()
    fine = zs < -0.3 + 0.03 - 1e-9
    assert fine.sum() == 6 and np.allclose(step[-6:], 0.005)  # the last 3 cm every 5 mm
    assert step[:-6].max() <= 0.02 + 1e-12 and step[:-6].min() > 0.015
    # no band: the evenly spaced rows of before
    assert np.array_equal(row_heights(0.2, -0.3, 0.02), np.linspace(0.2, -0.3, 26))
    # a layer too short for a band below a coarse row gets none
    assert np.array_equal(row_heights(0.0, -0.04, 0.02, hem_band=0.03), np.linspace(0.0, -0.04, 4))


def test_interpolation_matrix_matches_np_interp():
    src = np.array([0.3, 0.1, 0.05, 0.0, -0.02, -0.025])
    dst = np.array([0.35, 0.3, 0.2, 0.07, 0.0, -0.021, -0.03])
    A = interpolation_matrix(src, dst)
    rng = np.random.default_rng(0)
    f = rng.normal(size=len(src))
    want = np.interp(-dst, -src, f)  # increasing abscissae; clamped at the ends like A
    assert np.allclose(A @ f, want, atol=1e-12)
    assert np.allclose(A.sum(1), 1.0)


def test_hem_rows_keep_the_weights_of_an_even_grid(body):
    """The weights are diffused over rows every row_step whatever the hem's rows: the layer with the
    fine band agrees with the evenly spaced one interpolated to its heights, closer than when the
    fine rows are diffused as if they were row_step apart."""
    hint = _hint(body)
    fine = build_garment_layer(body, hint, cols=16, row_step=0.02, hem_band=0.03)
    even = build_garment_layer(body, hint, cols=16, row_step=0.02, hem_band=0.0)
    Rf, C = fine.grid_shape
    Re, _ = even.grid_shape
    assert Rf > Re and fine.num_gaussians == Rf * C
    zf = fine.positions.reshape(Rf, C, 3)[:, 0, 2].double()
    ze = even.positions.reshape(Re, C, 3)[:, 0, 2].double()
    assert float(zf[-1]) == pytest.approx(hint.hem_z - 0.01, abs=1e-6)  # the margin below the hint's hem
    assert float(ze[-1]) == pytest.approx(hint.hem_z - 0.01, abs=1e-6)
    Wf, We = fine.weights.reshape(Rf, C, -1), even.weights.reshape(Re, C, -1)
    at_fine = torch.einsum("fe,ecj->fcj", torch.as_tensor(interpolation_matrix(ze.numpy(), zf.numpy())), We.double())
    gap = float((at_fine - Wf.double()).abs().max())
    assert gap < 0.08, gap
    # diffused over the fine rows as if they were 2 cm apart, the hem's weights would differ more
    coarse_rows = build_garment_layer(body, hint, cols=16, row_step=0.02, hem_band=0.03, diffusion=(0.75, 6.0))
    assert float((coarse_rows.weights.reshape(Rf, C, -1).double() - at_fine).abs().max()) > gap
    assert torch.allclose(fine.weights.sum(1), torch.ones(fine.num_gaussians), atol=1e-5)


def _back_alpha_profile(body, layer) -> tuple[np.ndarray, float, float]:
    """The layer alone (opacity 0.99, initial decode, rest pose) seen from behind near the hem:
    alpha down the image column through the back's centre, the metres per pixel there, and the image
    row of the lowest grid row's back point."""
    cfg = AvatarConfig(gaussian_resolution=32, feature_resolution=16, feature_channels=4, pose_feature_channels=4,
                       hidden=16)
    torch.manual_seed(0)
    m = AvatarModel(body, cfg, layer=layer)
    with torch.no_grad():
        m.layer_opacity.fill_(float(torch.logit(torch.tensor(0.99))) / cfg.garment_opacity_gain)
        c = m.canonical()
        posed = m.pose(c, body.canonical_transforms.float())
    N = m.num_body
    only = PosedGaussians(*(getattr(posed, k)[N:] for k in ("means", "normals", "colors", "scales", "quats",
                                                            "opacities")))
    R, C = layer.grid_shape
    P = layer.positions.reshape(R, C, 3).double().numpy()
    back = P[-1, C // 2]  # column C/2 is the back of the tube
    target = np.array([0.0, back[1], back[2]])
    size, dist, fov = 256, 3.0, 8.0
    cam = Camera.orbit(180.0, 0.0, dist, target, width=size, height=size, fov_y_deg=fov)
    with torch.no_grad():
        r = render_avatar(only, cam, torch.zeros(3), normals=False)
    alpha = r.alpha.reshape(size, size).numpy()
    uv, _ = cam.project(back[None])
    col = int(round(float(uv[0, 0])))
    metres_per_px = 2 * dist * np.tan(np.radians(fov / 2)) / size  # the back point is ``dist`` from the camera
    return alpha[:, col], metres_per_px, float(uv[0, 1])


def test_the_hem_ends_sharply_where_nothing_stands_behind(body):
    """Seen from behind, the cloth must be opaque (alpha >= 0.9) to within 6 mm of its lowest row
    and end within about a centimetre below that: with rows every 2 cm down to the hem, the discs
    (at least 0.6 of a grid step) spill some 2 cm past the last row and fade over more than twice
    the fine band's height. Training then makes the last rows transparent where they spill past the
    mask, and the soft edge moves up into the cloth: holes wherever no leg stands behind it."""
    hint = _hint(body)
    fine, even = (build_garment_layer(body, hint, cols=32, row_step=0.02, hem_band=band) for band in (0.03, 0.0))
    prof_f, mpp, row_f = _back_alpha_profile(body, fine)
    prof_e, _, row_e = _back_alpha_profile(body, even)

    def edge(profile, last_row):
        opaque = np.flatnonzero(profile >= 0.9)
        low = int(opaque.max())  # the lowest opaque pixel (image rows grow downwards)
        clear = low + int(np.flatnonzero(profile[low:] < 0.1)[0])
        return (last_row - low) * mpp, (clear - low) * mpp  # opaque end above (+) the last row; the soft band

    short_f, band_f = edge(prof_f, row_f)
    short_e, band_e = edge(prof_e, row_e)
    assert band_f < 0.012 and abs(short_f) < 0.006, (band_f, short_f)
    assert band_e > 2 * band_f and abs(short_e) > 0.01, (band_e, short_e)  # soft, and off the last row


def test_hem_rows_past_the_covered_body_keep_the_ring(body):
    """A floor-length skirt: the hem rows reach below the shins' end, where a 1.2 cm slice holds a few
    points on one side of the body. Those rows take the nearest full row's ring (``_tube_rings``),
    so the ring's centre does not run off sideways within the hem's 5 mm rows (on the long-skirt
    photo it ran 6 cm out and 7 cm back, the hem's discs spanning the jumps as needles)."""
    from reconstruct.avatar.garment_layer import _dense_body

    pts, _ = _dense_body(body)
    low = float(pts[:, 2].min())
    m = landmark_heights(body)
    hint = VolumeHint(top_z=m["waist"], hem_z=low + 0.004, standoff_hem=0.05)
    layer = build_garment_layer(body, hint, cols=32)
    R, C = layer.grid_shape
    P = layer.positions.double().reshape(R, C, 3)
    centre = P[..., :2].mean(1)  # (R,2): the ring's centre in the body's x-y
    zs = P[:, 0, 2]
    past = zs < low + 0.012  # rows whose slab reaches past the shins' end
    assert past.sum() >= 2
    first = int(np.flatnonzero(past.numpy())[0])
    drift = (centre[first - 1:] - centre[first - 1]).norm(dim=1)
    assert drift.max() < 2e-3, drift
    # the hem's discs span their own 5 mm rows, not jumps between rings
    down = layer.steps().reshape(R, C, 2)[-6:, :, 1]
    assert down.max() < 0.012, down.max()
