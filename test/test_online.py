"""The online core (no ROS): segmentation as the data stream in, and estimates per phase."""

import threading
from dataclasses import replace

import numpy as np
import pytest
from conftest import BAGS, REPO, TRUTH

from rheo_ros.app.analyze import estimate_bag
from rheo_ros.config.setup import Setup, load_params
from rheo_ros.config.tuning import EstimatorConfig
from rheo_ros.io.bag import bag_samples, read_bag
from rheo_ros.online.estimator import Job, OnlineEstimator, estimate_stream
from rheo_ros.online.segmenter import PhaseEvent, PhaseSegmenter
from rheo_ros.record import RecordError, segment_stage
from rheo_ros.rig.simulator import simulate_run

NAMES = sorted(p.stem for p in (BAGS / "params").glob("*.yaml"))
SHORT_RUN = {"stage.depth": 0.004, "stage.velocity": 0.001, "stage.keep_time": 6.0, "stage.release_time": 30.0,
             "stage.start_delay": 1.0}


def messages(stage_t, depth, force_t, force, marker_t, markers, offset=0.0):
    """(stream, t, data) in stamp order, the order a bag holds them."""
    out = [("stage", t + offset, d) for t, d in zip(stage_t, depth)]
    out += [("force", t + offset, f) for t, f in zip(force_t, force)]
    out += [("markers", t + offset, m) for t, m in zip(marker_t, markers)]
    return sorted(out, key=lambda m: (m[1], ("stage", "force", "markers").index(m[0])))


def feed_segmenter(seg, msgs):
    add = {"stage": seg.add_stage, "force": lambda t, f: seg.add_force(t, float(np.sum(f))),
           "markers": seg.add_markers}
    return [e for s, t, d in msgs for e in add[s](t, d)]


def record_messages(rec, offset=0.0):
    return messages(rec.stage_t, rec.stage_depth, rec.force_t, rec.force, rec.marker_t, rec.markers, offset)


def simulated(params: dict, seed: int = 0):
    setup = Setup({**load_params(None), **params})
    run = simulate_run(setup, seed)
    return setup, run, setup.tactile.nodal_forces(run.tactile)


@pytest.mark.parametrize("name", NAMES)
def test_segmenter_matches_the_offline_segmentation_within_one_sample(name):
    rec = read_bag(BAGS / name).record
    offline = rec.profile()
    events = {e.name: e for e in feed_segmenter(PhaseSegmenter(), record_messages(rec))}
    dt = float(np.median(np.diff(rec.stage_t)))
    assert abs(events["pull"].t_start - offline.t_pull_start) <= dt
    assert abs(events["pull"].t_end - offline.t_pull_end) <= dt
    assert abs(events["keep"].t_end - offline.t_keep_end) <= dt
    assert events["release"].t_start == events["keep"].t_end
    # Release ends when the mesh has settled: after the stage left, before the bag ends.
    assert offline.t_keep_end < events["release"].t_end < rec.marker_t[-1]
    release = events["release"]
    assert release.samples == np.count_nonzero((rec.marker_t > release.t_start) & (rec.marker_t <= release.t_end))
    assert abs(events["contact"].t_start - offline.t_pull_start) < 0.1


def test_segmenter_is_robust_to_encoder_noise_and_stamp_jitter():
    """2 um encoder noise and +-2 ms of stamp jitter: within one sample of the offline
    segmentation of the same noisy samples."""
    rec = read_bag(BAGS / "clean_short_keep").record
    rng = np.random.default_rng(0)
    t = rec.stage_t + rng.uniform(-0.002, 0.002, rec.stage_t.size)
    depth = rec.stage_depth + rng.normal(0, 2e-6, rec.stage_t.size)
    offline = segment_stage(t, depth)
    msgs = messages(t, depth, rec.force_t, rec.force, rec.marker_t, rec.markers)
    events = {e.name: e for e in feed_segmenter(PhaseSegmenter(), msgs)}
    assert abs(events["pull"].t_start - offline.t_pull_start) <= 0.01
    assert abs(events["pull"].t_end - offline.t_pull_end) <= 0.01
    assert abs(events["keep"].t_end - offline.t_keep_end) <= 0.01


