"""The one scheduled-value type: threestudio's ramp, the learning-rate drops, Eq. 14's halving."""

import pytest

from reconstruct.schedule import Scheduled
from reconstruct.stage2.config import Stage2Config
from reconstruct.train.config import Stage1Config


def test_ramp_like_threestudio():
    r = Scheduled.parse([100, 0.98, 0.5, 200])
    assert r(0) == 0.98 and r(100) == 0.98 and r(150) == pytest.approx(0.74) and r(200) == 0.5 and r(1e6) == 0.5
    assert Scheduled.parse(3.0)(12345) == 3.0
    assert Scheduled.parse("[0, 1, 3, 10]")(5) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="start_step, start_value"):
        Scheduled.parse([1, 2, 3])


def test_learning_rate_drops():
    s = Scheduled.drops(1.0, at=(1 / 3, 2 / 3), factor=0.1)
    assert s(0.0) == 1.0 and s(0.5) == pytest.approx(0.1) and s(0.9) == pytest.approx(0.01)
    assert Stage1Config.paper().lr_schedule()(0.5) == pytest.approx(0.1)
    assert Stage2Config().lr_schedule()(0.5) == 1.0 and Stage2Config().lr_schedule()(0.7) == pytest.approx(0.1)


def test_sds_weight_halving_eq14():
    # lambda(t) = lambda0 / 2^floor((t - t0) / k), t0 = k = 100
    h = Scheduled.halving(0.3, 100, 100)
    assert h(50) == 0.3 and h(100) == 0.3 and h(199) == 0.3
    assert h(200) == pytest.approx(0.15) and h(350) == pytest.approx(0.075) and h(400) == pytest.approx(0.0375)
    with pytest.raises(ValueError, match="interval k must be positive"):
        Scheduled.halving(0.3, 0, 0)
    with pytest.raises(ValueError, match="shape"):
        Scheduled("cosine", 1.0)


def test_exponential_decay_over_the_budget():
    e = Scheduled.exponential(2.0, 0.5, 1.0, 0.1)
    assert e(0.0) == 2.0 and e(0.5) == 2.0 and e(1.0) == pytest.approx(0.2) and e(2.0) == pytest.approx(0.2)
    assert e(0.75) == pytest.approx(2.0 * 0.1 ** 0.5)
    with pytest.raises(ValueError, match="x0 < x1"):
        Scheduled.exponential(1.0, 0.5, 0.5, 0.1)
    # Stage I: full rate for the first half of whatever budget ends first, then geometric to 1/10
    c = Stage1Config(iters=10**7, minutes=3.0)
    assert c.progress(100, 90.0) == pytest.approx(0.5)  # a minutes-only budget: time decides
    assert c.lr_schedule()(c.progress(100, 60.0)) == 1.0
    assert c.lr_schedule()(c.progress(400, 135.0)) == pytest.approx(0.1 ** 0.5)
    assert Stage1Config(iters=1000).lr_schedule()(Stage1Config(iters=1000).progress(1000, 1.0)) == pytest.approx(0.1)
