"""``rheo simulate``: a run of the simulator written straight to a bag (same physics as
the nodes, no DDS)."""

from __future__ import annotations

import shutil
from pathlib import Path

from rheo_ros.config.setup import Setup
from rheo_ros.io.bag import write_run
from rheo_ros.rig.simulator import simulate_run


def simulate_to_bag(setup: Setup, seed: int, out: str | Path) -> dict[str, int]:
    """Simulate a run and write the bag directly (same physics as the nodes, no DDS).
    Returns the message count per topic; a failure leaves no bag behind."""
    run = simulate_run(setup, seed)
    try:
        return write_run(run, {**setup.params, "simulator.seed": seed}, out)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)  # no half-written bag to trip the next run
        raise
