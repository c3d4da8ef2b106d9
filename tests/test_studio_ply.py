"""The studio and .ply files (Xvfb, scripted like tests/test_studio.py): the export panel writes the
current frame, the canonical space and the pose sequence as .ply while training goes on; the viewer
(``wonderhuman-studio --ply FILE``, no trainer) shows our files and other programs', keeps the
file shown when another cannot be read, and a malformed file at start is an error window with the
studio's exit status for files it cannot open."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
SCENE = "synthetic:seed=1,frames=3,size=64,azimuths=8,eval_frames=1,texture_size=128"


def _xvfb(script: Path | None, cwd: Path, code: str | None = None, timeout: int = 300, args=()):
    assert shutil.which("xvfb-run"), "xvfb-run is missing (scripts/bootstrap.sh installs xvfb)"
    cmd = ["xvfb-run", "-a", sys.executable] + (["-c", code] if code else [str(script)]) + list(args)
    return subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=timeout, cwd=str(cwd))


def _red_pixels(path) -> int:
    from PIL import Image

    img = np.asarray(Image.open(path).convert("RGB"), np.int32)
    return int(((img[..., 0] > 200) & (img[..., 1] < 160) & (img[..., 2] < 150)).sum())


DROPPED_BVH = ROOT / "tests" / "data" / "fbx" / "walk.bvh"
DROPPED_SPZ = ROOT / "tests" / "data" / "splats" / "source.spz"

EXPORT_SCRIPT = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {root!r})
    sys.path.insert(0, {root!r} + "/tests")
    from app.studio.window import run_studio
    from studio_driver import tiny_config

    out = {out!r}
    result = {{}}
    state = {{"phase": 0}}
    JOBS = [("ply_frame", out + "_frame1.ply", "ply"), ("ply_canonical", out + "_canonical.ply", "ply"),
            ("ply_frame", out + "_frame1.spz", "spz"), ("ply_sequence", out + "_spz_frames", "spz"),
            ("ply_sequence", out + "_frames", "ply")]

    def key(job):  # the result's name: the kind, and the format where it is not .ply
        return job[0] if job[2] == "ply" else job[0] + "_" + job[2]

    def script(app):
        s, ex = app.status, app.export
        p = state["phase"]
        if p == 0 and s.step >= 2 and len(app.latest_snapshot()):
            app.set_frame(1)
            e = ex.settings
            e.kind, e.out = "ply_sequence", out + "_missing/frames"  # a folder that is not there
            result["bad_job"] = app.start_export() is not None
            result["bad_message"] = ex.message
            e.kind, e.out = "ply_frame", out + "_frame1.ply.txt"
            result["bad_suffix"] = app.start_export() is not None and ex.message
            result["bad_suffix_message"] = ex.message
            state["phase"] = 1
        elif 1 <= p <= len(JOBS) and (p == 1 or ex.job.done):
            if p > 1:
                result[key(JOBS[p - 2])] = str(ex.job.result) if ex.job.result else ex.job.error
            e = ex.settings
            e.kind, e.out, e.splat_format = JOBS[p - 1]
            result.setdefault("steps", []).append(s.step)
            app.start_export()
            state["phase"] = p + 1
        elif p == len(JOBS) + 1 and ex.job.done:
            result[key(JOBS[-1])] = str(ex.job.result) if ex.job.result else ex.job.error
            result["sequence_total"] = ex.job.total
            result["steps"].append(s.step)
            app.request_screenshot(out + "_export_panel.png")
            state["phase"] = 9
        elif p == 9:
            app.open_beside_ply(out + "_missing.ply")  # the Beside panel: a file that is not there
            state["phase"] = 10
        elif p == 10 and app.view.beside.job is None:
            result["beside_missing"] = app.view.beside.message
            app.open_beside_ply(out + "_canonical.ply")
            state["phase"] = 11
        elif p == 11 and app.view.beside.job is None:
            b = app.view.beside
            result["beside"] = {{"name": b.loaded and b.loaded.name, "message": b.message,
                                "n_live": len(app.latest_snapshot()), "n_drawn": len(app.drawn_snapshot())}}
            state["wait"] = app.frame_count + 3
            state["phase"] = 12
        elif p == 12 and app.frame_count >= state["wait"]:
            app.request_screenshot(out + "_beside.png")
            result["error"] = s.error
            # files dropped on the window: a motion file, a splat file, something else
            app.drops.paths.extend([{walk!r}, {spz!r}])
            state["phase"] = 13
        elif p == 13 and app.view.motion.job is None and app.view.beside.job is None:  # both read and taken
            m, b = app.view.motion, app.view.beside
            result["dropped"] = {{"motion": m.loaded and m.loaded.name, "motion_message": m.message,
                                 "beside": b.loaded and b.loaded.name, "source": app.view.pose_source}}
            app.drops.paths.append(out + "_notes.txt")
            state["phase"] = 14
        elif p == 14:
            result["dropped"]["beside_message"] = app.view.beside.message
            app.close()
        result["phase"] = state["phase"]

    rc = run_studio({scene!r}, None, config=tiny_config(), size=(1280, 800), max_frames=3000, script=script,
                    idle_fps=30, progress=False)
    result["rc"] = rc
    json.dump(result, open(out + ".json", "w"))
""")


