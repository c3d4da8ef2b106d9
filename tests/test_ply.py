"""Gaussians as 3DGS ``.ply`` files (``reconstruct.ply``): the layout other viewers read (checked with
``plyfile``), round trips in both frames, files written by others (property order, ascii, big
endian, SH degree 1, extra properties, no normals), malformed files, sequences written all or
nothing, and a render check: the live avatar and its re-read file drawn by our splat renderer
(``-s`` prints the PSNR figures)."""

from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest

plyfile = pytest.importorskip("plyfile")

from reconstruct.camera import Camera  # noqa: E402
from reconstruct.ply import (C0, UP_ROTATION, PlyFormatError, num_rest_coefficients, ply_to_snapshot,  # noqa: E402
                             property_names, read_gaussians_ply, read_snapshot_ply, write_gaussians_ply,
                             write_ply_sequence, write_snapshot_ply)
from reconstruct.snapshot import Snapshot  # noqa: E402


def quat_matrix(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(q.shape[:-1] + (3, 3))


def gaussians(n: int = 200, seed: int = 0) -> dict:
    """Random Gaussians in Snapshot conventions; some opacities exactly 1 (as the avatar's),
    quaternions not normalised (the writer normalises)."""
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(n, 3))
    op = rng.uniform(0.05, 1.0, n)
    op[: n // 4] = 1.0
    return {"means": rng.normal(0, 0.5, (n, 3)) + [0, 0, 0.9], "scales": np.exp(rng.normal(-4.5, 0.5, (n, 3))),
            "rotations": rng.normal(size=(n, 4)) * 3.0, "opacities": op, "colors": rng.uniform(0, 1, (n, 3)),
            "normals": normals / np.linalg.norm(normals, axis=1, keepdims=True)}


def logit(p):
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


# ----------------------------------------------------------------------------- the layout
@pytest.mark.parametrize("sh_degree", [3, 0])
def test_layout_read_by_plyfile(tmp_path, sh_degree):
    g = gaussians()
    path = write_gaussians_ply(tmp_path / "a.ply", **g, up="z_up", sh_degree=sh_degree, comments=["made by a test"])
    ply = plyfile.PlyData.read(str(path))
    assert ply.text is False and ply.byte_order == "<"
    assert [e.name for e in ply.elements] == ["vertex"]
    v = ply["vertex"]
    k = num_rest_coefficients(sh_degree)
    assert k == {3: 45, 0: 0}[sh_degree]
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(k)] \
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert [p.name for p in v.properties] == names == property_names(sh_degree)
    assert all(v.data.dtype[p] == np.dtype("<f4") for p in names)
    assert all(p.val_dtype == "f4" for p in v.properties)
    assert ply.comments == ["wonderhuman up=z_up", f"wonderhuman sh_degree={sh_degree}", "made by a test"]
    d = v.data
    col = lambda *ks: np.stack([d[k] for k in ks], 1).astype(np.float64)  # noqa: E731
    assert len(d) == 200
    assert np.allclose(col("x", "y", "z"), g["means"], atol=1e-6)
    assert np.allclose(col("nx", "ny", "nz"), g["normals"], atol=1e-6)
    assert np.allclose(col("f_dc_0", "f_dc_1", "f_dc_2"), (g["colors"] - 0.5) / C0, atol=1e-5)
    assert np.allclose(0.5 + C0 * col("f_dc_0", "f_dc_1", "f_dc_2"), g["colors"], atol=1e-6)
    if k:
        assert np.all(col(*[f"f_rest_{i}" for i in range(k)]) == 0)
    assert np.allclose(d["opacity"], logit(g["opacities"]), rtol=1e-6, atol=1e-5)
    assert abs(float(d["opacity"][0]) - math.log((1 - 1e-6) / 1e-6)) < 1e-4  # opacity 1 -> logit(1 - 1e-6)
    assert np.allclose(col("scale_0", "scale_1", "scale_2"), np.log(g["scales"]), atol=1e-5)
    q = col("rot_0", "rot_1", "rot_2", "rot_3")
    assert np.allclose(np.linalg.norm(q, axis=1), 1, atol=1e-6)
    assert np.allclose(q, g["rotations"] / np.linalg.norm(g["rotations"], axis=1, keepdims=True), atol=1e-6)


