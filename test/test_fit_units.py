"""The whole-record fit (``rheo_ros.identification.fit``) on a tiny record made by its own
forward model (3 x 3 markers, three tactile segments, 41 s at 10 Hz): every figure it
reports against an independent measure of it, at a stated tolerance. Fast (each fit
0.1-0.2 s): mutation testing runs these (``./tasks mutation``). The fixtures are
per test, not per module: mutmut maps a test to the functions it calls, and a fit
cached by an earlier test would leave the later ones unmapped (never run on a mutant)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
import pytest

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import GAMMA_RANGE, Mesh
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification import fit as F
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.fit import (
    FitStatistics,
    ParameterMap,
    WholeRecordProblem,
    cramer_rao_std,
    fit_record,
)
from rheo_ros.identification.noise import Weights
from rheo_ros.models.effects import Effect, Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record

TRUTH = {"E": 2.0, "c1": 8.0, "c2": 40.0, "gamma": 0.3}
PROFILE = StageProfile(depth=0.01, velocity=0.001, keep_time=20.0, start_delay=1.0, release_time=10.0)
FORCE_STD, MARKER_STD = 5e-7, 1e-6          # N (~0.5 % of the peak force), m
MODEL = Model(three_element(1.0, 1.0, 1.0))
NAMES = ("E", "c1", "c2", "gamma")



def with_band(record: Record, band) -> Record:
    """``record`` read through a dead band of any per-segment forces: a sensor stand-in
    (``Record.dead_band`` is its tactile array's)."""
    from types import SimpleNamespace
    return replace(record, sensor=SimpleNamespace(tactile=SimpleNamespace(dead_band=band, noise=0.0, cell_area=1.0)))

def tiny_record(truth=TRUTH, force_std=0.0, marker_std=0.0, seed=0, forward=None, tactile_delay=0.0, marker_dt=0.5):
    """A 3 x 3 plane block's record made by ``forward`` (default: the marker grid's own
    quasi-static model, the one the fit uses), with white noise."""
    mesh = forward.mesh if forward is not None else Mesh.build("plane_fe", 0.08, 0.08, 0.0125, rows=3, cols=3)
    forward = forward or QuasiStaticFE(mesh)
    p = PROFILE
    ft, mt, st = np.arange(0.0, p.t_end, 0.1), np.arange(0.05, p.t_end, marker_dt), np.arange(0.0, p.t_end, 0.05)
    pred = forward.predict(Model(three_element(truth["E"], truth["c1"], truth["c2"])), truth["gamma"], p, ft, mt)
    rng = np.random.default_rng(seed)
    return Record(mesh=mesh, stage_t=st, stage_depth=p.depth_at(st), force_t=ft + tactile_delay,
                  force=pred.force + rng.normal(0, 1, pred.force.shape) * force_std, marker_t=mt,
                  markers=mesh.nodes[None] + pred.displacement + rng.normal(0, 1, pred.displacement.shape) * marker_std,
                  source="tiny", stage_profile=p)


def start(scale=1.05):
    return Estimate({k: v * scale for k, v in TRUTH.items()}, "start", ())


WEIGHTS = Weights(np.full(3, FORCE_STD), MARKER_STD)


@pytest.fixture
def rec():
    return tiny_record(force_std=FORCE_STD, marker_std=MARKER_STD)


@pytest.fixture
def fit_w(rec):
    return fit_record(rec, start(), weights=WEIGHTS, discretisation=False)


@pytest.fixture
def fit_d(rec):
    return fit_record(rec, start(), weights=WEIGHTS)          # discretisation on by default


def problem(record, delays=True, **kw):
    return WholeRecordProblem(record, MODEL, np.full(3, FORCE_STD), MARKER_STD, delays=delays, **kw)


def fd_std(prob, params):
    """Cramer-Rao std from an independent central-difference Jacobian (relative steps;
    the offsets in steps of 1 ms about 0)."""
    names = prob.names
    p0 = np.array([params.get(n, 0.0) for n in names])
    steps = np.array([1e-3 if n in F.DELAYS else 1e-5 * abs(v) for n, v in zip(names, p0)])
    cols = []
    for i, h in enumerate(steps):
        up, down = p0.copy(), p0.copy()
        up[i] += h
        down[i] -= h
        cols.append((prob.residuals(dict(zip(names, up))) - prob.residuals(dict(zip(names, down)))) / (2 * h))
    J = np.column_stack(cols)
    return dict(zip(names, np.sqrt(np.diag(np.linalg.inv(J.T @ J)))))


# ---------------------------------------------------------------- the bound and the fit's std

def test_cramer_rao_std_is_the_inverse_fisher_information(rec):
    prob = problem(rec)
    crb = cramer_rao_std(prob, TRUTH)                       # offsets not given: at 0
    ref = fd_std(prob, TRUTH)
    assert set(crb) == set(NAMES) | set(F.DELAYS)
    for n in crb:
        assert crb[n] == pytest.approx(ref[n], rel=1e-5), n
    # Sizes that would move were a factor lost: E to ~0.04 %; the tactile offset (slow
    # forces) to 5 ms, inside its 10 ms prior; the markers' to 0.13 ms.
    assert 1e-4 < crb["E"] / TRUTH["E"] < 1e-3
    assert 1e-3 < crb["tactile_delay"] < 0.01 and 1e-5 < crb["marker_delay"] < 1e-3
    # Offsets given: the bound is taken there (half a second moves every force sample
    # across the phases: E's bound 6 % tighter).
    at = {**TRUTH, "tactile_delay": 0.5, "marker_delay": -0.3}
    shifted, ref = cramer_rao_std(prob, at), fd_std(prob, at)
    for n in ("E", "c1", "c2", "gamma", "marker_delay"):
        assert shifted[n] == pytest.approx(ref[n], rel=1e-4), n
    assert shifted["E"] == pytest.approx(0.944 * crb["E"], rel=0.01)
    # A parameter missing is an error, not a zero.
    with pytest.raises(KeyError):
        cramer_rao_std(prob, {"E": 2.0, "c1": 8.0, "gamma": 0.3})
    # Without offsets the problem has four parameters, and the bound no prior.
    plain = cramer_rao_std(problem(rec, delays=False), TRUTH)
    assert set(plain) == set(NAMES)
    assert plain["gamma"] == pytest.approx(fd_std(problem(rec, delays=False), TRUTH)["gamma"], rel=2e-3)


def test_the_fits_std_is_the_bound_scaled_by_the_reduced_chi_square(rec, fit_w):
    st = fit_w.statistics
    crb = cramer_rao_std(problem(rec), {**fit_w.params, "tactile_delay": st.delay("tactile"),
                                        "marker_delay": st.delay("marker")})
    scale = np.sqrt(st.reduced_chi2)
    assert 0.9 < scale < 1.1                                 # weighted by the true noise
    for n in NAMES:
        assert fit_w.std[n] == pytest.approx(crb[n] * scale, rel=0.01), n
        assert abs(fit_w.params[n] - TRUTH[n]) < 4 * fit_w.std[n]
    for stream in ("tactile", "marker"):
        offset, std = st.clock_offsets[stream]
        assert std == pytest.approx(crb[f"{stream}_delay"] * scale, rel=0.01)
        assert abs(offset) < 4 * std


# ---------------------------------------------------------------- the statistics

def test_fit_statistics_count_and_weigh_the_readings(rec, fit_w):
    st = fit_w.statistics
    edges = np.array([PROFILE.t_pull_start, PROFILE.t_pull_end, PROFILE.t_keep_end])
    away = int(np.sum(np.abs(rec.force_t[:, None] - edges).min(axis=1) >= 0.05))
    assert away == rec.force_t.size - 3                       # the samples at each boundary
    assert st.signals == ("P1", "P2", "P3", "markers")
    assert st.samples == {"P1": away, "P2": away, "P3": away, "markers": rec.markers.size}
    assert st.readings == 3 * away + rec.markers.size
    assert st.free_parameters == 6 and st.passes == 1
    assert st.dof == st.readings + 2 - 6                      # the offsets' priors are two readings more
    assert st.weights == {"P1": FORCE_STD, "P2": FORCE_STD, "P3": FORCE_STD, "markers": MARKER_STD}
    np.testing.assert_array_equal(st.force_weights, np.full(3, FORCE_STD))
    # A chi-square at the true noise: its mean dof, its std sqrt(2 dof).
    assert abs(st.cost - st.dof) < 4 * np.sqrt(2 * st.dof)
    assert st.cost == pytest.approx(float(np.sum(problem(rec).residuals(
        {**fit_w.params, "tactile_delay": st.delay("tactile"), "marker_delay": st.delay("marker")}) ** 2)), rel=1e-9)
    # -2 log-likelihood: 2 ln(sigma) per reading on top of the chi-square.
    assert st.deviance - st.cost == pytest.approx(2 * (3 * away * np.log(FORCE_STD)
                                                       + rec.markers.size * np.log(MARKER_STD)), rel=1e-12)
    # What the data show: the noise put in, by signal.
    for s in ("P1", "P2", "P3"):
        assert st.noise[s] == pytest.approx(FORCE_STD, rel=0.1)
        assert st.residual_rms[s] == pytest.approx(FORCE_STD, rel=0.1)
        assert st.fit_to_noise[s] == pytest.approx(st.residual_rms[s] / st.noise[s], rel=1e-6)
    assert st.noise["markers"] == pytest.approx(MARKER_STD, rel=0.3)   # second differences: 1.2e-6
    assert st.residual_rms["markers"] == pytest.approx(MARKER_STD, rel=0.05)
    assert st.misfits() == {}
    # Without the discretisation: no systematic std, the floor only the readings' float32 half-ulp.
    assert st.discretisation == {n: 0.0 for n in NAMES}
    for i, s in enumerate(("P1", "P2", "P3")):
        assert st.floor[s] == pytest.approx(np.sqrt(np.mean(rec.force[:, i] ** 2)) * 2.0**-24, rel=1e-6, abs=0)
    assert st.floor["markers"] == 0.0


def test_fit_record_result_fields(fit_w):
    assert fit_w.method == "whole_record"
    assert fit_w.equations == ("eq.1/18-21 FE model, quasi-static limit", "weighted least squares over all phases")
    assert list(fit_w.params) == list(NAMES) and fit_w.covariance.shape == (4, 4)
    assert np.all(np.isfinite(fit_w.covariance))
    corr = fit_w.covariance / np.outer(np.sqrt(np.diag(fit_w.covariance)), np.sqrt(np.diag(fit_w.covariance)))
    np.testing.assert_allclose(corr, corr.T, atol=1e-12)
    assert np.all(np.abs(corr[np.triu_indices(4, 1)]) < 1.0)
    assert fit_w.message == f"1 pass(es); {fit_w.statistics.message}"
    assert fit_w.statistics.message            # the solver's


def test_a_held_parameter_is_exact_and_the_rest_refit(rec, fit_w):
    held = fit_record(rec, start(), weights=WEIGHTS, fixed={"c1": 8.4}, discretisation=False)
    assert held.params["c1"] == 8.4 and held.std["c1"] == 0.0
    assert held.covariance[1].tolist() == [0.0] * 4
    assert held.statistics.free_parameters == 5 and held.statistics.dof == fit_w.statistics.dof + 1
    # c1 5 % off its optimum: the fit is worse by many std.
    assert held.statistics.cost - fit_w.statistics.cost > 100


# ---------------------------------------------------------------- discretisation

def test_the_discretisation_std_is_the_parameters_move_to_the_continuum(rec, fit_w, fit_d):
    """The parameters' shifts to the meshes 2 and 4 times as fine, each one Gauss-Newton
    step (here with an independent central-difference Jacobian), and the tail beyond at
    0.37 per halving; against full refits on those meshes for gamma (the step is linear,
    the refits are not: 15 % apart)."""
    st = fit_w.statistics
    at = {**fit_w.params, "tactile_delay": st.delay("tactile"), "marker_delay": st.delay("marker")}
    fe = QuasiStaticFE(rec.mesh)
    r = [problem(rec, forward=f).residuals(at) for f in (fe, fe.finer(), fe.finer().finer())]
    names = problem(rec).names
    p0 = np.array([at[n] for n in names])
    steps = np.array([1e-3 if n in F.DELAYS else 1e-5 * abs(v) for n, v in zip(names, p0)])
    J = np.column_stack([(problem(rec).residuals(dict(zip(names, p0 + h * e)))
                          - problem(rec).residuals(dict(zip(names, p0 - h * e)))) / (2 * h)
                         for h, e in zip(steps, np.eye(len(names)))])
    d1, d2 = (-np.linalg.lstsq(J, b - a, rcond=None)[0] for a, b in ((r[0], r[1]), (r[1], r[2])))
    sys = fit_d.statistics.discretisation
    assert set(sys) == set(NAMES)
    for i, n in enumerate(NAMES):
        assert sys[n] == pytest.approx(abs(d1[i] + d2[i] / (1 - 0.37)), rel=0.02), n
    refit = [fit_record(rec, fit_w, weights=WEIGHTS, discretisation=False, forward=f).params["gamma"]
             for f in (fe.finer(), fe.finer().finer())]
    assert sys["gamma"] == pytest.approx(abs(refit[0] - fit_w.params["gamma"]) + abs(refit[1] - refit[0]) / 0.63,
                                         rel=0.2)
    for n in NAMES:
        # It joins the statistical std in quadrature.
        assert fit_d.std[n] ** 2 == pytest.approx(fit_w.std[n] ** 2 + sys[n] ** 2, rel=1e-6)
    # On this 2 x 2-element mesh the mesh dominates: gamma's std grows ~700 x.
    assert sys["gamma"] > 100 * fit_w.std["gamma"]
    assert {k: v for k, v in fit_d.params.items()} == pytest.approx(fit_w.params, rel=1e-9)


def continuum(rec):
    """Noise-free data from the continuum: the 4x-finer mesh's, extrapolated at 0.37 per halving."""
    fe = QuasiStaticFE(rec.mesh)
    dt = rec.marker_t[1] - rec.marker_t[0]
    r2, r4 = (tiny_record(forward=f, marker_dt=dt) for f in (fe.finer(), fe.finer().finer()))
    return replace(r4, force=r4.force + (r4.force - r2.force) * 0.37 / 0.63,
                   markers=r4.markers + (r4.markers - r2.markers) * 0.37 / 0.63, sensor=rec.sensor)


def test_the_floor_is_the_misfit_a_fit_leaves_on_continuum_data(rec, fit_d):
    """The floor (the predictions' move to the continuum no parameter takes up) against
    the misfit a fit on this mesh leaves on noise-free data from the continuum (the
    4x-finer mesh extrapolated at 0.37 per halving)."""
    misfit = fit_record(continuum(rec), start(), weights=WEIGHTS, discretisation=False).statistics.residual_rms
    floor = fit_d.statistics.floor
    force_misfit = np.sqrt(np.mean([misfit[s] ** 2 for s in ("P1", "P2", "P3")]))
    assert floor["P1"] == pytest.approx(floor["P2"], rel=1e-6) == floor["P3"]   # one level for every segment
    assert floor["P1"] == pytest.approx(force_misfit, rel=0.1)
    assert floor["markers"] == pytest.approx(misfit["markers"], rel=0.1)
    assert floor["P1"] > FORCE_STD                            # this mesh's floor is above the noise
    # Judged against noise and floor together.
    st = fit_d.statistics
    for s in st.signals:
        assert st.fit_to_noise[s] == pytest.approx(st.residual_rms[s] / np.hypot(st.noise[s], floor[s]), rel=1e-9)


# ---------------------------------------------------------------- weights from the residuals

def test_weights_from_the_residuals_settle_on_the_noise(rec, fit_w):
    est = fit_record(rec, start(), discretisation=False)
    st = est.statistics
    assert st.passes == 2                   # a loose first solve sets the weights, one more settles them
    for s in ("P1", "P2", "P3"):
        assert st.weights[s] == pytest.approx(FORCE_STD, rel=0.05)
    assert st.weights["markers"] == pytest.approx(MARKER_STD, rel=0.05)
    # The last weights are the residuals' RMS of the fit they weighted (settled to 2 %).
    for s in st.signals:
        assert st.weights[s] == pytest.approx(st.residual_rms[s], rel=0.02)
    assert st.reduced_chi2 == pytest.approx(1.0, rel=0.03)
    for n in NAMES:
        assert est.std[n] == pytest.approx(fit_w.std[n], rel=0.05)
        assert est.params[n] == pytest.approx(fit_w.params[n], abs=0.2 * fit_w.std[n])
    assert est.message.startswith("2 pass(es); ")


def test_noise_free_weights_stop_at_their_floor():
    rec = tiny_record()
    est = fit_record(rec, start(), discretisation=False)
    st = est.statistics
    # Residuals at round-off: the weights at 1e-9 of the force scale (1 % of each segment's
    # peak force) and 1e-12 m; settled on the second pass.
    peak = np.abs(rec.force).max(axis=0)
    for i, s in enumerate(("P1", "P2", "P3")):
        assert st.weights[s] == pytest.approx(1e-9 * (1e-2 * peak[i] + 1e-12), rel=1e-9, abs=0)
    assert st.weights["markers"] == 1e-12
    assert st.passes == 2
    for n in NAMES:
        assert est.params[n] == pytest.approx(TRUTH[n], rel=1e-6)


def test_a_capped_fit_says_so(rec):
    est = fit_record(rec, start(1.5), weights=WEIGHTS, discretisation=False, max_iterations=2)
    assert "maximum number of function evaluations" in est.statistics.message
    assert "maximum number" not in fit_record(rec, start(1.5), weights=WEIGHTS, discretisation=False).message


# ---------------------------------------------------------------- clock offsets

def test_a_late_tactile_stream_is_fitted_and_named():
    rec = tiny_record(force_std=FORCE_STD, marker_std=MARKER_STD, tactile_delay=0.03)
    est = fit_record(rec, start(), weights=WEIGHTS, discretisation=False)
    offset, std = est.statistics.clock_offsets["tactile"]
    assert offset == pytest.approx(0.03, abs=3 * std) and 1e-3 < std < 1e-2
    assert est.statistics.delay("tactile") == offset
    assert f"; the tactile stamps are {1e3 * offset:+.3g} +- {1e3 * std:.2g} ms off the stage's (fitted)" in est.message
    assert "marker stamps" not in est.message
    for n in NAMES:
        assert abs(est.params[n] - TRUTH[n]) < 4 * est.std[n]


def test_an_offset_at_its_limit_is_not_bounded():
    rec = tiny_record(force_std=FORCE_STD, marker_std=MARKER_STD, tactile_delay=0.06)
    est = fit_record(rec, start(), weights=WEIGHTS)                # the mesh's error left out where loose
    offset, std = est.statistics.clock_offsets["tactile"]
    assert abs(offset) >= 0.95 * F.DELAY_LIMIT and std == np.inf
    assert "; not bounded by the data: tactile_delay" in est.message
    assert "tactile stamps" not in est.message
    assert np.all(np.isfinite(est.covariance))                # the physical parameters stay bounded
    assert set(est.statistics.discretisation) == set(NAMES) and est.statistics.discretisation["gamma"] > 0.01


# ---------------------------------------------------------------- the residuals

def test_residuals_are_the_weighted_misfit_with_each_marker_start_profiled_out():
    rec = tiny_record()
    prob = problem(rec, delays=False)
    np.testing.assert_allclose(prob.residuals(TRUTH), 0.0, atol=1e-6)
    n_force = 3 * (rec.force_t.size - 3)
    assert prob.residuals(TRUTH).size == n_force + rec.markers.size
    assert prob.samples == n_force + rec.markers.size and prob.marker_count == rec.markers.size
    np.testing.assert_array_equal(prob.live_counts, [rec.force_t.size - 3] * 3)
    # One reading 3 std high: one residual of -3; a marker moved as a whole: nothing.
    i = int(np.searchsorted(rec.force_t, 10.0))
    force = rec.force.copy()
    force[i, 1] += 3 * FORCE_STD
    markers = rec.markers + np.array([2e-4, -1e-4])
    r = problem(replace(rec, force=force, markers=markers), delays=False).residuals(TRUTH)
    away = prob._use.nonzero()[0]
    k = int(np.searchsorted(away, i)) * 3 + 1
    assert r[k] == pytest.approx(-3.0, rel=1e-6)
    assert np.abs(np.delete(r, k)).max() < 1e-6
    # The offsets' priors: offset / 10 ms, last.
    full = problem(rec).residuals({**TRUTH, "tactile_delay": 0.0, "marker_delay": 0.004})
    assert full.size == n_force + rec.markers.size + 2
    assert full[-2:].tolist() == pytest.approx([0.0, 0.4])


def test_a_marker_delay_shifts_the_marker_times():
    rec = tiny_record()
    late = replace(rec, marker_t=rec.marker_t + 0.3)
    prob = problem(late)
    r = prob.residuals({**TRUTH, "tactile_delay": 0.0, "marker_delay": 0.3})
    np.testing.assert_allclose(r[:-2], 0.0, atol=1e-6)
    assert np.abs(prob.residuals({**TRUTH, "tactile_delay": 0.0, "marker_delay": 0.0})).max() > 10
    # The tactile delay shifts the force times the same way.
    early = replace(rec, force_t=rec.force_t - 0.02)
    r = problem(early).residuals({**TRUTH, "tactile_delay": -0.02, "marker_delay": 0.0})
    np.testing.assert_allclose(r[:-2], 0.0, atol=1e-6)


def test_group_rms_per_segment_and_of_the_profiled_markers():
    rec = tiny_record()
    n = rec.marker_t.size
    force = rec.force.copy()
    force[:, 0] += 2e-6
    force[:, 2] -= np.where(np.arange(force.shape[0]) % 2, 1e-6, -1e-6)
    wobble = np.where(np.arange(n) % 2, 3e-6, -3e-6)[:, None, None] * np.ones(rec.markers.shape[1:])
    prob = problem(replace(rec, force=force, markers=rec.markers + wobble + 5e-4))
    rf, rm = prob.group_rms(TRUTH)
    np.testing.assert_allclose(rf, [2e-6, 0.0, 1e-6], rtol=1e-5, atol=1e-12)
    # The markers' RMS about their mean: unbiased for the mean profiled out (n / (n - 1)).
    assert rm == pytest.approx(3e-6 * np.sqrt(n / (n - 1)), rel=1e-5)


def test_readings_not_live_are_left_out_or_bound_the_model_from_above():
    rec = tiny_record()
    live = np.ones(rec.force.shape, bool)
    live[:, 1] = False
    live[rec.force_t > 30.0, 0] = False
    prob = problem(rec, delays=False, live=live)
    rf, _ = prob.group_rms(TRUTH)
    assert np.isnan(rf[1]) and rf[0] == pytest.approx(0.0, abs=1e-12)
    keep = prob.live_counts
    assert keep[1] == 0 and keep[2] == rec.force_t.size - 3
    assert keep[0] == int(np.sum(prob._use & (rec.force_t <= 30.0)))
    assert prob.residuals(TRUTH).size == keep.sum() + rec.markers.size
    # Censored: a reading that is not live stands for a force below the ceiling.
    ceiling = np.full(3, 0.5 * np.abs(rec.force).max())
    censored = problem(rec, delays=False, live=live, ceiling=ceiling)
    extra = censored.residuals(TRUTH)[keep.sum() + rec.markers.size:]
    pred = censored.predict(TRUTH).force
    expected = (np.maximum(pred - ceiling, 0.0) / FORCE_STD)[~censored.live_mask]
    assert extra.size == (~censored.live_mask).sum()
    np.testing.assert_allclose(extra, expected, rtol=1e-9)
    assert extra.max() > 50                          # P2's peak is twice the ceiling
    assert censored.samples == prob.samples          # bounds add no count


def test_predict_reads_the_model_and_gamma():
    rec = tiny_record()
    prob = problem(rec, delays=False)
    other = {"E": 4.0, "c1": 16.0, "c2": 80.0, "gamma": 0.3}
    # Twice the moduli: twice the force, the same displacements.
    np.testing.assert_allclose(prob.predict(other).force, 2 * prob.predict(TRUTH).force, rtol=1e-9)
    np.testing.assert_allclose(prob.predict(other).displacement, prob.predict(TRUTH).displacement, atol=1e-15)
    lateral = prob.predict({**TRUTH, "gamma": 0.1}).displacement - prob.predict(TRUTH).displacement
    assert np.abs(lateral).max() > 1e-4
    np.testing.assert_allclose(prob.predict(TRUTH).force, rec.force[prob._use], rtol=1e-9, atol=1e-15)


def test_the_guard_leaves_out_the_samples_near_a_boundary():
    rec = tiny_record()
    wide = problem(rec, delays=False, guard=0.25)
    assert wide.live_counts[0] == rec.force_t.size - 3 * 5   # 0.25 s each side at 10 Hz: 5 per boundary


# ---------------------------------------------------------------- the map and the message

def test_parameter_map_edges_and_clips():
    pm = ParameterMap(("E", "gamma", "offset", "tactile_delay", "marker_delay"),
                      {"E": 2.0, "gamma": 0.3, "offset": 0.0, "tactile_delay": 0.0, "marker_delay": -0.01},
                      frozenset({"offset"}))
    x0 = pm.start()
    assert x0.tolist() == pytest.approx([0.0, np.log(1.3 / 0.2), 0.0, 0.0, -1.0])
    # A signed parameter starting at 0 moves in absolute units; it is never clipped.
    x = np.array([-50.0, -50.0, 50.0, 0.0, 0.0])
    v = pm.values(x)
    assert v[0] == pytest.approx(2.0 * np.exp(-30.0), abs=0) and v[1] == pytest.approx(GAMMA_RANGE[0], abs=1e-12)
    assert v[2] == 50.0
    s = pm.slope(x)
    assert s[0] == pytest.approx(2.0 * np.exp(-30.0), abs=0)
    assert s[1] == pytest.approx(1.5 * np.exp(-30.0) * (1 - np.exp(-30.0)), rel=1e-9, abs=0)
    assert pm.slope(-x)[1] == pytest.approx(1.5 * np.exp(-30.0), rel=1e-2, abs=0)     # the upper end alike (1 - sig rounds)
    assert s[2] == 1.0 and s[3] == 0.01 and s[4] == 0.01
    assert pm.at_edge(x).tolist() == [True, True, False, False, False]
    # Offsets: clipped at their limit (the residuals stop moving there), their edge at 0.95
    # of it, beside it not.
    assert pm.values(np.array([0.0, 0.0, 0.0, 10.0, -4.1]))[3:].tolist() == [F.DELAY_LIMIT, -F.DELAY_LIMIT]
    assert pm.values(np.array([0.0, 0.0, 0.0, 3.9, -3.9]))[3:].tolist() == pytest.approx([0.039, -0.039])
    assert pm.at_edge(np.array([0.0, 0.0, 0.0, 3.8, -3.8])).tolist() == [False, False, False, True, True]
    edge = 0.99 * F.SEARCH_LIMIT
    assert pm.at_edge(np.array([edge, -edge, 0.0, 0.0, 0.0])).tolist() == [True, True, False, False, False]
    assert pm.at_edge(np.array([29.69, -29.69, 1e6, 3.79, 0.0])).tolist() == [False, False, False, False, False]
    # Gamma near its bounds starts inside the open range.
    g = ParameterMap(("gamma",), {"gamma": 0.5}, frozenset())
    assert g.start()[0] == pytest.approx(np.log((1 - 1e-6) / 1e-6), rel=1e-9)
    assert ParameterMap(("gamma",), {"gamma": -1.0}, frozenset()).start()[0] == pytest.approx(
        -np.log((1 - 1e-6) / 1e-6), rel=1e-9)
    # A signed start sets the unit; a positive start is scale-free.
    signed = ParameterMap(("offset", "E"), {"offset": -4.0, "E": 3.0}, frozenset({"offset"}))
    assert signed.values(np.array([0.5, 1.0])).tolist() == pytest.approx([-2.0, 3.0 * np.e])
    assert signed.slope(np.array([0.5, 1.0])).tolist() == pytest.approx([4.0, 3.0 * np.e])


def stats(**kw):
    base = {"signals": ("P1", "P2", "markers"), "noise": {"P1": 0.1, "P2": 0.2, "markers": 1e-5},
            "floor": {"P1": 0.0, "P2": 0.0, "markers": 0.0}, "weights": {"P1": 0.1, "P2": 0.3, "markers": 1e-5},
            "residual_rms": {}, "fit_to_noise": {"P1": 1.0, "P2": 1.3, "markers": np.nan},
            "samples": {"P1": 100, "P2": 10_000, "markers": 50}, "clock_offsets": {}, "discretisation": {},
            "cost": 300.0, "deviance": 0.0, "dof": 150, "free_parameters": 6, "passes": 2, "message": "done"}
    return FitStatistics(**{**base, **kw})


def test_message_names_the_loose_the_misfits_and_the_clocks():
    assert F._message(stats(fit_to_noise={"P1": 1.0}), []) == "2 pass(es); done"
    assert F._message(stats(fit_to_noise={}), ["c2", "tactile_delay"]) == (
        "2 pass(es); done; not bounded by the data: c2, tactile_delay")
    msg = F._message(stats(fit_to_noise={"P1": 1.7, "P2": 2.5, "markers": np.nan}), [])
    assert msg == ("2 pass(es); done; WARNING: the model misfits: its residuals are 2.5 x the sensor noise on P2, "
                   "1.7 x the sensor noise on P1 (expected 1): an effect the model lacks or a wrong set-up "
                   "(boundary, geometry); the std assume white residuals and understate the error")
    clocks = {"tactile": (0.0021, 0.0005), "marker": (-0.0031, 0.001)}
    assert F._message(stats(fit_to_noise={}, clock_offsets=clocks), []) == (
        "2 pass(es); done; the tactile stamps are +2.1 +- 0.5 ms off the stage's (fitted)"
        "; the marker stamps are -3.1 +- 1 ms off the stage's (fitted)")
    # Within 3 std, under 1 ms, or not bounded: not named.
    for offset, std in ((0.0029, 0.001), (0.003, 0.001), (0.00095, 1e-6), (0.001, 1e-6), (0.03, np.inf)):
        assert F._message(stats(fit_to_noise={}, clock_offsets={"tactile": (offset, std)}), []) == "2 pass(es); done"
    assert "-1.2 +- 0.001 ms" in F._message(stats(fit_to_noise={}, clock_offsets={"marker": (-0.0012, 1e-6)}), [])
    assert "+50 +- 9.9 ms" in F._message(stats(fit_to_noise={}, clock_offsets={"marker": (0.05, 0.009945)}), [])
    # Every note kept: the loose, the misfits, the clocks, in that order.
    both = F._message(stats(fit_to_noise={"P2": 2.0}, clock_offsets={"tactile": (0.01, 0.001)}), ["c2"])
    assert both.startswith("2 pass(es); done; not bounded by the data: c2; WARNING: the model misfits: its residuals "
                           "are 2 x the sensor noise on P2 (expected 1)")
    assert both.endswith("; the tactile stamps are +10 +- 1 ms off the stage's (fitted)")


def test_statistics_figures_and_limits():
    s = stats(clock_offsets={"tactile": (0.002, 0.001)})
    assert s.delay("tactile") == 0.002 and s.delay("marker") == 0.0
    assert stats(fit_to_noise={"P1": 1.66, "P2": 1.25, "markers": 3.0}).misfits() == {"P1": 1.66, "markers": 3.0}
    assert stats(fit_to_noise={"P1": 1.65, "P2": 1.2501}).misfits() == {"P2": 1.2501}
    assert F.misfit_limit(100) == pytest.approx(1.65)
    assert F.misfit_limit(1) == pytest.approx(7.5) and F.misfit_limit(-5) == pytest.approx(7.5)
    assert F.misfit_limit(2) == pytest.approx(1.0 + 6.5 / np.sqrt(2))
    assert F.misfit_limit(676) == pytest.approx(1.25)       # 1 + 6.5 / 26
    assert F.misfit_limit(600) == pytest.approx(1.0 + 6.5 / np.sqrt(600))


def test_live_ceiling_is_the_dead_bands_threshold(rec):
    from rheo_ros.sensors import DeadBand

    assert F.live_ceiling(rec, np.full(3, 0.1)) is None
    band = DeadBand(force=np.array([1.0, 2.0, 3.0]), cells=np.array([4, 4, 4]))
    banded = with_band(rec, band)
    std = np.array([0.1, np.nan, 0.3])
    np.testing.assert_allclose(F.live_ceiling(banded, std), band.threshold(np.array([0.1, 0.0, 0.3])))
    assert np.all(np.isfinite(F.live_ceiling(banded, std)))


# ---------------------------------------------------------------- the solves

def _jacobian(f, params: dict, names: tuple[str, ...]) -> np.ndarray:
    """Central differences of ``f`` over ``names`` at ``params``, a relative step of 1e-6."""
    cols = []
    for n in names:
        h = 1e-6 * max(abs(params[n]), 1e-3)
        up, down = dict(params), dict(params)
        up[n], down[n] = params[n] + h, params[n] - h
        cols.append((f(up) - f(down)) / (2 * h))
    return np.array(cols).T


@pytest.mark.parametrize("grid", [3, 5])
def test_the_solver_works_on_the_markers_in_the_span_of_the_shapes(grid, monkeypatch):
    """The markers' shapes over every Poisson ratio span 2 of 18 coordinates (3 x 3) and 8
    of 50 (5 x 5), within 1e-12; the solver's residuals turn the markers into that span:
    the same sum of squares (1e-12 relative) on fewer rows, and their Jacobian turned
    back is every reading's (central differences of both; 1e-6 of the largest entry). The
    force readings unbinned here (``REDUCE_ABOVE``): only the markers' rows are compared."""
    monkeypatch.setattr(F, "REDUCE_ABOVE", 10**12)
    mesh = Mesh.build("plane_fe", 0.08, 0.08, 0.0125, rows=grid, cols=grid)
    forward = QuasiStaticFE(mesh)
    span = forward.marker_span
    assert span.shape == (2 * grid * grid, {3: 2, 5: 8}[grid])
    np.testing.assert_allclose(span.T @ span, np.eye(span.shape[1]), atol=1e-12)
    for gamma in (-0.99, 0.0, 0.3, 0.499):
        shape = forward.shape(gamma).displacement.ravel()
        assert np.linalg.norm(shape - span @ (span.T @ shape)) < 1e-12 * np.linalg.norm(shape)
    rec = tiny_record(force_std=FORCE_STD, marker_std=MARKER_STD, forward=forward)
    problem = WholeRecordProblem(rec, MODEL, np.full(grid, FORCE_STD), MARKER_STD, forward=forward, delays=True)
    params = {**{k: 1.05 * v for k, v in TRUTH.items()}, "tactile_delay": 0.01, "marker_delay": -0.02}
    full, reduced = problem.residuals(params), problem.solver_residuals(params)
    frames = rec.markers.shape[0]
    assert full.size - reduced.size == frames * (2 * grid * grid - span.shape[1]) - 1
    assert reduced @ reduced == pytest.approx(full @ full, rel=1e-12)
    names = tuple(params)
    jac = _jacobian(problem.residuals, params, names)
    turned = problem.from_solver(_jacobian(problem.solver_residuals, params, names))
    assert np.abs(turned - jac).max() < 1e-6 * np.abs(jac).max()
    # A residual vector turned into the solver's rows is the solver's (1e-12 of the largest row).
    np.testing.assert_allclose(np.abs(problem.to_solver(full)), np.abs(reduced), rtol=0,
                               atol=1e-12 * np.abs(reduced).max())


@dataclass(frozen=True)
class CameraCreep(Effect):
    """A camera creeping at ``rate`` (m/s): an effect on the markers alone."""

    id: ClassVar[str] = "camera_creep"
    rate: float = 1e-6

    def measured_markers(self, t, displacement):
        return displacement + self.rate * t[:, None, None]


def test_a_model_whose_effect_moves_the_markers_is_solved_on_every_reading(rec, monkeypatch):
    monkeypatch.setattr(F, "REDUCE_ABOVE", 10**12)   # the force readings unbinned: the markers alone compared
    model = Model(three_element(1.0, 1.0, 1.0), (CameraCreep(),))
    assert model.moves_markers and not MODEL.moves_markers
    problem = WholeRecordProblem(rec, model, np.full(3, FORCE_STD), MARKER_STD)
    params = {**TRUTH, "camera_creep.rate": 1e-6}
    np.testing.assert_array_equal(problem.solver_residuals(params), problem.residuals(params))


def test_markers_still_to_their_rounding_show_no_noise_and_the_fit_weighs_by_its_residuals():
    """Noise-free positions whose second differences show 3e-17 m (table_I_short's: the
    rounding of float64 coordinates near a metre), not a camera's noise: 0, so the fit
    takes its weights from its residuals (``fit_weights`` None), as on any noise-free record."""
    from rheo_ros.identification.noise import sensor_noise
    from rheo_ros.identification.pipeline import fit_weights
    from rheo_ros.sensors import difference_noise

    rec = tiny_record(marker_std=3e-17)
    assert 1e-17 < difference_noise(rec.markers)[0] < 1e-16
    noise = sensor_noise(rec)
    assert noise.marker_std == 0.0 and fit_weights(noise) is None

def test_the_offsets_join_the_solve_last(rec, monkeypatch):
    calls = []
    real = F._least_squares

    def spy(fun, x0, tol, max_iterations):
        calls.append((len(x0), tol, max_iterations))
        return real(fun, x0, tol, max_iterations)

    monkeypatch.setattr(F, "_least_squares", spy)
    fit_record(rec, start(), weights=WEIGHTS, discretisation=False, max_iterations=7)
    # The solve without the offsets only brings them near (NEAR_TOLERANCE).
    assert calls == [(4, F.NEAR_TOLERANCE, 7), (6, F.SOLVER_TOLERANCE, 7)]
    calls.clear()
    est = fit_record(rec, start(), discretisation=False)
    # A loose first solve (it only sets the weights), then one weighted solve per pass.
    assert calls[:2] == [(4, F.NEAR_TOLERANCE, None), (6, 1e-6, None)]
    assert calls[2:] == [(6, F.SOLVER_TOLERANCE, None)] * (est.statistics.passes - 1)


def test_least_squares_caps_the_evaluations_at_two_per_iteration():
    def rosenbrock(x):
        return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])

    capped = F._least_squares(rosenbrock, np.array([-1.2, 1.0]), 1e-10, 3)
    assert capped.nfev == 6 and capped.status == 0
    free = F._least_squares(rosenbrock, np.array([-1.2, 1.0]), 1e-10, None)
    assert free.status > 0 and free.x == pytest.approx([1.0, 1.0], abs=1e-12)
    # Levenberg-Marquardt (MINPACK): its Jacobian by differences, not counted in nfev.
    assert free.njev is None


