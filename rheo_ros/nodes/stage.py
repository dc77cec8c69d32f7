"""Stage node: publishes ``/stage/joint_states`` from its motion source (``ros2 run rheo_ros stage``).

With ``stage.autostart`` it runs the profile once at start; either way it serves the
``/rheo/identify`` action (``rheo_ros_interfaces/action/Identify``): a planner asks for
one push-keep-release of the object in front of it, gets feedback as each phase's
estimate arrives on ``/rheo/estimate`` and the final estimate as its result, with the
estimator's diagnosis and its pool (``/rheo/pool``: this push pooled with the earlier
ones on the same object). The goal's ``object`` (new, same, or "" for the data to decide)
goes out on ``/rheo/object`` as the run starts, for the estimator, the simulator and a
recording. A cancel (or a shutdown mid-run) makes the stage retract at once
(``MotionSource.abort``).
"""

from __future__ import annotations

import threading
import time

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rheo_ros_interfaces.action import Identify
from rheo_ros_interfaces.msg import Diagnosis, Estimate, ObjectHint, Pool
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from rheo_ros.config.setup import ParamsError, Setup, check_params
from rheo_ros.experiment import check_object_hint
from rheo_ros.io.messages import (
    DIAGNOSIS_TOPIC,
    ESTIMATE_TOPIC,
    OBJECT_TOPIC,
    POOL_TOPIC,
    STAGE_TOPIC,
    JointStateEncoder,
    MessageTypes,
    object_hint_message,
    stamp_ns,
)
from rheo_ros.nodes.common import NODE_OPTIONS, declare_all, run_node
from rheo_ros.nodes.estimator import LATCHED_QOS
from rheo_ros.online.estimator import trusted
from rheo_ros.rig.stage import MotionSource, motion_source

IDENTIFY_ACTION = "/rheo/identify"


