"""``rheo play``: a bag's topics published over DDS, with their recorded timing or as fast
as the subscribers take them while driving ``/clock``.

The serialized CDR of each message goes out as recorded (no re-encoding), so a
subscriber decodes exactly what was recorded. ``--loop N`` plays the bag N times,
each pass shifted by the bag's length on every header stamp (messages re-serialized
by rosbags' typestore), for soak runs over many experiments.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock

from rheo_ros.io.bag import bag_reader, require_bag
from rheo_ros.io.errors import BagError
from rheo_ros.io.messages import MessageTypes
from rheo_ros.nodes.common import stop_on_signals
from rheo_ros.nodes.errors import GraphError

# KEEP_ALL + reliable: the writer holds what a reader has not acknowledged, so a slow
# subscriber slows the player down instead of losing messages (KEEP_LAST overwrites
# silently: measured, 3 760 of 27 000 delivered). Readers that must see every message
# subscribe with KEEP_ALL too (the estimator and segmenter nodes do).
PLAY_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
# Fast DDS writer settings for the player's process: a reader that lost or refused data
# is repaired at the next heartbeat (3 s by default: a replay crawled at ~600 msg/s);
# a full writer blocks publish() for max_blocking_time, then refuses it (retried).
WRITER_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com">
  <profiles>
    <data_writer profile_name="rheo_play_writer" is_default_profile="true">
      <qos><reliability><max_blocking_time><sec>1</sec><nanosec>0</nanosec></max_blocking_time></reliability></qos>
      <times><heartbeat_period><sec>0</sec><nanosec>10000000</nanosec></heartbeat_period></times>
    </data_writer>
  </profiles>
</dds>
"""
ACK_EVERY = 500      # messages between waits for every reader's acknowledgement
ACK_SLICE = 0.1      # s: the longest a wait for acknowledgements holds off Ctrl-C