@pytest.mark.gl
def test_export_panel_writes_ply_while_training(tmp_path):
    from reconstruct.ply import read_gaussians_ply

    out = str(tmp_path / "studio")
    script = tmp_path / "studio_ply_export.py"
    script.write_text(EXPORT_SCRIPT.format(root=str(ROOT), out=out, scene=SCENE, walk=str(DROPPED_BVH),
                                           spz=str(DROPPED_SPZ)))
    proc = _xvfb(script, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    r = json.loads(Path(out + ".json").read_text())
    assert r["rc"] == 0 and r["phase"] == 14 and r["error"] is None, r
    assert r["bad_job"] is False and "does not exist" in r["bad_message"], r
    assert r["bad_suffix"] is False and "'.txt'" in r["bad_suffix_message"] and ".ply" in r["bad_suffix_message"]
    assert not Path(out + "_missing").exists() and not Path(out + "_frame1.ply.txt").exists()
    frame = read_gaussians_ply(r["ply_frame"])
    assert r["ply_frame"] == out + "_frame1.ply" and any("space=observation frame=1" in c for c in frame.comments)
    canon = read_gaussians_ply(r["ply_canonical"])
    assert any("space=canonical" in c for c in canon.comments) and len(canon) == len(frame)
    assert not np.allclose(canon.means, frame.means)  # posed vs canonical
    from reconstruct.gaussian_files import read_gaussians

    assert r["ply_frame_spz"] == out + "_frame1.spz" and r["ply_sequence_spz"] == out + "_spz_frames"
    spz = read_gaussians(out + "_frame1.spz")  # the Export panel's .spz: the name picks the layout
    assert len(spz) == len(frame) and spz.comments == ("spz version 3",)
    spz_seq = sorted(Path(out + "_spz_frames").iterdir())
    assert [p.name for p in spz_seq] == [f"frame_{i:04d}.spz" for i in range(3)]
    assert len(read_gaussians(spz_seq[-1])) == len(frame)
    seq = sorted(Path(out + "_frames").iterdir())
    assert [p.name for p in seq] == [f"frame_{i:04d}.ply" for i in range(3)] == \
        [f"frame_{i:04d}.ply" for i in range(r["sequence_total"])]
    assert r["steps"][-1] > r["steps"][0]  # training went on
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temporary files
    assert _red_pixels(out + "_export_panel.png") < 50  # no error shown after the good exports
    # the Beside panel: a missing file is a message; the canonical export is drawn next to the live avatar
    assert "_missing.ply" in r["beside_missing"] and "cannot be read" in r["beside_missing"], r["beside_missing"]
    b = r["beside"]
    assert b["name"] == "studio_canonical.ply" and b["message"] is None and b["n_drawn"] == 2 * b["n_live"], b
    d = r["dropped"]  # the motion file went to the Pose panel, the .spz beside, the .txt is a message
    assert d["motion"] == "walk.bvh" and d["source"] == "motion" and d["beside"] == "source.spz", d
    assert "_notes.txt: dropped, but neither a motion file" in d["beside_message"], d


@pytest.fixture(scope="module")
def avatar_ply(tmp_path_factory, tiny_scene):
    """A .ply of a briefly trained tiny avatar (ours, y_down) and a foreign file (written with plyfile,
    no comment of ours, in the 3DGS y-down convention)."""
    import plyfile
    from studio_driver import tiny_config

    from app.export import export_ply
    from reconstruct.ply import UP_ROTATION, property_names
    from reconstruct.train.trainer import Trainer

    folder = tmp_path_factory.mktemp("plys")
    t = Trainer(tiny_scene, tiny_config())
    for _ in range(3):
        t.step()
    ours = export_ply(t.avatar(), folder / "avatar.ply", frame=0, progress=False)
    snap = t.avatar().make_snapshot("observation", 0)
    n = len(snap)
    names = property_names(0, normals=False)
    vals = {k: np.zeros(n, np.float32) for k in names}
    m = snap.means @ UP_ROTATION.T  # y down, as a 3DGS capture would be
    vals["x"], vals["y"], vals["z"] = m[:, 0], m[:, 1], m[:, 2]
    for i in range(3):
        vals[f"f_dc_{i}"] = (snap.colors[:, i] - 0.5) / 0.28209479177387814
        vals[f"scale_{i}"] = np.log(snap.scales[:, i])
    vals["opacity"][:] = 4.0
    vals["rot_0"][:] = 1.0
    arr = np.zeros(n, dtype=[(k, "f4") for k in names])
    for k in names:
        arr[k] = vals[k]
    foreign = folder / "foreign.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")], text=False).write(str(foreign))
    broken = folder / "broken.ply"
    data = ours.read_bytes()
    broken.write_bytes(data[: len(data) // 2])  # truncated mid-vertices
    return ours, foreign, broken


VIEWER_SCRIPT = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {root!r})
    from app.studio.viewer import run_viewer

    out, foreign, broken = {out!r}, {foreign!r}, {broken!r}
    result = {{}}
    state = {{"phase": 0, "wait": 0}}

    def script(app):
        p, f = state["phase"], app.file
        if p == 0 and app.frame_count >= 3:
            result["first"] = {{"name": f.loaded.name, "n": f.loaded.num_gaussians, "up": f.loaded.recorded_up,
                               "summary": f.loaded.summary()}}
            result["height_z"] = float(app.snapshot.means[:, 2].max() - app.snapshot.means[:, 2].min())
            app.request_screenshot(out + "_rgb.png")
            state["phase"] = 1
        elif p == 1:
            app.set_mode("normal")
            app.view_from(90.0)
            app.request_screenshot(out + "_normal_side.png")
            state["phase"] = 2
        elif p == 2:
            app.set_mode("rgb")
            app.view_from(0.0)
            app.open_ply(broken)
            state["phase"] = 3
        elif p == 3 and f.job is None:
            result["broken_message"] = f.message
            result["kept"] = f.loaded.name
            state["wait"] = app.frame_count + 3
            state["phase"] = 4
        elif p == 4 and app.frame_count >= state["wait"]:
            app.request_screenshot(out + "_broken_message.png")
            state["phase"] = 5
        elif p == 5:
            app.open_ply(foreign)
            state["phase"] = 55
        elif p == 55 and f.job is None:
            result["second"] = {{"name": f.loaded.name, "n": f.loaded.num_gaussians, "up": f.loaded.recorded_up,
                                "turned": f.loaded.turned_up, "message": f.message}}
            result["height_z_foreign"] = float(app.snapshot.means[:, 2].max() - app.snapshot.means[:, 2].min())
            app.request_screenshot(out + "_foreign.png")
            state["phase"] = 6
        elif p == 6:  # a splat file dropped on the viewer opens: called as GLFW calls the drop callback
            import ctypes
            import glfw

            addr = ctypes.cast(ctypes.pointer(app.window), ctypes.POINTER(ctypes.c_long)).contents.value
            _, c_callback = glfw._window_drop_callback_repository[addr]
            c_callback(app.window, 1, (ctypes.c_char_p * 1)({spz!r}.encode()))
            state["phase"] = 7
        elif p == 7 and f.job is None:
            result["dropped"] = f.loaded.name
            app.drops.paths.append(out + "_walk.bvh")  # the viewer opens splat files only
            state["phase"] = 8
        elif p == 8:
            result["dropped_other"] = f.message
            app.close()
        result["phase"] = state["phase"]

    rc = run_viewer({ply!r}, size=(960, 640), max_frames=600, script=script, idle_fps=30)
    result["rc"] = rc
    json.dump(result, open(out + ".json", "w"))
""")


@pytest.mark.gl
def test_viewer_shows_ours_and_foreign_files_and_reports_a_broken_one(tmp_path, avatar_ply):
    ours, foreign, broken = avatar_ply
    out = str(tmp_path / "viewer")
    script = tmp_path / "viewer.py"
    script.write_text(VIEWER_SCRIPT.format(root=str(ROOT), out=out, ply=str(ours), foreign=str(foreign),
                                           broken=str(broken), spz=str(DROPPED_SPZ)))
    proc = _xvfb(script, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    r = json.loads(Path(out + ".json").read_text())
    print("\n[viewer]", json.dumps(r, indent=1))
    assert r["rc"] == 0 and r["phase"] == 8, r
    assert r["dropped"] == "source.spz" and "dropped, but neither" in r["dropped_other"], r
    assert r["first"]["name"] == "avatar.ply" and r["first"]["up"] == "y_down" and r["first"]["n"] > 100
    assert 1.2 < r["height_z"] < 2.2  # stood up: the body's height is along +Z again
    assert "broken.ply" in r["broken_message"] and "truncated" in r["broken_message"]
    assert r["kept"] == "avatar.ply"  # the file shown stays
    s = r["second"]
    assert s["name"] == "foreign.ply" and s["up"] is None and s["turned"] == "y_down" and s["message"] is None
    assert s["n"] == r["first"]["n"]
    assert r["height_z_foreign"] == pytest.approx(r["height_z"], rel=1e-3)  # the y-down file stood up too
    from PIL import Image

    rgb = np.asarray(Image.open(out + "_rgb.png").convert("RGB"), np.float32)
    side = np.asarray(Image.open(out + "_normal_side.png").convert("RGB"), np.float32)
    foreign_img = np.asarray(Image.open(out + "_foreign.png").convert("RGB"), np.float32)
    assert rgb.shape == (640, 960, 3)
    centre = (slice(100, 540), slice(340, 620))  # the Gaussians are in the middle, panels on the right
    assert rgb[centre].std() > 5 and (np.abs(rgb - side).max(-1) > 30).sum() > 2000
    assert foreign_img[centre].std() > 5
    assert _red_pixels(out + "_broken_message.png") > 100  # the error is in the File panel


@pytest.mark.gl
def test_malformed_ply_at_start_is_an_error_window(tmp_path, avatar_ply):
    _, _, broken = avatar_ply
    bad = tmp_path / "not_a.ply"
    bad.write_text("hello\n")
    for path, expect in ((bad, "not a PLY file"), (broken, "truncated")):
        shot = tmp_path / f"{path.stem}.png"
        code = textwrap.dedent(f"""
            import sys
            sys.path.insert(0, {str(ROOT)!r})
            from app.studio.viewer import run_viewer
            sys.exit(run_viewer({str(path)!r}, size=(640, 400), max_frames=5, screenshot={str(shot)!r}))
        """)
        proc = _xvfb(None, tmp_path, code=code, timeout=120)
        assert proc.returncode == 2, proc.stdout + proc.stderr  # as the studio's other open errors
        assert "could not open the .ply" in proc.stderr and path.name in proc.stderr and expect in proc.stderr
        assert "Traceback" not in proc.stderr
        assert _red_pixels(shot) > 100
    # the command line: --ply with --run is refused before any window opens
    proc = subprocess.run([sys.executable, "-m", "app.cli", "--ply", str(bad), "--run", str(tmp_path)],
                          capture_output=True, text=True, check=False, timeout=120, cwd=str(ROOT))
    assert proc.returncode == 2 and "cannot go with --scene, --run or --device" in proc.stderr