def test_y_down_frame_rotates_means_normals_and_rotations_together(tmp_path):
    g = gaussians()
    path = write_gaussians_ply(tmp_path / "a.ply", **g)  # default: y_down
    ply = plyfile.PlyData.read(str(path))
    assert "wonderhuman up=y_down" in ply.comments
    d = ply["vertex"].data
    col = lambda *ks: np.stack([d[k] for k in ks], 1).astype(np.float64)  # noqa: E731
    x, y, z = g["means"].T
    assert np.allclose(col("x", "y", "z"), np.stack([x, -z, y], 1), atol=1e-6)  # x' = x, y' = -z, z' = y
    nx, ny, nz = g["normals"].T
    assert np.allclose(col("nx", "ny", "nz"), np.stack([nx, -nz, ny], 1), atol=1e-6)
    # each Gaussian's orientation is rotated by the same matrix: R' = U R
    R_file = quat_matrix(col("rot_0", "rot_1", "rot_2", "rot_3"))
    assert np.allclose(R_file, UP_ROTATION @ quat_matrix(g["rotations"]), atol=1e-6)
    # so each Gaussian's world covariance is U Σ U^T
    S = g["scales"]
    cov = lambda R, s: R @ (s[:, :, None] ** 2 * np.swapaxes(R, 1, 2))  # noqa: E731
    assert np.allclose(cov(R_file, S), UP_ROTATION @ cov(quat_matrix(g["rotations"]), S) @ UP_ROTATION.T, atol=1e-8)
    # scales, colours and opacities do not depend on the frame
    z_up = plyfile.PlyData.read(str(write_gaussians_ply(tmp_path / "b.ply", **g, up="z_up")))["vertex"].data
    for k in ("f_dc_0", "opacity", "scale_0", "scale_2"):
        assert np.array_equal(d[k], z_up[k])


@pytest.mark.parametrize("up", ["y_down", "z_up"])
def test_round_trip(tmp_path, up):
    g = gaussians(seed=1)
    back = read_gaussians_ply(write_gaussians_ply(tmp_path / "a.ply", **g, up=up))
    assert back.up == up and back.sh_degree == 3 and len(back) == 200
    assert all(a.dtype == np.float32 for a in (back.means, back.scales, back.rotations, back.opacities, back.colors,
                                               back.normals))
    assert np.allclose(back.means, g["means"], atol=1e-6)
    assert np.allclose(back.normals, g["normals"], atol=1e-6)
    assert np.allclose(back.scales, g["scales"], rtol=1e-6, atol=0)
    assert np.allclose(back.colors, g["colors"], atol=1e-6)
    assert np.allclose(back.opacities, np.clip(g["opacities"], 0, 1 - 1e-6), atol=2e-7)
    q = g["rotations"] / np.linalg.norm(g["rotations"], axis=1, keepdims=True)
    assert np.allclose(back.rotations * np.sign(np.sum(back.rotations * q, 1, keepdims=True)), q, atol=1e-6)
    snap = ply_to_snapshot(back)
    assert isinstance(snap, Snapshot) and len(snap) == 200 and not snap.visibility.any()
    assert snap.visibility.dtype == np.uint8 and snap.colors.min() >= 0 and snap.colors.max() <= 1


def test_writer_refuses_bad_input(tmp_path):
    g = gaussians(10)
    with pytest.raises(ValueError, match=r"scales: expected shape \(10, 3\), found \(9, 3\)"):
        write_gaussians_ply(tmp_path / "a.ply", **{**g, "scales": g["scales"][:9]})
    bad = g["means"].copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"means: 1 rows hold NaN or inf \(first: row 3\)"):
        write_gaussians_ply(tmp_path / "a.ply", **{**g, "means": bad})
    q = g["rotations"].copy()
    q[2] = 0
    with pytest.raises(ValueError, match=r"rotations: 1 quaternions are zero \(first: row 2\)"):
        write_gaussians_ply(tmp_path / "a.ply", **{**g, "rotations": q})
    with pytest.raises(ValueError, match="up must be one of"):
        write_gaussians_ply(tmp_path / "a.ply", **g, up="y_up")
    with pytest.raises(ValueError, match="one line"):
        write_gaussians_ply(tmp_path / "a.ply", **g, comments=["a\nelement face 3"])
    assert list(tmp_path.iterdir()) == []  # nothing half-written, no temporary files left


