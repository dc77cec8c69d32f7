"""The pipeline driven phase by phase: E, c1, c2 (and gamma) updated as each phase of a
push completes, and the push's diagnosis after release.

``OnlineEstimator`` takes the three measurement streams sample by sample (header
stamps), segments them (``PhaseSegmenter``) and, once every stream has passed a
phase's end, turns that phase into a ``Job``: a ``Record`` of the push so far. Running
a job (``PhaseIdentifier``, pure numpy/scipy, safe in a worker process) gives the
updates, each from the shared pipeline steps (``rheo_ros.identification.pipeline``):
the phase's closed form, then the whole-record fit of the data so far; after release
(``estimator.diagnose``) the model-discovery loop on the push (``rheo_ros.diagnosis``).
``rheo analyze`` drives the same object over a whole bag, so the node publishes for a
bag what the analysis reports.

While a release goes on, an interim release job comes every ``release_interval`` s of
data. The release closes when the markers settle, when the next push starts, at
``segmenter.max_release``, or when the data stop (``finish``: offline at the end of the
bag, in the node when every topic has been silent for ``estimator.stale_after``); a
release closed by the data stopping is final all the same, with a warning.

Every update says which parameters the data do not determine yet (NaN value, with
the reason and the experiment that would determine it). Which samples a job uses is
decided by header stamps alone, so a bag replayed over DDS gives the numbers of the
same bag read offline. Memory is bounded: only the current push and a short window
before it are kept.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from rheo_ros.config.setup import Setup
from rheo_ros.config.tuning import EstimatorConfig, SegmenterConfig
from rheo_ros.diagnosis.decision import Verdict, at_bound
from rheo_ros.diagnosis.discover import discover
from rheo_ros.diagnosis.evidence import judged_keep, keep_too_short
from rheo_ros.diagnosis.fits import ModelFit, base_model
from rheo_ros.experiment import PUSH_PHASES, StageProfile, check_object_hint
from rheo_ros.fe.mesh import Mesh
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import BASE_PARAMETERS, Estimate
from rheo_ros.identification.noise import sensor_noise
from rheo_ros.identification.pipeline import (
    SEARCHED,
    ClosedForm,
    closed_form,
    fit_from_starts,
    fit_starts,
    force_error,
    interim_start,
    met_at_rest,
    relaxation_unseen,
    searched_starts,
    undetermined,
    without_undetermined,
)
from rheo_ros.identification.pooling import Change, Pool, pool_experiments, pool_of
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.models.response import StateSpace
from rheo_ros.online.segmenter import PhaseEvent, PhaseSegmenter
from rheo_ros.record import Record, RecordError
from rheo_ros.sensors import SensorReading


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
                                    # closed form when the estimator does not fit)
    interim: bool = False           # a release still going on (its message says so too)
    # The sensor model its record was read with (``Record.sensor_json``, /diagnostics), on
    # the fit lane's updates (or the closed forms' where the node does not fit): a new
    # noise's dead-band excess costs tens of ms, which the fit computes anyway and the
    # closed form's latency cannot spare.
    sensor: dict | None = None

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
    fitted in order (the base first) with their force RMS (N) and BIC, the form of each
    missing effect, the candidates tried on the base with their BIC change, and the last model's parameters."""

    experiment: int
    stamp: float
    adequate: bool
    missing_effects: tuple[str, ...]
    undecided: tuple[str, ...]
    models: tuple[str, ...]
    forms: tuple[str, ...]
    rmse_force: np.ndarray
    bic: np.ndarray
    candidates: tuple[str, ...]
    delta_bic: np.ndarray
    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    evidence: str
    final: Estimate | None = None   # the last model's fit (pooled with the other pushes')
    explained: bool = True          # Verdict.explained: the last model fits and is not degenerate
    at_bound: tuple[str, ...] = ()  # the last model's parameters at a bound (no measurement: std inf)
    leftover: tuple[str, ...] = ()  # where the last model, with effects added, still misfits
    diagnosed: bool = True          # False: the diagnosis could not run (``not_diagnosed``; evidence says why)

    @property
    def verdict(self) -> str:
        """adequate (the base model), missing_effect (found, and with it adequate),
        undecided (the data ask for an effect but cannot pin it down or tell two apart) or
        unexplained (the model misfits, or the effects added leave it degenerate: no
        effect in the catalogue explains it); not_diagnosed when it could not run."""
        if not self.diagnosed:
            return "not_diagnosed"
        if self.adequate and self.explained:
            return "missing_effect" if self.missing_effects else "adequate"
        return "undecided" if self.undecided else "unexplained"

    @property
    def undetermined(self) -> tuple[str, ...]:
        """The base parameters of the last model the data do not pin down."""
        return tuple(n for n, s in zip(self.names, self.std) if n in BASE_PARAMETERS and not np.isfinite(s))

    @classmethod
    def not_run(cls, experiment: int, stamp: float, why: str) -> OnlineDiagnosis:
        """A push's diagnosis that could not run (it failed, or a newer push's came first):
        published all the same, so that whoever waits for it (the identify action) hears why."""
        empty = np.zeros(0)
        return cls(experiment=experiment, stamp=stamp, adequate=False, missing_effects=(), undecided=(), models=(),
                   forms=(), rmse_force=empty, bic=empty, candidates=(), delta_bic=empty, names=(), values=empty,
                   std=empty, evidence=f"not diagnosed: {why}", explained=False, diagnosed=False)

    @classmethod
    def of(cls, experiment: int, stamp: float, models: list[ModelFit], verdict: Verdict,
           bound: Sequence[str] = ()) -> OnlineDiagnosis:
        """``bound``: the last model's parameters at a bound (``decision.at_bound``), sent
        with an infinite std as ``rheo analyze`` reports them with none."""
        last = models[-1].estimate
        std = {**last.std, **{n: np.inf for n in bound}}
        return cls(
            experiment=experiment, stamp=stamp, adequate=bool(verdict.adequate),
            missing_effects=verdict.missing_effects, undecided=verdict.undecided,
            models=tuple(m.name for m in models),
            forms=tuple(models[-1].forms.get(e, "") for e in verdict.missing_effects),
            rmse_force=np.array([m.rmse_force for m in models]), bic=np.array([m.bic for m in models]),
            candidates=tuple(c.effect for c in verdict.candidates),
            delta_bic=np.array([c.delta_bic for c in verdict.candidates]),
            names=tuple(last.params), values=np.array(list(last.params.values())),
            std=np.array([std.get(n, np.inf) for n in last.params]),
            evidence=verdict.evidence, final=last, explained=bool(verdict.explained),
            at_bound=tuple(bound), leftover=verdict.leftover,
        )


