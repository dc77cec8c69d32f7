"""The model-discovery loop: fit candidate effects, decide which one is missing, add
it, and repeat until no effect earns its parameters.

Every model is fitted over the whole record with the same fixed weights, the sensor
noise the data show (``identification.noise``), so each fit's cost is a chi-square
and ``BIC = cost + k ln n`` compares models with different parameter counts ``k``
on the same ``n`` readings. An effect is named missing only when all of these hold:

1. it lowers the BIC by more than ``BIC_DECISIVE`` (10: "very strong" on Kass and
   Raftery's scale; by chance, with two parameters, about once in 10^5 fits);
2. the base model misfits where the effect shows (``Effect.shows_in``): the phase's
   chi-square over its readings exceeds what noise gives by ``EXCESS_SIGMAS``
   standard deviations;
3. adding it removes at least ``EXCESS_EXPLAINED`` of that excess.

(2) and (3) keep a small systematic error elsewhere (the sensors' quirks, a mesh
not quite converged) from being claimed as an effect that can absorb it: a drift
offset fitted to a bias in the keep is no drift when the readings before contact
and after release are clean. When the best two candidates are within
``BIC_DECISIVE`` of each other, the data cannot decide between them, and the
diagnosis says so and names the experiments that would.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace

import numpy as np

from rheo_ros.diagnosis.compare import PHASES, Comparison, compare, phase_of
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.noise import SensorNoise, sensor_noise
from rheo_ros.identification.paper import identify_paper
from rheo_ros.identification.refine import (
    WholeRecordProblem, away_from_boundaries, live_ceiling, misfit_limit, refine,
)
from rheo_ros.models.effects import Effect, FitContext, Model, catalogue, effect_class
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record, RecordError

BIC_DECISIVE = 10.0
EXCESS_SIGMAS = 5.0
EXCESS_EXPLAINED = 0.5
REPORTED_PHASES = ("pull", "keep", "release")
# A candidate the data do not support wanders (a vanishing arm); its fit is stopped here.
MAX_ITERATIONS = 25

Progress = Callable[[str], None]


@dataclass(frozen=True)
class ModelFit:
    """One model fitted to a record.

    Attributes:
        model: the model with its fitted values.
        estimate: the whole-record fit (params with gamma, covariance, std, message).
        comparison: its residual statistics per phase and signal.
        cost: chi-square of the fit against the sensor noise; samples: readings (n).
        rmse_force: RMS error of the total bottom force over the record (N), every
            reading but those at a phase boundary (mid-jump), the model read through the
            tactile dead band (``DeadBand.reading``).
        rmse_by_phase: the same per phase (pull, keep, release).
        prediction_total: the model's total bottom force at the record's force times (N).
    """

    model: Model
    estimate: Estimate
    comparison: Comparison
    cost: float
    samples: int
    rmse_force: float
    rmse_by_phase: dict[str, float]
    prediction_total: np.ndarray = field(repr=False)

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def effects(self) -> tuple[str, ...]:
        return tuple(e.id for e in self.model.effects)

    @property
    def free_parameters(self) -> int:
        """Parameters fitted: the model's, the Poisson ratio and the two clock offsets."""
        return len(self.model.parameters) + 3

    @property
    def bic(self) -> float:
        return self.cost + self.free_parameters * float(np.log(max(self.samples, 2)))

    @property
    def delays(self) -> tuple[float, float]:
        r = self.estimate.residual_rms
        return r.get("tactile_delay_s", 0.0), r.get("marker_delay_s", 0.0)

    @property
    def misfits(self) -> dict[str, float]:
        """Signals whose residual RMS exceeds what the sensor noise allows: ratio by signal."""
        r = self.estimate.residual_rms
        out = {}
        for key, ratio in r.items():
            if key.startswith("fit_to_noise_") and np.isfinite(ratio):
                signal = key.removeprefix("fit_to_noise_")
                n = self.comparison_samples(signal)
                if ratio > misfit_limit(n):
                    out[signal] = float(ratio)
        return out

    def comparison_samples(self, signal: str) -> int:
        return sum(s.samples for s in self.comparison.stats if s.signal == signal)

    def phase_chi2(self, phases: Iterable[str]) -> tuple[float, int]:
        """Chi-square of the force residuals (every segment, live readings) over
        ``phases`` and the readings it counts."""
        chi, n = 0.0, 0
        for s in self.comparison.stats:
            if s.signal.startswith("P") and s.phase in phases and s.noise > 0:
                chi += s.samples * (s.rms / s.noise) ** 2
                n += s.samples
        return chi, n


