"""``rheo demo``: the live system on the default experiment, end to end over DDS.

Simulator (driving ``/clock``: as fast as the nodes exchange messages), stage (on
simulated time), segmenter and estimator run as four processes; this process listens
to ``/rheo/phase`` and ``/rheo/estimate``, prints each as it arrives, and ends with the
final estimate beside the simulator's true parameters.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from rheo_ros.params import load_params, params_yaml

NODES = ("simulator", "segmenter", "estimator", "stage")


def stop_processes(procs: Iterable[subprocess.Popen], timeout: float = 10.0) -> None:
    """Ctrl-C to every node still running (they clean up: the stage retracts), then wait;
    kill what does not end within ``timeout`` s."""
    procs = list(procs)
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()


def _format(update: dict) -> str:
    parts = []
    for name, value in update["params"].items():
        std = update["std"].get(name)
        if not np.isfinite(value):
            parts.append(f"{name} not determined")
        elif std is not None and np.isfinite(std):
            parts.append(f"{name} {value:.4g} +- {std:.2g}")
        else:
            parts.append(f"{name} {value:.4g}")
    return (f"  t = {update['stamp']:7.2f} s  after {update['phase']:<7} {update['method']:<17} "
            + ", ".join(parts) + f"  (force RMS {update['rmse_force']:.3g} N)")


def run_demo(params_file: str | None = None, timeout: float = 120.0) -> int:
    """Run the four nodes, print the estimates; 0 when the final estimate arrived."""
    params = load_params(params_file)
    params["simulator.clock"] = True
    params["stage.wait_for_subscribers"] = 3      # simulator, segmenter, estimator: nobody misses the start
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
    os.environ.update({k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID")})

    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rheo_ros_interfaces.msg import Estimate, Phase

    from rheo_ros.io.messages import ESTIMATE_TOPIC, PHASE_TOPIC, read_estimate, stamp_ns

    tmp = Path(tempfile.mkdtemp(prefix="rheo-demo-"))
    (tmp / "params.yaml").write_text(params_yaml(params))
    bin_dir = Path(sys.executable).parent
    procs: dict[str, subprocess.Popen] = {}
    rclpy.init()
    node = rclpy.create_node("rheo_demo")
    updates: list[dict] = []
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)

    def on_phase(msg: Phase) -> None:
        print(f"  t = {stamp_ns(msg) * 1e-9:7.2f} s  phase {msg.name} of experiment {msg.experiment}: "
              f"{msg.start.sec + msg.start.nanosec * 1e-9:.3f} .. {msg.end.sec + msg.end.nanosec * 1e-9:.3f} s",
              flush=True)

    def on_estimate(msg: Estimate) -> None:
        updates.append(read_estimate(msg))
        print(_format(updates[-1]), flush=True)

    node.create_subscription(Phase, PHASE_TOPIC, on_phase, qos)
    node.create_subscription(Estimate, ESTIMATE_TOPIC, on_estimate, qos)
    start = time.monotonic()
    try:
        for name in NODES:
            cmd = [str(bin_dir / name), "--ros-args", "--params-file", str(tmp / "params.yaml")]
            if name == "stage":
                cmd += ["-p", "use_sim_time:=true"]
            procs[name] = subprocess.Popen(cmd, env=env, stdout=(tmp / f"{name}.log").open("w"),
                                           stderr=subprocess.STDOUT)
        print(f"rheo demo: {', '.join(NODES)} started (ROS_DOMAIN_ID {env['ROS_DOMAIN_ID']}, logs in {tmp}); "
              f"pushing {params['stage.depth'] * 1e3:g} mm at {params['stage.velocity'] * 1e3:g} mm/s, "
              f"keep {params['stage.keep_time']:g} s", flush=True)
        final = None
        while final is None:
            rclpy.spin_once(node, timeout_sec=0.1)
            final = next((u for u in updates if u["final"]), None)
            dead = [n for n, p in procs.items() if p.poll() is not None]
            if dead or time.monotonic() - start > timeout:
                why = f"{', '.join(dead)} exited" if dead else f"no final estimate after {timeout:g} s"
                print(f"rheo demo: error: {why} (logs in {tmp})", file=sys.stderr)
                return 1
        wall = time.monotonic() - start
        truth = {"E": params["material.E"], "c1": params["material.c1"], "c2": params["material.c2"],
                 "gamma": params["material.gamma"]}
        print(f"\nfinal estimate after {final['stamp']:.1f} s of experiment ({wall:.1f} s wall), "
              f"{final['method']}:")
        print(f"  {'param':<6} {'estimate':>12} {'std':>10} {'true':>12} {'error %':>9} {'error/std':>9}")
        for k, v in truth.items():
            est, std = final["params"].get(k, np.nan), final["std"].get(k, np.nan)
            print(f"  {k:<6} {est:12.5g} {std:10.2g} {v:12.5g} {100 * (est / v - 1):9.3f} {(est - v) / std:9.2f}")
        effects = params["simulator.effects"]
        if any(effects):
            print(f"  (the simulator had hidden effects {', '.join(e for e in effects if e)}: "
                  "the three-element fit is then misspecified)")
        return 0
    finally:
        stop_processes(procs.values())
        node.destroy_node()
        rclpy.try_shutdown()
