"""The sensor noise the data show, independent of any model.

A measured signal is a smooth response plus white noise; its second difference
``y[i-1] - 2 y[i] + y[i+1]`` is noise with variance 6 sigma^2 plus the response's
curvature, which at the sensors' rates is far below the noise except at a phase's
corners. A robust scale (median absolute deviation) of the second differences ignores
those few corners. Tactile readings count only where they are live (above the dead
band, ``DeadBand``): the dead band's exact zeros would claim a noise-free sensor.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rheo_ros.record import Record

MIN_DIFFERENCES = 10   # fewer live second differences than this: the noise is not known
MAD_TO_STD = 1.4826    # of a Gaussian


def difference_noise(y: np.ndarray, use: np.ndarray | None = None) -> tuple[float, int]:
    """White-noise std of a smooth signal ``y`` (T, ...) along its first axis from its
    second differences, counting only where three samples in a row are in ``use``
    (T, ...). Returns the std (NaN when too few) and the differences counted."""
    y = np.asarray(y, float)
    d2 = y[:-2] - 2.0 * y[1:-1] + y[2:]
    if use is not None:
        d2 = d2[use[:-2] & use[1:-1] & use[2:]]
    d2 = d2.ravel()
    if d2.size < MIN_DIFFERENCES:
        return float("nan"), int(d2.size)
    mad = np.median(np.abs(d2 - np.median(d2)))
    return float(MAD_TO_STD * mad / np.sqrt(6.0)), int(d2.size)


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
    # Live by the threshold alone first, then with the margin the noise found sets.
    live = np.ones(force.shape, bool) if band is None else force > band.force
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
