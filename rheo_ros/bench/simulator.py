"""``rheo bench simulator``: how fast the simulator writes a bag, as a multiple of real time."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from rheo_ros.app.simulate import simulate_to_bag
from rheo_ros.config.setup import Setup, load_params
from rheo_ros.rig.simulator import simulate_run


def run(repeats: int = 3) -> dict[str, Any]:
    """Best of ``repeats`` wall times for the default run (5 x 5 markers on the converged
    FE mesh), physics alone and with the bag written, and a new specimen's first run with
    the bag written (which builds what the runs of one specimen share: each repeat's
    specimen a Poisson ratio of its own, as the bags of a bench each have)."""
    params = load_params(None)
    setup = Setup(params)
    duration = setup.profile.t_end
    first = []
    for i in range(repeats):
        specimen = Setup({**params, "material.gamma": params["material.gamma"] + 0.001 * (i + 1)})
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            simulate_to_bag(specimen, i, Path(tmp) / "bag")
            first.append(time.perf_counter() - t0)
    simulate_run(setup, 0)  # builds the default specimen's condensed mesh and flows, kept for the runs after
    physics, total = [], []
    for i in range(repeats):
        t0 = time.perf_counter()
        simulate_run(setup, i)
        physics.append(time.perf_counter() - t0)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            counts = simulate_to_bag(setup, i, Path(tmp) / "bag")
            total.append(time.perf_counter() - t0)
            size = sum(f.stat().st_size for f in (Path(tmp) / "bag").iterdir())
    refine = setup.params["simulator.refine"]
    return {
        "simulated_s": duration, "mesh": f"{setup.mesh.rows} x {setup.mesh.cols}",
        "fe_mesh": f"{(setup.mesh.rows - 1) * refine + 1} x {(setup.mesh.cols - 1) * refine + 1}", "messages": counts,
        "first_s": min(first), "physics_s": min(physics), "bag_s": min(total), "bag_bytes": size,
        "physics_x_realtime": duration / min(physics), "bag_x_realtime": duration / min(total),
    }


def format_table(r: dict[str, Any]) -> str:
    return (f"simulator, {r['mesh']} markers on a {r['fe_mesh']} FE mesh, {r['simulated_s']:.0f} s simulated, "
            f"{sum(r['messages'].values())} messages, bag {r['bag_bytes'] / 1e6:.2f} MB\n"
            f"  physics + sensors: {r['physics_s']:.3f} s = {r['physics_x_realtime']:.0f} x real time\n"
            f"  writing the bag:   {r['bag_s']:.3f} s = {r['bag_x_realtime']:.0f} x real time (target >= 200 x)\n"
            f"  a new specimen's first run, the bag written (its condensed mesh and flows built): "
            f"{r['first_s']:.3f} s = {r['simulated_s'] / r['first_s']:.0f} x real time (target >= 200 x)")
