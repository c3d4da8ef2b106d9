"""MonoCap: 1-based frame files (images and params/<n>.npy from 1) and .jpg masks."""

import numpy as np
import pytest

import smpl_synth as S
from reconstruct.data.load import load_scene
from reconstruct.data.loaders import LoaderError, detect_layout


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("monocap")
    smpl = S.write_model(root / "smpl").parent
    info = S.write_annots_dataset(root / "lan_images620_1300", S.build_model()[0], "monocap", T=5, distort_camera=None)
    return root / "lan_images620_1300", smpl, info


def test_one_based_frames_and_jpg_masks(data):
    folder, smpl, info = data
    assert detect_layout(folder) == "monocap"
    scene = load_scene(f"{folder},smpl_dir={smpl},eval_every=3")  # a bare folder with options: detected
    assert scene.meta["source_frames"] == [1, 2, 3, 4, 5]  # image 000001.jpg -> params/1.npy
    assert scene.meta["layout"] == "monocap" and not scene.meta["skipped"]
    for f in scene.frames[:2]:
        assert set(np.unique(f.mask)) == {0.0, 1.0}  # lossy .jpg masks thresholded at half
    # the pose of frame position k is params/<k+1>.npy: the body projects like EasyMocap's
    c = info["cams"]
    for pos in (0, 4):
        assert S.projection_error(scene, pos, info["world"][pos], c["K"][0], c["R"][0], c["T"][0] / 1000.0) < 1e-6
    # the mask agrees with that body (jpg noise aside)
    f = scene.frames[4]
    uv, _ = f.camera.project(scene.body_model().posed_vertices(f.pose).numpy())
    px = np.clip(uv.astype(int), 0, 63)
    assert f.mask[px[:, 1], px[:, 0]].mean() > 0.97
    assert len(scene.eval_views) == 2 * 4 and {v.frame_index for v in scene.eval_views} == {0, 3}


def test_trains_and_evaluates(data, tiny_config):
    folder, smpl, _ = data
    scene = load_scene(f"monocap:{folder},smpl_dir={smpl},frames=0:2,eval_cameras=01+03")
    losses, rows, summary = S.train_and_evaluate(scene, tiny_config, steps=3)
    assert all(np.isfinite(losses)) and [r["view"] for r in rows] == ["01", "03"]
    assert [r["seen"] for r in rows] == [True, False] and all(np.isfinite(r["psnr"]) for r in rows)


def test_frames_without_parameters(data, tmp_path):
    import shutil

    folder, smpl, _ = data
    bad = tmp_path / "m"
    shutil.copytree(folder, bad)
    shutil.rmtree(bad / "params")
    (bad / "params").mkdir()
    with pytest.warns(UserWarning), pytest.raises(LoaderError, match=r"none of the 5 selected frames of camera 00.*no params/1.npy"):
        load_scene(f"monocap:{bad},smpl_dir={smpl}")
    with pytest.raises(LoaderError, match="training camera 9 does not exist"):
        load_scene(f"monocap:{folder},train_camera=9")
