"""Sensor models: the tactile pressure array under the specimen and the marker camera.

The tactile array (contract) has ``rows`` cells along z and ``cols`` along x. The
bottom face is split into one segment per bottom FE node: the columns whose centres
are nearest that node (P1 and P5 own half as many as the inner nodes, as in the
paper's Fig. 6). A nodal force is spread evenly over its segment's cells, so the
force read back from a segment is that node's force.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property, lru_cache

import numpy as np
from scipy.special import erfc, gammaincinv

MIN_DIFFERENCES = 10   # fewer second differences than this: the noise is not known
# E[max(n, 0)] of a zero-mean Gaussian n over its std (1 / sqrt(2 pi)): the most a cell's
# reading of a pressure p >= 0 exceeds p on average, whatever its dead band (``DeadBand.excess``).
CLIPPED_NOISE_MEAN = 0.3989422804014327
MAD_TO_STD = 1.4826    # of a Gaussian
LINEAR = -math.inf     # the threshold of a cell with neither a dead band nor clipping at zero


def _normal_pdf(x: np.ndarray | float) -> np.ndarray:
    return np.exp(-0.5 * np.square(x)) / math.sqrt(2.0 * math.pi)


# Beyond this many noise stds per count the noise no longer smooths a cell's counts: its
# reading's bias is bounded as if it had none (half a count; the whole band).
COARSE_STEPS = 4.0
# How far the noise of a cell near the band may exceed the one the live readings show:
# the bias at p = 0 is the noise's tail over the band, exponential in band / std (a std
# 10 % high triples it at a 3-std band), and a sensor's noise may grow or lose its
# Gaussian tails near zero.
NOISE_DOUBT = 1.25
# Frames of the unloaded array (before contact) that measure the excess in its stead
# (``DeadBand.unloaded``), and the one-sided confidence of its bound (a Gaussian's 3 stds).
MIN_UNLOADED = 20
UNLOADED_CONFIDENCE = 0.99865


@lru_cache(maxsize=256)
def cell_reading_bias(threshold: float, std: float, step: float) -> tuple[float, float]:
    """The most a cell's mean reading lies above and below its pressure ``p`` >= 0, over
    every ``p``: a cell reading ``p`` plus Gaussian noise of ``std``, nothing under
    ``threshold`` (0: the noise clipped at zero; -inf: neither), in counts of ``step`` (0:
    none), all in one unit. Whether the band applies to the value or to its count is not
    known: the worse of the two.

    Without counts, in noise stds with t = threshold / std: E[(p+n) 1(p+n >= t)] - p =
    phi(a) + (a - t) Phi(a), a = t - p, is at most phi(t) (at p = 0: the noise over the
    band) and at least its minimum where Phi(a) = t phi(a) (1.45 stds short for t = 3:
    cells just under the band). With counts, on a grid of ``p`` and of the noise: the
    counts' edge at the band lets values up to half a count under it read, and a step
    the noise does not smooth leaves its rounding."""
    if threshold == -math.inf:
        return 0.5 * step, 0.5 * step
    threshold = max(threshold, 0.0)
    if not std > 0.0 or step > COARSE_STEPS * std:
        return CLIPPED_NOISE_MEAN * max(std, 0.0) + 0.5 * step, threshold + 0.5 * step
    t, s = threshold / std, step / std
    if s == 0.0:
        a = np.linspace(-12.0, t, 20001)
        short = a - t
        return (float(_normal_pdf(t)) * std,
                float(-np.min(_normal_pdf(a) + short * 0.5 * erfc(-a / math.sqrt(2.0)))) * std)
    dz = min(s, 1.0) / 32.0
    z = np.arange(-9.0, 9.0 + dz, dz)
    weight = _normal_pdf(z) * dz
    p = np.arange(0.0, t + 9.0, 0.01)
    above = below = 0.0
    for chunk in np.array_split(p, max(1, p.size // 64)):
        x = chunk[:, None] + z[None]
        counted = s * np.round(x / s)
        for read in (np.where(x >= t, counted, 0.0), np.where(counted >= t, counted, 0.0)):
            bias = read @ weight - chunk
            above, below = max(above, float(bias.max())), max(below, float(-bias.min()))
    return above * std, below * std


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
    saturation: np.ndarray | float = math.inf   # N per segment: its cells at their largest reading
    # Share of a segment's cells that clip at ``saturation``: 1 for the whole array's
    # saturation, 1 / cells where one cell saturates alone (the others read on above it).
    clipping: np.ndarray | float = 1.0
    quantum: float = 0.0   # N: one count of one cell (the ADC's step times a cell's area)
    # (nodes,) N: the most a segment's mean reading exceeds its force as the unloaded array
    # shows it (``unloaded``); None: not measured, the noise's doubt stands in for it.
    measured_excess: np.ndarray | None = None

    def threshold(self, force_std: np.ndarray) -> np.ndarray:
        """(nodes,) N: the smallest live segment force, given each segment's noise std
        (N): three cell stds above the threshold in every cell (a segment's std is
        sqrt(cells) cell stds, its margin cells x 3 cell stds). A reading below it
        says the force was at most about this much."""
        return self.force + 3.0 * np.asarray(force_std) * np.sqrt(self.cells)

    def top(self, force_std: np.ndarray) -> np.ndarray:
        """(nodes,) N: the largest live segment force, three cell stds below saturation in
        every cell (inf without saturation). A reading above it says the force was at
        least about this much."""
        return self.saturation - 3.0 * np.asarray(force_std) * np.sqrt(self.cells)

    def _bias(self, force_std: np.ndarray, doubt: float = NOISE_DOUBT,
              counts: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(nodes,) N each: the most a segment's mean reading lies above and below its force:
        ``cell_reading_bias`` of one cell times its cells, above at ``doubt`` times its
        noise and below at its noise over ``doubt`` (the worse of each); ``counts`` False:
        as if the cells read continuous values (closed forms, no grid to compute)."""
        cells = np.asarray(self.cells, float)
        cell_std = np.broadcast_to(np.asarray(force_std, float) / np.sqrt(cells), cells.shape)
        cell_threshold = np.broadcast_to(np.asarray(self.force, float) / cells, cells.shape)
        quantum = float(self.quantum) if counts else 0.0
        above = [cell_reading_bias(float(thr), doubt * float(std), quantum)[0]
                 for thr, std in zip(cell_threshold, cell_std)]
        below = [cell_reading_bias(float(thr), float(std) / doubt, quantum)[1]
                 for thr, std in zip(cell_threshold, cell_std)]
        return cells * np.array(above), cells * np.array(below)

    def excess(self, force_std: np.ndarray) -> np.ndarray:
        """(nodes,) N: the most a segment's reading exceeds its force on average, given
        each segment's noise std (N), however the force spreads over its cells (only
        tension, which reads nothing, is not pressure): each cell's most
        (``cell_reading_bias``) times its cells. A reading under the dead band that is
        clearly above zero says the force was there (``fit.ReadingWindows``); the tighter
        this, the smaller a force under the band it reveals (a 300 Pa band at 100 Pa of
        noise, 10 Pa counts: 3.1 Pa a cell, with the noise's doubt; 50 Pa when the noise is
        clipped at zero). Where the unloaded array measured it (``unloaded``), that, within
        the noise's own tail over the band (no doubt, no counts: 0.44 Pa a cell) and the
        doubt's bound: a baseline offset or a preload before contact is no noise, and leaves
        the doubt's bound."""
        doubted = self._bias(force_std)[0]
        if self.measured_excess is None:
            return doubted
        return np.clip(self.measured_excess, self._bias(force_std, doubt=1.0, counts=False)[0], doubted)

    def unloaded(self, readings: np.ndarray, cell_noise: float) -> DeadBand:
        """This band with its excess measured on ``readings`` (T, nodes) N of the unloaded
        array (before the first contact), each cell's noise ``cell_noise`` (N).

        A cell's reading exceeds its pressure most at zero pressure (``cell_reading_bias``),
        so readings at zero bound the excess at any pressure with no assumption on the
        noise's tail (``NOISE_DOUBT`` assumes one: for a 3-std band its bound is 6 x the
        value at the stated noise). Pooled over the cells (one per-cell mean, each segment
        its share): the readings are the cells' crossings of the band, a Poisson count,
        bounded at ``UNLOADED_CONFIDENCE`` (exact Poisson bound; with no crossing seen, 6.6
        of them at the band plus one noise; two cells of a segment crossing in one frame
        count as one crossing twice the size, which only widens the bound). Fewer than
        ``MIN_UNLOADED`` frames: unchanged."""
        readings = np.asarray(readings, float)
        if readings.shape[0] < MIN_UNLOADED:
            return self
        cells = np.asarray(self.cells, float)
        total, squares = float(np.sum(np.maximum(readings, 0.0))), float(np.sum(np.square(readings)))
        # The crossings as a Poisson count of equal readings: their size the mean reading
        # weighted by itself, their count the total over it (exact for equal crossings).
        size = squares / total if total > 0.0 else float(np.max(np.asarray(self.force, float) / cells)) + cell_noise
        if not size > 0.0:   # no noise, no band: nothing crosses, nothing to measure
            return self
        crossings = total / size
        most = float(gammaincinv(crossings + 1.0, UNLOADED_CONFIDENCE))   # Poisson's upper bound
        return replace(self, measured_excess=cells * size * most / (readings.shape[0] * cells.sum()))

    def deficit(self, force_std: np.ndarray) -> np.ndarray:
        """(nodes,) N: the most a segment's mean reading falls short of its force, given its
        noise std (N), however the force spreads: so the mean of readings plus this is at
        least the mean force, less three stds of noise (``fit.ReadingWindows``). A cell
        under the band reads nothing most of the time, but its noise lifts it over the band
        often enough that its mean reading falls short of its pressure by at most 1.45
        noise stds (a band 3 stds up; 166 Pa for the band above, with the noise's doubt),
        not by the whole band; with no dead band (the noise clipped at zero) by about
        nothing, so the readings bound the force from both sides."""
        return self._bias(force_std)[1]

    def live(self, force: np.ndarray, force_std: np.ndarray) -> np.ndarray:
        """(T, nodes) mask of live readings for segment forces (T, nodes) in N."""
        force = np.asarray(force)
        return (force >= self.threshold(force_std)) & (force <= self.top(force_std))

    def reading(self, force: np.ndarray) -> np.ndarray:
        """What the segments read of noise-free forces (T, nodes) in N, to first order:
        the force, or zero below the dead band (cells at the threshold) and for tension.
        A model compared with readings goes through it first: where the specimen has let
        go, a force sinking below the dead band reads zero, not its small true value. Above
        ``saturation`` the clipping cells stop rising (all of them: the reading stays there)."""
        force = np.asarray(force)
        read = np.where(force >= self.force, force, 0.0)
        return read - self.clipping * np.maximum(read - self.saturation, 0.0)


