"""A bag in, the pipeline's answers out: ``analyze`` (``rheo analyze``: identify, compare,
diagnose, add what is missing, refit) and ``estimate_bag`` (the estimator node's work
on the bag, offline).

Both drive the one pipeline (``rheo_ros.online.estimator.OnlineEstimator`` over the
bag's samples, then the steps of ``rheo_ros.identification.pipeline``): the push
``analyze`` reports is the release job the node identifies, its base model the node's
final estimate.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from rheo_ros.config.setup import Setup, check_params, load_params
from rheo_ros.diagnosis.analysis import Analysis
from rheo_ros.diagnosis.decision import Diagnosis
from rheo_ros.diagnosis.discover import Progress, default_workers, discover
from rheo_ros.diagnosis.fits import add_effect, base_model, polish
from rheo_ros.identification.estimate import BASE_PARAMETERS, Estimate
from rheo_ros.identification.noise import sensor_noise, spikes_note
from rheo_ros.identification.pipeline import (
    SEARCHED,
    NoClosedForm,
    closed_form,
    fit_from_starts,
    fit_starts,
    relaxation_unseen,
    require_readings,
    searched_starts,
    undetermined,
    without_undetermined,
)
from rheo_ros.io.bag import bag_samples, read_params, release_cuts, require_bag
from rheo_ros.io.checks import SampleCheck
from rheo_ros.io.errors import BagError
from rheo_ros.io.files import write_json_atomic
from rheo_ros.io.messages import MARKERS_TOPIC, STAGE_TOPIC, TACTILE_TOPIC
from rheo_ros.io.prefetch import Prefetched
from rheo_ros.models.effects import effect_class
from rheo_ros.online.estimator import Job, OnlineDiagnosis, OnlineEstimator, PoolUpdate, Update, estimate_stream
from rheo_ros.online.segmenter import PhaseEvent
from rheo_ros.record import RecordError, contact_depth

TOPIC_OF = {"stage": STAGE_TOPIC, "image": TACTILE_TOPIC, "markers": MARKERS_TOPIC}
CORE_TOPIC = {"stage": STAGE_TOPIC, "force": TACTILE_TOPIC, "markers": MARKERS_TOPIC}   # the core's stream names


def bag_params(bag: str | Path, params_file: str | Path | None = None) -> dict[str, Any]:
    """The parameters to analyse ``bag`` with: ``params_file`` where given, else the bag's own.

    Raises:
        BagError: not a bag. RecordError: a bag without parameters and no file given.
        ParamsError: a bad parameters file.
    """
    path = require_bag(bag)
    if params_file:
        return check_params(load_params(params_file), str(params_file))
    params = read_params(path)
    if params is None:
        raise RecordError(f"{path}: no parameters in the bag's metadata; give --params-file")
    return check_params(params, f"{path}: parameters")


# A topic silent for longer than this many of its median intervals, and at least GAP_MIN
# s, has a hole (a chunk lost, rheo bag repair; a sensor that stopped): the fit uses the
# samples around it, and what shows only inside it goes unseen, so the analysis says so.
GAP_INTERVALS = 20
GAP_MIN = 1.0


@dataclass(frozen=True)
class SampleNote:
    """A warning on a bag's samples: ``span`` (s) where it happened (a hole), None for the
    whole bag (samples dropped out of order)."""

    text: str
    span: tuple[float, float] | None = None

    def touches(self, t0: float, t1: float) -> bool:
        """Whether it concerns a push whose data run from ``t0`` to ``t1`` (s)."""
        return self.span is None or (self.span[0] < t1 and self.span[1] > t0)


def checked_samples(bag: str | Path, setup: Setup,
                    warnings: list[SampleNote] | None = None) -> Iterator[tuple[str, float, Any]]:
    """The bag's measurement samples (``bag_samples``), each through the estimator node's
    checks (``io.checks.SampleCheck``: shapes, clock jumps, units, NaN), and at the end a
    topic with no message, or whose header stamps do not advance, refused; a hole in a
    topic's stamps (``GAP_INTERVALS``) appended to ``warnings``.

    Raises:
        BagError: names the file, the topic and what is wrong.
    """
    counts = dict.fromkeys(TOPIC_OF, 0)   # the measurement topics must all be there (/rheo/object may not)
    # Samples stamped no later than their topic's latest: the core drops them, as the node
    # drops a reorder; half a topic's samples or more so stamped is a clock that does not
    # run (stamps all 0, every message twice), not a reorder.
    stale, latest = dict.fromkeys(TOPIC_OF, 0), dict.fromkeys(TOPIC_OF, -float("inf"))
    check = SampleCheck(setup)
    stamps: dict[str, list[float]] = {stream: [] for stream in TOPIC_OF}
    for stream, t, data in bag_samples(bag):
        if stream in TOPIC_OF:
            problem = check.problem(TOPIC_OF[stream], t, data)
            if problem:
                raise BagError(f"{bag}: {TOPIC_OF[stream]}: {problem}")
            stale[stream] += t <= latest[stream]
            latest[stream] = max(latest[stream], t)
            stamps[stream].append(t)
        counts[stream] = counts.get(stream, 0) + 1
        yield stream, t, data
    for stream in TOPIC_OF:
        if not counts[stream]:
            raise BagError(f"{bag}: {TOPIC_OF[stream]}: no messages")
        if counts[stream] > 1 and 2 * stale[stream] >= counts[stream]:
            raise BagError(f"{bag}: {TOPIC_OF[stream]}: {stale[stream]} of {counts[stream]} header stamps are not "
                           f"after the one before (the latest {latest[stream]:.3f} s): the stamps do not advance "
                           "(duplicated messages, or a header stamp not filled in?)")
    if warnings is not None:
        warnings += [SampleNote(f"{TOPIC_OF[stream]}: {gap.text}", gap.span)
                     for stream, t in stamps.items() for gap in stamp_gaps(t)]


def stamp_gaps(stamps: Sequence[float]) -> list[SampleNote]:
    """Each hole in a topic's header stamps (longer than ``GAP_INTERVALS`` of its median
    interval and ``GAP_MIN`` s), in words and with its span."""
    t = np.sort(np.asarray(stamps, float))
    steps = np.diff(t)
    if steps.size < 2:
        return []
    limit = max(GAP_MIN, GAP_INTERVALS * float(np.median(steps)))
    return [SampleNote(f"no message for {steps[k]:.3g} s ({t[k]:.3f}-{t[k + 1]:.3f} s, a lost chunk or a sensor "
                       "that stopped): the analysis fits the samples around the gap; what shows only inside it "
                       "goes unseen", (float(t[k]), float(t[k + 1])))
            for k in np.flatnonzero(steps > limit)]


def _checked_then_notes(bag: str | Path, setup: Setup) -> Iterator[tuple[str, float, Any] | list[SampleNote]]:
    """``checked_samples``, then the notes on them as one list: one producer, so that the
    checks run where the bag is decoded (``io.prefetch``), off the stream work's core."""
    notes: list[SampleNote] = []
    yield from checked_samples(bag, setup, notes)
    yield notes


