"""The SMPL backend, on a synthetic SMPL-shaped model written in SMPL's file formats."""

import math

import numpy as np
import pytest
import torch

import smpl_synth as S
from reconstruct.body import smpl_backend as B
from reconstruct.body.spec import smpl_body_spec
from reconstruct.body.uv_map import build_uv_map

BETAS = np.linspace(-1.0, 1.0, 10)


@pytest.fixture(scope="module")
def model_dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("smpl")
    return {fmt: S.write_model(root / fmt, fmt=fmt).parent for fmt in ("npz", "pkl", "chumpy")}


@pytest.fixture(scope="module")
def arrays():
    return S.build_model()[0]


@pytest.fixture(scope="module")
def body(model_dirs):
    return smpl_body_spec(BETAS, "neutral", model_dirs["npz"]).build()


def random_pose(seed):
    rng = np.random.default_rng(seed)
    return rng.normal(0, 0.4, 72), rng.normal(0, 1.0, 3), rng.normal(0, 1.0, 3)


@pytest.mark.parametrize("fmt", ["npz", "pkl", "chumpy"])
def test_model_files_load_without_chumpy(model_dirs, arrays, fmt):
    import sys

    assert "chumpy" not in sys.modules
    path = B.find_model_file("neutral", model_dirs[fmt])
    got = B.load_model_arrays(path)
    for key in ("v_template", "weights", "J_regressor", "shapedirs", "posedirs"):
        assert np.allclose(got[key], arrays[key], atol=0, rtol=0), key
    assert np.array_equal(got["f"], arrays["f"].astype(np.int64))
    assert got["parents"].tolist() == S.PARENTS.tolist()


def test_pickle_with_other_classes_is_refused(tmp_path):
    import os
    import pickle

    class Evil:
        def __reduce__(self):
            return (os.system, ("echo pwned",))

    path = tmp_path / "SMPL_NEUTRAL.pkl"
    path.write_bytes(pickle.dumps({"v_template": Evil()}))
    with pytest.raises(B.SMPLFilesError, match=r"SMPL_NEUTRAL.pkl.*refusing to load (posix|nt)\.system"):
        B.load_model_arrays(path)


def test_lbs_matches_independent_float64_smpl_with_easymocap_rh_th(body, arrays):
    for seed in range(3):
        full, Rh, Th = random_pose(seed)
        ours = body.posed_vertices(B.smpl_body_pose(full, transl=Th, Rh=Rh)).numpy()
        ref = S.smpl_forward(arrays, full, BETAS) @ S.rodrigues(Rh).T + Th
        assert np.abs(ours - ref).max() < 1e-10
        # joints: SMPL's regressed joints, posed
        joints = body.posed_joints(B.smpl_body_pose(full, transl=Th, Rh=Rh)).numpy()
        assert joints.shape == (24, 3)


def test_lbs_matches_smplx_forward(body, arrays):
    smplx = pytest.importorskip("smplx")
    from smplx.utils import Struct

    st = Struct(**{**arrays, "posedirs": np.zeros_like(arrays["posedirs"]), "f": arrays["f"].astype(np.int64)})
    model = smplx.SMPL("", data_struct=st, vertex_ids={k: 0 for k in ("nose", "reye", "leye", "rear", "lear")},
                       use_hands=False, use_feet_keypoints=False, dtype=torch.float64)
    full, _, transl = random_pose(7)
    out = model(betas=torch.tensor(BETAS)[None], global_orient=torch.tensor(full[:3])[None],
                body_pose=torch.tensor(full[3:])[None], transl=torch.tensor(transl)[None])
    ours = body.posed_vertices(B.smpl_body_pose(full, transl=transl)).numpy()
    # smplx keeps its buffers in float32 internally
    assert np.abs(ours - out.vertices[0].detach().numpy()).max() < 1e-5


def test_pose_correctives_are_the_only_difference(body, arrays):
    full, Rh, Th = random_pose(4)
    ours = body.posed_vertices(B.smpl_body_pose(full, transl=Th, Rh=Rh)).numpy()
    with_pd = S.smpl_forward(arrays, full, BETAS, posedirs=True) @ S.rodrigues(Rh).T + Th
    diff = np.abs(ours - with_pd).max()
    assert 1e-4 < diff < 0.2  # posedirs are left out by design (documented)


