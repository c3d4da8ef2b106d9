"""A PNG comparing an avatar's renders with the ground truth of every evaluation camera."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from reconstruct.atomic import atomic_output


def write_comparison_sheet(session, path: str | Path, *, frame_index: int | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from reconstruct.metrics import psnr
    from reconstruct.train.render import render_avatar

    scene = session.scene
    views = scene.eval_views
    if not views:
        raise ValueError(f"scene {scene.name} has no evaluation views to compare with")
    if frame_index is None:
        frame_index = views[0].frame_index
    chosen = [v for v in views if v.frame_index == frame_index]
    with torch.no_grad():
        canon = session.model.canonical()
        posed = session.model.pose(canon, session.frame_transforms(frame_index))
        renders = [render_avatar(posed, v.camera, session.background, normals=False).rgb.clamp(0, 1) for v in chosen]
    fig, axes = plt.subplots(2, len(chosen), figsize=(1.6 * len(chosen), 3.8), squeeze=False)
    for c, (v, r) in enumerate(zip(chosen, renders)):
        value = float(psnr(r, torch.as_tensor(v.image)))
        color = "tab:orange" if v.seen else "tab:blue"
        axes[0, c].imshow(np.clip(v.image, 0, 1))
        axes[0, c].set_title(f"az {v.azimuth_deg:.0f}° {'seen' if v.seen else 'unseen'}", fontsize=7, color=color)
        axes[1, c].imshow(r.numpy())
        axes[1, c].set_title(f"{value:.1f} dB", fontsize=7)
        for ax in axes[:, c]:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0, 0].set_ylabel("ground truth", fontsize=8)
    axes[1, 0].set_ylabel(f"avatar (step {session.step_count})", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100, facecolor="white")
    plt.close(fig)
    return path