@pytest.mark.parametrize("stage_lag", [0.0, 40.0])
def test_repeated_pushes_are_separate_experiments(stage_lag):
    """Also with the stage stream 40 s behind the others (a backlog on the busiest topic):
    the mesh settles before the stage stream has left the release."""
    setup, run, force = simulated(SHORT_RUN)
    msgs = []
    for k in range(3):
        msgs += messages(run.stage_t, run.stage_depth, run.tactile_t, force, run.marker_t, run.markers,
                         offset=k * (run.stage_t[-1] + 1.0))
    msgs.sort(key=lambda m: m[1] + (stage_lag if m[0] == "stage" else 0.0))
    events = feed_segmenter(PhaseSegmenter(), msgs)
    events.sort(key=lambda e: (e.experiment, ["contact", "pull", "keep", "release"].index(e.name)))
    assert [(e.experiment, e.name) for e in events if e.name != "contact"] == [
        (k, n) for k in (1, 2, 3) for n in ("pull", "keep", "release")]
    pulls = [e for e in events if e.name == "pull"]
    starts = np.array([e.t_start for e in pulls]) - np.arange(3) * (run.stage_t[-1] + 1.0)
    np.testing.assert_allclose(starts, setup.profile.t_pull_start, atol=0.01)


def test_a_new_push_before_the_mesh_settles_ends_the_release():
    _, run, force = simulated({**SHORT_RUN, "stage.release_time": 2.0})
    span = run.stage_t[-1] + 0.01
    msgs = messages(run.stage_t, run.stage_depth, run.tactile_t, force, run.marker_t, run.markers)
    msgs += messages(run.stage_t, run.stage_depth, run.tactile_t, force, run.marker_t, run.markers, offset=span)
    events = [e for e in feed_segmenter(PhaseSegmenter(), msgs) if e.name in ("release", "pull")]
    first_release, second_pull = events[1], events[2]
    assert first_release.name == "release" and first_release.experiment == 1
    assert first_release.t_end < second_pull.t_start


@pytest.fixture(scope="module")
def clean_updates():
    phases, updates, errors = estimate_bag(str(BAGS / "clean_short_keep"))
    return phases, updates, errors


def test_estimator_updates_after_each_phase_with_closed_form_then_fit(clean_updates):
    _, every, errors = clean_updates
    assert errors == []
    updates = [u for u in every if not u.interim]
    assert [(u.phase, u.method) for u in updates] == [
        ("pull", "paper_pull"), ("pull", "whole_record"), ("keep", "paper_keep"), ("keep", "whole_record"),
        ("release", "paper_short_time"), ("release", "whole_record")]
    assert [u.final for u in updates] == [False] * 5 + [True]
    # The release (69.0-99.8 s) goes on for 30.8 s: interim updates (closed form, fit) at
    # 10, 20 and 30 s of it (estimator.release_interval), before the final ones.
    interim = [(u.method, round(u.stamp, 2)) for u in every if u.interim]
    assert [m for m, _ in interim] == ["paper_short_time", "whole_record"] * 3 or [
        m for m, _ in interim if m == "whole_record"] == ["whole_record"] * 3, interim
    assert sorted({t for _, t in interim}) == pytest.approx([79.0, 89.0, 99.0], abs=0.021)
    assert all("interim" in u.message and not u.final for u in every if u.interim)
    # Each update uses only the samples up to its phase's end.
    stamps = [u.stamp for u in every]
    assert stamps == sorted(stamps) and updates[0].stamp < 21.1 and updates[2].stamp < 69.1