@dataclass(frozen=True)
class PoolUpdate:
    """The pool a push joined or started (``/rheo/pool``): its joint estimate, and the
    change when the push starts it (None: it joined)."""

    experiment: int
    stamp: float
    pool: Pool
    change: Change | None
    message: str


def trusted(verdict: str, undetermined: Sequence[str], missing_effects: Sequence[str] = (),
            undecided: Sequence[str] = ()) -> tuple[bool, str]:
    """Whether a robot may act on a push's estimate, and why (or why not): E, c1 and c2
    determined, and a model that fits (``verdict`` adequate or missing_effect; not_diagnosed
    where the estimator does not diagnose, the parameters alone then decide)."""
    open_ = [n for n in ("E", "c1", "c2") if n in undetermined]
    if open_:
        return False, f"the data do not determine {', '.join(open_)}"
    if verdict == "undecided":
        return False, f"the data ask for {' or '.join(undecided)} but cannot pin it down"
    if verdict == "unexplained":
        return False, "the model misfits and no effect in the catalogue explains it"
    if verdict == "missing_effect":
        return True, f"identified with {', '.join(missing_effects)}"
    return True, "identified" if verdict == "adequate" else "identified (not diagnosed: the parameters decide)"


@dataclass(frozen=True)
class Job:
    """A completed phase with the data it is identified from.

    Attributes:
        event: the phase.
        record: the push's data up to the phase's end (None: too few samples).
        stale: streams that had stopped when the job was made (it went without them).
        interim: a release still going on (its update is not final).
        cut_short: why a release was closed before the markers settled ("" when they did).
        object: what the robot said of the push's object (``/rheo/object``): new, same, or
            "" (the data decide).
    """

    event: PhaseEvent
    record: Record | None
    stale: tuple[str, ...] = ()
    interim: bool = False
    cut_short: str = ""
    object: str = ""

    @property
    def final(self) -> bool:
        return self.event.name == "release" and not self.interim

    def warning(self) -> str:
        """What a cut-short release leaves undetermined ("" for one that settled)."""
        if not self.cut_short:
            return ""
        e = self.event
        return (f"WARNING: the release was cut short {e.t_end - e.t_start:.3g} s after the let-go "
                f"({self.cut_short}) while the specimen still recovered: the settled displacement was not "
                "reached, so the permanent set (and with it c2) rests on the fit's extrapolation of the "
                "recovery, and an effect that shows late in the release (adhesion fading, drift) may go unseen")