def test_a_capped_reweighted_fit_says_so(rec, monkeypatch):
    est = fit_record(rec, start(1.5), discretisation=False, max_iterations=1)
    assert "maximum number of function evaluations" in est.statistics.message
    assert est.statistics.passes == F.MAX_PASSES               # the weights never settle
    # MAX_PASSES caps the weighted solves: at 1, the loose first solve alone.
    monkeypatch.setattr(F, "MAX_PASSES", 1)
    once = fit_record(rec, start(), discretisation=False)
    assert once.statistics.passes == 1
    assert once.statistics.weights["P1"] == pytest.approx(1e-2 * np.abs(rec.force[:, 0]).max() + 1e-12, rel=1e-9, abs=0)
    assert once.statistics.weights["markers"] == 1e-5


def test_weights_right_from_the_start_still_get_a_weighted_solve():
    """Noise at exactly the first pass's guess (1 % of each segment's peak, 10 um): the
    weights do not move, and the fit still solves once with them."""
    clean = tiny_record()
    rng = np.random.default_rng(4)
    scale = np.abs(clean.force).max(axis=0) * 1e-2
    noise = rng.normal(0, 1, clean.force.shape)
    noise = noise / np.sqrt(np.mean(noise**2, axis=0)) * scale
    mk = rng.normal(0, 1, clean.markers.shape)
    mk -= mk.mean(axis=0)
    mk *= 1e-5 / np.sqrt(np.sum(mk**2) / (mk.size * (mk.shape[0] - 1) / mk.shape[0]))
    est = fit_record(replace(clean, force=clean.force + noise, markers=clean.markers + mk), start(),
                     discretisation=False)
    assert est.statistics.passes == 2
    assert est.statistics.weights["P2"] == pytest.approx(scale[1], rel=0.02)


