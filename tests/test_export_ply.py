"""`export RUN --ply`: the avatar's Gaussians as 3DGS .ply (one pose, or a folder of frames), read
back with an independent reader (plyfile) and rendered with the project's renderer against the live
avatar (the round-trip PSNR table is printed); the size and write time of a 60-frame sequence; clear
errors with nothing written."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from tiny_runs import TINY_SCENE, train_tiny

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A briefly trained run folder (a checkpoint after 3 steps)."""

    run = tmp_path_factory.mktemp("ply_run") / "run"
    return train_tiny(run)


@pytest.fixture(scope="module")
def avatar(run):
    from reconstruct.run_folder import RunFolder

    return RunFolder(run).resume().avatar()


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_cli_ply_single_and_sequences(run, avatar, tmp_path, capsys):
    import plyfile

    from app.cli import main
    from reconstruct.ply import property_names, read_gaussians_ply

    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    assert main(["export", str(run), "--ply", str(tmp_path / "f1.ply"), "--frame", "1", "--quiet"]) == 0
    assert main(["export", str(run), "--ply", str(tmp_path / "canon.ply"), "--canonical", "--up", "z_up",
                 "--quiet"]) == 0
    assert main(["export", str(run), "--ply", str(tmp_path / "walk"), "--novel", "walk", "--frames", "4"]) == 0
    assert main(["export", str(run), "--ply", str(tmp_path / "video"), "--poses", TINY_SCENE, "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "wrote " + str(tmp_path / "walk") + " (4 frames" in captured.out
    assert "4/4" in captured.err  # the progress bar of the sequence
    # the layout, read by plyfile: names, order, float32, one vertex per Gaussian
    n = len(avatar.make_snapshot())
    for name in ("f1.ply", "canon.ply", "walk/frame_0003.ply", "video/frame_0002.ply"):
        ply = plyfile.PlyData.read(str(tmp_path / name))
        v = ply["vertex"]
        assert [p.name for p in v.properties] == property_names(3)
        assert {p.val_dtype for p in v.properties} == {"f4"} and v.count == n
        assert ply.elements[0].name == "vertex" and not ply.text and ply.byte_order == "<"
    assert _listing(tmp_path / "walk") == [f"frame_{i:04d}.ply" for i in range(4)]
    assert _listing(tmp_path / "video") == [f"frame_{i:04d}.ply" for i in range(3)]
    # what the files hold: frame 1 posed, the canonical space, the video's poses in order
    f1 = read_gaussians_ply(tmp_path / "f1.ply")
    assert np.allclose(f1.means, avatar.make_snapshot("observation", 1).means, atol=1e-5)
    canon = read_gaussians_ply(tmp_path / "canon.ply")
    assert canon.up == "z_up" and np.allclose(canon.means, avatar.make_snapshot("canonical").means, atol=1e-6)
    v2 = read_gaussians_ply(tmp_path / "video" / "frame_0002.ply")
    assert np.allclose(v2.means, avatar.make_snapshot("observation", 2).means, atol=1e-5)
    walk = [read_gaussians_ply(tmp_path / "walk" / f"frame_{i:04d}.ply").means for i in range(4)]
    assert min(np.abs(walk[i] - walk[i + 1]).max() for i in range(3)) > 1e-3  # the walk moves
    assert {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == before  # the run folder is untouched
    assert [p for p in _listing(tmp_path) if p.startswith(".")] == []


def test_cli_writes_the_other_splat_layouts(run, avatar, tmp_path, capsys):
    """A single pose as .spz, .splat and .compressed.ply (the name picks the layout), a sequence
    as .spz files (--format): each reads back to the avatar's Gaussians within the layout's
    quantisation, the y-down frame as stored (the compressed PLY names it, like our .ply) (tests/test_splat_formats.py checks the layouts against splat-transform)."""
    from app.cli import main
    from reconstruct.gaussian_files import read_gaussians
    from reconstruct.ply import UP_ROTATION, read_gaussians_ply

    for name in ("f1.spz", "f1.splat", "f1.compressed.ply", "f1.ply"):
        assert main(["export", str(run), "--ply", str(tmp_path / name), "--frame", "1", "--quiet"]) == 0
    assert main(["export", str(run), "--ply", str(tmp_path / "walk"), "--novel", "walk", "--frames", "3",
                 "--format", "spz", "--quiet"]) == 0
    assert "(3 frames, frame_0000.spz ...)" in capsys.readouterr().out
    assert _listing(tmp_path / "walk") == [f"frame_{i:04d}.spz" for i in range(3)]
    ref = read_gaussians_ply(tmp_path / "f1.ply")  # our frame (its comment says y_down)
    means_y_down = ref.means.astype(np.float64) @ UP_ROTATION.T
    sizes = {}
    for name, tol in (("f1.spz", 3e-4), ("f1.splat", 1e-6), ("f1.compressed.ply", 2e-3)):
        g = read_gaussians(tmp_path / name)
        assert len(g) == len(ref)
        # the compressed PLY keeps our comment, so it reads back in our frame like a .ply; the others as stored
        assert g.up == ("y_down" if name.endswith(".ply") else None)
        want = ref.means.astype(np.float64) if g.up else means_y_down
        d = np.linalg.norm(g.means[:, None].astype(np.float64) - want[None], axis=-1)
        j = d.argmin(1)
        assert len(set(j)) == len(ref) and d.min(1).max() < tol, name
        assert np.abs(g.colors - np.clip(ref.colors[j], 0, 1)).max() < 6e-3, name
        assert np.abs(g.opacities - ref.opacities[j]).max() < 6e-3, name
        sizes[name] = (tmp_path / name).stat().st_size
    assert sizes["f1.spz"] * 8 < (tmp_path / "f1.ply").stat().st_size
    assert len(read_gaussians(tmp_path / "walk" / "frame_0002.spz")) == len(ref)


def test_cli_ply_errors_write_nothing(run, tmp_path, capsys):
    from app.cli import main

    (tmp_path / "exists").mkdir()
    (tmp_path / "exists" / "keep.txt").write_text("mine")
    cases = [
        (["--ply", str(tmp_path / "a.ply"), "--frame", "7"], "frame 7 is out of range: the scene has 3 frames (0..2)"),
        (["--ply", str(tmp_path / "a.ply"), "--frame", "-1"], "frame -1 is out of range"),
        (["--ply", str(tmp_path / "seq.ply"), "--novel", "walk"], ("seq.ply: a pose sequence is written as one "
                                                                   "file per frame into a folder")),
        (["--ply", str(tmp_path / "seq.spz"), "--novel", "walk"], "give a folder name (without .spz)"),
        (["--ply", str(tmp_path / "a.spz"), "--format", "splat"], "the name asks for 'spz', the format given is 'splat'"),
        (["--out", str(tmp_path / "a.gif"), "--orbit", "3", "--format", "spz"], "--format applies to --ply only"),
        (["--ply", str(tmp_path / "exists"), "--novel", "walk"], "already exists and is a folder (pass --overwrite"),
        (["--ply", str(tmp_path / "a.txt"), "--canonical"], "unsupported output type '.txt'"),
        (["--ply", str(tmp_path / "no" / "a.ply")], "the output folder"),
        (["--ply", str(tmp_path / "m"), "--motion", str(tmp_path / "nope.bvh")], "nope.bvh: no such motion file"),
        (["--ply", str(tmp_path / "m"), "--motion", str(tmp_path / "walk.fbx")], "walk.fbx"),
        (["--ply", str(tmp_path / "a.ply"), "--novel", "moonwalk"], "walk, arms_up"),
        (["--ply", str(tmp_path / "a.ply"), "--start", "1"], "--start, --end and --loop apply to --motion only"),
    ]
    (tmp_path / "walk.fbx").write_text("Kaydara FBX Binary")
    for args, expect in cases:
        assert main(["export", str(run), *args, "--quiet"]) == 2, args
        err = capsys.readouterr().err
        assert expect in err, (args, err)
    for args in (["--ply", str(tmp_path / "o"), "--orbit", "4"], ["--ply", str(tmp_path / "a.ply"), "--frame", "1",
                                                                   "--novel", "walk"],
                 ["--out", str(tmp_path / "a.gif"), "--canonical"], ["--ply", str(tmp_path / "a.ply"), "--out",
                                                                     str(tmp_path / "a.gif"), "--orbit", "3"],
                 ["--orbit", "3"]):
        with pytest.raises(SystemExit) as exc:
            main(["export", str(run), *args])
        assert exc.value.code == 2
    capsys.readouterr()
    assert _listing(tmp_path) == ["exists", "walk.fbx"] and _listing(tmp_path / "exists") == ["keep.txt"]
    # --overwrite replaces a sequence folder as a whole
    assert main(["export", str(run), "--ply", str(tmp_path / "exists"), "--novel", "walk", "--frames", "3",
                 "--overwrite", "--quiet"]) == 0
    assert _listing(tmp_path / "exists") == [f"frame_{i:04d}.ply" for i in range(3)]
    assert [p for p in _listing(tmp_path) if p.startswith(".")] == []


# ----------------------------------------------------------------------------- round trip
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)


def _cameras(snap, size: int = 128):
    from reconstruct.camera import Camera

    lo, hi = snap.means.min(0), snap.means.max(0)
    target = (lo + hi) / 2
    dist = 1.3 * float(np.max(hi - lo)) / (2 * math.tan(math.radians(30) / 2)) + 0.5
    return [Camera.orbit(az, el, dist, target=target, width=size, height=size, fov_y_deg=30.0, name=f"az{az:+d}")
            for az, el in ((0, 5), (90, 10), (180, 0), (-60, 30))]


def _plyfile_snapshot(path):
    """The stored arrays as an independent reader (plyfile) gives them, no frame change undone."""
    import plyfile

    from reconstruct.ply import C0
    from reconstruct.snapshot import Snapshot

    raw = plyfile.PlyData.read(str(path))["vertex"].data
    st = lambda *ks: np.stack([raw[k] for k in ks], 1).astype(np.float32)
    return Snapshot(st("x", "y", "z"), np.exp(st("scale_0", "scale_1", "scale_2")), st("rot_0", "rot_1", "rot_2", "rot_3"),
                    np.clip(0.5 + C0 * st("f_dc_0", "f_dc_1", "f_dc_2"), 0, 1),
                    1 / (1 + np.exp(-raw["opacity"].astype(np.float32))), st("nx", "ny", "nz"),
                    np.zeros(len(raw), np.uint8))


@pytest.mark.gl
def test_round_trip_renders_like_the_live_avatar(avatar, tmp_path):
    """export --ply -> reopen (our reader; plyfile with the viewer's camera for the stored y-down
    file) -> render, against the live avatar's render: canonical and posed."""
    from app.export import export_ply
    from reconstruct.camera import Camera
    from reconstruct.ply import UP_ROTATION, read_snapshot_ply
    from renderer.gl_context import create_offscreen_context
    from renderer.splat_renderer import SplatRenderer

    cases = [("canonical", {"canonical": True}, avatar.make_snapshot("canonical")),
             ("posed frame 1", {"frame": 1}, avatar.make_snapshot("observation", 1)),
             ("posed frame 2", {"frame": 2}, avatar.make_snapshot("observation", 2))]
    rows = []
    ctx = create_offscreen_context()
    renderer = SplatRenderer(ctx)
    try:
        for label, what, live in cases:
            for up in ("y_down", "z_up"):
                path = export_ply(avatar, tmp_path / f"{label.replace(' ', '_')}_{up}.ply", up=up, progress=False,
                                  **what)
                ours = read_snapshot_ply(path)
                raw = _plyfile_snapshot(path)
                for cam in _cameras(live):
                    renderer.set_snapshot(live)
                    a = renderer.render(cam, "rgb", background=(1.0, 1.0, 1.0))
                    assert (a[..., 3] > 0.5).mean() > 0.03  # the avatar is in view
                    renderer.set_snapshot(ours)
                    b = renderer.render(cam, "rgb", background=(1.0, 1.0, 1.0))
                    # plyfile's arrays as stored; a y-down file seen by the camera rotated the same way
                    R = cam.R @ UP_ROTATION.T if up == "y_down" else cam.R
                    vcam = Camera(K=cam.K, R=R, t=cam.t, width=cam.width, height=cam.height, near=cam.near,
                                  far=cam.far, name=cam.name)
                    renderer.set_snapshot(raw)
                    c = renderer.render(vcam, "rgb", background=(1.0, 1.0, 1.0))
                    rows.append((label, up, cam.name, psnr(a[..., :3], b[..., :3]), psnr(a[..., 3], b[..., 3]),
                                 psnr(a[..., :3], c[..., :3])))
    finally:
        renderer.release()
        ctx.release()
    print(f"\n[export --ply] round trip, {len(cases[0][2])} Gaussians, 128x128, PSNR (dB) against the live "
          f"render (inf = identical)")
    print(f"[export --ply] {'export':>14} {'up':>6} {'camera':>7} {'ours rgb':>9} {'ours alpha':>10} "
          f"{'plyfile rgb':>11}")
    for label, up, cam, p_rgb, p_a, p_raw in rows:
        print(f"[export --ply] {label:>14} {up:>6} {cam:>7} {p_rgb:9.2f} {p_a:10.2f} {p_raw:11.2f}")
    for label in ("canonical", "posed frame 1", "posed frame 2"):
        worst = min(min(r[3], r[4], r[5]) for r in rows if r[0] == label)
        print(f"[export --ply] worst over cameras and frames, {label}: {worst:.2f} dB")
    assert all(min(r[3], r[4], r[5]) > 60.0 for r in rows)


def test_sixty_frame_sequence_size_and_time(avatar, tmp_path):
    """A 60-frame .ply sequence (the walk cycle): total size and time, posing included and not."""
    from app.export import export_ply
    from reconstruct.body.novel_poses import novel_pose_sequence
    from reconstruct.ply import write_ply_sequence

    t0 = time.perf_counter()
    out = export_ply(avatar, tmp_path / "walk60", novel="walk", frames=60, progress=False)
    total = time.perf_counter() - t0
    files = sorted(out.iterdir())
    assert len(files) == 60
    size = sum(p.stat().st_size for p in files)
    n = len(avatar.make_snapshot())
    assert all(62 * 4 * n < p.stat().st_size < 62 * 4 * n + 4096 for p in files)
    poses = novel_pose_sequence(avatar.body, "walk", 60, base=avatar.scene.frames[0].pose)
    snaps = [avatar.snapshot_at_pose(p, 0) for p in poses]
    t1 = time.perf_counter()
    write_ply_sequence(tmp_path / "walk60_again", snaps)
    write_only = time.perf_counter() - t1
    print(f"\n[export --ply] 60-frame sequence, {n} Gaussians/frame: {size / 1e6:.2f} MB; export (posing + "
          f"writing) {total:.2f} s, writing alone {write_only:.3f} s ({write_only / 60 * 1e3:.1f} ms/frame)")


def test_the_export_panels_file_field_follows_the_splat_format():
    from app.studio.panels.export import _retarget_suffix

    assert _retarget_suffix("exports/avatar.mp4", "ply_frame", "spz") == "exports/avatar.spz"
    assert _retarget_suffix("exports/avatar.spz", "ply_frame", "compressed.ply") == "exports/avatar.compressed.ply"
    assert _retarget_suffix("exports/avatar.compressed.ply", "ply_canonical", "ply") == "exports/avatar.ply"
    assert _retarget_suffix("exports/avatar.compressed.ply", "ply_sequence", "spz") == "exports/avatar_frames"
    assert _retarget_suffix("exports/avatar_frames", "orbit") == "exports/avatar.mp4"


def test_dropped_files_are_sorted_by_name():
    from app.studio.drops import drop_kind, not_taken

    for name in ("walk.bvh", "Mixamo Run.FBX", "a.glb", "a.gltf", "amass.npz"):
        assert drop_kind(f"/x/{name}") == "motion", name
    for name in ("avatar.ply", "a.compressed.ply", "a.splat", "a.SPZ", "a.sog", "sog/meta.json"):
        assert drop_kind(f"/x/{name}") == "splat", name
    for name in ("notes.txt", "clip.mp4", "folder", "a.pkl"):
        assert drop_kind(f"/x/{name}") == "other", name
    assert "notes.txt: dropped, but neither a motion file (.bvh" in not_taken("notes.txt")
