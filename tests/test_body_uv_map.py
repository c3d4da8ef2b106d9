import numpy as np
import torch
import trimesh

from reconstruct.body.parts import PART_NAMES
from reconstruct.body.pose import BodyPose
from reconstruct.body.uv_map import build_uv_map, posed_position_map, texel_spacing


def test_uv_map_256_counts_weights_and_parts(anny_body):
    uv = build_uv_map(anny_body, 256)
    n = len(uv)
    assert 35_000 < n < 45_000, n
    assert uv.mask.sum() == n
    assert (uv.weights.sum(1) - 1).abs().max() < 1e-12
    assert (uv.weights >= 0).all()
    assert set(np.unique(uv.parts)) == set(range(len(PART_NAMES)))
    assert torch.allclose(uv.normals.norm(dim=1), torch.ones(n, dtype=torch.float64))


def test_uv_map_texels_sit_at_their_texel_centres(anny_body):
    """Independent check of the UV rasterisation: the UV point recovered from each texel's triangle
    and barycentrics (trimesh's barycentric conversion) is the texel centre, and the 3D point is the
    same barycentric combination of the triangle's canonical vertices."""
    R = 128
    uv = build_uv_map(anny_body, R)
    uv_tri = anny_body.uv_coords.numpy()[anny_body.face_uv_indices.numpy()][uv.face]
    centres = np.stack([(uv.texel_rc[:, 1] + 0.5) / R, 1.0 - (uv.texel_rc[:, 0] + 0.5) / R], 1)
    tri3 = np.concatenate([uv_tri, np.zeros((len(uv), 3, 1))], 2)
    bary = trimesh.triangles.points_to_barycentric(tri3, np.concatenate([centres, np.zeros((len(uv), 1))], 1))
    assert np.abs(bary - uv.bary).max() < 1e-6
    verts = anny_body.canonical_vertices.numpy()[anny_body.faces.numpy()[uv.face]]
    assert np.abs(np.einsum("nk,nkd->nd", bary, verts) - uv.positions.numpy()).max() < 1e-6


def test_uv_map_excludes_inner_surfaces(anny_body):
    uv = build_uv_map(anny_body, 256)
    faces_used = set(uv.face.tolist())
    # every excluded texel centre is on a cavity/eye/tongue colour of Anny's segmentation
    uv_tri = anny_body.uv_coords.numpy()[anny_body.face_uv_indices.numpy()]
    centres = uv_tri.mean(1)
    excluded_faces = np.where(anny_body.excluded_uv(centres))[0]
    assert len(excluded_faces) > 100  # eyes, cavities and tongue exist and are found
    assert len(faces_used & set(excluded_faces.tolist())) < 0.02 * len(excluded_faces)


def test_uv_map_scales_with_resolution(anny_body):
    n64, n128 = len(build_uv_map(anny_body, 64)), len(build_uv_map(anny_body, 128))
    assert 3.3 < n128 / n64 < 4.7


def test_posed_position_map_is_lbs_of_canonical_points(anny_body):
    uv = build_uv_map(anny_body, 64)
    rng = np.random.default_rng(5)
    pose = BodyPose(rng.normal(0, 0.2, (anny_body.num_joints, 3)), np.array([0.0, 0.0, 1.0]), np.array([0.5, 0, 0]))
    img = posed_position_map(anny_body, uv, pose)
    assert img.shape == (3, 64, 64) and img.dtype == torch.float32
    assert (img[:, ~torch.as_tensor(uv.mask)] == 0).all()
    # independent path: posed mesh vertices interpolated with the texels' barycentrics
    no_global = BodyPose(pose.joint_rotations, np.zeros(3), np.zeros(3))
    verts = anny_body.posed_vertices(no_global)
    tri = anny_body.faces[torch.as_tensor(uv.face)]
    ref = (torch.as_tensor(uv.bary)[:, :, None] * verts[tri]).sum(1)
    got = img[:, uv.texel_rc[:, 0], uv.texel_rc[:, 1]].T.double()
    # LBS is not linear inside a triangle: texel points differ from interpolated posed corners by
    # at most millimetres
    assert (got - ref).norm(dim=1).median() < 1e-4
    assert (got - ref).norm(dim=1).max() < 5e-3
    # the global motion is left out unless asked for
    with_global = posed_position_map(anny_body, uv, pose, include_global=True)
    assert (with_global - img).abs().max() > 0.1


def test_texel_spacing_is_positive_and_plausible(anny_body):
    uv = build_uv_map(anny_body, 128)
    s = texel_spacing(uv)
    assert (s > 0).all()
    assert 0.002 < float(s.median()) < 0.03
