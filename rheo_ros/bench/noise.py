"""``rheo bench noise``: the estimators under measurement noise, against the Cramer-Rao bound.

The 2D default experiment with the Table IV parameters is simulated once; each
replicate adds fresh Gaussian noise (1 % of each node's peak force, 20 um per
marker coordinate) and is identified by the paper's closed-form method and by the
whole-record refinement started from it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rheo_ros.bench.cases import table_iv_case
from rheo_ros.identification.closed_form import from_final_displacement
from rheo_ros.identification.fit import WholeRecordProblem, cramer_rao_std, fit_record
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record, RecordError


@dataclass(frozen=True)
class Noise:
    """Additive Gaussian noise of known std on a noise-free record: ``force`` as a
    fraction of each node's peak force, ``markers`` in m per coordinate.

    Not a sensor (the simulator's sensors are ``rheo_ros.sensors``, with their dead band,
    clipping and quantisation, calibrated by ``rheo bench calibration``): the
    Cramer-Rao bound this bench compares with is defined for additive Gaussian noise of
    known std, so the replicates get exactly that."""

    force: float = 0.01
    markers: float = 20e-6

    def force_std(self, record: Record) -> np.ndarray:
        return self.force * np.abs(record.force).max(axis=0)

    def apply(self, record: Record, rng: np.random.Generator) -> Record:
        force = record.force + rng.standard_normal(record.force.shape) * self.force_std(record)
        markers = record.markers + rng.standard_normal(record.markers.shape) * self.markers
        return replace(record, force=force, markers=markers)


def run(replicates: int = 200, seed: int = 0, noise: Noise | None = None) -> dict[str, Any]:
    noise = noise or Noise()
    case = table_iv_case()
    truth, clean = case.truth, case.record
    problem = WholeRecordProblem(clean, Model(three_element(1.0, 1.0, 1.0)), noise.force_std(clean), noise.markers,
                                 delays=True)
    bound = cramer_rao_std(problem, truth)
    estimates: dict[str, list[list[float]]] = {"closed_form": [], "whole_record": []}
    failures = {"closed_form": 0, "whole_record": 0}
    for i in range(replicates):
        record = noise.apply(clean, np.random.default_rng([seed, i]))
        try:
            closed = from_final_displacement(record)
        except RecordError:
            failures["closed_form"] += 1
            failures["whole_record"] += 1
            continue
        estimates["closed_form"].append([closed.params[k] for k in truth])
        try:
            fit = fit_record(record, closed)
            estimates["whole_record"].append([fit.params[k] for k in truth])
        except (RecordError, np.linalg.LinAlgError):
            failures["whole_record"] += 1
    methods = {}
    for name, rows in estimates.items():
        values = np.array(rows)
        stats = {}
        for j, k in enumerate(truth):
            col = values[:, j]
            std = float(np.std(col, ddof=1))
            stats[k] = {
                "bias": float(col.mean() - truth[k]),
                "bias_pct": float(100 * (col.mean() - truth[k]) / truth[k]),
                "std": std,
                "std_pct": float(100 * std / truth[k]),
                "crlb_std": bound[k],
                "std_over_crlb": std / bound[k],
            }
        methods[name] = {"replicates": len(rows), "failures": failures[name], "params": stats}
    return {
        "case": case.name, "truth": truth, "replicates": replicates, "seed": seed,
        "noise": {"force_fraction_of_node_peak": noise.force, "marker_m": noise.markers},
        "crlb_std": bound, "methods": methods,
    }


def format_table(result: dict[str, Any]) -> str:
    n = result["noise"]
    lines = [
        f"{result['case']}: {result['replicates']} replicates, seed {result['seed']}, "
        f"force noise {100 * n['force_fraction_of_node_peak']:g} % of node peak, marker noise "
        f"{1e6 * n['marker_m']:g} um",
        f"  {'method':<13} {'param':<6} {'true':>10} {'bias%':>9} {'std%':>9} {'CRLB%':>9} {'std/CRLB':>9}",
    ]
    for name, m in result["methods"].items():
        for k, s in m["params"].items():
            t = result["truth"][k]
            lines.append(f"  {name:<13} {k:<6} {t:>10.4g} {s['bias_pct']:>9.3f} {s['std_pct']:>9.3f} "
                         f"{100 * s['crlb_std'] / t:>9.3f} {s['std_over_crlb']:>9.3f}")
        lines.append(f"  {name:<13} fits: {m['replicates']} done, {m['failures']} failed")
    return "\n".join(lines)