def test_estimates_converge_on_the_truth_as_phases_complete(clean_updates):
    """Noisy reference bag, simulated on a mesh twice as fine as the identification's
    (65 x 65 against 33 x 33 nodes: not its own model). Tolerances: 4 reported std
    (noise and the mesh's discretisation error) and 0.2 % for the final fit; the pull's
    and keep's fits within 4 std."""
    updates = [u for u in clean_updates[1] if not u.interim]
    final = updates[-1]
    for k, v in TRUTH.items():
        assert abs(final.params[k] - v) < 4 * final.std[k], (k, final.params[k], final.std[k])
        assert abs(final.params[k] - v) < 2e-3 * v
    for u in (updates[1], updates[3]):
        for k, v in TRUTH.items():
            assert abs(u.params[k] - v) < 4 * u.std[k], (u.phase, k, u.params[k], u.std[k])
    # The fits narrow down as data come in: c2's std after keep is below a tenth of after pull.
    assert updates[3].std["c2"] < 0.1 * updates[1].std["c2"]
    assert updates[5].std["c2"] <= updates[3].std["c2"]
    # The keep's closed form (eq. 6, 7, 10 through the shared forward model): E, c1, c2
    # within 0.2 % of the truth (measured on the clean bags: 0.06 % at most).
    assert max(abs(e) for e in (100 * (updates[2].params[k] / v - 1) for k, v in TRUTH.items() if k != "gamma")) < 0.2
    # N, total force, whose noise here is 0.0072 N (the RMS of a perfect model): the fits
    # and the pull's and keep's closed forms within 1.7 x that (measured 0.0060-0.0072 N);
    # the release's closed form (final displacement: 2-4 % off on these bags) misfits by
    # 0.12 N (measured), held below 0.2 N.
    assert all(u.rmse_force < 0.012 for u in updates if u.phase != "release" or u.method == "whole_record")
    assert updates[4].method == "paper_short_time" and updates[4].rmse_force < 0.2


def test_results_do_not_depend_on_how_the_streams_interleave(clean_updates):
    """Markers 120 s ahead of the stage (a backlog on the busy topic), the tactile frames
    30 s behind: same numbers, exactly."""
    _, reference, _ = clean_updates
    from rheo_ros.io.bag import bag_samples, read_params

    shift = {"stage": 0.0, "image": 30.0, "markers": -120.0}
    msgs = sorted(bag_samples(BAGS / "clean_short_keep"), key=lambda m: m[1] + shift[m[0]])
    est = OnlineEstimator(Setup(read_params(BAGS / "clean_short_keep")))
    _, updates, errors = estimate_stream(est, msgs)
    assert errors == [] and len(updates) == len(reference)
    for a, b in zip(updates, reference):
        np.testing.assert_array_equal(a.values, b.values)
        assert a.samples == b.samples and a.stamp == b.stamp


def test_bad_samples_are_counted_not_fatal():
    c = read_bag(BAGS / "clean_short_keep")
    est = OnlineEstimator(Setup(c.params))
    assert est.add_stage(1.0, 0.0) == [] and est.add_stage(0.5, 0.0) == []      # out of order
    assert est.add_stage(2.0, float("nan")) == []
    assert est.add_force(1.0, np.array([np.nan] * 5)) == []
    assert est.rejected == {"stage": 2, "force": 1, "markers": 0}
    with pytest.raises(RecordError, match="markers: 3 markers, parameters say 25"):
        est.add_markers(1.0, np.zeros((3, 2)))


def test_an_object_hint_applies_to_the_first_push_that_starts_after_it():
    """``/rheo/object``: a hint applies to the push whose pull starts at or after its stamp
    and after the push before it started; the last such hint wins; another word is refused."""
    from rheo_ros.experiment import StageProfile

    est = OnlineEstimator(Setup(load_params(None)))
    first = StageProfile(depth=0.008, velocity=0.001, keep_time=15.0, release_time=40.0, start_delay=1.0)
    second = replace(first, start_delay=80.0, before=(first,))
    third = replace(first, start_delay=160.0, before=(first, replace(second, before=())))
    est.add_object(50.0, "same")
    est.add_object(79.5, "new")     # the later of two before push 2: it wins
    est.add_object(200.0, "same")   # after push 3's start: for a push to come
    assert [est.object_of(p) for p in (first, second, third)] == ["", "new", ""]
    with pytest.raises(ValueError, match="object: 'old' is none of new, same or empty"):
        est.add_object(1.0, "old")


