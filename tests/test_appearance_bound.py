"""benchmarks/appearance_bound.py: fitting the colours to the views lowers their error, moves only the
chosen Gaussians' colour residual, leaves the run folder as it was and the parameters' flags as found."""

import hashlib

import pytest
import torch

from benchmarks.appearance_bound import fit_colours, run_bound
from tests.tiny_runs import train_tiny


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    return train_tiny(tmp_path_factory.mktemp("bound") / "run", 3)


def _trainer(run):
    from reconstruct.run_folder import RunFolder

    return RunFolder(run).resume()


def _view_mse(state, views, background):
    from reconstruct.train.evaluate import rendered_views

    errs = [float((r.rgb - gt).square().mean()) for _, r, gt, _ in rendered_views(state, None, background, views=views)]
    return sum(errs) / len(errs)


def test_fitting_lowers_the_error_and_moves_only_the_chosen_rows(tiny_run):
    tr = _trainer(tiny_run)
    model, views = tr.state.model, tr.scene.eval_views
    before = _view_mse(tr.state, views, tr.background)
    start = model.decoder.color_residual.detach().clone()
    flags = {n: p.requires_grad for n, p in model.named_parameters()}
    rows = torch.zeros(model.num_gaussians, dtype=torch.bool)
    rows[::2] = True
    losses = fit_colours(tr.state, views, tr.background, rows, epochs=4, lr=0.01)
    assert len(losses) == 4
    after = _view_mse(tr.state, views, tr.background)
    assert after < 0.95 * before
    moved = (model.decoder.color_residual.detach() != start).any(1)
    assert moved[rows].any() and not moved[~rows].any()
    assert {n: p.requires_grad for n, p in model.named_parameters()} == flags


def test_no_rows_no_change_and_a_bad_mask_is_refused(tiny_run):
    tr = _trainer(tiny_run)
    model = tr.state.model
    start = model.decoder.color_residual.detach().clone()
    fit_colours(tr.state, tr.scene.eval_views[:2], tr.background, torch.zeros(model.num_gaussians, dtype=torch.bool),
                epochs=2, lr=0.05)
    assert torch.equal(model.decoder.color_residual.detach(), start)
    with pytest.raises(ValueError, match="rows must be"):
        fit_colours(tr.state, tr.scene.eval_views[:1], tr.background, torch.ones(3, dtype=torch.bool))


def test_the_run_folder_is_not_written_and_layer_needs_a_layer(tiny_run):
    digest = lambda: {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(tiny_run.iterdir()) if p.is_file()}
    was = digest()
    r = run_bound(tiny_run, "all", epochs=2, lr=0.01)
    assert r["after"]["seen_psnr"] > r["before"]["seen_psnr"]
    assert r["after"]["unseen_psnr"] > r["before"]["unseen_psnr"]
    assert digest() == was
    with pytest.raises(ValueError, match="needs a run with a garment layer"):
        run_bound(tiny_run, "layer", epochs=1)
