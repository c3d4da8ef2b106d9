"""PeopleSnapshot as processed by InstantAvatar."""

import shutil

import numpy as np
import pytest

import smpl_synth as S
from reconstruct.data.load import load_scene
from reconstruct.data.loaders import LoaderError, detect_layout


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("snapshot")
    smpl = S.write_model(root / "smpl", gender="FEMALE").parent
    S.write_model(root / "smpl", gender="MALE")
    info = S.write_snapshot(root / "female-3-casual", S.build_model()[0], T=5)
    return root / "female-3-casual", smpl, info


def test_loads_and_projects_like_smplx(data):
    folder, smpl, info = data
    assert detect_layout(folder) == "snapshot"
    scene = load_scene(f"snapshot:{folder},smpl_dir={smpl},eval_every=2")
    assert len(scene.frames) == 5 and scene.meta["source_frames"] == [0, 1, 2, 3, 4]
    assert dict(scene.body.params)["gender"] == "female"  # from the subject's folder name
    cam = scene.frames[0].camera
    assert np.allclose(cam.K[:2, 2], info["K"][:2, 2] + 0.5) and np.allclose(cam.R, np.eye(3))
    f = scene.frames[2]
    assert set(np.unique(f.mask)) == {0.0, 1.0} and np.all(f.image[f.mask == 0] == 0)
    assert np.allclose(np.median(f.image[f.mask == 1], 0), np.array([90, 180, 220]) / 255, atol=1e-6)
    for pos in range(5):
        assert S.projection_error(scene, pos, info["world"][pos], info["K"], info["E"][:3, :3], info["E"][:3, 3]) < 1e-6
    assert [(v.frame_index, v.seen) for v in scene.eval_views] == [(0, True), (2, True), (4, True)]


def test_missing_frame_keeps_numbering(data, tmp_path):
    folder, smpl, info = data
    gap = tmp_path / "male-1"
    shutil.copytree(folder, gap)
    (gap / "images" / "image_0002.png").unlink()
    (gap / "masks" / "mask_0002.npy").unlink()
    scene = load_scene(f"snapshot:{gap},smpl_dir={smpl}")
    assert scene.meta["source_frames"] == [0, 1, 3, 4] and dict(scene.body.params)["gender"] == "male"
    assert S.projection_error(scene, 2, info["world"][3], info["K"], info["E"][:3, :3], info["E"][:3, 3]) < 1e-6


def test_trains_and_evaluates(data, tiny_config):
    folder, smpl, _ = data
    scene = load_scene(f"snapshot:{folder},smpl_dir={smpl},frames=0:5:2")
    losses, rows, _ = S.train_and_evaluate(scene, tiny_config)
    assert all(np.isfinite(losses)) and len(rows) == 1 and np.isfinite(rows[0]["psnr"])


def test_bad_inputs_are_named(data, tmp_path):
    folder, smpl, _ = data
    bad = tmp_path / "bad"
    shutil.copytree(folder, bad)
    (bad / "masks" / "mask_0004.npy").unlink()
    with pytest.raises(LoaderError, match=r"mismatched frames: 5 images, 4 masks; images without a mask: \['image_0004.png'\]"):
        load_scene(f"snapshot:{bad}")
    np.save(bad / "masks" / "mask_0004.npy", np.zeros((64, 64), np.uint8))
    z = dict(np.load(bad / "poses.npz"))
    np.savez(bad / "poses.npz", **{**z, "thetas": z["thetas"][:4], "transl": z["transl"][:4]})
    with pytest.raises(LoaderError, match=r"poses.npz: mismatched frame counts: 4 poses, but 5 images .* up to 4 \(image_0004.png\)"):
        load_scene(f"snapshot:{bad}")
    np.savez(bad / "poses.npz", **{**z, "thetas": z["thetas"][:, :69]})
    with pytest.raises(LoaderError, match=r"poses.npz: 'thetas' has shape \(5, 69\), expected \(T, 72\)"):
        load_scene(f"snapshot:{bad}")
    np.savez(bad / "poses.npz", **z)
    np.save(bad / "masks" / "mask_0004.npy", np.zeros((60, 64), np.uint8))
    with pytest.raises(LoaderError, match=r"mask_0004.npy: the mask is 64x60, expected 64x64 \(height/width in cameras.npz\)"):
        load_scene(f"snapshot:{bad}")