class StageNode(Node):
    """Ticks at ``rates.stage`` on the wall clock, or on each ``/clock`` tick with ``use_sim_time``."""

    def __init__(self) -> None:
        super().__init__("stage", **NODE_OPTIONS)
        params = declare_all(self)
        self.setup = Setup(params)
        self.driver = params["stage.driver"]
        self.exit_when_done = params["stage.exit_when_done"]
        self.wait_for = params["stage.wait_for_subscribers"]
        self.publisher = self.create_publisher(JointState, STAGE_TOPIC,
                                               QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.encode = JointStateEncoder(MessageTypes.rclpy())
        self.source: MotionSource | None = None
        self.t0: int | None = None
        self.now_ns = 0
        self.phase = ""
        if params["stage.autostart"]:
            self.start(self.setup.profile)
        self.period_ns = round(1e9 / params["rates.stage"])
        self.next_ns: int | None = None
        if self.get_parameter("use_sim_time").value:
            # Simulated time: every sample due by the /clock tick's time, on the
            # stage's own grid (the simulator moves the clock on once it has them).
            self.create_subscription(Clock, "/clock", lambda m: self.on_clock(m.clock.sec * 10**9 + m.clock.nanosec),
                                     10)
        else:
            self.create_timer(1.0 / params["rates.stage"], lambda: self.tick(self.get_clock().now().nanoseconds))
        group = ReentrantCallbackGroup()
        self.goal_lock = threading.Lock()
        self.estimates: list[Estimate] = []
        self.create_subscription(Estimate, ESTIMATE_TOPIC, self.estimates.append, LATCHED_QOS, callback_group=group)
        # The result says whether to trust the estimate: the estimator's diagnosis of the push.
        self.diagnose = params["estimator.diagnose"]
        self.diagnoses: list[Diagnosis] = []
        self.create_subscription(Diagnosis, DIAGNOSIS_TOPIC, self.diagnoses.append, LATCHED_QOS, callback_group=group)
        self.fits = params["estimator.fit"]   # no whole-record fit: no covariance to pool
        # After a goal's "new" hint the stage holds at rest this long on its own clock: the
        # estimator takes the markers' starting positions from the data before each pull,
        # which must show the new block only (in simulation the block is swapped when the
        # hint arrives; a swap inside that window moved c1 -6 std).
        self.new_object_rest_ns = round((params["estimator.pre_contact"] + 0.5) * 1e9)
        self.pools: list[Pool] = []
        self.create_subscription(Pool, POOL_TOPIC, self.pools.append, LATCHED_QOS, callback_group=group)
        self.hints = self.create_publisher(ObjectHint, OBJECT_TOPIC, LATCHED_QOS)
        self.types = MessageTypes.rclpy()
        self.action = ActionServer(self, Identify, IDENTIFY_ACTION, execute_callback=self.identify,
                                   goal_callback=self.accept_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
                                   callback_group=group)
        p = self.setup.profile
        self.get_logger().info(
            f"stage ready: {p.depth * 1e3:.3g} mm at {p.velocity * 1e3:.3g} mm/s, keep {p.keep_time:g} s, "
            f"retract at {p.retract_speed * 1e3:.3g} mm/s ({self.driver}); "
            + ("running the profile" if self.source else f"waiting for {IDENTIFY_ACTION} goals")
        )

    def start(self, profile) -> None:
        self.source, self.t0, self.phase = motion_source(self.driver, profile), None, ""

    @property
    def running(self) -> bool:
        return self.source is not None and self.phase != "done"

    def on_clock(self, now: int) -> None:
        if self.next_ns is None or self.t0 is None or now < self.next_ns - self.period_ns:
            self.next_ns = now          # not started (idle or waiting), or the clock went back: restart the grid
        while self.next_ns <= now:
            self.tick(self.next_ns)
            self.next_ns += self.period_ns

    def tick(self, now: int) -> None:
        if now == 0:
            return  # simulated time has not started
        self.now_ns = now
        source = self.source   # once: a goal's thread may end the run between two reads
        if source is None:
            self.publisher.publish(self.encode(now, 0.0, 0.0))   # idle: at rest, off the specimen
            return
        if self.t0 is None:
            if self.publisher.get_subscription_count() < self.wait_for:
                return
            self.t0 = now
        sample = source.sample((now - self.t0) * 1e-9)
        if sample.phase != self.phase:
            self.phase = sample.phase
            self.get_logger().info(f"phase {sample.phase}: depth {sample.depth * 1e3:.3f} mm, "
                                   f"velocity {sample.velocity * 1e3:.3f} mm/s")
            if sample.phase == "done":
                source.close()
        self.publisher.publish(self.encode(now, sample.depth, sample.velocity))
        if self.phase == "done" and self.exit_when_done and not self.action_active:
            self.get_logger().info("profile done: exiting (stage.exit_when_done)")
            self.context.try_shutdown()

    action_active = False          # a goal holds the stage, from its acceptance to its result
    HINT_SETTLE = 0.3    # s of wall time for the subscribers to act on a goal's /rheo/object before the stage moves
    FIT_TIMEOUT = 60.0   # s of wall time without an estimate, once the profile is done
    # s of wall time for the push's diagnosis after its final estimate: the discovery loop
    # fits several candidate models (tens of seconds here, minutes on a loaded machine).
    DIAGNOSIS_TIMEOUT = 600.0

    # -- /rheo/identify ----------------------------------------------------------------

    def accept_goal(self, goal: Identify.Goal) -> GoalResponse:
        # The goal holds the stage from its acceptance: a second goal arriving before the
        # first one's execution starts must not be accepted too (the callback group is
        # reentrant, hence the lock).
        with self.goal_lock:
            if self.running or self.action_active:
                self.get_logger().warning(f"{IDENTIFY_ACTION}: rejected, a run is in progress")
                return GoalResponse.REJECT
            self.action_active = True
            return GoalResponse.ACCEPT

    def identify(self, handle) -> Identify.Result:
        try:
            return self._run_goal(handle)
        finally:
            self.action_active = False   # whatever ended the goal (a driver's exception too)

    def _run_goal(self, handle) -> Identify.Result:
        goal = handle.request
        # Zero or negative keeps the configured value (the action's definition); anything
        # else, NaN and inf included, is checked as the parameters file's value would be.
        changes = {f"stage.{k}": getattr(goal, k) for k in ("depth", "velocity", "keep_time")
                   if not getattr(goal, k) <= 0}
        result = Identify.Result()
        try:
            try:
                check_object_hint(goal.object)
            except ValueError as exc:
                raise ParamsError(str(exc)) from None
            profile = Setup(check_params({**self.setup.params, **changes}, "goal")).profile.pushes[0]   # one push
        except ParamsError as exc:
            handle.abort()
            result.message = f"bad goal: {exc}"
            self.get_logger().warning(f"{IDENTIFY_ACTION}: {result.message}")
            return result
        seen = len(self.estimates)
        # This run's push is a new experiment: estimates of earlier ones (a release that
        # closes only as this push starts, a cancelled push's) are not its result.
        earlier = max((m.experiment for m in self.estimates), default=0)
        run_experiment: int | None = None
        # Stamped before the stage moves: it applies to the push this run makes. The stage
        # moves a moment later, once the subscribers have acted on it: a simulator that took
        # it a few samples late put its new block in place 75 um under the stage, and the
        # push's c2 came out 24 % high. Not wait_for_all_acked: across processes Fast DDS
        # acknowledges at its heartbeat (measured 0.2 s to over 2 s) while the message itself
        # arrives within milliseconds.
        stamp = self.now_ns
        self.hints.publish(object_hint_message(self.types, stamp, goal.object))
        time.sleep(self.HINT_SETTLE)
        if goal.object == "new":
            wall_limit = time.monotonic() + self.FIT_TIMEOUT   # a clock that stopped must not hold the goal
            while self.now_ns < stamp + self.new_object_rest_ns and time.monotonic() < wall_limit:
                if handle.is_cancel_requested:
                    handle.canceled()
                    result.message = "cancelled before the stage moved"
                    return result
                time.sleep(0.02)
        self.start(profile)
        asked = ", ".join([f"{k.removeprefix('stage.')} {v:g}" for k, v in changes.items()]
                          + [f"object {goal.object}"] * bool(goal.object))
        self.get_logger().info(f"{IDENTIFY_ACTION}: run started ({asked})")
        # The run takes its own length on the stage clock (sim time in fast mode); the
        # fits after it take wall time: a minute of it once the profile is done, counted
        # again from each estimate of this run (a slow machine's fit lane still working).
        deadline = None
        while True:
            time.sleep(0.02)
            if self.phase == "done" and deadline is None:
                deadline = time.monotonic() + self.FIT_TIMEOUT
            if handle.is_cancel_requested:
                return self._cancel(handle, result)
            for msg in self.estimates[seen:]:
                seen += 1
                if deadline is not None:   # the estimator is still at work (maybe on an earlier push)
                    deadline = time.monotonic() + self.FIT_TIMEOUT
                if self.t0 is None or stamp_ns(msg) < self.t0 or msg.experiment <= earlier:
                    continue        # an estimate of an earlier run
                if run_experiment is None and msg.phase in ("pull", "keep"):
                    run_experiment = msg.experiment   # this run's push showed itself
                mine = msg.experiment == run_experiment if run_experiment is not None else msg.final
                if not mine:
                    continue        # a push before this one, closing its release now
                handle.publish_feedback(Identify.Feedback(phase=msg.phase, estimate=msg))
                if msg.final:
                    # Identified: the stage is off the specimen (the release has
                    # settled); the rest of the profile's recording time is not needed.
                    source, self.source, self.phase = self.source, None, "done"
                    source.close()
                    return self._judged(handle, msg)
            if deadline is not None and time.monotonic() > deadline:
                handle.abort()
                result.message = "no final estimate on /rheo/estimate in time (is the estimator running?)"
                return result

    def _judged(self, handle, estimate: Estimate) -> Identify.Result:
        """The result: the final estimate with the estimator's diagnosis of the same push
        (waited for where the estimator diagnoses) and its pool, ``success`` whether to
        trust the estimate."""
        result = Identify.Result(estimate=estimate, undetermined=list(estimate.undetermined))
        diagnosis = None
        if self.diagnose:
            diagnosis = self._wait_for(self.diagnoses, estimate, handle, self.DIAGNOSIS_TIMEOUT)
            if diagnosis is None:
                handle.abort()
                result.verdict = "not_diagnosed"
                result.message = ("cancelled while waiting for the diagnosis" if handle.is_cancel_requested else
                                  "no diagnosis on /rheo/diagnosis in time (the estimate is in the result)")
                return result
        if diagnosis is None:
            result.verdict = "not_diagnosed"
        else:
            result.diagnosis, result.verdict = diagnosis, diagnosis.verdict
            result.missing_effects = list(diagnosis.missing_effects)
            result.undetermined = sorted({*result.undetermined, *diagnosis.undetermined})
        result.success, result.message = trusted(
            result.verdict, result.undetermined, result.missing_effects,
            [] if diagnosis is None else list(diagnosis.undecided))
        if diagnosis is not None and diagnosis.verdict == "not_diagnosed":   # it could not run: why
            result.message = f"{result.message}; {diagnosis.evidence}"
        # The pool follows the diagnosis at once (the same lane); the estimate stands without it.
        pool = self._wait_for(self.pools, estimate, handle, self.FIT_TIMEOUT) if self.fits else None
        if pool is not None:
            result.pool = pool
        elif self.fits:
            self.get_logger().warning(f"{IDENTIFY_ACTION}: no pool on {POOL_TOPIC} in time; the result has none")
        handle.succeed()   # the action ran; success says whether its estimate can be used
        self.get_logger().info(f"{IDENTIFY_ACTION}: {result.verdict}: {result.message}"
                               + (f"; {pool.message}" if pool is not None else ""))
        return result

    @staticmethod
    def _wait_for(messages: list, estimate: Estimate, handle, timeout: float):
        """The first message of ``messages`` (a subscription's list) about the estimate's
        push and not older than it; None after ``timeout`` s or a cancel."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not handle.is_cancel_requested:
            found = next((m for m in reversed(messages) if m.experiment == estimate.experiment
                          and stamp_ns(m) >= stamp_ns(estimate)), None)
            if found is not None:
                return found
            time.sleep(0.02)
        return None

    def _cancel(self, handle, result: Identify.Result) -> Identify.Result:
        if self.t0 is None:
            # Not moved yet (waiting for subscribers): nothing to retract.
            source, self.source, self.phase = self.source, None, "done"
            source.close()
            handle.canceled()
            result.message = "cancelled before the stage moved"
            return result
        t = (self.now_ns - self.t0) * 1e-9
        self.source.abort(t)
        self.get_logger().warning(f"{IDENTIFY_ACTION}: cancelled at {t:.2f} s: retracting")
        while self.phase != "done" and self.context.ok():
            time.sleep(0.02)
        handle.canceled()
        result.message = "cancelled: the stage retracted to depth 0"
        return result

    def destroy_node(self) -> None:
        if self.running and self.t0 is not None:
            self.source.abort((self.now_ns - self.t0) * 1e-9)   # never leave the specimen loaded
            self.source.close()
        super().destroy_node()


def main() -> None:
    run_node(StageNode, "Publishes /stage/joint_states from its motion source: runs the stage.* profile at "
                        "start (stage.autostart) and on each /rheo/identify goal.", MultiThreadedExecutor)


if __name__ == "__main__":
    main()
