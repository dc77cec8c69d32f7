"""The paper's identification and the whole-record refinement on the FE model's data."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import analytic_block_record

from rheo_ros.bench.cases import TABLE_IV
from rheo_ros.bench.mesh import fine_mesh_record
from rheo_ros.bench.noise import Noise
from rheo_ros.config.setup import Setup, check_params, load_params
from rheo_ros.experiment import StageProfile
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.closed_form import deformation_error, fit_force_curves, from_final_displacement
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.fit import WholeRecordProblem, cramer_rao_std, fit_record
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import RecordError
from rheo_ros.rig.simulator import simulate_clean

PAPER_TOL = 0.01    # % per parameter, noise-free 1D (the paper: 0.0125 % to 0.335 %)
PLANE_TOL = 0.1     # % per parameter, noise-free 2D


def max_abs_error(est, truth):
    return max(abs(e) for e in est.relative_errors(truth).values())


def test_long_time_case_uses_eq_6_7_10_within_001_percent(long_case):
    est = from_final_displacement(long_case.record)
    assert est.method == "paper_long_time"
    assert est.equations == ("eq.6", "eq.7", "eq.10", "gamma from the markers' lateral strain")
    assert max_abs_error(est, long_case.truth) < PAPER_TOL


def test_short_time_case_recovers_c2_from_final_displacements(short_case):
    est = from_final_displacement(short_case.record)
    assert est.method == "paper_short_time"
    assert est.equations == ("eq.6+14", "eq.7", "eq.15-17", "gamma from the markers' lateral strain")
    assert max_abs_error(est, short_case.truth) < PAPER_TOL


def test_long_time_equations_fail_on_short_time_data(short_case):
    # The long-time assumption u_keep = u_final is wrong here: eq. 14 is what fixes it.
    est = from_final_displacement(short_case.record, method="long_time")
    assert max_abs_error(est, short_case.truth) > 10.0


def test_plane_case_recovers_four_parameters_with_poisson_ratio(plane_case):
    est = from_final_displacement(plane_case.record)
    assert set(est.params) == {"E", "c1", "c2", "gamma"}
    assert "IV.B least squares over P1,P2,P3,P4,P5" in est.equations
    assert max_abs_error(est, plane_case.truth) < PLANE_TOL


def test_plane_case_with_the_papers_nodes_p2_p4(plane_case):
    est = from_final_displacement(plane_case.record, nodes=(1, 2, 3))
    assert "IV.B least squares over P2,P3,P4" in est.equations
    assert max_abs_error(est, plane_case.truth) < PLANE_TOL


def test_force_curve_rate_is_E_over_c1_plus_c2(short_case):
    rec = short_case.record
    curves = fit_force_curves(rec.force_t, rec.force, rec.profile())
    assert curves.rate == pytest.approx(2.0 / 48.0, rel=1e-8)


def test_whole_record_refinement_is_exact_on_clean_data(plane_case):
    closed = from_final_displacement(plane_case.record)
    est = fit_record(plane_case.record, closed)
    assert est.method == "whole_record"
    assert max_abs_error(est, plane_case.truth) < 1e-3
    assert set(est.std) == {"E", "c1", "c2", "gamma"}


def test_refinement_std_is_within_the_cramer_rao_bound(plane_case):
    """30 noisy replicates: the refinement's spread is at the bound (efficient), its
    bias small, and the paper's closed form is far above the bound."""
    noise, clean, truth = Noise(), plane_case.record, plane_case.truth
    problem = WholeRecordProblem(clean, Model(three_element(1, 1, 1)), noise.force_std(clean), noise.markers,
                                 delays=True)
    bound = cramer_rao_std(problem, truth)
    refined, closed = [], []
    for i in range(30):
        rec = noise.apply(clean, np.random.default_rng([7, i]))
        c = from_final_displacement(rec)
        closed.append([c.params[k] for k in truth])
        # The spread only: the discretisation term touches the std, not the values.
        fit = fit_record(rec, c, discretisation=False)
        refined.append([fit.params[k] for k in truth])
    refined, closed = np.array(refined), np.array(closed)
    for j, k in enumerate(truth):
        ratio = refined[:, j].std(ddof=1) / bound[k]
        # 30 replicates: the sample std is within +-40 % of the true one at 3 sigma.
        assert 0.6 < ratio < 1.4, (k, ratio)
        assert abs(refined[:, j].mean() - truth[k]) < 3 * bound[k] / np.sqrt(30) * 1.4, k
        assert closed[:, j].std(ddof=1) > 2 * bound[k], k


