"""``Analysis``: what ``rheo analyze`` found on a push, and its JSON (the contract's report).

It reads the bag, segments pull / keep / release, identifies the three-element
parameters by the paper's equations, fits the base model over the whole record,
adds the effects the user asks for, then diagnoses what is still missing, adds it
and refits until the model is adequate (``discover``). The result carries every
model fitted with its residuals, the verdicts, and the contract's JSON.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rheo_ros.config.setup import Setup
from rheo_ros.diagnosis.decision import Diagnosis, Verdict, at_bound
from rheo_ros.diagnosis.evidence import judged_keep, keep_too_short
from rheo_ros.diagnosis.fits import ModelFit
from rheo_ros.diagnosis.remaining import remaining
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import BASE_PARAMETERS, Estimate
from rheo_ros.identification.noise import SensorNoise
from rheo_ros.identification.pooling import Change, Pool, pool_experiments, pooled
from rheo_ros.record import Record, contact_depth


@dataclass(frozen=True)
class Analysis:
    """What ``analyze`` found.

    Attributes:
        bag: the bag's path.
        record: its measurements; setup: its parameters, built; forward: the forward
            model every fit used.
        noise: the sensor noise the data show.
        closed_form: the paper's identification (eq. 6, 7, 10 / 14-17); NaN where the
            data leave a parameter undetermined (``undetermined``: why).
        models: every model fitted, in the order tried: the base, the user's
            additions, then each effect the diagnosis added.
        diagnoses: the verdict on each model the loop judged, in order.
        added: the effects the user asked for.
        warnings: what the analysis went without (a closed form with no solution).
        experiments: every push's analysis, in order, when the bag holds more than
            one (each push's record carries the pushes before it); empty for one push.
        object: what the robot said of this push's object (``/rheo/object``): new, same
            or "" (the data decide).
        undetermined: the closed form's parameters the data leave open, each with why
            (``pipeline.undetermined``, as the estimator node reports them).
    """

    bag: str
    record: Record
    setup: Setup
    forward: QuasiStaticFE
    noise: SensorNoise
    closed_form: Estimate
    models: tuple[ModelFit, ...]
    diagnoses: tuple[Diagnosis, ...]
    added: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    experiments: tuple[Analysis, ...] = ()
    object: str = ""
    undetermined: dict[str, str] = field(default_factory=dict)

    @property
    def base(self) -> ModelFit:
        return self.models[0]

    @property
    def final(self) -> ModelFit:
        return self.models[-1]

    @property
    def missing_effects(self) -> tuple[str, ...]:
        """The effects the diagnosis added, in the order found."""
        return Verdict.of(self.diagnoses).missing_effects

    def phases(self) -> list[dict[str, Any]]:
        return [{"name": p.name, "t_start": float(p.t_start), "t_end": float(p.t_end)}
                for p in self.record.profile().phases]

    def evidence(self) -> str:
        """The verdict's paragraph (``Verdict.evidence``), never a plain "adequate" on a
        keep the analysis could not judge (``evidence.judged_keep``, as the node says it)."""
        verdict = Verdict.of(self.diagnoses)
        short = keep_too_short(self.closed_form, self.record.profile(), self.setup.estimator_config().rate_std)
        return judged_keep(verdict.evidence, bool(verdict.adequate), short)

    def closed_form_std(self) -> dict[str, float | None]:
        """A std for the closed form, which has no covariance of its own: the whole-record
        fit's of the same model combined with the closed form's distance from that fit,
        ``sqrt(std_fit^2 + (closed - fit)^2)``. The fit is the efficient estimate, so the
        squared distance estimates the closed form's extra variance (on average; one
        draw); where the model misfits, the two part and the std says so, instead of
        quoting the fit's 0.1 % beside a value 70 % off."""
        fit, std = self.base.estimate.params, self.base.estimate.std
        return {k: _finite(np.hypot(std.get(k, np.nan), self.closed_form.params[k] - fit[k])) for k in BASE_PARAMETERS}

    def to_json(self) -> dict[str, Any]:
        """The contract's report: bag, phases, estimate, models, diagnosis; with several
        pushes, ``experiments``: each push's report with the same keys."""
        if not self.experiments:
            return self._push_json()
        pools, changes = self.pools()
        report = self._pooled_json(pools[-1])
        # Where the stage met the specimen (m of stage depth; the top markers' sinking):
        # the set and recovery the earlier pushes left.
        # from_rest: a later push that met a specimen at rest (met_at_rest), modelled from rest.
        # object: what the robot said of the push's object (the goal's; "" the data decide).
        report["experiments"] = [e._push_json() | {"experiment": k, "contact_depth": contact_depth(e.record),
                                                   "from_rest": k > 1 and not e.record.profile().before,
                                                   "object": e.object}
                                 for k, e in enumerate(self.experiments, 1)]
        report["pools"] = [p.to_json() for p in pools]
        report["changes"] = [c.to_json() for c in changes]
        return report

    def _pooled_json(self, pool: Pool) -> dict[str, Any]:
        """The top level of a report of several pushes: the pooled fit of the experiments
        judged one object - the last pool, the object under the stage when the record ends.
        Each model all members share is pooled by information (``pooled``); its RMS errors
        are the members' root mean squares (force readings weighted by their count, phases
        alike), its BIC their sum (independent records). The closed form is pooled by its
        std (``closed_form_std``, no correlations). The diagnosis is the members' together:
        adequate when each is, every effect any of them misses, the evidence of each."""
        numbers = pool.experiments
        members = [self.experiments[k - 1] for k in numbers]
        which = f"experiment{'s' if len(numbers) > 1 else ''} {', '.join(map(str, numbers))}"
        first = members[0]._push_json()
        report = {"bag": self.bag,
                  "phases": [ph | {"experiment": k} for k, m in zip(numbers, members) for ph in m.phases()],
                  "estimate": _pooled_closed_form(members, which), "sensor": first["sensor"]}
        # A model is shared when every member fitted it with the same parameters (an effect's
        # form may differ between pushes: two relaxation arms in one, one in another).
        def same(x: ModelFit, m: ModelFit) -> bool:
            return x.name == m.name and list(x.estimate.params) == list(m.estimate.params)

        shared = [m for m in members[0].models if all(any(same(x, m) for x in e.models) for e in members)]
        report["models"] = [_pooled_model([next(x for x in e.models if same(x, m)) for e in members], numbers)
                            for m in shared]
        verdicts = [Verdict.of(m.diagnoses) for m in members]
        missing = list(dict.fromkeys(e for v in verdicts for e in v.missing_effects))
        adequate = None if any(v.adequate is None for v in verdicts) else all(v.adequate for v in verdicts)
        finals = {m.final.name for m in members}
        report["diagnosis"] = {
            **first["diagnosis"], "steps": [],   # candidates, undecided: the first member's (experiments)
            "missing_effect": missing[0] if missing else None, "missing_effects": missing,
            "adequate": adequate, "adequate_model": finals.pop() if adequate and len(finals) == 1 else None,
            "explained": None if any(v.explained is None for v in verdicts) else all(v.explained for v in verdicts),
            "closest": list(dict.fromkeys(e for v in verdicts for e in v.closest)), "remaining": None,
            "degenerate": [], "leftover": [], "shared_times": [],   # each push's: experiments
            "evidence": " ".join(f"Experiment {k}: {m.evidence()}" for k, m in zip(numbers, members)),
            "experiments": list(numbers),
        }
        others = [k for k in range(1, len(self.experiments) + 1) if k not in numbers]
        note = (f"{len(self.experiments)} pushes in the bag: each is an experiment (experiments); the top level "
                f"is the pooled fit of {which}, judged one object"
                + (f" (experiments {', '.join(map(str, others))} are another object or the same before it "
                   "changed: see pools and changes)" if others else ""))
        report["warnings"] = list(dict.fromkeys(w for m in self.experiments for w in m.report_warnings())) + [note]
        return report

    def pools(self) -> tuple[list[Pool], list[Change]]:
        """The experiments judged one object, pooled, and where the object changed
        (``pool_experiments`` on each experiment's final model)."""
        return pool_experiments([e.final.estimate for e in self.experiments],
                                new_objects={k for k, e in enumerate(self.experiments, 1) if e.object == "new"})

    def what_remains(self) -> dict[str, Any] | None:
        """What the final model leaves (``remaining.remaining``) where the catalogue does not
        explain these data (``Verdict.explained`` false), with the effects in no catalogue
        fitted against it; None otherwise. Where one of those fits better than the effects
        found (``Verdict.rivals``), those stood in for what is missing: what remains is the
        base model's misfit, the footprint the missing effect must explain."""
        if Verdict.of(self.diagnoses).explained is not False:
            return None
        return remaining(self.remaining_model, self.record, self.diagnoses[-1].rivals)

    @property
    def remaining_model(self) -> ModelFit:
        """The model whose misfit ``what_remains`` describes: the final one, or the base
        where an effect in no catalogue fits better than the effects found."""
        return self.base if Verdict.of(self.diagnoses).rivals else self.final

    def _push_json(self) -> dict[str, Any]:
        verdict = Verdict.of(self.diagnoses)
        # Not diagnosed (--no-discover): adequate is unknown, null.
        diagnosis = self.diagnoses[0].to_json() if self.diagnoses else {"candidates": []}
        diagnosis["missing_effect"] = verdict.missing_effects[0] if verdict.missing_effects else None
        diagnosis["missing_effects"] = list(verdict.missing_effects)
        diagnosis["adequate"] = verdict.adequate
        # explained false: no effect named; the closest the loop found and what is left.
        diagnosis["explained"] = verdict.explained
        diagnosis["closest"] = list(verdict.closest)
        diagnosis["degenerate"] = list(verdict.degenerate)
        diagnosis["leftover"] = list(verdict.leftover)
        diagnosis["shared_times"] = list(verdict.shared_times)
        diagnosis["remaining"] = self.what_remains()
        diagnosis["adequate_model"] = self.final.name if verdict.adequate else None
        diagnosis["evidence"] = self.evidence() if self.diagnoses else "not diagnosed (--no-discover)"
        diagnosis["steps"] = [d.to_json() | {"model": d.model} for d in self.diagnoses]
        return {
            "bag": self.bag,
            "phases": self.phases(),
            "estimate": {
                **{k: _finite(self.closed_form.params[k]) for k in BASE_PARAMETERS},   # null: undetermined
                "std": self.closed_form_std(),
                "undetermined": dict(self.undetermined),
                "method": self.closed_form.method,
                "equations": list(self.closed_form.equations),
                "message": self.closed_form.message,
            },
            "sensor": self.record.sensor_json(),
            "models": [self._model_json(m) for m in self.models],
            "diagnosis": diagnosis,
            "warnings": self.report_warnings(),
        }

    def at_bound(self, m: ModelFit) -> tuple[str, ...]:
        """The parameters of model ``m`` that are no measurement (``decision.at_bound``)."""
        return at_bound(m, self.base, self.record)

    def report_warnings(self) -> list[str]:
        """The analysis's warnings, and a line per model with parameters at a bound."""
        bound = [f"{m.name}: {', '.join(names)} at a bound, not determined by these data (collapsed, run off "
                 "or never moved): no std, no measurement" for m in self.models if (names := self.at_bound(m))]
        return list(self.warnings) + bound

    def _model_json(self, m: ModelFit) -> dict[str, Any]:
        std, bound = m.estimate.std, self.at_bound(m)
        return {
            "name": m.name, "effects": list(m.effects), "forms": m.forms,
            "params": {k: float(v) for k, v in m.estimate.params.items()},
            "std": {k: None if k in bound else _finite(v) for k, v in std.items()}, "at_bound": list(bound),
            "rmse_force": m.rmse_force, "rmse_by_phase": m.rmse_by_phase, "bic": m.bic,
            "fit_to_noise": {k: _finite(v) for k, v in m.estimate.statistics.fit_to_noise.items()},
            "message": m.estimate.message,
        }


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _pooled_closed_form(members: list[Analysis], which: str) -> dict[str, Any]:
    """The members' closed forms, each parameter weighted by its inverse variance
    (``closed_form_std``); a parameter no member determines is null, its std too."""
    values, stds = {}, {}
    for k in BASE_PARAMETERS:
        v = np.array([m.closed_form.params[k] for m in members], float)
        s = np.array([np.nan if (x := m.closed_form_std()[k]) is None else x for m in members], float)
        ok = np.isfinite(v) & np.isfinite(s) & (s > 0)
        w = 1.0 / s[ok] ** 2
        values[k] = float(np.sum(w * v[ok]) / np.sum(w)) if ok.any() else None
        stds[k] = float(1.0 / np.sqrt(np.sum(w))) if ok.any() else None
    methods = {m.closed_form.method for m in members}
    # A parameter no member determines: the first member's reason.
    why = {k: next((m.undetermined[k] for m in members if k in m.undetermined), "no push determines it")
           for k in BASE_PARAMETERS if values[k] is None}
    return {**values, "std": stds, "undetermined": why, "method": methods.pop() if len(methods) == 1 else "pooled",
            "equations": list(dict.fromkeys(q for m in members for q in m.closed_form.equations)),
            "message": f"{which} pooled by inverse variance"}