@dataclass(frozen=True)
class Candidate:
    """One effect tried on top of the current model.

    Attributes:
        effect: its id.
        fit: the model with it (None: every start failed, ``note`` says why).
        delta_bic: BIC change against the current model (negative: better).
        rmse_after: total force RMS with it (N).
        excess_before, excess_after: chi-square excess over the noise in the phases
            it shows in, without and with it (in standard deviations of that chi-square).
        explained: the share of that excess it removes.
        significant: it passes the BIC and signature tests (module docstring).
        determined: the data bound each of its parameters (a std below the value; a
            parameter run to the edge of its search means the effect vanished or degenerated).
    """

    effect: str
    fit: ModelFit | None
    delta_bic: float
    rmse_after: float
    excess_before: float
    excess_after: float
    explained: float
    significant: bool
    determined: bool
    note: str = ""

    @property
    def eligible(self) -> bool:
        """An effect the data both ask for and pin down."""
        return self.significant and self.determined


@dataclass(frozen=True)
class Diagnosis:
    """The verdict on one model.

    Attributes:
        model: the model judged.
        adequate: no candidate earns its parameters.
        missing_effect: the effect to add, or None (adequate, or undecided).
        candidates: every effect tried, best BIC first.
        evidence: a paragraph a person can read.
        undecided: the effects the data cannot tell apart (empty when decided).
    """

    model: str
    adequate: bool
    missing_effect: str | None
    candidates: tuple[Candidate, ...]
    evidence: str
    undecided: tuple[str, ...] = ()

    def to_json(self) -> dict:
        return {
            "adequate": self.adequate, "missing_effect": self.missing_effect,
            "candidates": [{"effect": c.effect, "delta_bic": _finite(c.delta_bic), "rmse_after": _finite(c.rmse_after),
                            "explained": _finite(c.explained), "eligible": c.eligible} for c in self.candidates],
            "evidence": self.evidence, "undecided": list(self.undecided),
        }


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def fit_model(
    record: Record, forward: QuasiStaticFE, effects: Sequence[Effect], start: dict[str, float],
    noise: SensorNoise | None = None, discretisation: bool = False,
) -> ModelFit:
    """Fit the three-element model with ``effects`` (their values are the start) over
    the whole record, weighted by the sensor noise; ``start``: the base parameters
    (E, c1, c2, gamma) to start from."""
    noise = noise or sensor_noise(record)
    model = Model(three_element(1.0, 1.0, 1.0), tuple(effects))
    initial = Estimate(params={**start, **{k: v for e in effects for k, v in e.parameters.items()}},
                       method="start", equations=())
    est = refine(record, initial, model=model, forward=forward, force_std=noise.force_std,
                 marker_std=noise.marker_std, discretisation=discretisation, max_iterations=MAX_ITERATIONS)
    fitted = model.with_parameters(est.params)
    return _assess(record, forward, fitted, est, noise)


def polish(record: Record, forward: QuasiStaticFE, fit: ModelFit, noise: SensorNoise | None = None) -> ModelFit:
    """Fit ``fit``'s model again from its values, to convergence (no iteration cap) and
    with the mesh's discretisation error in its std: the model a report shows."""
    noise = noise or sensor_noise(record)
    est = refine(record, fit.estimate, model=fit.model, forward=forward, force_std=noise.force_std,
                 marker_std=noise.marker_std, discretisation=True)
    return _assess(record, forward, fit.model.with_parameters(est.params), est, noise)


