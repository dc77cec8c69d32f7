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
    Rival,
    choose,
    collapsed,
    judge,
    judged_where,
    leftover,
    phase_excess,
    resolved_times,
    shared_times,
    undetermined,
)
from rheo_ros.diagnosis.evidence import evidence_text
from rheo_ros.diagnosis.fits import (
    BASE_PARAMETERS,
    ModelFit,
    add_effect,
    fit_model,
    other_form,
    polish,
    restart_from_corrected,
)
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.noise import SensorNoise, sensor_noise
from rheo_ros.models.effects import Effect, catalogue, effect_class, effect_forms
from rheo_ros.models.rivals import RIVALS
from rheo_ros.record import Record

Progress = Callable[[str], None]


# A family's other forms are fitted, where the model misfits in their phases, unless a
# default lowers the BIC by more than ``FORM_LEADER`` and this family's by less than
# ``FORM_SHARE`` of that leader's drop: a family far behind a leader that large does not
# overtake it by a change of form, and an idle form (a second relaxation arm on data with
# none) can cost tens of seconds of fitting. Behind a smaller leader every family's forms
# may be the one: a settling drift the linear default took 36 % of, 4.9 in BIC, and a
# settling form all of; generator seed 17 bag 14 (a held adhesion found, each cell's
# baseline settling over 11 s left): a linear stiffening led by 59, the drift's linear
# form was 13.5 behind the model without it, and its settling form 163 ahead.
FORM_SHARE = 0.1
FORM_LEADER = 1000.0
# Forms whose screening BIC drops are within this share of each other are refined before
# one is named (a linear drift's screening fit left c2 25 x off: a per-segment one beat
# it by 0.015 % of the drop, and lost once both converged).
FORM_WINDOW = 0.05
# Form changes ``revisit_forms`` makes in one model at most.
REVISIT_PASSES = 2


def try_effect(record: Record, forward: QuasiStaticFE, current: ModelFit, effect_id: str,
               noise: SensorNoise, form: str | None = None) -> Candidate:
    """Fit ``current`` + the effect in ``form`` (default: the family's default) and judge it;
    its second start is fitted only where the first fit is no answer (``_sound``)."""
    times = resolved_times(record)
    try:
        best = add_effect(record, forward, current, effect_id, noise, form,
                          sound=lambda fit: _sound(fit, effect_id, current, times, current))
    except Exception as exc:  # a user's effect may fail in any way: it loses, the diagnosis goes on
        return Candidate(effect_id, None, np.inf, np.nan, 0.0, 0.0, 0.0, False, False,
                         note=f"the fit failed: {type(exc).__name__}: {exc}",
                         form=effect_class(effect_id, form).form)
    return judge(current, best, effect_id, record)


def other_forms(current: ModelFit, defaults: Sequence[Candidate]) -> list[tuple[str, str]]:
    """(effect id, form) of the other forms worth fitting after the families' defaults:
    where ``current`` misfits in the phases the form shows in (elsewhere no form can earn
    its parameters: ``decision.judge``), or every form of a family whose default completes
    the model (``Candidate.clears``: a fading adhesion whose time runs off is a held one),
    those of each family but the ones far behind a large leader (``FORM_SHARE``,
    ``FORM_LEADER``)."""
    drops = [c.delta_bic for c in defaults if np.isfinite(c.delta_bic)]
    if not drops:
        return []
    leader = min(drops)
    bar = FORM_SHARE * leader if leader < -FORM_LEADER else np.inf
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


def _flawed(fit: ModelFit, base: ModelFit, times: tuple[float, float]) -> bool:
    """``fit`` is no answer as it stands: a base parameter lost to a bound (``collapsed``),
    a misfit, or a phase left misfitting (``leftover``)."""
    return bool(collapsed(fit, base, times) or fit.misfits or leftover(fit))


def _sound(fit: ModelFit, effect_id: str, base: ModelFit, times: tuple[float, float],
           without: ModelFit | None = None) -> bool:
    """``fit`` (with ``effect_id``) is an answer as it stands: not ``_flawed`` against
    ``base``, and either the data pin the effect's parameters down (``undetermined``) or
    the effect is idle: the fit's BIC is no lower than ``without``'s (the model it was
    added to). A fit from another start is not tried beside it (``fits.fit_from``):
    generator seed 17 bag 1 (each segment settling, 1.7 x the total-force noise) fits
    within the noise from the first start with the drift's time unbounded (BIC lower by
    18), and from the second with it bounded. An idle effect on data that fit within the
    noise is undetermined by nature; a second start for it is a whole fit that earns
    nothing."""
    if _flawed(fit, base, times):
        return False
    return not undetermined(fit, effect_id) or (without is not None and fit.bic >= without.bic)


