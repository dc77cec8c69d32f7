"""``rheo record``: live topics from DDS into a rosbag2 MCAP bag (rosbags' writer).

There is no rosbag2 in the package index; this records the serialized CDR of each
message as received. Ctrl-C or SIGTERM stops it cleanly: the writer is closed and
``metadata.yaml`` written, so the bag reads back whole.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from rheo_ros.io.bag import BagWriter
from rheo_ros.io.messages import MessageTypes
from rheo_ros.record import RecordError


def record(
    topics: Sequence[str], out: str | Path, params: dict[str, Any] | None, duration: float | None = None,
    discovery_timeout: float = 10.0,
) -> dict[str, int]:
    """Record ``topics`` until SIGINT/SIGTERM or ``duration`` s; return counts per topic.

    Raises:
        RecordError: a topic did not appear on the graph within ``discovery_timeout`` s.
    """
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("rheo_record")
    try:
        types: dict[str, str] = {}
        deadline = time.monotonic() + discovery_timeout
        while len(types) < len(topics) and time.monotonic() < deadline and not stop.is_set():
            rclpy.spin_once(node, timeout_sec=0.05)
            for name, names in node.get_topic_names_and_types():
                if name in topics and names:
                    types[name] = names[0]
        missing = [t for t in topics if t not in types]
        if missing:
            raise RecordError(f"{', '.join(missing)}: not on the ROS graph after {discovery_timeout:g} s")
        counts = dict.fromkeys(topics, 0)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        lookup = MessageTypes.rclpy().lookup
        with BagWriter(out, params, topics={t: types[t] for t in topics}) as bag:
            def writer(topic: str):
                def on_message(data: bytes) -> None:
                    bag.write_raw(topic, node.get_clock().now().nanoseconds, data)
                    counts[topic] += 1
                return on_message

            for topic in topics:
                node.create_subscription(lookup(types[topic]), topic, writer(topic), qos, raw=True)
            end = None if duration is None else time.monotonic() + duration
            while not stop.is_set() and (end is None or time.monotonic() < end):
                rclpy.spin_once(node, timeout_sec=0.05)
        return counts
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        for s, handler in previous.items():
            signal.signal(s, handler)
