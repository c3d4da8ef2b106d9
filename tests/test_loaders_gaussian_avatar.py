"""The GaussianAvatar layout (train/ split with cam_parms.npz and smpl_parms.pth)."""

import shutil

import numpy as np
import pytest
import torch

import smpl_synth as S
from reconstruct.data.load import load_scene
from reconstruct.data.loaders import LoaderError, detect_layout


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("ga")
    smpl = S.write_model(root / "smpl").parent
    info = S.write_gaussian_avatar(root / "snap_male3casual", S.build_model()[0], T=5)
    return root / "snap_male3casual", smpl, info


def test_loads_and_projects_like_smplx(data):
    folder, smpl, info = data
    assert detect_layout(folder) == "gaussian_avatar"
    scene = load_scene(f"gaussian_avatar:{folder},smpl_dir={smpl},eval_every=4")
    assert len(scene.frames) == 5 and scene.meta["source_frames"] == ["00000", "00001", "00002", "00003", "00004"]
    cam = scene.frames[0].camera
    assert np.allclose(cam.R, info["E"][:3, :3]) and np.allclose(cam.t, info["E"][:3, 3])
    f = scene.frames[1]
    assert set(np.unique(f.mask)) == {0.0, 1.0}
    for pos in (0, 3):
        assert S.projection_error(scene, pos, info["world"][pos], info["K"], info["E"][:3, :3], info["E"][:3, 3]) < 1e-5
    assert [v.frame_index for v in scene.eval_views] == [0, 4]


def test_trains_and_evaluates(data, tiny_config):
    folder, smpl, _ = data
    scene = load_scene(f"auto:{folder},smpl_dir={smpl},frames=1:4")
    losses, rows, _ = S.train_and_evaluate(scene, tiny_config)
    assert all(np.isfinite(losses)) and len(rows) == 1 and np.isfinite(rows[0]["psnr"])


def test_bad_inputs_are_named(data, tmp_path):
    folder, smpl, _ = data
    bad = tmp_path / "bad"
    shutil.copytree(folder, bad)
    pth = bad / "train" / "smpl_parms.pth"
    d = torch.load(pth)
    torch.save({**d, "body_pose": torch.zeros(5, 165)}, pth)
    with pytest.raises(LoaderError, match=r"smpl_parms.pth: 'body_pose' has shape \(5, 165\), expected \(T, 72\).*SMPL-X"):
        load_scene(bad)
    torch.save({**d, "body_pose": d["body_pose"][:3], "trans": d["trans"][:3]}, pth)
    with pytest.raises(LoaderError, match=r"smpl_parms.pth: mismatched frame counts: 3 poses for 5 images"):
        load_scene(bad)
    torch.save(d, pth)
    import imageio.v3 as iio

    iio.imwrite(bad / "train" / "images" / "00003.png", np.zeros((64, 80, 3), np.uint8))
    with pytest.raises(LoaderError, match=r"00003.png: the image is 80x64, expected 64x64 \(the size of 00000.png"):
        load_scene(bad)