def revisit_forms(record: Record, forward: QuasiStaticFE, fit: ModelFit, base: ModelFit, noise: SensorNoise,
                  progress: Progress | None = None) -> tuple[ModelFit, list[str]]:
    """``fit`` (the base with effects, the last just added) with each effect's form chosen
    again in the model it ended up in: an effect's form was chosen on the model before the
    effects found after it. Each effect's other forms are fitted with the rest as they are
    (``fits.other_form``); the best, once refined, is taken where it lowers the BIC, or
    where it is sound and ``fit`` is not: a fit that ran a base parameter off to a bound
    (``decision.collapsed``) is no measurement, and loses to a form that fits within the
    noise without (``flawed``). The last effect's form was chosen beside the others as they
    are (unless its fit lost a base parameter); an effect whose form changes sends the
    others back to be chosen again (at most ``REVISIT_PASSES`` changes). Generator seed 10
    bag 17 (a Maxwell arm and a stiffening Voigt spring): two arms beat one on the base,
    and with the stiffening found next c2 ran off to its bound; one arm with the stiffening
    fits better (BIC lower by 22), every parameter within its std of the truth. Returns the
    model and what changed, in words."""
    times = resolved_times(record)

    def lost(f: ModelFit) -> tuple[str, ...]:
        return collapsed(f, base, times)

    def flawed(f: ModelFit) -> bool:
        return _flawed(f, base, times)

    changes: list[str] = []
    effects = fit.model.effects
    open_ = [e.id for e in (effects if lost(fit) else effects[:-1])]   # the effects whose form is chosen again
    while open_ and len(changes) < REVISIT_PASSES:
        effect_id = open_.pop(0)
        index = next(i for i, e in enumerate(fit.model.effects) if e.id == effect_id)
        effect = fit.model.effects[index]
        others = [cls for cls in effect_forms(effect_id) if cls.form != effect.form]
        if not others:
            continue
        if progress:
            progress(f"{fit.name}: {effect_id} in its {', '.join(c.form for c in others)} form(s)")
        trials = [other_form(record, forward, fit, index, cls, noise, base,
                             sound=lambda f: _sound(f, effect_id, base, times)) for cls in others]
        trial = min(trials, key=lambda f: (bool(lost(f)), f.bic))
        if not lost(fit) and trial.bic >= fit.bic + max(BIC_DECISIVE, FORM_WINDOW * abs(fit.bic - base.bic)):
            continue   # a screening fit this far behind does not overtake once refined
        refined = polish(record, forward, trial, noise)
        if (flawed(refined), refined.bic) >= (flawed(fit), fit.bic):
            continue
        beside = " and ".join(e.id for e in fit.model.effects if e.id != effect_id)
        form = refined.forms[effect_id]
        changes.append((f"with {beside} in the model, " if beside else "")
                       + (f"{effect_id}'s {form} form fits better than its {effect.form} form (BIC lower by "
                          f"{fit.bic - refined.bic:.3g})" if refined.bic < fit.bic else
                          f"{effect_id}'s {form} form fits within the noise with no parameter at a bound, where its "
                          f"{effect.form} form ran {', '.join(lost(fit))} off to one (BIC higher by "
                          f"{refined.bic - fit.bic:.3g})"))
        fit = refined
        open_ = [e.id for e in fit.model.effects if e.id != effect_id]
    return fit, changes