def _assess(record: Record, forward: QuasiStaticFE, model: Model, est: Estimate, noise: SensorNoise) -> ModelFit:
    delays = (est.residual_rms.get("tactile_delay_s", 0.0), est.residual_rms.get("marker_delay_s", 0.0))
    comparison = compare(record, model, est.params["gamma"], forward, delays, noise)
    p = forward.predict(model, est.params["gamma"], record.profile(), record.force_t - delays[0],
                        record.marker_t - delays[1])
    total = p.force.sum(axis=1)
    read = record.reading(p.force).sum(axis=1)
    away = away_from_boundaries(record.force_t, record.profile())
    err = (read - record.force.sum(axis=1))[away]
    which = phase_of(record.force_t[away], record.profile())
    by_phase = {name: float(np.sqrt(np.mean(err[which == PHASES.index(name)] ** 2)))
                for name in REPORTED_PHASES if np.any(which == PHASES.index(name))}
    return ModelFit(model, est, comparison, est.residual_rms["cost"], int(est.residual_rms["samples"]),
                    float(np.sqrt(np.mean(err**2))), by_phase, total)


def _context(record: Record, forward: QuasiStaticFE, fit: ModelFit, noise: SensorNoise) -> FitContext:
    tactile, marker = fit.delays
    p = forward.predict(fit.model, fit.estimate.params["gamma"], record.profile(), record.force_t - tactile,
                        record.marker_t - marker)
    return FitContext(record.profile(), fit.estimate.params, float(np.max(record.force)), record.force_t,
                      record.force - p.force, noise.force_live)


def _excess(chi: float, n: int) -> float:
    """A chi-square's excess over its expectation in units of its std (sqrt(2n))."""
    return (chi - n) / np.sqrt(2.0 * n) if n else 0.0


def _start_cost(record: Record, forward: QuasiStaticFE, current: ModelFit, effect: Effect,
                noise: SensorNoise) -> float:
    """The chi-square of ``current`` + ``effect`` as given (no fit); inf if it cannot be evaluated."""
    model = Model(three_element(1.0, 1.0, 1.0), (*current.model.effects, effect))
    problem = WholeRecordProblem(record, model, noise.force_std, noise.marker_std, forward=forward,
                                 live=noise.force_live, delays=True, ceiling=live_ceiling(record, noise.force_std))
    tactile, marker = current.delays
    params = {**current.estimate.params, **effect.parameters, "tactile_delay": tactile, "marker_delay": marker}
    try:
        r = problem.residuals(params)
    except (ValueError, np.linalg.LinAlgError):
        return np.inf
    return float(r @ r) if np.all(np.isfinite(r)) else np.inf


def add_effect(record: Record, forward: QuasiStaticFE, current: ModelFit, effect_id: str,
               noise: SensorNoise) -> ModelFit:
    """``current`` + the effect, fitted from the best of the effect's starts (by the
    chi-square there: a fit from each would cost a fit each)."""
    starts = effect_class(effect_id).starts(_context(record, forward, current, noise))
    start = min(starts, key=lambda e: _start_cost(record, forward, current, e, noise))
    return fit_model(record, forward, (*current.model.effects, start), current.estimate.params, noise)


def try_effect(record: Record, forward: QuasiStaticFE, current: ModelFit, effect_id: str,
               noise: SensorNoise) -> Candidate:
    """Fit ``current`` + the effect and judge it."""
    try:
        best = add_effect(record, forward, current, effect_id, noise)
    except Exception as exc:  # a user's effect may fail in any way: it loses, the diagnosis goes on
        return Candidate(effect_id, None, np.inf, np.nan, 0.0, 0.0, 0.0, False, False,
                         note=f"the fit failed: {type(exc).__name__}: {exc}")
    return judge(current, best, effect_id)