def release_jobs(bag: str | Path, setup: Setup, warnings: list[SampleNote] | None = None,
                 workers: int | None = None) -> list[Job]:
    """Each push's release job, as the estimator node makes it from the bag (a release
    still open at the end of the bag closed there, and said so). ``warnings``: what the
    bag's samples lacked is appended to it (a hole in a topic; samples out of stamp order,
    which the core drops as the node does, counted as the node's /diagnostics counts them).
    ``workers``: as ``analyze``'s; with more than one the bag is decoded in a process of its
    own, its samples checked there, beside the estimator's stream work (``io.prefetch``: the same
    samples, in order).

    Raises:
        BagError: unreadable bag, missing topic, malformed message.
        RecordError: no push whose release began.
    """
    stream = OnlineEstimator(setup, setup.segmenter_config(), replace(setup.estimator_config(), release_interval=0.0))
    add = {"stage": stream.add_stage, "image": stream.add_image, "markers": stream.add_markers,
           "object": stream.add_object}
    jobs: list[Job] = []
    deepest = 0.0
    cuts = None   # releases the node closed on silence: closed here at the same samples
    with Prefetched(partial(_checked_then_notes, bag, setup), process=(workers or default_workers()) > 1) as decoded:
        for item in decoded:
            if isinstance(item, list):   # the last item: the notes on the samples
                if warnings is not None:
                    warnings += item
                continue
            name, t, data = item
            if cuts is None:   # the samples' reader has checked every chunk by its first sample
                cuts = release_cuts(bag, chunks_checked=True)
            while cuts and t > cuts[0][0]:
                stream.replay_cut(*cuts.pop(0))
                jobs += stream.ready_jobs(silent=stream.streams)
            add[name](t, data)
            jobs += stream.ready_jobs()
            if name == "stage":
                deepest = max(deepest, float(data))
    stream.finish()
    jobs += stream.ready_jobs(silent=stream.streams)
    if warnings is not None:
        warnings += [SampleNote(f"{CORE_TOPIC[s]}: {n} message(s) stamped not after the one before (out of "
                                "header-stamp order) dropped, as the estimator node drops them (its /diagnostics "
                                "'out of order'): the analysis went without them")
                     for s, n in stream.rejected.items() if n]
    releases = [j for j in jobs if j.event.name == "release"]
    min_depth = setup.segmenter_config().min_depth
    if not releases and 0.0 < deepest < min_depth:
        raise RecordError(f"{bag}: {STAGE_TOPIC}: the stage went {deepest * 1e3:.3g} mm deep, under "
                          f"segmenter.min_depth ({min_depth * 1e3:.3g} mm): too shallow a push to identify")
    plateau = setup.segmenter_config().plateau
    if not jobs and deepest >= min_depth:
        raise RecordError(f"{bag}: {STAGE_TOPIC}: the stage went {deepest * 1e3:.3g} mm deep but never held still "
                          f"there for segmenter.plateau ({plateau} samples): no pull ended, so no keep to identify "
                          "from (a keep too short, or none)")
    if not releases:
        seen = ", ".join(sorted({j.event.name for j in jobs})) or "no phase"
        raise RecordError(f"{bag}: {STAGE_TOPIC}: no push with a release (the stage never let go after a pull "
                          f"and a keep; found {seen})")
    return releases


