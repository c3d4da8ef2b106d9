import numpy as np
import pytest
import torch

from reconstruct.stage2.view_selection import ViewSelectionConfig, candidate_cameras, select_views, visibility_ratio


def sphere(n=3000, radius=0.5, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    means = torch.tensor(d * radius, dtype=torch.float32)
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1
    scales = torch.full((n, 3), 0.04)
    return means, quats, scales, torch.ones(n), torch.tensor(d, dtype=torch.float32)


def test_candidates_are_100_azimuths_and_one_overhead():
    cams = candidate_cameras([0, 0, 0], ViewSelectionConfig())
    assert len(cams) == 101
    az = [a for _, a, e in cams[:-1]]
    assert np.allclose(np.diff(az), 3.6)
    assert cams[-1][2] == 80.0
    for cam, _, _ in cams:
        assert np.isclose(np.linalg.norm(cam.center), 5.0)


def test_front_seen_sphere_selects_the_back():
    """Seen = the front hemisphere (facing -Y, where the training camera is). Views from the front
    see mostly seen Gaussians, views from behind mostly unseen ones; the 50% threshold splits them
    near the sides."""
    means, quats, scales, opac, normals = sphere()
    seen = normals[:, 1] < 0
    views = select_views(means, quats, scales, opac, seen, [0, 0, 0], ViewSelectionConfig(num_azimuths=12, distance=3.0))
    by_az = {round(v.azimuth_deg): v for v in views if v.elevation_deg == 0}
    assert by_az[0].visibility > 0.9 and not by_az[0].unseen
    assert by_az[180].visibility < 0.1 and by_az[180].unseen
    assert by_az[30].visibility > by_az[60].visibility > by_az[120].visibility > by_az[150].visibility
    assert all(v.unseen == (v.visibility <= 0.5) for v in views)
    # the overhead view looks down at the seam: about half visible
    assert 0.3 < views[-1].visibility < 0.7


def test_visibility_ratio_extremes_and_threshold_checks():
    means, quats, scales, opac, _ = sphere(800)
    cam = candidate_cameras([0, 0, 0], ViewSelectionConfig(num_azimuths=1, distance=3.0))[0][0]
    assert visibility_ratio(means, quats, scales, opac, torch.ones(800, dtype=torch.bool), cam)[0] == pytest.approx(1.0)
    assert visibility_ratio(means, quats, scales, opac, torch.zeros(800, dtype=torch.bool), cam)[0] == 0.0
    for bad in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match=r"threshold must be in \(0, 1\)"):
            ViewSelectionConfig(threshold=bad)


def test_trained_stage1_avatar_has_unseen_back_views(tiny_scene, tiny_config):
    from reconstruct.train.trainer import Trainer

    s = Trainer(tiny_scene, tiny_config)
    for _ in range(12):
        s.step()
    canon = s.model.canonical()
    views = select_views(canon.means.detach(), torch.tensor([[1.0, 0, 0, 0]]).expand(len(canon.means), 4),
                         canon.scales.detach(), torch.ones(len(canon.means)), s.state.seen, canon.means.mean(0).tolist(),
                         ViewSelectionConfig(num_azimuths=8, distance=3.0, size=64))
    by_az = {round(v.azimuth_deg): v for v in views if v.elevation_deg == 0}
    assert not by_az[0].unseen and by_az[180].unseen


def test_the_seen_flags_are_moved_to_the_splats_device(monkeypatch):
    """The seen flags live on the CPU; on a GPU the splats do not. The flags are composited on the
    splats' device (here ``meta`` stands in for CUDA: the rasteriser stand-in checks the devices and
    then renders the CPU copies)."""
    from reconstruct.stage2 import view_selection

    means, quats, scales, opacities, _ = sphere(400)
    seen = means[:, 1] < 0
    real = view_selection.rasterization
    devices = []

    def checked(m, q, s, o, feats, camera):
        devices.append((m.device.type, feats.device.type))
        assert feats.device == m.device, f"features on {feats.device}, splats on {m.device}"
        return real(means, quats, scales, opacities, seen.float()[:, None], camera)

    monkeypatch.setattr(view_selection, "rasterization", checked)
    cam = candidate_cameras([0, 0, 0], ViewSelectionConfig())[0][0]
    meta = [t.to("meta") for t in (means, quats, scales, opacities)]
    ratio, _ = visibility_ratio(*meta, seen, cam)
    assert devices == [("meta", "meta")]
    assert ratio == pytest.approx(visibility_ratio(means, quats, scales, opacities, seen, cam)[0])