@dataclass(frozen=True)
class CellFault:
    """A tactile cell that does not read its load, as the data show it (``read_sensor``).

    ``kind``: ``dead``, one reading ``value`` (Pa) from ``since`` (s; None: throughout)
    to the end; ``saturated``, clipped alone at ``value`` (Pa). ``peak`` (Pa): where the
    other cells of its column (of its segment, for a one-row array) peak meanwhile, the
    load it missed.
    """

    row: int
    col: int
    kind: str
    value: float
    peak: float
    since: float | None = None

    def warning(self) -> str:
        where = f"tactile cell (row {self.row}, col {self.col})"
        if self.kind == "dead" and self.since is None:
            return (f"{where} reads {self.value:g} throughout while the other cells of its column peak at "
                    f"{self.peak:.4g} Pa: left out, its segment read from its other cells")
        if self.kind == "dead":
            return (f"{where} reads {self.value:g} from {self.since:.3f} s on while the other cells of its column "
                    f"peak at {self.peak:.4g} Pa: left out from then, its segment read from its other cells")
        return (f"{where} saturates alone at {self.value:.4g} Pa while the other "
                f"cells of its column peak at {self.peak:.4g} Pa: its segment's readings from there up are not live "
                "(they bound the force from below)")

    def to_json(self) -> dict:
        return {"row": self.row, "col": self.col, "kind": self.kind, "value": self.value, "peak": self.peak,
                "since": self.since}