def analyze(
    bag: str | Path, effects: Sequence[str] = (), params_file: str | Path | None = None,
    discover_effects: bool = True, candidates: Sequence[str] | None = None,
    progress: Progress | None = None, workers: int | None = None,
) -> Analysis:
    """Analyse a bag: identify, compare, diagnose, add what is missing, refit.

    Args:
        bag: a rosbag2 directory of the contract.
        effects: effect ids to add to the base model, in order (``--add``; ``id:form`` for a
            form other than the family's default).
        params_file: parameters overriding the bag's own (``--params-file``).
        discover_effects: run the diagnosis loop after the user's effects.
        candidates: effect ids the diagnosis may try (default: the whole catalogue).
        progress: called with a line of text at each step.
        workers: processes for the candidates' fits (default: one per core).

    Raises:
        BagError: unreadable bag, missing topic, malformed message (the message names
            the file, topic or field).
        RecordError: data that cannot be identified (no push, a phase too short).
        ParamsError: a bad parameters file.
        KeyError: an unknown effect id.
    """
    for effect in effects:
        effect_class(*effect.split(":", 1))  # an unknown id or form fails before any work
    say = progress or (lambda _: None)
    params = bag_params(bag, params_file)
    setup = Setup(params)
    say(f"reading {bag}")
    said: list[SampleNote] = []   # what the bag's samples lacked: each push's report, where it touches it
    releases = release_jobs(bag, setup, said, workers)
    pushes = []
    for number, job in enumerate(releases, 1):
        if len(releases) > 1:
            say(f"experiment {number} of {len(releases)} (t {job.event.t_start:.2f} s to {job.event.t_end:.2f} s)")
        earlier = pushes[-1].base.estimate if pushes else None   # the node's final fit of the push before
        pushes.append(_analyze_push(bag, setup, job, number, effects, discover_effects, candidates, say, workers,
                                    earlier, said))
    if len(pushes) == 1:
        return pushes[0]
    # Every push is an experiment; the report's top level pools the last object's (to_json).
    return replace(pushes[0], experiments=tuple(pushes))