def _pooled_model(fits: list[ModelFit], numbers: tuple[int, ...]) -> dict[str, Any]:
    """One model's fits on the experiments of a pool, as one (see ``Analysis._pooled_json``)."""
    names = tuple(fits[0].estimate.params)
    pool = pooled([f.estimate for f in fits], names, numbers)
    counts = np.array([f.prediction_total.size for f in fits], float)
    rms = np.array([f.rmse_force for f in fits], float)
    phases = [ph for ph in fits[0].rmse_by_phase if all(ph in f.rmse_by_phase for f in fits)]
    ratios = {k: np.array([f.estimate.statistics.fit_to_noise.get(k, np.nan) for f in fits], float)
              for k in fits[0].estimate.statistics.fit_to_noise}
    return {
        "name": fits[0].name, "effects": list(fits[0].effects), "forms": fits[0].forms,
        "params": {k: _finite(v) for k, v in pool.params.items()},   # null: no push determines it
        "std": {k: _finite(v) for k, v in pool.std.items()},
        "rmse_force": float(np.sqrt(np.sum(counts * rms ** 2) / counts.sum())),
        "rmse_by_phase": {ph: float(np.sqrt(np.mean([f.rmse_by_phase[ph] ** 2 for f in fits]))) for ph in phases},
        "bic": float(sum(f.bic for f in fits)),
        "fit_to_noise": {k: _finite(np.sqrt(np.nanmean(r ** 2)) if np.isfinite(r).any() else np.nan)
                         for k, r in ratios.items()},
        "message": f"experiments {', '.join(map(str, numbers))} pooled by information (chi-square {pool.chi2:.3g} "
                   f"on {pool.dof} dof)",
    }
