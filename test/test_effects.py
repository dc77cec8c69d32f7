"""Each hidden effect changes the simulated signal where the contract says it shows, and nowhere else."""

import numpy as np
import pytest

from rheo_ros.config.setup import Setup, load_params
from rheo_ros.rig.simulator import simulate_run


def run(effect: str | None):
    params = load_params(None)
    # Noise-free sensors, so that any difference is the effect's; a 33 x 33-node mesh and a
    # 30 s release (where each effect shows does not need the finer mesh or the long tail).
    params.update({"tactile.noise": 0.0, "tactile.resolution": 0.0, "tactile.threshold": 0.0, "markers.noise": 0.0,
                   "simulator.refine": 8, "stage.release_time": 30.0,
                   "simulator.effects": [effect] if effect else [""]})
    setup = Setup(params)
    r = simulate_run(setup, 0)
    return setup, r, setup.tactile.nodal_forces(r.tactile)


@pytest.fixture(scope="module")
def clean():
    return run(None)


def phase_masks(setup, t):
    p = setup.profile
    return {
        "before": t < p.t_pull_start,
        "pull": (t > p.t_pull_start + 0.1) & (t < p.t_pull_end - 0.1),
        "keep": (t > p.t_pull_end + 0.1) & (t < p.t_keep_end - 0.1),
        "contact": t < p.t_keep_end,
        "after": t > p.t_keep_end + 1.0,
    }


def test_relaxation_branch_shows_in_keep_as_a_fast_early_drop(clean):
    setup, r, F = run("relaxation_branch")
    _, rc, Fc = clean
    m = phase_masks(setup, r.tactile_t)
    extra = (F - Fc).sum(axis=1)
    np.testing.assert_array_equal(F[m["before"]], Fc[m["before"]])
    keep = extra[m["keep"]]
    assert keep[0] > 0.05 * Fc[m["keep"]].sum(axis=1)[0]       # visible at the start of keep
    assert keep[-1] < 1e-3 * keep[0]                            # gone after 48 s (branch time 5 s)
    # Displacement-controlled while in contact: the markers do not see the material.
    mm = phase_masks(setup, r.marker_t)["contact"]
    np.testing.assert_allclose(r.markers[mm], rc.markers[mm], rtol=0, atol=1e-8)  # inertia: < 1 nm


def test_adhesion_shows_only_after_release(clean):
    setup, r, F = run("adhesion")
    _, rc, Fc = clean
    m = phase_masks(setup, r.tactile_t)
    np.testing.assert_array_equal(F[m["contact"]], Fc[m["contact"]])
    after = F[m["after"]].sum(axis=1)
    assert np.all(Fc[m["after"]].sum(axis=1) < 1e-3)               # clean: back to zero
    keep_end = Fc[m["keep"]].sum(axis=1)[-1]
    fraction, time = setup.params["effects.adhesion.fraction"], setup.params["effects.adhesion.time"]
    assert after[0] == pytest.approx(fraction * keep_end, rel=0.02)   # stuck: does not return to zero
    assert after[-1] == pytest.approx(after[0] * np.exp(-(r.tactile_t[m["after"]][-1] - r.tactile_t[m["after"]][0]) / time), rel=0.02)
    np.testing.assert_array_equal(r.markers, rc.markers)


def test_strain_stiffening_curves_the_pull_force_up_with_depth(clean):
    setup, r, F = run("strain_stiffening")
    _, rc, Fc = clean
    m = phase_masks(setup, r.tactile_t)
    np.testing.assert_array_equal(F[m["before"]], Fc[m["before"]])
    ratio = F[m["pull"]].sum(axis=1) / Fc[m["pull"]].sum(axis=1)
    depth = setup.profile.depth_at(r.tactile_t[m["pull"]])
    k, height = setup.params["effects.strain_stiffening.coefficient"], setup.params["specimen.height"]
    np.testing.assert_allclose(ratio, 1 + k * depth / height, rtol=2e-3)
    np.testing.assert_array_equal(r.markers, rc.markers)


def test_sensor_drift_is_a_baseline_and_a_trend_everywhere(clean):
    setup, r, F = run("sensor_drift")
    _, rc, Fc = clean
    offset, rate = setup.params["effects.sensor_drift.offset"], setup.params["effects.sensor_drift.rate"]
    expected = offset + rate * r.tactile_t
    # 1e-5 N: after release the clean force is a hair below zero (inertia), which the
    # sensor reads as zero (no tension) while the drifted one is read as it is.
    np.testing.assert_allclose(F - Fc, np.repeat(expected[:, None], 5, axis=1), atol=1e-5)
    m = phase_masks(setup, r.tactile_t)
    assert F[m["before"]].min() > 0.9 * offset                       # non-zero baseline before contact
    np.testing.assert_array_equal(r.markers, rc.markers)


def test_effects_combine():
    params = load_params(None)
    params.update({"tactile.noise": 0.0, "tactile.resolution": 0.0, "tactile.threshold": 0.0, "markers.noise": 0.0,
                   "simulator.effects": ["adhesion", "sensor_drift"]})
    setup = Setup(params)
    assert setup.model().name == "three_element+adhesion+sensor_drift"
    F = setup.tactile.nodal_forces(simulate_run(setup, 0).tactile)
    assert F[0].min() > 0.9 * params["effects.sensor_drift.offset"]
