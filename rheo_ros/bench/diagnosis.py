"""``rheo bench diagnosis``: the model-discovery loop's confusion table over generated bags.

Each bag is a simulator run (dynamic FE on its own finer mesh, the noisy sensor path)
with parameters drawn from ``numpy.random.default_rng(seed)``:

- material: E log-uniform 1e4..1e5 Pa, c1 / E uniform 2..15 s, c2 / E uniform
  300..3000 s, gamma uniform 0.2..0.45;
- stage: depth uniform 5..12 mm, keep 15..40 s, release 20..40 s (the brief's ranges
  are 15..60 and 20..60 s; cut to their shorter part because 5 bags over the full
  ranges took 50 s each, 84 min for 100, the analysis time growing with the record);
- sensors: tactile noise uniform 60..150 Pa per cell, marker noise 1e-5..3e-5 m;
- geometry: ``plane_fe`` (80 %) or ``uniaxial`` (20 %, frictionless faces);
- hidden effect: bag ``i`` has class ``i mod 5`` of (none, relaxation_branch,
  adhesion, strain_stiffening, sensor_drift), with a magnitude from barely detectable
  to large (``draw_effect``).

Each bag is analysed by ``analyze`` (every candidate, default workers) as ``rheo
analyze`` would; the diagnosed class is the first missing effect, ``undecided`` when
the first diagnosis cannot decide, else ``none``. A bag that cannot be made or read
counts as ``failed`` with its message.

The **effect size** is independent of the analysis: the RMS over the force readings of
the change the hidden effect makes in the noise-free total bottom force, over the std
of the total force's noise (``sqrt(rows cols) x tactile.noise x cell_area``). It is
computed with the identification's forward model (``QuasiStaticFE.predict``) and the
true parameters, with and without the effect, not with a second simulator run: the
simulator's noise-free run costs about as much as the analysis (measured: 20-40 s of a
bag's 40-80 s), while ``predict`` takes 0.04 s and gives the simulator's size within
0.1 % (checked on one bag of each effect). ``size_live`` is the same with each
segment's noise-free force through the array's dead band (below ``tactile.threshold``
per cell it reads zero, and it reads no tension): an adhesion of a few percent, or a
drift below zero before contact, can be large by ``size`` and still unreadable.

The **detection threshold** is the smallest readable effect size ``s`` (``size_live``)
such that at least 98 % of the bags with an effect of that size or more are diagnosed
correctly (undecided and failed count as wrong).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
import traceback
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rheo_ros.app.analyze import analyze
from rheo_ros.config.setup import ParamsError, Setup, check_params
from rheo_ros.io.bag import write_run
from rheo_ros.io.errors import BagError
from rheo_ros.record import RecordError
from rheo_ros.rig.simulator import simulate_run

EFFECTS = ("relaxation_branch", "adhesion", "strain_stiffening", "sensor_drift")
CLASSES = ("none", *EFFECTS)
COLUMNS = (*CLASSES, "undecided", "failed")
TARGET = 0.98
# Uniform ranges (s) of the keep and of the release: full runs, and quick ones for tests.
KEEP, RELEASE = (15.0, 40.0), (20.0, 40.0)
QUICK_KEEP, QUICK_RELEASE = (15.0, 18.0), (20.0, 24.0)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_effect(rng: np.random.Generator, effect: str, E: float, keep_time: float) -> dict[str, float]:
    """The hidden effect's parameters, from barely detectable to large."""
    if effect == "relaxation_branch":
        stiffness = _log_uniform(rng, 0.003, 0.5) * E
        return {"stiffness": stiffness, "viscosity": stiffness * float(rng.uniform(1.0, keep_time / 3))}
    if effect == "adhesion":
        return {"fraction": _log_uniform(rng, 0.002, 0.4), "time": _log_uniform(rng, 10.0, 300.0)}
    if effect == "strain_stiffening":
        return {"coefficient": _log_uniform(rng, 0.02, 6.0)}
    if effect == "sensor_drift":
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return {"offset": float(rng.uniform(0.0, 0.3)), "rate": sign * _log_uniform(rng, 1e-5, 3e-3)}
    raise KeyError(effect)