def test_memory_stays_bounded_over_many_experiments():
    """Twenty pushes: the buffers hold one push and a window, not the history."""
    setup, run, force = simulated(SHORT_RUN)
    est = OnlineEstimator(setup, config=replace(setup.estimator_config(), fit=False, release_interval=0.0))
    span = run.stage_t[-1] + 1.0
    sizes, n_updates = [], 0
    for k in range(20):
        msgs = messages(run.stage_t, run.stage_depth, run.tactile_t, force, run.marker_t, run.markers, k * span)
        _, updates, errors = estimate_stream(est, msgs)
        assert errors == []
        n_updates += len(updates)
        sizes.append(sum(len(s.t) for s in est.streams.values()))
    assert n_updates == 20 * 3
    assert max(sizes[5:]) <= max(sizes[:5]) and max(sizes) < 2 * (run.stage_t.size + run.tactile_t.size
                                                                   + run.marker_t.size)


def test_a_keep_far_shorter_than_the_relaxation_time_leaves_c2_undetermined():
    """A 1 mm push held 1 s: the relaxation (time ~1000 s) is not seen; E and c2 come
    back NaN with a reason that names the experiment that would determine them.

    Without the tactile dead band: with it, forces this small are clipped and the
    three-element fit is misspecified (the honest-identification issue's subject)."""
    setup, run, force = simulated({"stage.depth": 0.001, "stage.velocity": 0.001, "stage.keep_time": 1.0,
                                   "stage.release_time": 20.0, "tactile.threshold": 0.0})
    msgs = messages(run.stage_t, run.stage_depth, run.tactile_t, force, run.marker_t, run.markers)
    _, updates, _ = estimate_stream(OnlineEstimator(setup), msgs)
    assert updates, "no update at all"
    keep = [u for u in updates if u.method == "whole_record" and u.phase == "keep"][-1]
    assert "c2" in keep.undetermined and np.isnan(keep.params["c2"])
    reason = dict(zip(keep.undetermined, keep.reasons))["c2"]
    assert "keep of at least" in reason
    # After release the permanent set (the dashpot's share) bounds c2 again: either
    # reported within 3 std of the truth, or still undetermined.
    final = updates[-1]
    assert final.phase == "release"
    if "c2" not in final.undetermined:
        assert abs(final.params["c2"] - TRUTH["c2"]) < 3 * final.std["c2"]


def test_a_shallow_short_push_gets_a_closed_form_from_the_nodes_above_the_noise_and_a_calibrated_fit():
    """A 2 mm push held 2 s: at some nodes the final displacement is within the marker
    noise and eq. 14-17 get the wrong sign there; the closed form leaves them out and says
    so, and the release's fit of all the data reports values within 3 std of the truth.
    Here the permanent set is at the markers' noise: the release's fit finds c2 in a flat
    valley out to infinity (E and c2 undetermined), and c1's std holds the valley's move
    (``relaxation_unseen``): measured c1 -1.16 std, gamma -0.93 (without that term c1
    was -3.8 std: a std conditional on an infinite c2)."""
    setup, run, force = simulated({"stage.depth": 0.002, "stage.velocity": 0.002, "stage.keep_time": 2.0,
                                   "stage.release_time": 30.0})
    msgs = messages(run.stage_t, run.stage_depth, run.tactile_t, force, run.marker_t, run.markers)
    _, updates, errors = estimate_stream(OnlineEstimator(setup), msgs)
    assert errors == []
    closed = [u for u in updates if u.phase == "release" and u.method.startswith("paper_")]
    assert closed and "left out of the equations" in closed[0].message
    last = updates[-1]
    assert (last.phase, last.method) == ("release", "whole_record")
    determined = [n for n in last.names if n not in last.undetermined]
    assert {"c1", "gamma"} <= set(determined)
    for n in determined:
        assert abs(last.params[n] - TRUTH[n]) < 3 * last.std[n], n
    assert abs(last.params["c1"] / TRUTH["c1"] - 1) < 0.01


