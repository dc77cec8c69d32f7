"""The evidence: one paragraph a person reads, on where a model fails, what each candidate
effect changes and the verdict."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rheo_ros.diagnosis.decision import (
    BIC_DECISIVE,
    DETECT_SIGMAS,
    EXCESS_EXPLAINED,
    EXCESS_SIGMAS,
    Candidate,
    held_ranges,
    undetermined,
)
from rheo_ros.diagnosis.fits import ModelFit
from rheo_ros.experiment import StageProfile
from rheo_ros.identification.estimate import Estimate
from rheo_ros.models.effects import catalogue, effect_class


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
        head += f"; worst in the {phase} phase at {ratio:.3g} x the noise{_windows_text(windows)}"
    parts = [head + "."]
    by_id = {c.effect: c for c in tried}
    if missing:
        c = by_id[missing]
        cls = effect_class(missing)
        shows = ", ".join(cls.shows_in) or "every phase"
        effect = next(e for e in c.fit.model.effects if e.id == missing)
        before = {p: current.rmse_by_phase.get(p, np.nan) for p in cls.shows_in if p in current.rmse_by_phase}
        moved = "; ".join(f"{p} RMS {before[p]:.3g} -> {c.fit.rmse_by_phase[p]:.3g} N" for p in before)
        head = (f"Adding {missing} ({effect.form} form: {effect.describe()}) lowers BIC by {-c.delta_bic:.3g}, the total "
                f"force RMS from {current.rmse_force:.3g} N to {c.rmse_after:.3g} N ({moved or 'where it shows: ' + shows})")
        if c.significant:
            parts.append(f"{head} and removes {100 * min(c.explained, 1.0):.0f} % of the misfit where it shows ({shows}).")
        else:
            parts.append(f"{head} and completes the model: the model misfit beyond {EXCESS_SIGMAS:g} sd "
                         f"({', '.join(c.clears)}) and with it misfits nowhere, though where {missing} shows "
                         f"({shows}) it fit within the noise already (the effects added took up its share).")
        ranged = {k: r for k, r in held_ranges(c.fit).items() if k.startswith(missing + ".")}
        if ranged:
            spans = "; ".join(f"{k.split('.', 1)[1]} between {lo:.3g} and {hi:.3g}" for k, (lo, hi) in ranged.items())
            parts.append(f"Only readings under the dead band show it: they hold its {spans} (the middle "
                         f"reported, half the range as its std).")
        loose = undetermined(c.fit, missing, 0.5)
        if loose:
            names = " and ".join(k.split(".", 1)[1] for k in loose)
            verb, them = ("is", "it") if len(loose) == 1 else ("are", "them")
            parts.append(f"Its {names} {verb} only loosely determined by these data (std above half the value): "
                         f"{cls.resolving_experiment} would pin {them} down.")
        louder = [o for o in tried if o.eligible and o.delta_bic < c.delta_bic]
        if louder:
            parts.append("Counted where the model misfits (each phase's gain up to its excess over the noise), "
                         f"{missing} lowers BIC by {-c.misfit_delta_bic:.3g}, "
                         + ", ".join(f"{o.effect} by {-o.misfit_delta_bic:.3g} (over the whole record "
                                     f"{-o.delta_bic:.3g}: the rest fits what the noise leaves)" for o in louder) + ".")
        parts.append(f"Verdict: {missing} is missing.")
    elif undecided:
        rivals = [by_id[e] for e in undecided]
        listed = " and ".join(f"{c.effect} (BIC -{-c.delta_bic:.3g}, RMS {c.rmse_after:.3g} N)" for c in rivals)
        if len(rivals) > 1 and all(c.determined for c in rivals):
            why = (f"they explain the misfit within {BIC_DECISIVE:g} of each other in BIC counted where the model "
                   "misfits")
        else:
            why = "the data do not bound " + ", ".join(k for c in rivals for k in undetermined(c.fit, c.effect))
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
                elif c.contradicted and c.delta_bic < -BIC_DECISIVE:
                    why.append(f"{c.effect} ({c.form} form) lowers BIC by {-c.delta_bic:.3g}, but {c.contradicted}")
                elif c.delta_bic >= -BIC_DECISIVE:
                    why.append(f"{c.effect} changes BIC by {c.delta_bic:+.3g}")
                elif c.excess_before <= DETECT_SIGMAS:
                    why.append(f"{c.effect} lowers BIC by {-c.delta_bic:.3g} but the phases it shows in "
                               f"({', '.join(effect_class(c.effect).shows_in)}) fit within the noise "
                               f"({c.excess_before:.2g} sd)")
                elif c.misfit_delta_bic >= -BIC_DECISIVE:
                    why.append(f"{c.effect} lowers BIC by {-c.delta_bic:.3g}, but counted where the model "
                               f"misfits by {-c.misfit_delta_bic:+.3g}: it fits the noise, not a misfit")
                elif c.explained >= EXCESS_EXPLAINED and c.footprint:
                    phase, share = min(c.footprint.items(), key=lambda kv: kv[1])
                    why.append(f"{c.effect} lowers BIC by {-c.delta_bic:.3g} and removes "
                               f"{100 * c.explained:.0f} % of the misfit where it shows, but "
                               + (f"makes the {phase} phase misfit" if share == -np.inf else
                                  f"only {100 * share:.0f} % in the {phase} phase"))
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


def keep_too_short(closed_form: Estimate, profile: StageProfile, rate_std: float) -> str:
    """Why the keep shows too little for "adequate" to stand plain ("": it does not):
    the force curved too little in it to show its relaxation rate (the closed form's
    rule, ``pipeline.undetermined``: its relative std above ``rate_std``), so the
    equations determine no parameter and an effect that shows only in the keep had
    nowhere to show."""
    rel = closed_form.residual_rms.get("rate_rel_std", 0.0)
    if rel <= rate_std:
        return ""
    keep = next((p for p in profile.phases if p.name == "keep"), None)
    length = f" ({keep.t_end - keep.t_start:.3g} s)" if keep is not None else ""
    unseen = [e for e in catalogue() if set(effect_class(e).shows_in) == {"keep"}]
    return (f"the keep{length} was too short for the force to relax visibly: c2 (and E, c1, gamma) not "
            "determined by the closed form because the keep is too short"
            + (f", and {' and '.join(unseen)}, which shows in the keep, could not show" if unseen else ""))


def judged_keep(evidence: str, adequate: bool, short: str) -> str:
    """The verdict's paragraph, never a plain "adequate" on a keep the analysis could not
    judge (``short``: ``keep_too_short``'s reason)."""
    if not (adequate and short):
        return evidence
    return f"{evidence} But {short}: adequate for the phases recorded, not judged on the keep; a longer keep decides."
