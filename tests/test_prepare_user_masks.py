"""``prepare`` with the user's own person masks: a cut-out's transparency or ``--masks`` (a mask image,
a folder of mask images matched by name or by order, a mask video); sizes, orientation and the crop;
the errors that name the file. The pipeline runs with ``SyntheticSceneDetector`` (a TEST DOUBLE, see
test_prepare_video.py), whose masks are the scene's true ones, so a user mask that differs from them
shows in the scene written."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from reconstruct.data.prepare import InputError, alpha_video, prepare_video
from reconstruct.data.prepare.crop import Crop, apply_crop
from reconstruct.data.prepare.fit import FitConfig
from reconstruct.data.prepare.masks import fill_holes
from reconstruct.data.prepare.user_masks import image_alpha, mask_from_image, read_user_masks, video_alpha
from reconstruct.data.scene_io import read_scene
from test_prepare_inputs import synth  # noqa: F401 - the module's synthetic scene fixture, shared
from test_prepare_video import SyntheticSceneDetector

QUICK = FitConfig(keypoint_iters=60, silhouette_iters=0)



def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.asarray(x) * 255 + 0.5, 0, 255).astype(np.uint8)


def _bitten(mask: np.ndarray) -> np.ndarray:
    """The mask with a block of the person's middle cleared: what the user says the segmenter got wrong
    (as the wall between an arm and a skirt); hole filling would close it, the user's mask keeps it."""
    out = mask.copy()
    ys, xs = np.nonzero(mask > 0.5)
    cy, cx = int(ys.mean()), int(xs.mean())
    out[cy - 2:cy + 2, cx - 2:cx + 1] = 0.0
    return out


# ----- reading one mask --------------------------------------------------------------------------------
def test_a_mask_image_is_its_alpha_or_its_brightness(tmp_path):
    a = np.zeros((20, 10), np.uint8)
    a[5:15, 2:8] = 255
    a[0, 0] = 128
    rgba = np.zeros((20, 10, 4), np.uint8)
    rgba[..., :3] = 255 - a[..., None]  # colours that say the opposite: the alpha is what counts
    rgba[..., 3] = a
    Image.fromarray(rgba, "RGBA").save(tmp_path / "cut.png")
    Image.fromarray(a, "L").save(tmp_path / "grey.png")
    Image.fromarray(np.repeat(a[..., None], 3, -1), "RGB").save(tmp_path / "rgb.png")
    Image.fromarray(a.astype(np.uint16) * 257).save(tmp_path / "grey16.png")
    opaque = rgba.copy()
    opaque[..., 3] = 255
    Image.fromarray(opaque, "RGBA").save(tmp_path / "opaque.png")
    for name in ("cut.png", "grey.png", "rgb.png", "grey16.png"):
        m = mask_from_image(tmp_path / name)
        assert m.dtype == np.float32 and m.shape == (20, 10), name
        np.testing.assert_allclose(m, a / 255.0, atol=1e-6, err_msg=name)
    assert image_alpha(tmp_path / "grey.png") is None
    assert image_alpha(tmp_path / "opaque.png") is None  # opaque everywhere: not a cut-out
    # an opaque RGBA image is read by its brightness, as any other picture
    np.testing.assert_allclose(mask_from_image(tmp_path / "opaque.png"), 1.0 - a / 255.0, atol=2 / 255)


def test_a_mask_of_another_resolution_is_resized_and_another_shape_is_refused(tmp_path):
    a = np.zeros((40, 20), np.float32)
    a[10:30, 5:15] = 1.0
    Image.fromarray(_u8(a), "L").save(tmp_path / "half.png")
    Image.fromarray(_u8(a[:, :18]), "L").save(tmp_path / "narrow.png")
    Image.fromarray(np.zeros((10, 10), np.uint8)).save(tmp_path / "frame.png")
    m, src = read_user_masks(tmp_path / "half.png", tmp_path / "frame.png", names=["frame.png"],
                             indices=np.array([0]), source_size=(40, 80))
    assert src == str(tmp_path / "half.png") and m.shape == (1, 80, 40)
    # bilinear at twice the size: the block's inside stays person, far outside stays empty
    assert m[0, 30:50, 14:26].min() > 0.99 and m[0, :15].max() < 0.01
    with pytest.raises(InputError, match=r"narrow.png: the mask is 18x40 pixels, the frame of frame.png is 40x80"):
        read_user_masks(tmp_path / "narrow.png", tmp_path / "frame.png", names=["frame.png"],
                        indices=np.array([0]), source_size=(40, 80))
    with pytest.raises(FileNotFoundError, match="nothere.png: no such mask"):
        read_user_masks(tmp_path / "nothere.png", tmp_path / "frame.png", names=["frame.png"],
                        indices=np.array([0]), source_size=(10, 10))


