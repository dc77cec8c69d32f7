"""``rheo simulate``: a run of the simulator written straight to a bag (same physics as
the nodes, no DDS)."""

from __future__ import annotations

import shutil
from pathlib import Path

from rheo_ros.config.setup import ParamsError, Setup
from rheo_ros.io.bag import write_run
from rheo_ros.rig.simulator import simulate_run

# The whole run is held in memory before it is written (the simulator node streams it
# instead): a keep of 1e9 s was an allocation of 745 GiB and a traceback (issue 21).
MAX_RUN_BYTES = 4 * 2**30


def run_bytes(setup: Setup) -> float:
    """The bytes of the samples a whole run holds: stage depth and velocity, the tactile
    images, the marker frames (float64), over the profile's length."""
    p = setup.params
    per_second = (p["rates.stage"] * 2 + p["rates.tactile"] * p["tactile.rows"] * p["tactile.cols"]
                  + p["rates.markers"] * setup.mesh.nodes.size) * 8
    return setup.profile.t_end * per_second


def simulate_to_bag(setup: Setup, seed: int, out: str | Path) -> dict[str, int]:
    """Simulate a run and write the bag directly (same physics as the nodes, no DDS).
    Returns the message count per topic; a failure leaves no bag behind.

    Raises:
        ParamsError: a run too long, or sampled too fast, to hold in memory (names the
            parameters that make it)."""
    need = run_bytes(setup)
    if need > MAX_RUN_BYTES:
        raise ParamsError(f"stage.*, rates.*: a run of {setup.profile.t_end:.4g} s at these rates holds "
                          f"{need / 2**30:.3g} GiB of samples, more than the {MAX_RUN_BYTES / 2**30:g} GiB rheo "
                          "simulate holds; shorten stage.keep_time, stage.release_time or stage.pushes, or lower "
                          "rates.*")
    run = simulate_run(setup, seed)
    try:
        return write_run(run, {**setup.params, "simulator.seed": seed}, out)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)  # no half-written bag to trip the next run
        raise
