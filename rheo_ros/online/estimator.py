"""Online identification: E, c1, c2 (and gamma) updated as each phase of a push completes.

``OnlineEstimator`` takes the three measurement streams sample by sample (header
stamps), segments them (``PhaseSegmenter``) and, once every stream has passed a
phase's end, turns that phase into a ``Job``: a ``Record`` of the push so far. Running
a job (``run_job``, pure numpy/scipy, safe in a worker thread) gives the updates:

- pull: eq. 6 on the pull alone (``identify_pull``), then the whole-record fit of the
  pull's data with its covariance;
- keep: eq. 6, 7, 10 with the keep's marker displacement (``identify_keep``), then the
  fit of pull and keep;
- release: the paper's final-displacement solution (eq. 6+14, 7, 15-17, long- or
  short-time), then the whole-record refinement, then (``estimator.diagnose``) the
  model-discovery loop on the whole push (``diagnose``): which effect the three-element
  model misses, the model with it and the evidence.

Every update says which parameters the data do not determine yet (NaN value, with
the reason and the experiment that would determine it). Which samples a job uses is
decided by header stamps alone, so a bag replayed over DDS gives the numbers of the
same bag read offline. Memory is bounded: only the current push and a short window
before it are kept.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from rheo_ros.diagnosis.compare import PHASES
from rheo_ros.diagnosis.discover import Diagnosis, ModelFit, discover, fit_model, polish
from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import Mesh
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.noise import sensor_noise
from rheo_ros.identification.paper import identify_keep, identify_paper, identify_pull
from rheo_ros.identification.refine import away_from_boundaries, refine
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.online.config import EstimatorConfig, SegmenterConfig
from rheo_ros.online.segmenter import PhaseEvent, PhaseSegmenter
from rheo_ros.params import Setup
from rheo_ros.record import Record, RecordError

BASE_PARAMETERS = ("E", "c1", "c2", "gamma")


@dataclass(frozen=True)
class Update:
    """One published estimate (``/rheo/estimate``)."""

    experiment: int
    phase: str
    stamp: float                    # s, measurement time of the last sample used
    model: str
    effects: tuple[str, ...]
    method: str
    equations: tuple[str, ...]
    names: tuple[str, ...]
    values: np.ndarray              # NaN where not determined
    covariance: np.ndarray | None   # (n, n), NaN rows/columns where not determined; None: the method gives none
    rmse_force: float               # N, total bottom force over the samples used
    samples: int
    undetermined: tuple[str, ...]
    reasons: tuple[str, ...]
    message: str
    final: bool = False             # the experiment's last update (after release: the fit, or the
                                    # closed form when the estimator does not refine)

    @property
    def params(self) -> dict[str, float]:
        return dict(zip(self.names, self.values.tolist()))

    @property
    def std(self) -> dict[str, float]:
        if self.covariance is None:
            return {}
        return dict(zip(self.names, np.sqrt(np.diag(self.covariance)).tolist()))


@dataclass(frozen=True)
class OnlineDiagnosis:
    """The model-discovery loop's verdict on one push (``/rheo/diagnosis``): the models
    fitted in order (the base first) with their force RMS (N) and BIC, the candidates
    tried on the base with their BIC change, and the last model's parameters."""

    experiment: int
    stamp: float
    adequate: bool
    missing_effects: tuple[str, ...]
    undecided: tuple[str, ...]
    models: tuple[str, ...]
    rmse_force: np.ndarray
    bic: np.ndarray
    candidates: tuple[str, ...]
    delta_bic: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    evidence: str

    @classmethod
    def of(cls, experiment: int, stamp: float, models: list[ModelFit], verdicts: list[Diagnosis]) -> OnlineDiagnosis:
        last = models[-1].estimate
        std = last.std
        first = verdicts[0].candidates if verdicts else ()
        return cls(
            experiment=experiment, stamp=stamp, adequate=bool(verdicts and verdicts[-1].adequate),
            missing_effects=tuple(v.missing_effect for v in verdicts if v.missing_effect),
            undecided=verdicts[-1].undecided if verdicts else (), models=tuple(m.name for m in models),
            rmse_force=np.array([m.rmse_force for m in models]), bic=np.array([m.bic for m in models]),
            candidates=tuple(c.effect for c in first), delta_bic=np.array([c.delta_bic for c in first]),
            names=tuple(last.params), values=np.array(list(last.params.values())),
            std=np.array([std.get(n, np.inf) for n in last.params]),
            evidence=" ".join(v.evidence for v in verdicts),
        )