def test_a_start_lacking_gamma_starts_it_at_0_3(rec, fit_w):
    for params in ({"E": 2.1, "c1": 8.4, "c2": 42.0},):
        est = fit_record(rec, Estimate(params, "start", ()), weights=WEIGHTS, discretisation=False)
        for n in NAMES:
            assert est.params[n] == pytest.approx(fit_w.params[n], abs=0.05 * fit_w.std[n]), (params, n)


def test_noise_free_markers_have_no_fit_to_noise_and_warn_nothing():
    import warnings

    rec = tiny_record(force_std=FORCE_STD)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = fit_record(rec, start(), weights=WEIGHTS, discretisation=False)
    st = est.statistics
    assert st.noise["markers"] == 0.0 and st.floor["markers"] == 0.0
    assert np.isnan(st.fit_to_noise["markers"]) and np.isfinite(st.fit_to_noise["P1"])
    assert all(type(v) is int for v in st.samples.values())
    assert "markers" not in st.misfits()


# ---------------------------------------------------------------- the dead band

def banded(record):
    from rheo_ros.sensors import DeadBand

    peak = np.abs(record.force).max(axis=0)
    # P1 and P3 live above 30 % of their peak; P2 never (its band above any force).
    return with_band(record, DeadBand(force=np.array([0.3, 1e6, 0.3]) * peak, cells=np.ones(3)))


