"""``rheo bench mesh``: how fine the identification's FE mesh must be.

The data come from a much finer mesh (``reference`` x the marker grid's elements:
65 x 65 nodes at 16) of the quasi-static plane-stress model, noise-free, read as the
sensors read them (markers interpolated at their positions, each tactile segment
the bottom pressure integrated over its columns). The whole-record fit then
identifies E, c1, c2 and gamma with the forward model at each refinement level;
the errors against the true values are the discretisation error of that level
(the data's own, from the reference mesh, is printed beside: the same fit on data
from a mesh twice as fine again).

Independent of the identifier's own mesh; not of its physics (the quasi-static
limit, the correspondence principle): that is the simulator's (dynamic) part.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from rheo_ros.bench.cases import TABLE_IV
from rheo_ros.config.setup import Setup, load_params
from rheo_ros.experiment import StageProfile, sample_times
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.fit import DISCRETISATION_RATIO, fit_record
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record

LEVELS = (1, 2, 3, 4, 6, 8)
REFERENCE = 16
PARAMETERS = ("E", "c1", "c2", "gamma")
# The convergence order: data from this level (257 x 257 nodes) fitted at the levels
# below; each halving's shift over the previous one is 2^-p.
ORDER_DATA, ORDER_LEVELS = 64, (8, 16, 32)


def fine_mesh_record(setup: Setup, truth: dict[str, float], refine_level: int, profile: StageProfile) -> Record:
    """Noise-free data of the quasi-static model on the marker grid refined
    ``refine_level`` times, sampled at the contract's rates."""
    p = setup.params
    forward = QuasiStaticFE(setup.mesh, refine_level, setup.tactile.segment_edges)
    model = Model(three_element(truth["E"], truth["c1"], truth["c2"]))
    stage_t, force_t, marker_t = (sample_times(profile.t_end, p[f"rates.{k}"]) for k in ("stage", "tactile", "markers"))
    pred = forward.predict(model, truth["gamma"], profile, force_t, marker_t)
    return Record(mesh=setup.mesh, stage_t=stage_t, stage_depth=profile.depth_at(stage_t), force_t=force_t,
                  force=pred.force, marker_t=marker_t, markers=setup.mesh.nodes[None] + pred.displacement,
                  source=f"quasi-static FE, refine {refine_level}", stage_profile=profile)


def run(boundaries: tuple[tuple[str, str], ...] = (("bonded", "bonded"),)) -> dict[str, Any]:
    truth = dict(TABLE_IV)
    # The quasi-static model lets go at once: the stage leaves the specimen at release.
    profile = StageProfile(keep_time=48.0, release_time=60.0)
    start = Estimate({k: v * 1.05 for k, v in truth.items()}, "start", ())
    out = []
    for bottom, top in boundaries:
        setup = Setup({**load_params(None), "boundary.bottom": bottom, "boundary.top": top})
        rows = []
        for data_level in (REFERENCE, 2 * REFERENCE):
            record = fine_mesh_record(setup, truth, data_level, profile)
            for level in (LEVELS if data_level == REFERENCE else (REFERENCE,)):
                forward = QuasiStaticFE(setup.mesh, level, setup.tactile.segment_edges)
                t0 = time.perf_counter()
                est = fit_record(record, start, forward=forward)
                rows.append({"data_refine": data_level, "refine": level, "fe_nodes": forward.fe_mesh.nodes.shape[0],
                             "error_pct": est.relative_errors(truth), "fit_s": time.perf_counter() - t0})
        out.append({"boundary": {"bottom": bottom, "top": top}, "rows": rows, "order": convergence(setup, truth, profile, start)})
    return {"truth": truth, "reference_refine": REFERENCE, "cases": out}


def convergence(setup: Setup, truth: dict[str, float], profile: StageProfile, start: Estimate) -> dict[str, Any]:
    """Fits at ``ORDER_LEVELS`` of data from ``ORDER_DATA``: the parameters (%, against the
    truth) and, per parameter, the ratio of successive shifts (2^-p; the identification's
    ``DISCRETISATION_RATIO``)."""
    record = fine_mesh_record(setup, truth, ORDER_DATA, profile)
    fits = [fit_record(record, start, forward=QuasiStaticFE(setup.mesh, level, setup.tactile.segment_edges),
                   discretisation=False).relative_errors(truth) for level in ORDER_LEVELS]
    errors = np.array([[fit[k] for k in PARAMETERS] for fit in fits])
    shifts = np.diff(errors, axis=0)
    return {"data_refine": ORDER_DATA, "levels": list(ORDER_LEVELS), "error_pct": errors.tolist(),
            "ratio": (shifts[1:] / shifts[:-1]).tolist()}


def format_table(r: dict[str, Any]) -> str:
    lines = [f"mesh convergence: noise-free data from the quasi-static plane-stress FE at refine "
             f"{r['reference_refine']} ({4 * r['reference_refine'] + 1} x {4 * r['reference_refine'] + 1} nodes), "
             "fitted at each level; error of each parameter against the truth, %"]
    for case in r["cases"]:
        b = case["boundary"]
        lines.append(f"  boundary: bottom {b['bottom']}, top {b['top']}")
        lines.append(f"    {'data':>5} {'refine':>6} {'FE nodes':>8} {'E':>9} {'c1':>9} {'c2':>9} {'gamma':>9} {'fit s':>6}")
        for row in case["rows"]:
            e = row["error_pct"]
            lines.append(f"    {row['data_refine']:>5} {row['refine']:>6} {row['fe_nodes']:>8} "
                         + " ".join(f"{e[k]:>+9.4f}" for k in PARAMETERS) + f" {row['fit_s']:>6.1f}")
        o = case["order"]
        for level, e in zip(o["levels"], o["error_pct"]):
            lines.append(f"    {o['data_refine']:>5} {level:>6} {'':>8} " + " ".join(f"{v:>+9.4f}" for v in e))
        for (a, b, c), ratio in zip(zip(o["levels"], o["levels"][1:], o["levels"][2:]), o["ratio"]):
            lines.append(f"    shift {b}->{c} over {a}->{b} (2^-p): " + " ".join(
                f"{k} {v:.3f}" for k, v in zip(PARAMETERS, ratio)) + " (identification: DISCRETISATION_RATIO "
                f"{DISCRETISATION_RATIO})")
    return "\n".join(lines)