def test_covariance_std_agrees_with_the_bound(plane_case):
    """The statistical part of the std (without the mesh's discretisation term)."""
    noise, clean, truth = Noise(), plane_case.record, plane_case.truth
    rec = noise.apply(clean, np.random.default_rng(3))
    est = fit_record(rec, from_final_displacement(rec), discretisation=False)
    problem = WholeRecordProblem(clean, Model(three_element(1, 1, 1)), noise.force_std(clean), noise.markers,
                                 delays=True)
    bound = cramer_rao_std(problem, truth)
    for k in truth:
        assert est.std[k] == pytest.approx(bound[k], rel=0.2), k


def test_deformation_error_is_the_papers_measure():
    a = np.zeros((25, 2))
    b = a.copy()
    b[0] = [0.001, 0.002]
    assert deformation_error(a, b, 0.08, 0.08) == pytest.approx((1e-6 + 4e-6) / 0.0064 * 100)


def test_identification_is_deterministic_across_processes():
    """The same bag gives the same numbers in another interpreter, to the last bit."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from rheo_ros.io.bag import read_bag

    bag = Path(__file__).resolve().parents[1] / "bags" / "clean_short_keep"
    code = ("import json, sys; from rheo_ros.io.bag import read_bag; "
            "from rheo_ros.identification.closed_form import from_final_displacement; "
            f"print(json.dumps(from_final_displacement(read_bag({str(bag)!r}).record).params))")
    other = json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                      check=True).stdout)
    assert from_final_displacement(read_bag(bag).record).params == other


def test_a_keep_phase_too_short_to_fit_is_a_clear_error(short_case):
    rec = short_case.record
    prof = rec.profile()
    cut = (rec.stage_t < prof.t_pull_end + 0.05) | (rec.stage_t >= prof.t_keep_end)
    depth = np.where(cut, rec.stage_depth, 0.0)
    depth[(rec.stage_t >= prof.t_pull_end + 0.05) & (rec.stage_t < prof.t_keep_end)] = 0.0
    short = replace(rec, stage_depth=depth)
    with pytest.raises(RecordError, match=r"table_I_short: force: \d+ samples in the keep phase, need 4"):
        from_final_displacement(short)


def test_non_finite_force_is_refused_naming_the_field(short_case):
    force = short_case.record.force.copy()
    force[10, 0] = np.nan
    with pytest.raises(RecordError, match="table_I_short: force: non-finite"):
        replace(short_case.record, force=force)


def test_table_iv_values_are_the_papers():
    assert TABLE_IV == {"E": 3.33e4, "c1": 1.69e5, "c2": 3.11e7, "gamma": 0.332}


# -- identification on data its own model did not make ---------------------------------

MESH_PROFILE = StageProfile(keep_time=48.0, release_time=60.0)   # quasi-static data: instant release


def _fit_with(setup: Setup, refine_level: int, record) -> Estimate:
    forward = QuasiStaticFE(setup.mesh, refine_level, setup.tactile.segment_edges)
    return fit_record(record, Estimate({k: 1.05 * v for k, v in TABLE_IV.items()}, "start", ()), forward=forward)


def test_fit_on_a_finer_mesh_is_within_a_tenth_of_a_percent_at_refine_8():
    """Noise-free data from the plane-stress FE at 65 x 65 nodes (refine 16), read as the
    sensors read them; fitted with the forward model at refine 8 (33 x 33). Measured
    (`rheo bench mesh`): E -0.031 %, c1 -0.032 %, c2 -0.049 %, gamma +0.055 %; at the
    marker grid itself (refine 1) E -1.4 %. Tolerance: the issue's 0.1 %."""
    setup = Setup(load_params(None))
    record = fine_mesh_record(setup, TABLE_IV, 16, MESH_PROFILE)
    fine = _fit_with(setup, 8, record).relative_errors(TABLE_IV)
    coarse = _fit_with(setup, 1, record).relative_errors(TABLE_IV)
    assert all(abs(e) < 0.1 for e in fine.values()), fine
    assert abs(coarse["E"]) > 1.0            # the marker grid alone is not converged


