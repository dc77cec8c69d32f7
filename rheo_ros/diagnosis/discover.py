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

from rheo_ros.diagnosis.decision import BIC_DECISIVE, Candidate, Diagnosis, judge
from rheo_ros.diagnosis.evidence import evidence_text
from rheo_ros.diagnosis.fits import ModelFit, add_effect, polish, restart_from_corrected
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.noise import SensorNoise, sensor_noise
from rheo_ros.models.effects import catalogue, effect_class, effect_forms
from rheo_ros.record import Record

Progress = Callable[[str], None]


def try_effect(record: Record, forward: QuasiStaticFE, current: ModelFit, effect_id: str,
               noise: SensorNoise) -> Candidate:
    """Fit ``current`` + the effect and judge it: its default form, then, where the data
    ask for the family (the default lowers the BIC decisively), its other forms. The
    family's candidate is its best form by BIC among those that earn their parameters,
    else its best form by BIC."""
    tried = [_try_form(record, forward, current, effect_id, noise, None)]
    if tried[0].delta_bic < -BIC_DECISIVE:
        tried += [_try_form(record, forward, current, effect_id, noise, cls.form)
                  for cls in effect_forms(effect_id)[1:]]
    eligible = [c for c in tried if c.eligible]
    return min(eligible or tried, key=lambda c: c.delta_bic)


def _try_form(record: Record, forward: QuasiStaticFE, current: ModelFit, effect_id: str, noise: SensorNoise,
              form: str | None) -> Candidate:
    try:
        best = add_effect(record, forward, current, effect_id, noise, form)
    except Exception as exc:  # a user's effect may fail in any way: it loses, the diagnosis goes on
        return Candidate(effect_id, None, np.inf, np.nan, 0.0, 0.0, 0.0, False, False,
                         note=f"the fit failed: {type(exc).__name__}: {exc}",
                         form=effect_class(effect_id, form).form)
    return judge(current, best, effect_id)


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
