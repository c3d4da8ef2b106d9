"""Adam over the rows of a parameter, each row on its own: the per-frame pose corrections.

Why. Pose refinement keeps one correction per video frame in one (frames, ...) tensor, and a step
draws one frame, so one row gets a gradient. ``torch.optim.Adam`` steps every row on every step: a
row's first moment keeps moving it for tens of steps after its frame was drawn (0.9^k), and its
second moment, fed zeros in between, shrinks, so the stale move is divided by less. With 53 frames
a row moved about as far between two of its draws as a dense parameter would in 70 steps, along a
gradient the avatar had long answered. Here a row's moments and step count advance only on the steps
its gradient is non-zero, which is Adam on that frame's own sequence of gradients (InstantAvatar's
sparse per-frame embeddings with ``SparseAdam`` do the same; this keeps the bias correction per row).

The common part. A correction shared by every frame (all frames 2 cm further from the camera) is the
avatar's to learn, not the poses': the avatar can follow it, the frames no step trains (held-out
frames, and every novel pose) then lack it, and the corrections drift along it because nothing in
the images pins it. With ``centre``, after each step the rows that have had a step are moved
together so that their mean is zero: refinement corrects how the frames differ from one another,
and their mean pose stays the fit's.
"""

from __future__ import annotations

import torch


class RowAdam(torch.optim.Optimizer):
    """Adam (Kingma & Ba, no weight decay) in which each row of each parameter (its first index)
    has its own moments and step count, advanced only on steps where the row's gradient is not all
    zero; rows without one are left exactly as they are. ``centre``: afterwards subtract from the
    rows that have had a step their mean (module docstring)."""

    def __init__(self, params, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8,
                 centre: bool = False) -> None:
        if lr <= 0:
            raise ValueError(f"RowAdam: lr must be > 0, found {lr}")
        if not (0.0 <= betas[0] < 1.0 and 0.0 <= betas[1] < 1.0):
            raise ValueError(f"RowAdam: betas must be in [0, 1), found {betas}")
        super().__init__(params, dict(lr=lr, betas=tuple(betas), eps=eps, centre=centre))

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            b1, b2 = group["betas"]
            for p in group["params"]:
                if p.grad is None or p.dim() == 0:
                    continue
                g = p.grad
                state = self.state[p]
                if not state:
                    state["step"] = torch.zeros(p.shape[0], dtype=torch.float64, device=p.device)
                    state["exp_avg"] = torch.zeros_like(p)
                    state["exp_avg_sq"] = torch.zeros_like(p)
                rows = (g.reshape(p.shape[0], -1) != 0).any(1)
                if rows.any():
                    steps = state["step"]
                    steps[rows] += 1
                    m, v = state["exp_avg"], state["exp_avg_sq"]
                    m[rows] = b1 * m[rows] + (1 - b1) * g[rows]
                    v[rows] = b2 * v[rows] + (1 - b2) * g[rows] * g[rows]
                    shape = (-1,) + (1,) * (p.dim() - 1)
                    c1 = (1 - b1 ** steps[rows]).to(p.dtype).reshape(shape)
                    c2 = (1 - b2 ** steps[rows]).to(p.dtype).reshape(shape)
                    p[rows] -= group["lr"] * (m[rows] / c1) / ((v[rows] / c2).sqrt() + group["eps"])
                if group["centre"]:
                    stepped = state["step"] > 0
                    if stepped.any():
                        p[stepped] -= p[stepped].mean(0, keepdim=True)
        return loss
