"""Runs the studio for the GUI tests: a real window (the test drives it with xdotool) whose state is
written to ``OUT.state.json`` and widget rectangles to ``OUT.rects.json`` every few frames.

Requests from the test are files: ``OUT.shot_NAME.req`` saves a screenshot ``OUT.NAME.png`` of the
current frame, ``OUT.quit`` closes the window (as the user closing it would), ``OUT.dump_NAME.req``
writes ``OUT.NAME.npz``: the edit selection and the latest snapshot's arrays (tests/test_studio_edit.py).

usage: python tests/studio_driver.py OUT SCENE [RUN]"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def tiny_config():
    from reconstruct.avatar.config import AvatarConfig
    from reconstruct.train.config import Stage1Config

    return Stage1Config(iters=100000, eval_every_seconds=1e9, checkpoint_every_seconds=1e9, crop_margin=4,
                        avatar=AvatarConfig(gaussian_resolution=48, feature_resolution=32, feature_channels=8,
                                            pose_feature_channels=8, hidden=32))


def state_of(app) -> dict:
    s = app.status
    c = app.trainer.controls.get()  # what the GUI handed to the trainer thread
    snap = app.latest_snapshot()
    return {
        "frame": app.frame_count, "fps": app.fps, "step": s.step, "stage": s.stage,
        "num_frames": len(app.scene.frames), "mode": app.view.mode.value,
        "controls": {"paused": c.paused, "frame_index": c.frame_index, "space": c.space, "stage2": c.stage2,
                     "stage2_version": c.stage2_version, "novel": c.novel},
        "snapshot": {"frame_index": snap.frame_index, "step": snap.step, "version": snap.version, "n": len(snap)},
        "drawn": list(app.last_drawn_snapshot) if app.last_drawn_snapshot else None,
        "stage2_message": s.stage2_message, "error": s.error,
        "export_message": app.export.message, "screenshots": app.export.saved_screenshots,
        "edits": edit_state(app),
    }


def edit_state(app) -> dict:
    """The editor as the tests see it: tool, selection, the edit list, a request in flight."""
    ed = getattr(app, "edits", None)
    if ed is None or ed.session is None:
        return {"error": getattr(ed, "error", None) if ed is not None else None}
    s = ed.session
    return {"tool": ed.tools.tool, "panel": bool(app.view.edit_panel), "selected": ed.selected_count,
            "applied": [[e.id, e.op.name, e.count] for e in s.entries()],
            "undone": [[e.id, e.op.name, e.count] for e in s.undone],
            "pending": ed.busy, "message": ed.panel.message, "result": ed.panel.result,
            "strokes": len(ed.timings)}


def dump_arrays(app, path) -> None:
    """The selection and the latest snapshot's arrays (``ids``: -1 when the snapshot has no ids)."""
    import numpy as np

    snap = app.latest_snapshot()
    s = app.edits.session
    arrays = {k: getattr(snap, k) for k in ("means", "scales", "rotations", "colors", "opacities", "normals",
                                             "visibility")}
    arrays["ids"] = np.full(1, -1) if snap.ids is None else np.asarray(snap.ids)
    arrays["selection"] = s.selection.copy()
    arrays["version"] = np.asarray(snap.version)
    tmp = Path(str(path) + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def main(out: str, scene: str, run=None) -> int:
    from app.studio.window import run_studio

    out_p = Path(out)

    def write(path: Path, data) -> None:
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(path)

    def script(app):
        for req in sorted(out_p.parent.glob(out_p.name + ".shot_*.req")):
            name = req.name[len(out_p.name) + len(".shot_"):-len(".req")]
            app.request_screenshot(f"{out}.{name}.png")
            req.unlink()
        for req in sorted(out_p.parent.glob(out_p.name + ".dump_*.req")):
            name = req.name[len(out_p.name) + len(".dump_"):-len(".req")]
            dump_arrays(app, f"{out}.{name}.npz")
            req.unlink()
        if Path(out + ".quit").exists():
            app.close()
        if app.frame_count % 3 == 0:
            write(Path(out + ".state.json"), state_of(app))

    rc = run_studio(scene, run, config=tiny_config(), size=(1280, 800), script=script, progress=False,
                    rects_path=out + ".rects.json")
    write(Path(out + ".exit.json"), {"rc": rc})
    return rc


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
