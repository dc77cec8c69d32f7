"""Estimator node: E, c1, c2 and gamma updated as each phase completes (``ros2 run rheo_ros estimator``).

Subscribes to the three measurement topics; publishes ``/rheo/estimate`` (the last one
kept for late subscribers: transient-local), after each release the verdict of the
model-discovery loop on ``/rheo/diagnosis`` (which effect the three-element model
misses, the model with it; transient-local too), ``/diagnostics``, and the
model's prediction of what is measured, for an overlay in Foxglove or PlotJuggler:

- ``/rheo/measured/force`` and ``/rheo/prediction/force`` (``geometry_msgs/WrenchStamped``:
  ``wrench.force.y`` = total bottom force, N, positive pressing), stamped with each
  tactile frame's stamp;
- ``/rheo/prediction/markers`` (``geometry_msgs/PoseArray``, like ``/markers/mesh``);

and on ``/rheo/phase`` a release it closed because every topic went silent (its
``cut_short`` says why): ``rheo analyze`` of a recording that holds it closes that
release there too, whatever the recording holds after.

The callbacks only convert messages and feed the core (``rheo_ros.online``). The
identification runs in two lanes, each a worker process, so that nothing waits behind
a fit and no computation shares the interpreter with message intake: the paper's
closed forms (tens of milliseconds), and the whole-record fits (up to seconds) at
lower priority. A bad message is counted and reported, never fatal; a worker that
dies is replaced.
"""

from __future__ import annotations

import queue
import sys
import threading
import time
from collections import deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, WrenchStamped
from rclpy._rclpy_pybind11 import InvalidHandle
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rheo_ros_interfaces.msg import Diagnosis, Estimate, ObjectHint, Phase, Pool
from sensor_msgs.msg import Image, JointState

from rheo_ros.config.setup import Setup
from rheo_ros.identification.pipeline import ClosedForm
from rheo_ros.io.checks import SampleCheck
from rheo_ros.io.messages import (
    DIAGNOSIS_TOPIC,
    ESTIMATE_TOPIC,
    MARKERS_TOPIC,
    OBJECT_TOPIC,
    PHASE_TOPIC,
    POOL_TOPIC,
    STAGE_TOPIC,
    TACTILE_TOPIC,
    MarkerArrayEncoder,
    MessageError,
    MessageTypes,
    diagnosis_message,
    estimate_message,
    phase_message,
    pool_message,
    read_joint_state,
    read_marker_array,
    read_object_hint,
    read_pressure_image,
    stamp_ns,
)
from rheo_ros.nodes.common import NODE_OPTIONS, BadMessages, Silence, declare_all, diagnostic_array, run_node
from rheo_ros.online.backlog import Backlog
from rheo_ros.online.estimator import Job, OnlineDiagnosis, OnlineEstimator, PoolUpdate, Update, supersedes
from rheo_ros.online.worker import Worker, WorkerDied
from rheo_ros.record import RecordError

