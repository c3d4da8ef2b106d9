"""ZJU-MoCap in the Instant-NVR layout, layout detection and the loader spec syntax."""

import numpy as np
import pytest

import smpl_synth as S
from reconstruct.data.load import load_scene
from reconstruct.data.loaders import LoaderError, detect_layout, parse_spec
from reconstruct.data.loaders.common import undistort


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("zju")
    smpl = S.write_model(root / "smpl").parent
    arrays = S.build_model()[0]
    info = S.write_annots_dataset(root / "my_377", arrays, "zju", T=6)
    (root / "my_377" / "smpl_params" / "3.npy").unlink()  # a missing frame
    return root, smpl, info


def spec(data, extra=""):
    root, smpl, _ = data
    return f"zju:{root / 'my_377'},smpl_dir={smpl}" + extra


def test_loads_cameras_images_masks_and_skips_missing_frames(data):
    root, smpl, info = data
    with pytest.warns(UserWarning, match="left out 1 frame"):
        scene = load_scene(spec(data, ",eval_every=2"))
    assert len(scene.frames) == 5 and scene.meta["source_frames"] == [0, 1, 2, 4, 5]
    assert "no smpl_params/3.npy" in scene.meta["skipped"][0]
    cam = scene.frames[0].camera
    assert (cam.width, cam.height, cam.name) == (64, 64, "00")
    assert np.allclose(cam.t, info["cams"]["T"][0].reshape(3) / 1000.0)  # millimetres -> metres
    assert np.allclose(cam.R, info["cams"]["R"][0])
    assert np.allclose(cam.K[:2, 2], info["cams"]["K"][0][:2, 2] + 0.5)  # OpenCV -> pixel centres at +0.5
    f = scene.frames[1]
    assert set(np.unique(f.mask)) == {0.0, 1.0}  # masks stored 0/1 (camera 00)
    assert np.all(f.image[f.mask == 0] == 0)  # black outside the mask
    inside = f.image[f.mask == 1]
    assert np.allclose(np.median(inside, 0), np.array([200, 120, 60]) / 255, atol=0.04)  # the colour written (jpg)
    # evaluation: every other frame, 4 cameras; seen = within 45 deg of the training camera
    assert len(scene.eval_views) == 3 * 4
    seen = {v.camera.name: v.seen for v in scene.eval_views}
    assert seen == {"01": True, "02": False, "03": False, "04": False}
    az = {v.camera.name: v.azimuth_deg for v in scene.eval_views if v.frame_index == 0}
    assert abs(az["01"] - 30) < 3 and abs(az["02"] - 90) < 5 and abs(abs(az["03"]) - 180) < 5 and abs(az["04"] + 90) < 5
    assert scene.body.model == "smpl" and np.allclose(
        [float(b) for b in dict(scene.body.params)["betas"].split(",")], info["betas"], atol=1e-6)


def test_body_projects_like_easymocap(data):
    root, smpl, info = data
    scene = load_scene(spec(data, ",frames=0:3"))
    c = info["cams"]
    for pos in range(3):
        err = S.projection_error(scene, pos, info["world"][pos], c["K"][0], c["R"][0], c["T"][0] / 1000.0)
        assert err < 1e-6


def test_distorted_camera_is_undistorted(data):
    root, smpl, info = data
    # camera 02 has lens distortion: after undistortion its mask covers the body's pinhole projection
    scene = load_scene(spec(data, ",train_camera=02,frames=0:1,eval_cameras=00"))
    f = scene.frames[0]
    body = scene.body_model()
    uv, _ = f.camera.project(body.posed_vertices(f.pose).numpy())
    px = np.clip(uv.astype(int), 0, 63)
    assert f.mask[px[:, 1], px[:, 0]].mean() > 0.97
    # undistort() moves a dot from its distorted position back to the pinhole one
    K = np.array([[70.0, 0, 31.5], [0, 70.0, 31.5], [0, 0, 1]])
    D = np.array([-0.6, 0.1, 0.002, -0.002, 0.0])
    p = np.array([[0.4, -0.3, 1.0]])
    ud, vd = S.opencv_project(p, K, np.eye(3), np.zeros(3), D)[0]
    img = np.zeros((64, 64), np.float32)
    yy, xx = np.mgrid[0:64, 0:64]
    img[(xx - ud) ** 2 + (yy - vd) ** 2 <= 2.0] = 1.0
    out = undistort(img, K, D)
    u0, v0 = S.opencv_project(p, K, np.eye(3), np.zeros(3))[0]
    cy, cx = (np.array([yy[out > 0.5].mean(), xx[out > 0.5].mean()]))
    assert abs(cx - u0) < 0.6 and abs(cy - v0) < 0.6 and np.hypot(ud - u0, vd - v0) > 2.0


