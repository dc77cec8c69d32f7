"""What a model leaves when no effect in the catalogue explains the data (issue 24): where
the misfit sits and its shape in each phase, described so that a user can write the
missing effect.

Each phase's total-force residual (measured minus the model, N) is matched against
four shapes - a step (a constant offset), a ramp (a line), a decay (an exponential
with its own time, plus an offset) and a pulse (after a delay, a rise over one time and
a fall over a longer one within the phase, plus an offset: a delayed or lagging
response to a jump) - and the one with the lowest BIC on the residual's
own white-noise level (``sensors.difference_noise``) names the shape; "none" where even a
step does not beat zero by ``BIC_DECISIVE``. Sizes are in units of that noise.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.optimize import minimize

from rheo_ros.diagnosis.decision import BIC_DECISIVE, Rival, misfit_cells
from rheo_ros.diagnosis.fits import ModelFit
from rheo_ros.experiment import PHASES
from rheo_ros.identification.fit import live_top, steady_readings
from rheo_ros.identification.noise import sensor_noise
from rheo_ros.record import Record
from rheo_ros.sensors import difference_noise

DECAY_TIMES = 40   # times a fit starts from, log-spaced from two samples to ten phase lengths


def phase_shape(t: np.ndarray, residual: np.ndarray, noise: float) -> dict[str, Any]:
    """The shape of one phase's residual: ``shape`` (none, step, ramp, decay, pulse),
    ``size`` (its largest excursion from zero over the phase, in noise units, signed),
    ``tau`` (s, a decay's time or a pulse's fall; None otherwise), ``rise`` and ``delay``
    (s, a pulse's), ``bic`` of each shape against zero, and the curve itself (``shape_curve``):
    ``t0`` (s, the phase's first reading) and ``coefficients`` in N - a step's level; a
    ramp's level at ``t0`` and slope (N/s); a decay's level and the amplitude of
    exp(-(t - t0) / tau); a pulse's level and the amplitude of ``pulse_curve``."""
    t0 = float(t[0])
    t = np.asarray(t, float) - t0
    r = np.asarray(residual, float)
    n = r.size
    span = max(t[-1], 1e-9)

    def fitted(basis: np.ndarray) -> tuple[float, np.ndarray]:
        coef = np.linalg.lstsq(basis, r, rcond=None)[0]
        return float(np.sum((r - basis @ coef) ** 2) / noise**2 + basis.shape[1] * np.log(n)), coef

    ones = np.ones(n)
    fits: dict[str, tuple[float, np.ndarray, tuple[float, ...]]] = {
        "none": (float(np.sum(r**2) / noise**2), np.zeros(0), ()),
        "step": (*fitted(ones[:, None]), ()),
        "ramp": (*fitted(np.column_stack([ones, t])), ())}
    step = float(np.median(np.diff(t))) if n > 1 else span
    shortest = 2 * step

    def timed(basis: Callable[[np.ndarray], np.ndarray | None], starts: list[tuple[float, ...]]
              ) -> tuple[float, np.ndarray, tuple[float, ...]]:
        """The best times (s) of a shape whose curve is linear in its coefficients given
        them: the best of ``starts``, refined by Nelder-Mead (``basis`` None: out of
        bounds). Each time is a parameter of the BIC."""
        def score(times: np.ndarray) -> float:
            b = basis(times)
            return np.inf if b is None else fitted(b)[0]
        first = min(starts, key=lambda times: score(np.array(times)))
        times = minimize(score, np.array(first), method="Nelder-Mead",
                         options={"xatol": 1e-3 * step, "fatol": 1e-3}).x
        value, coef = fitted(basis(times))
        return value + len(times) * np.log(n), coef, tuple(float(x) for x in times)

    def decay(times: np.ndarray) -> np.ndarray | None:
        tau = times[0]
        return np.column_stack([ones, np.exp(-t / tau)]) if shortest <= tau <= 10 * span else None

    def pulse(times: np.ndarray) -> np.ndarray | None:
        # Back to the level within the phase (a fall longer than the phase is a decay or a
        # ramp), the rise the shorter time, any delay within the first half.
        fall, rise, delay = times
        if not shortest <= rise < fall <= span or not 0.0 <= delay <= span / 2:
            return None
        return np.column_stack([ones, pulse_curve(t, fall, rise, delay)])

    grid = np.geomspace(shortest, 10 * span, DECAY_TIMES)
    fits["decay"] = timed(decay, [(x,) for x in grid])
    inside = grid[grid < span][::4]
    fits["pulse"] = timed(pulse, [(fall, rise, delay) for i, fall in enumerate(inside) for rise in inside[:i]
                                  for delay in (0.0, span / 10, span / 4)]) if inside.size > 1 else (np.inf, np.zeros(0), ())
    shape = min(fits, key=lambda k: fits[k][0])
    if fits["none"][0] - fits[shape][0] < BIC_DECISIVE:
        shape = "none"
    _, coef, times = fits[shape]
    out = {"shape": shape, "tau": times[0] if times else None, "rise": times[1] if len(times) > 1 else None,
           "delay": times[2] if len(times) > 2 else None, "t0": t0, "coefficients": [float(c) for c in coef],
           "bic": {k: float(v[0] - fits["none"][0]) for k, v in fits.items() if k != "none"}}
    curve = shape_curve(out, t + t0)
    out["size"] = float(curve[np.argmax(np.abs(curve))] / noise) if n else 0.0
    return out


def pulse_curve(t: np.ndarray, fall: float, rise: float, delay: float) -> np.ndarray:
    """A pulse of unit amplitude: zero until ``delay``, then a rise over ``rise`` and a
    fall over ``fall`` (s; exp(-s/fall) - exp(-s/rise), s the time since the delay)."""
    since = np.maximum(t - delay, 0.0)
    return np.exp(-since / fall) - np.exp(-since / rise)


def shape_curve(shape: dict[str, Any], t: np.ndarray) -> np.ndarray:
    """The fitted curve of a ``phase_shape`` result at times ``t`` (s), in N."""
    t = np.asarray(t, float) - shape["t0"]
    coef = shape["coefficients"]
    if shape["shape"] == "none":
        return np.zeros_like(t)
    if shape["shape"] == "step":
        return np.full_like(t, coef[0])
    if shape["shape"] == "ramp":
        return coef[0] + coef[1] * t
    if shape["shape"] == "pulse":
        return coef[0] + coef[1] * pulse_curve(t, shape["tau"], shape["rise"], shape["delay"])
    return coef[0] + coef[1] * np.exp(-t / shape["tau"])


def remaining(fit: ModelFit, record: Record, rivals: Sequence[Rival] = ()) -> dict[str, Any]:
    """What ``fit`` leaves: the misfitting signals and phases (``decision.misfit_cells``:
    RMS and mean residual in noise units), whether in the force alone or the markers too
    (a sensor-side effect, or a material one), the total force's residual shape in each
    phase of the push (``phase_shape``), and the effects in no catalogue fitted against
    it (``rivals``: ``decision.Rival``), best first."""
    cells = misfit_cells(fit)
    markers = [c for c in cells if c["signal"] == "markers"]
    force = [c for c in cells if c["signal"] != "markers"]   # the segments and their total
    residual = record.force.sum(axis=1) - fit.prediction_total
    away = steady_readings(record)
    # The noise from the frames every segment reads live: a dead band's zeros and a
    # saturated reading's constant have no noise, and where they are most of the record
    # they would claim a level of almost none (seen: 8e-8 N, sizes of 4e7 x the noise).
    sensor = sensor_noise(record)
    live = sensor.force_live.all(axis=1)
    noise = difference_noise(residual, away & live)[0]
    if not np.isfinite(noise):
        noise = difference_noise(residual, away)[0]
    # A saturated reading is no measure of the force (it only bounds it): its frame has
    # no residual to describe.
    top = live_top(record, sensor.force_std)
    if top is not None:
        away = away & ~(record.force > top).any(axis=1)
    shapes = {}
    if np.isfinite(noise) and noise > 0:
        for phase in record.profile().phases:
            # Away from the phase boundaries, where the model jumps (as the fit leaves them out).
            inside = (record.force_t > phase.t_start) & (record.force_t < phase.t_end) & away
            if inside.sum() >= 10:
                shapes[phase.name] = phase_shape(record.force_t[inside], residual[inside], noise)
    order = (*PHASES, "after")
    return {"misfits": cells,
            "phases": sorted({c["phase"] for c in cells}, key=lambda ph: (order.index(ph) if ph in order else 9, ph)),
            "segments": sorted({c["signal"] for c in force if c["signal"].startswith("P")}),
            "force_only": bool(force) and not markers,
            "markers_only": bool(markers) and not force, "force_noise": float(noise), "shapes": shapes,
            "rivals": [r.to_json() for r in sorted(rivals, key=lambda r: r.delta_bic)]}


def describe(rest: dict[str, Any]) -> str:
    """A ``remaining`` result in one sentence (``rheo analyze``'s text, the report)."""
    where = ("the force alone" if rest["force_only"] else "the markers alone" if rest["markers_only"]
             else "the force and the markers")
    better = [r for r in rest.get("rivals", []) if r["beats"]]
    return (f"What remains (in {where}; total force, noise {rest['force_noise']:.3g} N): " + "; ".join(
        f"{phase}: {v['shape']}" + (f" {v['delay']:.3g} s in, rising over {v['rise']:.3g} s and falling over "
                                    f"{v['tau']:.3g} s" if v["rise"] else f" of {v['tau']:.3g} s" if v["tau"] else "")
        + f", {v['size']:+.3g} x noise"
        for phase, v in rest["shapes"].items())
        + "".join(f". It looks like an effect in no catalogue: {r['description']} fits it within the noise"
                  for r in better[:1]))