def test_discretisation_std_is_the_distance_to_a_much_finer_mesh():
    """The fit's systematic std (the shifts to meshes 2 and 4 times as fine and the tail
    beyond them) against the error it makes on noise-free data from a 257 x 257 mesh,
    which the std's own computation never solves: measured |error| / std 0.945-0.951
    for all four parameters (the data keep ~5 % of the error themselves). Tolerance
    0.88-1.02: the tail's order per parameter (`rheo bench mesh`: 2^-p 0.35-0.52). The
    former std (1.7 x the first shift) gave 0.87 for E."""
    setup = Setup(load_params(None))
    record = fine_mesh_record(setup, TABLE_IV, 64, MESH_PROFILE)
    fit = _fit_with(setup, 8, record)
    errors = fit.relative_errors(TABLE_IV)
    ratio = {k: abs(errors[k]) / (100 * fit.std[k] / v) for k, v in TABLE_IV.items()}
    systematic = {k: fit.statistics.discretisation[k] / fit.std[k] for k in TABLE_IV}
    assert all(0.88 <= r <= 1.02 for r in ratio.values()), ratio
    assert all(s > 0.99 for s in systematic.values()), systematic   # noise-free: the std is all systematic


def test_frictionless_block_is_identified_with_the_frictionless_choice():
    """Analytic uniaxial block (frictionless faces: test_fe shows the FE reproduces it
    to 1e-10). With `boundary: frictionless` every parameter comes back to 1e-6 %
    (noise-free); with the bonded default the same data give E about -6 %, gamma -15 %:
    the boundary conditions are a stated choice that matters."""
    free = Setup({**load_params(None), "boundary.bottom": "frictionless", "boundary.top": "frictionless"})
    record = fine_mesh_record(free, TABLE_IV, 2, MESH_PROFILE)
    right = _fit_with(free, 2, record).relative_errors(TABLE_IV)
    wrong = _fit_with(Setup(load_params(None)), 2, record).relative_errors(TABLE_IV)
    assert all(abs(e) < 1e-6 for e in right.values()), right
    # Measured: E +1.2 %, c2 +8.5 %, gamma -30 % (the clock offsets absorb part of the misfit).
    assert max(abs(e) for e in wrong.values()) > 3.0 and wrong["gamma"] < -10.0, wrong


@pytest.mark.parametrize("speed", [0.5e-3, 2e-3, 20e-3])
def test_slow_release_is_identified_by_the_fit_that_follows_the_contact(speed):
    """Noise-free data of the dynamic FE simulator (17 x 17 nodes, inertia, one-sided
    contact found inside the step) with the stage retracting at ``speed``; the paper's
    0.5 mm/s keeps the specimen on the stage for 13.5 s. The fit (quasi-static model,
    same mesh) follows the contact: measured |error| <= 0.004 % at every speed; the
    issue's tolerance 0.1 %. The closed form warns where it cannot follow (measured:
    -7 % at 0.5 mm/s)."""
    setup = Setup(check_params({**{f"material.{k}": v for k, v in TABLE_IV.items()}, "simulator.refine": 4,
                                "stage.keep_time": 48.0, "stage.release_time": 60.0, "stage.retract_speed": speed}))
    record = simulate_clean(setup).record(setup, f"retract at {speed} m/s")
    fit = _fit_with(setup, 4, record).relative_errors(TABLE_IV)
    assert all(abs(e) < 0.1 for e in fit.values()), fit
    closed = from_final_displacement(record)
    if speed == 0.5e-3:
        assert "slow release" in closed.message and closed.residual_rms["release_follow_s"] > 10
        assert closed.relative_errors(TABLE_IV)["c2"] < -5.0
    else:
        assert "slow release" not in closed.message


