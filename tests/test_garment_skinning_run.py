"""benchmarks/garment_skinning_run.py: the garment's weights read at a layer Gaussian are the mesh's
own at a vertex and the barycentric blend inside a triangle; a scene without a garment is refused."""

import numpy as np
import pytest

from benchmarks.garment_skinning_run import garment_weights_at, main
from tests.tiny_runs import TINY_SCENE

VERTS = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], np.float64)
FACES = np.array([[0, 1, 2], [0, 2, 3]])
W = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.2, 0.3, 0.5]], np.float64)


def test_at_a_vertex_the_vertex_weights_and_inside_the_blend():
    pts = np.array([[0.1, 0.0, 0.003],  # over vertex 1, off the surface by 3 mm
                    [0.2 / 3, 0.1 / 3, 0.0]])  # the centroid of face 0
    w = garment_weights_at(pts, VERTS, FACES, W, n=6)
    np.testing.assert_allclose(w[0], W[1], atol=1e-12)
    np.testing.assert_allclose(w[1], W[:3].mean(0), atol=1e-12)
    np.testing.assert_allclose(w.sum(1), 1.0)


def test_a_weight_table_of_the_wrong_length_is_refused():
    with pytest.raises(ValueError, match="3 rows for 4 vertices"):
        garment_weights_at(np.zeros((1, 3)), VERTS, FACES, W[:3])


def test_a_scene_without_a_loose_garment_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="not a synthetic loose-clothing scene"):
        main(["train", "--scene", TINY_SCENE, "--out", str(tmp_path / "run"), "--iters", "1"])
    assert not (tmp_path / "run").exists()
