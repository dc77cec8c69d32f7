"""The model-discovery loop on data with hidden effects: simulator bags (65 x 65-node
FE, noisy sensor path) made here with parameters unlike the committed bags', each
with an effect the analysis is not told about. The diagnosis must name it, the model
with it must cut the force RMS below a third, and clean data must come back
adequate with no effect claimed."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

import rheo_ros
from rheo_ros.app.simulate import simulate_to_bag
from rheo_ros.config.setup import Setup, check_params
from rheo_ros.models.effects import Effect, register_effect, unregister_effect

# Not the committed bags' clay: stiffer, more viscous, a shallower push, a shorter keep.
# Short records keep the suite short; the simulator's mesh (49 x 49 nodes) is still finer
# than the identification's (33 x 33), so the data are not the identifier's own model.
MATERIAL = {"material.E": 5.0e4, "material.c1": 3.0e5, "material.c2": 5.0e7, "material.gamma": 0.3}
STAGE = {"stage.depth": 0.008, "stage.keep_time": 20.0, "stage.release_time": 20.0, "simulator.refine": 12}


def make_bag(directory, name: str, seed: int, effects: dict[str, dict[str, float]] | None = None,
             **extra) -> str:
    params = {**MATERIAL, **STAGE, **extra, "simulator.effects": list(effects or {}) or [""]}
    for effect_id, values in (effects or {}).items():
        params |= {f"effects.{effect_id}.{k}": v for k, v in values.items()}
    out = directory / name
    simulate_to_bag(Setup(check_params(params, name)), seed, out)
    return str(out)


HIDDEN = [
    # (effect, its parameters, seed): the weaker of the magnitudes tried, a few times the
    # noise (the stronger ones - a 30 % arm of 8 s, stiffening 6, drift 0.2 N - passed
    # too, and the bench covers sizes); adhesion at both, the stronger with the largest
    # parameter error measured (4.1 std).
    ("relaxation_branch", {"stiffness": 1.0e4, "viscosity": 3.0e4}, 12),      # 3 s, 20 % of E
    ("adhesion", {"fraction": 0.15, "time": 60.0}, 13),
    ("adhesion", {"fraction": 0.4, "time": 15.0}, 14),
    ("strain_stiffening", {"coefficient": 2.0}, 15),
    ("sensor_drift", {"offset": 0.12, "rate": 2.0e-3}, 18),
]


@pytest.mark.parametrize("effect,values,seed", HIDDEN, ids=[f"{e}-{s}" for e, _, s in HIDDEN])
def test_a_hidden_effect_is_named_and_adding_it_cuts_the_force_error_below_a_third(tmp_path, effect, values, seed):
    bag = make_bag(tmp_path, "run", seed, {effect: values})
    result = rheo_ros.analyze(bag)
    report = result.to_json()
    assert report["diagnosis"]["missing_effect"] == effect, report["diagnosis"]["evidence"]
    assert report["diagnosis"]["missing_effects"] == [effect], report["diagnosis"]["evidence"]
    assert report["diagnosis"]["adequate"]
    base, fixed = report["models"][0], report["models"][1]
    assert fixed["effects"] == [effect]
    # Measured 4.0 x lower at least (relaxation_branch-12): below 0.35 x fails if the
    # remaining error doubles there.
    assert fixed["rmse_force"] <= 0.35 * base["rmse_force"]
    assert fixed["bic"] < base["bic"]
    # With the effect, the residuals are at the sensor noise (1 within the misfit limit).
    assert max(v for v in fixed["fit_to_noise"].values() if v is not None) < 1.25
    # The hidden effect's own parameters come back within 6 of their reported std (which
    # holds the noise and the mesh's discretisation; measured up to 4.1 std, adhesion-14's
    # fraction 0.16 % off: the simulator's finer mesh is not the fit's).
    for name, value in values.items():
        key = f"{effect}.{name}"
        assert abs(fixed["params"][key] - value) < 6 * fixed["std"][key], (key, fixed["params"][key], fixed["std"][key])


CLEAN = [
    # (seed, extra parameters): short and long keeps, both geometries (ten seeds ran clean
    # at stop 35; the bench counts false claims over many more: 0/20 in its slices).
    (21, {}), (25, {"stage.keep_time": 60.0}),
    (28, {"geometry": "uniaxial"}), (30, {"geometry": "uniaxial", "stage.keep_time": 60.0}),
]


@pytest.mark.parametrize("seed,extra", CLEAN, ids=[f"clean-{s}" for s, _ in CLEAN])
def test_clean_data_are_adequate_and_no_effect_is_claimed(tmp_path, seed, extra):
    bag = make_bag(tmp_path, "run", seed, **extra)
    steps: list[str] = []
    result = rheo_ros.analyze(bag, progress=steps.append)
    d = result.to_json()["diagnosis"]
    assert d["adequate"] and d["missing_effect"] is None and d["missing_effects"] == [], d["evidence"]
    assert len(result.models) == 1
    assert "is adequate" in d["evidence"]
    # Where the model fits, no family's other forms are fitted (clean-22: 44 s -> 8 s).
    assert not [s for s in steps if " form)" in s], steps


def test_a_keep_too_short_for_the_second_time_says_which_parameter_is_open_and_what_would_pin_it(tmp_path):
    # A 28 s relaxation mode seen through a 5 s keep: the misfit is there, its time is not.
    bag = make_bag(tmp_path, "run", 51, {"relaxation_branch": {"stiffness": 2.0e4, "viscosity": 6.0e5}},
                   **{"stage.keep_time": 5.0, "stage.release_time": 20.0})
    result = rheo_ros.analyze(bag)
    evidence = result.to_json()["diagnosis"]["evidence"]
    assert result.missing_effects == ("relaxation_branch",), evidence
    assert "viscosity is only loosely determined by these data (std above half the value)" in evidence
    assert "a keep at least five times the fast relaxation time" in evidence
    std = result.models[1].estimate.std
    assert std["relaxation_branch.viscosity"] > 0.3 * result.models[1].estimate.params["relaxation_branch.viscosity"]


def test_two_hidden_effects_are_found_one_after_the_other_in_order_of_importance(tmp_path):
    # Stiffening changes the force by ~25 %, the relaxation arm by ~5 %.
    bag = make_bag(tmp_path, "run", 31, {"strain_stiffening": {"coefficient": 5.0},
                                         "relaxation_branch": {"stiffness": 4.0e3, "viscosity": 1.6e4}})
    result = rheo_ros.analyze(bag)
    assert result.missing_effects == ("strain_stiffening", "relaxation_branch"), result.to_json()["diagnosis"]
    rmse = [m.rmse_force for m in result.models]
    assert rmse[0] > 2 * rmse[1] > 2 * 1.0 * rmse[2]       # the error falls at each step
    assert result.diagnoses[-1].adequate


@dataclass(frozen=True)
class TactileCrosstalk(Effect):
    """A user's effect, written outside the package: the tactile array's segments leak
    ``fraction`` of their force into each neighbour (an edge segment keeps what would
    leak outward). It needs no history, so the simulator streams it too."""

    id: ClassVar[str] = "test_tactile_crosstalk"
    shows_in: ClassVar[tuple[str, ...]] = ("pull", "keep")
    fraction: float = 0.05

    def measured_force(self, t: np.ndarray, force: np.ndarray, release) -> np.ndarray:
        padded = np.pad(force, ((0, 0), (1, 1)), mode="edge")
        return (1 - 2 * self.fraction) * force + self.fraction * (padded[:, :-2] + padded[:, 2:])


@pytest.fixture
def user_effect():
    register_effect(TactileCrosstalk)
    yield TactileCrosstalk.id
    unregister_effect(TactileCrosstalk.id)   # other tests see the package's catalogue only


def test_a_users_own_effect_is_fitted_and_found(tmp_path, user_effect):
    bag = make_bag(tmp_path, "run", 41, {user_effect: {"fraction": 0.15}})
    added = rheo_ros.analyze(bag, effects=[user_effect], discover_effects=False)
    assert [m.name for m in added.models] == ["three_element", f"three_element+{user_effect}"]
    assert added.models[1].rmse_force < 0.5 * added.models[0].rmse_force
    assert added.models[1].estimate.params[f"{user_effect}.fraction"] == pytest.approx(0.15, rel=0.1)
    found = rheo_ros.analyze(bag)     # the catalogue now holds the user's effect too
    assert found.missing_effects == (user_effect,), found.to_json()["diagnosis"]["evidence"]


def test_an_effect_the_user_adds_is_fitted_side_by_side_with_the_base(tmp_path):
    bag = make_bag(tmp_path, "run", 42, {"adhesion": {"fraction": 0.2, "time": 40.0}})
    result = rheo_ros.analyze(bag, effects=["adhesion"], discover_effects=False)
    report = result.to_json()
    assert [m["name"] for m in report["models"]] == ["three_element", "three_element+adhesion"]
    assert report["models"][1]["rmse_force"] < 0.2 * report["models"][0]["rmse_force"]
    assert np.isfinite(report["models"][1]["std"]["adhesion.fraction"])


@dataclass(frozen=True)
class RetardationBranch(Effect):
    """A second Voigt element in series: as a standard linear solid, the same family of
    responses as a Maxwell arm in parallel (relaxation_branch), in other parameters."""

    id: ClassVar[str] = "test_retardation_branch"
    shows_in: ClassVar[tuple[str, ...]] = ("keep",)
    stiffness: float = 1.0e5
    viscosity: float = 5.0e5

    def material(self, element):
        from rheo_ros.models.elements import Series, voigt

        names = (f"{self.id}.stiffness", f"{self.id}.viscosity")
        return Series((element, voigt(self.stiffness, self.viscosity, names)))


def test_two_effects_that_explain_the_data_equally_are_left_undecided(tmp_path):
    register_effect(RetardationBranch)
    try:
        bag = make_bag(tmp_path, "run", 12, {"relaxation_branch": {"stiffness": 1.0e4, "viscosity": 3.0e4}})
        result = rheo_ros.analyze(bag, candidates=[RetardationBranch.id, "relaxation_branch"])
    finally:
        unregister_effect(RetardationBranch.id)
    d = result.to_json()["diagnosis"]
    assert d["missing_effect"] is None and not d["adequate"], d["evidence"]
    assert set(d["undecided"]) == {RetardationBranch.id, "relaxation_branch"}
    assert "The data cannot decide" in d["evidence"] and "To decide, record" in d["evidence"]
    bic = {c["effect"]: c["delta_bic"] for c in d["candidates"]}
    assert abs(bic[RetardationBranch.id] - bic["relaxation_branch"]) < 10


def test_when_no_candidate_explains_the_misfit_the_verdict_says_so():
    """The strain-stiffening reference bag diagnosed with only adhesion and sensor drift to
    try: the base model misfits, neither effect earns its parameters, and the verdict
    names no effect, calls the model inadequate and says that no effect in the catalogue
    explains the misfit (rather than claiming the nearest one)."""
    from conftest import BAGS

    report = rheo_ros.analyze(BAGS / "effect_strain_stiffening", candidates=["adhesion", "sensor_drift"]).to_json()
    d = report["diagnosis"]
    assert d["missing_effect"] is None and d["missing_effects"] == [] and not d["adequate"], d["evidence"]
    assert d["adequate_model"] is None and [m["effects"] for m in report["models"]] == [[]]
    assert "no effect in the catalogue explains it" in d["evidence"], d["evidence"]
    assert {c["effect"] for c in d["candidates"]} == {"adhesion", "sensor_drift"}