def _analyze_push(bag: str | Path, setup: Setup, job: Job, number: int, effects: Sequence[str],
                  discover_effects: bool, candidates: Sequence[str] | None, say: Progress,
                  workers: int | None, earlier: Estimate | None = None, said: Sequence[SampleNote] = ()) -> Analysis:
    """One push's analysis: the release job's record (its profile carries the pushes
    before it on the same specimen), closed form, fit (``earlier``: the push before's, a
    start where the closed form leaves a parameter open), the user's effects, discovery; ``said``: what
    the bag's samples lacked (``release_jobs``), among its warnings."""
    if job.record is None:
        raise RecordError(f"{bag}: experiment {number}: too few samples to identify")
    record = replace(job.record, source=str(bag))
    require_readings(record, TACTILE_TOPIC)   # before any work, naming the topic
    forward = setup.forward_model()
    noise = sensor_noise(record)
    t0, t1 = float(record.stage_t[0]), float(record.stage_t[-1])
    warnings = [*(n.text for n in said if n.touches(t0, t1)), *(w for w in (job.warning(),) if w),
                *(record.sensor.warnings if record.sensor else ()),
                *(w for w in (spikes_note(record, noise.force_spikes),) if w)]
    if job.object:
        warnings.append(f"experiment {number}: the goal said {job.object!r} object (/rheo/object): "
                        + ("modelled from rest, a new pool" if job.object == "new" else
                           "modelled from the pushes before, whatever the data say"))
    elif number > 1 and not record.profile().before:
        warnings.append(f"experiment {number}: the stage met the specimen at {contact_depth(record) * 1e3:.3f} mm, "
                        "at rest: another object, or one that recovered fully; modelled from rest, not from the "
                        "pushes before")
    say("closed form (eq. 6, 7, 10 / 14-17)")
    try:
        closed = closed_form("release", record, forward)
    except NoClosedForm as exc:   # as the node: the fit starts from a search
        reported = Estimate({k: np.nan for k in BASE_PARAMETERS}, "none", (), message=str(exc))
        open_ = {k: "no closed form has a solution" for k in BASE_PARAMETERS}
        warnings.append(f"closed form: {exc}; {SEARCHED}")
        starts = searched_starts(record, forward, earlier)
    else:
        if closed.failed:
            warnings.append(f"closed form: {closed.estimate.method} reported in place of: {'; '.join(closed.failed)}")
        open_ = undetermined(record, closed.estimate, setup.estimator_config())   # as the node reports it
        warnings += [f"closed form: {name} not determined: {why}" for name, why in open_.items()]
        reported = without_undetermined(closed.estimate, open_)
        starts = fit_starts(record, closed, setup.estimator_config(), earlier)
    for warning in warnings:
        say(f"warning: {warning}")
    say("fitting three_element over the whole record")
    fit = fit_from_starts(record, forward, starts, noise=noise)
    _, fit = relaxation_unseen(record, fit, forward, starts)   # as the node: a flat c2 valley widens the rest
    base, noise = base_model(record, forward, fit, noise)
    models = [base]
    for effect in effects:
        current = models[-1]
        effect_id, _, form = effect.partition(":")
        say(f"fitting {current.name}+{effect}")
        models.append(polish(record, forward, add_effect(record, forward, current, effect_id, noise, form or None),
                             noise))
    diagnoses: list[Diagnosis] = []
    if discover_effects:
        found, diagnoses = discover(record, forward, models[-1], candidates, noise, progress=say, workers=workers)
        models += found[1:]
    return Analysis(str(bag), record, setup, forward, noise, reported,
                    tuple(models), tuple(diagnoses), tuple(effects), tuple(warnings), object=job.object,
                    undetermined=open_)


def estimate_bag(path: str | Path, params: dict | None = None, diagnoses: list[OnlineDiagnosis] | None = None,
                 pools: list[PoolUpdate] | None = None) -> tuple[list[PhaseEvent], list[Update], list[str]]:
    """The estimator node's work on a bag, offline: same core, same samples, same order
    of work (what a replay over DDS into the node must reproduce); ``diagnoses`` and
    ``pools`` as in ``estimate_stream``."""
    params = params or read_params(path)
    if params is None:
        raise RecordError(f"{path}: no parameters in the bag's metadata; give --params-file")
    setup = Setup(params)
    estimator = OnlineEstimator(setup, setup.segmenter_config(), setup.estimator_config())
    return estimate_stream(estimator, bag_samples(path), diagnoses, pools)


def write_outputs(result: Analysis, json_path: str | Path | None, report_dir: str | Path | None,
                  data: dict[str, Any] | None = None) -> Path | None:
    """An analysis's JSON (``data``: its ``to_json()`` where the caller has it; written
    atomically) and HTML report, where asked; the report's path."""
    if json_path:
        write_json_atomic(json_path, result.to_json() if data is None else data)
    if not report_dir:
        return None
    from rheo_ros.reports.html import write_report

    return Path(write_report(result, report_dir))