def test_protocol_options(data):
    with pytest.warns(UserWarning):
        scene = load_scene(spec(data, ",train_camera=1,frames=1:6:2,eval_cameras=2,eval_every=1,scale=0.5"))
    assert scene.meta["train_camera"] == "01" and scene.meta["source_frames"] == [1, 5]  # frame 3 is missing
    assert scene.frames[0].camera.width == 32 and scene.frames[0].image.shape == (32, 32, 3)
    assert len(scene.meta["eval_cameras"]) == 2 and "01" not in scene.meta["eval_cameras"]
    assert scene.fps == 15.0


def test_loaded_scene_round_trips_through_a_scene_folder(data, tmp_path):
    from reconstruct.data.scene_io import read_scene, write_scene

    with pytest.warns(UserWarning):
        scene = load_scene(spec(data, ",frames=0:4,eval_every=3"))
    back = read_scene(write_scene(scene, tmp_path / "s"))
    assert back.body == scene.body and back.body_model().num_joints == 24
    assert len(back.frames) == 3 and len(back.eval_views) == 4
    assert np.allclose(back.frames[2].pose.to_vector(), scene.frames[2].pose.to_vector())
    assert np.abs(back.frames[1].image - scene.frames[1].image).max() <= 0.5 / 255 + 1e-6


def test_trains_and_evaluates(data, tiny_config):
    scene = load_scene(spec(data, ",frames=0:3,eval_every=2"))
    losses, rows, summary = S.train_and_evaluate(scene, tiny_config)
    assert all(np.isfinite(losses)) and len(rows) == len(scene.eval_views) == 8
    assert all(np.isfinite(r["psnr"]) and 0 < r["ssim"] <= 1 for r in rows)


def test_detection_and_spec_syntax(data, tmp_path):
    root, smpl, _ = data
    assert detect_layout(root / "my_377") == "zju"
    layout, folder, proto = parse_spec(f"auto:{root},frames=0:300:5,train_camera=B1,eval_cameras=6")
    assert layout is None and folder == root and proto.frames == (0, 300, 5) and proto.train_camera == "B1"
    assert proto.eval_cameras == 6
    with pytest.raises(ValueError, match="unknown key 'fps'"):
        parse_spec("zju:/x,fps=3")
    with pytest.raises(ValueError, match="frames='a:b'"):
        parse_spec("zju:/x,frames=a:b")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "notes.txt").write_text("x")
    with pytest.raises(LoaderError) as e:
        load_scene(tmp_path / "junk")
    for need in ("unknown dataset layout", "notes.txt", "zju: annots.npy", "monocap: annots.npy, params/",
                 "snapshot: cameras.npz, poses.npz", "gaussian_avatar:", "scene.json"):
        assert need in str(e.value)


def test_missing_annots_and_bad_parameters(data, tmp_path):
    import shutil

    root, smpl, _ = data
    bad = tmp_path / "bad"
    shutil.copytree(root / "my_377", bad)
    (bad / "annots.npy").unlink()
    with pytest.raises(LoaderError, match=r"bad/annots.npy: missing; the folder has smpl_params/"):
        load_scene(bad)
    with pytest.raises(LoaderError, match=r"bad/annots.npy: missing \(camera parameters"):
        load_scene(f"zju:{bad}")
    shutil.copy(root / "my_377" / "annots.npy", bad / "annots.npy")
    p = np.load(bad / "smpl_params" / "0.npy", allow_pickle=True).item()
    p["poses"] = p["poses"][:, :69]
    np.save(bad / "smpl_params" / "0.npy", p)
    with pytest.raises(LoaderError, match=r"smpl_params/0.npy: 'poses' has shape \(1, 69\), expected \(1, 72\)"):
        load_scene(f"zju:{bad},frames=0:2")
    import imageio.v3 as iio

    iio.imwrite(bad / "images" / "00" / "000001.jpg", np.zeros((48, 64, 3), np.uint8))
    shutil.copy(root / "my_377" / "smpl_params" / "0.npy", bad / "smpl_params" / "0.npy")
    with pytest.raises(LoaderError, match=r"images/00/000001.jpg: the image is 64x48, expected 64x64 \(the size of 000000.jpg"):
        load_scene(f"zju:{bad},frames=0:2")
