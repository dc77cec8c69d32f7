"""Stage node: publishes ``/stage/joint_states`` from its motion source (``ros2 run rheo_ros stage``)."""

from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from rheo_ros.io.messages import STAGE_TOPIC, JointStateEncoder, MessageTypes
from rheo_ros.nodes.common import declare_all, run_node
from rheo_ros.params import Setup
from rheo_ros.stage import motion_source


class StageNode(Node):
    """Ticks at ``rates.stage`` on the wall clock, or on each ``/clock`` tick with ``use_sim_time``."""

    def __init__(self) -> None:
        super().__init__("stage")
        params = declare_all(self)
        self.setup = Setup(params)
        self.source = motion_source(params["stage.driver"], self.setup.profile)
        self.wait_for = params["stage.wait_for_subscribers"]
        self.publisher = self.create_publisher(JointState, STAGE_TOPIC, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.encode = JointStateEncoder(MessageTypes.rclpy())
        self.t0: int | None = None
        self.phase = ""
        if self.get_parameter("use_sim_time").value:
            # Simulated time: one sample per /clock tick (the simulator moves the clock
            # one stage period per sample), stamped with the tick's time.
            self.create_subscription(Clock, "/clock", lambda m: self.tick(m.clock.sec * 10**9 + m.clock.nanosec), 10)
        else:
            self.create_timer(1.0 / params["rates.stage"], lambda: self.tick(self.get_clock().now().nanoseconds))
        p = self.setup.profile
        self.get_logger().info(
            f"stage ready: {p.depth * 1e3:.3g} mm at {p.velocity * 1e3:.3g} mm/s, keep {p.keep_time:g} s, "
            f"retract at {p.retract_speed * 1e3:.3g} mm/s ({params['stage.driver']})"
        )

    def tick(self, now: int) -> None:
        if now == 0:
            return  # simulated time has not started
        if self.t0 is None:
            if self.publisher.get_subscription_count() < self.wait_for:
                return
            self.t0 = now
        sample = self.source.sample((now - self.t0) * 1e-9)
        if sample.phase != self.phase:
            self.phase = sample.phase
            self.get_logger().info(f"phase {sample.phase}: depth {sample.depth * 1e3:.3f} mm, "
                                   f"velocity {sample.velocity * 1e3:.3f} mm/s")
            if sample.phase == "done":
                self.source.close()
        self.publisher.publish(self.encode(now, sample.depth, sample.velocity))


def main() -> None:
    run_node(StageNode)


if __name__ == "__main__":
    main()