def drop_idle(record: Record, forward: QuasiStaticFE, fit: ModelFit, base: ModelFit, noise: SensorNoise,
              progress: Progress | None = None) -> tuple[ModelFit, list[str], list[str]]:
    """``fit`` (the base with effects, the last just added) without the effects found
    before the last that no longer earn their parameters beside it: each taken out in turn
    (the rest refitted from their values, polished) stays out where the BIC without it is
    lower, or higher by less than ``BIC_DECISIVE``, unless without it the model misfits,
    leaves a phase misfitting or loses a base parameter and with it does not. An effect
    found first can have stood in for one found after it: generator x 2 seed 20 bag 40 (each
    segment's baseline settling, 23 x the total-force noise) had a linear stiffening take
    the pull's curve first (the drift's settling forms were not tried beside a leader that
    far ahead); with the drift found next the stiffening's coefficient fell to zero, and both
    were named. Returns the model, the effects taken out, and why, in words."""
    times = resolved_times(record)
    dropped: list[str] = []
    words: list[str] = []
    for effect_id in [e.id for e in fit.model.effects[:-1]]:
        rest = tuple(e for e in fit.model.effects if e.id != effect_id)
        if progress:
            progress(f"{fit.name}: without {effect_id}")
        start = {k: fit.estimate.params[k] for k in BASE_PARAMETERS}
        trial = polish(record, forward, fit_model(record, forward, rest, start, noise), noise)
        if trial.bic >= fit.bic + BIC_DECISIVE or (_flawed(trial, base, times) and not _flawed(fit, base, times)):
            continue
        change = trial.bic - fit.bic
        words.append(f"{effect_id} no longer earns its parameters beside "
                     f"{' and '.join(e.id for e in rest)}: without it the BIC is "
                     + (f"lower by {-change:.3g}" if change < 0 else f"higher by only {change:.3g}")
                     + ", so it is taken out")
        dropped.append(effect_id)
        fit = trial
    return fit, dropped, words


def forms_again(record: Record, forward: QuasiStaticFE, current: ModelFit, verdict: Diagnosis, base: ModelFit,
                noise: SensorNoise, progress: Progress | None = None) -> tuple[Diagnosis, list[str]] | None:
    """Where ``current`` (effects added) still misfits and no candidate passes the rules
    (``verdict``), the candidate that lowers the BIC most added with the forms of
    ``current``'s effects chosen again beside it (``revisit_forms``), judged again: the
    forms were chosen on a model without it. Generator seed 17 bag 38 (a settling drift
    of each segment and a stiffening Voigt spring): on the base, each segment's linear
    drift beat the settling form (the stiffening bent the pull both ways); beside it the
    stiffening removed 48 % of the pull's misfit and nothing was named. With the
    stiffening the settling form fits (BIC lower by 2.9e3 than the linear drift's) and
    no phase misfits. The diagnosis naming that candidate, and the forms changed in
    words; None when no form changes or the candidate still fails the rules."""
    rivals = [c for c in verdict.candidates if c.fit is not None and c.delta_bic < -BIC_DECISIVE]
    if not rivals:
        return None
    best = min(rivals, key=lambda c: c.delta_bic)
    if progress:
        progress(f"choosing the forms of {best.fit.name} again")
    revised, changes = revisit_forms(record, forward, refine(record, forward, best.fit, noise), base, noise, progress)
    if not changes:
        return None
    tried = [judge(current, revised, c.effect, record) if c is best else c for c in verdict.candidates]
    missing, undecided = choose(tried)
    if missing != best.effect:
        return None
    return replace(verdict, adequate=False, missing_effect=missing, candidates=tuple(tried), undecided=undecided,
                   evidence=evidence_text(current, tried, missing, undecided)), changes


def try_rival(record: Record, forward: QuasiStaticFE, base: ModelFit, judged: ModelFit, rival: type[Effect],
              noise: SensorNoise) -> Rival:
    """``base`` + the effect in no catalogue ``rival``, fitted as a candidate is
    (``fits.add_effect``) and, unless that screening fit is far behind, to convergence
    (``polish``, as every model added is), held up against ``judged`` (the model the loop
    ended with). Far behind: by more than ``BIC_DECISIVE`` and ``FORM_WINDOW`` of what the
    effects found gained, as ``revisit_forms`` judges a form; nor is its second start
    fitted then (a polish and a start are whole fits: with both, the analysis of
    in-catalogue generator bags with an effect named took 1.5-2.7 x as long, the rivals
    thousands behind)."""
    times = resolved_times(record)
    bar = judged.bic + max(BIC_DECISIVE, FORM_WINDOW * abs(judged.bic - base.bic))

    def settled(f: ModelFit) -> bool:   # an answer, or so far behind that a second start is not fitted
        return f.bic >= bar or _sound(f, rival.id, base, times, base)

    try:
        fit = add_effect(record, forward, base, rival, noise, sound=settled)
        if fit.bic < bar:
            fit = polish(record, forward, fit, noise)
    except Exception as exc:  # a rival that cannot be fitted is no rival; the verdict stands
        return Rival(rival.id, f"the fit failed: {type(exc).__name__}: {exc}", np.inf, False)
    effect = next(e for e in fit.model.effects if e.id == rival.id)
    return Rival(rival.id, effect.describe(), fit.bic - judged.bic, _sound(fit, rival.id, base, times), fit)


