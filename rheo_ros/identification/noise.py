"""The sensor noise the data show, independent of any model: each signal's second
differences (``sensors.difference_noise``). Tactile readings count only where they are
live (above the dead band, ``DeadBand``): the dead band's exact zeros would claim a
noise-free sensor.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rheo_ros.record import Record
from rheo_ros.sensors import difference_noise

__all__ = ["SensorNoise", "Weights", "difference_noise", "force_noise", "sensor_noise"]


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
            live readings; force_live: (T, nodes) the live readings.
        marker_std: std of a marker coordinate (m).
        force_samples, marker_samples: second differences each level rests on.
    """

    force_std: np.ndarray
    force_live: np.ndarray
    marker_std: float
    force_samples: np.ndarray
    marker_samples: int

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
                       marker_std=float(np.hypot(self.marker_std, floor["markers"])))


def force_noise(record: Record) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each tactile segment's noise over its live readings: (nodes,) std (N, NaN where
    too few live readings), (T, nodes) the live readings, (nodes,) differences counted."""
    force = record.force
    nodes = force.shape[1]
    band = record.dead_band
    # Live by the threshold and the saturation alone first (a saturated reading has no
    # noise: a record at saturation most of the time would show none), then with the
    # margin the noise found sets.
    live = np.ones(force.shape, bool) if band is None else (force > band.force) & (force < band.saturation)
    std = np.full(nodes, np.nan)
    counts = np.zeros(nodes, int)
    for _ in range(2 if band is not None else 1):
        for j in range(nodes):
            std[j], counts[j] = difference_noise(force[:, j], live[:, j])
        if band is not None:
            live = band.live(force, np.nan_to_num(std, nan=0.0))
    return std, live, counts


def sensor_noise(record: Record) -> SensorNoise:
    """The noise of each tactile segment over its live readings, and of the markers."""
    std, live, counts = force_noise(record)
    marker_std, marker_samples = difference_noise(record.markers)
    return SensorNoise(std, live, marker_std, counts, marker_samples)