def test_masks_follow_the_frames_turns_and_crop(tmp_path):
    """A mask is turned as its frame was (a lying person read standing) and cropped with it, so that
    it lies on the same pixels as the frame ``prepare`` keeps."""
    img = np.zeros((30, 50, 3), np.uint8)
    img[5:12, 10:40] = 255
    Image.fromarray(img).save(tmp_path / "lying.png")
    Image.fromarray(img[..., 0]).save(tmp_path / "lying_mask.png")
    crop = Crop(2.0, 4.0, 20.0, 40.0, 10, 20)
    m, _ = read_user_masks(tmp_path / "lying_mask.png", tmp_path / "lying.png", names=["lying.png"],
                           indices=np.array([0]), source_size=(30, 50), turns=1,
                           transform=lambda x: apply_crop(x[None], crop)[0])
    frame = apply_crop(np.ascontiguousarray(np.rot90(img[..., 0] / 255.0, 1), np.float32)[None], crop)[0]
    assert m.shape == (1, 20, 10) and frame.max() == 1.0
    np.testing.assert_allclose(m[0], frame, atol=1e-6)
    # a quarter turn the other way puts the block elsewhere: the turn is not a no-op
    other, _ = read_user_masks(tmp_path / "lying_mask.png", tmp_path / "lying.png", names=["lying.png"],
                               indices=np.array([0]), source_size=(30, 50), turns=3,
                               transform=lambda x: apply_crop(x[None], crop)[0])
    assert np.abs(other[0] - frame).max() > 0.5


def test_a_folder_of_masks_is_matched_by_name_then_by_order(tmp_path):
    shots, masks, plain = tmp_path / "shots", tmp_path / "masks", tmp_path / "plain"
    for d in (shots, masks, plain):
        d.mkdir()
    for k, name in enumerate(("a.jpg", "b.jpg", "c.jpg")):
        Image.fromarray(np.zeros((8, 6, 3), np.uint8)).save(shots / name)
        # named as the frame with a suffix, in an order that their names alone would not give
        Image.fromarray(np.full((8, 6), 40 * (k + 1), np.uint8)).save(masks / f"{name[0]}_mask.png")
        Image.fromarray(np.full((8, 6), 40 * (k + 1), np.uint8)).save(plain / f"{k + 10:03d}.png")
    (masks / "notes.txt").write_text("not a mask")
    names, idx = ["a.jpg", "c.jpg"], np.array([0, 2])  # --every 2
    by_name, _ = read_user_masks(masks, shots, names=names, indices=idx, source_size=(6, 8))
    by_order, _ = read_user_masks(plain, shots, names=names, indices=idx, source_size=(6, 8))
    np.testing.assert_allclose(by_name[:, 0, 0], [40 / 255, 120 / 255], atol=1e-6)
    np.testing.assert_allclose(by_order[:, 0, 0], [40 / 255, 120 / 255], atol=1e-6)
    (plain / "999.png").write_bytes((plain / "010.png").read_bytes())
    with pytest.raises(InputError, match=r"plain: holds 4 mask images and no mask named as the frame a.jpg.*"
                                         r"one mask per image in the same order \(3\)"):
        read_user_masks(plain, shots, names=names, indices=idx, source_size=(6, 8))
    with pytest.raises(InputError, match=r"one mask image for 2 frames of shots"):
        read_user_masks(masks / "a_mask.png", shots, names=names, indices=idx, source_size=(6, 8))


