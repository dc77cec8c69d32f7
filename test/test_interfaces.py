"""The ROS interface package rheo_ros_interfaces, as built into the venv by
tools/build_interfaces.sh (./tasks venv): generated types, real DDS across
processes (topic and action), and CDR compatibility with rosbags."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rheo_ros_interfaces.action import Identify
from rheo_ros_interfaces.msg import Diagnosis, Estimate, ObjectHint, Phase, Pool
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

PKG = Path(__file__).resolve().parent.parent / "interfaces" / "rheo_ros_interfaces"
NAN = float("nan")
TIMEOUT = 10.0  # s, for each wait on another process


# --- the .msg / .action files, parsed --------------------------------------

_PRIMITIVES = {"float64": "double", "float32": "float", "bool": "boolean", "byte": "octet", "char": "uint8"}


def _idl_type(msg_type: str) -> str:
    """A .msg field type as rclpy's get_fields_and_field_types() spells it."""
    seq = msg_type.endswith("[]")
    base = msg_type[:-2] if seq else msg_type
    base = _PRIMITIVES.get(base, base)
    if "/" not in base and base not in _PRIMITIVES.values() and not re.fullmatch(r"u?int\d+|string", base):
        base = f"rheo_ros_interfaces/{base}"  # a type of this package, named without the package
    return f"sequence<{base}>" if seq else base


def _fields(text: str) -> dict:
    """Field name -> type of one .msg section, in order (comments and blank lines dropped)."""
    fields = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            msg_type, name = line.split()[:2]
            fields[name] = _idl_type(msg_type)
    return fields


@pytest.mark.parametrize("msg_type", [Estimate, Phase, Diagnosis, ObjectHint, Pool], ids=lambda t: t.__name__)
def test_message_fields_are_those_of_the_msg_file(msg_type):
    expected = _fields((PKG / "msg" / f"{msg_type.__name__}.msg").read_text())
    assert list(msg_type.get_fields_and_field_types().items()) == list(expected.items())


def test_action_fields_are_those_of_the_action_file():
    goal, result, feedback = (PKG / "action" / "Identify.action").read_text().split("---")
    for part, text in ((Identify.Goal, goal), (Identify.Result, result), (Identify.Feedback, feedback)):
        assert list(part.get_fields_and_field_types().items()) == list(_fields(text).items()), part


# --- a sample Estimate ------------------------------------------------------

def _estimate() -> Estimate:
    m = Estimate()
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 12, 345_000_000, "stage"
    m.experiment, m.phase, m.model = 2, "keep", "three_element+adhesion"
    m.effects, m.method = ["adhesion"], "paper_keep"
    m.equations = ["(7)", "(9)"]
    m.names = ["E", "c1", "c2", "gamma"]
    m.values = [1.25e5, 3.5, NAN, -0.0]
    cov = np.full((4, 4), NAN)
    cov[:2, :2] = [[4.0e6, 1.5], [1.5, 0.25]]
    cov[3, 3] = 1e-300
    m.covariance = cov.ravel().tolist()
    m.rmse_force, m.samples = 0.0123, 4321
    m.undetermined, m.reasons = ["c2"], ["needs the release phase (experiment 2)"]
    m.message = "ünïcödé ok"
    return m


def _as_plain(m: Estimate) -> dict:
    """Every field of an Estimate as JSON-able Python values (NaN kept)."""
    out = {}
    for name in m.get_fields_and_field_types():
        v = getattr(m, name)
        if name == "header":
            v = [v.stamp.sec, v.stamp.nanosec, v.frame_id]
        elif not isinstance(v, (str, int, float)):
            v = list(v)
        out[name] = v
    return out


def _assert_same(got: dict, want: dict):
    assert got.keys() == want.keys()
    for k in want:
        if k in ("values", "covariance", "rmse_force"):
            np.testing.assert_array_equal(np.asarray(got[k], float), np.asarray(want[k], float), err_msg=k)
        else:
            assert got[k] == want[k], k


def _ros_env(slot: int) -> dict:
    """Own DDS domain on localhost only. test_nodes.py uses 1-200; these are 201-232."""
    domain = 201 + (os.getpid() % 16) * 2 + slot
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")


