"""Where the stage's motion comes from, behind one small interface.

The stage node asks its ``MotionSource`` for the depth at each tick and publishes
it. The default source replays a ``StageProfile`` (the simulated stage); a real
stage driver implements the same two methods, commanding the hardware and
reporting its measured position, and is registered under the entry-point group
``rheo_ros.stage_drivers``.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Protocol

import numpy as np

from rheo_ros.experiment import StageProfile


@dataclass(frozen=True)
class StageSample:
    depth: float      # m, positive into the specimen
    velocity: float   # m/s
    phase: str        # wait | pull | keep | release | done


class MotionSource(Protocol):
    def sample(self, t: float) -> StageSample:
        """Depth and velocity at ``t`` s after the run started (the first call is t = 0)."""

    def abort(self, t: float) -> None:
        """Leave the specimen now: retract to depth 0 from wherever the stage is, at a
        safe speed (a cancelled identification, a node shutting down mid-run)."""

    def close(self) -> None:
        """Stop the stage (end of run, or node shutdown)."""


class SimulatedStage:
    """The profile played back: no hardware."""

    # Retraction speed of an abort when the profile lets go at once (m/s).
    SAFE_RETRACT = 0.005

    def __init__(self, profile: StageProfile) -> None:
        self.profile = profile
        self._abort: tuple[float, float, float] | None = None   # (t, depth then, speed)

    def abort(self, t: float) -> None:
        if self._abort is None:
            speed = self.profile.retract_speed if np.isfinite(self.profile.retract_speed) else self.SAFE_RETRACT
            self._abort = (t, float(self.profile.depth_at(t)), speed)

    def phase(self, t: float) -> str:
        if self._abort is not None:
            t0, d0, speed = self._abort
            return "release" if d0 - speed * (t - t0) > 0 else "done"
        p = self.profile
        if t < p.t_pull_start:
            return "wait"
        if t < p.t_pull_end:
            return "pull"
        if t < p.t_keep_end:
            return "keep"
        return "release" if t < p.t_end else "done"

    def sample(self, t: float) -> StageSample:
        if self._abort is not None:
            t0, d0, speed = self._abort
            depth = max(d0 - speed * (t - t0), 0.0)
            return StageSample(depth, -speed if depth > 0 else 0.0, self.phase(t))
        return StageSample(float(self.profile.depth_at(t)), float(self.profile.velocity_at(t)), self.phase(t))

    def close(self) -> None:
        pass


def motion_source(driver: str, profile: StageProfile) -> MotionSource:
    """The motion source named ``driver``: ``simulated`` or a registered driver."""
    if driver == "simulated":
        return SimulatedStage(profile)
    for ep in entry_points(group="rheo_ros.stage_drivers"):
        if ep.name == driver:
            return ep.load()(profile)
    raise KeyError(f"stage driver {driver!r} not found (have: simulated)")
