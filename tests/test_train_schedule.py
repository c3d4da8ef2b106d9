import pytest

from reconstruct.train.schedule import Ramp, halving, step_decay


def test_ramp_like_threestudio():
    r = Ramp.parse([100, 0.98, 0.5, 200])
    assert r(0) == 0.98 and r(100) == 0.98 and r(150) == pytest.approx(0.74) and r(200) == 0.5 and r(1e6) == 0.5
    assert Ramp.parse(3.0)(12345) == 3.0
    assert Ramp.parse("[0, 1, 3, 10]")(5) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="start_step, start_value"):
        Ramp.parse([1, 2, 3])


def test_step_decay():
    assert step_decay(0.0, (1 / 3, 2 / 3), 0.1) == 1.0
    assert step_decay(0.5, (1 / 3, 2 / 3), 0.1) == pytest.approx(0.1)
    assert step_decay(0.9, (1 / 3, 2 / 3), 0.1) == pytest.approx(0.01)


def test_sds_weight_halving_eq14():
    # lambda(t) = lambda0 / 2^floor((t - t0) / k), t0 = k = 100
    assert halving(0.3, 50, 100, 100) == 0.3
    assert halving(0.3, 100, 100, 100) == 0.3
    assert halving(0.3, 199, 100, 100) == 0.3
    assert halving(0.3, 200, 100, 100) == pytest.approx(0.15)
    assert halving(0.3, 350, 100, 100) == pytest.approx(0.075)
    assert halving(0.3, 400, 100, 100) == pytest.approx(0.0375)
    with pytest.raises(ValueError):
        halving(0.3, 1, 0, 0)