def test_without_the_fit_the_release_closed_form_is_the_final_update(clean_updates):
    """``estimator.fit: false``: the closed forms alone, the release's marked final
    (what the stage's /rheo/identify action waits for), with the same values as with
    the fit (the closed form does not depend on the fits)."""
    bag = str(BAGS / "clean_short_keep")
    setup = Setup(read_bag(bag).params)
    _, updates, errors = estimate_stream(OnlineEstimator(setup, config=EstimatorConfig(fit=False)),
                                         bag_samples(bag))
    assert errors == []
    assert [(u.phase, u.final, u.interim) for u in updates] == [
        ("pull", False, False), ("keep", False, False), *[("release", False, True)] * 3, ("release", True, False)]
    closed = [u for u in clean_updates[1] if u.method != "whole_record"]
    for mine, theirs in zip(updates, closed):
        np.testing.assert_array_equal(mine.values, theirs.values)


def test_a_lane_that_falls_behind_keeps_the_newest_jobs_and_counts_the_rest():
    """The estimator's fit lane (seconds per job) under pushes arriving faster: bounded
    at its size, oldest dropped and counted, order kept; a waiting reader wakes."""
    from rheo_ros.online.backlog import Backlog

    lane: Backlog[int] = Backlog(3)
    for i in range(10):
        lane.put(i)
    assert len(lane) == 3 and lane.dropped == 7
    assert [lane.get() for _ in range(3)] == [7, 8, 9]
    got: list[int] = []
    reader = threading.Thread(target=lambda: got.append(lane.get()))
    reader.start()
    lane.put(42)
    reader.join(timeout=5.0)
    assert got == [42] and lane.dropped == 7
    with pytest.raises(ValueError, match="at least 1"):
        Backlog(0)


def test_a_full_fit_lane_skips_the_fits_a_later_phase_of_their_push_covers():
    """The estimator node's fit lane behind the pushes: to make room it skips first a
    waiting pull or keep fit whose push's later phase is waiting too (its fit covers their
    data), the oldest job only if there is none; a lane with room skips nothing. A release
    without a closed form starts from the keep's fit, so it covers nothing."""
    from rheo_ros.nodes.estimator import EstimatorNode
    from rheo_ros.online.backlog import Backlog

    def job(experiment: int, phase: str, closed: object | None = "a closed form"):
        return (Job(PhaseEvent(experiment, phase, 0.0, 1.0, 1.0, 10), None, ()), closed, 0.0)

    def waiting(lane):
        return [(j.event.experiment, j.event.name) for j, _, _ in lane._items]

    lane = Backlog(4, supersedes=EstimatorNode._supersedes)
    for item in [job(1, "pull"), job(1, "keep"), job(2, "pull"), job(1, "release")]:
        lane.put(item)
    assert waiting(lane) == [(1, "pull"), (1, "keep"), (2, "pull"), (1, "release")]
    assert (lane.superseded, lane.dropped) == (0, 0)
    lane.put(job(2, "keep"))
    lane.put(job(2, "release"))
    assert waiting(lane) == [(2, "pull"), (1, "release"), (2, "keep"), (2, "release")]
    assert (lane.superseded, lane.dropped) == (2, 0)
    lane.put(job(3, "pull"))
    lane.put(job(3, "keep"))
    assert waiting(lane) == [(1, "release"), (2, "release"), (3, "pull"), (3, "keep")]
    assert (lane.superseded, lane.dropped) == (4, 0)
    lane.put(job(3, "release", None))   # no closed form
    assert waiting(lane) == [(1, "release"), (2, "release"), (3, "keep"), (3, "release")]
    assert (lane.superseded, lane.dropped) == (5, 0)
    lane.put(job(4, "pull"))
    assert waiting(lane) == [(2, "release"), (3, "keep"), (3, "release"), (4, "pull")]
    assert (lane.superseded, lane.dropped) == (5, 1)
    # What the lane asks before a diagnosis: is a newer push's release fit waiting?
    assert lane.holds(lambda item: item[0].event == PhaseEvent(3, "release", 0.0, 1.0, 1.0, 10))
    assert not lane.holds(lambda item: item[0].event.experiment == 1)


