"""``rheo record``: live topics from DDS into a rosbag2 MCAP bag (rosbags' writer).

There is no rosbag2 in the package index; this records the serialized CDR of each
message as received. Ctrl-C or SIGTERM stops it cleanly: the writer is closed and
``metadata.yaml`` written, so the bag reads back whole. What has been received is put
on disk every ``FLUSH_PERIOD`` s (a closed MCAP chunk) and the parameters at the start
(``recording.params.yaml``), so that a recorder killed outright (SIGKILL, power) loses at
most that much: ``rheo bag repair`` rebuilds the rest into a whole bag.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from rheo_ros.config.setup import params_yaml
from rheo_ros.io.bag import RECORDING_PARAMS, BagWriter, typestore
from rheo_ros.io.messages import MessageTypes
from rheo_ros.nodes.common import stop_on_signals
from rheo_ros.nodes.errors import GraphError


def parameters_of_publishers(node: Any, topics: Sequence[str], timeout: float = 5.0) -> tuple[dict | None, str]:
    """The package's parameters as the nodes publishing ``topics`` run with them (their
    parameter services), checked; ``(None, why)`` when no publisher serves them (a
    driver that is not ours). The simulator, which makes the measurements, wins."""
    from rclpy.parameter_client import AsyncParameterClient

    from rheo_ros.config.setup import DEFAULTS, ParamsError, check_params

    publishers: list[str] = []
    deadline = time.monotonic() + timeout
    while True:
        infos = [i for topic in topics for i in node.get_publishers_info_by_topic(topic)]
        # The graph learns a publisher's node name a moment after the publisher itself.
        if not any(i.node_name == "_NODE_NAME_UNKNOWN_" for i in infos) or time.monotonic() > deadline:
            break
        rclpy.spin_once(node, timeout_sec=0.05)
    for info in infos:
        name = f"{info.node_namespace.rstrip('/')}/{info.node_name}"
        if info.node_name != "_NODE_NAME_UNKNOWN_" and name not in publishers:
            publishers.append(name)
    publishers.sort(key=lambda n: not n.endswith("/simulator"))
    names = list(DEFAULTS)
    for name in publishers:
        client = AsyncParameterClient(node, name)
        if not client.wait_for_services(timeout_sec=timeout):
            continue
        future = client.get_parameters(names)
        rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
        values = future.result().values if future.done() and future.result() else []
        if len(values) != len(names) or any(v.type == 0 for v in values):   # 0: not set / not ours
            continue
        given = {n: rclpy.parameter.parameter_value_to_python(v) for n, v in zip(names, values)}
        try:
            return check_params(given, f"parameters of {name}"), f"parameters of {name}"
        except ParamsError as exc:
            return None, str(exc)
    return None, "no publisher serves the rheo_ros parameters"


FLUSH_PERIOD = 0.5   # s of wall time: at most this much received data at risk of a kill


def installed_definitions(types: Sequence[str]) -> dict[str, str]:
    """The ``.msg`` text of each of ``types`` that rosbags' store does not know (the
    package's own: /rheo/estimate, /rheo/object, ...), from the interface packages'
    ``share/<package>/msg`` folders on the ament prefix path (a colcon install, or this
    venv, where tools/build_interfaces.sh installs them).

    Raises:
        GraphError: a type with no definition on the prefix path (it could not be decoded)."""
    known = typestore().types
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    found: dict[str, str] = {}
    for name in dict.fromkeys(types):
        if name in known:
            continue
        package, kind, msg = name.split("/")
        paths = [Path(p) / "share" / package / kind / f"{msg}.msg" for p in prefixes]
        path = next((p for p in paths if p.is_file()), None)
        if path is None:
            raise GraphError(f"{name}: no message definition under share/{package}/{kind} on the ament prefix path "
                             f"({os.pathsep.join(prefixes)}): cannot record it")
        found[name] = path.read_text()
    return found


def record(
    topics: Sequence[str], out: str | Path, params: dict[str, Any] | None, duration: float | None = None,
    discovery_timeout: float = 10.0,
) -> dict[str, int]:
    """Record ``topics`` until SIGINT/SIGTERM or ``duration`` s; return counts per topic.

    Without ``params`` the bag stores the parameters of the nodes that publish the
    topics (read from their parameter services), so that it can be analysed as is.
    Prints ``recording`` once every topic's subscription has matched its publishers.

    Raises:
        GraphError: a topic did not appear on the graph within ``discovery_timeout`` s.
    """
    with stop_on_signals() as stop:
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
                raise GraphError(f"{', '.join(missing)}: not on the ROS graph after {discovery_timeout:g} s")
            if params is None:
                params, source = parameters_of_publishers(node, topics)
                print(f"rheo record: storing {source}" if params else f"rheo record: no parameters stored ({source})",
                      flush=True)
            counts = dict.fromkeys(topics, 0)
            qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
            lookup = MessageTypes.rclpy().lookup
            chosen = {t: types[t] for t in topics}
            with BagWriter(out, params, topics=chosen, definitions=installed_definitions(list(chosen.values()))) as bag:
                def writer(topic: str):
                    def on_message(data: bytes) -> None:
                        bag.write_raw(topic, node.get_clock().now().nanoseconds, data)
                        counts[topic] += 1
                    return on_message

                subs = [node.create_subscription(lookup(types[topic]), topic, writer(topic), qos, raw=True)
                        for topic in topics]
                # Wait for the graph, not a fixed time: every subscription matched.
                while not stop.is_set() and any(s.get_publisher_count() == 0 for s in subs):
                    if time.monotonic() > deadline:
                        late = [t for t, s in zip(topics, subs) if s.get_publisher_count() == 0]
                        raise GraphError(f"{', '.join(late)}: no publisher matched after {discovery_timeout:g} s")
                    rclpy.spin_once(node, timeout_sec=0.01)
                if params is not None:
                    (Path(out) / RECORDING_PARAMS).write_text(params_yaml(params))   # metadata.yaml comes at close
                print(f"recording {len(topics)} topic(s)", flush=True)
                end = None if duration is None else time.monotonic() + duration
                flushed = time.monotonic()
                while not stop.is_set() and (end is None or time.monotonic() < end):
                    rclpy.spin_once(node, timeout_sec=0.05)
                    if time.monotonic() - flushed >= FLUSH_PERIOD:
                        bag.flush()
                        flushed = time.monotonic()
            (Path(out) / RECORDING_PARAMS).unlink(missing_ok=True)   # closed: the metadata has them
            return counts
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
