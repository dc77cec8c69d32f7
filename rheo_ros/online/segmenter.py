"""Online segmentation: contact, pull, keep and release found from the data as it streams.

Each stream is judged on its own samples, in header-stamp order, so the boundaries do
not depend on how messages of different topics interleave on the wire:

- stage depth: the start of a push (``confirm`` samples above the resting level), the
  end of the pull (a flat run of ``plateau`` samples), the end of the keep (``confirm``
  samples below the held level). Boundaries are placed as ``record.segment_stage``
  places them offline: lines through the ramps, to a fraction of a sample.
- tactile total force: contact (``confirm`` frames above the resting baseline).
- marker mesh: the end of release, when the mesh has stopped moving within its noise
  (or the next push starts).

Repeated pushes are separate experiments, numbered from 1. Memory is bounded: the
segmenter keeps the current push's stage samples and a short window of the rest.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from rheo_ros.config.tuning import SegmenterConfig
from rheo_ros.experiment import StageProfile


@dataclass(frozen=True)
class PhaseEvent:
    """A completed phase: ``name`` (contact | pull | keep | release) of push
    ``experiment``, from ``t_start`` to ``t_end`` (s, header stamps), found at the
    sample stamped ``t_found``; ``samples``: stage samples inside (marker frames for
    release)."""

    experiment: int
    name: str
    t_start: float
    t_end: float
    t_found: float
    samples: int


class _Line:
    """Least-squares line ``depth = a + b (t - t0)`` through samples given one by one."""

    def __init__(self, t0: float) -> None:
        self.t0 = t0
        self.n = self.st = self.sd = self.stt = self.std = 0.0

    def add(self, t: float, depth: float) -> None:
        x = t - self.t0
        self.n += 1
        self.st, self.sd, self.stt, self.std = self.st + x, self.sd + depth, self.stt + x * x, self.std + x * depth

    def slope(self) -> float:
        """The line's slope (m/s); 0 with fewer than two distinct times."""
        det = self.n * self.stt - self.st**2
        return (self.n * self.std - self.st * self.sd) / det if self.n >= 2 and det > 0 else 0.0

    def time_at(self, depth: float) -> float:
        b = self.slope()
        return self.t0 + (depth - (self.sd - b * self.st) / self.n) / b


