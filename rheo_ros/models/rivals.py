"""Effects in no catalogue that the diagnosis holds the catalogue's answer up against.

A catalogue effect can fit data it did not make within the noise: a tactile array's own
lag reads as a Maxwell arm (alone, or beside a drift or a fading adhesion), a material
that softens with the largest strain it has seen reads as a settling drift under a dead
band (stop 68: 9 of 90 out-of-catalogue generator bags named so, each fitting within the
noise). The named model's residuals cannot tell; only a better alternative can (stop
70, docs/bench/outside-truth-stop70: the true effect beat the named one by 18-191 in BIC
in each). These are such alternatives, of kinds a lab meets and the catalogue lacks: a
sensor with memory (one that lags, one with play) and a material with memory. They are
never named missing: where one fits the data decisively better than the effects found,
the catalogue does not explain the data, and the rival describes what the missing effect
looks like (``diagnosis.discover.rivals``).

They are ``Effect`` subclasses like any other, fitted by the same machinery, but not
registered: a user's registered effect of the same kind competes in the catalogue
instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from rheo_ros.models.effects import Effect, FitContext, Release, segment_shares

# A lag's recursion is solved in closed form over stretches of at most this many of its
# times (e^-30: below float64's resolution of the carried value).
_LAG_STRETCH = 30.0


def first_order_lag(t: np.ndarray, x: np.ndarray, time: float) -> np.ndarray:
    """``x`` (T, ...) at times ``t`` (s, increasing) through a first-order lag of ``time``
    (s), at rest at ``x[0]`` before the record: dy/dt = (x - y) / time, exact for ``x``
    linear between samples, so the same on any grid. The recursion y_i = k_i y_(i-1) + s_i
    is summed in closed form (cumulative sums scaled by e^(t / time)) over stretches short
    enough not to overflow: vectorised, any record length."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    y = np.empty_like(x)
    if t.size == 0:
        return y
    y[0] = x[0]
    if t.size == 1:
        return y
    h = np.maximum(np.diff(t), 1e-12).reshape((-1,) + (1,) * (x.ndim - 1))
    k = np.exp(-h / time)
    step = x[1:] - k * x[:-1] - np.diff(x, axis=0) * time / h * (1 - k)   # s_i
    a = (t - t[0]) / time
    start = 0
    while start < t.size - 1:
        stop = int(np.searchsorted(a, a[start] + _LAG_STRETCH, side="right"))
        stop = max(stop, start + 2)   # at least one step
        rel = (a[start + 1:stop] - a[start]).reshape((-1,) + (1,) * (x.ndim - 1))
        grown = np.cumsum(step[start:stop - 1] * np.exp(rel), axis=0)
        y[start + 1:stop] = np.exp(-rel) * (y[start] + grown)
        start = stop - 1
    return y


def play(x: np.ndarray, width: float | np.ndarray, start: float = 0.0) -> np.ndarray:
    """``x`` (T, ...) through a play (backlash) of half-width ``width`` (broadcast over the
    columns), reading ``start`` before the first sample: y_i = clip(y_(i-1), x_i - width,
    x_i + width). A reading follows the input only once it has moved ``width`` past it:
    ``width`` under on loading, over on unloading; rate-independent. The recursion is a
    chain of clamps, and clamps compose into a clamp (clip(clip(y, L, H), a, b) =
    clip(y, clip(L, a, b), clip(H, a, b))), so each prefix of the chain is found by a
    doubling scan: log2(T) vectorised passes, exact (clip only selects)."""
    x = np.asarray(x, float)
    lo, hi = x - width, x + width
    shift = 1
    while shift < x.shape[0]:
        # The chain up to i-shift, then the one from there to i: its clamp clips both ends.
        # (maximum then minimum: clip's own checks cost twice as much here.)
        later_lo, later_hi = lo[shift:], hi[shift:]
        new_lo = np.minimum(np.maximum(lo[:-shift], later_lo), later_hi)
        new_hi = np.minimum(np.maximum(hi[:-shift], later_lo), later_hi)
        later_lo[...], later_hi[...] = new_lo, new_hi
        shift *= 2
    return np.minimum(np.maximum(start, lo), hi)


