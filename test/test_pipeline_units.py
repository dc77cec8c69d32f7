"""The pipeline's search around the whole-record fit (``fit_from_starts``,
``relaxation_unseen``) with the fit replaced by a stand-in whose cost along c2 is known
exactly: which fits it asks for, which it keeps, and how far the valley's other end
widens the std. Instant: mutation testing runs these (``./tasks mutation``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rheo_ros.identification import pipeline as pl
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.fit import FitStatistics
from rheo_ros.identification.noise import SensorNoise
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import RecordError


class Rec:
    source = "recX"
    sensor = None   # a model record: no sensor read
    dead_band = None


def statistics(cost=100.0, deviance=0.0):
    sig = ("P1", "P2", "markers")
    return FitStatistics(signals=sig, noise=dict.fromkeys(sig, 0.1), floor=dict.fromkeys(sig, 0.0),
                         weights={"P1": 0.1, "P2": 0.2, "markers": 1e-5}, residual_rms={}, fit_to_noise={},
                         samples=dict.fromkeys(sig, 100), clock_offsets={}, discretisation={}, cost=cost,
                         deviance=deviance, dof=290, free_parameters=6, passes=1, message="ok")


FIT = Estimate({"E": 2.0, "c1": 8.0, "c2": 1e4, "gamma": 0.3}, "whole_record", (),
               covariance=np.diag([1e-4, 4e-4, 1e4, 1e-6]), statistics=statistics())


class HeldFits:
    """Stand-in for ``fit_record`` with c2 held: cost flat down to c2 = ``knee``, then
    rising 10 per e-fold below it; E falls 0.1 per e-fold of c2 below the fit's."""

    def __init__(self, knee, fail_above=np.inf, slope=10.0, flat=0.01):
        self.knee, self.fail_above, self.slope, self.flat, self.calls = knee, fail_above, slope, flat, []

    def __call__(self, record, initial, fixed=None, forward=None, discretisation=True, weights=None, **kw):
        assert initial is FIT and forward == "fwd" and discretisation is False and not kw
        assert weights.force_std.tolist() == [0.1, 0.2] and weights.marker_std == 1e-5
        c2 = fixed["c2"]
        self.calls.append(c2)
        if c2 > self.fail_above:
            raise np.linalg.LinAlgError("singular")
        drop = np.log(FIT.params["c2"] / c2)
        cost = FIT.statistics.cost + self.slope * max(0.0, np.log(self.knee / c2)) + self.flat
        params = {**FIT.params, "E": 2.0 - 0.1 * drop, "c1": 8.0 + 0.2 * drop, "c2": c2}
        return replace(FIT, params=params, statistics=replace(FIT.statistics, cost=cost))


def test_a_relaxation_the_data_see_is_reported_as_fitted(monkeypatch):
    held = HeldFits(knee=1e6)                   # 30 x c2 costs 10 ln(1e6 / 3e5) = 12 more
    monkeypatch.setattr(pl, "fit_record", held)
    assert pl.relaxation_unseen(Rec(), FIT, "fwd", [{"c2": 1.0}]) == ("", FIT)
    assert held.calls == [pytest.approx(3e5)]
    # A held fit that fails says nothing either.
    monkeypatch.setattr(pl, "fit_record", HeldFits(knee=1.0, fail_above=1e5))
    assert pl.relaxation_unseen(Rec(), FIT, "fwd", [{"c2": 1.0}]) == ("", FIT)


def test_the_flat_valley_is_bisected_to_its_other_end(monkeypatch):
    held = HeldFits(knee=1e3)                   # within a cost of 4 down to 1e3 e^-0.4
    monkeypatch.setattr(pl, "fit_record", held)
    starts = [{"c2": 50.0}, {"c2": 2e4}, {"E": 1.0}, {"c2": -5.0}, {"c2": 10.0}]
    reason, est = pl.relaxation_unseen(Rec(), FIT, "fwd", starts)
    assert reason == ("the data fit as well with c2 30 x larger (cost +0.01): the relaxation is not seen")
    # 30 x, the lowest start proposed (10: not within), then 8 halvings of log c2 between.
    assert held.calls[:2] == [pytest.approx(3e5), pytest.approx(10.0)]
    assert len(held.calls) == 2 + pl.PROFILE_STEPS
    lo, hi = np.log(10.0), np.log(1e4)
    for c2 in held.calls[2:]:
        mid = 0.5 * (lo + hi)
        assert np.log(c2) == pytest.approx(mid, rel=1e-12)
        if 10.0 * max(0.0, np.log(1e3 / c2)) + 0.01 < 4.0:
            hi = mid
        else:
            lo = mid
    # The end: within (1/256 of the log range) of 1e3 e^-0.4, where E is 0.1 x ln(1e4 / c2) lower.
    end = 1e3 * np.exp(-0.4)
    assert abs(hi - np.log(end)) < np.log(1e3) / 256
    half_e, half_c1 = -0.05 * np.log(1e4 / np.exp(hi)), 0.1 * np.log(1e4 / np.exp(hi))
    np.testing.assert_allclose(np.diag(est.covariance),
                               [1e-4 + half_e**2, 4e-4 + half_c1**2, 1e4, 1e-6], rtol=1e-9)
    assert abs(half_e) == pytest.approx(0.05 * np.log(1e4 / end), rel=0.03)
    assert est.params == FIT.params and est.statistics is FIT.statistics
    np.testing.assert_array_equal(est.covariance - np.diag(np.diag(est.covariance)), 0.0)