def _median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D array of finite values, to the bit (the middle two's mean),
    without its generic machinery: a baseline is refreshed every few samples of every
    stream, and the wrapper cost four times the partition on a few hundred values."""
    k = x.size // 2
    if x.size == 0:
        return float("nan")
    if x.size % 2:
        return float(np.partition(x, k)[k])
    middle = np.partition(x, (k - 1, k))
    return float((middle[k - 1] + middle[k]) / 2)


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope and intercept of y on x (slope 0 where x does not vary):
    ``np.polyfit(x, y, 1)``'s line to rounding, without its SVD, run every few samples."""
    xm, ym = x.mean(), y.mean()
    xc = x - xm
    sxx = float(xc @ xc)
    slope = float(xc @ (y - ym)) / sxx if sxx > 0 else 0.0
    return slope, float(ym - slope * xm)


def _robust_spread(x: np.ndarray) -> float:
    """Standard deviation from the median absolute deviation (outliers ignored)."""
    return 1.4826 * _median(np.abs(x - _median(x))) if x.size else 0.0


class PhaseSegmenter:
    """Feed samples with ``add_stage``, ``add_force`` and ``add_markers`` (each stream in
    stamp order; late or repeated stamps are dropped and counted in ``dropped``); each
    call returns the phases it completed."""

    REST = 200          # resting samples kept for the baseline and its noise
    HELD = 1000         # held samples used for the level and its noise
    MIN_REST = 10       # resting tactile frames before contact can be judged
    REFRESH = 10        # samples between refreshes of a baseline's median and spread
    MAX_FRAMES = 20000  # marker frames kept at most (memory bound when the stage stream stops)

    def __init__(self, config: SegmenterConfig | None = None) -> None:
        self.config = config or SegmenterConfig()
        self.experiment = 0
        # The pushes done on the specimen: the next push's profile carries them (``before``),
        # so its model starts from where they left the specimen.
        self.history: tuple[StageProfile, ...] = ()
        self.state = "rest"                 # rest | pull | keep | release | settled
        self._settled_at = -np.inf
        self.dropped = {"stage": 0, "force": 0, "markers": 0}
        self._last = {"stage": -np.inf, "force": -np.inf, "markers": -np.inf}
        self._rest: deque[float] = deque(maxlen=self.REST)
        self._rest_seen = 0
        self._rest_cache: tuple[int, float, float] | None = None
        self._held_cache: tuple[int, float, float] | None = None
        self._force_cache: tuple[int, float, float, float, float] | None = None
        self._force_seen = 0
        self._run: list[tuple[float, float]] = []     # samples confirming a change
        self._ramp: list[tuple[float, float]] = []    # this push's pull samples
        self._held: deque[float] = deque(maxlen=self.HELD)
        self._held_count = 0
        self.profile: StageProfile | None = None      # the current push, once its pull is known
        self._t_pull: tuple[float, float] | None = None
        self._t_release: float | None = None
        self._level = 0.0
        # contact (force stream)
        self._force_rest: deque[tuple[float, float]] = deque(maxlen=self.REST)
        self._force_run: list[float] = []
        self._in_contact = False
        self.contacts = 0
        # release end (marker stream)
        self._frames: deque[tuple[float, np.ndarray]] = deque(maxlen=self.MAX_FRAMES)
        self._lo: np.ndarray | None = None            # range of each marker coordinate this push
        self._hi: np.ndarray | None = None
        self._pending_release: float | None = None   # release start not yet judged on markers
        self._release_frames = 0                      # marker frames after the release's start
        self._judged = -np.inf
        self._unjudged: deque[float] = deque(maxlen=self.MAX_FRAMES)   # a release's frames not judged yet
        self.release_reason = ""

    # -- stage -------------------------------------------------------------------------

    def _in_order(self, stream: str, t: float) -> bool:
        if not t > self._last[stream]:
            self.dropped[stream] += 1
            return False
        self._last[stream] = t
        return True

    def add_stage(self, t: float, depth: float) -> list[PhaseEvent]:
        if not (self._in_order("stage", t) and math.isfinite(depth)):
            return []
        if self.state == "settled":
            # The mesh settled (marker stream) at a stamp the stage stream has not
            # reached yet: until then the stage is still in that release.
            if t <= self._settled_at:
                self._release_rest.append(depth)
                return []
            self.state = "rest"
            self._rest.clear()
            self._rest.extend(self._release_rest)
            self._rest_cache = None
        handler = {"rest": self._stage_rest, "pull": self._stage_pull, "keep": self._stage_keep,
                   "release": self._stage_release}[self.state]
        return handler(t, depth)

    def _rest_tolerance(self) -> tuple[float, float]:
        # Medians cost more than the rest of a sample's work: refreshed every
        # REFRESH resting samples (a count of this stream's samples: deterministic).
        if self._rest_cache is None or self._rest_seen - self._rest_cache[0] >= self.REFRESH:
            rest = np.fromiter(self._rest, float)
            base = _median(rest) if rest.size else 0.0
            self._rest_cache = (self._rest_seen, base, max(6.0 * _robust_spread(rest), 0.05 * self.config.min_depth))
        return self._rest_cache[1], self._rest_cache[2]

    def _stage_rest(self, t: float, depth: float) -> list[PhaseEvent]:
        base, tol = self._rest_tolerance()
        if depth > base + tol:
            self._run.append((t, depth))
            if len(self._run) >= self.config.confirm:
                self.state, self._ramp, self._run = "pull", list(self._run), []
                self._sums, self._summed = np.zeros(5), 0
                self.experiment += 1
                self._base = base
            return []
        self._rest.extend(d for _, d in self._run)
        self._rest_seen += len(self._run) + 1
        self._run = []
        self._rest.append(depth)
        return []

    def _stage_pull(self, t: float, depth: float) -> list[PhaseEvent]:
        self._ramp.append((t, depth))
        n = self.config.plateau
        if len(self._ramp) < n + self.config.confirm:
            return []
        # The ramp's velocity from running sums over the samples before the last n
        # (a line fit per sample would cost O(pull) each).
        t_ref = self._ramp[0][0]
        while self._summed < len(self._ramp) - n:
            tr, dr = self._ramp[self._summed]
            tr -= t_ref
            self._sums += (1.0, tr, dr, tr * tr, tr * dr)
            self._summed += 1
        k, st, sd, stt, std = self._sums
        if k < 2 or stt * k - st * st <= 0:
            return []
        velocity = (k * std - st * sd) / (k * stt - st * st)
        tt, dd = np.array(self._ramp[-n:]).T
        slope = _line(tt - tt[0], dd)[0]
        if not (velocity > 0 and abs(slope) < self.config.flat_slope * velocity):
            return []
        level = _median(dd)
        if level - self._base < self.config.min_depth:      # a twitch, not a push
            self.state, self.experiment = "rest", self.experiment - 1
            self._rest.extend(dd.tolist())
            return []
        t_all, d_all = np.array(self._ramp).T
        inside = (d_all > 0.05 * level) & (d_all < 0.95 * level)
        if inside.sum() < 2:
            inside = t_all < tt[0]          # a ramp of a few samples: every one before the plateau
        v, icept = np.polyfit(t_all[inside], d_all[inside], 1)
        t_start, t_end = -icept / v, (level - icept) / v
        self._level = level
        self._held.clear()
        self._held.extend(dd.tolist())
        self._held_count, self._held_cache = n, None
        self._last_held_t = float(tt[-1])
        self._t_pull = (t_start, t_end)
        self.profile = StageProfile(depth=level, velocity=float(v), keep_time=1e9, start_delay=float(t_start),
                                    release_time=0.0, before=self.history)
        self.state = "keep"
        inside_pull = int(np.sum((t_all >= t_start) & (t_all <= t_end)))
        return [PhaseEvent(self.experiment, "pull", float(t_start), float(t_end), t, inside_pull)]

    def _held_tolerance(self) -> tuple[float, float]:
        if self._held_cache is None or self._held_count - self._held_cache[0] >= self.REFRESH:
            held = np.fromiter(self._held, float)
            level = _median(held)
            self._held_cache = (self._held_count, level, max(1e-3 * level, 6.0 * _robust_spread(held)))
        return self._held_cache[1], self._held_cache[2]

    def _stage_keep(self, t: float, depth: float) -> list[PhaseEvent]:
        level, tol = self._held_tolerance()
        if depth >= level - tol:
            self._held.extend(d for _, d in self._run)
            self._held_count += len(self._run) + 1
            self._run = []
            self._held.append(depth)
            self._last_held_t = t
            return []
        self._run.append((t, depth))
        if len(self._run) < self.config.confirm:
            return []
        rt, rd = np.array(self._run).T
        t_leave, retract_speed = float(rt[0]), float("inf")
        on_ramp = (rd > 0.05 * level) & (rd < level - tol)
        self._retraction = _Line(float(rt[0]))
        for tr, dr in zip(rt[on_ramp], rd[on_ramp]):
            self._retraction.add(tr, dr)
        t_pull_end = self._t_pull[1]
        if (slope := self._retraction.slope()) < 0:
            # One line through the retraction: where it leaves the level (a slow one takes
            # several samples to leave the tolerance band), and its speed.
            t_leave = float(np.clip(self._retraction.time_at(level), t_pull_end, rt[0]))
            retract_speed = -slope
        self._retraction_band = (0.05 * level, level - tol)
        self._level = level
        self.profile = replace(self.profile, depth=level, keep_time=max(t_leave - t_pull_end, 0.0),
                               release_time=0.0, retract_speed=retract_speed)
        self._t_release = t_leave
        self._pending_release = t_leave
        # Frames are trimmed once judged: count them here (those already in, then each new one).
        self._release_frames = sum(1 for tf, _ in self._frames if tf > t_leave)
        self.state, self._run = "release", []
        self._release_min = float(rd.min())
        self._release_rest: deque[float] = deque(maxlen=self.REST)
        self._release_seen, self._release_cache = 0, None
        self._judged = t_leave
        self._unjudged = deque((tf for tf, _ in self._frames if tf > t_leave), maxlen=self.MAX_FRAMES)
        events = [PhaseEvent(self.experiment, "keep", t_pull_end, t_leave, t, self._held_count)]
        return events + self._judge_settled()

    def _release_level(self) -> float:
        """The depth over which a stage sample after the release starts a new push: the
        resting samples' median plus six spreads (refreshed every REFRESH, as at rest)."""
        if self._release_cache is None or self._release_seen - self._release_cache[0] >= self.REFRESH:
            rest = np.fromiter(self._release_rest, float)
            level = _median(rest) + max(6.0 * _robust_spread(rest), 0.05 * self.config.min_depth)
            self._release_cache = (self._release_seen, level)
        return self._release_cache[1]

    def _stage_release(self, t: float, depth: float) -> list[PhaseEvent]:
        # The stage is back near rest once it is below 5 % of the push; a new push is
        # a confirmed rise from there.
        self._release_min = min(self._release_min, depth)
        if self._retraction_band[0] < depth < self._retraction_band[1]:
            self._retraction.add(t, depth)   # the retraction's speed from all of its samples (at release end)
        if self._release_min > 0.05 * self._level:
            return []
        if len(self._release_rest) >= 3 and depth > self._release_level():
            self._run.append((t, depth))
            if len(self._run) >= self.config.confirm:
                # The next push started before the mesh settled: the release ends here.
                run, t_next = self._run, self._run[0][0]
                events = self._end_release(self._last_frame_before(t_next), t, "next push")
                self._rest.clear()
                self._rest.extend(self._release_rest)
                for tr, dr in run:
                    events += self._stage_rest(tr, dr)
                return events
            return []
        self._release_rest.extend(d for _, d in self._run)
        self._release_seen += len(self._run) + 1
        self._run = []
        self._release_rest.append(depth)
        # Marker frames wait for the stage to pass them (``_judge_settled``): judge them now.
        return self._judge_settled() if self._pending_release is not None else []

    # -- tactile ------------------------------------------------------------------------

    def add_force(self, t: float, total: float) -> list[PhaseEvent]:
        """Total bottom force (N) of a tactile frame."""
        if not (self._in_order("force", t) and math.isfinite(total)):
            return []
        if len(self._force_rest) < self.MIN_REST and not self._in_contact:
            self._force_rest.append((t, total))    # no baseline yet: nothing to compare with
            return []
        # The resting baseline may drift (sensor_drift): a line through it, not a level;
        # refreshed every REFRESH resting frames.
        if self._force_cache is None or self._force_seen - self._force_cache[0] >= self.REFRESH:
            rt, rf = np.array(self._force_rest).T
            slope, icept = _line(rt - rt[-1], rf)
            spread = _robust_spread(rf - (icept + slope * (rt - rt[-1])))
            self._force_cache = (self._force_seen, float(rt[-1]), float(slope), float(icept), spread)
        _, t_ref, slope, icept, spread = self._force_cache
        base = icept + slope * (t - t_ref)
        threshold = base + max(self.config.contact_force, 6.0 * spread)
        if not self._in_contact:
            if total > threshold:
                self._force_run.append(t)
                if len(self._force_run) >= self.config.confirm:
                    self._in_contact, self.contacts = True, self.contacts + 1
                    t0, self._force_run = self._force_run[0], []
                    return [PhaseEvent(self.contacts, "contact", t0, t0, t, 0)]
                return []
            self._force_run = []
            self._force_rest.append((t, total))
            self._force_seen += 1
        elif total <= threshold:
            self._force_run.append(t)
            if len(self._force_run) >= self.config.confirm:
                self._in_contact, self._force_run = False, []
        else:
            self._force_run = []
        return []

    # -- markers ------------------------------------------------------------------------

    def add_markers(self, t: float, positions: np.ndarray) -> list[PhaseEvent]:
        positions = np.asarray(positions, float).ravel()
        if not (self._in_order("markers", t) and np.all(np.isfinite(positions))):
            return []
        self._frames.append((t, positions))
        if self._pending_release is not None and t > self._pending_release:
            self._release_frames += 1
            self._unjudged.append(t)
        if self._lo is None or self._lo.shape != positions.shape:
            self._lo, self._hi = positions.copy(), positions.copy()
        np.minimum(self._lo, positions, out=self._lo)
        np.maximum(self._hi, positions, out=self._hi)
        if self.state == "release" and self._pending_release is not None:
            return self._judge_settled()
        # Frames are kept until the stage stream has passed them by a window: the stage
        # decides when a release starts, and it may run far behind this stream (a
        # backlog); every frame after a release must still be judged.
        self._trim(min(t, self._last["stage"]) - self.config.settle_window)
        return []

    def _trim(self, t_keep: float) -> None:
        while self._frames and self._frames[0][0] < t_keep:
            self._frames.popleft()

    def _last_frame_before(self, t: float) -> float:
        before = [tf for tf, _ in self._frames if tf < t]
        return before[-1] if before else (self._t_release if self._t_release is not None else t)

    def _judge_settled(self, until: float | None = None) -> list[PhaseEvent]:
        """Release ends at the first frame whose window (``settle_window`` s back, all
        after the stage left) shows the mesh still within its noise. Every frame is
        judged in stamp order, however the streams interleave, and only once the stage
        stream has passed it (``until``, default its last stamp): a frame the stage has not
        reached may already belong to the next push (markers ahead of a lagging stage)."""
        W, t_release = self.config.settle_window, self._pending_release
        until = self._last["stage"] if until is None else until
        while self._unjudged and self._unjudged[0] <= self._judged:
            self._unjudged.popleft()
        if not self._unjudged or self._unjudged[0] > until:
            return []   # called at every stage sample: nothing new to judge is the common case
        frames = list(self._frames)
        times = np.array([tf for tf, _ in frames])
        peak = float(np.max(self._hi - self._lo)) if self._lo is not None else 0.0
        for j in np.flatnonzero((times > self._judged) & (times <= until)):
            t_now = float(times[j])
            self._judged = t_now
            if t_now - t_release > self.config.max_release:
                return self._end_release(t_now, t_now, f"still moving after {self.config.max_release:g} s")
            if t_now - W < t_release:
                continue
            inside = (times >= t_now - W - 1e-9) & (times <= t_now)
            if inside.sum() < 6:
                continue
            tw = times[inside]
            X = np.array([frames[i][1] for i in np.flatnonzero(inside)])
            tc = tw - tw.mean()
            sxx = float(tc @ tc)
            Xc = X - X.mean(axis=0)
            slope = tc @ Xc / sxx
            resid = Xc - np.outer(tc, slope)
            sigma = float(np.sqrt(np.sum(resid**2) / ((tw.size - 2) * X.shape[1])))
            span = float(tw[-1] - tw[0])
            motion = float(np.sqrt(np.mean(slope**2))) * span
            noise_motion = sigma / np.sqrt(sxx) * span
            if motion < max(2.0 * noise_motion, self.config.settle_fraction * peak):
                return self._end_release(t_now, t_now, "settled")
        self._trim(self._judged - W - 1e-6)
        return []

    @property
    def release_began(self) -> float:
        """Stamp (s) where the open release began; inf when none is open."""
        if self.state != "release" or self._t_release is None:
            return np.inf
        return self._t_release

    def judge_ahead_of_stage(self) -> list[PhaseEvent]:
        """Judge every marker frame of an open release, also those the stage stream has not
        reached (it stopped): the release's end if the mesh settled; nothing otherwise."""
        if self.state != "release" or self._pending_release is None:
            return []
        return self._judge_settled(until=np.inf)

    def close_release(self, why: str) -> list[PhaseEvent]:
        """End a release still open at the last marker frame (the data stopped: at the end
        of a bag, or when every topic went silent); nothing when no release is open."""
        if self.state != "release" or self._pending_release is None:
            return []
        settled = self.judge_ahead_of_stage()   # frames the stage stream never passed
        if settled:
            return settled
        t_end = self._frames[-1][0] if self._frames else self._t_release
        # Found at the latest sample heard on any topic: a recording replays the close
        # after exactly those samples (io.bag.release_cuts).
        return self._end_release(max(t_end, self._t_release), max(t_end, *self._last.values()), why)

    def _end_release(self, t_end: float, t_found: float, why: str) -> list[PhaseEvent]:
        t_release = self._t_release
        n = self._release_frames - sum(1 for tf, _ in self._frames if tf > t_end)
        slope = self._retraction.slope()
        self.profile = replace(self.profile, release_time=max(t_end - t_release, 0.0),
                               retract_speed=-slope if slope < 0 else self.profile.retract_speed)
        self.release_reason = why
        self.history = (*self.history, replace(self.profile, before=()))
        # The stage stream goes back to rest once it passes the release's end.
        self.state, self._settled_at = ("settled", t_end) if why != "next push" else ("rest", t_end)
        self._pending_release, self._t_pull, self._run = None, None, []
        self._unjudged.clear()
        last = self._frames[-1][1] if self._frames else None
        self._lo = None if last is None else last.copy()
        self._hi = None if last is None else last.copy()
        return [PhaseEvent(self.experiment, "release", t_release, t_end, t_found, n)]