def test_a_mask_video_gives_one_mask_per_frame(tmp_path):
    import imageio.v3 as iio

    T, H, W = 6, 64, 48
    frames = np.zeros((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t, 8:56, 4 + 4 * t:20 + 4 * t] = 255  # a block that walks right
    iio.imwrite(tmp_path / "clip.mp4", frames, plugin="pyav", codec="libx264", fps=10)
    iio.imwrite(tmp_path / "alpha.mp4", frames, plugin="pyav", codec="libx264", fps=10)
    names = [f"clip.mp4 frame {i}" for i in (0, 2, 4)]
    m, src = read_user_masks(tmp_path / "alpha.mp4", tmp_path / "clip.mp4", names=names,
                             indices=np.array([0, 2, 4]), source_size=(W, H), every=2)
    assert src == str(tmp_path / "alpha.mp4") and m.shape == (3, H, W)
    for k, t in enumerate((0, 2, 4)):
        assert ((m[k] > 0.5) == (frames[t, ..., 0] > 127)).mean() > 0.99
    with pytest.raises(InputError, match=r"alpha.mp4: gives 6 mask frames, clip.mp4 gives 3"):
        read_user_masks(tmp_path / "alpha.mp4", tmp_path / "clip.mp4", names=names,
                        indices=np.array([0, 2, 4]), source_size=(W, H))
    with pytest.raises(InputError, match=r"alpha.mp4: the mask is 48x64 pixels, the frame of clip.mp4 is 40x64"):
        read_user_masks(tmp_path / "alpha.mp4", tmp_path / "clip.mp4", names=names,
                        indices=np.array([0, 2, 4]), source_size=(40, 64), every=2)


# ----- through prepare ---------------------------------------------------------------------------------
def test_prepare_takes_the_users_masks_as_they_are(synth, tmp_path):
    """The test double reports the scene's true masks; the user's (the truth with a block of the
    middle cleared, an enclosed hole that hole filling would close) are what the scene keeps."""
    shots, masks = tmp_path / "shots", tmp_path / "masks"
    shots.mkdir()
    masks.mkdir()
    want = []
    for k in range(3):
        Image.fromarray(_u8(synth.frames[k].image)).save(shots / f"f{k}.png")
        m = _bitten(synth.frames[k].mask)
        want.append(m)
        Image.fromarray(_u8(m)).save(masks / f"f{k}.png")
    out = tmp_path / "scene"
    _, report = prepare_video(shots, out, detector=SyntheticSceneDetector(synth), fit_config=QUICK,
                              masks=masks, crop=False, log=lambda m: None)
    assert report["masks"]["source"] == str(masks) and report["masks"]["holes_filled"] == 0
    bite = (want[0] == 0) & (synth.frames[0].mask > 0.5)
    assert bite.sum() >= 12 and (fill_holes(want[0])[0][bite] == 1).all()  # the segmenter's would be closed
    scene = read_scene(out)
    for k, f in enumerate(scene.frames):
        assert np.abs(f.mask - want[k]).max() < 1 / 255 + 1e-6
        assert (f.image[want[k] == 0] == 0).all()  # the bite shows no wall: training sees it empty
    # the same without the user's masks: the detector's (the truth), its small holes filled
    _, plain = prepare_video(shots, tmp_path / "plain", detector=SyntheticSceneDetector(synth), fit_config=QUICK,
                             crop=False, log=lambda m: None)
    assert plain["masks"]["source"] == "segmenter"
    first = read_scene(tmp_path / "plain").frames[0]
    np.testing.assert_allclose(first.mask, fill_holes(synth.frames[0].mask, image=_u8(synth.frames[0].image))[0],
                               atol=1e-6)


def test_prepare_takes_a_cut_outs_alpha_unless_told_not_to(synth, tmp_path):
    rgba = np.concatenate([_u8(synth.frames[0].image), _u8(_bitten(synth.frames[0].mask))[..., None]], -1)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "cutout.png")
    _, report = prepare_video(tmp_path / "cutout.png", tmp_path / "a", detector=SyntheticSceneDetector(synth),
                              fit_config=QUICK, crop=False, log=lambda m: None)
    assert report["masks"]["source"] == "the input's transparency"
    mask = read_scene(tmp_path / "a").frames[0].mask
    assert np.abs(mask - _bitten(synth.frames[0].mask)).max() < 1 / 255 + 1e-6
    _, report = prepare_video(tmp_path / "cutout.png", tmp_path / "b", detector=SyntheticSceneDetector(synth),
                              fit_config=QUICK, crop=False, use_alpha=False, log=lambda m: None)
    assert report["masks"]["source"] == "segmenter"
    saved = json.loads((tmp_path / "b" / "prepare_report.json").read_text())
    assert saved["masks"]["source"] == "segmenter"


