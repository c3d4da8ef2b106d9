"""``SCENE/prepare_report.png``: what ``prepare`` did, for a few frames: the input crop, the person mask
(green: added by the refinement, red: removed by it), the fitted body over the image, and the fitted
body seen from the side with its lean. An edge of the frame that cuts the person off is a red line
across the image panels."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .lean import SideView

REPORT_IMAGE = "prepare_report.png"


@dataclass
class ReportFrame:
    name: str
    image: np.ndarray  # (H,W,3) uint8, the crop before masking
    mask: np.ndarray  # (H,W) float final mask
    raw_mask: np.ndarray | None  # (H,W) float the segmenter's mask before refinement
    fitted: np.ndarray  # (H,W) bool fitted body silhouette
    iou: float
    side: SideView
    # the edges of the frame that cut the person off in this frame: {edge: its position in the crop's
    # pixels} (a row for the top and the bottom, a column for the sides; ``crop.edge_lines``)
    cut: dict[str, float] = field(default_factory=dict)


def pick_frames(count: int, most: int = 4) -> list[int]:
    if count <= most:
        return list(range(count))
    return sorted({int(round(x)) for x in np.linspace(0, count - 1, most)})


def write_report_image(path: str | os.PathLike, frames: list[ReportFrame], title: str,
                       mask_title: str = "mask (green added, red removed)") -> Path:
    """``mask_title``: what the mask panel's green and red say (the refinement's, or where the
    user's own masks differ from the segmenter's)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    rows = len(frames)
    fig, axes = plt.subplots(rows, 4, figsize=(12, 3.2 * rows + 0.6), squeeze=False)
    for r, f in enumerate(frames):
        img = f.image.astype(np.float32) / 255.0
        m = f.mask > 0.5
        over = img * 0.35
        over[m] = img[m]
        if f.raw_mask is not None:
            raw = f.raw_mask > 0.5
            over[m & ~raw] = 0.5 * over[m & ~raw] + 0.5 * np.array([0.0, 1.0, 0.0])
            over[raw & ~m] = 0.5 * img[raw & ~m] + 0.5 * np.array([1.0, 0.0, 0.0])
        fit = img * 0.6
        fit[f.fitted] = 0.45 * img[f.fitted] + 0.55 * np.array([0.2, 0.5, 1.0])
        edge = m & ~_erode(m)
        fit[edge] = [1.0, 1.0, 0.0]
        side = np.where(f.side.silhouette[..., None], np.array([0.2, 0.5, 1.0]), np.array([1.0, 1.0, 1.0]))
        name = f.name + (f" (cut off: {', '.join(f.cut)})" if f.cut else "")
        panels = [(img, name), (over, mask_title),
                  (fit, f"fitted body, IoU {f.iou:.3f}"), (side, f"side view, lean {f.side.lean_deg:+.1f} deg")]
        for c, (im, label) in enumerate(panels):
            ax = axes[r, c]
            ax.imshow(np.clip(im, 0, 1))
            ax.set_title(label, fontsize=9)
            ax.axis("off")
        h, w = img.shape[:2]
        for c in range(3):  # the cutting edges in red on the image panels: what lies past them is guessed
            for e, at in f.cut.items():
                at = float(np.clip(at, 0, (h if e in ("top", "bottom") else w) - 1))
                if e in ("top", "bottom"):
                    axes[r, c].axhline(at, color="r", lw=2.5)
                else:
                    axes[r, c].axvline(at, color="r", lw=2.5)
        ax = axes[r, 3]
        ax.plot([f.side.head[0], f.side.feet[0]], [f.side.head[1], f.side.feet[1]], "r-", lw=1.5)
        ax.axvline(f.side.feet[0], color="0.6", lw=0.8, ls="--")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    """Lay out, write to a temporary file and rename onto ``path`` (a reader never sees half a PNG),
    and close the figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    tmp = path.with_name(path.name + ".part.png")
    fig.savefig(tmp, dpi=80)
    plt.close(fig)
    os.replace(tmp, path)
    return path


def _erode(m: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_erosion(m, iterations=1)


PEOPLE_IMAGE = "prepare_people.png"
# the people's tints, by their number (1-based) left to right; the chosen one is drawn in full
_TINTS = np.array([[0.95, 0.25, 0.2], [0.2, 0.45, 0.95], [0.2, 0.8, 0.3], [0.95, 0.8, 0.15], [0.8, 0.3, 0.85],
                   [0.2, 0.85, 0.85]])


def write_people_image(path: str | os.PathLike, image: np.ndarray, regions: list[np.ndarray],
                       boxes: list[tuple[float, float, float, float]], chosen: int, title: str) -> Path:
    """``SCENE/prepare_people.png`` where several people were found: ``image`` (H,W,3) uint8 (the frame
    they were numbered in), each person's pixels (``regions``, (H,W) bool, in their number's order,
    left to right) tinted and their box and number drawn, the ``chosen`` one (1-based) in a thick box
    and untinted: which ``--person N`` is whom."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    img = image.astype(np.float32) / 255.0
    over = img * 0.45
    for i, region in enumerate(regions):
        tint = _TINTS[i % len(_TINTS)]
        if i + 1 == chosen:
            over[region] = img[region]
        else:
            over[region] = 0.5 * img[region] + 0.5 * tint
    h, w = img.shape[:2]
    fig, ax = plt.subplots(figsize=(6.0 * w / max(h, w) + 0.4, 6.0 * h / max(h, w) + 0.6))
    ax.imshow(np.clip(over, 0, 1))
    for i, (x0, y0, x1, y1) in enumerate(boxes):
        tint = _TINTS[i % len(_TINTS)]
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color=tint,
                                   lw=3.0 if i + 1 == chosen else 1.2))
        ax.text(x0 + 3, y0 + 3, str(i + 1), color="white", fontsize=12, fontweight="bold", va="top",
                bbox={"facecolor": tint, "edgecolor": "none", "pad": 2})
    ax.set_title(title, fontsize=9)
    ax.axis("off")
    return _save(fig, path)