def test_a_valley_reaching_the_lowest_start_ends_there(monkeypatch):
    held = HeldFits(knee=1.0)
    monkeypatch.setattr(pl, "fit_record", held)
    reason, est = pl.relaxation_unseen(Rec(), FIT, "fwd", [{"c2": 100.0}, {"c2": 500.0}])
    assert held.calls == [pytest.approx(3e5), pytest.approx(100.0)]
    drop = np.log(1e4 / 100.0)
    np.testing.assert_allclose(np.diag(est.covariance),
                               [1e-4 + (0.05 * drop) ** 2, 4e-4 + (0.1 * drop) ** 2, 1e4, 1e-6], rtol=1e-9)
    assert reason.startswith("the data fit as well with c2 30 x larger")


def test_an_unseen_relaxation_without_a_lower_start_or_a_covariance_keeps_the_fit(monkeypatch):
    held = HeldFits(knee=1.0)
    monkeypatch.setattr(pl, "fit_record", held)
    for starts in ((), [{"c2": 1e4}, {"c2": 2e5}, {"E": 1.0}, {"c2": 0.0}]):
        reason, est = pl.relaxation_unseen(Rec(), FIT, "fwd", starts)
        assert reason.endswith("the relaxation is not seen") and est is FIT
    no_cov = replace(FIT, covariance=None)

    def held_no_cov(record, initial, **kw):
        return replace(no_cov, statistics=replace(FIT.statistics, cost=101.0))
    monkeypatch.setattr(pl, "fit_record", held_no_cov)
    reason, est = pl.relaxation_unseen(Rec(), no_cov, "fwd", [{"c2": 1.0}])
    assert "(cost +1)" in reason and est is no_cov


# ---------------------------------------------------------------- fit_from_starts

NOISE = SensorNoise(np.array([0.1, 0.2]), np.ones((3, 2), bool), 1e-5, np.array([10, 10]), 30)


class Fits:
    """Stand-in for ``fit_record``: a fit's deviance is its start's ``dev``."""

    def __init__(self, fail=()):
        self.calls, self.fail = [], fail

    def __call__(self, record, initial, model=None, forward=None, weights=None, discretisation=True,
                 max_iterations=None):
        self.calls.append({"initial": initial, "model": model, "forward": forward, "weights": weights,
                           "discretisation": discretisation, "max_iterations": max_iterations})
        if initial.params.get("dev") in self.fail:
            raise ValueError(f"bad {initial.params['dev']}")
        return Estimate(dict(initial.params), "whole_record", (),
                        statistics=statistics(deviance=initial.params.get("dev", 0.0)))


def test_the_most_likely_screened_start_is_fitted_to_convergence(monkeypatch):
    fits = Fits()
    monkeypatch.setattr(pl, "fit_record", fits)
    model = Model(three_element(1.0, 1.0, 1.0))
    starts = [{"E": 5.0, "dev": 3.0}, {"E": 6.0, "dev": np.nan}, {"E": 7.0, "dev": -2.0}, {"E": 8.0, "dev": 1.0}]
    est = pl.fit_from_starts(Rec(), "fwd", starts, model=model, noise=NOISE)
    screened, final = fits.calls[:4], fits.calls[4]
    assert len(fits.calls) == 5
    for call, s in zip(screened, starts):
        assert call["initial"].params == {"E": s["E"], "c1": 1.0, "c2": 1.0, "dev": s["dev"]} or np.isnan(s["dev"])
        assert call["model"] is model and call["forward"] == "fwd" and call["weights"] == NOISE.weights
        assert call["discretisation"] is False and call["max_iterations"] == 25
    # The lowest deviance (a NaN never wins), to convergence with the mesh's error.
    assert final["initial"].params["E"] == 7.0
    assert final["discretisation"] is True and final["max_iterations"] is None
    assert final["model"] is model and final["forward"] == "fwd" and final["weights"] == NOISE.weights
    assert est.params["E"] == 7.0
    # A NaN first, then worse ones: still not the NaN.
    fits.calls.clear()
    pl.fit_from_starts(Rec(), "fwd", [{"E": 1.0, "dev": np.nan}, {"E": 2.0, "dev": 50.0}], model=model, noise=NOISE)
    assert fits.calls[-1]["initial"].params["E"] == 2.0