def test_prepare_names_a_bad_mask_and_writes_nothing(synth, tmp_path):
    Image.fromarray(_u8(synth.frames[0].image)).save(tmp_path / "person.png")
    Image.fromarray(np.zeros((50, 20), np.uint8)).save(tmp_path / "wrong.png")
    out = tmp_path / "scene"
    with pytest.raises(InputError, match=r"wrong.png: the mask is 20x50 pixels, the frame of person.png is 192x192"):
        prepare_video(tmp_path / "person.png", out, detector=SyntheticSceneDetector(synth), fit_config=QUICK,
                      masks=tmp_path / "wrong.png", crop=False, log=lambda m: None)
    assert not out.exists()


# ----- cut-out videos ----------------------------------------------------------------------------------
def _alpha_video(path, codec: str, pix: str, frames: np.ndarray, fps: int = 10):
    """Write (T,H,W,4) uint8 RGBA ``frames`` with PyAV (``codec`` keeping alpha in ``pix``)."""
    import av

    with av.open(str(path), "w") as c:
        st = c.add_stream(codec, rate=fps)
        st.width, st.height, st.pix_fmt = frames.shape[2], frames.shape[1], pix
        for f in frames:
            for p in st.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgba")):
                c.mux(p)
        for p in st.encode():
            c.mux(p)
    return path


def _cutout_clip(T=5, H=48, W=64) -> np.ndarray:
    rgba = np.zeros((T, H, W, 4), np.uint8)
    rgba[..., :3] = (250, 20, 20)  # a colour under the transparent pixels that must not show
    for t in range(T):
        rgba[t, 8:40, 8 + 6 * t:24 + 6 * t] = (30, 90, 160, 255)  # the person, walking right
    return rgba


@pytest.mark.parametrize("codec,pix,suffix", [("libvpx-vp9", "yuva420p", ".webm"), ("qtrle", "argb", ".mov"),
                                              ("prores_ks", "yuva444p10le", ".mov")])
def test_a_cut_out_videos_alpha_is_the_mask_and_its_frames_are_laid_over_the_wall(tmp_path, codec, pix, suffix):
    """WebM (VP9 with alpha, which ffmpeg's own decoder drops), QuickTime Animation and ProRes 4444."""
    from reconstruct.data.prepare.alpha_video import CUTOUT_BACKGROUND, alpha_decoder
    from reconstruct.data.prepare.video import read_video

    rgba = _cutout_clip()
    path = _alpha_video(tmp_path / f"cutout{suffix}", codec, pix, rgba)
    assert alpha_decoder(path) is not None
    v = read_video(path, max_size=None, every=2)
    assert v.frames.shape == (3, 48, 64, 3) and v.indices.tolist() == [0, 2, 4]
    inside, outside = v.frames[:, 20, 12].astype(int), v.frames[:, 2, 2].astype(int)
    assert np.abs(inside[0] - [30, 90, 160]).max() <= 12  # lossy codecs: within a few levels
    assert np.abs(outside - np.array(CUTOUT_BACKGROUND)).max() <= 12  # the wall, not the red underneath
    m, src = read_user_masks(None, path, names=[f"f{i}" for i in (0, 2, 4)], indices=v.indices,
                             source_size=v.source_size, every=2, alpha=v.alpha)
    assert src == "the input's transparency" and m.shape == (3, 48, 64)
    for k, t in enumerate((0, 2, 4)):
        assert ((m[k] > 0.5) == (rgba[t, ..., 3] > 127)).mean() > 0.99
    assert read_user_masks(None, path, names=["f0", "f2", "f4"], indices=v.indices, source_size=v.source_size,
                           every=2, use_alpha=False, alpha=v.alpha) == (None, "segmenter")


