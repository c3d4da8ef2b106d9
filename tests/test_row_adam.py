"""RowAdam (train/row_adam.py): each row is Adam on its own gradients; rows without one stay put."""

import copy

import torch

from reconstruct.train.row_adam import RowAdam


def _grads(seed: int, steps: int, shape) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(shape, generator=g, dtype=torch.float64) for _ in range(steps)]


def test_one_row_is_torch_adam():
    """With a gradient on every step a single-row parameter follows torch.optim.Adam exactly."""
    start = torch.randn(1, 4, 3, dtype=torch.float64)
    a = torch.nn.Parameter(start.clone())
    b = torch.nn.Parameter(start.clone())
    ra, ta = RowAdam([a], lr=5e-3), torch.optim.Adam([b], lr=5e-3)
    for g in _grads(0, 25, start.shape):
        a.grad, b.grad = g.clone(), g.clone()
        ra.step()
        ta.step()
    assert torch.allclose(a, b, atol=1e-12, rtol=0)
    assert float((a - start).abs().max()) > 0.05  # it moved


def test_a_row_moves_only_on_its_own_gradients():
    """Rows drawn in turn: each ends where Adam on its own gradient sequence puts it, and a row that
    got no gradient on a step is left exactly as it was (torch.optim.Adam moves it by momentum)."""
    R = 3
    start = torch.randn(R, 2, 3, dtype=torch.float64)
    p = torch.nn.Parameter(start.clone())
    opt = RowAdam([p], lr=1e-2)
    dense = torch.nn.Parameter(start.clone())
    dense_opt = torch.optim.Adam([dense], lr=1e-2)
    per_row = [torch.nn.Parameter(start[r:r + 1].clone()) for r in range(R)]
    per_row_opt = [torch.optim.Adam([q], lr=1e-2) for q in per_row]
    gs = _grads(1, 30, (1, 2, 3))
    for k, g in enumerate(gs):
        r = k % R
        full = torch.zeros_like(start)
        full[r] = g[0]
        before = p.detach().clone()
        p.grad = full.clone()
        opt.step()
        others = [i for i in range(R) if i != r]
        assert torch.equal(p.detach()[others], before[others])
        per_row[r].grad = g.clone()
        per_row_opt[r].step()
        dense.grad = full.clone()
        dense_opt.step()
    for r in range(R):
        assert torch.allclose(p.detach()[r], per_row[r].detach()[0], atol=1e-12, rtol=0)
    assert not torch.allclose(dense.detach(), p.detach(), atol=1e-3)  # the dense Adam differs
    assert opt.state[p]["step"].tolist() == [10, 10, 10]


def test_centre_keeps_the_stepped_rows_mean_at_zero_and_leaves_the_others():
    R = 5
    p = torch.nn.Parameter(torch.zeros(R, 3, dtype=torch.float64))
    opt = RowAdam([p], lr=0.1, centre=True)
    for k in range(12):
        g = torch.zeros(R, 3, dtype=torch.float64)
        g[k % 3] = torch.tensor([1.0, -0.5, 0.25]) * (1 + k % 3)  # rows 0-2, all pushed the same way
        p.grad = g
        opt.step()
    moved = p.detach()[:3]
    assert torch.allclose(moved.mean(0), torch.zeros(3, dtype=torch.float64), atol=1e-12)
    assert float(moved.abs().max()) > 1e-3  # what differs between the rows is kept
    assert torch.equal(p.detach()[3:], torch.zeros(2, 3, dtype=torch.float64))  # never stepped: untouched
    # without centring the common push stays in every row
    q = torch.nn.Parameter(torch.zeros(R, 3, dtype=torch.float64))
    plain = RowAdam([q], lr=0.1)
    for k in range(12):
        g = torch.zeros(R, 3, dtype=torch.float64)
        g[k % 3] = torch.tensor([1.0, -0.5, 0.25]) * (1 + k % 3)
        q.grad = g
        plain.step()
    assert float(q.detach()[:3, 0].max()) < -0.3


def test_state_dict_round_trip_continues_identically():
    start = torch.randn(4, 3, dtype=torch.float64)
    a = torch.nn.Parameter(start.clone())
    oa = RowAdam([a], lr=1e-2, centre=True)
    gs = _grads(2, 10, (4, 3))
    for g in gs[:5]:
        a.grad = g * (torch.arange(4) % 2 == 0)[:, None]
        oa.step()
    b = torch.nn.Parameter(a.detach().clone())
    ob = RowAdam([b], lr=1e-2, centre=True)
    ob.load_state_dict(copy.deepcopy(oa.state_dict()))  # as a checkpoint file would
    for g in gs[5:]:
        a.grad, b.grad = g.clone(), g.clone()
        oa.step()
        ob.step()
    assert torch.equal(a, b)