def test_a_waiting_interim_release_fit_leaves_once_a_later_stretch_of_its_release_waits():
    """Interim release fits in a slow fit lane: each leaves the queue as soon as a later
    release job of its push (interim or final) is put, room or not, and is counted; other
    pushes' jobs and the pull and keep fits stay."""
    from rheo_ros.nodes.estimator import EstimatorNode
    from rheo_ros.online.backlog import Backlog

    def job(experiment: int, phase: str, t_end: float, interim: bool = False):
        return (Job(PhaseEvent(experiment, phase, 0.0, t_end, t_end, 10), None, (), interim=interim), "cf", 0.0)

    lane = Backlog(8, supersedes=EstimatorNode._supersedes, replaces=EstimatorNode._replaces)
    for item in [job(1, "pull", 4), job(1, "keep", 10), job(1, "release", 20, True), job(2, "release", 30, True)]:
        lane.put(item)
    lane.put(job(1, "release", 30, True))
    lane.put(job(1, "release", 35))
    assert [(j.event.experiment, j.event.name, j.event.t_end, j.interim) for j, _, _ in lane._items] == [
        (1, "pull", 4, False), (1, "keep", 10, False), (2, "release", 30, True), (1, "release", 35, False)]
    assert (lane.replaced, lane.superseded, lane.dropped) == (2, 0, 0)


def test_a_worker_process_returns_results_raises_errors_and_replaces_itself_when_killed():
    """The estimator's lanes call their identifier in a worker process: a result comes
    back, an exception is raised in the caller, a worker killed during a call (out of
    memory) fails that call with WorkerDied and a new one serves the next, and one that
    died while idle is replaced without failing the call."""
    import os
    import signal
    import time

    from rheo_ros.online.worker import Worker, WorkerDied

    worker = Worker(time.sleep)   # any picklable object: its methods are called
    try:
        assert worker.call("__call__", 0.01) is None
        assert 0.01 <= worker.last_compute < 5.0   # the sleep, timed in the worker
        with pytest.raises(TypeError, match="cannot be interpreted"):
            worker.call("__call__", "ten")
        first = worker.process.pid
        killer = threading.Timer(0.3, os.kill, (first, signal.SIGKILL))
        killer.start()
        with pytest.raises(WorkerDied, match="exit code -9"):
            worker.call("__call__", 30.0)
        second = worker.process.pid
        assert second != first and worker.call("__call__", 0.0) is None
        os.kill(second, signal.SIGKILL)
        worker.process.join(timeout=5.0)
        assert worker.call("__call__", 0.0) is None and worker.process.pid not in (first, second)
    finally:
        worker.close()
    assert not worker.process.is_alive()
    with pytest.raises(WorkerDied, match="stopped"):
        worker.call("__call__", 0.0)


def test_a_worker_asked_for_a_realtime_priority_runs_under_sched_fifo_or_says_why_not():
    """``estimator.closed_form_priority``: the closed-form worker under SCHED_FIFO at the
    priority asked (where the process may: root, CAP_SYS_NICE or an rtprio limit), else
    under normal scheduling with the refusal said (``Worker.refused``, on /diagnostics);
    0 leaves it as it is. Each branch checks the process's own scheduling."""
    import os
    import time

    from rheo_ros.online.worker import Worker

    for asked in (0, 7):
        worker = Worker(time.sleep, realtime=asked)
        try:
            policy, priority = os.sched_getscheduler(worker.process.pid), os.sched_getparam(worker.process.pid)
            assert worker.call("__call__", 0.0) is None
        finally:
            worker.close()
        if not asked:
            assert worker.refused == "" and (policy, priority.sched_priority) == (os.SCHED_OTHER, 0)
        elif worker.refused:   # not permitted here: said, and normal scheduling
            assert "SCHED_FIFO) refused" in worker.refused and (policy, priority.sched_priority) == (os.SCHED_OTHER, 0)
        else:
            assert (policy, priority.sched_priority) == (os.SCHED_FIFO, 7)