# Measurements: reliable, KEEP_ALL: a reader that falls behind holds the writer back
# (a KEEP_ALL writer: rheo play) instead of having its queue overwritten; with a
# KEEP_LAST writer (a live driver) the depth below is what the writer keeps.
SENSOR_QOS = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
# The last updates stay with the publisher for subscribers that join later (one that
# asks for depth 1 gets the last). Deeper than one push's burst of updates: a
# reliable KEEP_LAST writer drops a sample a slow reader has not acknowledged when the
# next one comes, and discovery may finish after the first updates.
LATCHED_QOS = QoSProfile(depth=16, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
FIT_BACKLOG = 8          # whole-record jobs waiting (about three pushes' worth)
PREDICTION_RATE = 10.0   # Hz of stamps, per predicted topic
TOPICS = {"stage": STAGE_TOPIC, "force": TACTILE_TOPIC, "markers": MARKERS_TOPIC}
INPUTS = {**TOPICS, "object": OBJECT_TOPIC}   # what the node takes in: the measurements and the robot's hints


class EstimatorNode(Node):
    def __init__(self, name: str = "estimator") -> None:
        super().__init__(name, **NODE_OPTIONS)
        params = declare_all(self)
        self.setup = Setup(params)
        self.core = OnlineEstimator(self.setup, self.setup.segmenter_config(), self.setup.estimator_config())
        self.check = SampleCheck(self.setup)   # the samples rheo analyze would refuse, refused
        self.stale_after = params["estimator.stale_after"]
        self.types = MessageTypes.rclpy()
        self.create_subscription(JointState, STAGE_TOPIC, self.on_stage, SENSOR_QOS)
        self.create_subscription(Image, TACTILE_TOPIC, self.on_tactile, SENSOR_QOS)
        self.create_subscription(PoseArray, MARKERS_TOPIC, self.on_markers, SENSOR_QOS)
        self.estimates = self.create_publisher(Estimate, ESTIMATE_TOPIC, LATCHED_QOS)
        self.verdicts = self.create_publisher(Diagnosis, DIAGNOSIS_TOPIC, LATCHED_QOS)
        self.pools = self.create_publisher(Pool, POOL_TOPIC, LATCHED_QOS)
        # A release this node closes on silence (its wall clock: the data stopped) is said
        # on /rheo/phase, so a recording of the run is analysed as the node analysed it.
        self.phases = self.create_publisher(Phase, PHASE_TOPIC, LATCHED_QOS)
        # What the robot says of the next push's object: latched, the stage's goals.
        self.create_subscription(ObjectHint, OBJECT_TOPIC, self.on_object, LATCHED_QOS)
        self.verdict = ""    # the last experiment's model verdict, while it says the base model misfits
        self.diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.measured_force = self.create_publisher(WrenchStamped, "/rheo/measured/force", 10)
        self.predicted_force = self.create_publisher(WrenchStamped, "/rheo/prediction/force", 10)
        self.predicted_markers = self.create_publisher(PoseArray, "/rheo/prediction/markers", 10)
        self.encode_markers = MarkerArrayEncoder(self.types)
        self.silence = Silence(TOPICS, self.stale_after)
        self.create_timer(self.silence.tick_period, self.silence.tick)
        self.bad = BadMessages(INPUTS, self.stale_after)
        self.last_error = ""
        self.latest: Update | None = None
        # The last sensor model an update brought (``Update.sensor``) for /diagnostics.
        self.sensor_model: dict | None = None
        self.open_params: dict[str, str] = {}
        self.predicted_at: dict[str, float] = {}
        self.updates = 0
        self.skipped_diagnoses = 0
        # Latency from the message that completed a phase to the update's publication; of
        # that the closed form's round trip through its worker process, and of that its
        # computation (the rest: the transfer, and the lanes' queues and the executor).
        self.latency = {k: deque(maxlen=1000) for k in ("closed_form", "whole_record", "closed_form worker",
                                                        "closed_form compute")}
        self.started = time.monotonic()
        # Lanes: a thread each, handing the work to its worker process and the result back.
        self.workers = {"closed_form": Worker(self.core.identify, self.NICENESS["closed_form"],
                                              realtime=params["estimator.closed_form_priority"])}
        if self.workers["closed_form"].refused:
            self.get_logger().warning(f"closed-form worker: {self.workers['closed_form'].refused}")
        if self.core.config.fit:
            self.workers["fit"] = Worker(self.core.identify, self.NICENESS["fit"])
        self.closed_jobs: queue.Queue[tuple[Job, float] | None] = queue.Queue()
        # Fits and diagnoses take seconds: a lane that falls behind keeps FIT_BACKLOG jobs,
        # skipping first a push's earlier fits that its later phase's covers, and counts
        # what it skips (reported on /diagnostics); a waiting interim release fit leaves as
        # soon as a later stretch of its release is queued.
        self.fit_jobs: Backlog[tuple[Job, ClosedForm | None, float] | None] = Backlog(
            FIT_BACKLOG, supersedes=self._supersedes, replaces=self._replaces)
        # Results go back to the executor's thread to be published: rclpy entities are
        # used from one thread only (taking and publishing concurrently crashed rclpy).
        # Log lines of the lanes go the same way (rclpy's logger keeps per-call-site state).
        self.outbox: queue.Queue[tuple[Update | OnlineDiagnosis, float, tuple[float, float] | None]
                                 | tuple[str, str]] = queue.Queue()
        self.results_ready = self.create_guard_condition(self.publish_results)
        self.lanes = [threading.Thread(target=self.closed_form_lane, name="estimator-closed-forms", daemon=True),
                      threading.Thread(target=self.fit_lane, name="estimator-fits", daemon=True)]
        for lane in self.lanes:
            lane.start()
        self.create_timer(params["estimator.diagnostics_period"], self.publish_diagnostics)
        self.get_logger().info(f"estimator ready: {params['geometry']}, markers {self.setup.mesh.rows} x "
                               f"{self.setup.mesh.cols}, tactile {self.setup.tactile.rows} x {self.setup.tactile.cols}")

    # -- measurements in ---------------------------------------------------------------

    def _feed(self, stream: str, msg, decode, add) -> None:
        arrival = time.perf_counter()
        self.silence.heard(stream)
        try:
            t = stamp_ns(msg) * 1e-9
            value = decode(msg)
            if not np.all(np.isfinite(value)):
                raise MessageError("non-finite values")   # a bad message, not one out of order
            problem = self.check.problem(TOPICS[stream], t, value)
            if problem:   # as rheo analyze refuses it: a clock jump, a frame of another size, mm
                raise MessageError(problem)
            events = add(t, value)
        except (MessageError, RecordError, ValueError) as exc:
            if self.bad.bad(stream, f"{TOPICS[stream]}: {exc}"):
                self.get_logger().warning(f"{self.bad.last}; message ignored")
            return
        self.bad.good()
        for e in events:  # /rheo/phase is the segmenter node's; the same core finds the same phases
            self.get_logger().info(f"experiment {e.experiment}: {e.name} {e.t_start:.3f} .. {e.t_end:.3f} s")
        self.dispatch(arrival)
        if stream == "force":
            self.publish_force(t, self.setup.tactile.nodal_forces(value[None])[0])
        elif stream == "markers":
            self.publish_markers(t)

    def dispatch(self, arrival: float) -> None:
        """Hand the phases whose data are all in to the worker. Which samples a job uses
        depends on stamps only; a silent topic stops holding phases back, and when every
        topic has gone silent a release still open closes there (cut short: the robot
        let go and moved on, or the recording stopped)."""
        silent = self.silence.silent()
        if self.silence.all_silent and self.core.release_open:
            for e in self.core.finish(f"no message on any topic for {self.stale_after:g} s"):
                why = self.core.cut_short(e)
                if why:   # recorded, a recording's rheo analyze closes this release here too
                    self.phases.publish(phase_message(self.types, e, cut_short=why))
                    self.get_logger().warning(f"experiment {e.experiment}: release closed at {e.t_end:.3f} s: "
                                              "the data stopped before the specimen settled")
        for job in self.core.ready_jobs(silent):
            self.closed_jobs.put((job, arrival))

    def on_object(self, msg: ObjectHint) -> None:
        try:
            self.core.add_object(stamp_ns(msg) * 1e-9, read_object_hint(msg))
        except MessageError as exc:
            self.bad.bad("object", f"{OBJECT_TOPIC}: {exc}")
            self.get_logger().warning(f"{self.bad.last}; message ignored")

    def on_stage(self, msg: JointState) -> None:
        self._feed("stage", msg, lambda m: read_joint_state(m)[0], self.core.add_stage)

    def on_tactile(self, msg: Image) -> None:
        self._feed("force", msg, read_pressure_image, self.core.add_image)

    def on_markers(self, msg: PoseArray) -> None:
        self._feed("markers", msg, read_marker_array, self.core.add_markers)

    # -- identification lanes ------------------------------------------------------------

    NICENESS = {"closed_form": 0, "fit": 10}

    def _in_worker(self, lane: str, method: str, *args):
        try:
            return self.workers[lane].call(method, *args)
        except WorkerDied as exc:
            # Killed or out of memory: the worker restarted itself for the next jobs.
            raise RecordError(f"{lane.replace('_', ' ')} lane: {exc}") from None

    def _hand_out(self, update: Update | OnlineDiagnosis, arrival: float,
                  worker: tuple[float, float] | None = None) -> None:
        self.outbox.put((update, arrival, worker))
        self._wake()

    def _wake(self) -> None:
        """Tell the executor's thread that results wait; a lane finishing while the node
        shuts down finds the guard condition gone, and its result has nowhere to go."""
        try:
            self.results_ready.trigger()
        except InvalidHandle:
            pass

    @staticmethod
    def _supersedes(new: tuple[Job, ClosedForm | None, float] | None,
                    old: tuple[Job, ClosedForm | None, float] | None) -> bool:
        """Whether fit job ``new`` makes the waiting ``old`` pointless: a later stretch of
        the same push with a closed form to start from (one without starts from the
        earlier phase's fit)."""
        return new is not None and old is not None and new[1] is not None and supersedes(new[0], old[0])

    @staticmethod
    def _replaces(new: tuple[Job, ClosedForm | None, float] | None,
                  old: tuple[Job, ClosedForm | None, float] | None) -> bool:
        """Whether fit job ``new`` makes the waiting interim ``old`` stale."""
        return new is not None and old is not None and old[0].interim and supersedes(new[0], old[0])

    def _failed(self, job: Job, exc: Exception) -> None:
        e = job.event
        where = f"experiment {e.experiment} {e.name}: "
        if isinstance(exc, RecordError):   # the core's messages mostly name the phase already
            self.last_error = f"{where}{str(exc).removeprefix(where)}"
            self.outbox.put(("warn", self.last_error))
        else:   # a fit must never take the node down
            self.last_error = f"{where}fit failed: {type(exc).__name__}: {exc}"
            self.outbox.put(("error", self.last_error))
        self._wake()

    def closed_form_lane(self) -> None:
        while (item := self.closed_jobs.get()) is not None:
            job, arrival = item
            start = time.perf_counter()
            try:
                update, closed = self._in_worker("closed_form", "closed_form", job)
            except RecordError as exc:   # no closed form: the fit starts from the push's last fit
                closed, failure = None, exc
            except Exception as exc:
                self._failed(job, exc)
                continue
            else:
                self._hand_out(update, arrival, (time.perf_counter() - start,
                                                 self.workers["closed_form"].last_compute))
                self.last_error = ""
            if "fit" in self.workers:
                self.fit_jobs.put((job, closed, arrival))
            elif closed is None:
                self._failed(job, failure)
        self.fit_jobs.put(None)

    def fit_lane(self) -> None:
        while (item := self.fit_jobs.get()) is not None:
            job, closed, arrival = item
            try:
                self._hand_out(self.core.fit(job, closed, run=lambda *a: self._in_worker("fit", "fit", *a)),
                               arrival)
            except Exception as exc:
                self._failed(job, exc)
                continue
            e = job.event
            self.last_error = (f"experiment {e.experiment} {e.name}: identified without "
                               f"{', '.join(TOPICS[s] for s in job.stale)} (stale)") if job.stale else ""
            fit = self.core.last_fit(e.experiment)
            if not job.final or fit is None:
                continue
            final = fit   # the push's final model, pooled with the earlier pushes'
            stamp = float(job.record.force_t[-1])
            if self.core.config.diagnose:
                if self.fit_jobs.holds(lambda item: item is not None and item[0].final):
                    # Seconds of work on a push the robot has moved on from, while a newer
                    # push's final estimate waits: that one's diagnosis is the one to have.
                    self.skipped_diagnoses += 1
                    self._hand_out(OnlineDiagnosis.not_run(e.experiment, stamp, "skipped: a newer push's "
                                                           "final estimate was waiting"), arrival)
                else:
                    try:
                        diagnosis = self._in_worker("fit", "diagnose", job, fit)
                        self._hand_out(diagnosis, arrival)
                        final = diagnosis.final or fit
                    except Exception as exc:
                        self._failed(job, exc)
                        # Said on /rheo/diagnosis too: an identify goal waits for it.
                        self._hand_out(OnlineDiagnosis.not_run(e.experiment, stamp, f"the diagnosis failed: {exc}"),
                                       arrival)
            self._hand_out(self.core.pool(e.experiment, stamp, final), arrival)

    def publish_results(self) -> None:
        while not self.outbox.empty():
            item = self.outbox.get()
            if isinstance(item[0], str):
                level, text = item
                if level == "warn":
                    self.get_logger().warning(text)
                else:
                    self.get_logger().error(text)
                continue
            update, arrival, worker = item
            if worker is not None:
                self.latency["closed_form worker"].append(worker[0])
                self.latency["closed_form compute"].append(worker[1])
            if isinstance(update, OnlineDiagnosis):
                self.publish_verdict(update)
                continue
            if isinstance(update, PoolUpdate):
                self.pools.publish(pool_message(self.types, update))
                self.get_logger().info(f"experiment {update.experiment}: {update.message}: "
                                       + ", ".join(f"{n} {v:.4g} +- {s:.2g}" for n, v, s in zip(
                                           update.pool.names, update.pool.values, np.sqrt(np.diag(
                                               update.pool.covariance)))))
                continue
            if update.sensor is not None:
                self.sensor_model = update.sensor
            self.estimates.publish(estimate_message(self.types, update))
            kind = "whole_record" if update.method == "whole_record" else "closed_form"
            self.latency[kind].append(time.perf_counter() - arrival)
            self.updates += 1
            if not update.undetermined:
                self.latest = update
            self.open_params = dict(zip(update.undetermined, update.reasons))
            self.log_update(update)

    def publish_verdict(self, d: OnlineDiagnosis) -> None:
        self.verdicts.publish(diagnosis_message(self.types, d))
        if not d.diagnosed:   # the failure itself is already on /diagnostics (last_error)
            self.get_logger().warning(f"experiment {d.experiment}: {d.evidence}")
            return
        steps = " -> ".join(f"{m} ({r:.3g} N)" for m, r in zip(d.models, d.rmse_force))
        if d.missing_effects or d.undecided or not d.adequate:
            found = f"missing {', '.join(d.missing_effects)}" if d.missing_effects else "no effect found"
            undecided = f"; undecided: {', '.join(d.undecided)}" if d.undecided else ""
            self.verdict = (f"experiment {d.experiment}: the three-element model misfits: {found}{undecided}; "
                            f"force RMS {steps}" + ("" if d.adequate else "; the last model still misfits"))
            self.get_logger().warning(self.verdict)
        else:
            self.verdict = ""
            self.get_logger().info(f"experiment {d.experiment}: three_element adequate (force RMS {steps})")

    def log_update(self, u: Update) -> None:
        std = u.std
        parts = [f"{n} {v:.4g}" + (f" +- {std[n]:.2g}" if n in std and np.isfinite(std[n]) else "")
                 for n, v in zip(u.names, u.values)]
        self.get_logger().info(f"experiment {u.experiment} after {u.phase} ({u.method}): {', '.join(parts)}; "
                               f"force RMS {u.rmse_force:.3g} N" + (f"; not determined: {', '.join(u.undetermined)}"
                                                                    if u.undetermined else ""))

    # -- model overlay -----------------------------------------------------------------

    def _prediction_due(self, stream: str, t: float) -> bool:
        """A prediction for this stamp: once an estimate of the current push exists, at
        most ``PREDICTION_RATE`` per second of stamps (a model evaluation costs ~1 ms)."""
        u = self.latest
        if u is None or u.experiment != self.core.segmenter.experiment or self.core.segmenter.state in ("rest",
                                                                                                          "settled"):
            return False
        if t - self.predicted_at.get(stream, -np.inf) < 1.0 / PREDICTION_RATE - 1e-9:
            return False
        self.predicted_at[stream] = t
        return True

    def publish_force(self, t: float, forces: np.ndarray) -> None:
        self.measured_force.publish(self._wrench(t, float(np.sum(forces))))
        if self._prediction_due("force", t):
            try:
                total, _ = self.core.predict(self.latest, np.array([t]))
                self.predicted_force.publish(self._wrench(t, float(total[0])))
            except ValueError:
                pass

    def publish_markers(self, t: float) -> None:
        if self._prediction_due("markers", t):
            try:
                _, positions = self.core.predict(self.latest, np.array([t]))
                self.predicted_markers.publish(self.encode_markers(int(round(t * 1e9)), positions[0]))
            except ValueError:
                pass

    @staticmethod
    def _wrench(t: float, total: float) -> WrenchStamped:
        msg = WrenchStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 1_000_000_000)
        msg.header.frame_id = "tactile"
        msg.wrench.force.y = total
        return msg

    # -- health ------------------------------------------------------------------------

    def health(self) -> tuple[str, str, dict]:
        """Level, reason and figures for ``/diagnostics``."""
        now = time.monotonic()
        seg = self.core.segmenter
        reasons = []
        arrived = self.silence.arrived
        for stream, topic in TOPICS.items():
            if arrived[stream] is None:
                if now - self.started > self.stale_after and any(arrived.values()):
                    reasons.append(f"no message on {topic}")
            elif now - arrived[stream] > self.stale_after and any(
                    a is not None and now - a < self.stale_after for a in arrived.values()):
                reasons.append(f"{topic} stale: silent for {now - arrived[stream]:.1f} s")
        if self.last_error:
            reasons.append(self.last_error)
        if self.workers["closed_form"].refused:   # asked for, not granted: the latency it was for is not there
            reasons.append(f"closed-form worker: {self.workers['closed_form'].refused}")
        if self.verdict:
            reasons.append(self.verdict)
        if self.open_params:
            reasons.append("not identifiable yet: " + "; ".join(f"{n}: {r}" for n, r in self.open_params.items()))
        if self.fit_jobs.dropped or self.fit_jobs.superseded:
            reasons.append(f"the fit lane fell behind the pushes (it keeps {FIT_BACKLOG} jobs): "
                           f"{self.fit_jobs.superseded} pull/keep fit(s) skipped for their push's later phase, "
                           f"{self.fit_jobs.dropped} older fit(s) skipped")
        if self.skipped_diagnoses:
            reasons.append(f"{self.skipped_diagnoses} diagnosis(es) skipped: a newer push's release fit was waiting")
        if self.core.dropped_pushes:
            reasons.append(f"{self.core.dropped_pushes} push(es) dropped: longer than estimator.max_push_time")
        if self.bad.warning():
            reasons.append(self.bad.warning())
        sensor = self.core.sensor
        if sensor is not None:
            reasons += sensor.warnings
        model = self.sensor_model
        excess = (model["tactile"].get("excess") if model else None) or {}
        figures = {"experiment": seg.experiment, "state": seg.state, "updates": self.updates,
                   **({} if sensor is None else {"sensor": sensor.law, "tactile noise Pa": f"{sensor.tactile.noise:.4g}",
                                                 "marker noise m": f"{sensor.marker_noise:.4g}"}),
                   **{f"tactile excess {k} Pa": "none" if v is None else f"{v:.4g}" for k, v in excess.items()},
                   "interim fits skipped": self.fit_jobs.replaced,
                   **{f"bad {INPUTS[s]}": n for s, n in self.bad.counts.items()},
                   **{f"out of order {TOPICS[s]}": n for s, n in self.core.rejected.items()},
                   **{f"latency {k} {q} ms": f"{1e3 * np.percentile(v, int(q[1:])):.2f}"
                      for k, v in self.latency.items() if v for q in ("p50", "p99")},
                   **{f"latency {k} n": len(v) for k, v in self.latency.items()}}
        if reasons:
            return "WARN", "; ".join(reasons), figures
        return "OK", f"experiment {seg.experiment}: {seg.state}", figures

    def publish_diagnostics(self) -> None:
        self.dispatch(time.perf_counter())
        level, message, figures = self.health()
        self.diagnostics.publish(diagnostic_array(self, level, message, figures))

    def destroy_node(self) -> None:
        if not hasattr(self, "lanes"):      # __init__ failed part way (bad parameters)
            super().destroy_node()
            return
        self.closed_jobs.put(None)
        for worker in self.workers.values():   # a fit may be running: it is stopped, not awaited
            worker.close()
        for lane in self.lanes:
            lane.join(timeout=5.0)
        super().destroy_node()


# s the interpreter lets a thread hold its lock while another waits (Python's default 5 ms):
# a lane's reply from its worker waits for the lock behind message intake, several times
# per hand-off. Measured at 10 x replay with the closed-form worker under SCHED_FIFO (100
# experiments): p99 43 ms at 0.5 ms; at 5 ms 42 and 87 ms in two runs of 40, the worker's
# round trip p99 75 ms against 14 ms of computing.
SWITCH_INTERVAL = 0.0005


def main() -> None:
    sys.setswitchinterval(SWITCH_INTERVAL)
    run_node(EstimatorNode, "Identifies E, c1, c2 (and the Poisson ratio) from the stage, tactile and marker "
                            "topics as each phase completes; publishes /rheo/estimate, /rheo/phase, /diagnostics "
                            "and /rheo/prediction/*.")


if __name__ == "__main__":
    main()
