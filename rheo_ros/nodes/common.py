"""What every node shares: parameter declaration from the package's table, startup,
``--help``, diagnostics."""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from rheo_ros.config.setup import ParamsError, check_params
from rheo_ros.config.table import PARAMETERS
from rheo_ros.online.worker import single_threaded_blas

LEVELS = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN, "ERROR": DiagnosticStatus.ERROR}


# Every node passes these to Node.__init__: rclpy drops an override nobody declares,
# so a misspelt name in a parameters file would be ignored in silence. Declared from
# the overrides, every name reaches check_params, which refuses it as the CLI does.
NODE_OPTIONS: dict[str, Any] = {"automatically_declare_parameters_from_overrides": True}

# rclpy's own parameters on every node: a parameters file may set them.
ROS_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})


def declare_all(node: Node) -> dict[str, Any]:
    """Declare the package's parameters (defaults, descriptions) and return their values,
    checked like the CLI's (unknown names, types, set-ups that cannot work).

    One table for every node, so one parameters file serves them all. The node must be
    created with ``NODE_OPTIONS``.
    """
    # Only the names set (declared from the overrides) are checked: a default that
    # depends on others (uniaxial's frictionless faces) is check_params' to fill in.
    given = {name: p.value for name, p in node.get_parameters_by_prefix("").items() if name not in ROS_PARAMETERS}
    try:
        params = check_params(given, f"node {node.get_name()}")
    except ParamsError:
        # rclpy's shutdown destroys every node it tracks, and a subclass's destroy_node
        # would trip over the attributes its refused __init__ never set (a traceback
        # after the one-line error): the node goes now, as the plain rclpy Node it is.
        Node.destroy_node(node)
        raise
    for parameter in PARAMETERS:
        # Dynamic typing: a file's "150" for a float parameter means 150.0, as in the CLI;
        # check_params above applies the one set of rules.
        name, descriptor = parameter.name, ParameterDescriptor(description=parameter.help, dynamic_typing=True)
        if node.has_parameter(name):  # declared from the file: keep its value, give it the table's descriptor
            node.set_descriptor(name, descriptor)
        else:  # the value the node runs with, which the parameter services then serve (rheo record)
            node.declare_parameter(name, params[name], descriptor)
    return params


def node_help(name: str, summary: str) -> str:
    """``--help`` text: usage, what the node does, and every parameter with its default."""
    lines = [f"usage: {name} [--help] [--ros-args --params-file FILE] [--ros-args -p NAME:=VALUE ...]", "",
             summary, "", "parameters, name = default: meaning (config/rheo_ros.yaml also lists effects.<id>.*):"]
    lines += [f"  {p.name} = {p.default!r}: {p.help}" for p in PARAMETERS if not p.name.startswith("effects.")]
    return "\n".join(lines)


