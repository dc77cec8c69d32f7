"""Set-ups that cannot work are refused when the parameters are checked, in one line
naming the field: by check_params (the CLI) and by the nodes alike."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rheo_ros.config.setup import ParamsError, check_params, parse_params
from rheo_ros.sensors import TactileArray

REPO = Path(__file__).resolve().parents[1]
# The children run this checkout's code, whatever the virtualenv has installed.
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))


UNIAXIAL_BONDED = ("with geometry uniaxial, the block in uniaxial stress with both faces frictionless; "
                   "use geometry plane_fe for a bonded face")


def params_text(body: str) -> str:
    return "/**:\n  ros__parameters:\n" + "".join(f"    {line}\n" for line in body.splitlines())


def params_file(tmp_path: Path, body: str) -> Path:
    f = tmp_path / "p.yaml"
    f.write_text(params_text(body))
    return f


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("tactile: {rows: 0}", "p.yaml: tactile.rows: 0 cells; must be at least 1"),
        ("tactile: {cols: 0}", "p.yaml: tactile.cols: 0 cells; must be at least 1"),
        ("tactile: {cols: 4}",
         "p.yaml: tactile.cols: 4 columns for 5 segments (one per bottom marker, markers.cols); must be at least 5"),
        ("markers: {cols: 9}\ntactile: {cols: 8}",
         "p.yaml: tactile.cols: 8 columns for 9 segments (one per bottom marker, markers.cols); must be at least 9"),
        ("stage: {depth: 0.08}",
         "p.yaml: stage.depth: 0.08 m is not less than specimen.height (0.08 m): the stage cannot push through "
         "the specimen"),
        ("markers: {rows: 1}", "p.yaml: markers.rows: 1 markers; must be at least 2"),
        ("markers: {cols: 1}", "p.yaml: markers.cols: 1 markers; must be at least 2"),
        ("stage: {dept: 0.01}", "p.yaml: unknown parameter(s): stage.dept"),
        ("geometry: uniaxial\nboundary: {bottom: bonded}", f"p.yaml: boundary.bottom: 'bonded' {UNIAXIAL_BONDED}"),
        ("geometry: uniaxial\nboundary: {top: bonded, bottom: frictionless}",
         f"p.yaml: boundary.top: 'bonded' {UNIAXIAL_BONDED}"),
        ("geometry: uniaxial\nmarkers: {cols: 1}\ntactile: {cols: 1}", "p.yaml: markers.cols: 1 markers; must be at least 2"),
        ("simulator: {effects: [strain_stiffening]}\n"
         "effects: {strain_stiffening: {coefficient: 2.0, form: voigt_exponential}}",
         "p.yaml: effects.strain_stiffening.form: 'voigt_exponential' makes the Voigt spring nonlinear; "
         "the FE simulator's material is linear (the analysis fits this form)"),
    ],
    ids=["tactile-rows-0", "tactile-cols-0", "fewer-columns-than-segments", "fewer-columns-than-markers-cols",
         "depth-at-height", "one-marker-row", "one-marker-column", "unknown-name", "uniaxial-bonded-bottom",
         "uniaxial-bonded-top", "uniaxial-one-marker-column", "nonlinear-spring-in-the-simulator"],
)
def test_bad_setup_is_refused_in_one_line_naming_the_field(body, message):
    with pytest.raises(ParamsError) as err:
        parse_params(params_text(body), "p.yaml")
    assert str(err.value) == message


def test_a_segment_without_a_column_is_refused_even_with_enough_columns(monkeypatch):
    """The nearest-node split gives every segment a column once cols >= nodes; the check
    guards the rule itself, so the split is replaced by one that leaves P3 empty."""
    monkeypatch.setattr(TactileArray, "segment", property(lambda self: np.array([0, 0, 1, 1, 1, 1, 3, 3, 4, 4])))
    with pytest.raises(ParamsError) as err:
        check_params({"tactile.cols": 10}, "p.yaml")
    assert str(err.value) == ("p.yaml: tactile.cols: 10 columns leave segment(s) P3 without a column; "
                              "each of the 5 segments needs one")


@pytest.mark.parametrize("given", [{"tactile.cols": 5}, {"stage.depth": 0.079},
                                   {"geometry": "uniaxial", "markers.cols": 2, "tactile.cols": 2},
                                   {"geometry": "uniaxial", "boundary.bottom": "frictionless"}])
def test_edge_setups_that_can_work_are_accepted(given):
    check_params(given, "p.yaml")


def test_simulate_with_no_tactile_rows_exits_2_in_one_line(tmp_path):
    f = params_file(tmp_path, "tactile: {rows: 0}")
    run = subprocess.run([sys.executable, "-m", "rheo_ros", "simulate", "--params-file", str(f),
                          "--out", str(tmp_path / "bag")], env=ENV, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert run.stderr == f"rheo: error: {f}: tactile.rows: 0 cells; must be at least 1\n"
    assert not (tmp_path / "bag").exists()


def node_env() -> dict:
    """Localhost only, a domain of its own: 232, the highest Fast DDS takes (233 and up
    overflow its port numbers). The node stops before it talks to anyone, so sharing
    the domain with another test's graph is harmless."""
    return dict(ENV, ROS_DOMAIN_ID="232", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")


@pytest.mark.parametrize(
    ("node", "body", "message"),
    [
        *[(node, "stage: {dept: 0.01}\nuse_sim_time: true\neffects.adhesion.fraction: 0.2",
           "unknown parameter(s): stage.dept") for node in ("segmenter", "stage", "simulator", "estimator")],
        ("simulator", "tactile: {rows: 0}", "tactile.rows: 0 cells; must be at least 1"),
        ("estimator", "geometry: uniaxial\nboundary: {bottom: bonded}", f"boundary.bottom: 'bonded' {UNIAXIAL_BONDED}"),
    ],
    ids=["unknown-segmenter", "unknown-stage", "unknown-simulator", "unknown-estimator", "simulator-tactile-rows-0",
         "estimator-uniaxial-bonded"],
)
def test_node_refuses_bad_parameters_at_start_in_one_line(tmp_path, node, body, message):
    """ROS's own use_sim_time and the open effects.* namespace pass; only the bad name
    is named, in check_params' words."""
    f = params_file(tmp_path, body)
    run = subprocess.run([sys.executable, "-m", "rheo_ros", "run", node, "--ros-args", "--params-file", str(f)],
                         env=node_env(), capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stderr
    assert run.stderr == f"{node}: error: node {node}: {message}\n"
    assert "ready" not in run.stdout


def test_uniaxial_faces_are_frictionless_unless_set():
    """check_params fills the uniaxial block's faces in (the defaults say bonded, for plane_fe)."""
    params = check_params({"geometry": "uniaxial"}, "p.yaml")
    assert params["boundary.bottom"] == params["boundary.top"] == "frictionless"
    assert check_params({}, "p.yaml")["boundary.bottom"] == "bonded"


def test_a_node_checks_only_the_parameters_set_and_serves_what_it_runs_with():
    """A node given geometry uniaxial alone runs with frictionless faces (the table's
    bonded default, declared before the check, would be refused), and its parameter
    services serve those values: what `rheo record` stores in a bag."""
    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from rheo_ros.nodes.common import NODE_OPTIONS, declare_all

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = Node("uniaxial_check", context=context, parameter_overrides=[Parameter("geometry", value="uniaxial")],
                    **NODE_OPTIONS)
        params = declare_all(node)
        assert params["boundary.bottom"] == params["boundary.top"] == "frictionless"
        assert node.get_parameter("boundary.top").value == "frictionless"
        assert node.get_parameter("markers.cols").value == 5
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