def draw_bag(rng: np.random.Generator, index: int, quick: bool = False) -> tuple[str, dict[str, Any], int]:
    """The ``index``-th bag's true class, its parameters (flat, unchecked) and simulator seed.

    ``quick``: the shortest records of the ranges (keep 15-18 s, release 20-24 s)."""
    E = _log_uniform(rng, 1e4, 1e5)
    keep = float(rng.uniform(*(QUICK_KEEP if quick else KEEP)))
    params: dict[str, Any] = {
        "geometry": "uniaxial" if rng.random() < 0.2 else "plane_fe",
        "material.E": E,
        "material.c1": E * float(rng.uniform(2.0, 15.0)),
        "material.c2": E * float(rng.uniform(300.0, 3000.0)),
        "material.gamma": float(rng.uniform(0.2, 0.45)),
        "stage.depth": float(rng.uniform(0.005, 0.012)),
        "stage.keep_time": keep,
        "stage.release_time": float(rng.uniform(*(QUICK_RELEASE if quick else RELEASE))),
        "tactile.noise": float(rng.uniform(60.0, 150.0)),
        "markers.noise": float(rng.uniform(1e-5, 3e-5)),
    }
    true = CLASSES[index % len(CLASSES)]
    if true != "none":
        params["simulator.effects"] = [true]
        params |= {f"effects.{true}.{k}": v for k, v in draw_effect(rng, true, E, keep).items()}
    seed = int(rng.integers(0, 2**31 - 1))
    return true, params, seed


def effect_size(setup: Setup, force_t: np.ndarray, marker_t: np.ndarray) -> dict[str, float]:
    """The hidden effects' size at the force readings ``force_t``: the RMS of their change
    of the noise-free total bottom force (the forward model with the true parameters)
    over the total force's noise std; ``size_live``: the same with each segment's
    force through the dead band (zero below ``tactile.threshold`` per cell)."""
    if not setup.effect_ids:
        return {"size": 0.0, "size_live": 0.0}
    forward, profile, gamma = setup.forward_model(), setup.profile, setup.gamma
    model = setup.model()
    plain = replace(model, effects=())
    with_effect = forward.predict(model, gamma, profile, force_t, marker_t).force
    without = forward.predict(plain, gamma, profile, force_t, marker_t).force
    tactile = setup.tactile
    noise_std = np.sqrt(tactile.rows * tactile.cols) * tactile.noise * tactile.cell_area
    out = {}
    for key, clip in (("size", False), ("size_live", True)):
        a, b = ((tactile.dead_band.reading(f) for f in (with_effect, without)) if clip
                else (with_effect, without))
        diff = a.sum(axis=1) - b.sum(axis=1)
        out[key] = float(np.sqrt(np.mean(diff**2)) / noise_std)
    return out


def make_bag(setup: Setup, seed: int, out: Path) -> dict[str, float]:
    """Write the bag of ``setup`` (its effects hidden in the data) and return its effect
    sizes (``effect_size``)."""
    run = simulate_run(setup, seed)
    try:
        write_run(run, {**setup.params, "simulator.seed": seed}, out)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    return effect_size(setup, run.tactile_t, run.marker_t)


def diagnosed_class(analysis: Any) -> str:
    if analysis.missing_effects:
        return analysis.missing_effects[0]
    if analysis.diagnoses and analysis.diagnoses[0].undecided:
        return "undecided"
    return "none"