@dataclass(frozen=True)
class TactileArray:
    """Cell grid ``rows`` (z) x ``cols`` (x) under a face ``width`` (x) by ``depth`` (z), in m.

    ``noise`` (Pa): Gaussian per cell; ``threshold`` (Pa): dead band, readings below
    it are zero (0: the noise clipped at zero; ``LINEAR``: neither, readings go
    negative); ``resolution`` (Pa per count, 0 = none): ADC quantisation. The
    simulator's sensor reads pressure only: tension reads as zero. Without a dead band,
    clipping the noise at zero would leave an unloaded array reading ~noise/2.5 per
    cell, a baseline that looks like drift.
    """

    rows: int = 6
    cols: int = 32
    width: float = 0.080
    depth: float = 0.0125
    nodes: int = 5
    noise: float = 100.0
    resolution: float = 10.0
    threshold: float = 300.0
    saturation: float = math.inf   # Pa: the largest reading a cell gives
    faults: tuple[CellFault, ...] = ()   # cells that do not read their load (read_sensor)

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
    def dead_band(self) -> DeadBand | None:
        """Where the segments read their force plus zero-mean noise; None for a linear
        cell (no dead band, no clipping: every reading is)."""
        lone = [f for f in self.faults if f.kind == "saturated"]
        if self.threshold == LINEAR and self.saturation == math.inf and not lone:
            return None
        cells = self.cells_per_segment
        saturation = np.full(self.nodes, self.saturation) * cells * self.cell_area
        clipping = np.ones(self.nodes)
        for fault in lone:   # its segment stops reading its force where that cell clips (even load)
            j = self.segment[fault.col]
            saturation[j] = min(saturation[j], fault.value * cells[j] * self.cell_area)
            clipping[j] = 1.0 / cells[j]
        return DeadBand(self.threshold * cells * self.cell_area, cells, saturation, clipping,
                        quantum=self.resolution * self.cell_area)

    @property
    def cells_per_segment(self) -> np.ndarray:
        """(nodes,) cells per segment."""
        return self.columns_per_segment * self.rows

    @property
    def cell_area(self) -> float:
        return (self.width / self.cols) * (self.depth / self.rows)

    @property
    def segment_noise(self) -> np.ndarray:
        """(nodes,) N: each segment's force std from ``noise``, its cells' (sqrt(cells) cells)."""
        return self.noise * np.sqrt(self.cells_per_segment) * self.cell_area

    @cached_property
    def _spread(self) -> np.ndarray:
        """(nodes, cols): pressure per column (Pa) per newton on each node."""
        counts = self.cells_per_segment
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
        return np.minimum(p, self.saturation).astype(np.float32)

    def nodal_forces(self, images: np.ndarray) -> np.ndarray:
        """Segment sums (T, nodes) in N from pressure images (T, rows, cols) in Pa."""
        per_col = np.asarray(images, dtype=float).sum(axis=1) * self.cell_area
        # A segment's columns are contiguous (nearest node along x): one sum per run.
        sums = np.add.reduceat(per_col, self._segment_starts, axis=1)
        if self._every_node_owned:
            return sums
        out = np.zeros((per_col.shape[0], self.nodes))
        out[:, self.columns_per_segment > 0] = sums
        return out

    @cached_property
    def _every_node_owned(self) -> bool:
        return bool(np.all(self.columns_per_segment > 0))

    @cached_property
    def _segment_starts(self) -> np.ndarray:
        """First column of each segment that owns columns (``nodal_forces``)."""
        return np.flatnonzero(np.diff(self.segment, prepend=-1))

    def segment_forces(self, sums: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The segment forces (T, nodes) in N of segment sums (``nodal_forces``) at stamps
        ``t`` (T,) with the dead cells left out from when they died: a dead cell's constant
        reading taken off and its segment's other cells scaled up to the whole segment.
        Scaled, not a cell fewer: the forward model integrates each segment over all its
        columns, and a nodal force is spread evenly over its cells, so the remaining cells
        stand for the missing one (in the plane FE the pressure varies along x within a
        segment: first order there)."""
        sums = np.asarray(sums, float)
        dead = [f for f in self.faults if f.kind == "dead"]
        if not dead:
            return sums
        out = sums.copy()
        cells = self.cells_per_segment.astype(float)
        # Each stretch between two deaths has its own set of dead cells.
        starts = sorted({-math.inf if f.since is None else f.since for f in dead})
        for k, start in enumerate(starts):
            rows = (np.asarray(t) >= start) & (np.asarray(t) < (starts[k + 1] if k + 1 < len(starts) else math.inf))
            stuck, left = np.zeros(self.nodes), cells.copy()
            for fault in dead:
                if (-math.inf if fault.since is None else fault.since) <= start:
                    j = self.segment[fault.col]
                    stuck[j] += fault.value * self.cell_area
                    left[j] -= 1
            out[rows] = (sums[rows] - stuck) * (cells / np.maximum(left, 1.0))
        return out


@dataclass(frozen=True)
class MarkerCamera:
    """Marker tracking with Gaussian noise ``noise`` (m) per coordinate."""

    noise: float = 2.0e-5

    def observe(self, positions: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return positions + rng.standard_normal(positions.shape) * self.noise


def difference_noise(y: np.ndarray, use: np.ndarray | None = None) -> tuple[float, int]:
    """White-noise std of a smooth signal ``y`` (T, ...) along its first axis from its
    second differences, counting only where three samples in a row are in ``use``
    (T, ...). Returns the std (NaN when too few) and the differences counted.

    A measured signal is a smooth response plus white noise; its second difference
    ``y[i-1] - 2 y[i] + y[i+1]`` is noise with variance 6 sigma^2 plus the response's
    curvature, which at the sensors' rates is far below the noise except at a phase's
    corners. A robust scale (median absolute deviation) ignores those few corners."""
    d2, ok = _second_differences(y, use)
    std, counts = _mad_noise(d2.reshape(-1, 1), ok.reshape(-1, 1))   # every column pooled
    return float(std[0]), int(counts[0])


def column_difference_noise(y: np.ndarray, use: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``difference_noise`` of each column of ``y`` (T, k) on its own, all at once: (k,)
    stds (NaN where too few) and (k,) differences counted."""
    return _mad_noise(*_second_differences(y, use))


def _second_differences(y: np.ndarray, use: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``y``'s second differences along its first axis and where three samples in a row
    are in ``use``."""
    y = np.asarray(y, float)
    d2 = y[:-2] - 2.0 * y[1:-1] + y[2:]
    return d2, (np.ones(d2.shape, bool) if use is None else use[:-2] & use[1:-1] & use[2:])


def _mad_noise(d2: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) the white-noise std of each column of second differences ``d2`` (T, k) where
    ``ok`` (NaN below ``MIN_DIFFERENCES``), and the differences counted."""
    counts = ok.sum(axis=0)
    mad = _column_medians(np.abs(d2 - _column_medians(d2, ok, counts)), ok, counts)
    return np.where(counts >= MIN_DIFFERENCES, MAD_TO_STD * mad / np.sqrt(6.0), np.nan), counts


def _column_medians(values: np.ndarray, ok: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(k,) the median of each column's entries where ``ok`` (T, k), NaN where none: by
    ``np.median`` over the columns at once, each column's other entries padded evenly by
    -inf and +inf, which leaves its middle where its own entries put it (a column whose
    padding is odd gets one more padding row)."""
    out = np.full(values.shape[1], np.nan)
    for extra in (0, 1):
        cols = np.flatnonzero(((values.shape[0] + extra - counts) % 2 == 0) & (counts > 0))
        if cols.size == 0:
            continue
        v, pad = values[:, cols], ~ok[:, cols]
        if extra:
            v = np.vstack([v, np.zeros((1, cols.size))])
            pad = np.vstack([pad, np.ones((1, cols.size), bool)])
        low = np.cumsum(pad, axis=0) <= pad.sum(axis=0) // 2
        out[cols] = np.median(np.where(pad, np.where(low, -np.inf, np.inf), v), axis=0)
    return out


MAX_DISTINCT = 1 << 16     # more distinct readings than this: no lattice to read (continuous)
MIN_LATTICE = 50           # distinct readings a quantisation step is read from
LATTICE_REPEATS = 100      # ... or fewer, each met this often on average (``TactileReadout.resolution``)
MARKER_RESOLUTION = 1e-9   # m: a marker noise below this is numerical (a noise-free record)
NOISE_AGREES = 1.5         # a stated noise within this factor of the data's agrees with them


def marker_noise(markers: np.ndarray) -> tuple[float, int]:
    """The camera's noise from the markers (T, N, 2) m (``difference_noise``) and the
    differences counted; 0 below ``MARKER_RESOLUTION``: no camera resolves a nanometre,
    it is the coordinates' rounding (float64 positions near a metre show 3e-17 m)."""
    std, count = difference_noise(markers)
    return (0.0 if std < MARKER_RESOLUTION else std), count


@dataclass
class TactileReadout:
    """What a tactile array's readings show of its cells, gathered frame by frame.

    Every fact is a count, an extreme, a set or the run of equal readings each cell
    ends with, so the same frames give the same facts however they are grouped (the node
    adds a block of frames at a time, a whole bag adds them all: one computation).
    ``distinct`` holds the distinct non-zero readings while there are at most
    ``MAX_DISTINCT`` (quantised readings have few; continuous ones overflow it and are
    dropped: ``overflow``). ``segment`` (column -> segment) groups a one-row array's
    cells by segment; more rows are grouped by column (the plane model's pressure is the
    same along z).
    """

    segment: np.ndarray | None = None
    readings: int = 0
    zeros: int = 0
    negatives: int = 0
    smallest_positive: float = math.inf
    largest: float = -math.inf
    at_largest: int = 0        # frames in which some cell reads ``largest``
    distinct: np.ndarray = field(default_factory=lambda: np.empty(0))
    overflow: bool = False
    first_t: float = math.nan  # the first frame's stamp (s)
    # Per cell (rows, cols), None before the first frame: its highest reading and the
    # frames in which it reads it (a lone saturated cell); the reading it ends with, since
    # when (s) and for how many frames, and the highest load its group's cells read
    # meanwhile (median over the group, Pa): a dead cell reads one value on under a load.
    cell_high: np.ndarray | None = None
    cell_at_high: np.ndarray | None = None
    cell_last: np.ndarray | None = None
    cell_since: np.ndarray | None = None
    cell_run: np.ndarray | None = None
    cell_load: np.ndarray | None = None

    BLOCK = 4096   # frames taken at once (memory: a frame-by-cell array per block)

    def add(self, images: np.ndarray, t: np.ndarray | None = None) -> None:
        """Frames (..., rows, cols) of readings in Pa at stamps ``t`` (s; default: the
        frames' numbers)."""
        images = np.asarray(images, float)
        v = images.ravel()
        if v.size == 0:
            return
        frames = images.reshape(-1, *images.shape[-2:])
        stamps = (self.frames + np.arange(len(frames), dtype=float) if t is None
                  else np.asarray(t, float).reshape(len(frames)))
        for k in range(0, len(frames), self.BLOCK):
            self._add_cells(frames[k:k + self.BLOCK], stamps[k:k + self.BLOCK])
        self.readings += v.size
        self.zeros += int(np.count_nonzero(v == 0.0))
        self.negatives += int(np.count_nonzero(v < 0.0))
        positive = v[v > 0.0]
        if positive.size:
            self.smallest_positive = min(self.smallest_positive, float(positive.min()))
        top = float(v.max())
        if top > self.largest:
            self.largest, self.at_largest = top, 0
        if top == self.largest:
            self.at_largest += int(np.count_nonzero((frames == top).any(axis=(1, 2))))
        if not self.overflow:
            self.distinct = np.union1d(self.distinct, v[v != 0.0])
            if self.distinct.size > MAX_DISTINCT:
                self.overflow, self.distinct = True, np.empty(0)

    def peers_median(self, frames: np.ndarray) -> np.ndarray:
        """(F, rows, cols): the median of each cell's peers - the other cells of its
        column, of its segment for a one-row array - per frame (-inf where it has none)."""
        if frames.shape[1] > 1 or self.segment is None:
            return np.moveaxis(_median_of_others(np.moveaxis(frames, 1, -1)), -1, 1)
        load = np.empty_like(frames)
        for j in np.unique(self.segment):
            cols = self.segment == j
            load[:, :, cols] = _median_of_others(frames[:, :, cols])
        return load

    def _add_cells(self, frames: np.ndarray, t: np.ndarray) -> None:
        high = frames.max(axis=0)
        at_high = np.count_nonzero(frames == high, axis=0)
        load = self.peers_median(frames)
        # Where each cell's last run of equal readings starts in this block (-1: before it).
        before = frames[:1] if self.cell_last is None else self.cell_last[None]
        changed = np.concatenate([frames[:1] != before, frames[1:] != frames[:-1]])
        if self.cell_last is None:
            changed[0] = True
        index = np.arange(len(frames))[:, None, None]
        start = np.max(np.where(changed, index, -1), axis=0)
        later = np.maximum.accumulate(load[::-1], axis=0)[::-1]   # the load from each frame on
        load_from = np.take_along_axis(later, np.maximum(start, 0)[None], axis=0)[0]
        fresh = start >= 0
        if self.cell_high is None:
            self.first_t = float(t[0])
            self.cell_high, self.cell_at_high = high, at_high
            self.cell_since, self.cell_run, self.cell_load = t[start], len(frames) - start, load_from
        else:
            self.cell_at_high = np.where(high > self.cell_high, at_high,
                                         self.cell_at_high + np.where(high == self.cell_high, at_high, 0))
            self.cell_high = np.maximum(self.cell_high, high)
            self.cell_since = np.where(fresh, t[np.maximum(start, 0)], self.cell_since)
            self.cell_run = np.where(fresh, len(frames) - start, self.cell_run + len(frames))
            self.cell_load = np.where(fresh, load_from, np.maximum(self.cell_load, later[0]))
        self.cell_last = frames[-1].copy()

    @property
    def frames(self) -> int:
        """Frames added."""
        return 0 if self.cell_high is None else self.readings // self.cell_high.size

    @property
    def resolution(self) -> float | None:
        """The quantisation step (Pa) the readings sit on, 0 for continuous readings, None
        when too few distinct readings show either way. The step is the smallest gap
        between distinct readings, kept only when every reading is a whole number of
        steps (to float32's precision). Fewer than ``MIN_LATTICE`` distinct readings show a
        lattice too when each is met ``LATTICE_REPEATS`` times on average: a coarse step
        under a soft specimen's small load (46 values of 50 Pa steps in 421 219 readings,
        read as the parameters' 10 Pa, made the clipped noise's first count a dead band)."""
        if self.overflow:
            return 0.0
        v = self.distinct
        repeated = v.size >= 3 and self.readings - self.zeros >= LATTICE_REPEATS * v.size
        if v.size < MIN_LATTICE and not repeated:
            return None
        step = float(np.diff(v).min())
        tolerance = np.maximum(1e-3 * step, 4.0 * np.finfo(np.float32).eps * np.abs(v))
        on_lattice = np.abs(v - np.round(v / step) * step) <= tolerance
        resolvable = step > 16.0 * np.finfo(np.float32).eps * float(np.abs(v).max())
        return step if resolvable and bool(on_lattice.all()) else 0.0


def _median_of_others(values: np.ndarray) -> np.ndarray:
    """(..., n): for each entry along the last axis, the median of the other n - 1
    (-inf where there are none)."""
    n = values.shape[-1]
    if n < 2:
        return np.full(values.shape, -np.inf)
    ordered = np.sort(values, axis=-1)
    rank = np.argsort(np.argsort(values, axis=-1, kind="stable"), axis=-1, kind="stable")

    def other(k: int) -> np.ndarray:   # the k-th smallest of the others
        return np.where(rank > k, ordered[..., k:k + 1], ordered[..., k + 1:k + 2])

    m = n - 1
    return other(m // 2) if m % 2 else 0.5 * (other(m // 2 - 1) + other(m // 2))


@dataclass(frozen=True)
class SensorReading:
    """The tactile array and camera as the data show them, what they rest on, and where
    they contradict the parameters.

    Attributes:
        tactile: the array with the threshold and resolution the readings show (the
            parameters' where the readings cannot tell) and the cell noise they show.
        marker_noise: m per coordinate (NaN: not shown).
        source: per field (``tactile.threshold``, ``tactile.resolution``,
            ``tactile.noise``, ``markers.noise``) whether it came from the ``data`` or
            the ``parameters``.
        warnings: one line per stated value the data contradict, and per cell left out
            (``tactile.faults``).
        unreadable: why the tactile readings carry no force ("" when they do): no push
            can be identified from them.
    """

    tactile: TactileArray
    marker_noise: float
    source: dict[str, str]
    warnings: tuple[str, ...] = ()
    unreadable: str = ""

    @property
    def law(self) -> str:
        """The cell's law in words."""
        t = self.tactile.threshold
        band = ("linear (no dead band, no clipping)" if t == LINEAR else
                "noise clipped at zero, no dead band" if t == 0 else f"dead band {t:g} Pa")
        steps = f", {self.tactile.resolution:g} Pa steps" if self.tactile.resolution > 0 else ", continuous"
        top = f", saturates at {self.tactile.saturation:g} Pa" if np.isfinite(self.tactile.saturation) else ""
        return band + steps + top

    def to_json(self) -> dict:
        t = self.tactile
        return {
            "law": self.law,
            "tactile": {"threshold": None if t.threshold == LINEAR else t.threshold,
                        "clipped_at_zero": t.threshold == 0.0, "resolution": t.resolution,
                        "noise": _finite(t.noise), "saturation": _finite(t.saturation),
                        "faults": [f.to_json() for f in t.faults]},
            "markers": {"noise": _finite(self.marker_noise)},
            "source": dict(self.source),
            "warnings": list(self.warnings),
        }


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def read_sensor(stated: TactileArray, readout: TactileReadout, forces: np.ndarray, marker_std: float,
                stated_marker_noise: float, given: frozenset[str] = frozenset()) -> SensorReading:
    """The sensor as the readings show it, against the parameters ``stated``.

    The data decide wherever they can. Saturation: the largest reading met in many
    frames (a smooth load passes its peak once). The cell noise: the segments' second
    differences (``forces`` (T, nodes) N) over readings clear of zero and of
    saturation, in two passes (the first sets the margin). A reading below zero means a
    linear cell; exact zeros beside positive readings down to about half a cell noise
    (or one step) mean the noise clipped at zero; no reading between zero and a level
    well above that means a dead band there (on noise-free readings a gap is the load's
    own, so the parameters' band is kept where it is lower). The quantisation step is
    the readings' lattice. A value in ``given`` (stated by the parameters file) that the
    data contradict gets a warning naming the field, both values and what the data
    show; the data's value is used all the same.
    """
    warnings: list[str] = []
    source = dict.fromkeys(("tactile.threshold", "tactile.resolution", "tactile.noise", "markers.noise"), "data")
    cells = stated.cells_per_segment
    to_cell = np.sqrt(cells) * stated.cell_area   # a segment's force std per cell std (Pa -> N)

    saturation = math.inf
    if readout.largest > 0 and _often(readout.at_largest, readout.frames):
        saturation = readout.largest
    unsaturated = forces < 0.9 * saturation * cells * stated.cell_area

    def cell_noise(floor: np.ndarray | None) -> float:
        use = unsaturated if floor is None else unsaturated & (forces > floor)
        seg = column_difference_noise(forces, use)[0] / to_cell
        return float(np.nanmedian(seg)) if np.isfinite(seg).any() else math.nan

    resolution = readout.resolution
    if resolution is None:
        resolution, source["tactile.resolution"] = stated.resolution, "parameters"
    elif "tactile.resolution" in given and not math.isclose(resolution, stated.resolution, rel_tol=1e-3):
        warnings.append(f"tactile.resolution: the parameters say {stated.resolution:g} Pa per count, the readings "
                        f"show {'continuous values' if resolution == 0 else f'{resolution:g} Pa steps'}")

    noise = cell_noise(None if readout.negatives else np.zeros(forces.shape[1]))
    # Below this a cell's noise is numerical, not a sensor's: 14 bits of the largest reading.
    # A noise the readings cannot show (too few live three frames in a row: a block
    # saturating the array most of the time) is not known, not zero: the parameters' then.
    noise_free = bool(np.isfinite(noise)) and not noise > 1e-4 * max(readout.largest, 0.0)
    low = readout.smallest_positive
    if readout.negatives:
        threshold, shown = LINEAR, f"{readout.negatives} readings below zero"
    elif readout.zeros and np.isfinite(low):
        clipped = low <= max(1.5 * resolution, 0.5 * (0.0 if noise_free else noise))
        threshold = 0.0 if clipped else low
        shown = (f"readings from {low:.3g} Pa up beside exact zeros" if clipped else
                 f"no reading between 0 and {low:g} Pa")
        if noise_free and not clipped and stated.threshold < low:
            threshold, source["tactile.threshold"] = stated.threshold, "parameters"
    else:
        threshold, shown, source["tactile.threshold"] = stated.threshold, "", "parameters"
    if "tactile.threshold" in given and source["tactile.threshold"] == "data":
        inside = np.isfinite(low) and low < stated.threshold - max(resolution, 1e-9 * stated.threshold)
        if threshold == LINEAR or inside or (threshold == 0.0 and stated.threshold > 0):
            warnings.append(f"tactile.threshold: the parameters say a dead band of {stated.threshold:g} Pa, the "
                            f"readings show {shown}")

    if np.isfinite(noise) and threshold != LINEAR:   # again over the readings clear of the dead band
        again = cell_noise((max(threshold, 0.0) + 3.0 * noise) * cells * stated.cell_area)
        noise = again if np.isfinite(again) else noise
    if noise_free:
        noise = 0.0
    if np.isfinite(noise):
        if "tactile.noise" in given and not _agrees(stated.noise, noise):
            warnings.append(f"tactile.noise: the parameters say {stated.noise:g} Pa per cell, the readings show "
                            f"{noise:.3g} Pa")
    else:
        noise, source["tactile.noise"] = stated.noise, "parameters"
    if np.isfinite(marker_std):
        if "markers.noise" in given and not _agrees(stated_marker_noise, marker_std):
            warnings.append(f"markers.noise: the parameters say {stated_marker_noise:g} m, the markers show "
                            f"{marker_std:.3g} m")
    else:
        marker_std, source["markers.noise"] = stated_marker_noise, "parameters"
    faults = cell_faults(readout, threshold, noise, float(resolution), saturation)
    warnings += [f.warning() for f in faults]
    tactile = replace(stated, threshold=threshold, resolution=float(resolution), noise=float(noise),
                      saturation=saturation, faults=faults)
    return SensorReading(tactile, float(marker_std), source, tuple(warnings), unreadable(stated, readout))


def unreadable(stated: TactileArray, readout: TactileReadout) -> str:
    """Why these readings carry no force ("" when they may): none above zero, or none
    above the parameters' dead band (stated or the default: the data cannot tell a
    sensor with a lower band from readings in other units, kPa read as Pa, which would
    scale every stiffness; so the parameters must say which). No readings (forces fed
    without their images): nothing to judge."""
    if not readout.readings:
        return ""
    if not readout.largest > 0:
        return "every reading is 0 or below: the array read no load"
    if stated.threshold > 0 and readout.largest < stated.threshold:
        return (f"the largest reading is {readout.largest:.3g} Pa, under the {stated.threshold:g} Pa dead band "
                "of the parameters (tactile.threshold): by them the array reads nothing, so no push can be "
                "identified; kPa read as Pa? (a sensor with a lower dead band: state it in tactile.threshold)")
    return ""


FAULT_MARGIN = 6.0     # cell noise stds between a faulty cell and the load it missed
FAULT_SHARE = 0.05     # ... and at least this share of that load (noise-free readings)
MIN_DEAD_RUN = 10      # frames of one reading under a load before a cell is called dead


def cell_faults(readout: TactileReadout, threshold: float, noise: float, resolution: float,
                saturation: float) -> tuple[CellFault, ...]:
    """The cells that do not read their load, each against the other cells of its
    column (in the plane model the pressure is the same along z; across a segment's
    columns it is not), of its segment for a one-row array: a cell that ends with one
    reading (``dead``: 0, or stuck; throughout or from when it died) while the others
    read clearly above it and the dead band meanwhile, or one whose highest reading,
    met in many frames (as ``read_sensor``'s saturation), is clearly under their peak
    and under the array's saturation (``saturated`` alone). Clearly: ``FAULT_MARGIN``
    cell noises, two steps and ``FAULT_SHARE`` of the load."""
    if readout.cell_high is None:
        return ()
    high = readout.cell_high
    value, load = readout.cell_last, readout.cell_load
    peak = readout.peers_median(high[None])[0]
    has_others = peak > -np.inf
    floor = max(threshold, 0.0)
    dead = has_others & (readout.cell_run >= MIN_DEAD_RUN) & (
        load > np.maximum(value, floor) + _clear(noise, resolution, load))
    often = _often(readout.cell_at_high, readout.frames)
    saturated = (has_others & ~dead & often & (floor < high) & (high < saturation)
                 & (peak > high + _clear(noise, resolution, peak)))
    faults = []
    for r, c in np.argwhere(dead | saturated):   # row-major, as the warnings are listed
        if dead[r, c]:
            since = float(readout.cell_since[r, c])
            faults.append(CellFault(int(r), int(c), "dead", float(value[r, c]), float(load[r, c]),
                                    None if since == readout.first_t else since))
        else:
            faults.append(CellFault(int(r), int(c), "saturated", float(high[r, c]), float(peak[r, c])))
    return tuple(faults)


def _clear(noise: float, resolution: float, load: np.ndarray) -> np.ndarray:
    """How far a load must be above a cell's reading to be clearly missed by it."""
    return np.maximum(max(FAULT_MARGIN * float(np.nan_to_num(noise)), 2.0 * resolution), FAULT_SHARE * load)


def _often(count: int | np.ndarray, frames: int) -> bool | np.ndarray:
    """A highest reading met in this many of ``frames`` is a ceiling (saturation): a
    smooth load passes its peak once."""
    return count >= max(10, 0.01 * frames)


def _agrees(stated: float, shown: float) -> bool:
    """A stated noise agrees with the data's within ``NOISE_AGREES`` (zero only with zero)."""
    if stated == 0 or shown == 0:
        return stated == shown
    return 1.0 / NOISE_AGREES <= stated / shown <= NOISE_AGREES