def judge(current: ModelFit, with_effect: ModelFit, effect_id: str) -> Candidate:
    """The BIC and signature tests of ``with_effect`` (``current`` + the effect)."""
    phases = effect_class(effect_id).shows_in or PHASES
    chi_b, n_b = current.phase_chi2(phases)
    chi_a, n_a = with_effect.phase_chi2(phases)
    before, after = _excess(chi_b, n_b), _excess(chi_a, n_a)
    explained = (chi_b - chi_a) / (chi_b - n_b) if chi_b > n_b else 0.0
    delta = with_effect.bic - current.bic
    significant = bool(delta < -BIC_DECISIVE and before > EXCESS_SIGMAS and explained >= EXCESS_EXPLAINED)
    std, values = with_effect.estimate.std, with_effect.estimate.params
    # Bound: a finite std below the value itself (within a factor of ~2 at one std); an arm
    # run off to a relaxation time of nanoseconds has a std, but the data do not bound it.
    determined = all(np.isfinite(std[k]) and std[k] < abs(values[k]) for k in values
                     if k.startswith(effect_id + "."))
    return Candidate(effect_id, with_effect, float(delta), with_effect.rmse_force, float(before), float(after),
                     float(explained), significant, determined)


def default_workers() -> int:
    """Processes for the candidates' fits: one per core, at most four."""
    return max(1, min(4, len(os.sched_getaffinity(0))))


def diagnose(record: Record, forward: QuasiStaticFE, current: ModelFit,
             candidates: Sequence[str] | None = None, noise: SensorNoise | None = None,
             progress: Progress | None = None, workers: int | None = None) -> Diagnosis:
    """Try each candidate effect not yet in ``current`` and decide what, if anything, is
    missing. The candidates are fitted in ``workers`` processes (default: one per core;
    1: in this process); each fit is deterministic, so the verdict does not depend on it."""
    noise = noise or sensor_noise(record)
    have = set(current.effects)
    ids = [e for e in (candidates if candidates is not None else catalogue()) if e not in have]
    workers = min(workers or default_workers(), max(len(ids), 1))
    tried: list[Candidate] = []
    if workers == 1:
        for i, effect_id in enumerate(ids):
            if progress:
                progress(f"trying {current.name}+{effect_id} ({i + 1}/{len(ids)})")
            tried.append(try_effect(record, forward, current, effect_id, noise))
    else:
        # fork: the children inherit the effects the user registered in this process.
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
            jobs = {pool.submit(try_effect, record, forward, current, e, noise): e for e in ids}
            for i, job in enumerate(as_completed(jobs)):
                tried.append(job.result())
                if progress:
                    progress(f"tried {current.name}+{jobs[job]} ({i + 1}/{len(ids)})")
    tried.sort(key=lambda c: (c.delta_bic, c.effect))
    eligible = [c for c in tried if c.eligible]
    undecided: tuple[str, ...] = ()
    missing = None
    if eligible:
        best = eligible[0]
        rivals = [c for c in eligible[1:] if c.delta_bic - best.delta_bic < BIC_DECISIVE]
        if rivals:
            undecided = (best.effect, *(c.effect for c in rivals))
        else:
            missing = best.effect
    else:
        # Asked for by the data but not pinned down: say which, and what would decide.
        undecided = tuple(c.effect for c in tried if c.significant)
    adequate = not eligible and not undecided and not current.misfits
    return Diagnosis(current.name, adequate, missing, tuple(tried),
                     evidence_text(current, tried, missing, undecided), undecided)