@pytest.mark.skipif(len(__import__("os").sched_getaffinity(0)) < 2,
                    reason="OpenBLAS runs one thread on one core whatever is asked")
def test_a_worker_process_runs_blas_on_one_thread_whatever_the_environment_asks(monkeypatch):
    """The estimator's workers limit numpy's and scipy's OpenBLAS to one thread
    (``single_threaded_blas``): started from an environment asking for two, each BLAS
    library in the worker reports one (two without the limit: asserted in the test's own
    child process, so that the test can fail)."""
    import os
    import subprocess
    import sys

    from rheo_ros.online.worker import Worker

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    worker = Worker(eval)   # runs an expression in the worker: there, load both libraries and ask them
    try:
        info = worker.call("__call__", "__import__('scipy.linalg') and __import__('threadpoolctl').threadpool_info()")
        blas = [(i["filepath"], i["num_threads"]) for i in info if i["user_api"] == "blas"]
    finally:
        worker.close()
    assert blas and {n for _, n in blas} == {1}, blas   # numpy's and scipy's (one where they share it)
    unlimited = subprocess.run([sys.executable, "-c", "import scipy.linalg, threadpoolctl; print(max("
                                "i['num_threads'] for i in threadpoolctl.threadpool_info() if i['user_api'] == 'blas'))"],
                               capture_output=True, text=True, timeout=60, env=dict(os.environ, OPENBLAS_NUM_THREADS="2"))
    assert unlimited.stdout.strip() == "2", unlimited


def test_a_relaxation_too_slow_to_see_is_undetermined_on_every_replay_pass(tmp_path):
    """`rheo bench online`'s short run (2 mm, keep 2 s; relaxation time ~900 s) at the
    stamps of its first 12 replay passes: the keep and release closed forms either leave
    E undetermined or give it within 10 % (the rate is not seen). Fitting eq. 6 as a line
    in exp(-r t) cancelled to rounding at the tiny rates the search wandered to: passes 3
    and 4 reported the rate to 2 % and 25 %, and E 8692 and 14770 Pa (truth 33300)."""
    from rosbags.highlevel import AnyReader

    from rheo_ros.app.simulate import simulate_to_bag
    from rheo_ros.bench.online import SHORT_RUN as BENCH_RUN

    setup = Setup({**load_params(None), **BENCH_RUN})
    simulate_to_bag(setup, 0, tmp_path / "bag")
    samples = list(bag_samples(str(tmp_path / "bag")))
    with AnyReader([tmp_path / "bag"]) as reader:   # rheo play --loop's shift: a pass and 10 ms
        span = reader.end_time - reader.start_time + 10_000_000
    config = replace(setup.estimator_config(), fit=False, release_interval=0.0)
    for k in range(12):
        shifted = [(s, (round(t * 1e9) + k * span) * 1e-9, d) for s, t, d in samples]
        _, updates, errors = estimate_stream(OnlineEstimator(setup, config=config), shifted)
        assert errors == [] and [u.phase for u in updates] == ["pull", "keep", "release"], (k, errors)
        for u in updates[1:]:
            # Measured on every pass: the rate is not seen, E undetermined with the reason.
            assert "E" in u.undetermined and np.isnan(u.params["E"]), (k, u.phase, u.params)
            assert "relaxation rate" in dict(zip(u.undetermined, u.reasons))["E"]