# ----------------------------------------------------------------------------- files written by others
def foreign_file(path, n=50, seed=2, *, order="shuffled", text=False, byte_order="<", sh_degree=1, normals=True,
                 extra=True, comments=()):
    """A 3DGS file written by plyfile: properties in another order, optional extra properties and a
    preceding element; returns the raw values written."""
    rng = np.random.default_rng(seed)
    names = property_names(sh_degree, normals)
    vals = {k: rng.normal(0, 1, n).astype(np.float32) for k in names}
    vals["opacity"] = rng.normal(0, 3, n).astype(np.float32)
    for i in range(3):
        vals[f"scale_{i}"] = rng.normal(-4, 1, n).astype(np.float32)
    cols = list(names)
    if extra:
        vals["confidence"] = rng.uniform(0, 1, n).astype(np.float64)
        vals["red"] = rng.integers(0, 256, n).astype(np.uint8)
        cols += ["confidence", "red"]
    if order == "shuffled":
        cols = [cols[i] for i in rng.permutation(len(cols))]
    arr = np.empty(n, [(k, vals[k].dtype) for k in cols])
    for k in cols:
        arr[k] = vals[k]
    elements = [plyfile.PlyElement.describe(arr, "vertex")]
    if extra:  # a scalar element before the vertices and a face element (with a list) after them
        cam = np.zeros(2, [("fx", "f4"), ("id", "i4")])
        faces = np.empty(1, [("vertex_indices", "O")])
        faces[0] = (np.array([0, 1, 2], np.int32),)
        elements = [plyfile.PlyElement.describe(cam, "camera")] + elements + [plyfile.PlyElement.describe(faces, "face")]
    plyfile.PlyData(elements, text=text, byte_order=byte_order, comments=list(comments)).write(str(path))
    return vals


def expected_of(vals, normals=True):
    st = lambda *ks: np.stack([vals[k] for k in ks], 1).astype(np.float64)  # noqa: E731
    q = st("rot_0", "rot_1", "rot_2", "rot_3")
    return {"means": st("x", "y", "z"), "colors": 0.5 + C0 * st("f_dc_0", "f_dc_1", "f_dc_2"),
            "scales": np.exp(st("scale_0", "scale_1", "scale_2")),
            "opacities": 1 / (1 + np.exp(-vals["opacity"].astype(np.float64))),
            "rotations": q / np.linalg.norm(q, axis=1, keepdims=True),
            "normals": st("nx", "ny", "nz") if normals else None}


@pytest.mark.parametrize("case", ["shuffled_binary_le", "ascii", "big_endian", "sh0_no_normals_ascii", "sh3_plain",
                                  "sh2_big_endian_no_extra"])
def test_files_written_by_plyfile_read_correctly(tmp_path, case):
    kw = {"shuffled_binary_le": {}, "ascii": {"text": True}, "big_endian": {"byte_order": ">"},
          "sh0_no_normals_ascii": {"text": True, "sh_degree": 0, "normals": False},
          "sh3_plain": {"sh_degree": 3, "order": "plain", "extra": False},
          "sh2_big_endian_no_extra": {"sh_degree": 2, "byte_order": ">", "extra": False}}[case]
    path = tmp_path / f"{case}.ply"
    vals = foreign_file(path, comments=["written by someone else"], **kw)
    g = read_gaussians_ply(path)
    exp = expected_of(vals, kw.get("normals", True))
    assert g.up is None and g.sh_degree == kw.get("sh_degree", 1) and g.comments == ("written by someone else",)
    assert len(g) == 50
    tol = 1e-6 if not kw.get("text") else 1e-5  # ascii: plyfile writes %.9g-ish text
    for k in ("means", "colors", "rotations", "opacities"):
        assert np.allclose(getattr(g, k), exp[k], atol=tol), k
    assert np.allclose(g.scales, exp["scales"], rtol=tol)
    if exp["normals"] is None:
        assert g.normals is None
        assert np.all(read_snapshot_ply(path).normals == 0)
    else:
        assert np.allclose(g.normals, exp["normals"], atol=tol)


def test_foreign_file_with_our_comment_is_transformed_back(tmp_path):
    vals = foreign_file(tmp_path / "a.ply", comments=["wonderhuman up=y_down"])
    g = read_gaussians_ply(tmp_path / "a.ply")
    exp = expected_of(vals)
    assert g.up == "y_down"
    assert np.allclose(g.means, exp["means"] @ UP_ROTATION, atol=1e-6)  # U^T applied to each row
    assert np.allclose(quat_matrix(g.rotations), UP_ROTATION.T @ quat_matrix(exp["rotations"]), atol=1e-6)


