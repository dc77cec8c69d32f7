"""``rheo bench online``: the estimator node under a stream of experiments over DDS.

A short push-keep-release (2 mm at 2 mm/s, keep 2 s, 30 s of release) is simulated
into a bag; an estimator node runs as its own process; ``rheo play --loop N`` replays
the bag N times (stamps shifted each pass) at ``rate`` times real time. Measured:

- latency from the arrival of the message that completes a phase to the publication
  of its estimate (the node's own clock; closed-form and whole-record updates apart),
  p50 and p99 as the node reports them on ``/diagnostics``;
- the node's CPU share while idle (no data, 10 s);
- its resident memory after each experiment (flat = bounded buffers).

CPU and memory count the node's fit worker process too.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rheo_ros.app.demo import stop_processes
from rheo_ros.app.simulate import simulate_to_bag
from rheo_ros.config.setup import Setup, load_params

SHORT_RUN = {"stage.depth": 0.002, "stage.velocity": 0.002, "stage.keep_time": 2.0, "stage.release_time": 30.0}


def _cpu_seconds(pid: int) -> float:
    """CPU time of a process and its children, s."""
    total = 0
    for p in _process_tree(pid):
        fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        total += int(fields[11]) + int(fields[12])
    return total / os.sysconf("SC_CLK_TCK")


def _process_tree(pid: int) -> list[int]:
    """``pid`` and its descendants (the estimator's fit worker)."""
    pids = [pid]
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            pids += _process_tree(int(child))
    return pids


def _rss_mb(pid: int) -> float:
    """Resident memory of a process and its children, MB."""
    total = 0.0
    for p in _process_tree(pid):
        for line in Path(f"/proc/{p}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                total += int(line.split()[1]) / 1024
    return total


def run(experiments: int = 100, rate: float = 10.0, idle: float = 10.0, closed_form_priority: int = 0
        ) -> dict[str, Any]:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rheo_ros_interfaces.msg import Estimate

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(180 + os.getpid() % 40))
    os.environ.update({k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID")})
    tmp = Path(tempfile.mkdtemp(prefix="rheo-bench-online-"))
    params = {**load_params(None), **SHORT_RUN}
    simulate_to_bag(Setup(params), 0, tmp / "bag")
    bin_dir = Path(sys.executable).parent
    est = subprocess.Popen([str(bin_dir / "estimator"), "--ros-args", "-p",
                            f"estimator.closed_form_priority:={closed_form_priority}"],
                           env=env, stdout=(tmp / "estimator.log").open("w"), stderr=subprocess.STDOUT)
    rclpy.init()
    node = rclpy.create_node("bench_online")
    finals: list[float] = []
    rss: list[float] = []
    status: dict[str, str] = {}

    def on_estimate(msg: Estimate) -> None:
        if msg.final:
            finals.append(time.monotonic())
            rss.append(_rss_mb(est.pid))
            print(f"  experiment {msg.experiment}: final estimate; estimator RSS {rss[-1]:.1f} MB", flush=True)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.name.endswith("estimator"):
                status.clear()
                status.update({kv.key: kv.value for kv in s.values})
                status["message"] = s.message

    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(Estimate, "/rheo/estimate", on_estimate, qos)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    try:
        ready = time.monotonic() + 60.0       # start-up (imports, worker processes, DDS discovery)
        while not status and time.monotonic() < ready:
            rclpy.spin_once(node, timeout_sec=0.1)
        time.sleep(2.0)
        rss_start = _rss_mb(est.pid)
        c0, t0 = _cpu_seconds(est.pid), time.monotonic()
        time.sleep(idle)
        idle_share = (_cpu_seconds(est.pid) - c0) / (time.monotonic() - t0)
        start = time.monotonic()
        play = subprocess.Popen([str(bin_dir / "rheo"), "play", str(tmp / "bag"), "--rate", str(rate), "--loop",
                                 str(experiments), "--wait-for-subscribers", "1"], env=env,
                                stdout=subprocess.DEVNULL, stderr=(tmp / "play.log").open("w"))
        while play.poll() is None or (len(finals) < experiments and time.monotonic() - start < 60 + 3600):
            rclpy.spin_once(node, timeout_sec=0.1)
            if play.poll() is not None and time.monotonic() - (finals[-1] if finals else start) > 30:
                break
        end = time.monotonic() + 3.0
        while time.monotonic() < end:           # one more diagnostics message
            rclpy.spin_once(node, timeout_sec=0.1)
        return {
            "experiments": experiments, "completed": len(finals), "rate_x_realtime": rate,
            "closed_form_priority": closed_form_priority,
            "experiment_s": Setup(params).profile.t_end, "wall_s": time.monotonic() - start,
            "idle_cpu_share": idle_share, "rss_mb_start": rss_start, "rss_mb": rss,
            "latency_ms": {f"{k} {q}": float(status.get(f"latency {k} {q} ms", "nan"))
                           for k in ("closed_form", "closed_form worker", "closed_form compute", "whole_record")
                           for q in ("p50", "p99")},
            "latency_n": {k: int(status.get(f"latency {k} n", 0)) for k in ("closed_form", "whole_record")},
            "diagnostics": status.get("message", ""),
        }
    finally:
        stop_processes([est])
        node.destroy_node()
        rclpy.try_shutdown()


def format_table(r: dict[str, Any]) -> str:
    rss = r["rss_mb"]
    pick = [rss[i] for i in (0, len(rss) // 4, len(rss) // 2, 3 * len(rss) // 4, len(rss) - 1)] if rss else []
    lat = r["latency_ms"]
    return "\n".join([
        f"estimator node over DDS: {r['completed']}/{r['experiments']} experiments of {r['experiment_s']:.0f} s "
        f"replayed at {r['rate_x_realtime']:g} x real time in {r['wall_s']:.0f} s (estimator.closed_form_priority "
        f"{r['closed_form_priority']}: " + ("normal scheduling)" if not r["closed_form_priority"] else "SCHED_FIFO)"),
        f"  latency, last message of a phase -> estimate published (node clock, last "
        f"{r['latency_n']['closed_form']} updates each):",
        f"    closed form (paper):    p50 {lat['closed_form p50']:.1f} ms, p99 {lat['closed_form p99']:.1f} ms "
        "(target p99 < 50 ms)",
        f"      of which its worker:  p50 {lat['closed_form worker p50']:.1f} ms, p99 {lat['closed_form worker p99']:.1f} ms "
        "(round trip to the worker process and the closed form)",
        f"      of which computing:   p50 {lat['closed_form compute p50']:.1f} ms, "
        f"p99 {lat['closed_form compute p99']:.1f} ms (the closed form in the worker process)",
        f"    whole-record fit:       p50 {lat['whole_record p50']:.1f} ms, p99 {lat['whole_record p99']:.1f} ms",
        f"  CPU while idle: {100 * r['idle_cpu_share']:.2f} % of one core",
        f"  memory (RSS): {r['rss_mb_start']:.1f} MB before; after experiments 1, 25 %, 50 %, 75 %, last: "
        + ", ".join(f"{m:.1f}" for m in pick) + " MB",
        f"  diagnostics at the end: {r['diagnostics']}",
    ])