def test_the_default_model_and_a_single_start(monkeypatch):
    fits = Fits()
    monkeypatch.setattr(pl, "fit_record", fits)
    pl.fit_from_starts(Rec(), "fwd", [{"E": 3.0}], noise=NOISE)
    (call,) = fits.calls
    assert call["initial"].params == {"E": 3.0, "c1": 1.0, "c2": 1.0}
    assert call["model"].parameters == {"E": 1.0, "c1": 1.0, "c2": 1.0}
    assert call["discretisation"] is True and call["max_iterations"] is None and call["forward"] == "fwd"
    fits.calls.clear()
    pl.fit_from_starts(Rec(), "fwd", [{"E": 3.0}, {"c2": 4.0}], noise=NOISE)
    assert fits.calls[1]["initial"].params == {"E": 1.0, "c1": 1.0, "c2": 4.0}
    assert all(c["model"].parameters == {"E": 1.0, "c1": 1.0, "c2": 1.0} for c in fits.calls)
    # Noise not known: the fit weights by its own residuals.
    unknown = SensorNoise(np.array([0.1, np.nan]), np.ones((3, 2), bool), 1e-5, np.array([10, 0]), 30)
    fits.calls.clear()
    pl.fit_from_starts(Rec(), "fwd", [{"E": 3.0}, {"c2": 4.0}], noise=unknown)
    assert [c["weights"] for c in fits.calls] == [None, None, None]


def test_every_failure_is_named(monkeypatch):
    monkeypatch.setattr(pl, "fit_record", Fits(fail=(1.0, 2.0)))
    with pytest.raises(RecordError, match=r"^recX: the whole-record fit failed from every start "
                                          r"\(ValueError: bad 1.0; ValueError: bad 2.0\)$"):
        pl.fit_from_starts(Rec(), "fwd", [{"dev": 1.0}, {"dev": 2.0}], noise=NOISE)
    with pytest.raises(RecordError, match=r"^recX: the whole-record fit failed \(ValueError: bad 1.0\)$"):
        pl.fit_from_starts(Rec(), "fwd", [{"dev": 1.0}], noise=NOISE)
    # One failing start among good ones is passed over.
    fits = Fits(fail=(1.0,))
    monkeypatch.setattr(pl, "fit_record", fits)
    assert pl.fit_from_starts(Rec(), "fwd", [{"dev": 1.0}, {"dev": 5.0}], noise=NOISE).params["dev"] == 5.0


def test_a_cost_of_exactly_4_more_is_not_as_good(monkeypatch):
    held = HeldFits(knee=1.0, flat=4.0)
    monkeypatch.setattr(pl, "fit_record", held)
    assert pl.relaxation_unseen(Rec(), FIT, "fwd", [{"c2": 1.0}]) == ("", FIT)
    monkeypatch.setattr(pl, "fit_record", HeldFits(knee=1.0, flat=3.99))
    assert pl.relaxation_unseen(Rec(), FIT, "fwd", [{"c2": 1.0}])[0].startswith("the data fit as well")


def test_any_positive_lower_start_counts(monkeypatch):
    held = HeldFits(knee=1e-3)                 # flat all the way down
    monkeypatch.setattr(pl, "fit_record", held)
    _, est = pl.relaxation_unseen(Rec(), FIT, "fwd", [{"c2": 0.5}])
    assert held.calls == [pytest.approx(3e5), 0.5]
    assert est.covariance[0, 0] == pytest.approx(1e-4 + (0.05 * np.log(1e4 / 0.5)) ** 2, rel=1e-9)


def test_a_valley_with_no_point_below_the_fit_leaves_the_std(monkeypatch):
    held = HeldFits(knee=1e4, slope=1000.0)    # steep at once below the fit's c2
    monkeypatch.setattr(pl, "fit_record", held)
    reason, est = pl.relaxation_unseen(Rec(), FIT, "fwd", [{"c2": 10.0}])
    assert len(held.calls) == 2 + pl.PROFILE_STEPS and reason
    np.testing.assert_array_equal(est.covariance, FIT.covariance)
