"""``rheo bench scaling``: ``rheo analyze`` against the record's length and the tactile
rate: wall time, multiple of real time and peak memory of all its processes.

Each record is the default experiment (package simulator) with the keep and the release
stretched to the length asked (two fifths keep, the rest release), written by ``rheo
simulate``'s own function; ``rheo analyze`` runs in a child process, with and without the
diagnosis, while the bench samples the memory of that process and of every process it
starts (the candidates' fits) every 0.2 s: the peak is of their sum. Each process counts
its proportional set size (its own pages, and each page it shares with others divided by
their number): the candidates' processes are forked, so their resident sizes each count
the parent's pages they only read (libraries, the record) again, and their sum overstates
the machine's memory by those copies.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rheo_ros.app.simulate import simulate_to_bag
from rheo_ros.config.setup import Setup, check_params, load_params

# s between memory samples: a proportional size reads the process's whole page map (~1-3 ms
# each), which every 20 ms took a third of a core from the analysis it measures (3000 s at
# 50 Hz: 28.8 -> 34.0 s); a fit's memory lasts seconds.
SAMPLE_INTERVAL = 0.2


def record_params(length: float, tactile_rate: float) -> dict[str, Any]:
    """The default parameters with the run stretched to ``length`` s and the tactile
    array at ``tactile_rate`` Hz (the stage's rate raised to it where lower: the
    simulator samples on the stage's grid)."""
    params = load_params(None)
    pull = params["stage.start_delay"] + params["stage.depth"] / params["stage.velocity"]
    rest = max(length - pull, 10.0)
    params.update({"stage.keep_time": 0.4 * rest, "stage.release_time": 0.6 * rest,
                   "rates.tactile": float(tactile_rate),
                   "rates.stage": float(max(params["rates.stage"], tactile_rate))})
    return check_params(params, "bench scaling")


def peak_memory(command: list[str]) -> tuple[float, float, int]:
    """Run ``command``: its wall time (s), the peak of the summed proportional set sizes
    (bytes: shared pages split between their sharers) of it and its descendants, and its
    exit code."""
    import psutil

    t0 = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    root, peak = psutil.Process(child.pid), 0
    while child.poll() is None:
        total = 0
        try:
            for p in [root, *root.children(recursive=True)]:
                try:
                    total += p.memory_full_info().pss
                except psutil.Error:   # ended between the listing and the reading
                    pass
        except psutil.Error:
            pass
        peak = max(peak, total)
        time.sleep(SAMPLE_INTERVAL)
    wall = time.perf_counter() - t0
    if child.returncode:
        raise RuntimeError(f"{' '.join(command)} exited {child.returncode}: {child.stderr.read().decode()[-500:]}")
    return wall, float(peak), child.returncode


def run(lengths: str = "170,600", rates: str = "50", seed: int = 1) -> dict[str, Any]:
    """Every length (s) x tactile rate (Hz), comma-separated: the bag's size, and
    ``rheo analyze``'s time and peak memory with the diagnosis and without (``--no-discover``)."""
    rows = []
    for rate in (float(r) for r in rates.split(",")):
        for length in (float(n) for n in lengths.split(",")):
            params = record_params(length, rate)
            with tempfile.TemporaryDirectory() as tmp:
                bag = Path(tmp) / "bag"
                t0 = time.perf_counter()
                counts = simulate_to_bag(Setup(params), seed, bag)
                simulated = time.perf_counter() - t0
                size = sum(f.stat().st_size for f in bag.iterdir())
                row = {"length_s": Setup(params).profile.t_end, "tactile_hz": rate, "messages": sum(counts.values()),
                       "bag_bytes": size, "simulate_s": simulated}
                for mode, extra in (("discover", []), ("no_discover", ["--no-discover"])):
                    wall, peak, _ = peak_memory([sys.executable, "-m", "rheo_ros", "analyze", str(bag), "--quiet",
                                                 *extra])
                    row[f"{mode}_s"], row[f"{mode}_peak_bytes"] = wall, peak
                    row[f"{mode}_x_realtime"] = row["length_s"] / wall
                rows.append(row)
    return {"rows": rows, "seed": seed}


def format_table(result: dict[str, Any]) -> str:
    lines = ["rheo analyze against the record (package simulator; wall time of the command, peak memory of all its "
             "processes: their proportional set sizes summed, shared pages counted once)",
             f"{'record':>9} {'tactile':>8} {'messages':>9} {'bag':>8} | {'analyze':>9} {'x real':>7} {'peak':>8} | "
             f"{'no-discover':>11} {'x real':>7} {'peak':>8} (target: 100 x real time with discovery)"]
    for r in result["rows"]:
        lines.append(
            f"{r['length_s']:>7.0f} s {r['tactile_hz']:>5.0f} Hz {r['messages']:>9d} {r['bag_bytes'] / 1e6:>5.1f} MB | "
            f"{r['discover_s']:>7.1f} s {r['discover_x_realtime']:>6.0f}x {r['discover_peak_bytes'] / 1e9:>5.2f} GB | "
            f"{r['no_discover_s']:>9.1f} s {r['no_discover_x_realtime']:>6.0f}x {r['no_discover_peak_bytes'] / 1e9:>5.2f} GB")
    return "\n".join(lines)
