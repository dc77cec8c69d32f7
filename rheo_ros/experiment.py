"""The pushing experiment: the stage's motion profile and its phases (pull, keep, release)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

# The phases of a push, in order, and every stretch of a record: "before" is before the
# stage touches the specimen. One vocabulary for the segmenter, the fits, the comparison,
# the effects' footprints and the reports.
PUSH_PHASES = ("pull", "keep", "release")
PHASES = ("before", *PUSH_PHASES)
# What a robot may say of the object a push meets (an identify goal's ``object``):
# another object, the one pushed before, or nothing (the data decide).
OBJECT_HINTS = ("new", "same", "")


def check_object_hint(kind: str) -> str:
    """``kind`` if it is one of ``OBJECT_HINTS``.

    Raises:
        ValueError: another word (the message names the field)."""
    if kind not in OBJECT_HINTS:
        raise ValueError(f"object: {kind!r} is none of new, same or empty (the data decide)")
    return kind


@dataclass(frozen=True)
class Phase:
    name: str
    t_start: float
    t_end: float


@dataclass(frozen=True)
class StageProfile:
    """Stage motion: push ``depth`` (m) at ``velocity`` (m/s), hold ``keep_time`` (s),
    then retract at ``retract_speed`` (m/s; ``inf``: the stage leaves at once);
    ``start_delay`` before contact and ``release_time`` recorded after release (s).

    The defaults are the paper's idealised experiment, instant release included (the
    benches' and tests' noise-free cases rely on it). The package's default experiment
    is the parameters table's ``stage.*`` (``rheo_ros.config.table``, a layer above):
    the same but ``stage.retract_speed`` 0.02 m/s, a stage that can really move
    (``test_config_table.py`` holds the two together).

    ``before``: the earlier pushes on the same specimen (single pushes, in order, on the
    same clock, each done before the next begins). The specimen remembers them (a
    permanent set, a recovery still under way), so the stage's history is theirs and
    then this push's: ``depth_at``, ``velocity_at`` and ``knots`` cover it all, the
    phases are this push's. Depth 0 is where the stage first met the specimen
    (the contract's ``/stage/joint_states``), for every push."""

    depth: float = 0.010
    velocity: float = 0.0005
    keep_time: float = 48.0
    start_delay: float = 1.0
    release_time: float = 100.0
    retract_speed: float = np.inf
    before: tuple[StageProfile, ...] = ()

    def __post_init__(self) -> None:
        if min(self.depth, self.velocity, self.retract_speed) <= 0 or min(self.keep_time, self.release_time) < 0:
            raise ValueError("stage profile: depth and speeds must be positive, times non-negative")
        starts = [p.t_pull_start for p in self.before] + [self.t_pull_start]
        if any(p.before for p in self.before) or np.any(np.diff(starts) <= 0):
            raise ValueError("stage profile: earlier pushes must be single pushes, each starting after the last")

    @classmethod
    def repeated(cls, push: StageProfile, pushes: int, pause: float = 0.0) -> StageProfile:
        """The last of ``pushes`` pushes like ``push``, each starting ``pause`` s after the
        last one's ``release_time``, the earlier ones in its ``before``."""
        if pushes < 1 or pause < 0:
            raise ValueError("stage profile: at least one push, and a non-negative pause")
        period = push.t_end - push.t_pull_start + pause
        single = [replace(push, before=(), start_delay=push.start_delay + k * period) for k in range(pushes)]
        return replace(single[-1], before=tuple(single[:-1]))

    @property
    def pushes(self) -> tuple[StageProfile, ...]:
        """Every push on the specimen, this one last, each on its own."""
        return (*self.before, replace(self, before=()))

    @classmethod
    def from_times(cls, depth: float, pull_time: float, keep_time: float, **kw: float) -> StageProfile:
        return cls(depth=depth, velocity=depth / pull_time, keep_time=keep_time, **kw)

    @property
    def pull_time(self) -> float:
        return self.depth / self.velocity

    @property
    def t_pull_start(self) -> float:
        return self.start_delay

    @property
    def t_pull_end(self) -> float:
        return self.start_delay + self.pull_time

    @property
    def t_keep_end(self) -> float:
        return self.t_pull_end + self.keep_time

    @property
    def t_end(self) -> float:
        return self.t_keep_end + self.release_time

    @property
    def phases(self) -> tuple[Phase, Phase, Phase]:
        return (
            Phase("pull", self.t_pull_start, self.t_pull_end),
            Phase("keep", self.t_pull_end, self.t_keep_end),
            Phase("release", self.t_keep_end, self.t_end),
        )

    def depth_at(self, t: np.ndarray) -> np.ndarray:
        """Commanded stage depth (m, positive into the specimen; back to 0 on release),
        the earlier pushes' before this one's."""
        return self._by_push(t, StageProfile._push_depth)

    def velocity_at(self, t: np.ndarray) -> np.ndarray:
        """Commanded stage velocity (m/s, positive pushing)."""
        return self._by_push(t, StageProfile._push_velocity)

    def _by_push(self, t: np.ndarray, of_push) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        out = of_push(self, t)
        if self.before:
            pushes = self.pushes
            which = np.searchsorted([p.t_pull_start for p in pushes], t, side="right") - 1
            for k, push in enumerate(pushes[:-1]):
                out = np.where(which == k, of_push(push, t), out)
        return out

    def _push_depth(self, t: np.ndarray) -> np.ndarray:
        d = np.clip((t - self.t_pull_start) * self.velocity, 0.0, self.depth)
        with np.errstate(invalid="ignore"):
            back = np.maximum(self.depth - self.retract_speed * (t - self.t_keep_end), 0.0)
        return np.where(t >= self.t_keep_end, np.nan_to_num(back), d)

    def _push_velocity(self, t: np.ndarray) -> np.ndarray:
        v = np.where((t >= self.t_pull_start) & (t < self.t_pull_end), self.velocity, 0.0)
        retracting = (t >= self.t_keep_end) & (t < self.t_keep_end + self.depth / self.retract_speed)
        return np.where(retracting, -self.retract_speed, v)

    @property
    def t_retracted(self) -> float:
        """When the stage is back at depth 0 (s): from then on nothing presses the specimen."""
        return self.t_keep_end + self.depth / self.retract_speed

    def knots(self) -> list[tuple[float, float]]:
        """Breakpoints ``(t, depth)`` of the piecewise-linear stage motion, every push's;
        an instant release appears as two knots at the same time."""
        return [knot for p in self.pushes for knot in
                ((p.t_pull_start, 0.0), (p.t_pull_end, p.depth), (p.t_keep_end, p.depth), (p.t_retracted, 0.0))]


def sample_times(t_end: float, rate: float) -> np.ndarray:
    """Sample times 0, 1/rate, ... up to ``t_end`` inclusive (s)."""
    n = int(np.floor(t_end * rate + 1e-9))
    return np.arange(n + 1) / rate


def phase_of(t: np.ndarray, profile: StageProfile) -> np.ndarray:
    """Index into ``PHASES`` of each time ``t`` (s)."""
    edges = [profile.t_pull_start, profile.t_pull_end, profile.t_keep_end]
    return np.searchsorted(edges, np.asarray(t), side="right")
