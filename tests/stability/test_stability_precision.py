"""float32 against float64: one Stage I training step (loss and every parameter gradient) of the
small avatar of the training tests, on a frame of the tiny synthetic scene.

Expectation: relative loss difference < 1e-6; relative gradient difference (norm of the difference
over the norm of the float64 gradient) < 1e-4 for every parameter tensor. The float64 run uses the
same rasterizer (the compiled kernel dispatches on the dtype)."""

from __future__ import annotations

import copy

import torch
from stability_helpers import all_finite, record, stage1_loss

LOSS_TOL = 1e-6
GRAD_TOL = 1e-4


def test_training_step_float32_vs_float64(tiny_scene, tiny_config):
    from reconstruct.train.trainer import Trainer

    session = Trainer(tiny_scene, tiny_config)
    for _ in range(3):  # away from the initial state
        session.step()
    results = {}
    for dtype in (torch.float32, torch.float64):
        model = copy.deepcopy(session.model).to(dtype)
        frame = 1
        tgt = session.data.targets[frame]
        transforms = session.state.frame_transforms(frame).to(dtype)
        loss, terms, _ = stage1_loss(model, transforms, tgt.camera, tgt.image.to(dtype),
                                     tgt.normal.to(dtype) if tgt.normal is not None else None,
                                     config=tiny_config, dtype=dtype, background=tiny_config.background)
        loss.backward()
        grads = {name: p.grad.double() for name, p in model.named_parameters() if p.grad is not None}
        assert all_finite([loss, *grads.values()])
        results[dtype] = (float(loss.detach()), {k: float(v.detach()) for k, v in terms.items()}, grads)

    (l32, t32, g32), (l64, t64, g64) = results[torch.float32], results[torch.float64]
    loss_rel = abs(l32 - l64) / abs(l64)
    grad_rel = {k: float((g32[k] - g64[k]).norm() / g64[k].norm()) for k in g64 if float(g64[k].norm()) > 0}
    worst = max(grad_rel, key=grad_rel.get)
    record("float32 vs float64 Stage I step", loss_rel_err=loss_rel, worst_grad_rel_err=grad_rel[worst],
           worst_grad=worst, terms_rel_err=max(abs(t32[k] - t64[k]) / max(abs(t64[k]), 1e-30) for k in t64))
    assert loss_rel < LOSS_TOL, (l32, l64)
    assert grad_rel[worst] < GRAD_TOL, grad_rel