def _bag_messages(path: Path, topics: Sequence[str] | None, loops: int
                  ) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, log time ns, CDR) in log-time order; later passes shifted in time."""
    with bag_reader(path) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if topics is not None:
            missing = sorted(set(topics) - {c.topic for c in conns})
            if missing:
                raise BagError(f"{path}: {', '.join(missing)}: not in the bag")
        span = reader.end_time - reader.start_time + 10_000_000   # a pass, plus one 10 ms gap
        for k in range(loops):
            shift = k * span
            for conn, t, raw in reader.messages(connections=conns):
                if shift:
                    msg = reader.deserialize(raw, conn.msgtype)
                    if hasattr(msg, "header"):
                        ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec + shift
                        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
                    raw = reader.typestore.serialize_cdr(msg, conn.msgtype)
                yield conn.topic, conn.msgtype, t + shift, bytes(raw)


def _publish(publisher: Any, raw: bytes, stop: threading.Event) -> bool:
    """Publish, waiting while the subscribers catch up: a KEEP_ALL writer whose
    readers have not acknowledged enough refuses the write after its blocking time.
    False: stopped (Ctrl-C) before the message could be written."""
    while True:
        try:
            publisher.publish(raw)
            return True
        except RCLError:
            if stop.is_set():
                return False
            publisher.wait_for_all_acked(rclpy.duration.Duration(seconds=0.05))


def _acked(publisher: Any, seconds: float, stop: threading.Event) -> bool:
    """Whether every reader acknowledged what ``publisher`` wrote within ``seconds``;
    waits in slices of ``ACK_SLICE`` s so that Ctrl-C ends the wait at once (False)."""
    deadline = time.monotonic() + seconds
    while not publisher.wait_for_all_acked(rclpy.duration.Duration(seconds=ACK_SLICE)):
        if stop.is_set() or time.monotonic() > deadline:
            return False
    return True


def message_class(msgtype: str) -> type | None:
    """The installed rclpy class of ``msgtype``; None where this machine lacks it (a bag
    may hold types of packages not installed here)."""
    try:
        return MessageTypes.rclpy().lookup(msgtype)
    except (ImportError, AttributeError, ValueError):
        return None


def playable_classes(path: Path, types: dict[str, str], warn: Callable[[str], None]) -> dict[str, type]:
    """The rclpy class of each topic of ``types`` (topic -> type name) whose type is
    installed; each other topic skipped with one ``warn`` line naming it and its type.

    Raises:
        BagError: no topic left to play (names the topics skipped and their types)."""
    classes = {topic: message_class(msgtype) for topic, msgtype in types.items()}
    skipped = [f"{topic}: type {types[topic]}" for topic, cls in classes.items() if cls is None]
    if skipped and len(skipped) == len(types):
        raise BagError(f"{path}: {', '.join(skipped)} is not installed here; nothing else to play")
    for line in skipped:
        warn(f"{path}: {line} is not installed here: not played")
    return {topic: cls for topic, cls in classes.items() if cls is not None}


def play(path: str | Path, rate: float = 1.0, clock: bool = False, loops: int = 1,
         topics: Sequence[str] | None = None, wait_for: int = 0, discovery_timeout: float = 10.0,
         warn: Callable[[str], None] = lambda line: None) -> dict[str, int]:
    """Publish a bag; returns the count per topic. Ctrl-C or SIGTERM stops it. A topic
    whose type is not installed here is skipped, said in a ``warn`` line.

    Args:
        rate: speed factor on the recorded timing (ignored with ``clock``).
        clock: publish ``/clock`` (each message's log time before it) and go as fast as
            the subscribers take the messages.
        wait_for: start once every topic has this many subscribers.

    Raises:
        BagError: unreadable bag, unknown topic, no topic of an installed type.
            GraphError: subscribers missing after ``discovery_timeout`` s.
    """
    path = require_bag(path)
    if not rate > 0:
        raise ValueError(f"--rate: {rate} must be positive")
    if not (isinstance(loops, int) and loops >= 1):
        raise ValueError(f"--loop: {loops} must be a whole number of passes, at least 1")
    with bag_reader(path) as reader:
        types = {c.topic: c.msgtype for c in reader.connections if topics is None or c.topic in topics}
    if topics is not None:
        missing = sorted(set(topics) - set(types))
        if missing:
            raise BagError(f"{path}: {', '.join(missing)}: not in the bag")
    classes = playable_classes(path, types, warn)   # before DDS starts
    types = {topic: types[topic] for topic in classes}
    with stop_on_signals() as stop:
        profile = Path(tempfile.mkdtemp(prefix="rheo-play-")) / "fastdds_writer.xml"
        profile.write_text(WRITER_PROFILE)
        ours = "FASTDDS_DEFAULT_PROFILES_FILE" not in os.environ
        if ours:
            os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = str(profile)   # read when DDS starts, below
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node("rheo_play")
        try:
            pubs: dict[str, Any] = {t: node.create_publisher(classes[t], t, PLAY_QOS) for t in types}
            clock_pub = node.create_publisher(Clock, "/clock", PLAY_QOS) if clock else None
            deadline = time.monotonic() + discovery_timeout
            while wait_for and any(p.get_subscription_count() < wait_for for p in pubs.values()):
                if time.monotonic() > deadline or stop.is_set():
                    short = [t for t, p in pubs.items() if p.get_subscription_count() < wait_for]
                    raise GraphError(f"{', '.join(short)}: fewer than {wait_for} subscriber(s) after "
                                      f"{discovery_timeout:g} s")
                rclpy.spin_once(node, timeout_sec=0.05)
            counts, sent = dict.fromkeys(types, 0), 0
            start_wall, start_bag, last_clock = time.monotonic(), None, -1
            tick = Clock()
            for topic, _, t, raw in _bag_messages(path, list(types), loops):
                if stop.is_set():
                    break
                if start_bag is None:
                    start_bag = t
                if clock_pub is not None:
                    if t > last_clock:
                        tick.clock.sec, tick.clock.nanosec = divmod(t, 1_000_000_000)
                        clock_pub.publish(tick)
                        last_clock = t
                else:
                    delay = start_wall + (t - start_bag) * 1e-9 / rate - time.monotonic()
                    if delay > 0:
                        stop.wait(delay)
                if not _publish(pubs[topic], raw, stop):
                    break
                counts[topic] += 1
                sent += 1
                if sent % ACK_EVERY == 0:
                    # Pacing: a backlog in a reader's queue makes each take slower.
                    for p in pubs.values():
                        _acked(p, 5.0, stop)

            # What a reader has not acknowledged dies with the writer: wait for it (not once
            # the user stopped the play: Ctrl-C ends it within a second, what is in flight lost).
            for p in pubs.values():
                if not _acked(p, 60.0, stop) and not stop.is_set():
                    raise GraphError(f"{path}: a subscriber did not acknowledge every message within 60 s")
            return counts
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
            shutil.rmtree(profile.parent, ignore_errors=True)   # DDS read it at start-up
            if ours:
                os.environ.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
