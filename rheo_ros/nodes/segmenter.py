"""Segmenter node: contact, pull, keep and release found online (``ros2 run rheo_ros segmenter``).

Subscribes to ``/stage/joint_states``, ``/tactile/pressure`` (contact) and
``/markers/mesh`` (the end of release); publishes each completed phase on
``/rheo/phase`` (the last one kept for late subscribers) and its health on
``/diagnostics``. The core is ``rheo_ros.online.segmenter.PhaseSegmenter``, the one the
estimator runs, so both find the same phases.
"""

from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from rclpy.node import Node
from rheo_ros_interfaces.msg import Phase
from sensor_msgs.msg import Image, JointState

from rheo_ros.config.setup import Setup
from rheo_ros.io.checks import SampleCheck
from rheo_ros.io.messages import (
    MARKERS_TOPIC,
    PHASE_TOPIC,
    STAGE_TOPIC,
    TACTILE_TOPIC,
    MessageError,
    MessageTypes,
    phase_message,
    read_joint_state,
    read_marker_array,
    read_pressure_image,
    stamp_ns,
)
from rheo_ros.nodes.common import NODE_OPTIONS, BadMessages, Silence, declare_all, diagnostic_array, run_node
from rheo_ros.nodes.estimator import LATCHED_QOS, SENSOR_QOS
from rheo_ros.online.segmenter import PhaseEvent, PhaseSegmenter


class SegmenterNode(Node):
    def __init__(self) -> None:
        super().__init__("segmenter", **NODE_OPTIONS)
        params = declare_all(self)
        self.setup = Setup(params)
        self.core = PhaseSegmenter(self.setup.segmenter_config())
        self.check = SampleCheck(self.setup)
        self.types = MessageTypes.rclpy()
        self.phases = self.create_publisher(Phase, PHASE_TOPIC, LATCHED_QOS)
        self.diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(JointState, STAGE_TOPIC, self.on_stage, SENSOR_QOS)
        self.create_subscription(Image, TACTILE_TOPIC, self.on_tactile, SENSOR_QOS)
        self.create_subscription(PoseArray, MARKERS_TOPIC, self.on_markers, SENSOR_QOS)
        self.stale_after = params["estimator.stale_after"]
        self.bad = BadMessages((STAGE_TOPIC, TACTILE_TOPIC, MARKERS_TOPIC), self.stale_after)
        self.silence = Silence(("measurements",), self.stale_after)
        self.create_timer(self.silence.tick_period, self.silence.tick)
        self.create_timer(params["estimator.diagnostics_period"], self.publish_diagnostics)
        self.get_logger().info("segmenter ready")

    def _feed(self, topic: str, msg, read, add) -> None:
        self.silence.heard("measurements")
        try:
            value, t = read(msg), stamp_ns(msg) * 1e-9
            if not np.all(np.isfinite(value)):
                raise MessageError("non-finite values")   # a bad message, not one out of order
            problem = self.check.problem(topic, t, value)
            if problem:   # as the estimator and rheo analyze refuse it
                raise MessageError(problem)
            events = add(t, value)
        except (MessageError, ValueError) as exc:
            if self.bad.bad(topic, f"{topic}: {exc}"):
                self.get_logger().warning(f"{self.bad.last}; message ignored")
            return
        self.bad.good()
        for e in events:
            self.publish(e)

    def publish(self, e: PhaseEvent, cut_short: str = "") -> None:
        self.phases.publish(phase_message(self.types, e, cut_short))
        self.get_logger().info(f"experiment {e.experiment}: {e.name} {e.t_start:.3f} .. {e.t_end:.3f} s")

    def on_stage(self, msg: JointState) -> None:
        self._feed(STAGE_TOPIC, msg, lambda m: read_joint_state(m)[0], self.core.add_stage)

    def on_tactile(self, msg: Image) -> None:
        total = self.setup.tactile.nodal_forces
        self._feed(TACTILE_TOPIC, msg, read_pressure_image, lambda t, p: self.core.add_force(t, float(total(p[None]).sum())))

    def on_markers(self, msg: PoseArray) -> None:
        self._feed(MARKERS_TOPIC, msg, read_marker_array, self.core.add_markers)

    def close_when_silent(self) -> None:
        """Every topic silent for ``estimator.stale_after`` s with a release open: the data
        stopped (the robot let go and moved on); the release ends at its last frame, as
        the estimator ends it."""
        if self.silence.all_silent and self.core.state == "release":
            why = f"no message on any topic for {self.stale_after:g} s"
            for e in self.core.close_release(why):
                self.publish(e, cut_short=why if self.core.release_reason == why else "")

    def publish_diagnostics(self) -> None:
        self.close_when_silent()
        c = self.core
        figures = {"experiment": c.experiment, "state": c.state, "bad messages": self.bad.total,
                   **{f"out of order {k}": n for k, n in c.dropped.items()}}
        if self.bad.warning():
            level, text = "WARN", self.bad.warning()
        else:
            level, text = "OK", f"experiment {c.experiment}: {c.state}"
        self.diagnostics.publish(diagnostic_array(self, level, text, figures))


def main() -> None:
    run_node(SegmenterNode, "Finds contact, pull, keep and release online from the stage, tactile and marker "
                            "topics and publishes each completed phase on /rheo/phase.")


if __name__ == "__main__":
    main()