def test_readings_in_the_dead_band_are_left_out_and_a_segment_without_any_weighs_1(rec):
    import warnings

    from rheo_ros.identification.noise import sensor_noise

    dead = banded(rec)
    noise = sensor_noise(dead)
    assert not noise.force_live[:, 1].any() and 0 < noise.force_live[:, 0].sum() < rec.force_t.size
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # a segment with no reading is no 0 / 0
        est = fit_record(dead, start(), discretisation=False)
    st = est.statistics
    edges = np.array([PROFILE.t_pull_start, PROFILE.t_pull_end, PROFILE.t_keep_end])
    away = np.abs(rec.force_t[:, None] - edges).min(axis=1) >= 0.05
    assert st.samples["P1"] == int(np.sum(noise.force_live[:, 0] & away)) and st.samples["P2"] == 0
    assert st.weights["P2"] == 1.0 and np.isnan(st.residual_rms["P2"]) and np.isnan(st.fit_to_noise["P2"])
    assert st.weights["P1"] == pytest.approx(FORCE_STD, rel=0.15)
    for n in NAMES:
        assert abs(est.params[n] - TRUTH[n]) < 4 * est.std[n]


def test_a_model_above_the_dead_band_where_nothing_was_read_pays_for_it(rec):
    from rheo_ros.identification.noise import sensor_noise

    dead = banded(rec)
    noise = sensor_noise(dead)
    strong = {"E": 6.0, "c1": 24.0, "c2": 120.0}            # three times the force
    est = fit_record(dead, start(), weights=WEIGHTS, fixed=strong, discretisation=False)
    st = est.statistics
    params = {**est.params, "tactile_delay": st.delay("tactile"), "marker_delay": st.delay("marker")}
    censored = problem(dead, live=noise.force_live, **F.bounds(dead, noise.force_std))
    uncensored = problem(dead, live=noise.force_live)
    assert st.cost == pytest.approx(float(np.sum(censored.residuals(params) ** 2)), rel=1e-9)
    assert st.cost > float(np.sum(uncensored.residuals(params) ** 2)) + 1e3


