"""The non-finite guard of the Trainer (reconstruct/train/trainer.py): a non-finite loss or
gradient skips the step (parameters and optimiser state untouched), a non-finite parameter after
the step restores the last good state; both are counted (trainer.nonfinite_skipped /
restored_states, the metrics log's train record) and training goes on.

The faults are injected at a chosen step: NaN from a loss term (a NaN loss), a NaN
gradient through a tensor hook on the feature map (a finite loss), NaN written into a weight by
the optimiser step (a non-finite parameter)."""

from __future__ import annotations

import copy
import json

import pytest
import torch
from stability_helpers import all_finite, record

from reconstruct.train.checkpoint import load_checkpoint
from reconstruct.run_folder import RunFolder
from reconstruct.train.trainer import Trainer

BAD_STEP = 2  # the fault is injected in the step that starts with this step count


def snapshot(session):
    return (copy.deepcopy(session.model.state_dict()), copy.deepcopy(session.optimizer.state_dict()),
            session.state.pose_delta.detach().clone())


def assert_same(a, b):
    (ma, oa, pa), (mb, ob, pb) = a, b
    for k in ma:
        assert torch.equal(ma[k], mb[k]), k
    assert torch.equal(pa, pb)
    for i, state in oa["state"].items():
        for k, v in state.items():
            assert torch.equal(torch.as_tensor(v), torch.as_tensor(ob["state"][i][k])), (i, k)


def run_with_fault(session, inject, steps=5):
    """Advance ``steps`` times; ``inject(session)`` arms the fault before step BAD_STEP and returns
    a disarm callable. Returns the outputs and the snapshots taken before each step."""
    outs, before = [], []
    for _ in range(steps):
        before.append(snapshot(session))
        disarm = inject(session) if session.step_count == BAD_STEP else None
        try:
            out, _ = session.advance(log_every=1000)
        finally:
            if disarm:
                disarm()
        outs.append(out)
    return outs, before


def nan_loss(session):
    """A NaN loss from a finite render: the offset regulariser returns NaN."""
    from reconstruct.train import losses

    original = losses.mean_square
    losses.mean_square = lambda x: original(x) * torch.nan

    def disarm():
        losses.mean_square = original

    return disarm


def nan_gaussians(session):
    """NaN in the decoded colours (what an overflowing decoder gives): NaN Gaussians."""
    original = session.model.canonical

    def canonical(*a, **k):
        canon = original(*a, **k)
        canon.colors = canon.colors * torch.nan
        return canon

    session.model.canonical = canonical
    return lambda: delattr(session.model, "canonical")


def nan_gradient(session):
    """A finite loss whose gradient w.r.t. the feature map is NaN in one entry."""
    def hook(grad):
        grad = grad.clone()
        grad.view(-1)[0] = torch.nan
        return grad

    handle = session.model.features.register_hook(hook)
    return handle.remove


def nan_parameter(session):
    """The optimiser step writes NaN into one decoder weight (finite loss and gradients)."""
    original = session.optimizer.step

    def step(*a, **k):
        out = original(*a, **k)
        with torch.no_grad():
            next(session.model.decoder.parameters()).view(-1)[0] = torch.nan
        return out

    session.optimizer.step = step
    return lambda: delattr(session.optimizer, "step")


@pytest.mark.parametrize("fault", [nan_loss, nan_gradient])
def test_nonfinite_loss_or_gradient_skips_the_step(fault, tiny_scene, tiny_config, tmp_path):
    session = Trainer(tiny_scene, tiny_config, tmp_path)
    outs, before = run_with_fault(session, fault)
    bad = outs[BAD_STEP]
    assert bad.get("skipped") and bad["nonfinite_skipped"] == 1 and bad["restored_states"] == 0
    # the skipped step changed nothing: parameters, Adam moments and step counts, poses
    assert_same(before[BAD_STEP], before[BAD_STEP + 1])
    # the steps around it trained, with finite numbers
    assert all(not o.get("skipped") for i, o in enumerate(outs) if i != BAD_STEP)
    assert not torch.equal(before[-1][0]["features"], session.model.state_dict()["features"])
    assert all_finite(list(session.model.parameters()))
    assert session.step_count == 5 and session.nonfinite_skipped == 1
    # counted in the metrics log and in the checkpoint
    records = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    skipped = [r for r in records if r.get("kind") == "train" and r.get("skipped")]
    assert len(skipped) == 1 and skipped[0]["nonfinite_skipped"] == 1 and skipped[0]["step"] == BAD_STEP + 1
    assert load_checkpoint(session.save())["nonfinite_skipped"] == 1
    assert RunFolder(tmp_path).resume(tiny_scene).nonfinite_skipped == 1
    record(f"guard: {fault.__name__}", skipped=session.nonfinite_skipped, restored=session.restored_states)


def test_nonfinite_parameter_restores_the_last_good_state(tiny_scene, tiny_config, tmp_path):
    session = Trainer(tiny_scene, tiny_config, tmp_path)
    outs, before = run_with_fault(session, nan_parameter)
    bad = outs[BAD_STEP]
    assert bad.get("skipped") and bad["restored_states"] == 1 and bad["nonfinite_skipped"] == 1
    # the last good state is the one kept at the first step (kept every GOOD_STATE_EVERY steps)
    assert_same(before[0], snapshot_after_restore := before[BAD_STEP + 1])
    assert all_finite([t for t in snapshot_after_restore[0].values()])
    assert all(not o.get("skipped") for i, o in enumerate(outs) if i != BAD_STEP)
    assert all_finite(list(session.model.parameters()))
    assert session.restored_states == 1
    record("guard: nan_parameter", skipped=session.nonfinite_skipped, restored=session.restored_states)


def test_persistent_nan_never_reaches_the_parameters(tiny_scene, tiny_config):
    """A fault on every step (a frame that always gives NaN): every step is skipped, the run still
    ends (skipped steps count), the parameters stay those of the start."""
    session = Trainer(tiny_scene, tiny_config)
    start = snapshot(session)
    disarm = nan_loss(session)
    try:
        for _ in range(4):
            assert session.step().get("skipped")
    finally:
        disarm()
    assert session.nonfinite_skipped == 4 and session.step_count == 4
    assert_same(start, snapshot(session))


def test_nonfinite_gaussians_skip_the_step(tiny_scene, tiny_config, tmp_path):
    session = Trainer(tiny_scene, tiny_config, tmp_path)
    outs, before = run_with_fault(session, nan_gaussians)
    assert outs[BAD_STEP].get("skipped") and session.nonfinite_skipped == 1
    assert_same(before[BAD_STEP], before[BAD_STEP + 1])
