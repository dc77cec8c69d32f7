"""What a model leaves when no effect in the catalogue explains the data (issue 24): where
the misfit sits and its shape in each phase, described so that a user can write the
missing effect.

Each phase's total-force residual (measured minus the model, N) is matched against
three shapes - a step (a constant offset), a ramp (a line) and a decay (an exponential
with its own time, plus an offset) - and the one with the lowest BIC on the residual's
own white-noise level (``sensors.difference_noise``) names the shape; "none" where even a
step does not beat zero by ``BIC_DECISIVE``. Sizes are in units of that noise.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rheo_ros.diagnosis.decision import BIC_DECISIVE, misfit_cells
from rheo_ros.diagnosis.fits import ModelFit
from rheo_ros.experiment import PHASES
from rheo_ros.identification.fit import away_from_boundaries
from rheo_ros.record import Record
from rheo_ros.sensors import difference_noise

DECAY_TIMES = 40   # decay times tried per phase, log-spaced from two samples to ten phase lengths


def phase_shape(t: np.ndarray, residual: np.ndarray, noise: float) -> dict[str, Any]:
    """The shape of one phase's residual: ``shape`` (none, step, ramp, decay), ``size``
    (its largest excursion from zero over the phase, in noise units, signed), ``tau``
    (s, a decay's time; None otherwise), ``bic`` of each shape against zero."""
    t = np.asarray(t, float) - t[0]
    r = np.asarray(residual, float)
    n = r.size
    span = max(t[-1], 1e-9)

    def bic(fitted: np.ndarray, k: int) -> float:
        return float(np.sum((r - fitted) ** 2) / noise**2 + k * np.log(n))

    ones = np.ones(n)
    fits: dict[str, tuple[float, np.ndarray, float | None]] = {"none": (bic(np.zeros(n), 0), np.zeros(n), None)}
    fits["step"] = (bic(np.full(n, r.mean()), 1), np.full(n, r.mean()), None)
    line = np.column_stack([ones, t / span])
    fitted = line @ np.linalg.lstsq(line, r, rcond=None)[0]
    fits["ramp"] = (bic(fitted, 2), fitted, None)
    best: tuple[float, np.ndarray, float | None] = (np.inf, np.zeros(n), None)
    step = float(np.median(np.diff(t))) if n > 1 else span
    for tau in np.geomspace(2 * step, 10 * span, DECAY_TIMES):
        basis = np.column_stack([ones, np.exp(-t / tau)])
        fitted = basis @ np.linalg.lstsq(basis, r, rcond=None)[0]
        score = bic(fitted, 3)
        if score < best[0]:
            best = (score, fitted, float(tau))
    fits["decay"] = best
    shape = min(fits, key=lambda k: fits[k][0])
    if fits["none"][0] - fits[shape][0] < BIC_DECISIVE:
        shape = "none"
    _, fitted, tau = fits[shape]
    extreme = fitted[np.argmax(np.abs(fitted))] if n else 0.0
    return {"shape": shape, "size": float(extreme / noise), "tau": tau if shape == "decay" else None,
            "bic": {k: float(v[0] - fits["none"][0]) for k, v in fits.items() if k != "none"}}


def remaining(fit: ModelFit, record: Record) -> dict[str, Any]:
    """What ``fit`` leaves: the misfitting signals and phases (``decision.misfit_cells``:
    RMS and mean residual in noise units), whether in the force alone or the markers too
    (a sensor-side effect, or a material one), and the total force's residual shape in
    each phase of the push (``phase_shape``)."""
    cells = misfit_cells(fit)
    force = [c for c in cells if c["signal"].startswith("P")]
    markers = [c for c in cells if not c["signal"].startswith("P")]
    residual = record.force.sum(axis=1) - fit.prediction_total
    noise = difference_noise(residual, away_from_boundaries(record.force_t, record.profile()))[0]
    shapes = {}
    away = away_from_boundaries(record.force_t, record.profile())
    if np.isfinite(noise) and noise > 0:
        for phase in record.profile().phases:
            # Away from the phase boundaries, where the model jumps (as the fit leaves them out).
            inside = (record.force_t > phase.t_start) & (record.force_t < phase.t_end) & away
            if inside.sum() >= 10:
                shapes[phase.name] = phase_shape(record.force_t[inside], residual[inside], noise)
    order = (*PHASES, "after")
    return {"misfits": cells,
            "phases": sorted({c["phase"] for c in cells}, key=lambda ph: (order.index(ph) if ph in order else 9, ph)),
            "segments": sorted({c["signal"] for c in force}), "force_only": bool(force) and not markers,
            "markers_only": bool(markers) and not force, "force_noise": float(noise), "shapes": shapes}
