"""A PNG comparing an avatar's renders with the ground truth of every evaluation camera."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from reconstruct.atomic import atomic_output


def write_comparison_sheet(avatar, path: str | Path, *, frame_index: int | None = None,
                           others: list | None = None) -> Path:
    """Ground truth on top, then one row per avatar: ``avatar`` (a ``TrainedAvatar``) and any
    ``others`` given as ``(label, avatar)`` pairs on the same scene (e.g. Stage I and Stage II)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from reconstruct.metrics import psnr
    from reconstruct.train.render import render_avatar

    scene = avatar.scene
    views = scene.eval_views
    if not views:
        raise ValueError(f"scene {scene.name} has no evaluation views to compare with")
    if frame_index is None:
        frame_index = views[0].frame_index
    chosen = [v for v in views if v.frame_index == frame_index]
    rows = [(f"avatar (stage {avatar.stage}, step {avatar.step})", avatar)] + list(others or [])
    renders = []
    with torch.no_grad():
        for _, a in rows:
            posed = a.state.posed(frame_index)
            bg = torch.tensor(a.background, dtype=torch.float32, device=a.state.device)
            renders.append([render_avatar(posed, v.camera, bg, normals=False).rgb.clamp(0, 1) for v in chosen])
    fig, axes = plt.subplots(1 + len(rows), len(chosen), figsize=(1.6 * len(chosen), 1.9 * (1 + len(rows))),
                             squeeze=False)
    for c, v in enumerate(chosen):
        color = "tab:orange" if v.seen else "tab:blue"
        axes[0, c].imshow(np.clip(v.image, 0, 1))
        axes[0, c].set_title(f"az {v.azimuth_deg:.0f}° {'seen' if v.seen else 'unseen'}", fontsize=7, color=color)
        for r, row in enumerate(renders, start=1):
            axes[r, c].imshow(row[c].numpy())
            axes[r, c].set_title(f"{float(psnr(row[c], torch.as_tensor(v.image))):.1f} dB", fontsize=7)
        for ax in axes[:, c]:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0, 0].set_ylabel("ground truth", fontsize=8)
    for r, (label, _) in enumerate(rows, start=1):
        axes[r, 0].set_ylabel(label, fontsize=7)
    fig.tight_layout()
    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100, facecolor="white")
    plt.close(fig)
    return path