# ----------------------------------------------------------------------------- malformed files
def plain_header(props, n=2, fmt="binary_little_endian", extra=""):
    lines = ["ply", f"format {fmt} 1.0", extra, f"element vertex {n}"] + [f"property float {p}" for p in props]
    return ("\n".join(ln for ln in lines if ln) + "\nend_header\n").encode()


def test_malformed_files_give_clear_errors(tmp_path):
    good = write_gaussians_ply(tmp_path / "good.ply", **gaussians(4), sh_degree=0)
    data = good.read_bytes()
    header_end = data.index(b"end_header\n") + len(b"end_header\n")
    props = property_names(0)
    cases = {
        "empty": (b"", r"not a PLY file: expected it to start with 'ply', found b''"),
        "random": (np.random.default_rng(0).integers(0, 256, 300, dtype=np.uint8).tobytes(), r"not a PLY file"),
        "obj": (b"v 0 0 0\nv 1 0 0\n", r"not a PLY file: expected it to start with 'ply', found b'v 0 0 0"),
        "no_end_header": (data[:60], r"no 'end_header' line"),
        "no_vertex": (b"ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n3 0 1 2\n",
                      r"no 'vertex' element \(found elements \['face'\]\)"),
        "missing": (plain_header(["x", "y", "z", "f_dc_0", "opacity", "rot_0", "rot_1", "rot_2", "rot_3"], n=0),
                    r"missing vertex properties \['f_dc_1', 'f_dc_2', 'scale_0', 'scale_1', 'scale_2'\]"),
        "list": (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty list uchar float f_dc\nend_header\n",
                 r"the vertex element has list properties \['f_dc'\]"),
        "truncated": (data[: header_end + 4 * 17 * 3 + 5], r"truncated: the header declares 4 vertices of 68 bytes "
                                                            r"\(272 bytes\), the file holds 209 bytes"),
        "count_mismatch": (data + data[header_end:header_end + 68], r"count mismatch: the header declares 4 vertices "
                                                                    r"\(272 bytes\) but the file holds 340 bytes"),
        "ascii_truncated": (plain_header(props, n=3, fmt="ascii") + b" ".join([b"0"] * 17) + b"\n",
                            r"truncated: the header declares 3 vertices, the file holds 1 vertex lines"),
        "ascii_short_line": (plain_header(props, n=1, fmt="ascii") + b"0 0 0\n", r"vertex line 0 holds 3 values, expected 17"),
        "ascii_word": (plain_header(props, n=1, fmt="ascii") + b" ".join([b"0"] * 16 + [b"zero"]) + b"\n",
                       r"not a number"),
        "bad_format": (b"ply\nformat binary_middle_endian 1.0\nend_header\n", r"expected 'format ascii\|binary_little"),
        "bad_type": (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
                     r"expected 'property <type> <name>'"),
        "unknown_up": (plain_header(props, n=0, extra="comment wonderhuman up=x_left"), r"unknown frame 'x_left'"),
    }
    nan = np.frombuffer(data[header_end:], "<f4").copy()
    nan[0] = np.nan  # x of vertex 0
    nan[17 + 9 + 1] = np.inf  # scale_0 of vertex 1 (log-scale)
    cases["nonfinite"] = (data[:header_end] + nan.tobytes(),
                          r"non-finite values \(NaN or inf\) in vertex properties \{'x': 1, 'scale_0': 1\}")
    big = np.frombuffer(data[header_end:], "<f4").copy()
    big[10] = 200.0  # scale_0 = e^200
    cases["huge_scale"] = (data[:header_end] + big.tobytes(), r"too large for float32")
    zero_q = np.frombuffer(data[header_end:], "<f4").copy()
    zero_q[13:17] = 0.0
    cases["zero_quaternion"] = (data[:header_end] + zero_q.tobytes(), r"1 rotations \(rot_0..3\) are zero quaternions")
    for name, (content, pattern) in cases.items():
        path = tmp_path / f"{name}.ply"
        path.write_bytes(content)
        with pytest.raises(PlyFormatError, match=rf"^{re.escape(str(path))}: (.*[^ ] )?{pattern}"):
            read_gaussians_ply(path)
    (tmp_path / "newline.ply").write_bytes(data + b"\n")  # trailing whitespace after binary data is tolerated
    assert len(read_gaussians_ply(tmp_path / "newline.ply")) == 4
    with pytest.raises(PlyFormatError, match=r"nothing.ply: cannot be read"):
        read_gaussians_ply(tmp_path / "nothing.ply")