def discover(record: Record, forward: QuasiStaticFE, base: ModelFit, candidates: Sequence[str] | None = None,
             noise: SensorNoise | None = None, max_effects: int | None = None,
             progress: Progress | None = None, workers: int | None = None) -> tuple[list[ModelFit], list[Diagnosis]]:
    """From ``base``, add the missing effect and re-diagnose until the model is adequate,
    the data cannot decide, or ``max_effects`` were added. Returns the models (``base``
    first) and the diagnosis of each."""
    noise = noise or sensor_noise(record)
    models, verdicts = [base], []
    limit = len(catalogue()) if max_effects is None else max_effects
    while True:
        verdict = diagnose(record, forward, models[-1], candidates, noise, progress, workers)
        verdicts.append(verdict)
        if verdict.missing_effect is None or len(models) > limit:
            return models, verdicts
        winner = next(c for c in verdict.candidates if c.effect == verdict.missing_effect)
        if progress:
            progress(f"refining {winner.fit.name}")
        fits = [winner.fit]
        restarted = restart_from_corrected(record, forward, winner.fit, noise)
        if restarted is not None:
            fits.append(restarted)
        models.append(polish(record, forward, min(fits, key=lambda f: f.cost), noise))
        # The verdict quotes the model as it is added (refitted to convergence), not its screening fit.
        tried = [judge(models[-2], models[-1], c.effect) if c is winner else c for c in verdict.candidates]
        verdicts[-1] = replace(verdict, candidates=tuple(tried), evidence=evidence_text(
            models[-2], tried, verdict.missing_effect, verdict.undecided))


def restart_from_corrected(record: Record, forward: QuasiStaticFE, fit: ModelFit,
                           noise: SensorNoise | None = None) -> ModelFit | None:
    """The model of ``fit`` fitted again from a fresh closed form, where it has effects on
    the sensor's side (``measured_force``: drift, adhesion): their predicted share is taken
    out of the readings, the paper's equations identify E, c1, c2 and gamma on what is
    left, and the fit starts there. The base's closed form on the raw readings can be far
    off (a 0.26 N drift put E at 12 % of the truth) and its fit stay in a local minimum
    that a further effect then seems to explain. None: no sensor-side effect, or no
    closed form on the corrected readings."""
    sensor_side = [e for e in fit.model.effects if type(e).measured_force is not Effect.measured_force]
    if not sensor_side:
        return None
    noise = noise or sensor_noise(record)
    bare = replace(fit.model, effects=tuple(e for e in fit.model.effects if e not in sensor_side))
    gamma, (tactile, marker) = fit.estimate.params["gamma"], fit.delays
    t_force, t_markers = record.force_t - tactile, record.marker_t - marker
    share = (forward.predict(fit.model, gamma, record.profile(), t_force, t_markers).force
             - forward.predict(bare, gamma, record.profile(), t_force, t_markers).force)
    try:
        closed = identify_paper(replace(record, force=record.force - share), forward=forward)
        start = {**fit.estimate.params, **{k: closed.params[k] for k in ("E", "c1", "c2", "gamma")}}
        return fit_model(record, forward, fit.model.effects, start, noise)
    except (RecordError, ValueError, np.linalg.LinAlgError):
        return None


# -- evidence -----------------------------------------------------------------------

def _worst_phase(fit: ModelFit) -> tuple[str, float, tuple[tuple[float, float], ...]]:
    """The phase whose force residuals stand out most (name, RMS over noise, windows)."""
    worst = ("", 0.0, ())
    for s in fit.comparison.stats:
        if s.signal == "total" and s.rms_over_noise > worst[1]:
            worst = (s.phase, s.rms_over_noise, s.windows)
    return worst


def _windows_text(windows: tuple[tuple[float, float], ...]) -> str:
    if not windows:
        return ""
    shown = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in windows[:3])
    more = f" and {len(windows) - 3} more" if len(windows) > 3 else ""
    return f", systematic over {shown}{more}"