def run_bag(index: int, true: str, params: dict[str, Any], seed: int, directory: Path) -> dict[str, Any]:
    """Make, analyse and delete one bag; its row of the result."""
    row: dict[str, Any] = {
        "index": index, "true": true, "seed": seed, "geometry": params["geometry"],
        "params": {k: v for k, v in params.items() if k != "simulator.effects"},
        "effect": {k.split(".", 2)[2]: v for k, v in params.items() if k.startswith("effects.")},
        "size": 0.0, "size_live": 0.0, "diagnosed": "failed", "missing_effects": [], "undecided": [],
        "evidence": "", "simulate_seconds": 0.0, "seconds": 0.0, "message": "",
    }
    out = directory / f"bag{index:04d}"
    try:
        t0 = time.perf_counter()
        setup = Setup(check_params(params, f"bag {index}"))
        row |= make_bag(setup, seed, out)
        row["simulate_seconds"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            analysis = analyze(out)
        finally:
            row["seconds"] = time.perf_counter() - t0
        row["diagnosed"] = diagnosed_class(analysis)
        row["missing_effects"] = list(analysis.missing_effects)
        row["undecided"] = list(analysis.diagnoses[0].undecided) if analysis.diagnoses else []
        row["evidence"] = analysis.diagnoses[0].evidence if analysis.diagnoses else ""
    except (BagError, RecordError, ParamsError) as exc:
        row["message"] = f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # noqa: BLE001 - one bag must not end a long bench
        row["message"] = f"unexpected {type(exc).__name__}: {exc}"
        traceback.print_exc(file=sys.stderr)
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return row


def confusion(rows: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    table = {t: {c: 0 for c in COLUMNS} for t in CLASSES}
    for r in rows:
        table[r["true"]][r["diagnosed"]] += 1
    return table


def detection_threshold(rows: list[dict[str, Any]], target: float = TARGET) -> dict[str, Any]:
    """The smallest readable effect size (``size_live``) above which at least ``target``
    of the bags with an effect are diagnosed correctly; None when even the largest alone
    is wrong."""
    effect = sorted((r for r in rows if r["true"] != "none"), key=lambda r: r["size_live"])
    correct = np.array([r["diagnosed"] == r["true"] for r in effect], dtype=float)
    for k in range(len(effect)):
        above = correct[k:]
        if above.mean() >= target:
            return {"threshold": effect[k]["size_live"], "bags_above": int(above.size),
                    "correct_above": int(above.sum()), "accuracy_above": float(above.mean()),
                    "bags_below": k, "correct_below": int(correct[:k].sum())}
    return {"threshold": None, "bags_above": 0, "correct_above": 0, "accuracy_above": None,
            "bags_below": len(effect), "correct_below": int(correct.sum())}


def per_effect_thresholds(rows: list[dict[str, Any]], target: float = TARGET) -> dict[str, dict[str, Any]]:
    """:func:`detection_threshold` over each hidden effect's bags alone (the effects differ
    in how much of their size the diagnosis can see)."""
    return {e: detection_threshold([r for r in rows if r["true"] == e], target)
            for e in EFFECTS if any(r["true"] == e for r in rows)}


def run(replicates: int = 100, seed: int = 0, quick: bool = False) -> dict[str, Any]:
    """Generate, analyse and score ``replicates`` bags (module docstring).

    ``quick``: the shortest records of the ranges (for tests)."""
    rng = np.random.default_rng(seed)
    rows = []
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rheo-bench-diagnosis-") as tmp:
        for i in range(replicates):
            true, params, bag_seed = draw_bag(rng, i, quick)
            row = run_bag(i, true, params, bag_seed, Path(tmp))
            rows.append(row)
            print(f"bag {i} ({i + 1}/{replicates}): true {true}, size {row['size']:.3g} (readable "
                  f"{row['size_live']:.3g}), diagnosed {row['diagnosed']}, "
                  f"{row['simulate_seconds']:.1f} + {row['seconds']:.1f} s"
                  + (f" ({row['message']})" if row["message"] else ""), file=sys.stderr, flush=True)
    seconds = [r["seconds"] for r in rows if r["diagnosed"] != "failed"]
    clean = [r for r in rows if r["true"] == "none"]
    return {
        "replicates": replicates, "seed": seed, "quick": quick, "target": TARGET,
        "confusion": confusion(rows),
        **detection_threshold(rows),
        "per_effect": per_effect_thresholds(rows),
        "clean_bags": len(clean),
        "false_claims_on_clean": sum(r["diagnosed"] in EFFECTS for r in clean),
        "undecided_on_clean": sum(r["diagnosed"] == "undecided" for r in clean),
        "failed": sum(r["diagnosed"] == "failed" for r in rows),
        # Bags where the loop went on to add a second effect (only one is ever hidden).
        "extra_effects": [{"index": r["index"], "true": r["true"], "added": r["missing_effects"]}
                          for r in rows if len(r["missing_effects"]) > 1],
        "seconds_median": float(np.median(seconds)) if seconds else None,
        "seconds_max": float(np.max(seconds)) if seconds else None,
        "simulate_seconds_median": float(np.median([r["simulate_seconds"] for r in rows])) if rows else None,
        "total_seconds": time.perf_counter() - t_start,
        "bags": rows,
    }


def _short(name: str) -> str:
    return {"relaxation_branch": "relax", "strain_stiffening": "stiffen", "sensor_drift": "drift"}.get(name, name)


def format_table(result: dict[str, Any]) -> str:
    lines = [f"diagnosis over {result['replicates']} generated bags (seed {result['seed']}"
             + (", quick records" if result.get("quick") else "") + "): rows true class, columns diagnosed"]
    head = f"  {'true':<18}" + "".join(f"{_short(c):>10}" for c in COLUMNS) + f"{'correct':>10}"
    lines.append(head)
    for t, counts in result["confusion"].items():
        n = sum(counts.values())
        right = f"{counts[t]}/{n}" if n else "-"
        lines.append(f"  {t:<18}" + "".join(f"{counts[c]:>10}" for c in COLUMNS) + f"{right:>10}")
    if result["threshold"] is None:
        lines.append(f"detection threshold: none (no effect size above which {100 * result['target']:.0f} % "
                     "are diagnosed correctly)")
    else:
        lines.append(f"detection threshold: readable effect size {result['threshold']:.3g} x the total-force noise "
                     f"({100 * result['target']:.0f} % correct above it)")
        lines.append(f"  accuracy above it: {result['correct_above']}/{result['bags_above']} "
                     f"({100 * result['accuracy_above']:.1f} %); below it: "
                     f"{result['correct_below']}/{result['bags_below']}")
    for effect, th in per_effect_thresholds(result["bags"], result["target"]).items():
        at = "none" if th["threshold"] is None else f"{th['threshold']:.3g}"
        lines.append(f"  {effect:<18} threshold {at:>6}: {th['correct_above']}/{th['bags_above']} correct above, "
                     f"{th['correct_below']}/{th['bags_below']} below")
    lines.append(f"false claims on clean bags: {result['false_claims_on_clean']}/{result['clean_bags']} "
                 f"(undecided {result['undecided_on_clean']}); failed bags: {result['failed']}")
    if result["extra_effects"]:
        lines.append(f"a second effect added after the first (one is hidden): {len(result['extra_effects'])} bags ("
                     + "; ".join(f"bag {x['index']}: {'+'.join(x['added'])}" for x in result["extra_effects"]) + ")")
    if result["seconds_median"] is not None:
        lines.append(f"analysis time per bag: median {result['seconds_median']:.1f} s, max "
                     f"{result['seconds_max']:.1f} s; simulation median {result['simulate_seconds_median']:.1f} s; "
                     f"total {result['total_seconds'] / 60:.1f} min")
    wrong = [r for r in result["bags"] if r["diagnosed"] != r["true"]]
    if wrong:
        lines.append("misdiagnosed:")
        for r in sorted(wrong, key=lambda r: -r["size_live"]):
            effect = ", ".join(f"{k} {v:.3g}" for k, v in r["effect"].items())
            lines.append(f"  bag {r['index']}: {r['true']} ({effect or 'clean'}; {r['geometry']}, keep "
                         f"{r['params']['stage.keep_time']:.0f} s) size {r['size']:.3g}, readable {r['size_live']:.3g} -> "
                         f"{r['diagnosed']}" + (f" [{', '.join(r['undecided'])}]" if r["undecided"] else "")
                         + (f": {r['message']}" if r["message"] else ""))
    return "\n".join(lines)
