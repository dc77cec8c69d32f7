"""Effects as families of forms (``models.effects``): the registry, and the diagnosis
naming the family with the form that fits, on bags of the independent generator
(test/generator.py, seed 1, the Table IV material, the default experiment and the
default-like sensor: 300 Pa dead band, 10 Pa steps), whose effects follow other laws
than the package's default forms: two Maxwell arms, adhesion fading over 200 s, each
cell's baseline settling over 60 s, the Voigt spring alone stiffening exponentially."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from conftest import BAGS
from generator import EFFECTS, Effects, Layout, Material, Profile, generate, synthesize

from rheo_ros.app.analyze import analyze
from rheo_ros.config.setup import Setup, load_params
from rheo_ros.models.effects import (
    Effect,
    catalogue,
    effect_class,
    effect_forms,
    register_effect,
    unregister_effect,
)


def test_each_family_lists_its_forms_default_first():
    forms = {family: [cls.form for cls in effect_forms(family)] for family in catalogue()}
    assert forms["relaxation_branch"] == ["one_arm", "two_arms"]
    assert forms["sensor_drift"] == ["linear", "settling", "per_segment", "settling_per_segment"]
    assert forms["adhesion"] == ["fading", "held"]
    assert forms["strain_stiffening"] == ["linear", "exponential", "power_law", "voigt_exponential"]
    assert effect_class("adhesion") is effect_class("adhesion", "fading")
    with pytest.raises(KeyError, match="no form 'quadratic'; its forms: linear, exponential"):
        effect_class("strain_stiffening", "quadratic")


def test_a_users_form_joins_its_family_and_a_duplicate_is_refused():
    @dataclass(frozen=True)
    class PowerStiffening(Effect):
        id: ClassVar[str] = "strain_stiffening"
        form: ClassVar[str] = "power_law_test"
        exponent: float = 1.0

    register_effect(PowerStiffening)
    try:
        assert effect_forms("strain_stiffening")[-1] is PowerStiffening
        assert effect_class("strain_stiffening") is effect_class("strain_stiffening", "linear")

        @dataclass(frozen=True)
        class Again(PowerStiffening):
            pass

        with pytest.raises(ValueError, match="form 'power_law_test' is registered already"):
            register_effect(Again)
    finally:
        from rheo_ros.models import effects
        effects._REGISTRY["strain_stiffening"].pop("power_law_test")
    assert [c.form for c in effect_forms("strain_stiffening")] == ["linear", "exponential", "power_law",
                                                                   "voigt_exponential"]
    unregister_effect("no_such_effect")   # forgetting an unknown id is not an error


@pytest.fixture(scope="module")
def analysed(tmp_path_factory) -> dict:
    """effect -> (the analysis' JSON, the generator's truth). The drift bag is diagnosed
    against the drift and its rivals (``DRIFT_RIVALS``); the others against their family
    alone (the suite's time: the full loop on them is measured in the README)."""
    folder = tmp_path_factory.mktemp("families")
    out = {}
    for effect, candidates in (("sensor_drift", DRIFT_RIVALS), ("relaxation_branch", ["relaxation_branch"]),
                               ("adhesion", ["adhesion"]), ("strain_stiffening", ["strain_stiffening"]),
                               ("column_drift", ["sensor_drift"]), ("held_adhesion", ["adhesion", "sensor_drift"]),
                               ("faint_held_adhesion", ["adhesion"]),
                               ("sensor_drift_no_dead_band", DRIFT_RIVALS)):
        sensor = "no_dead_band" if effect.endswith("no_dead_band") else "default_like"
        bag = generate(folder / effect, effects=EFFECTS.get(effect.removesuffix("_no_dead_band"), OWN.get(effect)),
                       sensor=sensor, seed=1)
        result = analyze(Path(bag), candidates=candidates, workers=1).to_json()
        out[effect] = (result, json.loads(Path(f"{bag}.truth.json").read_text())["effects"])
    return out


COLUMN_DRIFT = Effects(column_drift=(3.0, 0.6))   # 3 Pa/s on average, 60 % apart by column
# A layer stuck at 430 Pa a cell after release, under the 300 Pa dead band's live threshold
# (600 Pa): every release reading there is only a bound.
HELD_UNDER_BAND = Effects(adhesion=(430.0, math.inf))
# Held at 80 Pa a cell: under the 300 Pa band itself; a cell's noise (100 Pa) lifts it over
# the band in 1.4 % of its readings (0.13 % with nothing there), the only sign of it.
FAINT_UNDER_BAND = Effects(adhesion=(80.0, math.inf))
OWN = {"column_drift": COLUMN_DRIFT, "held_adhesion": HELD_UNDER_BAND, "faint_held_adhesion": FAINT_UNDER_BAND}
# The settling drift's bag against the drift and the effects a drift's share of the
# release could pass for (adhesion) or of the keep (a relaxation arm): named first and alone.
DRIFT_RIVALS = ["sensor_drift", "adhesion", "relaxation_branch"]


def within(model: dict, name: str, truth: float, stds: float) -> float:
    error = (model["params"][name] - truth) / model["std"][name]
    assert abs(error) < stds, (name, model["params"][name], truth, error)
    return error


def drawn_drift_amplitudes() -> np.ndarray:
    """The settling drift's amplitude on each segment (N) as the generator drew it for
    seed 1: each cell's a_j = 400 Pa x (1 + 0.25 N(0, 1)) from its drift stream, summed
    over the segment's cells (the package's split of columns into segments)."""
    layout = Layout()
    a, _, spread = EFFECTS["sensor_drift"].drift
    drift_rng = np.random.default_rng(1).spawn(3)[2]   # the generator's drift stream for seed 1
    cells = a * (1.0 + spread * drift_rng.standard_normal((layout.tactile_rows, layout.tactile_cols)))   # Pa
    area = (layout.width / layout.tactile_cols) * (layout.thickness / layout.tactile_rows)
    array = Setup(load_params(None)).tactile
    return np.bincount(array.segment, weights=cells.sum(axis=0), minlength=array.nodes) * area


def test_a_settling_drift_is_named_with_its_form(analysed):
    """Each cell settling over 60 s by its own amount: the segments settle over one time
    by amounts that differ (25 % per cell, 4 % per segment), the `settling_per_segment`
    form; named first and alone, adequate after it; its time within 3 std of the
    generator's 60 s (measured 58.4 +- 1.8 s) and each segment's amplitude within 3 std of
    the one drawn (measured within 0.0-1.5 std, 0.049-0.097 N)."""
    result, truth = analysed["sensor_drift"]
    diagnosis, final = result["diagnosis"], result["models"][-1]
    assert diagnosis["missing_effects"] == ["sensor_drift"] and diagnosis["adequate"], diagnosis["evidence"]
    assert final["forms"] == {"sensor_drift": "settling_per_segment"}
    assert "settling_per_segment form" in diagnosis["evidence"]
    within(final, "sensor_drift.time", truth["drift"][1], 3.0)
    for j, amplitude in enumerate(drawn_drift_amplitudes()):
        within(final, f"sensor_drift.amplitude_P{j + 1}", amplitude, 3.0)


def test_a_settling_drift_with_no_dead_band_is_named_with_its_parameters(analysed):
    """The same drift on a sensor with no dead band (the noise clipped at zero): each
    reading is live when its segment's running median is (``noise.LIVE_WINDOW``), so the
    readings kept while the drift settles through the live threshold are not those the
    noise lifted. Named alone with its form, adequate, its time within 3.5 std of 60 s and
    E within 3.5 std of the truth (measured 56.7 +- 1.4 s and 33280 +- 10 Pa; live by the
    reading itself they were 46.0 +- 0.7 s and 33170 +- 7, 21 and 20 std off). The 2-2.4
    std left: clipping at zero lifts a cell's mean by up to 0.4 of its std where it is
    near zero (cells 25 % apart within a segment), which a live segment's reading still
    carries."""
    result, truth = analysed["sensor_drift_no_dead_band"]
    diagnosis, final = result["diagnosis"], result["models"][-1]
    assert diagnosis["missing_effects"] == ["sensor_drift"] and diagnosis["adequate"], diagnosis["evidence"]
    assert final["forms"] == {"sensor_drift": "settling_per_segment"}
    within(final, "sensor_drift.time", truth["drift"][1], 3.5)
    within(final, "E", Material().E, 3.5)


def test_two_relaxation_arms_are_named_as_two(analysed):
    """Each arm's stiffness and viscosity within 3 std of the generator's (measured
    0.2-1.9 std), the base within 3 std too (measured 0.9-1.1)."""
    result, truth = analysed["relaxation_branch"]
    final = result["models"][-1]
    assert result["diagnosis"]["adequate"] and final["forms"] == {"relaxation_branch": "two_arms"}
    (k_fast, tau_fast), (k_slow, tau_slow) = truth["maxwell"]
    within(final, "relaxation_branch.stiffness", k_slow, 3.0)
    within(final, "relaxation_branch.viscosity", k_slow * tau_slow, 3.0)
    within(final, "relaxation_branch.stiffness_2", k_fast, 3.0)
    within(final, "relaxation_branch.viscosity_2", k_fast * tau_fast, 3.0)
    for name, value in (("E", 3.33e4), ("c2", 3.11e7)):
        within(final, name, value, 3.0)


def test_adhesion_that_fades_keeps_the_fading_form(analysed):
    """The held form (one parameter fewer) loses to the fading one; the fading time within
    3 std of the generator's 200 s (measured 199.3 +- 0.9 s)."""
    result, truth = analysed["adhesion"]
    final = result["models"][-1]
    assert result["diagnosis"]["adequate"] and final["forms"] == {"adhesion": "fading"}
    within(final, "adhesion.time", truth["adhesion"][1], 3.0)


def test_a_held_adhesion_under_the_dead_band_is_named_with_its_size(analysed):
    """Readings under the live threshold bound the force from below too (``fit.ReadingWindows``):
    a layer held at 430 Pa a cell after release, all of it under the live threshold, is
    named adhesion/held (before: "adequate", the release's readings only an upper bound),
    and its fraction of the let-go force, which only those bounds hold (the middle of the
    range where the cost stays within 1, half its width the std), within 2 std of the
    generator's 430 Pa over the block's stress at the let-go (measured 0.1239 +- 0.021
    against 0.1111: the range 0.104-0.147)."""
    result, _ = analysed["held_adhesion"]
    final = result["models"][-1]
    assert result["diagnosis"]["missing_effects"] == ["adhesion"] and result["diagnosis"]["adequate"]
    assert final["forms"] == {"adhesion": "held"}
    profile = Profile()
    stress = synthesize(Material(), Effects(), "noise_free", 1, profile)
    let_go = np.searchsorted(stress.tactile_t, profile.knots[2]) - 1
    within(final, "adhesion.fraction", 430.0 / float(stress.images[let_go].mean()), 2.0)


def test_a_held_adhesion_under_the_band_itself_is_named_by_the_range_its_readings_allow(analysed):
    """A layer held at 80 Pa a cell, under the 300 Pa dead band: nearly every release
    reading is zero, and the cells' noise crosses the band more often than with nothing
    there (a cell's mean reading 4.6 Pa). Windows of 250 readings, each cell's mean reading
    at most 0.85 Pa above its pressure as the unloaded array shows it (``DeadBand.unloaded``;
    3.1 Pa with the noise's doubt, which left this layer "adequate"), put the force's floor
    above zero, and the release misfits by the whole chi-square of the bounds
    (``compare.binned_chi_square``): adhesion/held named, its fraction given by the range
    the readings allow, which holds the truth (the evidence states it; measured: between
    0.00071 and 0.044, the truth 0.0207; at 160 Pa, 0.0062-0.050 against 0.0413)."""
    import re

    result, _ = analysed["faint_held_adhesion"]
    assert result["diagnosis"]["missing_effects"] == ["adhesion"] and result["diagnosis"]["adequate"]
    assert result["models"][-1]["forms"] == {"adhesion": "held"}
    low, high = map(float, re.search(r"fraction between (\S+) and (\S+) \(", result["diagnosis"]["evidence"]).groups())
    profile = Profile()
    stress = synthesize(Material(), Effects(), "noise_free", 1, profile)
    let_go = np.searchsorted(stress.tactile_t, profile.knots[2]) - 1
    assert 0.0 < low < 160.0 / float(stress.images[let_go].mean()) < high, (low, high)


def test_a_voigt_spring_that_stiffens_is_named_as_that_form(analysed):
    """The generator's spring E (exp(4 eps_v) - 1) / 4 in the Voigt element alone: the
    factor on the whole stress (linear, exponential, power law) leaves the pull at 5-8 x
    the noise; the Voigt-spring form fits to the noise. Its coefficient and the base within
    3 std of the generator's (measured: coefficient 3.998 +- 0.008, -0.25 std)."""
    result, truth = analysed["strain_stiffening"]
    final = result["models"][-1]
    assert result["diagnosis"]["adequate"], result["diagnosis"]["evidence"]
    assert final["forms"] == {"strain_stiffening": "voigt_exponential"}
    assert max(v for v in final["fit_to_noise"].values() if v is not None) < 1.25
    within(final, "strain_stiffening.coefficient", truth["stiffening"], 3.0)
    for name, value in (("E", 3.33e4), ("c1", 1.69e5), ("c2", 3.11e7)):
        within(final, name, value, 3.0)


def test_a_drift_of_each_segment_its_own_is_named_per_segment(analysed):
    """Each column of cells drifting at its own rate (3 Pa/s x (1 + 0.6 N(0, 1))): one line
    for every segment (linear) or one settling curve (settling) leave the pull 1.1-2.0 x
    the noise; the per-segment form fits to the noise, each segment's rate within 3 std
    of the columns' it sums (the package's own split of columns into segments; measured
    0.2-1.5 std), each offset within 3 std of zero."""
    result, _ = analysed["column_drift"]
    final = result["models"][-1]
    assert result["diagnosis"]["adequate"], result["diagnosis"]["evidence"]
    assert final["forms"] == {"sensor_drift": "per_segment"}
    layout = Layout()
    rate, spread = COLUMN_DRIFT.column_drift
    drift_rng = np.random.default_rng(1).spawn(3)[2]   # the generator's drift stream for seed 1
    columns = rate * (1.0 + spread * drift_rng.standard_normal(layout.tactile_cols))   # Pa/s
    array = Setup(load_params(None)).tactile
    area = (layout.width / layout.tactile_cols) * (layout.thickness / layout.tactile_rows)
    segment_rates = np.bincount(array.segment, weights=columns, minlength=array.nodes) * layout.tactile_rows * area
    for j, truth in enumerate(segment_rates):
        within(final, f"sensor_drift.rate_P{j + 1}", truth, 3.0)
        within(final, f"sensor_drift.offset_P{j + 1}", 0.0, 3.0)


def test_a_form_chosen_before_the_next_effect_is_chosen_again_beside_it(tmp_path):
    """Generator bench bag 17 of seed 10 (clipped sensor; one Maxwell arm of 4.5 kPa, 2.5 s,
    and a Voigt spring stiffening exponentially, k 1.08): on the base model two arms beat
    one, and with the stiffening found next the two-arm fit degenerates: c2 runs off to its
    bound (the second arm takes up the flow; an Intel machine at stop 51), or the second arm
    is left undetermined (this AMD EPYC machine, stop 56: its stiffness 2.8 kPa +- 62 kPa;
    the path of a degenerate fit follows the BLAS's last bits). Chosen again beside the
    stiffening (``discover.revisit_forms``), one arm fits better (measured: BIC lower by
    22.4, 21 on the EPYC) and nothing is at a bound: E, c1, c2, the arm and k within 3 std of
    the generator's truth (measured: c1 2.4-2.6 std, the arm's viscosity 2.1-2.2, the others
    within 1.2)."""
    from generator import bench_bag

    from rheo_ros.diagnosis.decision import collapsed, resolved_times, undetermined
    from rheo_ros.diagnosis.discover import revisit_forms
    from rheo_ros.diagnosis.fits import add_effect, polish

    truth = bench_bag(np.random.default_rng((10, 17)), 17, tmp_path / "bag", 1.0, True)
    analysis = analyze(tmp_path / "bag", params_file=truth["params_file"], discover_effects=False, workers=1)
    record, forward, noise, base = analysis.record, analysis.forward, analysis.noise, analysis.models[0]
    fit = base
    for effect, form in (("relaxation_branch", "two_arms"), ("strain_stiffening", "voigt_exponential")):
        fit = polish(record, forward, add_effect(record, forward, fit, effect, noise, form), noise)
    assert collapsed(fit, base, resolved_times(record)) == ("c2",) or undetermined(fit, "relaxation_branch")

    revised, changes = revisit_forms(record, forward, fit, base, noise)
    assert revised.forms == {"relaxation_branch": "one_arm", "strain_stiffening": "voigt_exponential"}, changes
    assert revised.bic < fit.bic - 10.0 and len(changes) == 1, changes
    assert collapsed(revised, base, resolved_times(record)) == ()
    material = json.loads((tmp_path / "bag.truth.json").read_text())
    (arm_stiffness, arm_time), = material["effects"]["maxwell"]
    p, std = revised.estimate.params, revised.estimate.std
    expected = {**{k: material["material"][k] for k in ("E", "c1", "c2")},
                "relaxation_branch.stiffness": arm_stiffness,
                "relaxation_branch.viscosity": arm_stiffness * arm_time,
                "strain_stiffening.coefficient": material["effects"]["stiffening"]}
    for name, value in expected.items():
        assert abs(p[name] - value) < 3 * std[name], (name, p[name], value, std[name])


def test_a_stalled_search_chooses_the_forms_again_beside_its_best_candidate(tmp_path):
    """Generator bench bag 38 of seed 17 (default-like sensor; each segment's baseline
    settling over 7.5 s by its own amount, 40 x the total-force noise, and a Voigt spring
    stiffening exponentially, k 0.43, 30 x). On the base each segment's linear drift beat
    the settling form, and beside it the stiffening removed 48 % of the pull's misfit:
    nothing was named. Beside the stiffening (``discover.forms_again``) the drift settles
    (BIC lower by 962 than the linear form's) and both are named with the generator's
    forms, the model adequate: E, c1, c2, k and the drift's time within 3 std of the truth
    (measured within 1.1)."""
    from generator import bench_bag

    truth = bench_bag(np.random.default_rng((17, 38)), 38, tmp_path / "bag", 1.0, True)
    report = analyze(tmp_path / "bag", params_file=truth["params_file"], candidates=["sensor_drift",
                     "strain_stiffening"], workers=1).to_json()
    diagnosis = report["diagnosis"]
    assert diagnosis["explained"] and diagnosis["adequate"], diagnosis["evidence"]
    assert diagnosis["missing_effects"] == ["sensor_drift", "strain_stiffening"], diagnosis["evidence"]
    model = report["models"][-1]
    assert model["forms"] == {"sensor_drift": "settling_per_segment", "strain_stiffening": "voigt_exponential"}
    material = json.loads((tmp_path / "bag.truth.json").read_text())
    _, drift_time, _ = material["effects"]["drift"]
    expected = {**{k: material["material"][k] for k in ("E", "c1", "c2")},
                "strain_stiffening.coefficient": material["effects"]["stiffening"], "sensor_drift.time": drift_time}
    for name, value in expected.items():
        within(model, name, value, 3.0)


def test_a_form_that_runs_a_base_parameter_off_to_a_bound_loses_to_one_that_does_not(tmp_path):
    """Generator bench bag 2 of seed 10 (quantised sensor; two Maxwell arms, 1.3 s and
    6.7 s, 17.5 x the total-force noise, and a stiffening under its threshold): two arms
    beat one by BIC, but beside them c2 runs off to its bound (no measurement: the verdict
    was "the catalogue does not explain these data"). One arm fits within the noise with
    c2 determined, and is named: at stop 51 by ``discover.revisit_forms`` once the two arms
    were added; since each form is fitted from a linearised step too (``fits.start_points``),
    one arm beats two on the base already (measured: c2 3.26e7 +- 1.8e6 Pa s)."""
    from generator import bench_bag

    truth = bench_bag(np.random.default_rng((10, 2)), 2, tmp_path / "bag", 1.0, True)
    report = analyze(tmp_path / "bag", params_file=truth["params_file"], candidates=["relaxation_branch"],
                     workers=1).to_json()
    diagnosis = report["diagnosis"]
    assert diagnosis["explained"] and diagnosis["missing_effects"] == ["relaxation_branch"], diagnosis["evidence"]
    model = report["models"][-1]
    assert model["forms"] == {"relaxation_branch": "one_arm"}
    assert math.isfinite(model["std"]["c2"]) and model["std"]["c2"] < 0.5 * model["params"]["c2"]


def test_a_settling_drift_beside_a_held_adhesion_starts_where_the_adhesion_makes_room(tmp_path):
    """Generator bench bag 14 of seed 17 (no dead band; a held adhesion, 79 x the
    total-force noise, and the array's baseline settling by -50 Pa over 10.9 s): with the
    adhesion in the model, the level after release is the adhesion's, and every start read
    off the quiet readings settles nowhere; judged where they stand (no step), the best of
    them ended at a constant offset (time 6e13 s). Each start taken one linearised step
    with every parameter too (``fits.start_points``), the drift settles over the generator's
    time: measured 10.94 +- 0.99 s, the fit 168 lower in BIC than the adhesion alone (no
    settling: 52)."""
    from generator import bench_bag

    from rheo_ros.diagnosis.fits import add_effect, polish

    truth = bench_bag(np.random.default_rng((17, 14)), 14, tmp_path / "bag", 1.0, True)
    analysis = analyze(tmp_path / "bag", params_file=truth["params_file"], discover_effects=False, workers=1)
    record, forward, noise, base = analysis.record, analysis.forward, analysis.noise, analysis.models[0]
    held = polish(record, forward, add_effect(record, forward, base, "adhesion", noise, "held"), noise)
    fit = polish(record, forward, add_effect(record, forward, held, "sensor_drift", noise, "settling"), noise)
    material = json.loads((tmp_path / "bag.truth.json").read_text())
    _, drift_time, _ = material["effects"]["drift"]
    p, std = fit.estimate.params, fit.estimate.std
    assert std["sensor_drift.time"] < 0.3 * drift_time, (p, std)
    assert abs(p["sensor_drift.time"] - drift_time) < 3 * std["sensor_drift.time"], (p, std)
    assert p["sensor_drift.amplitude"] < -3 * std["sensor_drift.amplitude"]
    assert fit.bic < held.bic - 100.0


def test_an_effect_that_stood_in_for_one_found_after_it_is_taken_out(tmp_path):
    """Generator bench bag 40 of seed 20 at twice the noise (no dead band; each segment's
    baseline settling over 3.7 s, 23 x the total-force noise, nothing else). A linear
    stiffening took the pull's curve first; with the drift found next its coefficient fell
    to zero and both were named. Taken out again (``discover.drop_idle``: without it the
    BIC is lower by 10.6, measured), the drift alone is named with the generator's form,
    the model adequate: E, c1, c2 and the drift's time within 3 std of the truth."""
    from generator import bench_bag

    truth = bench_bag(np.random.default_rng((20, 40)), 40, tmp_path / "bag", 2.0, True)
    report = analyze(tmp_path / "bag", params_file=truth["params_file"], workers=1).to_json()
    diagnosis = report["diagnosis"]
    assert diagnosis["explained"] and diagnosis["missing_effects"] == ["sensor_drift"], diagnosis["evidence"]
    assert "Strain_stiffening no longer earns its parameters beside sensor_drift" in diagnosis["evidence"]
    assert [step["dropped"] for step in diagnosis["steps"]][:2] == [[], ["strain_stiffening"]]
    model = report["models"][-1]
    assert model["forms"] == {"sensor_drift": "settling_per_segment"}
    material = json.loads((tmp_path / "bag.truth.json").read_text())
    _, drift_time, _ = material["effects"]["drift"]
    expected = {**{k: material["material"][k] for k in ("E", "c1", "c2")}, "sensor_drift.time": drift_time}
    for name, value in expected.items():
        within(model, name, value, 3.0)


def test_an_effect_fitted_from_its_stepped_start_never_ends_worse_than_none(tmp_path):
    """Generator bench bag 8 of seed 18 at twice the noise (quantised; a settling drift and
    a held adhesion, no stiffening). From the stiffening's start taken one linearised step
    (``fits.start_points``: coefficient 0.35) its coefficient ran to 1e-10, where a
    log-scaled parameter no longer moves, while c2 was still 4 % off: 639 in BIC above the
    base model, a candidate worse than none. The fit from the start as given is made too
    and the better kept (measured: BIC 11.5 above the base: its coefficient's price, ln n,
    and 1.0 of chi-square the screening fit stopped short by)."""
    from generator import bench_bag

    from rheo_ros.diagnosis.fits import add_effect

    truth = bench_bag(np.random.default_rng((18, 8)), 8, tmp_path / "bag", 2.0, True)
    analysis = analyze(tmp_path / "bag", params_file=truth["params_file"], discover_effects=False, workers=1)
    record, forward, noise, base = analysis.record, analysis.forward, analysis.noise, analysis.models[0]
    fit = add_effect(record, forward, base, "strain_stiffening", noise)
    # Within the screening fit's stopping tolerance (25 iterations) of the base: measured 1.0.
    assert fit.cost < base.cost + 2.0
    assert fit.bic - base.bic < np.log(fit.samples) + 2.0


def test_a_second_start_is_fitted_only_where_the_first_fit_is_no_answer(monkeypatch):
    """``fits.fit_from``: the start points in order, the lowest cost kept, and the later ones
    not fitted once a fit is sound (each start costs a whole fit)."""
    from types import SimpleNamespace

    from rheo_ros.diagnosis import fits

    fitted = []

    def fake_fit(record, forward, effects, start, noise):
        fitted.append(start["at"])
        return SimpleNamespace(cost=start["cost"], at=start["at"])

    monkeypatch.setattr(fits, "fit_model", fake_fit)
    points = [((), {"at": "as given", "cost": 5.0}), ((), {"at": "stepped", "cost": 3.0})]
    best = fits.fit_from(None, None, points, None)
    assert (best.at, fitted) == ("stepped", ["as given", "stepped"])
    fitted.clear()
    best = fits.fit_from(None, None, points, None, sound=lambda fit: fit.cost < 10.0)
    assert (best.at, fitted) == ("as given", ["as given"])
    fitted.clear()
    best = fits.fit_from(None, None, points, None, sound=lambda fit: fit.cost < 4.0)
    assert (best.at, fitted) == ("stepped", ["as given", "stepped"])


def test_a_first_fit_that_leaves_its_effect_unbounded_is_fitted_again_from_the_second_start(tmp_path):
    """Generator bench bag 1 of seed 17 (default-like sensor; each segment's baseline
    settling over 48 s, 1.7 x the total-force noise, the base at 1.03 x the noise). From the
    first start the drift fits within the noise with its time, offset and amplitude
    unbounded (the data could not decide); a fit that leaves its effect undetermined is no
    answer (``discover._sound``), so the second start is fitted too, and from it the drift
    lowers the BIC by 78 (measured on two machines). A time of 48 s in a 40 s record is at
    the edge of what it shows: its amplitude bounded, the drift named and the model
    adequate on an Intel machine (stop 52), the time left open on this AMD EPYC (stop 56),
    and the verdict "the data cannot decide", naming the time and the longer record that
    would pin it. Either is asserted, never another effect or "adequate" without it."""
    from generator import bench_bag

    from rheo_ros.diagnosis import fits

    truth = bench_bag(np.random.default_rng((17, 1)), 1, tmp_path / "bag", 1.0, True)
    fit_model, starts = fits.fit_model, []

    def counted(*args, **kwargs):
        starts.extend(e.id for e in args[2] if e.id == "sensor_drift")
        return fit_model(*args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(fits, "fit_model", counted)
        report = analyze(tmp_path / "bag", params_file=truth["params_file"], candidates=["sensor_drift"],
                         workers=1).to_json()
    assert len(starts) >= 2, starts   # the drift's first fit was no answer: the second start fitted
    diagnosis = report["diagnosis"]
    model = report["models"][-1]
    drift = next(c for c in diagnosis["steps"][0]["candidates"] if c["effect"] == "sensor_drift")
    assert drift["delta_bic"] < -10.0, drift
    if diagnosis["missing_effects"]:
        assert diagnosis["missing_effects"] == ["sensor_drift"] and diagnosis["adequate"], diagnosis["evidence"]
        assert diagnosis["explained"] and math.isfinite(model["std"]["sensor_drift.amplitude"]), model["std"]
    else:
        assert diagnosis["undecided"] == ["sensor_drift"], diagnosis["evidence"]
        assert "sensor_drift.time" in diagnosis["evidence"] and "longer record" in diagnosis["evidence"]


def test_an_idle_effect_on_data_the_model_fits_is_fitted_from_one_start_only(monkeypatch):
    """``discover._sound``: the package's clean bag (simulator, no effect) fits within the
    noise; a relaxation arm added to it lowers no BIC and the data cannot pin it down. That
    first fit is an answer (the effect is idle): the second start, a whole fit that could
    earn nothing, is not fitted."""
    from rheo_ros.diagnosis import discover, fits

    analysis = analyze(BAGS / "clean_long_keep", discover_effects=False, workers=1)
    record, forward, noise, base = analysis.record, analysis.forward, analysis.noise, analysis.models[0]
    starts = []
    fit_model = fits.fit_model
    monkeypatch.setattr(fits, "fit_model", lambda *a, **k: starts.append(a[3]) or fit_model(*a, **k))
    candidate = discover.try_effect(record, forward, base, "relaxation_branch", noise)
    assert candidate.fit.bic >= base.bic
    assert discover.undetermined(candidate.fit, "relaxation_branch")
    assert len(starts) == 1


def test_behind_a_small_leader_every_family_misfitting_where_it_shows_has_its_forms_fitted():
    """``discover.other_forms``: a family's other forms are skipped only behind a leader
    that lowers the BIC by more than ``FORM_LEADER``. Generator seed 17 bag 14 (a held
    adhesion found, each cell's baseline settling over 11 s left, 4 x the total-force
    noise): a linear stiffening led by 59 and the drift's linear form was 13.5 behind the
    model without it; its settling form, skipped as far behind, was 163 ahead (measured)."""
    from types import SimpleNamespace

    from rheo_ros.diagnosis import discover

    # Every phase 10 sd over the noise, in bins: each form's phases misfit.
    current = SimpleNamespace(phase_chi2=lambda phases, signals=("force",): (200.0 * len(phases), 100.0 * len(phases)))

    def default(effect, delta_bic):
        return SimpleNamespace(effect=effect, delta_bic=delta_bic, clears=())

    small = discover.other_forms(current, [default("strain_stiffening", -59.1), default("sensor_drift", 13.5)])
    assert {form for effect, form in small if effect == "sensor_drift"} == {"settling", "per_segment",
                                                                            "settling_per_segment"}
    large = discover.other_forms(current, [default("strain_stiffening", -2e4), default("sensor_drift", 13.5)])
    assert [effect for effect, _ in large] == ["strain_stiffening"] * 3