def test_a_cut_out_videos_alpha_is_read_with_its_frames_turned_cropped_and_resized_alike(tmp_path):
    """``Video.alpha`` (decoded with the colour) against the alpha decoded on its own (``video_alpha``,
    the --masks path) and against the frames it belongs to: a quarter turn, a crop and a resize."""
    from reconstruct.data.prepare.alpha_video import alpha_decoder
    from reconstruct.data.prepare.video import read_video

    rgba = _cutout_clip()
    path = _alpha_video(tmp_path / "cutout.mov", "qtrle", "argb", rgba)  # lossless
    crop = lambda f: np.ascontiguousarray(f[10:50, 4:36])  # noqa: E731 - a crop of the turned (64,48) frame
    v = read_video(path, max_size=None, every=2, turns=1, transform=crop)
    turned = np.rot90(rgba[::2], 1, axes=(1, 2))
    np.testing.assert_array_equal(v.alpha, turned[:, 10:50, 4:36, 3] / np.float32(255.0))
    person = v.alpha > 0.5  # the wall where the alpha is 0: the crop took the same pixels from both
    assert np.abs(v.frames[person].astype(int) - [30, 90, 160]).max() <= 1
    alone = video_alpha(path, alpha_decoder(path), lambda m, where: crop(m), turns=1, every=2)
    np.testing.assert_array_equal(v.alpha, alone)
    small = read_video(path, max_size=32, max_frames=2)
    assert small.alpha.shape == (2, 24, 32) == small.frames.shape[:3]
    big = rgba[:2, ..., 3].astype(np.float32) / 255.0
    np.testing.assert_allclose(small.alpha.mean((1, 2)), big.mean((1, 2)), atol=0.02)  # a resize keeps the cover
    rgba[..., 3] = 255
    assert read_video(_alpha_video(tmp_path / "opaque.mov", "qtrle", "argb", rgba)).alpha is None


def test_a_video_without_alpha_or_with_opaque_alpha_goes_to_the_segmenter(tmp_path):
    import imageio.v3 as iio

    from reconstruct.data.prepare.alpha_video import alpha_decoder

    rgba = _cutout_clip(T=3)
    iio.imwrite(tmp_path / "plain.mp4", rgba[..., :3], plugin="pyav", codec="libx264", fps=10)
    assert alpha_decoder(tmp_path / "plain.mp4") is None
    rgba[..., 3] = 255
    opaque = _alpha_video(tmp_path / "opaque.mov", "qtrle", "argb", rgba)
    assert alpha_decoder(opaque) == "qtrle"
    from reconstruct.data.prepare.video import read_video

    assert read_video(tmp_path / "plain.mp4").alpha is None and read_video(opaque).alpha is None
    assert read_user_masks(None, opaque, names=["a", "b", "c"], indices=np.arange(3),
                           source_size=(64, 48), alpha=read_video(opaque).alpha) == (None, "segmenter")


def test_prepare_takes_a_cut_out_videos_alpha(synth, tmp_path, monkeypatch):
    from reconstruct.data.prepare import user_masks as user_masks_module
    from reconstruct.data.prepare import video as video_module

    rgba = np.stack([np.concatenate([_u8(f.image), _u8(_bitten(f.mask))[..., None]], -1) for f in synth.frames[:3]])
    path = _alpha_video(tmp_path / "cutout.mov", "qtrle", "argb", rgba)  # lossless: the mask exactly
    decodes = []
    for module in (video_module, user_masks_module):  # every reader of a cut-out's RGBA frames
        monkeypatch.setattr(module, "rgba_frames", lambda *a, **k: decodes.append(a) or alpha_video.rgba_frames(*a, **k))
    _, report = prepare_video(path, tmp_path / "scene", detector=SyntheticSceneDetector(synth), fit_config=QUICK,
                              crop=False, log=lambda m: None)
    assert report["masks"]["source"] == "the input's transparency" and report["frames_used"] == 3
    assert len(decodes) == 2  # the preview and the frames; the alpha comes with the frames, not a third time
    for k, f in enumerate(read_scene(tmp_path / "scene").frames):
        assert np.abs(f.mask - _bitten(synth.frames[k].mask)).max() < 1 / 255 + 1e-6


def test_a_cut_out_video_given_as_the_masks_gives_its_alpha_not_its_brightness(tmp_path):
    import imageio.v3 as iio

    rgba = _cutout_clip(T=3)
    rgba[..., :3] = 255 - rgba[..., :3]  # colours whose brightness would say something else
    masks = _alpha_video(tmp_path / "matte.mov", "qtrle", "argb", rgba)
    iio.imwrite(tmp_path / "clip.mp4", rgba[..., :3], plugin="pyav", codec="libx264", fps=10)
    m, src = read_user_masks(masks, tmp_path / "clip.mp4", names=["a", "b", "c"], indices=np.arange(3),
                             source_size=(64, 48))
    assert src == str(masks)
    np.testing.assert_allclose(m, rgba[..., 3] / 255.0, atol=1e-6)


