"""reconstruct/avatar/layer_nodes.py: the garment layer's decode nodes. Every Gaussian its own node
at every=1; otherwise bilinear weights that reproduce the node values on the nodes, a linear
function between them (rows clamped at the hem, columns wrapping round each tube, never across
tubes)."""

import numpy as np
import pytest

from reconstruct.avatar.layer_nodes import layer_nodes


def _values(nodes, f):
    return f(nodes.grid_rc[:, 0].astype(float), nodes.grid_rc[:, 1].astype(float))


def test_every_one_is_the_identity():
    n = layer_nodes(7, 12, 2, 1)
    assert n.shape == (7, 12)
    np.testing.assert_array_equal(n.index[:, 0], np.arange(7 * 12))
    np.testing.assert_array_equal(n.weights[:, 0], 1.0)
    np.testing.assert_array_equal(n.weights[:, 1:], 0.0)
    r, c = np.divmod(np.arange(7 * 12), 12)
    np.testing.assert_array_equal(n.grid_rc, np.stack([r, c], 1))


@pytest.mark.parametrize("rows,cols,tubes,every", [(9, 16, 1, 2), (10, 18, 2, 2), (11, 21, 1, 3), (5, 14, 2, 4)])
def test_nodes_reproduce_their_values_and_linear_functions_between(rows, cols, tubes, every):
    n = layer_nodes(rows, cols, tubes, every)
    per_tube = cols // tubes
    assert n.index.shape == (rows * cols, 4) and (n.weights >= -1e-12).all()
    np.testing.assert_allclose(n.weights.sum(1), 1.0)
    # the hem row and the top row are nodes; node rows every `every`
    assert set(n.grid_rc[:, 0]) == set(range(0, rows, every)) | {rows - 1}
    r, c = np.divmod(np.arange(rows * cols), cols)
    tube, local = np.divmod(c, per_tube)
    # a Gaussian on a node takes exactly that node's value
    on = {tuple(x): i for i, x in enumerate(n.grid_rc)}
    vals = np.random.default_rng(0).normal(size=len(n.grid_rc))
    interp = (vals[n.index] * n.weights).sum(1)
    for g in range(rows * cols):
        if (r[g], c[g]) in on:
            assert interp[g] == pytest.approx(vals[on[(r[g], c[g])]])
    # never mixes tubes
    node_tube = n.grid_rc[:, 1] // per_tube
    used = n.weights > 0
    assert (node_tube[n.index][used] == np.repeat(tube[:, None], 4, 1)[used]).all()
    # a function linear in (row, column within the tube) is reproduced away from the wrap span
    f = lambda rr, cc: 0.3 * rr - 0.7 * (cc % per_tube) + 2.0  # noqa: E731
    interp = (_values(n, f)[n.index] * n.weights).sum(1)
    last_node = max(range(0, per_tube, every))
    inside = local <= last_node
    np.testing.assert_allclose(interp[inside], f(r, c)[inside].astype(float), atol=1e-12)
    # past the last node column the value runs linearly back to the tube's first column
    wrap = ~inside
    span = per_tube - last_node
    t = (local[wrap] - last_node) / span
    row_part = 0.3 * r[wrap] + 2.0
    np.testing.assert_allclose(interp[wrap], row_part - 0.7 * last_node * (1 - t), atol=1e-12)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="positive integer"):
        layer_nodes(4, 8, 1, 0)
    with pytest.raises(ValueError, match="does not split into 3 tubes"):
        layer_nodes(4, 8, 3, 2)