# ----------------------------------------------------------------------------- sequences
def snapshot_of(g: dict, frame: int = 0) -> Snapshot:
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return Snapshot(f32(g["means"]), f32(g["scales"]), f32(g["rotations"]), f32(g["colors"]), f32(g["opacities"]),
                    f32(g["normals"]), np.zeros(len(g["means"]), np.uint8), frame_index=frame, step=7)


def test_sequence_is_written_all_or_nothing(tmp_path):
    snaps = [snapshot_of(gaussians(30, seed=s), s) for s in range(5)]
    seen = []
    paths = write_ply_sequence(tmp_path / "seq", snaps, progress=lambda done, total: seen.append((done, total)))
    assert [p.name for p in paths] == [f"frame_{i:04d}.ply" for i in range(5)]
    assert sorted(p.name for p in (tmp_path / "seq").iterdir()) == [p.name for p in paths]
    assert seen == [(i, 5) for i in range(1, 6)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]  # no temporary folders left
    back = read_gaussians_ply(paths[3])
    assert np.allclose(back.means, snaps[3].means, atol=1e-6)
    assert "wonderhuman space=observation frame=3 stage=1 step=7" in back.comments
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_ply_sequence(tmp_path / "seq", snaps)
    # a failure in frame 2 (a NaN): nothing new appears, the previous sequence stays as it was
    bad = gaussians(30, seed=9)
    bad["means"][0, 0] = np.nan
    before = {p.name: p.read_bytes() for p in (tmp_path / "seq").iterdir()}

    def frames():  # a generator: no length, progress gets total None
        yield snaps[0]
        yield snaps[1]
        yield snapshot_of(bad)

    calls = []
    for target, overwrite in ((tmp_path / "seq", True), (tmp_path / "new", False)):
        with pytest.raises(ValueError, match="means: 1 rows hold NaN"):
            write_ply_sequence(target, frames(), overwrite=overwrite, progress=lambda d, t: calls.append((d, t)))
    assert calls[:2] == [(1, None), (2, None)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    assert {p.name: p.read_bytes() for p in (tmp_path / "seq").iterdir()} == before
    # overwrite replaces the whole folder
    paths = write_ply_sequence(tmp_path / "seq", snaps[:2], overwrite=True, up="z_up", sh_degree=0)
    assert sorted(p.name for p in (tmp_path / "seq").iterdir()) == ["frame_0000.ply", "frame_0001.ply"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    assert read_gaussians_ply(paths[1]).up == "z_up"


# ----------------------------------------------------------------------------- render check
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)


@pytest.fixture(scope="module")
def tiny_avatar(tiny_scene):
    import torch

    from reconstruct.avatar.config import AvatarConfig
    from reconstruct.avatar.model import AvatarModel

    torch.manual_seed(0)
    body = tiny_scene.body_model()
    model = AvatarModel(body, AvatarConfig(gaussian_resolution=32, hidden=16))
    with torch.no_grad():
        canon = model.canonical()
        n = model.num_gaussians
        seen = (torch.arange(n) % 3 == 0).to(torch.uint8)
        live = Snapshot.from_gaussians(model.splats(canon), seen, space="canonical")
        posed = [Snapshot.from_gaussians(model.pose(canon, body.bone_transforms(f.pose)), seen, frame_index=i)
                 for i, f in enumerate(tiny_scene.frames)]
    return live, posed


def cameras_around(snap: Snapshot, size: int = 160) -> list[Camera]:
    lo, hi = snap.means.min(0), snap.means.max(0)
    target = (lo + hi) / 2
    dist = 1.3 * float(np.max(hi - lo)) / (2 * math.tan(math.radians(30) / 2)) + 0.5
    return [Camera.orbit(az, el, dist, target=target, width=size, height=size, fov_y_deg=30.0, name=f"az{az}")
            for az, el in ((0, 5), (90, 10), (180, 0), (-60, 30), (30, -20))]


@pytest.mark.gl
def test_reread_avatar_renders_like_the_live_one(tmp_path, tiny_avatar):
    from renderer.gl_context import create_offscreen_context
    from renderer.splat_renderer import SplatRenderer

    live, posed = tiny_avatar
    ctx = create_offscreen_context()
    renderer = SplatRenderer(ctx)
    try:
        results = []
        for up in ("y_down", "z_up"):
            t0 = time.perf_counter()
            path = write_snapshot_ply(tmp_path / f"avatar_{up}.ply", live, up=up)
            dt = time.perf_counter() - t0
            back = read_snapshot_ply(path, space="canonical")
            for cam in cameras_around(live):
                renderer.set_snapshot(live)
                a = renderer.render(cam, "rgb", background=(1.0, 1.0, 1.0))
                renderer.set_snapshot(back)
                b = renderer.render(cam, "rgb", background=(1.0, 1.0, 1.0))
                assert a[..., 3].max() > 0.9 and (a[..., 3] > 0.5).mean() > 0.05  # the avatar is in view
                results.append((up, cam.name, psnr(a[..., :3], b[..., :3]), psnr(a[..., 3], b[..., 3])))
            print(f"\n[ply] {len(live)} Gaussians, up={up}: {path.stat().st_size} bytes, written in {dt * 1e3:.1f} ms")
        # what another viewer shows: the y_down file as stored, seen by the matching camera (R U^T)
        raw = plyfile.PlyData.read(str(tmp_path / "avatar_y_down.ply"))["vertex"].data
        st = lambda *ks: np.stack([raw[k] for k in ks], 1).astype(np.float32)  # noqa: E731
        stored = Snapshot(st("x", "y", "z"), np.exp(st("scale_0", "scale_1", "scale_2")),
                          st("rot_0", "rot_1", "rot_2", "rot_3"),
                          np.clip(0.5 + C0 * st("f_dc_0", "f_dc_1", "f_dc_2"), 0, 1),
                          1 / (1 + np.exp(-raw["opacity"].astype(np.float32))), st("nx", "ny", "nz"),
                          np.zeros(len(raw), np.uint8))
        # upright with -Y up: the height is along -y, and y spans what z spanned
        assert np.allclose([stored.means[:, 1].min(), stored.means[:, 1].max()],
                           [-live.means[:, 2].max(), -live.means[:, 2].min()], atol=1e-5)
        for cam in cameras_around(live):
            renderer.set_snapshot(live)
            a = renderer.render(cam, "rgb", background=(1.0, 1.0, 1.0))
            viewer_cam = Camera(K=cam.K, R=cam.R @ UP_ROTATION.T, t=cam.t, width=cam.width, height=cam.height,
                                near=cam.near, far=cam.far, name=cam.name)
            renderer.set_snapshot(stored)
            b = renderer.render(viewer_cam, "rgb", background=(1.0, 1.0, 1.0))
            results.append(("stored y_down", cam.name, psnr(a[..., :3], b[..., :3]), psnr(a[..., 3], b[..., 3])))
        # posed frames (observation space) too
        path = write_snapshot_ply(tmp_path / "posed.ply", posed[2])
        cam = cameras_around(posed[2])[0]
        renderer.set_snapshot(posed[2])
        a = renderer.render(cam, "rgb")
        renderer.set_snapshot(read_snapshot_ply(path))
        b = renderer.render(cam, "rgb")
        results.append(("y_down posed frame 2", cam.name, psnr(a[..., :3], b[..., :3]), psnr(a[..., 3], b[..., 3])))
    finally:
        renderer.release()
        ctx.release()
    print("[ply] PSNR (dB) of the re-read file's render against the live avatar's (inf = identical):")
    for up, name, p_rgb, p_alpha in results:
        print(f"[ply]   {up:>22} {name:>6}: rgb {p_rgb:7.2f}  alpha {p_alpha:7.2f}")
    assert all(p > 60.0 for _, _, p, _ in results)
    assert all(p > 60.0 for _, _, _, p in results)


def test_sequence_of_the_tiny_avatar_size_and_time(tmp_path, tiny_avatar):
    """60 posed frames of the tiny avatar (the 4 scene frames, cycled): file size and write time."""
    _, posed = tiny_avatar
    frames = [posed[i % len(posed)] for i in range(60)]
    t0 = time.perf_counter()
    paths = write_ply_sequence(tmp_path / "seq", frames)
    dt = time.perf_counter() - t0
    size = sum(p.stat().st_size for p in paths)
    n = len(frames[0])
    per = 62 * 4 * n  # 62 float32 properties per Gaussian (SH degree 3) + the header
    assert all(per < p.stat().st_size < per + 4096 for p in paths)
    print(f"\n[ply] 60-frame sequence, {n} Gaussians/frame: {size / 1e6:.2f} MB, written in {dt:.3f} s "
          f"({dt / 60 * 1e3:.1f} ms/frame)")
    back = read_gaussians_ply(paths[61 % 60])
    assert np.allclose(back.means, frames[1].means, atol=1e-6)
