"""One pipeline: what the estimator node computes for a bag (``estimate_bag``, the node's
core offline; ``test_online_nodes.py`` holds the node over DDS to it) is what ``rheo
analyze`` reports, on every reference bag and on bags whose release is cut short."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import BAGS
from generator import Profile, generate

from rheo_ros.app.analyze import analyze, estimate_bag
from rheo_ros.app.simulate import simulate_to_bag
from rheo_ros.config.setup import Setup, load_params
from rheo_ros.identification.estimate import BASE_PARAMETERS
from rheo_ros.io.bag import read_params
from rheo_ros.online.estimator import OnlineDiagnosis

REFERENCE = sorted(p.name for p in BAGS.iterdir() if (p / "metadata.yaml").is_file())
# The node's final estimate and the analysis' base model are one computation: equal to
# rounding (1e-9 relative), whatever the machine.
SAME = 1e-9


def final_update(bag: Path, diagnoses: list[OnlineDiagnosis] | None = None, interim: bool = True):
    """The node's updates on ``bag`` and its final estimate; ``interim=False``: without the
    interim release updates (they do not enter the final estimate, and cost a fit each)."""
    params = read_params(bag)
    if not interim:
        params = {**params, "estimator.release_interval": 0.0}
    phases, updates, errors = estimate_bag(str(bag), params=params, diagnoses=diagnoses)
    assert errors == []
    finals = [u for u in updates if u.final]
    assert len(finals) == 1 and finals[0] is updates[-1]
    return phases, updates, finals[0]


def assert_same_estimate(update, model_json) -> None:
    for name in BASE_PARAMETERS:
        value = update.params[name]
        fitted = model_json["params"][name]
        if np.isnan(value):   # not determined: the node says so, the analysis reports its raw value
            continue
        assert value == pytest.approx(fitted, rel=SAME), name
        assert update.std[name] == pytest.approx(model_json["std"][name], rel=1e-6), name


@pytest.mark.parametrize("name", REFERENCE)
def test_the_node_and_rheo_analyze_give_the_same_final_estimate(name):
    bag = BAGS / name
    _, _, final = final_update(bag, interim=False)
    report = analyze(bag, discover_effects=False).to_json()
    base = report["models"][0]
    assert final.method == "whole_record" and base["name"] == "three_element"
    assert_same_estimate(final, base)
    assert final.rmse_force == pytest.approx(base["rmse_force"], rel=1e-6)


def test_with_no_closed_form_the_fit_starts_from_a_search_online_as_offline(monkeypatch):
    """Where no closed form of a phase has a solution (data the three-element model reads
    badly), the node and rheo analyze both fit from a search over the relaxation times
    (``pipeline.searched_starts``): the same final estimate, the closed form reported as
    none with why, and on a clean bag (clean_short_keep, the package's simulator) the same
    fit as from the closed form's starts, within 0.1 std (measured: within 2e-5 std)."""
    import rheo_ros.identification.pipeline as pl
    from rheo_ros.record import RecordError

    bag = BAGS / "clean_short_keep"
    usual = analyze(bag, discover_effects=False).to_json()["models"][0]

    def no_solution(record, forward=None, nodes=None):
        raise RecordError("no solution here")

    for phase in ("pull", "keep", "release"):
        monkeypatch.setitem(pl.CLOSED_FORMS, phase, (("the only one", no_solution),))
    report = analyze(bag, discover_effects=False).to_json()
    assert report["estimate"]["method"] == "none" and report["estimate"]["E"] is None
    assert any("no closed form has a solution (the only one: no solution here); the fit started from a search "
               "over the relaxation times" in w for w in report["warnings"]), report["warnings"]
    base = report["models"][0]
    for name in BASE_PARAMETERS:
        assert abs(base["params"][name] - usual["params"][name]) < 0.1 * usual["std"][name], name
    _, updates, final = final_update(bag, interim=False)
    assert_same_estimate(final, base)
    assert "no closed form has a solution: the fit started from a search" in final.message
    assert not any(u.method != "whole_record" for u in updates)   # no closed form published


@pytest.fixture(scope="module")
def cut_short(tmp_path_factory):
    """The default experiment recorded 5 or 20 s past the let-go (the markers still move:
    the specimen recovers for ~30 s), clean, and 20 s with a hidden relaxation branch; on
    the 49 x 49-node simulator mesh (still finer than the identification's 33 x 33)."""
    out = {}
    for release, effect in ((5.0, ""), (20.0, ""), (20.0, "relaxation_branch")):
        params = {**load_params(None), "stage.release_time": release, "simulator.effects": [effect],
                  "simulator.refine": 12}
        path = tmp_path_factory.mktemp("cut") / "bag"
        simulate_to_bag(Setup(params), 5, path)
        out[(release, effect)] = path
    return out


@pytest.mark.parametrize("release", [5.0, 20.0])
def test_a_release_cut_short_still_ends_with_a_final_estimate_that_says_so(cut_short, release):
    """The data stop while the specimen recovers: the release closes at the last frame,
    the final estimate and the analysis agree, both warn, and interim release updates
    came every ``estimator.release_interval`` s of data before."""
    bag = cut_short[(release, "")]
    phases, updates, final = final_update(bag)
    assert [p.name for p in phases if p.name != "contact"] == ["pull", "keep", "release"]
    release_phase = phases[-1]
    assert release_phase.t_end - release_phase.t_start == pytest.approx(release, abs=0.15)
    assert "cut short" in final.message and "the data stopped" in final.message
    interim = [u for u in updates if u.interim]
    # release_interval 10 s: an interim (closed form and fit) each time the data reach 10 s
    # more of the release, whether or not they stop there: at 10 and 20 s of a 20 s
    # release (the node cannot know the data stop), none in 5 s.
    interval = read_params(bag)["estimator.release_interval"]
    due = np.arange(release_phase.t_start + interval, release_phase.t_end + 1e-6, interval)
    assert [(u.method, u.stamp) for u in interim] == [
        (m, pytest.approx(t, abs=0.02)) for t in due for m in ("paper_short_time", "whole_record")]
    assert all("interim" in u.message for u in interim if u.method == "whole_record")
    report = analyze(bag, discover_effects=False).to_json()
    assert_same_estimate(final, report["models"][0])
    assert any("cut short" in w for w in report["warnings"])
    # The clean specimen's truth within 4 std where the data determine it.
    for name in ("E", "c1", "c2"):
        if name not in final.undetermined:
            truth = Setup(load_params(None)).params[f"material.{name}"]
            assert abs(final.params[name] - truth) < 4 * final.std[name], (name, final.params[name], final.std[name])


def test_with_discovery_the_node_names_what_rheo_analyze_names_on_a_cut_short_release(cut_short):
    bag = cut_short[(20.0, "relaxation_branch")]
    diagnoses: list[OnlineDiagnosis] = []
    _, _, final = final_update(bag, diagnoses)
    assert len(diagnoses) == 1
    online = diagnoses[0]
    result = analyze(bag, workers=1)
    report = result.to_json()
    assert online.missing_effects == tuple(report["diagnosis"]["missing_effects"]) == ("relaxation_branch",)
    assert online.adequate == report["diagnosis"]["adequate"]
    assert "cut short" in online.evidence
    np.testing.assert_allclose(online.rmse_force, [m["rmse_force"] for m in report["models"]], rtol=1e-6)



def test_on_a_bag_the_package_did_not_make_the_node_diagnoses_what_rheo_analyze_does(tmp_path):
    """The independent generator (test/generator.py, seed 2, default-like sensor: 300 Pa
    dead band, 10 Pa steps) with its Voigt spring stiffening exponentially (k = 4), a
    short keep and release: the node reads the sensor from the images as the analysis
    does and names the same effect with the same numbers (measured: equal to the last
    digit; k 4.010, E 33281 Pa against 33300)."""
    bag = generate(tmp_path / "bag", effects="strain_stiffening", seed=2,
                   profile=Profile(depth=0.008, keep_time=8.0, release_time=15.0))
    diagnoses: list[OnlineDiagnosis] = []
    final_update(bag, diagnoses, interim=False)
    online = diagnoses[0]
    report = analyze(bag).to_json()   # the candidates in parallel: the same numbers (each fit is deterministic)
    assert online.missing_effects == tuple(report["diagnosis"]["missing_effects"]) == ("strain_stiffening",)
    assert online.adequate is report["diagnosis"]["adequate"] is True
    assert report["models"][-1]["forms"] == {"strain_stiffening": "voigt_exponential"}
    assert online.forms == ("voigt_exponential",) and "voigt_exponential form" in online.evidence
    last = report["models"][-1]
    for name, value in zip(online.names, online.values):
        assert value == pytest.approx(last["params"][name], rel=SAME), name
    np.testing.assert_allclose(online.rmse_force, [m["rmse_force"] for m in report["models"]], rtol=SAME)