def evidence_text(current: ModelFit, tried: Sequence[Candidate], missing: str | None,
                  undecided: tuple[str, ...]) -> str:
    """One paragraph: where the model fails, what each candidate changes, the verdict."""
    phase, ratio, windows = _worst_phase(current)
    head = (f"{current.name}: total force RMS {current.rmse_force:.3g} N over the record")
    if phase:
        head += f"; worst in the {phase} phase at {ratio:.3g} x the sensor noise{_windows_text(windows)}"
    parts = [head + "."]
    by_id = {c.effect: c for c in tried}
    if missing:
        c = by_id[missing]
        cls = effect_class(missing)
        shows = ", ".join(cls.shows_in) or "every phase"
        effect = next(e for e in c.fit.model.effects if e.id == missing)
        before = {p: current.rmse_by_phase.get(p, np.nan) for p in cls.shows_in if p in current.rmse_by_phase}
        moved = "; ".join(f"{p} RMS {before[p]:.3g} -> {c.fit.rmse_by_phase[p]:.3g} N" for p in before)
        parts.append(
            f"Adding {missing} ({effect.describe()}) lowers BIC by {-c.delta_bic:.3g}, the total force RMS from "
            f"{current.rmse_force:.3g} N to {c.rmse_after:.3g} N ({moved or 'where it shows: ' + shows}) and removes "
            f"{100 * min(c.explained, 1.0):.0f} % of the misfit where it shows ({shows}).")
        std = c.fit.estimate.std
        loose = [k for k, v in std.items() if k.startswith(missing + ".")
                 and not (np.isfinite(v) and v < 0.5 * abs(c.fit.estimate.params[k]))]
        if loose:
            names = " and ".join(k.split(".", 1)[1] for k in loose)
            verb, them = ("is", "it") if len(loose) == 1 else ("are", "them")
            parts.append(f"Its {names} {verb} not determined by these data (std above half the value): "
                         f"{cls.resolving_experiment} would pin {them} down.")
        parts.append(f"Verdict: {missing} is missing.")
    elif undecided:
        rivals = [by_id[e] for e in undecided]
        listed = " and ".join(f"{c.effect} (BIC -{-c.delta_bic:.3g}, RMS {c.rmse_after:.3g} N)" for c in rivals)
        if len(rivals) > 1 and all(c.determined for c in rivals):
            why = f"they explain the misfit within {BIC_DECISIVE:g} of each other in BIC"
        else:
            why = "the data do not bound " + ", ".join(
                k for c in rivals for k, v in c.fit.estimate.std.items()
                if k.startswith(c.effect + ".") and not v < abs(c.fit.estimate.params[k]))
        parts.append(f"The data cannot decide: {listed}; {why}. To decide, record "
                     + "; or ".join(effect_class(c.effect).resolving_experiment for c in rivals) + ".")
    else:
        best = tried[0] if tried else None
        if best is None:
            parts.append("No candidate effect left to try.")
        else:
            why = []
            for c in tried[:3]:
                if c.fit is None:
                    why.append(f"{c.effect}: {c.note}")
                elif c.delta_bic >= -BIC_DECISIVE:
                    why.append(f"{c.effect} changes BIC by {c.delta_bic:+.3g}")
                elif c.excess_before <= EXCESS_SIGMAS:
                    why.append(f"{c.effect} lowers BIC by {-c.delta_bic:.3g} but the phases it shows in "
                               f"({', '.join(effect_class(c.effect).shows_in)}) fit within the noise "
                               f"({c.excess_before:.2g} sd)")
                else:
                    why.append(f"{c.effect} lowers BIC by {-c.delta_bic:.3g} but removes only "
                               f"{100 * c.explained:.0f} % of the misfit where it shows")
            parts.append("No effect earns its parameters: " + "; ".join(why) + ".")
        misfits = current.misfits
        if misfits:
            parts.append("Verdict: the model misfits (" + ", ".join(
                f"{k} at {v:.3g} x the noise" for k, v in sorted(misfits.items(), key=lambda kv: -kv[1]))
                + ") but no effect in the catalogue explains it: an effect not yet written (register your own), "
                "or a wrong set-up (boundary, geometry, sensor layout).")
        else:
            parts.append(f"Verdict: {current.name} is adequate for these data.")
    return " ".join(parts)