# -- the uniaxial block (geometry uniaxial: both faces frictionless) ---------------------

BLOCK = {"E": 3.33e4, "c1": 1.69e5, "c2": 3.11e7, "gamma": 0.3}
# % per parameter, noise-free: measured 1.6e-11 %, so the tolerance is set by what another
# machine's BLAS moves (~1e-7 %), ten times that. The closed form that averaged the last
# frames instead of following the recovery was 9.2e-5 % off at a 100 s release (and
# 2.5 % at a 30 s one): it fails this.
ANALYTIC_TOL = 1e-6
# The dynamic FE's inertia and mesh: the closed form measured 2.3e-3 % (c2), the fit 7.7e-4 % (c2).
DYNAMIC_TOL = {"closed_form": 4.5e-3, "fit": 1.5e-3}


def _block_setup() -> Setup:
    """The contract's default specimen and sensors as the uniaxial block; the boundary
    conditions are left to the geometry (frictionless). Simulated on a 17 x 17 mesh,
    the stage leaving at once on release."""
    return Setup(check_params({"geometry": "uniaxial", **{f"material.{k}": v for k, v in BLOCK.items()},
                               "simulator.refine": 4, "stage.retract_speed": float("inf")}))


@pytest.mark.parametrize("release_time", [5.0, 100.0])
def test_analytic_uniaxial_block_is_identified_exactly_however_short_the_release(release_time):
    """Closed form: gamma from the markers' lateral strain, E, c1, c2 from eq. 6, 7, 14-17
    with the final displacements where the recovery tends (``recovered_displacement``),
    then the whole-record fit. Noise-free, so both are exact, also for a release of 5 s
    (one Voigt time c1/E: the specimen has recovered 63 % of its Voigt strain). Measured:
    closed form within 1.6e-11 %, fit within 6e-12 % (ANALYTIC_TOL)."""
    setup = _block_setup()
    record = analytic_block_record(setup, BLOCK, StageProfile(release_time=release_time))
    closed = from_final_displacement(record)
    assert closed.equations[-1] == "gamma from the markers' lateral strain"
    fit = fit_record(record, closed, forward=setup.forward_model())
    for est in (closed, fit):
        errors = est.relative_errors(BLOCK)
        assert set(errors) == set(BLOCK) and all(abs(e) < ANALYTIC_TOL for e in errors.values()), (est.method, errors)


def test_dynamic_fe_uniaxial_block_is_identified_to_thousandths_of_a_percent():
    """Noise-free data of the dynamic FE simulator (17 x 17 nodes, inertia, one-sided
    contact) on the uniaxial block; identified by the closed form and by the fit on the
    default forward model (33 x 33). Measured: closed form within 2.3e-3 % (c2; E and c1
    1.1e-3 %, gamma 1.5e-4 %), fit within 7.7e-4 % (c2; gamma 1.6e-5 %) (DYNAMIC_TOL)."""
    setup = _block_setup()
    record = simulate_clean(setup).record(setup, "dynamic FE uniaxial block")
    closed = from_final_displacement(record)
    fit = fit_record(record, closed, forward=setup.forward_model())
    for est, tol in ((closed, DYNAMIC_TOL["closed_form"]), (fit, DYNAMIC_TOL["fit"])):
        errors = est.relative_errors(BLOCK)
        assert set(errors) == set(BLOCK) and all(abs(e) < tol for e in errors.values()), (est.method, errors)