@dataclass(frozen=True)
class LaggingReading(Effect):
    """A share of each tactile reading lags the force through a first-order lag (a
    foam pad's creep, a charge amplifier's time constant): reading = (1 - share) force
    + share lag(force, time). In the force alone; the markers see the specimen as it is."""

    id: ClassVar[str] = "lagging_reading"
    shows_in: ClassVar[tuple[str, ...]] = ("pull", "keep", "release")
    resolving_experiment: ClassVar[str] = "a step of the stage held against a rigid block (the sensor alone)"
    time: float = 1.0
    share: float = 0.1

    @property
    def memory(self) -> float:
        return math.inf

    @property
    def times(self) -> dict[str, float]:
        return {"lag time": self.time}

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        # From a fraction of a second to a tenth of the keep: a lag seen in every phase.
        keep = max(context.profile.keep_time, 1.0)
        return tuple(cls(time, 0.1) for time in (0.5, max(0.1 * keep, 1.0)))

    def describe(self) -> str:
        return f"{self.share:.3g} of each tactile reading lagging the force by a first-order lag of {self.time:.3g} s"

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        return (1 - self.share) * force + self.share * first_order_lag(t, force, self.time)


@dataclass(frozen=True)
class StrainSoftening(Effect):
    """The stress falls with the largest strain the specimen has seen (damage,
    Mullins-like softening): stress / (1 + softening x max nominal strain so far). It
    shows as a pull that bends down and a keep and release that stay soft."""

    id: ClassVar[str] = "strain_softening"
    shows_in: ClassVar[tuple[str, ...]] = ("pull", "keep")
    resolving_experiment: ClassVar[str] = "a second push to the same depth"
    softening: float = 1.0

    @property
    def memory(self) -> float:
        return math.inf

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        return (cls(1.0),)

    def describe(self) -> str:
        return f"a stress that softens with the largest strain seen: / (1 + {self.softening:.3g} x max strain)"

    def stress_scale(self, strain: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + self.softening * np.maximum.accumulate(np.maximum(strain, 0.0)))


@dataclass(frozen=True)
class SensorPlay(Effect):
    """Each tactile segment reads through a play (backlash, rate-independent hysteresis)
    of half-width ``width`` (N per average segment, each segment's in proportion to its
    cells: ``shares``): a foam or a mechanism that must be pushed ``width`` past its
    reading before it follows. On loading it reads ``width`` under, on unloading
    ``width`` over, and after the release ``width`` stays read. In the force alone."""

    id: ClassVar[str] = "sensor_play"
    shows_in: ClassVar[tuple[str, ...]] = ("pull", "keep", "release")
    resolving_experiment: ClassVar[str] = "a load stepped up and down on the array (the sensor alone)"
    width: float = 0.01
    shares: tuple[float, ...] | None = field(default=None, metadata={"parameter": False})

    @property
    def memory(self) -> float:
        return math.inf

    @classmethod
    def starts(cls, context: FitContext) -> tuple[Effect, ...]:
        # What stays read after the release is the width itself; or a hundredth of the peak.
        after = (context.force_t > context.profile.t_keep_end)[:, None] & context.live
        level = float(np.mean(context.residual[after])) if after.sum() >= 10 else 0.0
        widths = [level] if level > 1e-6 * context.peak_force else []
        return tuple(cls(w, context.cell_shares) for w in (*widths, max(0.01 * context.peak_force, 1e-9)))

    def describe(self) -> str:
        return (f"each tactile segment reading through a play (hysteresis) of half-width {self.width:.3g} N: "
                "under on loading, over on unloading, held after the release")

    def measured_force(self, t: np.ndarray, force: np.ndarray, release: Release | None) -> np.ndarray:
        return play(force, self.width * segment_shares(self.shares, np.shape(force)[1])[None])


# Every rival the diagnosis fits, in the order it reports them.
RIVALS: tuple[type[Effect], ...] = (LaggingReading, StrainSoftening, SensorPlay)