def test_a_sample_exactly_one_guard_from_a_boundary_counts():
    t = np.array([0.75, 0.76, 1.25, 1.2])               # the pull starts at 1.0 s
    assert F.away_from_boundaries(t, PROFILE, PROFILE.t_pull_start, 0.25).tolist() == [True, False, True, False]


def test_a_parameter_without_effect_is_not_bounded(rec):
    """Adhesion held at zero: its time constant acts on nothing, so the data leave it
    loose (an infinite std, named), while the rest are fitted as without it."""
    from rheo_ros.models.effects import Adhesion

    model = Model(three_element(1.0, 1.0, 1.0), effects=(Adhesion(0.0, 5.0),))
    est = fit_record(rec, start(), model=model, weights=WEIGHTS, fixed={"adhesion.fraction": 0.0},
                     discretisation=False)
    assert est.std["adhesion.time"] == np.inf and est.params["adhesion.time"] == 5.0
    assert "; not bounded by the data: adhesion.time" in est.message
    plain = fit_record(rec, start(), weights=WEIGHTS, discretisation=False)
    for n in NAMES:
        assert est.std[n] == pytest.approx(plain.std[n], rel=1e-3)


def test_with_no_live_force_reading_the_floor_is_the_readings_resolution(rec):
    """Every reading in the dead band, the moduli held: gamma from the markers alone, and
    the force floor only the float32 half-ulp (no mesh move is measured on no reading)."""
    import warnings

    from rheo_ros.sensors import DeadBand

    dead = with_band(rec, DeadBand(force=np.full(3, 1e6), cells=np.ones(3)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = fit_record(dead, start(), weights=WEIGHTS, fixed={"E": 2.0, "c1": 8.0, "c2": 40.0})
    st = est.statistics
    assert st.samples == {"P1": 0, "P2": 0, "P3": 0, "markers": rec.markers.size}
    for i, s in enumerate(("P1", "P2", "P3")):
        assert st.floor[s] == pytest.approx(np.sqrt(np.mean(rec.force[:, i] ** 2)) * 2.0**-24, rel=1e-6, abs=0)
    assert est.params["gamma"] == pytest.approx(0.3, abs=4 * est.std["gamma"])
    assert st.discretisation["gamma"] > 0.01
    # The markers' floor: the misfit the same fit leaves on continuum data.
    held = {"E": 2.0, "c1": 8.0, "c2": 40.0}
    misfit = fit_record(continuum(dead), start(), weights=WEIGHTS, fixed=held, discretisation=False)
    assert st.floor["markers"] == pytest.approx(misfit.statistics.residual_rms["markers"], rel=0.1)


def test_least_squares_converges_to_its_tolerance():
    """A fit with a residual left (exponential decay in noise): at 1e-10 the solve is
    within 1e-9 of the optimum (scipy's default 1e-8 stops 3e-8 short)."""
    t = np.linspace(0, 4, 30)
    y = 2.0 * np.exp(-1.3 * t) + 0.3 + np.random.default_rng(1).normal(0, 0.05, t.size)

    def decay(x):
        return x[0] * np.exp(-x[1] * t) + x[2] - y

    from scipy.optimize import least_squares

    best = least_squares(decay, [1.0, 1.0, 0.0], method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(F._least_squares(decay, np.array([1.0, 1.0, 0.0]), 1e-10, None).x, best, rtol=1e-9)


def test_the_markers_floor_with_fewer_markers_than_force_readings():
    """Markers every 2 s (378 coordinates against 1221 force readings): the floor still
    takes the markers' part of the move."""
    rec = tiny_record(force_std=FORCE_STD, marker_std=MARKER_STD, marker_dt=2.0)
    assert rec.markers.size < 3 * rec.force_t.size
    floor = fit_record(rec, start(), weights=WEIGHTS).statistics.floor
    misfit = fit_record(continuum(rec), start(), weights=WEIGHTS, discretisation=False).statistics.residual_rms
    assert floor["markers"] == pytest.approx(misfit["markers"], rel=0.1)


def test_a_model_whose_forces_overflow_gets_large_residuals_not_nan_or_zero():
    """A trial law that overflows (inf or NaN forces) must look like the worst fit to the
    solver, live readings and censored ones alike: OVERFLOW_RESIDUAL noise stds."""
    from rheo_ros.identification.fit import OVERFLOW_RESIDUAL
    from rheo_ros.sensors import DeadBand

    rec = with_band(tiny_record(), DeadBand(np.full(3, 1e-7), np.full(3, 1.0)))
    prob = problem(rec, delays=False, live=rec.force > 1e-6, ceiling=np.full(3, 1e-6))
    good = prob.predict(TRUTH)
    for bad in (np.inf, np.nan):
        force = good.force.copy()
        force[5:, :] = bad
        prob.predict = lambda params, f=force: replace(good, force=f)
        r = prob.residuals(TRUTH)
        assert np.all(np.isfinite(r))
        assert np.sum(np.abs(r) == OVERFLOW_RESIDUAL) > 0


def test_reading_bounds_give_each_bounding_readings_excess_by_its_definition():
    """``ReadingBounds.excess`` at the readings that bound the force (a fit's every
    evaluation, those readings alone) is the definition over the whole array: the model
    over the live threshold, plus its window's excess (``ReadingWindows.excess``), and at a
    saturated reading the model under the top instead; on 200 random arrays with a dead
    band, saturation and windows, the same within 1e-12 N."""
    from rheo_ros.sensors import DeadBand

    rng = np.random.default_rng(7)
    for _ in range(200):
        T, nodes = int(rng.integers(5, 400)), int(rng.integers(1, 6))
        band = DeadBand(force=rng.uniform(0.1, 1.0, nodes), cells=np.full(nodes, 4.0), saturation=3.0)
        std = rng.uniform(0.01, 0.2, nodes)
        readings = rng.uniform(0.0, 4.0, (T, nodes)) * (rng.random((T, nodes)) < 0.7)
        bounded = rng.random((T, nodes)) < 0.6
        ceiling, top = band.threshold(std), band.top(std)
        windows = F.ReadingWindows(band, readings, bounded, std)
        force = rng.normal(1.0, 2.0, (T, nodes))
        full = np.maximum(force - ceiling, 0.0) + windows.excess(force)
        full = np.where(readings > top, np.minimum(force - top, 0.0), full)
        at = np.flatnonzero(bounded)
        got = F.ReadingBounds(readings, ceiling, top, windows, at).excess(force)
        np.testing.assert_allclose(got, full[bounded], rtol=0, atol=1e-12)
        assert np.any(got != 0.0) or not at.size


def test_reading_windows_put_each_windows_excess_at_its_readings():
    """``ReadingWindows``: a segment's readings that are not live, 25 at a time in time
    order (a short last window) and 250 at a time, bound the window's mean force; a model
    below the floor has the shortfall at every reading of that window, above the ceiling
    the excess (of a reading's two windows the farther), and a model's pull counts as zero
    force against the floor (tension reads nothing). A small force steady under the band
    (0.05 N where one reading's noise is 0.1 N) is within every short window's margin and
    outside the long windows'."""
    from rheo_ros.sensors import DeadBand

    band = DeadBand(force=np.array([1.0, 1.0]), cells=np.array([4.0, 4.0]))
    readings = np.zeros((500, 2))
    readings[:60, 0] = 2.0                                 # 2 N read under a 1 N dead band ...
    readings[:, 1] = 0.05                                  # ... and a steady 0.05 N
    bounded = np.zeros((500, 2), bool)
    bounded[:60, 0] = True                                 # segment 1: 60 readings, 25 + 25 + 10
    bounded[:, 1] = True                                   # segment 2: 500, 20 short windows, 2 long
    std = np.array([0.1, 0.1])
    w = F.ReadingWindows(band, readings, bounded, std)
    assert (w.floor.size, w.long_floor.size) == (3 + 20, 1 + 2)
    margin_full, margin_short = 3 * 0.1 / 5, 3 * 0.1 / np.sqrt(10)
    excess, deficit = band.excess(std)[0], band.deficit(std)[0]
    assert 0.0 < excess < 1e-3 and 0.0 < deficit < 1.0    # the cells' noise over a band 5 stds up
    np.testing.assert_allclose(w.floor[:3], 2.0 - excess - np.array([margin_full, margin_full, margin_short]))
    np.testing.assert_allclose(w.ceiling[:3], 2.0 + deficit + np.array([margin_full, margin_full, margin_short]))
    # Long: the readings' own spread (none here) floored at a quarter of the noise.
    np.testing.assert_allclose(w.long_floor[0], 2.0 - excess - 3 * 0.025 / np.sqrt(60))
    force = np.zeros((500, 2))
    force[:25, 0] = -5.0                                    # a pull: zero force against the floor
    force[25:50, 0] = 10.0                                  # above the ceiling
    out = w.excess(force)
    np.testing.assert_allclose(out[:25, 0], -w.floor[0])
    np.testing.assert_allclose(out[25:50, 0], 10.0 - w.ceiling[1])
    np.testing.assert_allclose(out[50:60, 0], -w.floor[2])
    assert np.all(out[60:, 0] == 0.0)                       # readings that bound nothing
    assert np.all(w.floor[3:] < 0.0) and np.all(w.long_floor[1:] > 0.0)
    np.testing.assert_allclose(out[:250, 1], -w.long_floor[1])   # a model of none: below the long floor
    force[:, 1] = 0.05
    assert np.all(w.excess(force)[:, 1] == 0.0)             # the force read: within every window


def test_live_bins_are_orthonormal_means_within_each_phase():
    """Each group's row is its readings' sum over the square root of their number: the rows
    are orthonormal, so the sum of squares splits into the groups' rows and the scatter
    about their means (Pythagoras, 1e-12 relative), and ``expand`` of the rows is each
    reading's group mean. No group crosses a phase boundary; a group spans at most
    BIN_GROWTH of the time since its phase began, or BIN_MIN."""
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 400.0, 20_000))
    nodes = 3
    row = np.repeat(np.arange(t.size), nodes)
    node = np.tile(np.arange(nodes), t.size)
    edges = np.array([5.0, 30.0, 160.0])
    bins = F.LiveBins(t, row, node, edges)
    r = rng.normal(size=row.size)
    rows = bins.reduce(r)
    assert 100 < bins.groups < row.size / 20
    assert rows @ rows + np.sum((r - bins.expand(rows)) ** 2) == pytest.approx(r @ r, rel=1e-12)
    means = np.bincount(bins.group, r) / np.bincount(bins.group)
    np.testing.assert_allclose(bins.expand(rows), means[bins.group], rtol=0, atol=1e-12)
    for g in range(bins.groups):
        members = bins.group == g
        times = t[row[members]]
        assert len(set(node[members])) == 1
        phase = np.searchsorted(edges, times, side="right")
        assert phase.min() == phase.max()
        began = np.concatenate([[t.min()], edges])[phase[0]]
        assert times.max() - times.min() <= _bin_bound(times.max() - began)


def _bin_bound(since: float) -> float:
    return max(F.BIN_GROWTH * (since + F.BIN_MIN / F.BIN_GROWTH), F.BIN_MIN) + 1e-9


def test_the_solver_on_bin_means_finds_the_fit_of_every_reading(rec, monkeypatch):
    """Above REDUCE_ABOVE live readings (every record by default) the solver takes the
    bins' means: the parameters within 0.05 of their std of the fit on every reading (bins
    held off), the std within 5 %, the cost (the whole record's, the scatter within the bins
    added back) within 1e-3."""
    monkeypatch.setattr(F, "REDUCE_ABOVE", 10**12)
    full = fit_record(rec, start(), weights=WEIGHTS, discretisation=False)
    monkeypatch.setattr(F, "REDUCE_ABOVE", 0)
    problem = WholeRecordProblem(rec, MODEL, np.full(3, FORCE_STD), MARKER_STD)
    assert problem._bins is not None and problem._bins.groups < problem.live_counts.sum()
    binned = fit_record(rec, start(), weights=WEIGHTS, discretisation=False)
    std = np.sqrt(np.diag(full.covariance))
    for i, n in enumerate(NAMES):
        assert abs(binned.params[n] - full.params[n]) < 0.05 * std[i], n
    np.testing.assert_allclose(np.sqrt(np.diag(binned.covariance)), std, rtol=0.05)
    assert binned.statistics.cost == pytest.approx(full.statistics.cost, rel=1e-3)


@pytest.mark.parametrize("with_bounds", [False, True])
def test_the_bins_rows_from_two_model_times_a_bin_are_every_readings_means(rec, monkeypatch, with_bounds):
    """Binned, the solver asks the model at two times a bin (``BinTimes``: Gauss's rule over
    the bin's times) and at the bounded readings, not at every reading: its rows are those
    of every reading's residuals turned to the solver's rows (``to_solver``) within 1e-3 of
    the noise (a bin's mean's own std is 1), the markers' and bounds' rows within 1e-9 of it;
    on fewer model times than readings."""
    from rheo_ros.identification.noise import sensor_noise

    monkeypatch.setattr(F, "REDUCE_ABOVE", 0)
    record = banded(rec) if with_bounds else rec
    noise = sensor_noise(record)
    kw = dict(live=noise.force_live, **F.bounds(record, noise.force_std)) if with_bounds else {}
    prob = problem(record, **kw)
    params = {**{k: 1.05 * v for k, v in TRUTH.items()}, "tactile_delay": 0.01, "marker_delay": -0.02}
    exact, fast = prob.to_solver(prob.residuals(params)), prob.solver_residuals(params)
    assert fast.shape == exact.shape
    groups = prob._bins.groups
    assert groups < prob.live_counts.sum()
    np.testing.assert_allclose(fast[:groups], exact[:groups], rtol=0, atol=1e-3)
    # The markers' and bounds' rows: the same to rounding (1e-9 of a noise std).
    np.testing.assert_allclose(np.abs(fast[groups:]), np.abs(exact[groups:]), rtol=1e-9, atol=1e-9)
    assert np.abs(fast[:groups] - exact[:groups]).max() > 0.0   # the model's times, not the readings'
    if with_bounds:
        assert prob._bounds is not None and prob._bounds.at.size > 0
    assert prob._bin_times.times.size < prob.live_counts.sum()
