"""Segmenter, estimator and the identify action over real DDS, in separate processes."""

import json
import math
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
from conftest import TRUTH, readme_block
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.action import ActionClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rheo_ros_interfaces.action import Identify
from rheo_ros_interfaces.msg import Diagnosis, Estimate, Phase
from sensor_msgs.msg import Image

from rheo_ros.app.analyze import analyze, estimate_bag
from rheo_ros.app.simulate import simulate_to_bag
from rheo_ros.config.setup import Setup, load_params, params_yaml
from rheo_ros.io.messages import read_diagnosis, read_estimate, read_pool

BIN = Path(sys.executable).parent
SHORT_RUN = {"stage.depth": 0.004, "stage.velocity": 0.001, "stage.keep_time": 6.0, "stage.release_time": 30.0}
LATCHED = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Graph:
    """Node processes of one test and an in-process probe node on their domain."""

    def __init__(self, env: dict[str, str], tmp: Path) -> None:
        self.env, self.tmp, self.procs = env, tmp, {}
        os.environ.update({k: self.env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("probe", context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def start(self, name: str, *args: str) -> subprocess.Popen:
        log = (self.tmp / f"{name}.log").open("w")
        self.procs[name] = subprocess.Popen([str(BIN / name), *args], env=self.env, stdout=log,
                                            stderr=subprocess.STDOUT)
        return self.procs[name]

    def spin_until(self, done, timeout: float, what) -> None:
        """Spin until done(); else fail with what (a text, or a function giving one) and the logs."""
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() > deadline:
                logs = " | ".join(f"{p.name}: {p.read_text()[-1500:]}" for p in self.tmp.glob("*.log"))
                pytest.fail(f"{what() if callable(what) else what} within {timeout} s; logs: {logs}")
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        running = [name for name, p in self.procs.items() if p.poll() is None]
        for name in running:
            self.procs[name].send_signal(signal.SIGINT)
        for p in self.procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
        # Never a traceback, the shutdown by Ctrl-C included (checked when the test itself
        # did not fail: its own error comes first).
        broken = {p.name: p.read_text()[-1500:] for p in self.tmp.glob("*.log") if "Traceback" in p.read_text()}
        if broken and sys.exc_info()[0] is None:
            pytest.fail(f"a traceback in {', '.join(broken)}: {broken}")
        # Ctrl-C ends a running node within 10 s with exit status 0 (-9: killed, it did not stop).
        codes = {name: self.procs[name].returncode for name in running}
        if any(codes.values()) and sys.exc_info()[0] is None:
            pytest.fail(f"nodes that did not exit cleanly on Ctrl-C: {codes}")


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("short")
    params = {**load_params(None), **SHORT_RUN}
    simulate_to_bag(Setup(params), 3, tmp / "bag")
    (tmp / "params.yaml").write_text(params_yaml(params))
    return tmp


@pytest.fixture(scope="module")
def replay(short_bag, tmp_path_factory, ros_env):
    """A bag replayed over DDS into the segmenter and estimator nodes, twice."""
    diagnoses = []
    offline = estimate_bag(str(short_bag / "bag"), diagnoses=diagnoses)
    runs = []
    for k in range(2):
        tmp = tmp_path_factory.mktemp(f"replay{k}")
        g = Graph(ros_env(), tmp)
        estimates, phases, verdicts = [], [], []
        g.node.create_subscription(Estimate, "/rheo/estimate", lambda m: estimates.append(read_estimate(m)), LATCHED)
        g.node.create_subscription(Diagnosis, "/rheo/diagnosis", lambda m: verdicts.append(read_diagnosis(m)),
                                   LATCHED)
        g.node.create_subscription(Phase, "/rheo/phase", phases.append, LATCHED)
        statuses = []
        g.node.create_subscription(DiagnosticArray, "/diagnostics",
                                   lambda m: statuses.extend(s for s in m.status if s.name.endswith("estimator")), 10)
        try:
            params = ["--ros-args", "--params-file", str(short_bag / "params.yaml")]
            g.start("estimator", *params)
            g.start("segmenter", *params)
            play = subprocess.run([str(BIN / "rheo"), "play", str(short_bag / "bag"), "--rate", "5",
                                   "--wait-for-subscribers", "2"], env=g.env, capture_output=True, text=True,
                                  timeout=120)
            assert play.returncode == 0, play.stderr
            # Every update first (the final is the last): a late subscriber that joined before
            # the last one would get two.
            g.spin_until(lambda: any(e["final"] for e in estimates) and len(phases) >= 4, 60,
                         lambda: f"the final estimate and 4 phases (got {len(estimates)} estimates, "
                                 f"{len(phases)} phases)")
            late = []
            late_node = rclpy.create_node("late", context=g.context)
            late_node.create_subscription(Estimate, "/rheo/estimate", late.append,
                                          QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                     durability=DurabilityPolicy.TRANSIENT_LOCAL))
            g.executor.add_node(late_node)
            g.spin_until(lambda: late, 10, "the last estimate for a late subscriber")
            g.spin_until(lambda: verdicts, 120, "the diagnosis after release")
            time.sleep(0.5)
            g.executor.spin_once(timeout_sec=0.1)
            g.spin_until(lambda: statuses and "tactile excess used Pa" in {v.key for v in statuses[-1].values}, 10,
                         "the sensor model on /diagnostics")
            runs.append({"estimates": estimates, "phases": phases, "late": late, "verdicts": verdicts,
                         "estimator_log": (tmp / "estimator.log").read_text(),
                         "figures": {v.key: v.value for v in statuses[-1].values}})
        finally:
            g.close()
    return runs, offline + (diagnoses,)


def test_replay_through_dds_gives_the_offline_estimates_every_run(replay):
    """Header stamps only: the same bag gives the offline core's numbers to 1e-9, twice.
    (The node publishes a phase's closed form as soon as it has it, so it may come
    before the previous phase's fit: each lane keeps its own order. A fit lane behind
    the data skips an interim fit once a later one of its release waits: every other
    update is published.)"""
    runs, (_, updates, errors, _) = replay
    assert errors == []

    def key(phase, method, stamp):   # interim release updates share phase and method
        return phase, method, round(stamp, 6)

    for run in runs:
        got = run["estimates"]
        by_key = {key(e["phase"], e["method"], e["stamp"]): e for e in got}
        published = [u for u in updates if key(u.phase, u.method, u.stamp) in by_key]
        assert len(by_key) == len(got) == len(published)
        skipped = [u for u in updates if key(u.phase, u.method, u.stamp) not in by_key]
        assert all(u.interim and u.method == "whole_record" for u in skipped), skipped
        for lane in (lambda m: m == "whole_record", lambda m: m != "whole_record"):
            assert ([key(e["phase"], e["method"], e["stamp"]) for e in got if lane(e["method"])]
                    == [key(u.phase, u.method, u.stamp) for u in published if lane(u.method)])
        assert got[-1]["final"] and updates[-1].final
        for u in published:
            e = by_key[key(u.phase, u.method, u.stamp)]
            a = np.array(list(e["params"].values()))
            np.testing.assert_array_equal(np.isnan(a), np.isnan(u.values))
            ok = ~np.isnan(a)
            np.testing.assert_allclose(a[ok], u.values[ok], rtol=1e-9)
            assert e["samples"] == u.samples and abs(e["stamp"] - u.stamp) < 1e-9
            assert e["undetermined"] == dict(zip(u.undetermined, u.reasons))
            if u.covariance is not None:
                np.testing.assert_allclose([e["std"][n] for n in u.names if np.isfinite(e["std"][n])],
                                           [u.std[n] for n in u.names if np.isfinite(u.std[n])], rtol=1e-6)


def test_segmenter_node_publishes_each_phase_as_the_core_finds_it(replay):
    runs, (phases, _, _, _) = replay
    for run in runs:
        got = [(p.experiment, p.name, round(p.start.sec + p.start.nanosec * 1e-9, 6)) for p in run["phases"]]
        assert got == [(e.experiment, e.name, round(e.t_start, 6)) for e in phases]


def test_a_late_subscriber_gets_the_last_estimate(replay):
    runs, (_, updates, _, _) = replay
    for run in runs:
        # DDS hands a depth-1 reader the writer's history as it comes: one, or a few
        # of the last 16 if the reader took one before the next arrived; the last is the latest.
        assert 1 <= len(run["late"]) <= 16
        last = read_estimate(run["late"][-1])
        assert (last["phase"], last["method"]) == (updates[-1].phase, updates[-1].method)


def test_the_estimator_publishes_the_offline_diagnosis_after_release(replay):
    """The model-discovery loop runs in the node after release: the same verdict, models
    and parameters as the offline core on the same bag (a clean run: adequate)."""
    runs, (_, _, _, diagnoses) = replay
    assert len(diagnoses) == 1
    d = diagnoses[0]
    assert d.adequate and d.missing_effects == () and d.models == ("three_element",)
    for run in runs:
        (got,) = run["verdicts"]
        assert got["adequate"] and got["missing_effects"] == [] and got["model"] == "three_element"
        assert list(got["candidates"]) == list(d.candidates)
        np.testing.assert_allclose(list(got["params"].values()), d.values, rtol=1e-9)
        np.testing.assert_allclose([v[1] for v in got["models"].values()], d.bic, rtol=1e-9)
        assert got["evidence"] == d.evidence and "is adequate" in got["evidence"]


def test_the_estimator_reports_the_sensor_it_read_on_diagnostics(replay):
    """/diagnostics carries the sensor model the last fit's record showed (the fit worker
    builds it, off the node's interpreter and the closed forms' latency): the package
    simulator's default array, a
    300 Pa dead band and 100 Pa of cell noise, whose mean reading exceeds a cell's pressure
    by at most 3.1 Pa (with the noise's doubt; README, Sensor)."""
    runs, _ = replay
    for run in runs:
        figures = run["figures"]
        assert figures["sensor"].startswith("dead band 300 Pa"), figures
        assert abs(float(figures["tactile noise Pa"]) - 100.0) < 10.0, figures   # 10 %: the noise's own spread
        assert 1.0 < float(figures["tactile excess used Pa"]) < 6.0, figures


def test_estimator_warns_on_a_missing_topic_and_survives_bad_messages(short_bag, tmp_path, ros_env):
    g = Graph(ros_env(), tmp_path)
    statuses = []
    g.node.create_subscription(DiagnosticArray, "/diagnostics",
                               lambda m: statuses.extend(s for s in m.status if s.name.endswith("estimator")), 10)
    bad = g.node.create_publisher(Image, "/tactile/pressure", 10)
    from sensor_msgs.msg import JointState
    stage_stamps = []
    g.node.create_subscription(JointState, "/stage/joint_states", lambda m: stage_stamps.append(m.header.stamp), 10)
    try:
        est = g.start("estimator", "--ros-args", "--params-file", str(short_bag / "params.yaml"),
                      "-p", "estimator.stale_after:=1.0")
        play = subprocess.Popen([str(BIN / "rheo"), "play", str(short_bag / "bag"), "--topics",
                                 "/stage/joint_states", "--wait-for-subscribers", "1"], env=g.env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        g.spin_until(lambda: any("no message on /tactile/pressure" in s.message for s in statuses), 30,
                     "a WARN naming the missing topic")
        assert any(s.level == DiagnosticStatus.WARN for s in statuses)
        g.spin_until(lambda: bad.get_subscription_count() > 0, 10, "the estimator subscribing")
        msg = Image(height=6, width=32, encoding="rgb8", step=96, data=bytes(6 * 96))
        for _ in range(3):
            bad.publish(msg)
        g.spin_until(lambda: any("bad message" in s.message and "encoding" in s.message for s in statuses), 20,
                     "a WARN on the bad messages")
        # A marker frame of NaN: a bad message (named), not one out of order.
        from geometry_msgs.msg import Pose, PoseArray
        nan_frame = PoseArray(poses=[Pose() for _ in range(25)])
        for pose in nan_frame.poses:
            pose.position.x = float("nan")
        markers = g.node.create_publisher(PoseArray, "/markers/mesh", 10)
        g.spin_until(lambda: markers.get_subscription_count() > 0, 10, "the estimator subscribing to markers")
        markers.publish(nan_frame)
        g.spin_until(lambda: any("/markers/mesh: non-finite values" in s.message for s in statuses), 20,
                     "a WARN naming the NaN marker frame")
        figures = {v.key: v.value for v in statuses[-1].values}
        assert (figures["bad /markers/mesh"], figures["out of order /markers/mesh"]) == ("1", "0"), figures
        # The markers in mm (a 4 x 4 cm grid read as metres) and a stage sample 10 s back
        # (a clock jump): refused, and named as rheo analyze names them (io.checks).
        # Each sent once a second until named: a reader that has not matched the probe's
        # new writer yet misses a message sent once (seen on a loaded machine).
        def until_named(send, pattern: str, what: str) -> int:
            sent = [0, -1.0]

            def named() -> bool:
                if any(re.search(pattern, s.message) for s in statuses):
                    return True
                if time.monotonic() - sent[1] > 1.0:
                    send()
                    sent[:] = [sent[0] + 1, time.monotonic()]
                return False

            g.spin_until(named, 20, what)
            return sent[0]

        mm = PoseArray(poses=[Pose() for _ in range(25)])
        for k, pose in enumerate(mm.poses):
            pose.position.x, pose.position.y = 10.0 * (k % 5), 10.0 * (k // 5)
        sent_mm = until_named(lambda: markers.publish(mm), re.escape(
            "/markers/mesh: the markers span 40 across, the specimen is 0.08 m wide: not in m (mm?)"),
            "a WARN naming the markers' units")
        g.spin_until(lambda: stage_stamps, 10, "stage samples")
        back = JointState(name=["stage"], position=[0.0], velocity=[0.0])
        back.header.stamp.sec, back.header.stamp.nanosec = stage_stamps[-1].sec - 10, stage_stamps[-1].nanosec
        stage = g.node.create_publisher(JointState, "/stage/joint_states", 10)
        g.spin_until(lambda: stage.get_subscription_count() > 1, 10, "the estimator subscribing to the stage")
        sent_back = until_named(lambda: stage.publish(back), r"/stage/joint_states: header stamps jump back "
                                r"\d+\.\d+ s at [\d.]+ s \(a clock jump", "a WARN naming the clock jump")
        figures = {v.key: v.value for v in statuses[-1].values}
        assert 2 <= int(figures["bad /markers/mesh"]) <= 1 + sent_mm, figures
        assert 1 <= int(figures["bad /stage/joint_states"]) <= sent_back, figures
        # Good stage samples go on flowing: 1 s (estimator.stale_after) after the last bad
        # message the WARN no longer names them; the counts stay.
        g.spin_until(lambda: "bad message" not in statuses[-1].message, 20, "the bad-message WARN cleared")
        figures = {v.key: v.value for v in statuses[-1].values}
        assert figures["bad /tactile/pressure"] == "3" and int(figures["bad /markers/mesh"]) >= 2, figures
        assert est.poll() is None, "the estimator died on a bad message"
        play.send_signal(signal.SIGINT)
        play.wait(timeout=10)
    finally:
        g.close()


def test_identify_action_runs_a_push_with_feedback_and_cancels_safely(tmp_path, ros_env):
    """Stage waiting for goals, simulator on /clock, estimator: a goal gives feedback per
    update and the final whole-record estimate, trusted and right; a second push by the
    README's client meets the set the first left, trusted and right; busy and bad goals are
    refused; a goal on a new object (the simulator's fresh block) is trusted, right and
    starts a pool of its own; a cancelled goal retracts the stage; the run's recording
    (with /rheo/object) through rheo analyze gives the node's estimates and pools."""
    # No interim fits of the releases (test_pipeline has them): the estimator's lane
    # spends itself on each push's final fit and diagnosis.
    params = {**load_params(None), **SHORT_RUN, "stage.autostart": False, "simulator.clock": True,
              "estimator.release_interval": 60.0}
    (tmp_path / "params.yaml").write_text(params_yaml(params))
    g = Graph(ros_env(), tmp_path)
    depths = []
    from sensor_msgs.msg import JointState

    g.node.create_subscription(JointState, "/stage/joint_states", lambda m: depths.append(m.position[0]), 100)
    client = ActionClient(g.node, Identify, "/rheo/identify")
    try:
        args = ["--ros-args", "--params-file", str(tmp_path / "params.yaml")]
        g.start("estimator", *args)
        g.start("simulator", *args)
        g.start("stage", *args, "-p", "use_sim_time:=true")
        # The run recorded as a user would, for rheo analyze at the end.
        # With the package's own outputs: their types are not in rosbags' store (issue 21).
        recorder = g.start("rheo", "record", "/stage/joint_states", "/tactile/pressure", "/markers/mesh",
                           "/rheo/object", "/rheo/estimate", "/rheo/diagnosis", "/rheo/pool", "/rheo/phase",
                           "--out", str(tmp_path / "recorded"), "--params-file", str(tmp_path / "params.yaml"),
                           # The simulator builds its 65 x 65 mesh first: 11 s seen on a loaded machine.
                           "--discovery-timeout", "60")
        g.spin_until(lambda: "recording 8 topic(s)" in (tmp_path / "rheo.log").read_text(), 90, "the recorder")
        g.spin_until(lambda: client.server_is_ready(), 30, "the identify action server")
        feedback = []
        goal = client.send_goal_async(Identify.Goal(), feedback_callback=feedback.append)
        g.spin_until(goal.done, 30, "goal accepted")
        handle = goal.result()
        assert handle.accepted
        # A goal while a run is in progress is rejected (the stage pushes one specimen at a time).
        busy = client.send_goal_async(Identify.Goal(depth=0.002))
        g.spin_until(busy.done, 30, "the busy goal answered")
        assert not busy.result().accepted
        result = handle.get_result_async()
        g.spin_until(result.done, 300, "the identification result")
        r = result.result().result
        assert r.success, r.message
        assert (r.estimate.phase, r.estimate.method, r.estimate.final) == ("release", "whole_record", True)
        phases = [f.feedback.phase for f in feedback]
        assert {"pull", "keep", "release"} <= set(phases)
        # Each lane (closed forms, fits) in phase order; a closed form may overtake a fit.
        for lane in (True, False):
            mine = [f.feedback.phase for f in feedback if (f.feedback.estimate.method == "whole_record") == lane]
            assert mine == sorted(mine, key=["pull", "keep", "release"].index)
        assert_trusted_and_right(r)
        first, first_estimate = r.estimate.experiment, r.estimate
        assert (list(r.pool.experiments), r.pool.started) == ([first], False)
        # A second push on the same specimen once the first has settled, by the README's client
        # as a process of its own: it meets the set the first left, and is trusted and right.
        run = subprocess.run([sys.executable, "-c", readme_client()], env=g.env, capture_output=True, text=True,
                             timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        second = json.loads(run.stdout.strip().splitlines()[-1])
        assert second["push"] == first + 1
        # The same object: pooled with the first push, the pooled std below the push's own.
        assert (second["pool"], second["new_pool"]) == ([first, first + 1], False)
        assert all(second["pooled_std"][k] < second["std"][k] for k in ("E", "c1"))
        assert (second["trust"], second["verdict"], second["missing"]) == (True, "adequate", []), second["why"]
        for k, v in TRUTH.items():
            if math.isfinite(second["std"][k]):   # c2 may be left open by a 6 s keep
                assert abs(second["values"][k] - v) < 4 * second["std"][k], (k, second["values"][k])
        # Bad goals are aborted with a line naming the value, and the stage never moves:
        # a push through the specimen, a NaN speed.
        height = params["specimen.height"]
        bad_goals = ((Identify.Goal(depth=height), "stage.depth"),
                     (Identify.Goal(velocity=float("nan")), "stage.velocity"))
        for bad, why in bad_goals:
            depths.clear()
            goal = client.send_goal_async(bad)
            g.spin_until(goal.done, 30, "bad goal answered")
            result = goal.result().get_result_async()
            g.spin_until(result.done, 30, "the bad goal's result")
            r = result.result().result
            assert not r.success and r.message.startswith("bad goal: goal: ") and why in r.message, r.message
            assert all(d == 0.0 for d in depths), depths
        # Then another object: the goal says so, the simulator puts a fresh block of the same
        # clay in place, and the push is modelled from rest (trusted and right) and starts a
        # pool.
        goal = client.send_goal_async(Identify.Goal(object="new"))
        g.spin_until(goal.done, 30, "the goal on a new object accepted")
        result = goal.result().get_result_async()
        g.spin_until(result.done, 300, "the result on the new object")
        third = result.result().result
        assert_trusted_and_right(third)
        assert third.estimate.experiment == first + 2
        assert (list(third.pool.experiments), third.pool.started, third.pool.stated) == ([first + 2], True, True)
        assert "a new block in place" in (tmp_path / "simulator.log").read_text()
        # A last goal, cancelled once the pull has been identified. (A push at once after a
        # cancel is not asserted here: the history model of a cancelled push is sometimes off,
        # issue 25's known limit in docs/PLAN.md.)
        feedback.clear()
        goal = client.send_goal_async(Identify.Goal(), feedback_callback=feedback.append)
        g.spin_until(goal.done, 30, "second goal answered")
        handle = goal.result()
        assert handle.accepted, "the first run should be over once it returned its estimate"
        g.spin_until(lambda: feedback, 60, "feedback after the pull")
        cancel = handle.cancel_goal_async()
        g.spin_until(cancel.done, 30, "cancel accepted")
        result = handle.get_result_async()
        g.spin_until(result.done, 60, "the cancelled result")
        assert not result.result().result.success and "retracted" in result.result().result.message
        # Samples published before the result may still be on their way: after it, the
        # stage only retracts (never pushes again) and ends at depth 0.
        depths.clear()
        g.spin_until(lambda: len(depths) > 5 and depths[-1] == 0.0, 30, "stage samples at depth 0 after the cancel")
        assert all(later <= earlier for earlier, later in zip(depths, depths[1:])), depths
        assert "cancelled" in (tmp_path / "stage.log").read_text()
        # The recording of the run through rheo analyze: four experiments, and the three full
        # pushes' final estimates are what the node published (one computation: to 1e-4 of
        # each parameter's std; the fit in the node's worker process and here differ in the
        # last bits - seen 1.7e-9 relative on c2, 3e-7 of its std); the hint was recorded,
        # so push 3 is a new object offline too, starting a pool of its own. A release the
        # node closed on silence (a simulator stalled on a loaded machine: seen in 2 runs of
        # 3 under the suite) is closed there offline too: the node said so on /rheo/phase.
        recorder.send_signal(signal.SIGINT)
        assert recorder.wait(timeout=30) == 0, (tmp_path / "rheo.log").read_text()[-1500:]
        report = analyze(tmp_path / "recorded", discover_effects=False, workers=1).to_json()
        # The package's outputs decode from the recording's own definitions, with mcap's
        # reader as with rosbags.
        assert_outputs_decode(tmp_path / "recorded", read_pool(third.pool))
        assert len(report["experiments"]) == 4
        assert [e["object"] for e in report["experiments"]] == ["", "", "new", ""]
        assert report["experiments"][2]["from_rest"]
        assert report["pools"][0]["experiments"] == [1, 2]
        assert any(c["experiment"] == 3 and c["stated"] for c in report["changes"]), report["changes"]
        pushes = ((1, read_estimate(first_estimate)), (2, {"params": second["values"], "std": second["std"]}),
                  (3, read_estimate(third.estimate)))
        for number, online in pushes:
            offline = report["experiments"][number - 1]["models"][0]["params"]
            for k, v in online["params"].items():
                if math.isfinite(online["std"][k]):
                    assert abs(v - offline[k]) <= 1e-4 * online["std"][k], (number, k, v, offline[k])
                else:
                    assert v == pytest.approx(offline[k], rel=1e-9, nan_ok=True), (number, k)
    finally:
        client.destroy()
        g.close()


def assert_outputs_decode(bag: Path, pool: dict) -> None:
    """The package's outputs in the recording decode with mcap's reader and with rosbags
    (from the bag's own definitions), and ``pool`` (a pushes' pool the action returned) is
    among the /rheo/pool messages, the same numbers in both."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    [mcap_file] = bag.glob("*.mcap")
    with mcap_file.open("rb") as fh:
        decoded = [(channel.topic, msg) for _, channel, _, msg in make_reader(
            fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/rheo/estimate", "/rheo/diagnosis", "/rheo/pool"])]
    topics = {t for t, _ in decoded}
    assert topics == {"/rheo/estimate", "/rheo/diagnosis", "/rheo/pool"}
    mine = [m for t, m in decoded if t == "/rheo/pool" and list(m.experiments) == pool["experiments"]]
    assert mine and mine[-1].stated
    with AnyReader([bag]) as reader:   # no default store: the bag's definitions alone
        conns = [c for c in reader.connections if c.topic == "/rheo/pool"]
        read = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    [same] = [m for m in read if list(m.experiments) == pool["experiments"]][-1:]
    assert np.allclose(same.values, list(pool["params"].values()), rtol=1e-12)
    assert np.allclose(mine[-1].values, same.values, rtol=0)


def readme_client() -> str:
    """The README's action client (the python block that makes an ActionClient for Identify)."""
    return readme_block("python", "ActionClient(node, Identify")


def assert_trusted_and_right(r) -> None:
    """The action's result on a clean push of the simulator (self-consistency): the
    diagnosis of the same push says adequate, the result trusts it, and every parameter the
    4 mm, 6 s push determines is within 4 of its std of the truth; c2 only if determined."""
    assert (r.estimate.phase, r.estimate.method, r.estimate.final) == ("release", "whole_record", True)
    assert r.diagnosis.experiment == r.estimate.experiment
    assert (r.verdict, r.success, list(r.missing_effects)) == ("adequate", True, []), (r.verdict, r.message)
    final = read_estimate(r.estimate)
    assert set(r.undetermined) == set(final["undetermined"]) <= {"c2"}
    for k, v in TRUTH.items():
        if k in final["undetermined"]:
            continue
        assert abs(final["params"][k] - v) < 4 * final["std"][k], (k, final["params"][k], final["std"][k])


def test_a_release_cut_short_by_silence_gets_its_final_estimate_and_diagnosis(tmp_path, ros_env):
    """A bag that stops 5 s after the let-go (the specimen still recovering), played into
    the segmenter and estimator, then silence: after ``estimator.stale_after`` both close
    the release, the final estimate (equal to the offline core's, which closes it at the
    end of the bag) and the diagnosis arrive, each with the cut-short warning."""
    params = {**load_params(None), **SHORT_RUN, "stage.release_time": 5.0, "estimator.stale_after": 1.0}
    simulate_to_bag(Setup(params), 4, tmp_path / "bag")
    (tmp_path / "params.yaml").write_text(params_yaml(params))
    diagnoses = []
    _, updates, errors = estimate_bag(str(tmp_path / "bag"), diagnoses=diagnoses)
    assert errors == [] and updates[-1].final and "cut short" in updates[-1].message
    g = Graph(ros_env(), tmp_path)
    estimates, phases, verdicts = [], [], []
    g.node.create_subscription(Estimate, "/rheo/estimate", lambda m: estimates.append(read_estimate(m)), LATCHED)
    g.node.create_subscription(Diagnosis, "/rheo/diagnosis", lambda m: verdicts.append(read_diagnosis(m)), LATCHED)
    g.node.create_subscription(Phase, "/rheo/phase", phases.append, LATCHED)
    try:
        args = ["--ros-args", "--params-file", str(tmp_path / "params.yaml")]
        g.start("estimator", *args)
        g.start("segmenter", *args)
        play = subprocess.run([str(BIN / "rheo"), "play", str(tmp_path / "bag"), "--rate", "5",
                               "--wait-for-subscribers", "2"], env=g.env, capture_output=True, text=True, timeout=120)
        assert play.returncode == 0, play.stderr
        g.spin_until(lambda: any(e["final"] for e in estimates) and verdicts, 120,
                     lambda: f"a final estimate and a diagnosis after the silence (got {len(estimates)} estimates, "
                             f"{len(verdicts)} diagnoses)")
        # Both nodes say on /rheo/phase that they cut the release short, at the same sample:
        # rheo analyze of a recording that holds it closes the release there too.
        g.spin_until(lambda: sum(p.name == "release" and bool(p.cut_short) for p in phases) == 2, 10,
                     "the segmenter's and the estimator's cut release")
        cuts = {(p.end.sec, p.end.nanosec, p.header.stamp.sec, p.header.stamp.nanosec, p.cut_short)
                for p in phases if p.name == "release"}
        assert len(cuts) == 1 and "no message on any topic for 1 s" in cuts.pop()[-1]
        final = next(e for e in estimates if e["final"])
        assert "cut short" in final["message"] and "no message on any topic for 1 s" in final["message"]
        np.testing.assert_allclose(list(final["params"].values()), updates[-1].values, rtol=1e-9)
        (verdict,) = verdicts
        assert "cut short" in verdict["evidence"]
        assert verdict["missing_effects"] == list(diagnoses[0].missing_effects)
        assert verdict["forms"] == dict(zip(diagnoses[0].missing_effects, diagnoses[0].forms))
        np.testing.assert_allclose(list(verdict["params"].values()), diagnoses[0].values, rtol=1e-9)
    finally:
        g.close()

