"""``analyze``: a bag in, the model-discovery loop's result out (``rheo analyze``).

It reads the bag, segments pull / keep / release, identifies the three-element
parameters by the paper's equations, fits the base model over the whole record,
adds the effects the user asks for, then diagnoses what is still missing, adds it
and refits until the model is adequate (``discover``). The result carries every
model fitted with its residuals, the verdicts, and the contract's JSON.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from rheo_ros.diagnosis.discover import Diagnosis, ModelFit, Progress, add_effect, discover, fit_model, polish
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.noise import SensorNoise, sensor_noise
from rheo_ros.identification.paper import identify_keep, identify_paper, identify_pull
from rheo_ros.io.bag import read_bag
from rheo_ros.models.effects import effect_class
from rheo_ros.params import Setup, check_params, load_params
from rheo_ros.record import Record, RecordError

BASE_PARAMS = ("E", "c1", "c2", "gamma")


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

    @property
    def base(self) -> ModelFit:
        return self.models[0]

    @property
    def final(self) -> ModelFit:
        return self.models[-1]

    @property
    def missing_effects(self) -> tuple[str, ...]:
        """The effects the diagnosis added, in the order found."""
        return tuple(d.missing_effect for d in self.diagnoses if d.missing_effect)

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
        return {k: _finite(np.hypot(std.get(k, np.nan), self.closed_form.params[k] - fit[k])) for k in BASE_PARAMS}

    def to_json(self) -> dict[str, Any]:
        """The contract's report: bag, phases, estimate, models, diagnosis."""
        first = self.diagnoses[0] if self.diagnoses else None
        # Not diagnosed (--no-discover): adequate is unknown, null.
        diagnosis = first.to_json() if first else {"candidates": []}
        diagnosis["missing_effect"] = self.missing_effects[0] if self.missing_effects else None
        diagnosis["missing_effects"] = list(self.missing_effects)
        diagnosis["adequate"] = bool(self.diagnoses[-1].adequate) if self.diagnoses else None
        diagnosis["adequate_model"] = self.final.name if diagnosis["adequate"] else None
        diagnosis["evidence"] = " ".join(d.evidence for d in self.diagnoses) or "not diagnosed (--no-discover)"
        diagnosis["steps"] = [d.to_json() | {"model": d.model} for d in self.diagnoses]
        return {
            "bag": self.bag,
            "phases": self.phases(),
            "estimate": {
                **{k: float(self.closed_form.params[k]) for k in BASE_PARAMS},
                "std": self.closed_form_std(),
                "method": self.closed_form.method,
                "equations": list(self.closed_form.equations),
                "message": self.closed_form.message,
            },
            "models": [self._model_json(m) for m in self.models],
            "diagnosis": diagnosis,
            "warnings": list(self.warnings),
        }

    @staticmethod
    def _model_json(m: ModelFit) -> dict[str, Any]:
        std = m.estimate.std
        return {
            "name": m.name, "effects": list(m.effects),
            "params": {k: float(v) for k, v in m.estimate.params.items()},
            "std": {k: _finite(v) for k, v in std.items()},
            "rmse_force": m.rmse_force, "rmse_by_phase": m.rmse_by_phase, "bic": m.bic,
            "fit_to_noise": {k.removeprefix("fit_to_noise_"): _finite(v) for k, v in m.estimate.residual_rms.items()
                             if k.startswith("fit_to_noise_")},
            "message": m.estimate.message,
        }


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def closed_forms(record: Record, forward: QuasiStaticFE) -> tuple[Estimate, list[dict[str, float]], str]:
    """The paper's identification to report, the starts of the whole-record fit, and
    which closed forms had no solution ("" when none failed).

    The final-displacement solution (eq. 6+14, 7, 15-17) is the one reported; the
    solution of eq. 6, 7, 10 on pull and keep alone is a second start, which an effect
    after release (adhesion, drift) cannot corrupt. Where the final-displacement
    solution has none (a drift that reverses the force drop at release), the pull and
    keep solution is reported in its place, or eq. 6 on the pull alone, with a message
    that says so.

    Raises:
        RecordError: no closed form has a solution (each reason named).
    """
    solutions: list[Estimate] = []
    failed: list[str] = []
    for label, identify in (("eq. 6+14, 7, 15-17 (final displacement)", identify_paper),
                            ("eq. 6, 7, 10 (pull and keep)", identify_keep), ("eq. 6 (pull)", identify_pull)):
        try:
            solutions.append(identify(record, forward=forward))
        except RecordError as exc:
            failed.append(f"{label}: {exc}")
        if len(solutions) == 2:
            break
    if not solutions:
        raise RecordError(f"{record.source}: no closed form has a solution ({'; '.join(failed)})")
    closed, note = solutions[0], ""
    if failed:
        note = f"{closed.method} reported in place of: {'; '.join(failed)}"
        closed = replace(closed, message=f"{note}; {closed.message}" if closed.message else note)
    return closed, [s.params for s in solutions], note


def analyze(
    bag: str | Path, effects: Sequence[str] = (), params_file: str | Path | None = None,
    discover_effects: bool = True, candidates: Sequence[str] | None = None,
    progress: Progress | None = None, workers: int | None = None,
) -> Analysis:
    """Analyse a bag: identify, compare, diagnose, add what is missing, refit.

    Args:
        bag: a rosbag2 directory of the contract.
        effects: effect ids to add to the base model, in order (``--add``).
        params_file: parameters overriding the bag's own (``--params-file``).
        discover_effects: run the diagnosis loop after the user's effects.
        candidates: effect ids the diagnosis may try (default: the whole catalogue).
        progress: called with a line of text at each step.
        workers: processes for the candidates' fits (default: one per core).

    Raises:
        RecordError: unreadable bag, missing topic, malformed message, a phase too
            short (the message names the file, topic or field).
        ParamsError: a bad parameters file.
        KeyError: an unknown effect id.
    """
    for effect_id in effects:
        effect_class(effect_id)  # an unknown id fails before any work
    say = progress or (lambda _: None)
    params = check_params(load_params(params_file), str(params_file)) if params_file else None
    say(f"reading {bag}")
    contents = read_bag(bag, params)
    params = check_params(contents.params, f"{bag}: parameters")
    setup = Setup(params)
    record = contents.record
    forward = setup.forward_model()
    noise = sensor_noise(record)
    say("closed form (eq. 6, 7, 10 / 14-17)")
    closed, starts, failed = closed_forms(record, forward)
    warnings = (f"closed form: {failed}",) if failed else ()
    for warning in warnings:
        say(f"warning: {warning}")
    say("fitting three_element over the whole record")
    base = polish(record, forward, min((fit_model(record, forward, (), s, noise) for s in starts),
                                       key=lambda f: f.cost), noise)
    models = [base]
    for effect_id in effects:
        current = models[-1]
        say(f"fitting {current.name}+{effect_id}")
        models.append(polish(record, forward, add_effect(record, forward, current, effect_id, noise), noise))
    diagnoses: list[Diagnosis] = []
    if discover_effects:
        found, diagnoses = discover(record, forward, models[-1], candidates, noise, progress=say,
                                     workers=workers)
        models += found[1:]
    return Analysis(str(bag), record, setup, forward, noise, closed, tuple(models), tuple(diagnoses), tuple(effects),
                    warnings)
