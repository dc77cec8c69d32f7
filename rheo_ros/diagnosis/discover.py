"""The model-discovery loop: fit each candidate effect on the current model, decide
(``decision``) which one is missing, add it, and repeat until no effect earns its
parameters."""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace

import numpy as np

from rheo_ros.diagnosis.decision import (
    BIC_DECISIVE,
    DETECT_SIGMAS,
    Candidate,
    Diagnosis,
    choose,
    collapsed,
    judge,
    judged_where,
    leftover,
    phase_excess,
    sample_interval,
)
from rheo_ros.diagnosis.evidence import evidence_text
from rheo_ros.diagnosis.fits import ModelFit, add_effect, fit_model, polish, restart_from_corrected
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.noise import SensorNoise, sensor_noise
from rheo_ros.models.effects import catalogue, effect_class, effect_forms
from rheo_ros.record import Record

Progress = Callable[[str], None]


# A family's other forms are fitted, where the model misfits in their phases, unless a
# default lowers the BIC decisively and this family's by less than this share of that
# leader's drop: a family far behind the leader does not overtake it by a change of form,
# and an idle form (a second relaxation arm on data with none) can cost tens of seconds
# of fitting. With no decisive leader every family's forms may be the one (a settling
# drift the linear default took 36 % of, 4.9 in BIC, and a settling form all of).
FORM_SHARE = 0.1
# Forms whose screening BIC drops are within this share of each other are refined before
# one is named (a linear drift's screening fit left c2 25 x off: a per-segment one beat
# it by 0.015 % of the drop, and lost once both converged).
FORM_WINDOW = 0.05


def try_effect(record: Record, forward: QuasiStaticFE, current: ModelFit, effect_id: str,
               noise: SensorNoise, form: str | None = None) -> Candidate:
    """Fit ``current`` + the effect in ``form`` (default: the family's default) and judge it."""
    try:
        best = add_effect(record, forward, current, effect_id, noise, form)
    except Exception as exc:  # a user's effect may fail in any way: it loses, the diagnosis goes on
        return Candidate(effect_id, None, np.inf, np.nan, 0.0, 0.0, 0.0, False, False,
                         note=f"the fit failed: {type(exc).__name__}: {exc}",
                         form=effect_class(effect_id, form).form)
    return judge(current, best, effect_id)


def other_forms(current: ModelFit, defaults: Sequence[Candidate]) -> list[tuple[str, str]]:
    """(effect id, form) of the other forms worth fitting after the families' defaults:
    where ``current`` misfits in the phases the form shows in (elsewhere no form can earn
    its parameters: ``decision.judge``), or every form of a family whose default completes
    the model (``Candidate.clears``: a fading adhesion whose time runs off is a held one),
    those of each family but the ones far behind a decisive leader (``FORM_SHARE``)."""
    drops = [c.delta_bic for c in defaults if np.isfinite(c.delta_bic)]
    if not drops:
        return []
    leader = min(drops)
    bar = FORM_SHARE * leader if leader < -BIC_DECISIVE else np.inf
    return [(c.effect, cls.form) for c in defaults if c.delta_bic <= bar for cls in effect_forms(c.effect)[1:]
            if c.clears or phase_excess(current, *judged_where(current, cls)) > DETECT_SIGMAS]


def best_form(tried: Sequence[Candidate]) -> Candidate:
    """A family's candidate: its best form by BIC among those that earn their
    parameters, else its best form by BIC. The other eligible forms within
    ``FORM_WINDOW`` of it ride along (``alternatives``): the screening fits stop after a
    few iterations, so forms that close are told apart only once refined."""
    eligible = [c for c in tried if c.eligible]
    best = min(eligible or tried, key=lambda c: c.delta_bic)
    window = max(BIC_DECISIVE, FORM_WINDOW * abs(best.delta_bic))
    close = tuple(c for c in eligible if c is not best and c.delta_bic - best.delta_bic < window)
    return replace(best, alternatives=close)


def refine(record: Record, forward: QuasiStaticFE, fit: ModelFit, noise: SensorNoise) -> ModelFit:
    """A screening fit taken to convergence: from where it stopped and, for sensor-side
    effects, from a closed form on the readings with their share taken out
    (``restart_from_corrected``); the better polished (discretisation std included)."""
    fits = [fit]
    restarted = restart_from_corrected(record, forward, fit, noise)
    if restarted is not None:
        fits.append(restarted)
    return polish(record, forward, min(fits, key=lambda f: f.cost), noise)


