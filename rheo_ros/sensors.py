"""Sensor models: the tactile pressure array under the specimen and the marker camera.

The tactile array (contract) has ``rows`` cells along z and ``cols`` along x. The
bottom face is split into one segment per bottom FE node: the columns whose centres
are nearest that node (P1 and P5 own half as many as the inner nodes, as in the
paper's Fig. 6). A nodal force is spread evenly over its segment's cells, so the
force read back from a segment is that node's force.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class DeadBand:
    """Where a tactile segment's reading stops being its force plus zero-mean noise.

    A cell reads zero below the threshold (and for tension), so a segment whose cells
    are near it reads too little or nothing: only a segment force at least
    ``force`` (N, per node: its cells at the threshold) plus three cell noise stds per
    cell is a live reading. ``cells``: cells per segment.
    """

    force: np.ndarray
    cells: np.ndarray

    def threshold(self, force_std: np.ndarray) -> np.ndarray:
        """(nodes,) N: the smallest live segment force, given each segment's noise std
        (N): three cell stds above the threshold in every cell (a segment's std is
        sqrt(cells) cell stds, its margin cells x 3 cell stds). A reading below it
        says the force was at most about this much."""
        return self.force + 3.0 * np.asarray(force_std) * np.sqrt(self.cells)

    def live(self, force: np.ndarray, force_std: np.ndarray) -> np.ndarray:
        """(T, nodes) mask of live readings for segment forces (T, nodes) in N."""
        return np.asarray(force) >= self.threshold(force_std)

    def reading(self, force: np.ndarray) -> np.ndarray:
        """What the segments read of noise-free forces (T, nodes) in N, to first order:
        the force, or zero below the dead band (cells at the threshold) and for tension.
        A model compared with readings goes through it first: where the specimen has let
        go, a force sinking below the dead band reads zero, not its small true value."""
        force = np.asarray(force)
        return np.where(force >= self.force, force, 0.0)


@dataclass(frozen=True)
class TactileArray:
    """Cell grid ``rows`` (z) x ``cols`` (x) under a face ``width`` (x) by ``depth`` (z), in m.

    ``noise`` (Pa): Gaussian per cell; ``threshold`` (Pa): dead band, readings below
    it are zero; ``resolution`` (Pa per count, 0 = none): ADC quantisation. The sensor
    reads pressure only: tension reads as zero. Without a dead band, clipping the
    noise at zero would leave an unloaded array reading ~noise/2.5 per cell, a
    baseline that looks like drift.
    """

    rows: int = 6
    cols: int = 32
    width: float = 0.080
    depth: float = 0.0125
    nodes: int = 5
    noise: float = 100.0
    resolution: float = 10.0
    threshold: float = 300.0

    @cached_property
    def segment(self) -> np.ndarray:
        """Bottom node (0-based) owning each column."""
        centres = (np.arange(self.cols) + 0.5) * self.width / self.cols
        node_x = np.linspace(0.0, self.width, self.nodes)
        return np.argmin(np.abs(centres[:, None] - node_x[None]), axis=1)

    @cached_property
    def segment_edges(self) -> np.ndarray:
        """x (m) where each segment begins, and the face's end (segments + 1)."""
        pitch = self.width / self.cols
        changes = np.flatnonzero(np.diff(self.segment)) + 1
        return np.concatenate([[0.0], changes * pitch, [self.width]])

    @cached_property
    def columns_per_segment(self) -> np.ndarray:
        """(nodes,): columns each bottom node owns (0: that node's force cannot be read)."""
        return np.bincount(self.segment, minlength=self.nodes)

    @cached_property
    def dead_band(self) -> DeadBand:
        cells = self.columns_per_segment * self.rows
        return DeadBand(self.threshold * cells * self.cell_area, cells)

    @property
    def cell_area(self) -> float:
        return (self.width / self.cols) * (self.depth / self.rows)

    @cached_property
    def _spread(self) -> np.ndarray:
        """(nodes, cols): pressure per column (Pa) per newton on each node."""
        counts = self.columns_per_segment * self.rows
        S = np.zeros((self.nodes, self.cols))
        S[self.segment, np.arange(self.cols)] = 1.0 / (counts[self.segment] * self.cell_area)
        return S

    def pressure(self, force: np.ndarray) -> np.ndarray:
        """Noise-free pressure images (T, rows, cols) in Pa for nodal forces (T, nodes) in N."""
        cols = np.asarray(force) @ self._spread
        return np.repeat(cols[:, None, :], self.rows, axis=1)

    def read(self, pressure: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """What the sensor reports: noise, dead band (no tension), quantisation; float32 Pa."""
        p = pressure + rng.standard_normal(pressure.shape) * self.noise
        p = np.where(p < self.threshold, 0.0, p)
        if self.resolution > 0:
            p = np.round(p / self.resolution) * self.resolution
        return p.astype(np.float32)

    def nodal_forces(self, images: np.ndarray) -> np.ndarray:
        """Segment sums (T, nodes) in N from pressure images (T, rows, cols) in Pa."""
        per_col = np.asarray(images, dtype=float).sum(axis=1) * self.cell_area
        out = np.zeros((per_col.shape[0], self.nodes))
        for node in range(self.nodes):
            out[:, node] = per_col[:, self.segment == node].sum(axis=1)
        return out


@dataclass(frozen=True)
class MarkerCamera:
    """Marker tracking with Gaussian noise ``noise`` (m) per coordinate."""

    noise: float = 2.0e-5

    def observe(self, positions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return positions + rng.standard_normal(positions.shape) * self.noise
