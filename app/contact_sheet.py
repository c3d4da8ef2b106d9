"""A labelled PNG grid of a scene: the training view and every evaluation camera, RGB and normals."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reconstruct.data.scene import Scene
from reconstruct.atomic import atomic_output


def _normal_rgb(normal: np.ndarray | None, like: np.ndarray) -> np.ndarray:
    if normal is None:
        return np.zeros_like(like)
    return np.clip(0.5 * (normal + 1.0), 0, 1) * (np.abs(normal).sum(-1, keepdims=True) > 0)


def write_contact_sheet(scene: Scene, path: str | Path, *, frame_index: int | None = None, dpi: int = 100) -> Path:
    """One column per camera (training first, then each evaluation azimuth) for one pose; rows: RGB,
    normals. Written to a temporary file and renamed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    views = scene.eval_views
    if frame_index is None:
        frame_index = views[0].frame_index if views else 0
    chosen = [v for v in views if v.frame_index == frame_index]
    frame = scene.frames[frame_index]
    cols = [("training view", frame.image, frame.normal, None)] + [
        (f"az {v.azimuth_deg:.0f}° {'seen' if v.seen else 'unseen'}", v.image, v.normal, v.seen) for v in chosen]
    fig, axes = plt.subplots(2, len(cols), figsize=(1.6 * len(cols), 3.6), squeeze=False)
    for c, (title, rgb, normal, seen) in enumerate(cols):
        color = "black" if seen is None else ("tab:orange" if seen else "tab:blue")
        axes[0, c].imshow(np.clip(rgb, 0, 1))
        axes[0, c].set_title(title, fontsize=7, color=color)
        axes[1, c].imshow(_normal_rgb(normal, rgb))
        for r in range(2):
            axes[r, c].set_xticks([])
            axes[r, c].set_yticks([])
    axes[0, 0].set_ylabel("RGB", fontsize=8)
    axes[1, 0].set_ylabel("normals (camera)", fontsize=8)
    fig.suptitle(f"{scene.name}: frame {frame_index}", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=dpi, facecolor="white")
    plt.close(fig)
    return path