def wants_help(argv: list[str]) -> bool:
    """``-h``/``--help`` before any ``--ros-args``: print help, start nothing."""
    user = argv[1: argv.index("--ros-args")] if "--ros-args" in argv else argv[1:]
    return any(a in ("-h", "--help") for a in user)


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event set by Ctrl-C or SIGTERM, in place of rclpy's handlers (init rclpy with
    ``SignalHandlerOptions.NO``); the previous handlers are back on exit.

    rclpy's own handler chains to Python's, which raises KeyboardInterrupt between any two
    bytecodes: once it landed inside rclpy's ``Task.__init__`` and the half-built task's
    ``__del__`` printed a traceback at shutdown. An event is looked at by the spin loop.
    """
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


# s between two looks at the stop event: how late a node answers Ctrl-C at most.
SPIN_PERIOD = 0.1


def run_node(make: Callable[[], Node], summary: str, executor: Callable[[], Executor] = SingleThreadedExecutor
             ) -> None:
    """Init, spin until Ctrl-C, SIGTERM or the node shuts itself down, clean up; bad
    parameters end in one line (exit 2); ``--help`` prints and starts nothing."""
    if wants_help(sys.argv):
        print(node_help(sys.argv[0].rsplit("/", 1)[-1], summary))
        return
    single_threaded_blas()
    with stop_on_signals() as stop:
        rclpy.init(args=sys.argv, signal_handler_options=SignalHandlerOptions.NO)
        node = None
        try:
            node = make()
            spinner = executor()
            spinner.add_node(node)
            while not stop.is_set() and rclpy.ok():
                spinner.spin_once(timeout_sec=SPIN_PERIOD)
        except rclpy.executors.ExternalShutdownException:
            pass   # the node shut its context down (stage.exit_when_done)
        except (ValueError, KeyError) as exc:  # ParamsError is a ValueError
            reason = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc   # str(KeyError) adds quotes
            print(f"{sys.argv[0]}: error: {reason}", file=sys.stderr)
            sys.exit(2)
        finally:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()


def diagnostic_array(node: Node, level: str, message: str, values: dict[str, Any]) -> DiagnosticArray:
    """One ``DiagnosticStatus`` for ``node``: level OK / WARN / ERROR, a reason a person
    can act on, and the figures behind it."""
    status = DiagnosticStatus(level=LEVELS[level], name=f"rheo_ros: {node.get_name()}", message=message,
                              hardware_id="rheo_ros",
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = node.get_clock().now().to_msg()
    return msg


class Silence:
    """Whether the measurement topics went silent for ``stale_after`` s of wall time, as
    judged from a node's executor, which may itself be held up (a long callback, the
    process starved of CPU): then messages wait unread in the queues, so a gap in the
    node's own ticks (a timer every ``tick_period`` s calls ``tick``) restarts the count
    instead of reading as silence. A hold-up longer than half ``stale_after`` is seen;
    a shorter one cannot make ``stale_after`` of silence out of a stream that publishes
    at least every ``stale_after / 2`` s."""

    def __init__(self, streams: Iterable[str], stale_after: float) -> None:
        self.stale_after = stale_after
        self.tick_period = stale_after / 4
        self.arrived: dict[str, float | None] = dict.fromkeys(streams)
        self.resumed = time.monotonic()
        self.last_tick: float | None = None

    def heard(self, stream: str) -> None:
        self.tick()
        self.arrived[stream] = time.monotonic()

    def tick(self) -> None:
        """Call from a timer every ``tick_period`` s (``heard`` and ``silent`` tick too): a
        tick later than that by more than half ``stale_after`` means the executor was held up."""
        now = time.monotonic()
        if self.last_tick is not None and now - self.last_tick > self.tick_period + 0.5 * self.stale_after:
            self.resumed = now
        self.last_tick = now

    def silent(self) -> list[str]:
        """Streams never heard, or silent for more than ``stale_after`` s."""
        self.tick()   # called from the executor: a hold-up just ended counts before its timer runs
        now = time.monotonic()
        return [s for s, a in self.arrived.items() if a is None or now - max(a, self.resumed) > self.stale_after]

    @property
    def all_silent(self) -> bool:
        """Some stream was heard and every one is silent now: the data stopped."""
        return any(a is not None for a in self.arrived.values()) and len(self.silent()) == len(self.arrived)


class BadMessages:
    """Malformed messages per input, counted for good, and a warning that holds until good
    data have flowed for ``clear_after`` s of wall time after the last bad one (a node must
    not stay WARN for a glitch long past: the count stays in the figures)."""

    LOG_PERIOD = 5.0   # s between two log lines of bad messages

    def __init__(self, inputs: Iterable[str], clear_after: float) -> None:
        self.counts: dict[str, int] = dict.fromkeys(inputs, 0)
        self.clear_after = clear_after
        self.last = ""                       # "<topic>: what was wrong"
        self.last_at: float | None = None    # wall time (monotonic) of the last bad message
        self.good_at: float | None = None    # of the last good one
        self.logged_at: float | None = None  # of the last one logged

    def bad(self, stream: str, text: str) -> bool:
        """Count a bad message; True where it is to be logged: the first, then one every
        ``LOG_PERIOD`` s. Throttled here, not by rclpy's logger, which finds its caller's
        frame on every call, throttled or not (~0.8 ms: a stream of bad messages at a few
        hundred a second took most of a core)."""
        now = time.monotonic()
        self.counts[stream] += 1
        self.last, self.last_at = text, now
        if self.logged_at is not None and now - self.logged_at < self.LOG_PERIOD:
            return False
        self.logged_at = now
        return True

    def good(self) -> None:
        self.good_at = time.monotonic()

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def warning(self) -> str:
        """The WARN reason while it holds ("" once cleared, or with none ever)."""
        if self.last_at is None:
            return ""
        if self.good_at is not None and self.good_at - self.last_at >= self.clear_after:
            return ""
        return f"{self.total} bad message(s), last: {self.last}"
