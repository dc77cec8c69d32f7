"""The sensor noise the data show, independent of any model: each signal's second
differences (``sensors.difference_noise``). Tactile readings count only where they are
live (above the dead band, ``DeadBand``): the dead band's exact zeros would claim a
noise-free sensor.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np

from rheo_ros.record import Record
from rheo_ros.sensors import column_difference_noise, difference_noise, marker_noise

__all__ = ["SensorNoise", "Weights", "despiked", "difference_noise", "force_noise", "isolated_spikes",
           "sensor_noise", "spikes_note"]

# A reading is live when the running median of its segment's readings over this many frames
# is above the live threshold, not the reading itself: chosen by its own noise, the readings
# kept near the threshold would be those the noise lifted (a drift settling through the
# threshold of a sensor with no dead band came out 46 s against 60).
LIVE_WINDOW = 25
SPIKE_SIGMAS = 8.0    # a reading this many noise stds off the midpoint of its two neighbours ...
SPIKE_SHARE = 0.005   # ... and this share of its segment's peak (a noise-free record), is a glitch


@dataclass(frozen=True)
class Weights:
    """The noise a fit weights its residuals by: per tactile segment (N) and per marker
    coordinate (m). ``None`` for a fit that estimates them from its own residuals."""

    force_std: np.ndarray
    marker_std: float


@dataclass(frozen=True)
class SensorNoise:
    """Noise levels a record shows.

    Attributes:
        force_std: (nodes,) std of each tactile segment's force (N), NaN where too few
            live readings; force_live: (T, nodes) the live readings (``force_spikes``
            left out); force_spikes: (T, nodes) the readings that are isolated spikes
            (``isolated_spikes``; None: none), neither live nor a bound: left out of
            every fit and comparison.
        marker_std: std of a marker coordinate (m).
        force_samples, marker_samples: second differences each level rests on.
        force_floor, marker_floor: the part of each level that is the model's own floor
            (``floored``; 0: the sensor's alone): a systematic error, the same in every
            reading of a stretch, where the sensor's noise is independent reading by reading.
    """

    force_std: np.ndarray
    force_live: np.ndarray
    marker_std: float
    force_samples: np.ndarray
    marker_samples: int
    force_spikes: np.ndarray | None = None
    force_floor: np.ndarray | float = 0.0
    marker_floor: float = 0.0

    @property
    def known(self) -> bool:
        """Every signal shows its noise (a noise-free record, or a segment with too few
        live readings, does not)."""
        levels = np.append(self.force_std, self.marker_std)
        return bool(np.all(np.isfinite(levels) & (levels > 0)))

    @property
    def weights(self) -> Weights:
        return Weights(self.force_std, self.marker_std)

    def floored(self, floor: dict[str, float]) -> SensorNoise:
        """These levels with a fit's floor (``FitStatistics.floor``, by signal) added in
        quadrature: what a model can be held to. A noise-free record's levels become the
        model's own resolution, never zero."""
        force_floor = np.array([floor[f"P{j + 1}"] for j in range(self.force_std.size)])
        # NaN stays NaN: a segment with too few live readings shows no level to floor.
        return replace(self, force_std=np.hypot(self.force_std, force_floor),
                       marker_std=float(np.hypot(self.marker_std, floor["markers"])),
                       force_floor=np.hypot(self.force_floor, force_floor),
                       marker_floor=float(np.hypot(self.marker_floor, floor["markers"])))


def cells_noise(record: Record) -> np.ndarray:
    """(nodes,) N: each segment's noise from its cells' (the sensor's cell noise, which
    the array's segments show or the parameters state); NaN where none is known."""
    tactile = None if record.sensor is None else record.sensor.tactile
    if tactile is None or not tactile.noise > 0:
        return np.full(record.force.shape[1], np.nan)
    return tactile.segment_noise


_T = TypeVar("_T")


def _frozen(value):
    """``value`` with its arrays read-only (a remembered answer is shared by its callers)."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, tuple):
        for v in value:
            _frozen(v)
    elif dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            _frozen(getattr(value, f.name))
    return value


def _per_record(compute: Callable[[Record], _T]) -> Callable[[Record], _T]:
    """``compute(record)`` remembered for the last record it was asked of, by identity (a
    Record is frozen and its arrays are not written; the answer's arrays are made
    read-only): a closed form asks the same record's noise twice (the despiking and the
    baseline), a fit at every start, each candidate again. One entry, swapped whole, so
    that threads asking for other records never read each other's."""
    last: list[tuple[Record, _T] | None] = [None]

    @functools.wraps(compute)
    def remembered(record: Record) -> _T:
        entry = last[0]
        if entry is None or entry[0] is not record:
            entry = (record, _frozen(compute(record)))
            last[0] = entry
        return entry[1]

    return remembered