def rivals(record: Record, forward: QuasiStaticFE, models: Sequence[ModelFit], noise: SensorNoise,
           workers: int = 1) -> tuple[Rival, ...]:
    """Each effect in no catalogue (``models.rivals.RIVALS``) on the base alone, against
    the last of ``models`` (the base first), where the loop added effects or the last
    model still misfits; none where the base fits and nothing was added (rule 2: no
    effect is asked for where nothing misfits). A catalogue effect can fit data it did
    not make within the noise, and then only a better alternative shows it is not the
    one: the out-of-catalogue generator bags named wrong at stop 68 each fit their true
    effect by 18-191 lower in BIC (docs/bench/outside-truth-stop70)."""
    final = models[-1]
    if len(models) == 1 and not (final.misfits or leftover(final)):
        return ()
    jobs = [(record, forward, models[0], final, cls, noise) for cls in RIVALS]
    if min(workers, len(jobs)) <= 1:
        return tuple(try_rival(*job) for job in jobs)
    with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=multiprocessing.get_context("fork")) as pool:
        return tuple(pool.map(try_rival, *zip(*jobs)))


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
        revisited: list[str] | None = None   # the forms chosen again beside the effect to add
        if (verdict.missing_effect is None and not verdict.undecided and len(models) > 1
                and (models[-1].misfits or leftover(models[-1]))):
            retried = forms_again(record, forward, models[-1], verdict, base, noise, progress)
            if retried is not None:
                verdict, revisited = retried
        if len(models) > 1:   # effects added: did they leave the base model whole?
            verdict = replace(verdict, degenerate=collapsed(models[-1], models[0], resolved_times(record)),
                              leftover=leftover(models[-1]), shared_times=shared_times(models[-1]))
        if verdict.missing_effect is None or len(models) > limit:
            found = rivals(record, forward, models, noise, workers or default_workers())
            if found and progress:
                progress("rivals in no catalogue: " + ", ".join(f"{r.effect} {r.delta_bic:+.3g}" for r in found))
            verdicts.append(replace(verdict, rivals=found))
            return models, verdicts
        verdicts.append(verdict)
        winner = next(c for c in verdict.candidates if c.effect == verdict.missing_effect)
        if revisited is not None:   # forms_again refined it and chose its forms: not again
            models.append(winner.fit)
        else:
            if progress:
                progress(f"refining {winner.fit.name}" + (f" ({len(winner.alternatives) + 1} forms)"
                                                          if winner.alternatives else ""))
            models.append(refine_forms(record, forward, winner, noise))
        changes = revisited or []
        if revisited is None and (len(models[-1].model.effects) > 1
                                  or collapsed(models[-1], base, resolved_times(record))):
            if progress:
                progress(f"choosing the forms of {models[-1].name} again")
            models[-1], changes = revisit_forms(record, forward, models[-1], base, noise, progress)
        # The verdict quotes the model as it is added (refitted to convergence), not its screening fit.
        tried = [judge(models[-2], models[-1], c.effect, record) if c is winner else c for c in verdict.candidates]
        evidence = evidence_text(models[-2], tried, verdict.missing_effect, verdict.undecided)
        if changes:
            evidence += " Forms chosen again in this model: " + "; ".join(changes) + "."
        dropped: list[str] = []
        if len(models[-1].model.effects) > 1:
            models[-1], dropped, why = drop_idle(record, forward, models[-1], base, noise, progress)
            if why:
                text = "; ".join(why)
                evidence += f" {text[0].upper()}{text[1:]}."
        verdicts[-1] = replace(verdict, candidates=tuple(tried), evidence=evidence, dropped=tuple(dropped))
