"""``Analysis``: what ``rheo analyze`` found on a push, and its JSON (the contract's report).

It reads the bag, segments pull / keep / release, identifies the three-element
parameters by the paper's equations, fits the base model over the whole record,
adds the effects the user asks for, then diagnoses what is still missing, adds it
and refits until the model is adequate (``discover``). The result carries every
model fitted with its residuals, the verdicts, and the contract's JSON.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rheo_ros.config.setup import Setup
from rheo_ros.diagnosis.decision import Diagnosis, Verdict
from rheo_ros.diagnosis.fits import ModelFit
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import BASE_PARAMETERS, Estimate
from rheo_ros.identification.noise import SensorNoise
from rheo_ros.identification.pipeline import contact_depth
from rheo_ros.identification.pooling import Change, Pool, pool_experiments
from rheo_ros.record import Record


@dataclass(frozen=True)
class Analysis:
    """What ``analyze`` found.

    Attributes:
        bag: the bag's path.
        record: its measurements; setup: its parameters, built; forward: the forward
            model every fit used.
        noise: the sensor noise the data show.
        closed_form: the paper's identification (eq. 6, 7, 10 / 14-17).
        models: every model fitted, in the order tried: the base, the user's
            additions, then each effect the diagnosis added.
        diagnoses: the verdict on each model the loop judged, in order.
        added: the effects the user asked for.
        warnings: what the analysis went without (a closed form with no solution).
        experiments: every push's analysis, in order, when the bag holds more than
            one (each push's record carries the pushes before it); empty for one push.
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
        report = self._push_json()
        if self.experiments:
            # Where the stage met the specimen (m of stage depth; the top markers' sinking):
            # the set and recovery the earlier pushes left.
            report["experiments"] = [e._push_json() | {"experiment": k, "contact_depth": contact_depth(e.record)}
                                     for k, e in enumerate(self.experiments, 1)]
            pools, changes = self.pools()
            report["pools"] = [p.to_json() for p in pools]
            report["changes"] = [c.to_json() for c in changes]
        return report

    def pools(self) -> tuple[list[Pool], list[Change]]:
        """The experiments judged one object, pooled, and where the object changed
        (``pool_experiments`` on each experiment's final model)."""
        return pool_experiments([e.final.estimate for e in self.experiments])

    def _push_json(self) -> dict[str, Any]:
        verdict = Verdict.of(self.diagnoses)
        # Not diagnosed (--no-discover): adequate is unknown, null.
        diagnosis = self.diagnoses[0].to_json() if self.diagnoses else {"candidates": []}
        diagnosis["missing_effect"] = verdict.missing_effects[0] if verdict.missing_effects else None
        diagnosis["missing_effects"] = list(verdict.missing_effects)
        diagnosis["adequate"] = verdict.adequate
        diagnosis["adequate_model"] = self.final.name if verdict.adequate else None
        diagnosis["evidence"] = verdict.evidence if self.diagnoses else "not diagnosed (--no-discover)"
        diagnosis["steps"] = [d.to_json() | {"model": d.model} for d in self.diagnoses]
        return {
            "bag": self.bag,
            "phases": self.phases(),
            "estimate": {
                **{k: float(self.closed_form.params[k]) for k in BASE_PARAMETERS},
                "std": self.closed_form_std(),
                "method": self.closed_form.method,
                "equations": list(self.closed_form.equations),
                "message": self.closed_form.message,
            },
            "sensor": self.record.sensor.to_json() if self.record.sensor else None,
            "models": [self._model_json(m) for m in self.models],
            "diagnosis": diagnosis,
            "warnings": list(self.warnings),
        }

    @staticmethod
    def _model_json(m: ModelFit) -> dict[str, Any]:
        std = m.estimate.std
        return {
            "name": m.name, "effects": list(m.effects), "forms": m.forms,
            "params": {k: float(v) for k, v in m.estimate.params.items()},
            "std": {k: _finite(v) for k, v in std.items()},
            "rmse_force": m.rmse_force, "rmse_by_phase": m.rmse_by_phase, "bic": m.bic,
            "fit_to_noise": {k: _finite(v) for k, v in m.estimate.statistics.fit_to_noise.items()},
            "message": m.estimate.message,
        }


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None