def test_a_release_still_moving_at_max_release_ends_there_and_says_so():
    """``segmenter.max_release``: the specimen recovers for ~20 s after this push; with a
    3 s limit the release ends at the first marker frame past it, with the reason."""
    from rheo_ros.config.tuning import SegmenterConfig

    _, run, force = simulated(SHORT_RUN)
    seg = PhaseSegmenter(SegmenterConfig(max_release=3.0))
    events = [e for e in feed_segmenter(seg, messages(run.stage_t, run.stage_depth, run.tactile_t, force,
                                                      run.marker_t, run.markers)) if e.name == "release"]
    assert len(events) == 1
    release = events[0]
    # Frames every 0.1 s: the first one more than 3 s after the let-go.
    assert 3.0 < release.t_end - release.t_start <= 3.1 + 1e-9
    assert seg.release_reason == "still moving after 3 s"
    # Without the limit the same data settle much later (the limit did cut it short).
    settled = [e for e in feed_segmenter(PhaseSegmenter(), messages(
        run.stage_t, run.stage_depth, run.tactile_t, force, run.marker_t, run.markers)) if e.name == "release"]
    assert settled[0].t_end - settled[0].t_start > 10.0


def test_a_release_a_node_closed_on_silence_closes_there_in_the_recordings_analysis(tmp_path):
    """One computation for a release the node cut short: its core's topics go silent 5 s
    into the release (a simulator that stalled) and the data then go on at later stamps.
    The node says so on /rheo/phase; rheo analyze of the recording (the phase message in
    it) closes the release at the same sample, with the same data, as the node did;
    without the message the release runs on to where the mesh settles."""
    from rosbags.highlevel import AnyReader

    from rheo_ros.app.analyze import release_jobs
    from rheo_ros.io.bag import BagWriter, read_params, typestore
    from rheo_ros.io.messages import PHASE_TOPIC, PHASE_TYPE, phase_message

    bag = BAGS / "clean_short_keep"
    setup = Setup(read_params(bag))
    core = OnlineEstimator(setup, setup.segmenter_config(), replace(setup.estimator_config(), release_interval=0.0))
    add = {"stage": core.add_stage, "image": core.add_image, "markers": core.add_markers}
    why = "no message on any topic for 2 s"
    jobs, cut = [], None
    for name, t, data in bag_samples(bag):
        if cut is None and t > core.segmenter.release_began + 5.0:
            [event] = core.finish(why)
            cut = (event, core.cut_short(event))
            jobs += core.ready_jobs(silent=core.streams)
        add[name](t, data)
        jobs += core.ready_jobs()
    core.finish()
    jobs += core.ready_jobs(silent=core.streams)
    event, said = cut
    assert said == why and event.name == "release"
    [online] = [j for j in jobs if j.event.name == "release"]
    assert online.cut_short == why and online.event == event

    definition = (REPO / "msg_schemas" / "rheo_ros_interfaces" / "msg" / "Phase.msg").read_text()
    recorded = tmp_path / "recorded"
    with AnyReader([bag], default_typestore=typestore()) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections} | {PHASE_TOPIC: PHASE_TYPE}
        with BagWriter(recorded, read_params(bag), topics=topics, definitions={PHASE_TYPE: definition}) as writer:
            found = round(event.t_found * 1e9)
            for conn, stamp, raw in reader.messages():
                writer.write_raw(conn.topic, stamp, raw)
                if found is not None and stamp >= found:   # logged when the node said it
                    writer.write(PHASE_TOPIC, stamp, phase_message(writer.types, event, cut_short=why))
                    found = None
    [offline] = release_jobs(recorded, setup)
    assert (offline.event, offline.cut_short) == (online.event, online.cut_short)
    for field in ("stage_t", "stage_depth", "force_t", "force", "marker_t", "markers"):
        assert np.array_equal(getattr(offline.record, field), getattr(online.record, field)), field
    # Without the node's word the recording's release runs on past the cut, to where the mesh settles.
    [whole] = release_jobs(bag, setup)
    assert whole.cut_short == "" and whole.event.t_end > event.t_end + 10.0