def test_a_scene_folders_fixed_masks_are_given_back(synth, tmp_path):
    """prepare -> the user fixes SCENE/frames/mask -> prepare --masks SCENE: the same crop takes the
    fixed masks as they are; another crop (another --size) puts them back into the photo by the old
    crop first. A scene prepared from another input is refused."""
    Image.fromarray(_u8(synth.frames[0].image)).save(tmp_path / "person.png")
    first = tmp_path / "first"
    prepare_video(tmp_path / "person.png", first, detector=SyntheticSceneDetector(synth), fit_config=QUICK,
                  log=lambda m: None)
    mask_file = first / "frames" / "mask" / "000000.png"
    fixed = _bitten(np.asarray(Image.open(mask_file), np.float32) / 255.0)
    Image.fromarray(_u8(fixed)).save(mask_file)
    _, report = prepare_video(tmp_path / "person.png", tmp_path / "again", detector=SyntheticSceneDetector(synth),
                              fit_config=QUICK, masks=first, log=lambda m: None)
    assert report["masks"]["source"] == str(first)
    np.testing.assert_allclose(read_scene(tmp_path / "again").frames[0].mask, fixed, atol=1 / 255 + 1e-6)
    Image.fromarray(_u8(synth.frames[1].image)).save(tmp_path / "other.png")
    with pytest.raises(InputError, match=r"first: was prepared from person.png, not other.png"):
        prepare_video(tmp_path / "other.png", tmp_path / "x", detector=SyntheticSceneDetector(synth),
                      fit_config=QUICK, masks=first, log=lambda m: None)


def test_a_scenes_masks_go_back_into_the_source_frame_by_its_crop(tmp_path):
    """A scene cropped round the person (a box inside the photo, resized): its masks are put back into
    the photo where that crop took them from, then cropped as this prepare crops. Checked against the
    photo's own mask cropped the new way."""
    from reconstruct.data.prepare.user_masks import scene_masks

    H0, W0 = 120, 90
    src = np.zeros((H0, W0), np.float32)
    src[30:100, 35:60] = 1.0
    old = Crop(20.0, 10.0, 60.0, 100.0, 30, 50)  # half resolution of a box inside the photo
    scene = tmp_path / "scene"
    (scene / "frames" / "mask").mkdir(parents=True)
    Image.fromarray(_u8(apply_crop(src[None], old)[0])).save(scene / "frames" / "mask" / "000003.png")
    (scene / "prepare_report.json").write_text(json.dumps({"crop": old.to_dict(), "source_frame_size": [W0, H0],
                                                           "video": str(tmp_path / "photo.png")}))
    new = Crop(0.0, 0.0, 90.0, 120.0, 45, 60)  # the whole photo this time
    place = lambda m, where: apply_crop(m[None], new)[0]  # noqa: E731
    got = scene_masks(scene, tmp_path / "photo.png", indices=np.array([3, 4]), source_size=(W0, H0), crop=new,
                      place=place)
    want = apply_crop(src[None], new)[0]
    assert got.shape == (2, 60, 45) and got[1].max() == 0.0  # frame 4: none in the scene, an empty mask
    assert ((got[0] > 0.5) == (want > 0.5)).mean() > 0.98 and np.abs(got[0] - want).mean() < 0.03
    # the old crop again: the scene's masks as they are
    same = scene_masks(scene, tmp_path / "photo.png", indices=np.array([3]), source_size=(W0, H0), crop=old,
                       place=place)
    np.testing.assert_allclose(same[0], np.asarray(Image.open(scene / "frames" / "mask" / "000003.png")) / 255.0,
                               atol=1e-6)
    with pytest.raises(InputError, match=r"scene: was prepared from frames of 90x120, photo.png's frames are 120x90"):
        scene_masks(scene, tmp_path / "photo.png", indices=np.array([3]), source_size=(120, 90), crop=new, place=place)