class _Graph:
    """This process's side of a two-process ROS graph: a private rclpy context in the
    test's domain, and the other process, stopped (SIGINT, then kill) on exit."""

    def __init__(self, slot: int, child_code: str, monkeypatch):
        self.env = _ros_env(slot)
        monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(self.env["ROS_DOMAIN_ID"]))
        self.node = rclpy.create_node("test_interfaces", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.child = subprocess.Popen([sys.executable, "-c", child_code], env=self.env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def until(self, condition, what: str, spin: bool = False):
        deadline = time.monotonic() + TIMEOUT
        while not condition():
            if self.child.poll() is not None:
                pytest.fail(f"other process exited while waiting for {what}: {self.child.stderr.read()[-2000:]}")
            if time.monotonic() > deadline:
                pytest.fail(f"timed out waiting for {what}")
            if spin:
                self.executor.spin_once(timeout_sec=0.05)
            else:
                time.sleep(0.02)

    def close(self):
        if self.child.poll() is None:
            self.child.send_signal(signal.SIGINT)
            try:
                self.child.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.child.kill()
                self.child.wait()
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


# --- topic across processes ----------------------------------------------------

LISTENER = r"""
import json, sys, time
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rheo_ros_interfaces.msg import Estimate
rclpy.init()
node = rclpy.create_node("estimate_listener")
qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
got = []
node.create_subscription(Estimate, "/test_interfaces/estimate", got.append, qos)
deadline = time.monotonic() + 15
while not got and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
if not got:
    sys.exit("no message")
m = got[0]
out = {}
for name in m.get_fields_and_field_types():
    v = getattr(m, name)
    out[name] = [v.stamp.sec, v.stamp.nanosec, v.frame_id] if name == "header" else (
        v if isinstance(v, (str, int, float)) else list(v))
print(json.dumps(out), flush=True)
"""


def test_estimate_crosses_processes(monkeypatch):
    sent = _estimate()
    g = _Graph(0, LISTENER, monkeypatch)
    try:
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        pub = g.node.create_publisher(Estimate, "/test_interfaces/estimate", qos)
        g.until(lambda: pub.get_subscription_count() >= 1, "the listener's subscription to match")
        pub.publish(sent)
        out, err = g.child.communicate(timeout=TIMEOUT)
        assert g.child.returncode == 0, err[-2000:]
        _assert_same(json.loads(out), _as_plain(sent))
    finally:
        g.close()


# --- action across processes ----------------------------------------------------

SERVER = r"""
import rclpy
from rclpy.action import ActionServer
from rclpy.executors import ExternalShutdownException
from rheo_ros_interfaces.action import Identify
from rheo_ros_interfaces.msg import Estimate

def execute(goal_handle):
    g = goal_handle.request
    fb = Identify.Feedback(phase="pull")
    fb.estimate = Estimate(phase="pull", names=["E"], values=[g.depth * 1e6])
    goal_handle.publish_feedback(fb)
    goal_handle.succeed()
    est = Estimate(phase="release", names=["depth", "velocity", "keep_time", "c2"],
                   values=[g.depth, g.velocity, g.keep_time, float("nan")])
    return Identify.Result(success=True, message="identified", estimate=est)

rclpy.init()
node = rclpy.create_node("identify_server")
server = ActionServer(node, Identify, "/test_interfaces/identify", execute)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


def test_identify_action_across_processes(monkeypatch):
    g = _Graph(1, SERVER, monkeypatch)
    try:
        client = ActionClient(g.node, Identify, "/test_interfaces/identify")
        g.until(client.server_is_ready, "the action server")
        feedback = []
        future = client.send_goal_async(Identify.Goal(depth=0.002, velocity=0.001, keep_time=1.5),
                                        feedback_callback=lambda msg: feedback.append(msg.feedback))
        g.until(future.done, "the goal to be accepted", spin=True)
        handle = future.result()
        assert handle.accepted
        result_future = handle.get_result_async()
        g.until(result_future.done, "the result", spin=True)
        result = result_future.result().result
        assert result.success and result.message == "identified"
        assert list(result.estimate.names) == ["depth", "velocity", "keep_time", "c2"]
        np.testing.assert_array_equal(result.estimate.values, [0.002, 0.001, 1.5, NAN])
        assert [f.phase for f in feedback] == ["pull"]
        assert feedback[0].estimate.values[0] == pytest.approx(2000.0)
        client.destroy()
    finally:
        g.close()


# --- CDR compatible with rosbags ----------------------------------------------

def test_rclpy_cdr_decodes_with_rosbags_from_the_msg_text():
    typestore = get_typestore(Stores.ROS2_KILTED)
    types = {}
    for name in ("Phase", "Estimate", "Diagnosis"):
        types.update(get_types_from_msg((PKG / "msg" / f"{name}.msg").read_text(),
                                        f"rheo_ros_interfaces/msg/{name}"))
    typestore.register(types)

    sent = _estimate()
    raw = serialize_message(sent)
    dec = typestore.deserialize_cdr(raw, "rheo_ros_interfaces/msg/Estimate")
    got = {name: getattr(dec, name) for name in sent.get_fields_and_field_types()}
    got["header"] = [dec.header.stamp.sec, dec.header.stamp.nanosec, dec.header.frame_id]
    got = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in got.items()}
    _assert_same(got, _as_plain(sent))
    # and back: rosbags' bytes are what rclpy reads
    again = deserialize_message(bytes(typestore.serialize_cdr(dec, "rheo_ros_interfaces/msg/Estimate")), Estimate)
    _assert_same(_as_plain(again), _as_plain(sent))

    phase = Phase(experiment=3, name="keep", samples=77)
    phase.start.sec, phase.end.sec, phase.end.nanosec = 1, 2, 500
    dec = typestore.deserialize_cdr(serialize_message(phase), "rheo_ros_interfaces/msg/Phase")
    assert (dec.experiment, dec.name, dec.samples) == (3, "keep", 77)
    assert (dec.start.sec, dec.end.sec, dec.end.nanosec) == (1, 2, 500)
    assert (dec.header.stamp.sec, dec.header.frame_id) == (0, "")


def test_a_diagnosis_sends_parameters_at_a_bound_with_no_std_and_where_the_model_still_misfits():
    """Issue 24 online: the last model's parameters at a bound go out with an infinite std
    and are listed (``at_bound``), as ``rheo analyze`` gives them a null std; ``leftover``
    says where the model with effects added still misfits (then the verdict is unexplained)."""
    from types import SimpleNamespace

    from rheo_ros.diagnosis.decision import Verdict
    from rheo_ros.io.messages import MessageTypes, diagnosis_message, read_diagnosis
    from rheo_ros.online.estimator import OnlineDiagnosis

    params = {"E": 3.3e4, "c1": 1.0e-6, "c2": 3e7, "gamma": 0.33, "adhesion.fraction": 0.1, "adhesion.time": 30.0}
    std = {"E": 20.0, "c1": 1e-12, "c2": 1e5, "gamma": 1e-3, "adhesion.fraction": 0.01, "adhesion.time": 1.0}
    models = [SimpleNamespace(name=n, estimate=SimpleNamespace(params=params, std=std), forms={}, rmse_force=0.1,
                              bic=1.0) for n in ("three_element", "three_element+adhesion")]
    verdict = Verdict(adequate=True, missing_effects=(), undecided=(), candidates=(), evidence="e", explained=False,
                      closest=("adhesion",), leftover=("markers in the release (45 sd)",))
    d = OnlineDiagnosis.of(4, 12.5, models, verdict, bound=("c1", "adhesion.time"))
    got = read_diagnosis(diagnosis_message(MessageTypes.rclpy(), d))
    assert got["at_bound"] == ["c1", "adhesion.time"] and got["leftover"] == ["markers in the release (45 sd)"]
    assert got["std"]["c1"] == got["std"]["adhesion.time"] == np.inf
    assert got["std"]["E"] == 20.0 and got["std"]["adhesion.fraction"] == 0.01
    assert got["verdict"] == "unexplained" and got["undetermined"] == ["c1"]


def test_a_diagnosis_that_could_not_run_is_sent_with_why_and_the_action_does_not_trust_blindly():
    """A push's diagnosis that failed (or was skipped for a newer push's) is published all
    the same, verdict not_diagnosed and the reason in evidence, so that an identify goal
    waiting for it ends at once instead of at its timeout (seen in CI: over 300 s)."""
    from rheo_ros.io.messages import MessageTypes, diagnosis_message, read_diagnosis
    from rheo_ros.online.estimator import OnlineDiagnosis, trusted

    d = OnlineDiagnosis.not_run(3, 40.5, "the diagnosis failed: experiment 3 release: E not determined")
    got = read_diagnosis(diagnosis_message(MessageTypes.rclpy(), d))
    assert (got["experiment"], got["verdict"], got["model"], got["models"], got["params"]) == (
        3, "not_diagnosed", "", {}, {})
    assert got["evidence"] == "not diagnosed: the diagnosis failed: experiment 3 release: E not determined"
    assert trusted("not_diagnosed", ["E"]) == (False, "the data do not determine E")
    assert trusted("not_diagnosed", []) == (True, "identified (not diagnosed: the parameters decide)")