def supersedes(new: Job, old: Job) -> bool:
    """Whether the whole-record fit of ``new`` makes that of ``old`` pointless: a later
    stretch of the same push (its record holds every sample the earlier one's does)."""
    n, o = new.event, old.event
    return n.experiment == o.experiment and (PUSH_PHASES.index(n.name), n.t_end) > (PUSH_PHASES.index(o.name), o.t_end)


class _Stream:
    """Samples of one topic in stamp order, trimmed from the front. Held in arrays that
    grow by doubling (a sample's stamp and value, not a Python object each): a push of
    an hour at 500 Hz is 48 bytes a tactile frame, where a list of arrays took ~190, and a
    job's window is a slice, not an array built from a list."""

    GROWTH_MIN = 1024   # samples: the first buffer's size

    def __init__(self) -> None:
        self._t = np.empty(0)
        self._data = np.empty(0)
        self._lo = self._hi = 0   # the samples held: [_lo, _hi) of the buffers
        # Their first and last stamps as Python floats: read at every sample (``_trim``).
        self.first, self.last = np.inf, -np.inf

    def __len__(self) -> int:
        return self._hi - self._lo

    @property
    def t(self) -> np.ndarray:
        """The stamps held (a view)."""
        return self._t[self._lo:self._hi]

    def add(self, t: float, value: np.ndarray) -> bool:
        if t <= self.last:
            return False
        hi = self._hi
        if hi == self._t.size:
            self._grow(value.shape)
            hi = self._hi
        elif value.shape != self._shape:   # never broadcast into the buffer
            raise ValueError(f"a sample of shape {value.shape} in a stream of {self._shape}")
        self._t[hi] = t
        self._data[hi] = value
        self._hi = hi + 1
        if hi == self._lo:
            self.first = t
        self.last = t
        return True

    def _grow(self, shape: tuple[int, ...]) -> None:
        # Room for as many again as held (what was trimmed off the front is dropped here).
        n = len(self)
        t, data = np.empty(max(2 * n, self.GROWTH_MIN)), np.empty((max(2 * n, self.GROWTH_MIN), *shape))
        if n:
            t[:n], data[:n] = self._t[self._lo:self._hi], self._data[self._lo:self._hi]
        self._t, self._data, self._lo, self._hi, self._shape = t, data, 0, n, shape

    def trim_before(self, t0: float) -> None:
        self._lo += int(np.searchsorted(self.t, t0, side="left"))
        self.first = float(self._t[self._lo]) if self._hi > self._lo else np.inf
        if self._hi == self._lo:
            self.last = -np.inf

    def window(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        t = self.t
        i, j = np.searchsorted(t, t0, side="left"), np.searchsorted(t, t1, side="right")
        return t[i:j].copy(), self._data[self._lo + i:self._lo + j].copy()


class PhaseIdentifier:
    """A completed phase's updates from the shared pipeline steps: the closed form, the
    whole-record fit, the diagnosis.

    Holds no stream state (what it needs travels in the ``Job``), so that it can run in
    a worker process beside the node.
    """

    def __init__(self, mesh: Mesh, config: EstimatorConfig, forward: QuasiStaticFE | None = None) -> None:
        self.mesh, self.config = mesh, config
        self.forward = forward or QuasiStaticFE(mesh)

    def prepare(self) -> None:
        """Build what the first closed form would otherwise wait for: the forward model's
        implied-force table (~0.4 s) and a model's state space (scipy.signal's import,
        ~0.7 s, which the package leaves to the processes that solve a model)."""
        self.forward.implied_force(np.zeros(self.mesh.nodes.shape), 0.3)
        StateSpace.of(three_element(1.0, 1.0, 1.0))

    @staticmethod
    def _record(job: Job) -> Record:
        if job.record is None:
            e = job.event
            raise RecordError(f"experiment {e.experiment} {e.name}: too few samples to identify")
        return job.record

    def closed_form(self, job: Job) -> tuple[Update, ClosedForm]:
        """The phase's closed form (``pipeline.closed_form``) as an update: its first
        solution, the latency the node answers in (``fit`` adds the other starts).

        Raises:
            RecordError: too few samples, or no closed form has a solution.
        """
        rec = self._record(job)
        closed = closed_form(job.event.name, rec, self.forward, solutions=1)
        # The table's shape: each update brings a new gamma, and an exact shape costs a
        # factorisation (~18 ms) in the closed form's latency; the RMS moves < 1e-5.
        p = closed.estimate.params
        predicted = self.forward.predict(Model(three_element(p["E"], p["c1"], p["c2"])), p["gamma"],
                                         rec.profile(), rec.force_t, rec.marker_t[:1], tabulated=True)
        return self._update(job, closed.estimate, force_error(rec, predicted.force)[0]), closed

    def fit(self, job: Job, closed: ClosedForm | None, earlier: Estimate | None = None) -> tuple[Update, Estimate]:
        """The whole-record fit of the job's data (``pipeline.fit_from_starts``) from the
        closed form's starts (with ``earlier``, the last fit of the push before, where the
        closed form leaves a parameter open) or, where it has none, from a search over the
        relaxation times and ``earlier`` (``pipeline.searched_starts``), checked for a
        relaxation the data do not show.

        Raises:
            RecordError: no start, or the fit failed from every start.
        """
        rec = self._record(job)
        if closed is not None and job.interim:
            # Superseded within release_interval s: one start, not the final's screening.
            starts, note = [interim_start(rec, closed, self.config)], ""
        elif closed is not None:
            # The closed forms' other solutions, computed here off the closed form's latency:
            # the same starts as rheo analyze's one call.
            closed = closed_form(job.event.name, rec, self.forward, after=closed)
            starts, note = fit_starts(rec, closed, self.config, earlier), ""
        else:   # as rheo analyze: a search over the relaxation times, and the push before's fit
            starts, note = searched_starts(rec, self.forward, earlier), f"no closed form has a solution: {SEARCHED}"
        fit = fit_from_starts(rec, self.forward, starts, noise=sensor_noise(rec))
        if note:
            fit = replace(fit, message=f"{note}; {fit.message}")
        unseen, fit = relaxation_unseen(rec, fit, self.forward, starts)
        stats = fit.statistics
        p = fit.params
        predicted = self.forward.predict(Model(three_element(p["E"], p["c1"], p["c2"])), p["gamma"], rec.profile(),
                                         rec.force_t - stats.delay("tactile"), rec.marker_t[:1])
        return self._update(job, fit, force_error(rec, predicted.force)[0], unseen), fit

    def diagnose(self, job: Job, fit: Estimate) -> OnlineDiagnosis:
        """The model-discovery loop (``rheo_ros.diagnosis``) on a release job's push from
        its whole-record ``fit``: each missing effect added until the model is adequate.
        Seconds to tens of seconds: the node runs it in the fit lane, after the release's
        fit is out.

        Raises:
            RecordError: the job has no record.
        """
        rec = self._record(job)
        base, noise = base_model(rec, self.forward, fit, sensor_noise(rec))   # as rheo analyze
        # One process: the node's fit lane is a worker already.
        models, verdicts = discover(rec, self.forward, base, noise=noise, workers=1)
        verdict = Verdict.of(verdicts)
        try:   # the closed form rheo analyze judges the keep by (milliseconds; not kept from the other lane)
            short = keep_too_short(closed_form("release", rec, self.forward).estimate, rec.profile(),
                                   self.config.rate_std)
        except RecordError:
            short = ""
        verdict = replace(verdict, evidence=judged_keep(verdict.evidence, bool(verdict.adequate), short))
        if job.cut_short:
            verdict = replace(verdict, evidence=f"{job.warning()}. {verdict.evidence}")
        return OnlineDiagnosis.of(job.event.experiment, float(rec.force_t[-1]), models, verdict,
                                  at_bound(models[-1], base, rec))

    def _update(self, job: Job, est: Estimate, rmse: float, unseen: str = "") -> Update:
        rec, e = self._record(job), job.event
        names = tuple(n for n in BASE_PARAMETERS if n in est.params)
        open_ = undetermined(rec, est, self.config, unseen)
        shown = without_undetermined(est, open_)
        values, cov = np.array([shown.params[n] for n in names]), shown.covariance
        interim = "interim: the release still goes on; " if job.interim else ""
        message = "; ".join(filter(None, [job.warning(), interim + est.message]))
        last_lane = est.method == "whole_record" or not self.config.fit
        sensor = None
        if last_lane:
            try:
                sensor = rec.sensor_json()
            except (ValueError, ArithmeticError) as exc:   # a figure for /diagnostics must not cost the estimate
                message = f"{message}; the sensor model for /diagnostics failed: {exc}"
        return Update(
            experiment=e.experiment, phase=e.name, stamp=float(rec.force_t[-1]),
            model="three_element", effects=(), method=est.method, equations=est.equations, names=names,
            values=values, covariance=cov, rmse_force=rmse, samples=int(rec.force_t.size),
            undetermined=tuple(open_), reasons=tuple(open_.values()), message=message,
            final=job.final and last_lane, interim=job.interim, sensor=sensor,
        )


class OnlineEstimator:
    """Streams in, jobs out. ``add_stage`` / ``add_force`` / ``add_markers`` return the
    phases they completed; ``ready_jobs()`` the phases whose data are all in (with the
    interim releases due); ``finish()`` closes a release still open when the data stop.

    Args:
        setup: geometry and sensor layout (the parameters file).
        segmenter: online segmentation tuning.
        config: estimator tuning.
    """

    MAX_SAMPLES = 500_000   # per stream, whatever happens (an hour at 100 Hz is 360 000)
    READOUT_BLOCK = 64      # tactile frames added to the readout at once (a job flushes up to this many)

    def __init__(self, setup: Setup, segmenter: SegmenterConfig | None = None,
                 config: EstimatorConfig | None = None) -> None:
        self.setup, self.mesh = setup, setup.mesh
        self.tactile = setup.tactile
        self.readout = setup.readout()   # the tactile readings so far, for the sensor they show
        self._unread: list[tuple[float, np.ndarray]] = []   # frames not yet added to it (in blocks: cheaper)
        self.sensor: SensorReading | None = None   # as the last record's readings showed it
        self.config = config or EstimatorConfig()
        self.segmenter = PhaseSegmenter(segmenter)
        self.streams = {"stage": _Stream(), "force": _Stream(), "markers": _Stream()}
        self.pending: list[PhaseEvent] = []
        self.profiles: dict[tuple[int, str], StageProfile] = {}
        self.push_start: float | None = None
        self.rejected = {"stage": 0, "force": 0, "markers": 0}
        self._kept_from = -np.inf   # where the streams were last trimmed to (``_trim``)
        self.identify = PhaseIdentifier(self.mesh, self.config, setup.forward_model())
        self._fits: dict[int, Estimate] = {}      # the last whole-record fit of the current push
        self._final: tuple[int, Estimate] | None = None   # the last push's final fit
        self.dropped_pushes = 0                    # pushes given up for lasting over max_push_time
        self.at_rest_since = -np.inf               # pull start of the last later push met at rest (met_at_rest)
        self.hints: list[tuple[float, str]] = []    # (stamp, new | same | ""): /rheo/object, in stamp order
        self._objects: dict[int, str] = {}          # each experiment's hint, as its jobs carried it
        self._pool_finals: dict[int, Estimate] = {}   # each push's final model, for the pools
        # Releases whose interim jobs are not all out: [experiment, profile, next due, release
        # end (inf while open)]. An interim is due every release_interval s of data before the
        # release's end, however the streams interleave.
        self._interims: list[list] = []
        self._cut_short: dict[int, str] = {}

    # -- streams ---------------------------------------------------------------------

    def add_stage(self, t: float, depth: float) -> list[PhaseEvent]:
        if not self._store("stage", t, np.float64(depth)):
            return []
        events = self.segmenter.add_stage(t, depth)
        if self.segmenter.state in ("pull", "keep", "release") and self.push_start is None:
            self.push_start = t
        return self._took(events)

    def add_image(self, t: float, image: np.ndarray) -> list[PhaseEvent]:
        """A tactile frame (rows, cols) in Pa: its segment forces, and what its readings
        show of the sensor (``readout``)."""
        image = np.asarray(image)
        return self.add_force(t, self.tactile.nodal_forces(image[None])[0], image)

    def add_force(self, t: float, forces: np.ndarray, image: np.ndarray | None = None) -> list[PhaseEvent]:
        """Bottom nodal forces (N) of one tactile frame (and the frame they came from)."""
        forces = np.asarray(forces, float)
        if not self._store("force", t, forces):
            return []
        if image is not None:
            self._unread.append((t, image))
            if len(self._unread) >= self.READOUT_BLOCK:
                self._read_frames()
        return self._took(self.segmenter.add_force(t, float(forces.sum())))

    def add_markers(self, t: float, positions: np.ndarray) -> list[PhaseEvent]:
        positions = np.asarray(positions, float)
        if positions.shape != self.mesh.nodes.shape:
            raise RecordError(f"markers: {positions.shape[0]} markers, parameters say {self.mesh.nodes.shape[0]}")
        if not self._store("markers", t, positions):
            return []
        return self._took(self.segmenter.add_markers(t, positions))

    def add_object(self, t: float, kind: str) -> None:
        """What the robot says of the object the next push meets (``/rheo/object``): it
        applies to the first push whose pull starts at or after ``t``.

        Raises:
            ValueError: ``kind`` is none of new, same, "" (the data decide)."""
        bisect.insort(self.hints, (float(t), check_object_hint(kind)))
        del self.hints[:-100]   # a hint older than a hundred goals has long been applied

    def object_of(self, profile: StageProfile) -> str:
        """The hint for the push ``profile`` describes: the last one stamped after the push
        before it started and no later than its own pull's start ("" without one)."""
        return self._hint_of(profile)[1]

    def _hint_of(self, profile: StageProfile) -> tuple[float, str]:
        """``object_of`` with the hint's stamp (-inf without one)."""
        after = profile.before[-1].t_pull_start if profile.before else -np.inf
        said = [(t, k) for t, k in self.hints if after < t <= profile.t_pull_start]
        return said[-1] if said else (-np.inf, "")

    def _read_frames(self) -> None:
        # The readout's facts are counts, extremes and sets: the same in blocks as frame by frame.
        if self._unread:
            self.readout.add(np.stack([image for _, image in self._unread]), np.array([t for t, _ in self._unread]))
            self._unread = []

    def _store(self, stream: str, t: float, value: np.ndarray) -> bool:
        finite = math.isfinite(value) if value.ndim == 0 else bool(np.isfinite(value).all())
        into = self.streams[stream]
        if not (math.isfinite(t) and finite) or not into.add(t, value):
            self.rejected[stream] += 1
            return False
        self._trim(into)
        return True

    def _trim(self, grown: _Stream) -> None:
        # The stage stream decides where a push starts: samples of the other streams
        # are kept until it has passed them, so that which samples a job sees never
        # depends on how the streams interleave (one may run far ahead of another).
        # After each call every stream starts at or after ``keep_from``: while it stays
        # where it was, only the stream that just grew can hold a sample before it.
        if len(grown) > self.MAX_SAMPLES:       # the stage stream stopped: bounded all the same
            grown.trim_before(grown.t[len(grown) - self.MAX_SAMPLES])
        stage = self.streams["stage"]
        if not len(stage):
            return
        latest = stage.last
        margin = self.config.pre_contact + 1.0
        if self.push_start is None:
            keep_from = latest - margin
        else:
            keep_from = self.push_start - self.config.pre_contact
            if latest - keep_from > self.config.max_push_time:
                # Bounded memory: a push this long is given up (reported by the caller).
                self.segmenter = PhaseSegmenter(self.segmenter.config)
                self.push_start, self.pending, self._interims = None, [], []
                self._final, self.at_rest_since = None, -np.inf   # numbering starts again at 1
                self._objects, self._pool_finals = {}, {}
                self.dropped_pushes += 1
                keep_from = latest - margin
        if keep_from != self._kept_from:
            self._kept_from = keep_from
            for s in self.streams.values():
                if s.first < keep_from:
                    s.trim_before(keep_from)
        elif grown.first < keep_from:
            grown.trim_before(keep_from)

    def _took(self, events: list[PhaseEvent]) -> list[PhaseEvent]:
        for e in events:
            if e.name == "contact":
                continue
            self.profiles[(e.experiment, e.name)] = self.segmenter.profile
            self.pending.append(e)
            if e.name == "keep":
                self._interims.append([e.experiment, self.segmenter.profile, e.t_end + self._interval, np.inf])
            elif e.name == "release":
                for entry in self._interims:
                    if entry[0] == e.experiment:
                        entry[3] = e.t_end
        return events

    @property
    def _interval(self) -> float:
        return self.config.release_interval if self.config.release_interval > 0 else np.inf

    # -- jobs ------------------------------------------------------------------------

    @property
    def release_open(self) -> bool:
        """A push has let go and its release has not closed yet."""
        return self.segmenter.state == "release"

    def finish(self, why: str = "the data stopped") -> list[PhaseEvent]:
        """The data stopped: close a release still open at its last marker frame (its
        job says it was cut short, and why). Call ``ready_jobs`` with every stream
        silent next."""
        if not self.release_open:
            return []
        events = self.segmenter.close_release(why)
        if self.segmenter.release_reason == why:   # not settled on frames the stage never passed
            for e in events:
                self._cut_short[e.experiment] = why
        return self._took(events)

    def cut_short(self, event: PhaseEvent) -> str:
        """Why ``event`` (a release ``finish`` returned) was closed before the mesh
        settled; empty where the frames showed it settled."""
        return self._cut_short.get(event.experiment, "") if event.name == "release" else ""

    def replay_cut(self, t_found: float, t_end: float, why: str) -> list[PhaseEvent]:
        """A node's recorded ``finish`` (``io.bag.release_cuts``), replayed on a recording
        once its samples up to ``t_found`` are in: the release open then, if it began by
        ``t_end``, closes as the node closed it. The caller then calls ``ready_jobs``
        with every stream silent, as the node did."""
        if not self.release_open or self.segmenter.release_began > t_end:
            return []
        return self.finish(why)

    def ready_jobs(self, silent: Iterable[str] = ()) -> list[Job]:
        """Completed phases whose every stream has passed their end, and the interim
        release jobs due (every ``release_interval`` s of data into a release).

        Args:
            silent: streams that stopped arriving (the node judges this on its wall
                clock; offline, every stream at the end of the bag): they no longer
                hold a phase back, and the job says it went without them.
        """
        if not (self.pending or self._interims or silent):
            return []   # called after every sample: nothing due is the common case
        jobs = []
        silent = set(silent)
        if "stage" in silent and self.release_open:
            # Markers wait for the stage stream to pass them before a release settles; a
            # stage stream that stopped no longer holds them back.
            self._took(self.segmenter.judge_ahead_of_stage())
        while True:
            self._interims = [r for r in self._interims if r[2] < r[3]]
            interim = self._interims[0] if self._interims else None
            if self.pending and (interim is None or self.pending[0].t_end <= interim[2]):
                e = self.pending[0]
            elif interim is not None:
                e = PhaseEvent(interim[0], "release", interim[1].t_keep_end, interim[2], interim[2], 0)
            else:
                break
            behind = {n for n, s in self.streams.items() if s.last < e.t_end}
            if behind - silent:
                break
            if self.pending and e is self.pending[0]:
                self.pending.pop(0)
                cut = self._cut_short.pop(e.experiment, "") if e.name == "release" else ""
                profile = self.profiles.pop((e.experiment, e.name))
                kind = self._objects[e.experiment] = self.object_of(profile)
                jobs.append(Job(e, self._record(e, profile, kind), tuple(sorted(behind)), cut_short=cut, object=kind))
                if e.name == "release":
                    self.push_start = None
            else:
                interim[2] += self._interval
                kind = self.object_of(interim[1])
                jobs.append(Job(e, self._record(e, interim[1], kind), tuple(sorted(behind)), interim=True,
                                object=kind))
        return jobs

    def _record(self, e: PhaseEvent, profile: StageProfile, kind: str = "") -> Record | None:
        if e.name == "pull":
            profile = replace(profile, keep_time=1e9, release_time=0.0)
        elif e.name == "release":
            profile = replace(profile, release_time=max(e.t_end - profile.t_keep_end, 0.0))
        t0 = profile.t_pull_start - self.config.pre_contact
        if kind == "new":
            # Data before the robot said "new" may show the object it took away: the
            # markers' starting positions come from the new one only, where it has frames.
            t_hint = self._hint_of(profile)[0]
            markers_t = self.streams["markers"].window(t_hint, profile.t_pull_start)[0]
            if np.any(markers_t < profile.t_pull_start):
                t0 = max(t0, t_hint)
        parts = {n: s.window(t0, e.t_end) for n, s in self.streams.items()}
        markers = parts["markers"][1].reshape(-1, *self.mesh.nodes.shape)
        self._read_frames()
        self.sensor, force = self.setup.sensor(self.readout, parts["force"][1].reshape(-1, self.mesh.cols),
                                              parts["force"][0], markers)
        if kind == "new":   # the robot says so: another object, at rest
            self.at_rest_since = max(self.at_rest_since, profile.t_pull_start)
        # Pushes before the last one found at rest are another object's (or fully undone).
        profile = replace(profile, before=tuple(h for h in profile.before if h.t_pull_start >= self.at_rest_since))
        try:
            record = Record(mesh=self.mesh, stage_t=parts["stage"][0], stage_depth=parts["stage"][1],
                            force_t=parts["force"][0], force=force, marker_t=parts["markers"][0], markers=markers,
                            source=f"experiment {e.experiment} {e.name}", stage_profile=profile, sensor=self.sensor)
        except RecordError:
            return None
        if not kind and e.name != "pull" and met_at_rest(record):
            # The data decide: the stage met a specimen at rest, so the pushes before are
            # not its history (another object, or one that recovered fully). From the keep
            # on (the hold shows where the stage met it), this push and the next start there.
            self.at_rest_since = max(self.at_rest_since, profile.t_pull_start)
            record = replace(record, stage_profile=replace(profile, before=()))
        return record

    def run_job(self, job: Job) -> Iterator[Update]:
        """The updates of a completed phase, each as soon as it is computed: the closed
        form (milliseconds), then the fit of the data so far (a tenth of a second or more).

        Raises:
            RecordError: the phase cannot be identified (too short, missing data, no
                solution and nothing to start a fit from); the message says why.
        """
        try:
            update, closed = self.identify.closed_form(job)
        except RecordError:
            if not self.config.fit:
                raise
            closed = None
        else:
            yield update
        if self.config.fit:
            yield self.fit(job, closed)

    def fit(self, job: Job, closed: ClosedForm | None,
            run: Callable[[Job, ClosedForm | None, Estimate | None], tuple[Update, Estimate]]
            | None = None) -> Update:
        """The whole-record fit of a job, started from its closed form or, where that has
        no solution, from a search over the relaxation times; the final fit of the push
        before helps where the closed form leaves a parameter open or has none
        (``PhaseIdentifier.fit``), as ``rheo analyze`` has it.

        Args:
            closed: the job's closed form (None: it has none).
            run: does the fit (``PhaseIdentifier.fit`` or a call of it in another process).

        Raises:
            RecordError: no start, or the fit failed from every start.
        """
        e = job.event
        earlier = self._final[1] if self._final and self._final[0] < e.experiment else None
        update, fit = (run or self.identify.fit)(job, closed, earlier)
        self._fits = {e.experiment: fit}
        if job.final:
            self._final = (e.experiment, fit)   # as rheo analyze has it: the push's final fit
        return update

    def pool(self, experiment: int, stamp: float, final: Estimate) -> PoolUpdate:
        """Pool a push's final model (the diagnosis' last model, or the base fit where the
        push is not diagnosed) with the earlier pushes' (``pool_experiments``, as ``rheo
        analyze`` pools a bag's): the pool it joined or started."""
        self._pool_finals[experiment] = final
        numbers = sorted(self._pool_finals)
        pools, changes = pool_experiments([self._pool_finals[k] for k in numbers], numbers=numbers,
                                          new_objects={k for k in numbers if self._objects.get(k) == "new"})
        pool = pool_of(pools, experiment)
        change = next((c for c in changes if c.experiment == experiment), None)
        members = ", ".join(map(str, pool.experiments))
        message = (change.describe() + "; a new pool" if change else
                   f"experiments {members} pooled (chi-square {pool.chi2:.3g} on {pool.dof} dof)")
        return PoolUpdate(experiment, stamp, pool, change, message)

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
                    diagnoses: list[OnlineDiagnosis] | None = None, pools: list[PoolUpdate] | None = None,
                    ) -> tuple[list[PhaseEvent], list[Update], list[str]]:
    """Feed ``(stream, t, data)`` samples in order, run each job as it becomes ready,
    and at the end of the data close a release still open (``finish``).

    The offline path of the node: same core, same order of work. Returns the phases,
    the updates and the errors (one line each); with a ``diagnoses`` list (and
    ``estimator.diagnose``), each release's verdict is appended to it, as the node
    publishes it; with a ``pools`` list, each push's pool (from its diagnosis' last
    model where ``diagnoses`` is given, else from its final fit), as the node publishes
    it on ``/rheo/pool``.
    """
    add = {"stage": estimator.add_stage, "force": estimator.add_force, "image": estimator.add_image,
           "markers": estimator.add_markers, "object": lambda t, kind: estimator.add_object(t, kind) or []}
    phases: list[PhaseEvent] = []
    updates: list[Update] = []
    errors: list[str] = []

    def run(jobs: list[Job]) -> None:
        for job in jobs:
            try:
                updates.extend(estimator.run_job(job))
                fit = estimator.last_fit(job.event.experiment)
                if not job.final or fit is None:
                    continue
                final = fit
                if diagnoses is not None and estimator.config.diagnose:
                    try:
                        diagnoses.append(estimator.identify.diagnose(job, fit))
                        final = diagnoses[-1].final or fit
                    except (RecordError, ValueError, np.linalg.LinAlgError) as exc:   # as the node says it
                        errors.append(str(exc))
                        diagnoses.append(OnlineDiagnosis.not_run(job.event.experiment, float(job.record.force_t[-1]),
                                                                 f"the diagnosis failed: {exc}"))
                if pools is not None:
                    pools.append(estimator.pool(job.event.experiment, float(job.record.force_t[-1]), final))
            except (RecordError, ValueError, np.linalg.LinAlgError) as exc:
                errors.append(str(exc))

    for stream, t, data in messages:
        phases += add[stream](t, data)
        run(estimator.ready_jobs())
    phases += estimator.finish()
    run(estimator.ready_jobs(silent=estimator.streams))   # the end of the data: nothing more will come
    return phases, updates, errors
