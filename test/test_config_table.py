"""The parameters table (rheo_ros.config.table) is the one place for names, defaults,
help and per-value checks: config/rheo_ros.yaml, the tuning dataclasses and the stage
profile are held to it, and a value that cannot work is refused naming it."""

from __future__ import annotations

import math
from dataclasses import fields, replace
from pathlib import Path

import pytest
import yaml

from rheo_ros.config.setup import DEFAULTS, PARAM_HELP, ParamsError, Setup, check_params, flatten, parse_params
from rheo_ros.config.table import MAX_REFINE, PARAMETERS, default
from rheo_ros.config.tuning import EstimatorConfig, SegmenterConfig
from rheo_ros.experiment import StageProfile

CONFIG = Path(__file__).resolve().parents[1] / "config" / "rheo_ros.yaml"
NAMES = [p.name for p in PARAMETERS]
FLOATS = [p.name for p in PARAMETERS if isinstance(p.default, float)]


def params_text(body: str) -> str:
    return "/**:\n  ros__parameters:\n" + "".join(f"    {line}\n" for line in body.splitlines())


def test_the_config_file_sets_every_table_name_in_order_and_nothing_else():
    text = CONFIG.read_text()
    in_file = list(flatten(yaml.safe_load(text)["/**"]["ros__parameters"]))
    assert in_file == NAMES
    # Read as ROS reads it (3.33e4 a float): every value the table's default, of its type.
    values = parse_params(text, str(CONFIG))
    assert {n: (values[n], type(values[n])) for n in NAMES} == {p.name: (p.default, type(p.default))
                                                                for p in PARAMETERS}


def test_the_public_tables_are_the_table():
    assert len(set(NAMES)) == len(NAMES)
    assert DEFAULTS == {p.name: p.default for p in PARAMETERS} and list(DEFAULTS) == NAMES
    assert PARAM_HELP == {p.name: p.help for p in PARAMETERS} and all(PARAM_HELP.values())


def test_every_default_passes_its_own_check():
    assert [p.name for p in PARAMETERS if p.refusal(p.default)] == []


def test_the_tuning_dataclasses_are_the_tables_rows():
    """Field x of each is the parameter <prefix>.x, defaults included; the estimator's
    diagnostics_period and closed_form_priority are the node's alone."""
    for cls, prefix, node_only in ((SegmenterConfig, "segmenter", set()),
                                   (EstimatorConfig, "estimator", {"estimator.diagnostics_period",
                                                                   "estimator.closed_form_priority"})):
        assert {f"{prefix}.{f.name}" for f in fields(cls)} | node_only == {n for n in NAMES if n.startswith(prefix)}
        assert {f.name: f.default for f in fields(cls)} == {f.name: default(f"{prefix}.{f.name}") for f in fields(cls)}
    setup = Setup(dict(DEFAULTS))
    assert setup.segmenter_config() == SegmenterConfig() and setup.estimator_config() == EstimatorConfig()


def test_stage_profile_defaults_are_the_papers_instant_release():
    """experiment.py is below the config layer and cannot read the table: its defaults
    are the paper's idealised experiment, which the noise-free benches and tests build
    with StageProfile(). They differ from the table in retract_speed alone: the paper's
    stage leaves at once (inf), the package's default stage really moves (0.02 m/s)."""
    ours = {f.name: f.default for f in fields(StageProfile) if f.name != "before"}   # stage.pushes makes it
    table = {name: default(f"stage.{name}") for name in ours}
    assert {k for k in ours if ours[k] != table[k]} == {"retract_speed"}
    assert math.isinf(ours["retract_speed"]) and table["retract_speed"] == 0.02
    assert Setup(dict(DEFAULTS)).profile == replace(StageProfile(), retract_speed=0.02)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("specimen: {height: .inf}", "p.yaml: specimen.height: inf; must be finite"),
        ("stage: {depth: .nan}", "p.yaml: stage.depth: nan; must be finite"),
        ("stage: {keep_time: .inf}", "p.yaml: stage.keep_time: inf; must be finite"),
        ("material: {E: -.inf}", "p.yaml: material.E: -inf; must be finite"),
        ("stage: {retract_speed: .nan}", "p.yaml: stage.retract_speed: nan; must be positive (.inf: at once)"),
        ("stage: {retract_speed: 0.0}", "p.yaml: stage.retract_speed: 0.0; must be positive (.inf: at once)"),
        ("mesh: {refine: 100000}", f"p.yaml: mesh.refine: 100000 splits per element; must be at most {MAX_REFINE}"),
        ("simulator: {refine: 65}", f"p.yaml: simulator.refine: 65 splits per element; must be at most {MAX_REFINE}"),
        ("mesh: {refine: 0}", "p.yaml: mesh.refine: 0 splits per element; must be at least 1"),
        ("rates: {markers: 0.0}", "p.yaml: rates.markers: 0.0; must be positive"),
        ("material: {density: -1500.0}", "p.yaml: material.density: -1500.0; must be positive"),
        ("simulator: {seed: -1}", "p.yaml: simulator.seed: -1; must not be negative"),
        ("tactile: {noise: -100.0}", "p.yaml: tactile.noise: -100.0; must not be negative"),
        ("estimator: {release_interval: -1.0}", "p.yaml: estimator.release_interval: -1.0; must not be negative"),
    ],
)
def test_a_value_that_cannot_work_is_refused_in_one_line_naming_it(body, message):
    with pytest.raises(ParamsError) as err:
        parse_params(params_text(body), "p.yaml")
    assert str(err.value) == message


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_every_float_but_the_retract_speed_must_be_finite(value):
    """NaN or inf in any float parameter is refused before anything is built, the
    effects' included (their rows are checked whether an effect is listed or not)."""
    for name in FLOATS:
        if name == "stage.retract_speed" and value == math.inf:
            continue
        with pytest.raises(ParamsError) as err:
            check_params({name: value}, "p.yaml")
        assert str(err.value).startswith(f"p.yaml: {name}: {value}; must be"), name


def test_an_instant_release_and_the_largest_refinement_are_accepted():
    params = check_params({"stage.retract_speed": math.inf, "mesh.refine": MAX_REFINE,
                           "simulator.refine": MAX_REFINE}, "p.yaml")
    assert math.isinf(Setup(params).profile.retract_speed)


def test_a_file_with_the_old_name_estimator_refine_still_reads():
    params = parse_params(params_text("estimator: {refine: false}"), "p.yaml")
    assert params["estimator.fit"] is False and "estimator.refine" not in params
