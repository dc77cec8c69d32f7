"""Simulator node: the specimen on the tactile array under the stage (``ros2 run rheo_ros simulator``).

Subscribes to ``/stage/joint_states``, steps the FE model with each stage sample and
publishes ``/tactile/pressure`` and ``/markers/mesh`` at their rates. With
``simulator.clock`` it also drives ``/clock`` (run the stage with ``use_sim_time``):
once the stage's sample for the current clock time is in, the clock moves
``simulator.clock_step`` stage periods on (the stage publishes every sample due by
then), so the run goes as fast as
the two nodes can exchange messages. An ``/rheo/object`` hint ``new`` (an identify goal
on another object) puts a new block of the same material in place, at rest.
"""

from __future__ import annotations

import time

from geometry_msgs.msg import PoseArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rheo_ros_interfaces.msg import ObjectHint
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image, JointState

from rheo_ros.config.setup import Setup
from rheo_ros.io.messages import (
    MARKERS_TOPIC,
    OBJECT_TOPIC,
    STAGE_TOPIC,
    TACTILE_TOPIC,
    MarkerArrayEncoder,
    MessageError,
    MessageTypes,
    PressureImageEncoder,
    read_joint_state,
    read_object_hint,
    stamp_ns,
)
from rheo_ros.nodes.common import NODE_OPTIONS, declare_all, run_node
from rheo_ros.nodes.estimator import LATCHED_QOS
from rheo_ros.rig.simulator import Simulator


class SimulatorNode(Node):
    def __init__(self) -> None:
        super().__init__("simulator", **NODE_OPTIONS)
        params = declare_all(self)
        self.setup = Setup(params)
        self.sim = Simulator(self.setup, params["simulator.seed"])
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        types = MessageTypes.rclpy()
        self.encode_tactile, self.encode_markers = PressureImageEncoder(types), MarkerArrayEncoder(types)
        self.tactile = self.create_publisher(Image, TACTILE_TOPIC, qos)
        self.markers = self.create_publisher(PoseArray, MARKERS_TOPIC, qos)
        self.create_subscription(JointState, STAGE_TOPIC, self.on_stage, qos)
        self.create_subscription(ObjectHint, OBJECT_TOPIC, self.on_object, LATCHED_QOS)
        self.swapped_at = -1   # stamp (ns) of the last hint acted on: a latched one arrives again
        self.t0: int | None = None
        self.drive_clock = params["simulator.clock"]
        self.clock_step = params["simulator.clock_step"]
        # A run driven as fast as the nodes answer lasts a second or less: a recorder or an
        # estimator whose subscription matches a moment late would miss its start.
        self.wait_for = params["simulator.wait_for_subscribers"]
        if self.drive_clock:
            self.clock_publisher = self.create_publisher(Clock, "/clock", 10)
            self.clock_ns = 1_000_000_000  # sim time starts at 1 s (0 means "no time yet")
            self.last_progress = time.monotonic()
            self.create_timer(0.2, self.kick_clock)  # wall timer: (re)sends the clock until the stage answers
        effects = ", ".join(self.setup.effect_ids) or "none"
        fine = self.sim.fe.structure.fine
        self.get_logger().info(f"simulator ready: {self.setup.params['geometry']} FE mesh {fine.rows} x {fine.cols} "
                               f"nodes ({self.setup.mesh.rows} x {self.setup.mesh.cols} markers), "
                               f"hidden effects: {effects}")

    def on_object(self, msg: ObjectHint) -> None:
        try:
            kind = read_object_hint(msg)
        except MessageError as exc:
            self.get_logger().warning(f"{OBJECT_TOPIC}: {exc}; hint ignored")
            return
        if kind == "new" and stamp_ns(msg) > self.swapped_at:
            self.swapped_at = stamp_ns(msg)
            self.sim.new_block()
            self.get_logger().info("a new block in place, at rest (object: new)")

    def on_stage(self, msg: JointState) -> None:
        try:
            depth, _ = read_joint_state(msg)
        except MessageError as exc:
            self.get_logger().warning(f"{STAGE_TOPIC}: {exc}; sample ignored", throttle_duration_sec=5.0)
            return
        stamp = stamp_ns(msg)
        if self.t0 is None:
            self.t0 = stamp
        for frame in self.sim.step((stamp - self.t0) * 1e-9, depth):
            ns = self.t0 + round(frame.t * 1e9)
            if frame.kind == "tactile":
                self.tactile.publish(self.encode_tactile(ns, frame.data))
            else:
                self.markers.publish(self.encode_markers(ns, frame.data))
        if self.drive_clock and stamp >= self.clock_ns:
            self.clock_ns = stamp + round(self.clock_step * self.sim.step_s * 1e9)
            self.publish_clock()

    def publish_clock(self) -> None:
        self.last_progress = time.monotonic()
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(self.clock_ns, 1_000_000_000)
        self.clock_publisher.publish(msg)

    def kick_clock(self) -> None:
        if self.wait_for:   # the run starts with the first /clock: not before every listener matched
            if min(self.tactile.get_subscription_count(), self.markers.get_subscription_count()) < self.wait_for:
                return
            self.wait_for = 0
        if time.monotonic() - self.last_progress > 0.2:
            self.publish_clock()


def main() -> None:
    run_node(SimulatorNode, "Stands in for the hardware: steps the FE model with each /stage/joint_states sample "
                            "and publishes /tactile/pressure and /markers/mesh (and /clock with simulator.clock).")


if __name__ == "__main__":
    main()
