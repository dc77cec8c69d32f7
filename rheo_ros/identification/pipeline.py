"""The steps every identification of a push takes, the same online (the estimator
node, phase by phase) and offline (``rheo analyze``, the whole bag): the closed form
of a phase, the whole-record fit from its starts, which parameters the data leave
undetermined, and the total force's error.

Both drivers call these functions and nothing else decides these questions, so the
node publishes for a bag what ``rheo analyze`` reports for it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from rheo_ros.config.tuning import EstimatorConfig
from rheo_ros.experiment import PUSH_PHASES, phase_of
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.closed_form import (
    displacement_at_depth,
    from_final_displacement,
    from_pull,
    from_pull_and_keep,
    lateral_strain_ratio,
)
from rheo_ros.identification.estimate import BASE_PARAMETERS, Estimate
from rheo_ros.identification.fit import fit_record, steady_readings
from rheo_ros.identification.noise import SensorNoise, Weights, despiked, force_noise, sensor_noise
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record, RecordError, contact_depth, frames_before, frames_held

# The closed forms a phase's data allow, best first: the first with a solution is
# reported, the first two are the whole-record fit's starts. After release the
# final-displacement solution (eq. 6+14, 7, 15-17); the pull-and-keep solution (eq. 6,
# 7, 10) is a second start which an effect after release (adhesion, drift) cannot
# corrupt, and stands in where the first has no solution; eq. 6 on the pull alone last.
CLOSED_FORMS: dict[str, tuple[tuple[str, Callable[..., Estimate]], ...]] = {
    "pull": (("eq. 6 (pull)", from_pull),),
    "keep": (("eq. 6, 7, 10 (pull and keep)", from_pull_and_keep), ("eq. 6 (pull)", from_pull)),
    "release": (("eq. 6+14, 7, 15-17 (final displacement)", from_final_displacement),
                ("eq. 6, 7, 10 (pull and keep)", from_pull_and_keep), ("eq. 6 (pull)", from_pull)),
}
# A fit from each start is capped (a start in the wrong basin wanders); the best is then
# fitted to convergence.
SCREENING_ITERATIONS = 25
# A slower relaxation (c2 this many times larger) that fits the data as well means the
# data set no upper bound on c2: its std from the local curvature would mislead.
PROFILE_FACTOR = 30.0
# Held fits that bisect the flat valley along c2 down to where the cost rises by 4.
PROFILE_STEPS = 8


@dataclass(frozen=True)
class ClosedForm:
    """A phase's closed form: the solution reported, the solutions the fit starts from,
    the closed forms that had none (each with its reason), and how many of the phase's
    closed forms (``CLOSED_FORMS``) were tried (``closed_form`` goes on from there)."""

    estimate: Estimate
    starts: tuple[dict[str, float], ...]
    failed: tuple[str, ...] = ()
    tried: int = 0


# The closed forms' solutions a fit starts from (the first is reported).
STARTS = 2


def require_readings(record: Record, stream: str = "tactile") -> None:
    """Refuse a record whose tactile readings carry no force (``SensorReading.unreadable``,
    or a push read only at saturation): every number identified from them would be
    wrong. ``stream`` names them in the message.

    Raises:
        RecordError: names the record's source, the stream and what is wrong.
    """
    if record.sensor is not None and record.sensor.unreadable:
        raise RecordError(f"{record.source}: {stream}: {record.sensor.unreadable}")
    band = record.dead_band
    if band is None or not np.any(np.isfinite(band.saturation)):
        return
    # A push read only at the array's saturation (and under its dead band) carries no
    # force: the closed forms read a flat line, the fit only bounds.
    profile = record.profile()
    pressing = (record.force_t >= profile.t_pull_start) & (record.force_t <= profile.t_keep_end)
    measured = force_noise(record)[0]
    std = np.nan_to_num(measured)
    force = record.force[pressing]
    saturated = force >= band.top(std)   # at saturation itself where the noise is nil
    # Between the two, too few readings for any segment to show its noise: no force scale.
    if saturated.any() and (not (band.live(force, std) & ~saturated).any() or np.isnan(measured).all()):
        top = ", ".join(f"{v:.3g}" for v in np.broadcast_to(band.saturation, (record.mesh.cols,)))
        raise RecordError(f"{record.source}: {stream}: through the pull and the keep every segment reads at its "
                          f"saturation ({top} N, P1, P2, ...) or under its dead band (too few readings between "
                          "them to show a noise): the array did not measure the push's force; a sensor with a "
                          "larger range, or a shallower push")


def closed_form(phase: str, record: Record, forward: QuasiStaticFE, solutions: int = STARTS,
                after: ClosedForm | None = None) -> ClosedForm:
    """The paper's solution for the data of a push up to the end of ``phase``
    (``CLOSED_FORMS``), with a note in its message naming the better ones that failed;
    up to ``solutions`` solutions as the fit's starts. ``after``: the same phase's closed
    form with fewer, gone on with (the node publishes the first solution before it
    computes the second: the same starts as in one call).

    Raises:
        RecordError: readings that carry no force (``require_readings``).
        NoClosedForm: no closed form has a solution (each reason named).
    """
    require_readings(record)
    failed: list[str] = [] if after is None else list(after.failed)
    starts = [] if after is None else list(after.starts)
    reported = None if after is None else after.estimate
    tried = 0 if after is None else after.tried
    record = despiked(as_fresh_push(record))
    nodes = unsaturated_nodes(record)
    forms = CLOSED_FORMS[phase]
    while tried < len(forms) and len(starts) < solutions:
        label, identify = forms[tried]
        tried += 1
        try:
            solution = identify(record, forward=forward, nodes=nodes)
        except RecordError as exc:
            failed.append(f"{label}: {exc}")
            continue
        if reported is None:
            reported = solution
            if failed:
                note = f"{solution.method} reported in place of: {'; '.join(failed)}"
                reported = replace(solution, message=f"{note}; {solution.message}" if solution.message else note)
        starts.append(solution.params)
    if reported is None:
        raise NoClosedForm(f"{record.source}: no closed form has a solution ({'; '.join(failed)})")
    return ClosedForm(reported, tuple(starts), tuple(failed), tried)


class NoClosedForm(RecordError):
    """No closed form of the phase has a solution: the fit starts from ``searched_starts``."""


# Where no closed form has a solution (a record the three-element model describes badly:
# an effect in no catalogue bends the curves the equations read), the fit starts from a
# search over the model's two times on the record's own scales, E at each by linear least
# squares (at fixed times the force is linear in E).
SEARCH_VOIGT_TIMES = (0.1, 0.3, 1.0, 3.0)      # c1/E in pull times
SEARCH_RELAXATION_TIMES = (1.0, 10.0, 100.0)   # c2/E in keep times (pull times before a keep)
SEARCH_GAMMA = 0.3                               # where the markers show no uniaxial compression
SEARCHED = "the fit started from a search over the relaxation times"


def searched_starts(record: Record, forward: QuasiStaticFE, earlier: Estimate | None = None,
                    count: int = STARTS) -> list[dict[str, float]]:
    """The fit's starts where no closed form has a solution (``NoClosedForm``): the
    ``count`` grid points over c1/E and c2/E (``SEARCH_VOIGT_TIMES``,
    ``SEARCH_RELAXATION_TIMES``) whose least-squares E leaves the smallest error in the
    live readings, gamma from the markers' uniform strain in the pull, and ``earlier``'s
    parameters (the push before's final fit).

    Raises:
        RecordError: no grid point gives the readings a positive E, and no ``earlier``.
    """
    profile = record.profile()
    live = sensor_noise(record).force_live & np.isfinite(record.force)
    measured = record.force[live]
    try:
        u = displacement_at_depth(record, profile.depth)
        gamma = float(np.clip(lateral_strain_ratio(record.mesh.nodes, u), 0.0, 0.45))
    except RecordError:
        gamma = SEARCH_GAMMA
    gamma = gamma if np.isfinite(gamma) else SEARCH_GAMMA
    pull = profile.pull_time
    slow = profile.keep_time if profile.keep_time > 0 else pull
    scored = []
    for voigt in SEARCH_VOIGT_TIMES:
        for relaxation in SEARCH_RELAXATION_TIMES:
            c1, c2 = voigt * pull, relaxation * slow
            unit = forward.predict(Model(three_element(1.0, c1, c2)), gamma, profile, record.force_t,
                                   record.marker_t[:1]).force[live]
            norm = float(unit @ unit)
            E = float(unit @ measured) / norm if norm > 0 else np.nan
            if E > 0:
                scored.append((float(np.sum((measured - E * unit) ** 2)), {"E": E, "c1": E * c1, "c2": E * c2,
                                                                             "gamma": gamma}))
    starts = [start for _, start in sorted(scored, key=lambda s: s[0])[:count]]
    if (start := start_from(earlier)) is not None:
        starts.append(start)
    if not starts:
        raise RecordError(f"{record.source}: no closed form has a solution, and no E > 0 fits the readings "
                          "at any relaxation time searched: nothing to start a fit from")
    return starts


def unsaturated_nodes(record: Record) -> np.ndarray | None:
    """The segments the closed forms use: those with no reading above the live range
    (``DeadBand.top``: a cell, or all of them, clipped), whose curves eq. 6 and 7 would
    bend. None: every segment (none saturates, or every one does: nothing to choose)."""
    band = record.dead_band
    if band is None or not np.any(np.isfinite(band.saturation)):
        return None
    std = force_noise(record)[0]
    over = (record.force > band.top(np.nan_to_num(std))).any(axis=0)
    return np.flatnonzero(~over) if over.any() and not over.all() else None


# A contact this shallow (share of the push's depth) is taken as the stage's zero.
SHALLOW_CONTACT = 0.01


def met_at_rest(record: Record) -> bool:
    """A later push (``profile.before``) that met the specimen at the stage's zero
    (``contact_depth`` within ``SHALLOW_CONTACT`` of the depth): whatever the pushes before
    did, the specimen is at rest in its first shape - another object, or one that
    recovered fully - and is modelled from rest. (The three-element model's state is two
    non-negative strains summing to the top's sinking: none left, no state left.)"""
    profile = record.profile()
    if not profile.before or not (frames_before(record).any() and frames_held(record).any()):
        return False   # no view of the top before the push or during the hold: cannot tell
    return contact_depth(record) <= SHALLOW_CONTACT * profile.depth


def as_fresh_push(record: Record) -> Record:
    """A push after others (``profile.before``), as the paper's closed forms see a push:
    from a specimen at rest, starting where the stage met it (``contact_depth``), as deep
    as it went from there. The recovery still under way when it began is not modelled:
    the closed form is a start and a check; the whole-record fit carries the history."""
    profile = record.profile()
    if not profile.before:
        return record
    if met_at_rest(record):
        return replace(record, stage_profile=replace(profile, before=()))
    met = contact_depth(record)
    late = met / profile.velocity
    fresh = replace(profile, before=(), depth=profile.depth - met, start_delay=profile.start_delay + late)
    return replace(record, stage_profile=fresh)


def fit_weights(noise: SensorNoise) -> Weights | None:
    """The sensor noise where the data show it (the fit's cost is then a chi-square,
    comparable across models); None where they do not (a noise-free record): the fit
    then weights by its own residuals."""
    return noise.weights if noise.known else None


def relaxation_in_view(record: Record, start: dict[str, float]) -> dict[str, float]:
    """``start`` with c2 lowered, if need be, so that the relaxation time (c1 + c2) / E is
    the record's length (c1 / E plus that length where c1 alone takes longer). An
    ill-posed closed form leaves its raw values wherever its search stopped, and a fit
    from a c2 far too slow strands where c2 has no gradient (seen: c2 1.7e14 ends at
    c2 -> inf, c1 3.8 std off; from c2 <= 1e12 every start tried reaches the optimum)."""
    if not all(np.isfinite(start[n]) and start[n] > 0 for n in ("E", "c1", "c2")):
        return start
    span = float(record.force_t[-1] - record.profile().t_pull_start)
    c2 = start["E"] * span - start["c1"]
    c2 = c2 if c2 > 0 else start["E"] * span
    return {**start, "c2": min(start["c2"], c2)}


def fit_starts(record: Record, closed: ClosedForm, config: EstimatorConfig,
               earlier: Estimate | None = None) -> list[dict[str, float]]:
    """Where the whole-record fit starts: the closed forms' solutions and, where the
    reported one leaves a parameter undetermined, it again with the relaxation in view and
    ``earlier`` (the final fit of the push before: a push that meets a specimen still
    recovering, after a cancelled one, has no usable closed form, and the object is most
    likely the same; a start only, kept if it fits best)."""
    starts = list(closed.starts)
    if undetermined(record, closed.estimate, config):
        in_view = relaxation_in_view(record, closed.estimate.params)
        if in_view != closed.estimate.params:
            starts.append(in_view)
        if (start := start_from(earlier)) is not None and start not in starts:
            starts.append(start)
    return starts


def start_from(estimate: Estimate | None) -> dict[str, float] | None:
    """An estimate's base parameters as a fit's start (None: no estimate, or a value
    that is not finite)."""
    if estimate is None:
        return None
    start = {k: float(estimate.params[k]) for k in BASE_PARAMETERS}
    return start if all(np.isfinite(v) for v in start.values()) else None


def interim_start(record: Record, closed: ClosedForm, config: EstimatorConfig) -> dict[str, float]:
    """The one start of an interim fit (superseded within seconds; no screening): the
    reported closed form, with the relaxation in view where it leaves a parameter
    undetermined (a c2 far too slow strands a fit, see ``relaxation_in_view``)."""
    if undetermined(record, closed.estimate, config):
        return relaxation_in_view(record, closed.estimate.params)
    return closed.starts[0]


def fit_from_starts(record: Record, forward: QuasiStaticFE, starts: Sequence[dict[str, float]],
                    model: Model | None = None, noise: SensorNoise | None = None) -> Estimate:
    """The whole-record fit: from each start (capped at SCREENING_ITERATIONS), the most
    likely kept (lowest deviance; a NaN never wins), then fitted to convergence with the
    mesh's discretisation error in its std. A single start is fitted to convergence
    directly (there is nothing to screen).

    Raises:
        RecordError: readings that carry no force (``require_readings``), or no start
            could be fitted.
    """
    require_readings(record)
    noise = noise or sensor_noise(record)
    weights = fit_weights(noise)
    model = model or Model(three_element(1.0, 1.0, 1.0))
    if len(starts) == 1:
        initial = Estimate(params={**model.parameters, **starts[0]}, method="start", equations=())
        try:
            return fit_record(record, initial, model=model, forward=forward, weights=weights, discretisation=True)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise RecordError(f"{record.source}: the whole-record fit failed ({type(exc).__name__}: {exc})") from exc
    fits: list[Estimate] = []
    errors: list[str] = []
    for start in starts:
        initial = Estimate(params={**model.parameters, **start}, method="start", equations=())
        try:
            fits.append(fit_record(record, initial, model=model, forward=forward, weights=weights,
                                   discretisation=False, max_iterations=SCREENING_ITERATIONS))
        except (ValueError, np.linalg.LinAlgError) as exc:
            errors.append(f"{type(exc).__name__}: {exc}")
    if not fits:
        raise RecordError(f"{record.source}: the whole-record fit failed from every start ({'; '.join(errors)})")
    best = min(fits, key=lambda f: np.nan_to_num(f.statistics.deviance, nan=np.inf))
    return fit_record(record, best, model=model, forward=forward, weights=weights, discretisation=True)


def relaxation_unseen(record: Record, fit: Estimate, forward: QuasiStaticFE,
                      starts: Sequence[dict[str, float]] = ()) -> tuple[str, Estimate]:
    """Profile of the likelihood along c2: the fit again with c2 held PROFILE_FACTOR times
    larger (same weights); a cost within 4 (2 std) says the data cannot tell: the reason
    ("" when they can) and the fit to report.

    Where they cannot, the fit's c2 is one point of a flat valley (often at the search's
    edge, an infinite c2) and the other parameters' std, taken there, is conditional on
    it. So the valley's other end is found: the smallest c2 that still fits within a cost
    of 4, bisected (PROFILE_STEPS held fits, in log c2) down to the smallest c2 a start
    proposed; each other parameter's move to that end is a two-std move, and half of it
    joins its std: the data know it only that well."""
    stats = fit.statistics
    weights = Weights(stats.force_weights, stats.weights["markers"])

    def held_at(c2: float) -> Estimate | None:
        try:
            return fit_record(record, fit, fixed={"c2": c2}, forward=forward, discretisation=False, weights=weights)
        except (ValueError, np.linalg.LinAlgError):
            return None

    def within(est: Estimate | None) -> bool:
        return est is not None and est.statistics.cost - stats.cost < 4.0

    alt = held_at(fit.params["c2"] * PROFILE_FACTOR)
    if not within(alt):
        return "", fit
    reason = (f"the data fit as well with c2 {PROFILE_FACTOR:g} x larger (cost +{alt.statistics.cost - stats.cost:.2g}): "
              "the relaxation is not seen")
    proposed = [float(s["c2"]) for s in starts if 0 < s.get("c2", np.nan) < fit.params["c2"]]
    if not proposed or fit.covariance is None:
        return reason, fit
    inside, outside = np.log(fit.params["c2"]), np.log(min(proposed))
    end = fit
    low = held_at(float(np.exp(outside)))
    if within(low):
        end = low
    else:
        for _ in range(PROFILE_STEPS):
            middle = 0.5 * (inside + outside)
            trial = held_at(float(np.exp(middle)))
            if within(trial):
                inside, end = middle, trial
            else:
                outside = middle
    half = np.array([0.0 if n == "c2" else 0.5 * (end.params[n] - fit.params[n]) for n in fit.params])
    return reason, replace(fit, covariance=fit.covariance + np.diag(half**2))


def undetermined(record: Record, est: Estimate, config: EstimatorConfig, unseen: str = "") -> dict[str, str]:
    """The parameters of ``est`` these data leave undetermined, each with why (and the
    experiment that would determine it): the one rule for every estimate.

    A closed form (no covariance) is undetermined where its relaxation rate is (relative
    std above ``config.rate_std``); a fit's parameter where its std exceeds
    ``config.undetermined_std`` of its value (gamma: ``config.gamma_std`` absolute), or
    where ``unseen`` (``relaxation_unseen``) says the relaxation is not seen. Gamma at
    its bound is never determined.
    """
    names = tuple(n for n in BASE_PARAMETERS if n in est.params)
    values = np.array([est.params[n] for n in names])
    out: dict[str, str] = {}
    profile = record.profile()
    rate = values[0] / (values[1] + values[2])
    seen = min(record.force_t[-1], profile.t_keep_end) - profile.t_pull_start
    longer = (f"a keep of at least {2.0 / rate:.0f} s (2 relaxation times) determines it" if 2.0 / rate < 1e5
              else "a keep long enough for the force to relax visibly determines it")
    if "gamma" in est.params and not -0.98 < est.params["gamma"] < 0.499:
        out["gamma"] = (f"the equations put it at its bound ({est.params['gamma']:.4g}): no solution "
                        "inside the physical range; a deeper push determines it")
        if est.covariance is None:
            # The closed form solves E, c1, c2 with gamma (K_gamma, eq. 14-17): pinned at
            # its bound, it biases them (a 0.4 s pull: E +24 %).
            for n in ("E", "c1", "c2"):
                out[n] = (f"solved with gamma at its bound ({est.params['gamma']:.4g}), which biases it; "
                          "a deeper or slower push determines it (the whole-record fit does not need it)")
    if est.covariance is None:
        rel = est.residual_rms.get("rate_rel_std", 0.0)
        if not rel <= config.rate_std:
            for n in names:   # every parameter of the equations rests on the rate
                out[n] = (f"the force curved too little to show its relaxation rate (+-{100 * rel:.0f} %, "
                          f"rate x time seen = {rate * seen:.2g}); {longer}")
    else:
        std = np.sqrt(np.clip(np.diag(est.covariance), 0, None))
        for i, n in enumerate(names):
            if n == "gamma":
                if not std[i] <= config.gamma_std:
                    out[n] = (f"std {std[i]:.2g}: the markers' lateral motion is within their noise; "
                              "a deeper push determines it")
            elif not std[i] <= config.undetermined_std * abs(values[i]):
                why = f"std {100 * std[i] / abs(values[i]):.0f} % of the value"
                out[n] = f"{why}; {longer}" if n in ("E", "c2") else why
    if unseen:
        for n in ("E", "c2"):
            out[n] = f"{unseen}; {longer}"
    return out


def without_undetermined(est: Estimate, open_: dict[str, str]) -> Estimate:
    """``est`` as it is reported: each parameter in ``open_`` (``undetermined``) NaN, its
    covariance row and column too (a value the data leave open is not a value)."""
    bad = [i for i, n in enumerate(est.params) if n in open_]
    cov = None if est.covariance is None else est.covariance.copy()
    if cov is not None:
        cov[bad, :] = np.nan
        cov[:, bad] = np.nan
    return replace(est, params={n: np.nan if n in open_ else v for n, v in est.params.items()}, covariance=cov)


def is_determined(value: float, std: float, relative_limit: float) -> bool:
    """A parameter the data pin down: a finite std within ``relative_limit`` of its value."""
    return bool(np.isfinite(std) and std <= relative_limit * abs(value))


def force_error(record: Record, predicted: np.ndarray) -> tuple[float, dict[str, float]]:
    """RMS error (N) of the total bottom force over the record and per phase, with the
    model ``predicted`` (T, nodes) at the record's force stamps read as the array reads
    (through its dead band: after the let-go a force below it reads zero, not its small
    true value), leaving out readings within a phase boundary's guard (mid-jump there;
    the quasi-static model has jumped)."""
    profile = record.profile()
    away = steady_readings(record)
    err = (record.reading(predicted).sum(axis=1) - record.force.sum(axis=1))[away]
    which = phase_of(record.force_t[away], profile)
    by_phase = {name: float(np.sqrt(np.mean(err[which == i] ** 2)))
                for i, name in enumerate(PUSH_PHASES, start=1) if np.any(which == i)}
    return float(np.sqrt(np.mean(err**2))), by_phase