@_per_record
def force_noise(record: Record) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each tactile segment's noise over its live readings: (nodes,) std (N, NaN where
    too few live readings), (T, nodes) the live readings, (nodes,) differences counted.

    A segment whose own readings show no level (live too seldom three frames in a row:
    saturated, or under the dead band) takes its margins from its cells' noise
    (``cells_noise``): without them, a segment saturated most of the time kept its
    readings up to the top as measures while its cells clipped one by one (seen: E 51 %
    low, the misfit "1e7 x the noise")."""
    force = record.force
    band = record.dead_band
    # Live by the threshold and the saturation alone first (a saturated reading has no
    # noise: a record at saturation most of the time would show none), then with the
    # margin the noise found sets.
    live = np.ones(force.shape, bool) if band is None else (force > band.force) & (force < band.saturation)
    from_cells = cells_noise(record)
    for _ in range(2 if band is not None else 1):
        std, counts = column_difference_noise(force, live)
        if band is not None:
            std0 = np.nan_to_num(np.where(np.isfinite(std), std, from_cells), nan=0.0)
            # The top by each reading: one above it is clipped and bounds the force from below
            # (``fit.ReadingBounds``); one below it, in a window the median puts above, would
            # be neither a measure nor a bound of the dead band's side (seen: E 8 std low).
            # At saturation itself never (a segment whose noise is not known has no margin).
            live = (_most_of_window(force >= band.threshold(std0)) & (force <= band.top(std0))
                    & (force < band.saturation))
    return std, live, counts


def _most_of_window(mask: np.ndarray) -> np.ndarray:
    """(T, n): where most of the ``LIVE_WINDOW`` frames centred on each (the ends
    repeated) are in ``mask`` (T, n): the running median of the readings is on the mask's
    side of its threshold. By counts (cumulative sums), not by sorting windows: an hour
    at 500 Hz in 0.4 s, not 5 (measured)."""
    half = LIVE_WINDOW // 2
    padded = np.pad(mask.astype(np.int32), ((half, half), (0, 0)), mode="edge")
    counts = np.cumsum(np.vstack([np.zeros((1, mask.shape[1]), np.int32), padded]), axis=0)
    return 2 * (counts[LIVE_WINDOW:] - counts[:-LIVE_WINDOW]) > LIVE_WINDOW


def isolated_spikes(force: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(T, nodes): the readings of ``force`` (T, nodes) that jump off both neighbours
    alike while the neighbours agree: further than ``SPIKE_SIGMAS`` stds of the
    midpoint's noise (``std`` per segment; sqrt(1.5) std for white noise) and
    ``SPIKE_SHARE`` of the segment's peak from the midpoint, the neighbours within that
    of each other. A glitch of one frame (a cell's electrical spike); a load's step (the
    let-go, a contact) moves the neighbours apart and a smooth load stays near the midpoint.
    """
    force = np.asarray(force, float)
    spikes = np.zeros(force.shape, bool)
    if force.shape[0] < 3:
        return spikes
    peak = np.abs(force).max(axis=0)
    limit = np.maximum(SPIKE_SIGMAS * np.sqrt(1.5) * np.nan_to_num(std, nan=np.inf), SPIKE_SHARE * peak)
    off = np.abs(force[1:-1] - 0.5 * (force[:-2] + force[2:]))
    spikes[1:-1] = (off > limit) & (np.abs(force[2:] - force[:-2]) < limit)
    return spikes


def spikes_note(record: Record, spikes: np.ndarray | None) -> str:
    """One line naming the spikes left out ("" without any): per segment, how many and
    when (the first few)."""
    if spikes is None:
        return ""
    parts = []
    for j in np.flatnonzero(spikes.any(axis=0)):
        t = record.force_t[spikes[:, j]]
        when = ", ".join(f"{x:.3f}" for x in t[:3]) + (", ..." if t.size > 3 else "")
        parts.append(f"P{j + 1}: {t.size} at {when} s")
    if not parts:
        return ""
    return (f"tactile readings left out as isolated spikes (off both neighbours by over {SPIKE_SIGMAS:g} x the "
            f"noise while they agree: a glitch of one frame, not a load): {'; '.join(parts)}")


def despiked(record: Record) -> Record:
    """``record`` with its isolated spikes (``sensor_noise``) replaced by the midpoint of
    their neighbours: for the closed forms, which read the force at given instants and
    over windows rather than reading by reading (the fit and the comparison leave the
    spikes out instead)."""
    spikes = isolated_spikes(record.force, force_noise(record)[0])   # ``sensor_noise``'s, without the markers'
    if not spikes.any():
        return record
    force = record.force.copy()
    rows, cols = np.nonzero(spikes)
    force[rows, cols] = 0.5 * (force[rows - 1, cols] + force[rows + 1, cols])
    return replace(record, force=force)


@_per_record
def sensor_noise(record: Record) -> SensorNoise:
    """The noise of each tactile segment over its live readings, and of the markers; the
    readings that are isolated spikes are left out of the live ones."""
    std, live, counts = force_noise(record)
    spikes = isolated_spikes(record.force, std)
    std = np.where(np.isfinite(std), std, cells_noise(record))   # the weights and the judgement's
    # (Taken for noise, a float64 position's 3e-17 m of rounding weighed the markers 1e16 x
    # the force on table_I_short, and a scaled E fitted them as well.)
    marker_std, marker_samples = marker_noise(record.markers)
    return SensorNoise(std, live & ~spikes, marker_std, counts, marker_samples, spikes)