def test_body_space_canonical_pose_and_parts(body):
    # rest mesh: Z up (head above feet), facing -Y (feet tips in front: -Y)
    v = body.rest_vertices.numpy()
    head, feet = body.rest_joints[15].numpy(), body.rest_joints[[10, 11]].numpy()
    assert head[2] > feet[:, 2].max() + 1.2
    toes = v[body.skin_weights.argmax(1).numpy() == 10]
    assert toes[:, 1].mean() < body.rest_joints[7, 1].item() - 0.02
    # canonical: legs spread 15 deg each way, arms 45 deg down from horizontal; left is +X
    cj = body.canonical_joints.numpy()
    rj = body.rest_joints.numpy()
    ang = lambda d: math.degrees(math.atan2(d[0], -d[2]))  # in the body's frontal (XZ) plane, from straight down
    assert math.isclose(ang(cj[4] - cj[1]) - ang(rj[4] - rj[1]), 15.0, abs_tol=1e-6)
    assert math.isclose(ang(cj[5] - cj[2]) - ang(rj[5] - rj[2]), -15.0, abs_tol=1e-6)
    assert math.isclose(ang(cj[18] - cj[16]) - ang(rj[18] - rj[16]), -45.0, abs_tol=1e-6)  # left arm: from +X towards down
    assert math.isclose(ang(cj[19] - cj[17]) - ang(rj[19] - rj[17]), 45.0, abs_tol=1e-6)
    assert body.bone_labels[16] == "upperarm.L" and len(body.bone_labels) == 24
    from reconstruct.body.parts import PART_INDEX

    assert (body.vertex_parts == PART_INDEX["head"]).sum() > 0 and (body.vertex_parts == PART_INDEX["hand.R"]).sum() > 0


def test_bone_transforms_differentiable_and_uv_map(body):
    r = torch.zeros(24, 3, dtype=torch.float64, requires_grad=True)
    T = body.bone_transforms_t(r, torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64))
    T[:, :3, 3].sum().backward()
    assert r.grad is not None and torch.isfinite(r.grad).all() and r.grad.abs().sum() > 0
    uv = build_uv_map(body, 48)
    assert len(uv) > 500
    assert torch.allclose(uv.weights.sum(1), torch.ones(len(uv), dtype=torch.float64))


def test_missing_files_name_the_file_and_every_place(tmp_path, monkeypatch, model_dirs):
    monkeypatch.setenv("WONDERHUMAN_SMPL_DIR", str(tmp_path / "env"))
    monkeypatch.setenv("WONDERHUMAN_CACHE_DIR", str(tmp_path / "cache"))
    with pytest.raises(B.SMPLFilesError) as e:
        B.find_model_file("female", tmp_path / "given")
    msg = str(e.value)
    for s in ("SMPL_FEMALE.pkl", "basicModel_f_lbs_10_207_0_v1.0.0.pkl", str(tmp_path / "given"), str(tmp_path / "env"),
              str(tmp_path / "cache" / "smpl"), "smpl_dir"):
        assert s in msg
    # model present, UV layout missing
    (tmp_path / "given").mkdir()
    (tmp_path / "given" / "SMPL_NEUTRAL.npz").write_bytes((model_dirs["npz"] / "SMPL_NEUTRAL.npz").read_bytes())
    with pytest.raises(B.SMPLFilesError, match=r"UV layout file not found: looked for smpl_uv.obj"):
        smpl_body_spec((), "neutral", tmp_path / "given").build()
    # found through the environment variable
    (tmp_path / "env").mkdir()
    for name in ("SMPL_NEUTRAL.npz", "smpl_uv.obj"):
        (tmp_path / "env" / name).write_bytes((model_dirs["npz"] / name).read_bytes())
    assert smpl_body_spec().build().num_joints == 24


def test_bad_model_file_is_named(tmp_path, arrays):
    bad = dict(arrays)
    bad["weights"] = bad["weights"][:, :23]
    np.savez(tmp_path / "SMPL_NEUTRAL.npz", **bad)
    with pytest.raises(B.SMPLFilesError, match=r"SMPL_NEUTRAL.npz: 'weights' has shape \(896, 23\), expected \(896, 24\)"):
        B.load_model_arrays(tmp_path / "SMPL_NEUTRAL.npz")
    with pytest.raises(ValueError, match="expected 72 values"):
        B.smpl_body_pose(np.zeros(69))


def test_pose_refinement_leaves_smpls_hands_and_toes_and_turns_the_rest():
    from reconstruct.body.parts import refinable_bone
    from reconstruct.body.smpl_backend import BONE_LABELS

    fixed = [b for b in BONE_LABELS if not refinable_bone(b)]
    assert sorted(fixed) == ["finger.L", "finger.R", "toe.L", "toe.R"]
    assert refinable_bone("upperarm01.L") and refinable_bone("head") and not refinable_bone("eye.R")