def refine_forms(record: Record, forward: QuasiStaticFE, winner: Candidate, noise: SensorNoise) -> ModelFit:
    """The model to add for ``winner``: its screening fit refined (``refine``); each close
    form (``Candidate.alternatives``) fitted again from the refined base parameters (a
    screening fit may stop far off, the base is shared) and, where its BIC then beats
    the refined one even before convergence, polished and taken instead."""
    best = refine(record, forward, winner.fit, noise)
    for other in winner.alternatives:
        base = {k: best.estimate.params[k] for k in ("E", "c1", "c2", "gamma")}
        trial = fit_model(record, forward, other.fit.model.effects, base, noise)
        if trial.bic < best.bic:
            best = polish(record, forward, trial, noise)
    return best


def default_workers() -> int:
    """Processes for the candidates' fits: one per core, at most four."""
    return max(1, min(4, len(os.sched_getaffinity(0))))


def _fit_all(record: Record, forward: QuasiStaticFE, current: ModelFit, jobs: Sequence[tuple[str, str | None]],
             noise: SensorNoise, progress: Progress | None, workers: int) -> list[Candidate]:
    """``try_effect`` for each (effect id, form), in ``workers`` processes; in job order."""
    def label(job: tuple[str, str | None]) -> str:
        return f"{current.name}+{job[0]}" + (f" ({job[1]} form)" if job[1] else "")

    if min(workers, len(jobs)) <= 1:
        out = []
        for i, job in enumerate(jobs):
            if progress:
                progress(f"trying {label(job)} ({i + 1}/{len(jobs)})")
            out.append(try_effect(record, forward, current, job[0], noise, job[1]))
        return out
    results: dict[int, Candidate] = {}
    # fork: the children inherit the effects the user registered in this process.
    with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=multiprocessing.get_context("fork")) as pool:
        futures = {pool.submit(try_effect, record, forward, current, e, noise, f): i for i, (e, f) in enumerate(jobs)}
        for n, future in enumerate(as_completed(futures)):
            results[futures[future]] = future.result()
            if progress:
                progress(f"tried {label(jobs[futures[future]])} ({n + 1}/{len(jobs)})")
    return [results[i] for i in range(len(jobs))]


def diagnose(record: Record, forward: QuasiStaticFE, current: ModelFit,
             candidates: Sequence[str] | None = None, noise: SensorNoise | None = None,
             progress: Progress | None = None, workers: int | None = None) -> Diagnosis:
    """Try each candidate effect not yet in ``current`` and decide what, if anything, is
    missing: every family's default form first, then the other forms of the families the
    data ask for (``other_forms``); each family is judged by its best form (``best_form``).
    The fits run in ``workers`` processes (default: one per core; 1: in this process);
    each fit is deterministic, so the verdict does not depend on it."""
    noise = noise or sensor_noise(record)
    have = set(current.effects)
    ids = [e for e in (candidates if candidates is not None else catalogue()) if e not in have]
    workers = workers or default_workers()
    defaults = _fit_all(record, forward, current, [(e, None) for e in ids], noise, progress, workers)
    more = other_forms(current, defaults)
    forms = _fit_all(record, forward, current, more, noise, progress, workers)
    tried = [best_form([d, *(c for (e, _), c in zip(more, forms) if e == d.effect)]) for d in defaults]
    tried.sort(key=lambda c: (c.delta_bic, c.effect))
    missing, undecided = choose(tried)
    adequate = missing is None and not undecided and not current.misfits
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
        if len(models) > 1:   # effects added: did they leave the base model whole?
            verdict = replace(verdict, degenerate=collapsed(models[-1], models[0], sample_interval(record)),
                              leftover=leftover(models[-1]))
        verdicts.append(verdict)
        if verdict.missing_effect is None or len(models) > limit:
            return models, verdicts
        winner = next(c for c in verdict.candidates if c.effect == verdict.missing_effect)
        if progress:
            progress(f"refining {winner.fit.name}" + (f" ({len(winner.alternatives) + 1} forms)"
                                                      if winner.alternatives else ""))
        models.append(refine_forms(record, forward, winner, noise))
        # The verdict quotes the model as it is added (refitted to convergence), not its screening fit.
        tried = [judge(models[-2], models[-1], c.effect) if c is winner else c for c in verdict.candidates]
        verdicts[-1] = replace(verdict, candidates=tuple(tried), evidence=evidence_text(
            models[-2], tried, verdict.missing_effect, verdict.undecided))