@dataclass(frozen=True)
class Job:
    """A completed phase with the data it is identified from."""

    event: PhaseEvent
    record: Record
    stale: tuple[str, ...] = ()


def supersedes(new: Job, old: Job) -> bool:
    """Whether the whole-record fit of ``new`` makes that of ``old`` pointless: a later
    phase of the same push (its record holds every sample the earlier one's does)."""
    n, o = new.event, old.event
    return n.experiment == o.experiment and PHASES.index(n.name) > PHASES.index(o.name)


@dataclass
class _Stream:
    """Samples of one topic in stamp order, trimmed from the front."""

    t: list[float] = field(default_factory=list)
    data: list[np.ndarray] = field(default_factory=list)

    def add(self, t: float, value: np.ndarray) -> bool:
        if self.t and t <= self.t[-1]:
            return False
        self.t.append(t)
        self.data.append(value)
        return True

    def trim_before(self, t0: float) -> None:
        i = bisect.bisect_left(self.t, t0)
        if i:
            del self.t[:i], self.data[:i]

    def window(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        i, j = bisect.bisect_left(self.t, t0), bisect.bisect_right(self.t, t1)
        return np.array(self.t[i:j]), np.array(self.data[i:j])

    @property
    def last(self) -> float:
        return self.t[-1] if self.t else -np.inf


class PhaseIdentifier:
    """A completed phase's updates: the paper's closed form and the whole-record fit.

    Holds no stream state (what it needs travels in the ``Job``), so that it can run in
    a worker process beside the node.
    """

    def __init__(self, mesh: Mesh, config: EstimatorConfig, forward: QuasiStaticFE | None = None) -> None:
        self.mesh, self.config = mesh, config
        self.forward = forward or QuasiStaticFE(mesh)

    def prepare(self) -> None:
        """Build what the first closed form would otherwise wait for (the forward model's
        implied-force table, ~0.4 s)."""
        self.forward.implied_force(np.zeros(self.mesh.nodes.shape), 0.3)

    def closed_form(self, job: Job) -> tuple[Update | None, Estimate | RecordError]:
        """The paper's solution for the phase (eq. 6 after pull; 6, 7, 10 after keep; 6+14,
        7, 15-17 after release) as an update, and the estimate a fit starts from; where
        the closed form has no solution, no update and the reason.

        Raises:
            RecordError: the phase has too few samples to identify at all.
        """
        e, rec = job.event, job.record
        if rec is None:
            raise RecordError(f"experiment {e.experiment} {e.name}: too few samples to identify")
        try:
            identify = {"pull": identify_pull, "keep": identify_keep, "release": identify_paper}[e.name]
            est = identify(rec, forward=self.forward)
        except RecordError as exc:
            return None, exc
        return self._update(e, rec, est), est

    def fit(self, job: Job, start: Estimate, note: str = "") -> tuple[Update, Estimate]:
        """The whole-record fit of the job's data from ``start``, checked for a relaxation
        the data do not show; ``note`` goes in front of the fit's message.

        Where ``start`` leaves a parameter undetermined (an ill-posed closed form: its raw
        values are wherever its search stopped), the fit also runs from ``start`` with c2
        lowered so that the relaxation shows within the record, and the more likely of the
        two is kept. A slower start can strand the fit where c2 has no gradient (seen: c2
        1.7e14 ends at c2 -> inf, c1 3.8 std off; from c2 <= 1e12 every start tried reaches
        the optimum). Both starts come from the job alone: the result does not depend on
        which earlier fits a lane behind the pushes skipped.
        """
        rec = job.record
        fits = [refine(rec, start, forward=self.forward)]
        if self.undetermined(rec, start):
            in_view = self._relaxation_in_view(rec, start)
            try:
                if in_view.params != start.params:
                    fits.append(refine(rec, in_view, forward=self.forward))
            except (ValueError, np.linalg.LinAlgError):
                pass   # the fit from the start stands
        # A NaN deviance (a non-finite prediction) never wins.
        fit = min(fits, key=lambda f: np.nan_to_num(f.residual_rms["deviance"], nan=np.inf))
        if fit is not fits[0]:
            gain = fits[0].residual_rms["deviance"] - fit.residual_rms["deviance"]
            note = "; ".join(filter(None, [note, f"fit from a start relaxing within the record ({gain:.3g} lower "
                                                 "deviance than from the undetermined start)"]))
        if note:
            fit = replace(fit, message=f"{note}; {fit.message}")
        return self._update(job.event, rec, fit, self._relaxation_unseen(rec, fit)), fit

    @staticmethod
    def _relaxation_in_view(rec: Record, est: Estimate) -> Estimate:
        """``est`` with c2 lowered, if need be, so that the relaxation time (c1 + c2) / E is
        the record's length (c1 / E plus that length where c1 alone takes longer); ``est``
        itself where its values are not finite and positive."""
        p = est.params
        if not all(np.isfinite(p[n]) and p[n] > 0 for n in ("E", "c1", "c2")):
            return est
        span = float(rec.force_t[-1] - rec.profile().t_pull_start)
        c2 = p["E"] * span - p["c1"]
        c2 = c2 if c2 > 0 else p["E"] * span
        return replace(est, params={**p, "c2": min(p["c2"], c2)})

    def diagnose(self, job: Job, fit: Estimate) -> OnlineDiagnosis:
        """The model-discovery loop on a release job's push (``rheo_ros.diagnosis``): the
        base model refitted with the sensor noise as weights from the release ``fit``,
        then each missing effect added until the model is adequate. Seconds to tens of
        seconds: the node runs it in the fit lane, after the release's fit is out.

        Raises:
            RecordError: the job has no record.
        """
        rec, e = job.record, job.event
        if rec is None:
            raise RecordError(f"experiment {e.experiment} {e.name}: too few samples to diagnose")
        noise = sensor_noise(rec)
        base = polish(rec, self.forward, fit_model(rec, self.forward, (), fit.params, noise), noise)
        # One process: the node's fit lane is a worker already.
        models, verdicts = discover(rec, self.forward, base, noise=noise, workers=1)
        return OnlineDiagnosis.of(e.experiment, float(rec.force_t[-1]), models, verdicts)

    # A slower relaxation (c2 this many times larger) that fits the data as well means the
    # data set no upper bound on c2: its std from the local curvature would mislead.
    PROFILE_FACTOR = 30.0

    def _relaxation_unseen(self, rec: Record, fit: Estimate) -> str:
        """Profile of the likelihood along c2: refit with c2 held PROFILE_FACTOR times
        larger (same noise weights); a cost within 4 (2 std) says the data cannot tell."""
        r = fit.residual_rms
        force_std = np.array([r[f"force_std_P{i + 1}"] for i in range(self.mesh.cols)])
        held = {"c2": fit.params["c2"] * self.PROFILE_FACTOR}
        try:
            alt = refine(rec, fit, force_std=force_std, marker_std=r["marker_std"], fixed=held,
                         forward=self.forward, discretisation=False)
        except (ValueError, np.linalg.LinAlgError):
            return ""
        delta = alt.residual_rms["cost"] - r["cost"]
        if delta < 4.0:
            return (f"the data fit as well with c2 {self.PROFILE_FACTOR:g} x larger (cost +{delta:.2g}): "
                    "the relaxation is not seen")
        return ""

    # -- one update ------------------------------------------------------------------

    def undetermined(self, rec: Record, est: Estimate, unseen: str = "") -> dict[str, str]:
        """The parameters of ``est`` these data leave undetermined, each with why (and what
        experiment would determine it); ``unseen``: the fit's relaxation check found none."""
        names = tuple(n for n in BASE_PARAMETERS if n in est.params)
        values = np.array([est.params[n] for n in names])
        undetermined: dict[str, str] = {}
        profile = rec.profile()
        rate = values[0] / (values[1] + values[2])
        seen = min(rec.force_t[-1], profile.t_keep_end) - profile.t_pull_start
        longer = (f"a keep of at least {2.0 / rate:.0f} s (2 relaxation times) determines it" if 2.0 / rate < 1e5
                  else "a keep long enough for the force to relax visibly determines it")
        if "gamma" in est.params and not -0.98 < est.params["gamma"] < 0.499:
            undetermined["gamma"] = (f"the equations put it at its bound ({est.params['gamma']:.4g}): no solution "
                                     "inside the physical range; a deeper push determines it")
        if est.covariance is None:
            rel = est.residual_rms.get("rate_rel_std", 0.0)
            if not rel <= self.config.rate_std:
                for n in names:   # every parameter of the equations rests on the rate
                    undetermined[n] = (f"the force curved too little to show its relaxation rate (+-{100 * rel:.0f} %, "
                                       f"rate x time seen = {rate * seen:.2g}); {longer}")
        else:
            std = np.sqrt(np.clip(np.diag(est.covariance), 0, None))
            for i, n in enumerate(names):
                if n == "gamma":
                    if not std[i] <= self.config.gamma_std:
                        undetermined[n] = (f"std {std[i]:.2g}: the markers' lateral motion is within their noise; "
                                           "a deeper push determines it")
                elif not std[i] <= self.config.undetermined_std * abs(values[i]):
                    why = f"std {100 * std[i] / abs(values[i]):.0f} % of the value"
                    undetermined[n] = f"{why}; {longer}" if n in ("E", "c2") else why
        if unseen:
            for n in ("E", "c2"):
                undetermined[n] = f"{unseen}; {longer}"
        return undetermined

    def _update(self, e: PhaseEvent, rec: Record, est: Estimate, unseen: str = "") -> Update:
        names = tuple(n for n in BASE_PARAMETERS if n in est.params)
        values = np.array([est.params[n] for n in names])
        undetermined = self.undetermined(rec, est, unseen)
        cov = None if est.covariance is None else est.covariance.copy()
        rmse = self._rmse_force(rec, est.params)
        bad = [i for i, n in enumerate(names) if n in undetermined]
        values[bad] = np.nan
        if cov is not None:
            cov[bad, :] = np.nan
            cov[:, bad] = np.nan
        return Update(
            experiment=e.experiment, phase=e.name, stamp=float(rec.force_t[-1]),
            model="three_element", effects=(), method=est.method, equations=est.equations, names=names,
            values=values, covariance=cov, rmse_force=rmse, samples=int(rec.force_t.size),
            undetermined=tuple(undetermined), reasons=tuple(undetermined.values()), message=est.message,
            final=e.name == "release" and (est.method == "whole_record" or not self.config.refine),
        )

    def _rmse_force(self, rec: Record, params: dict[str, float]) -> float:
        """RMS error of the total force as the array reads the model, leaving out samples
        within 0.05 s of a phase boundary (the measured force is mid-jump there, the
        quasi-static model has jumped)."""
        model = Model(three_element(params["E"], params["c1"], params["c2"]))
        profile = rec.profile()
        # The table's shape: each update brings a new gamma, and an exact shape costs a
        # factorisation (~18 ms) in the closed form's latency; the RMS moves < 1e-5.
        p = self.forward.predict(model, params["gamma"], profile, rec.force_t, rec.marker_t[:1], tabulated=True)
        use = away_from_boundaries(rec.force_t, profile)
        # Through the tactile dead band, as the offline analysis reads a model: after the
        # let-go a force below it reads zero, not its small true value.
        err = rec.reading(p.force).sum(axis=1)[use] - rec.force.sum(axis=1)[use]
        return float(np.sqrt(np.mean(err**2)))


class OnlineEstimator:
    """Streams in, jobs out. ``add_stage`` / ``add_force`` / ``add_markers`` return the
    phases they completed; ``ready_jobs()`` the phases whose data are all in.

    Args:
        setup: geometry and sensor layout (the parameters file).
        segmenter: online segmentation tuning.
        config: estimator tuning.
    """

    MAX_SAMPLES = 500_000   # per stream, whatever happens (an hour at 100 Hz is 360 000)

    def __init__(self, setup: Setup, segmenter: SegmenterConfig | None = None,
                 config: EstimatorConfig | None = None) -> None:
        self.setup, self.mesh = setup, setup.mesh
        self.tactile = setup.tactile
        self.config = config or EstimatorConfig()
        self.segmenter = PhaseSegmenter(segmenter)
        self.streams = {"stage": _Stream(), "force": _Stream(), "markers": _Stream()}
        self.pending: list[PhaseEvent] = []
        self.profiles: dict[tuple[int, str], StageProfile] = {}
        self.push_start: float | None = None
        self.rejected = {"stage": 0, "force": 0, "markers": 0}
        self.identify = PhaseIdentifier(self.mesh, self.config, setup.forward_model())
        self._fits: dict[int, Estimate] = {}      # the last whole-record fit of the current push
        self.dropped_pushes = 0                    # pushes given up for lasting over max_push_time

    # -- streams ---------------------------------------------------------------------

    def add_stage(self, t: float, depth: float) -> list[PhaseEvent]:
        if not self._store("stage", t, np.float64(depth)):
            return []
        events = self.segmenter.add_stage(t, depth)
        if self.segmenter.state in ("pull", "keep", "release") and self.push_start is None:
            self.push_start = t
        return self._took(events)

    def add_image(self, t: float, image: np.ndarray) -> list[PhaseEvent]:
        """A tactile frame (rows, cols) in Pa."""
        forces = self.tactile.nodal_forces(np.asarray(image)[None])[0]
        return self.add_force(t, forces)

    def add_force(self, t: float, forces: np.ndarray) -> list[PhaseEvent]:
        """Bottom nodal forces (N) of one tactile frame."""
        if not self._store("force", t, np.asarray(forces, float)):
            return []
        return self._took(self.segmenter.add_force(t, float(np.sum(forces))))

    def add_markers(self, t: float, positions: np.ndarray) -> list[PhaseEvent]:
        positions = np.asarray(positions, float)
        if positions.shape != self.mesh.nodes.shape:
            raise RecordError(f"markers: {positions.shape[0]} markers, parameters say {self.mesh.nodes.shape[0]}")
        if not self._store("markers", t, positions):
            return []
        return self._took(self.segmenter.add_markers(t, positions))

    def _store(self, stream: str, t: float, value: np.ndarray) -> bool:
        if not (np.isfinite(t) and np.all(np.isfinite(value))) or not self.streams[stream].add(t, value):
            self.rejected[stream] += 1
            return False
        self._trim()
        return True

    def _trim(self) -> None:
        # The stage stream decides where a push starts: samples of the other streams
        # are kept until it has passed them, so that which samples a job sees never
        # depends on how the streams interleave (one may run far ahead of another).
        latest = self.streams["stage"].last
        margin = self.config.pre_contact + 1.0
        for s in self.streams.values():
            if len(s.t) > self.MAX_SAMPLES:       # the stage stream stopped: bounded all the same
                s.trim_before(s.t[len(s.t) - self.MAX_SAMPLES])
        if not np.isfinite(latest):
            return
        if self.push_start is None:
            keep_from = latest - margin
        else:
            keep_from = self.push_start - self.config.pre_contact
            if latest - keep_from > self.config.max_push_time:
                # Bounded memory: a push this long is given up (reported by the caller).
                self.segmenter = PhaseSegmenter(self.segmenter.config)
                self.push_start, self.pending = None, []
                self.dropped_pushes += 1
                keep_from = latest - margin
        for s in self.streams.values():
            if s.t and s.t[0] < keep_from:
                s.trim_before(keep_from)

    def _took(self, events: list[PhaseEvent]) -> list[PhaseEvent]:
        for e in events:
            if e.name != "contact":
                self.profiles[(e.experiment, e.name)] = self.segmenter.profile
                self.pending.append(e)
        return events

    # -- jobs ------------------------------------------------------------------------

    def ready_jobs(self, silent: Iterable[str] = ()) -> list[Job]:
        """Completed phases whose every stream has passed their end.

        Args:
            silent: streams that stopped arriving (the node judges this on its wall
                clock; offline, every stream at the end of the bag): they no longer
                hold a phase back, and the job says it went without them.
        """
        jobs = []
        silent = set(silent)
        while self.pending:
            e = self.pending[0]
            behind = {n for n, s in self.streams.items() if s.last < e.t_end}
            if behind - silent:
                break
            self.pending.pop(0)
            jobs.append(Job(e, self._record(e), tuple(sorted(behind))))
            if e.name == "release":
                self.push_start = None
        return jobs

    def _record(self, e: PhaseEvent) -> Record | None:
        profile = self.profiles.pop((e.experiment, e.name))
        if e.name == "pull":
            profile = replace(profile, keep_time=1e9, release_time=0.0)
        t0 = profile.t_pull_start - self.config.pre_contact
        parts = {n: s.window(t0, e.t_end) for n, s in self.streams.items()}
        try:
            return Record(mesh=self.mesh, stage_t=parts["stage"][0], stage_depth=parts["stage"][1],
                          force_t=parts["force"][0], force=parts["force"][1].reshape(-1, self.mesh.cols),
                          marker_t=parts["markers"][0],
                          markers=parts["markers"][1].reshape(-1, *self.mesh.nodes.shape),
                          source=f"experiment {e.experiment} {e.name}", stage_profile=profile,
                          dead_band=self.tactile.dead_band)
        except RecordError:
            return None

    def run_job(self, job: Job) -> Iterator[Update]:
        """The updates of a completed phase, each as soon as it is computed: the closed
        form (milliseconds), then the fit of the data so far (a tenth of a second or more).

        Raises:
            RecordError: the phase cannot be identified (too short, missing data, a
                solution outside the model); the message says why.
        """
        update, closed = self.identify.closed_form(job)
        if update is not None:
            yield update
        elif not self.config.refine:
            raise closed
        if self.config.refine:
            yield self.fit(job, closed)

    def fit(self, job: Job, closed: Estimate | RecordError,
            run: Callable[[Job, Estimate, str], tuple[Update, Estimate]] | None = None) -> Update:
        """The whole-record fit of a job, started from its closed form or, where that has
        no solution, from this push's previous fit.

        Args:
            closed: the job's closed-form estimate, or why it has none.
            run: does the fit (``PhaseIdentifier.fit`` or a call of it in another process).

        Raises:
            RecordError: no closed form and no previous fit to start from.
        """
        e = job.event
        note = ""
        if isinstance(closed, RecordError):
            previous = self._fits.get(e.experiment)
            if previous is None:
                raise closed
            closed, note = previous, f"closed form failed ({closed}); fit started from the previous update"
        update, fit = (run or self.identify.fit)(job, closed, note)
        self._fits = {e.experiment: fit}
        return update

    def last_fit(self, experiment: int) -> Estimate | None:
        """The latest whole-record fit of ``experiment`` (None: none yet, or another push since)."""
        return self._fits.get(experiment)

    def predict(self, update: Update, t: np.ndarray, profile: StageProfile | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """The model of ``update`` at stamps ``t``: total bottom force (N) and marker
        positions (T, N, 2) in m, for the current push's profile as known now."""
        profile = profile or self.segmenter.profile
        p = {n: v for n, v in zip(update.names, update.values)}
        if profile is None or not all(np.isfinite(p[n]) for n in BASE_PARAMETERS):
            raise ValueError("no determined estimate to predict with")
        model = Model(three_element(p["E"], p["c1"], p["c2"]))
        t = np.asarray(t, float)
        pred = self.identify.forward.predict(model, p["gamma"], profile, t, t, tabulated=True)   # no solve in intake
        return pred.force.sum(axis=1), self.mesh.nodes[None] + pred.displacement


def estimate_stream(estimator: OnlineEstimator, messages: Iterable[tuple[str, float, np.ndarray]],
                    diagnoses: list[OnlineDiagnosis] | None = None,
                    ) -> tuple[list[PhaseEvent], list[Update], list[str]]:
    """Feed ``(stream, t, data)`` samples in order, run each job as it becomes ready.

    The offline path of the node: same core, same order of work. Returns the phases,
    the updates and the errors (one line each); with a ``diagnoses`` list (and
    ``estimator.diagnose``), each release's verdict is appended to it, as the node
    publishes it.
    """
    add = {"stage": estimator.add_stage, "force": estimator.add_force, "image": estimator.add_image,
           "markers": estimator.add_markers}
    phases: list[PhaseEvent] = []
    updates: list[Update] = []
    errors: list[str] = []
    def run(jobs: list[Job]) -> None:
        for job in jobs:
            try:
                updates.extend(estimator.run_job(job))
                fit = estimator.last_fit(job.event.experiment)
                if (diagnoses is not None and job.event.name == "release" and estimator.config.diagnose
                        and fit is not None):
                    diagnoses.append(estimator.identify.diagnose(job, fit))
            except (RecordError, ValueError, np.linalg.LinAlgError) as exc:
                errors.append(str(exc))

    for stream, t, data in messages:
        phases += add[stream](t, data)
        run(estimator.ready_jobs())
    run(estimator.ready_jobs(silent=estimator.streams))   # the end of the data: nothing more will come
    return phases, updates, errors


def estimate_bag(path: str, params: dict | None = None, diagnoses: list[OnlineDiagnosis] | None = None
                 ) -> tuple[list[PhaseEvent], list[Update], list[str]]:
    """The estimator node's work on a bag, offline: same core, same samples, same order
    of work (what a replay over DDS into the node must reproduce); ``diagnoses`` as in
    ``estimate_stream``."""
    from rheo_ros.io.bag import bag_samples, read_params

    params = params or read_params(path)
    if params is None:
        raise RecordError(f"{path}: no parameters in the bag's metadata; give --params-file")
    setup = Setup(params)
    estimator = OnlineEstimator(setup, setup.segmenter_config(), setup.estimator_config())
    return estimate_stream(estimator, bag_samples(path), diagnoses)
