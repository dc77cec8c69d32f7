"""Pooling successive experiments on one object, and flagging a changed one
(``identification.pooling``), on estimates drawn from known Gaussians."""

import numpy as np
import pytest
from scipy.stats import chi2

from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.pooling import LEVEL, pool_experiments, pool_of

TRUE = np.array([3.33e4, 1.69e5, 3.11e7])
STD = np.array([16.5, 104.0, 1.0e5])                 # one push's fit (test_many_pushes' bag)
CORR = np.array([[1.0, 0.6, -0.3], [0.6, 1.0, -0.2], [-0.3, -0.2, 1.0]])
COV = CORR * np.outer(STD, STD)


def estimate(values, cov=COV) -> Estimate:
    return Estimate(dict(zip(("E", "c1", "c2"), np.asarray(values, float).tolist())), "whole_record", (),
                    covariance=np.asarray(cov, float))


def draws(rng, n, shift=np.zeros(3)):
    return [estimate(v) for v in rng.multivariate_normal(TRUE + shift, COV, size=n)]


def test_pushes_on_one_object_pool_into_one_estimate_whose_std_falls_as_one_over_root_n():
    rng = np.random.default_rng(7)
    pools, changes = pool_experiments(draws(rng, 9))
    assert changes == [] and len(pools) == 1 and pools[0].experiments == tuple(range(1, 10))
    np.testing.assert_allclose(list(pools[0].std.values()), STD / 3, rtol=1e-9)
    # The information-weighted mean of equal covariances is the plain mean.
    assert pools[0].chi2 == pytest.approx(sum(
        float((np.array(list(e.params.values())) - pools[0].values) @ np.linalg.solve(COV, np.array(
            list(e.params.values())) - pools[0].values)) for e in draws(np.random.default_rng(7), 9)), rel=1e-9)
    assert pools[0].dof == 8 * 3


def test_the_pooled_values_are_right_and_the_false_alarm_rate_is_the_level():
    """400 runs of 4 unchanged pushes: every pooled value within 4 pooled stds of the
    truth, and the pooled chi-square's mean is its dof within 5 % (its own std of the mean
    is sqrt(2 dof / 400)); false 'changed' flags: 1 in 1000 per push expected, 0-4 allowed
    in 1200 tests (Poisson 1.2: P(> 4) = 0.8 %)."""
    rng = np.random.default_rng(11)
    flags, chis = 0, []
    for _ in range(400):
        pools, changes = pool_experiments(draws(rng, 4))
        flags += len(changes)
        if not changes:
            assert np.all(np.abs(pools[0].values - TRUE) < 4 * np.sqrt(np.diag(pools[0].covariance)))
            chis.append(pools[0].chi2)
    assert flags <= 4
    assert np.mean(chis) == pytest.approx(9.0, rel=0.05)


def test_a_changed_object_is_flagged_with_the_parameters_that_moved_and_starts_a_new_pool():
    """Two pushes, then the object softens by 0.5 % in E (10 push stds; c1 and c2 as
    before), two more: a change at push 3 naming E alone, two pools of two."""
    rng = np.random.default_rng(3)
    before, after = draws(rng, 2), draws(rng, 2, shift=np.array([-0.005 * TRUE[0], 0.0, 0.0]))
    pools, changes = pool_experiments(before + after)
    assert [p.experiments for p in pools] == [(1, 2), (3, 4)]
    assert [c.experiment for c in changes] == [3]
    assert list(changes[0].moved) == ["E"] and changes[0].moved["E"] < -5
    assert changes[0].limit == pytest.approx(chi2.isf(LEVEL, 3))


def test_a_parameter_the_data_leave_open_carries_no_weight():
    """A push whose c2 is undetermined (infinite variance) pools E and c1 with the others
    and leaves c2 to them, and is not flagged for its c2."""
    cov = COV.copy()
    cov[2, :], cov[:, 2] = 0.0, 0.0
    cov[2, 2] = np.inf
    rng = np.random.default_rng(5)
    pushes = draws(rng, 2) + [estimate(TRUE + [0.0, 0.0, 5e6], cov)]
    pools, changes = pool_experiments(pushes)
    assert changes == [] and len(pools) == 1
    # Its c2 value (50 stds off) does not pull the pool; its E and c1 sharpen c2 only through
    # their correlation with it (between two pushes' worth and three).
    assert abs(pools[0].params["c2"] - TRUE[2]) < 4 * pools[0].std["c2"]
    assert STD[2] / np.sqrt(3) < pools[0].std["c2"] <= STD[2] / np.sqrt(2)
    assert pools[0].std["E"] < STD[0] / np.sqrt(2)


def test_a_push_said_to_be_another_object_starts_a_pool_whatever_its_parameters():
    """Four draws of one object; the goal says push 3 is another: pools (1, 2) and (3, 4),
    the change stated, nothing moved (the same material, within its stds), its distance
    still given; numbers other than 1..n carry through."""
    rng = np.random.default_rng(3)
    pools, changes = pool_experiments(draws(rng, 4), numbers=[5, 6, 7, 8], new_objects={7})
    assert [p.experiments for p in pools] == [(5, 6), (7, 8)]
    [change] = changes
    assert change.experiment == 7 and change.stated and change.moved == {}
    assert 0.0 < change.distance < change.limit
    assert "said by the goal" in change.describe() and change.to_json()["stated"] is True
    # A statement on the first push has nothing to part from.
    pools, changes = pool_experiments(draws(rng, 2), new_objects={1})
    assert changes == [] and [p.experiments for p in pools] == [(1, 2)]


def test_pool_of_names_the_pool_that_holds_an_experiment():
    rng = np.random.default_rng(3)
    pools, _ = pool_experiments(draws(rng, 3), new_objects={3})
    assert pool_of(pools, 2).experiments == (1, 2) and pool_of(pools, 3).experiments == (3,)
    with pytest.raises(KeyError):
        pool_of(pools, 4)
