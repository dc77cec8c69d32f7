"""The whole-record fit: every phase, every node's force and every marker, fitted
with the FE model (its quasi-static limit, ``rheo_ros.fe.quasistatic``), with
standard deviations from the covariance; and the Cramer-Rao bound of the same
problem, the best any unbiased estimator can do on such data.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.differentiate import jacobian
from scipy.optimize import brentq, least_squares
from scipy.sparse import csr_matrix
from scipy.special import expit, logit

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import GAMMA_RANGE
from rheo_ros.fe.quasistatic import Prediction, QuasiStaticFE
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.noise import Weights, sensor_noise, spikes_note
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record, contact_time
from rheo_ros.sensors import DeadBand

SEARCH_LIMIT = 30.0         # transformed parameters beyond +-30: e^30 times the start, or gamma at its bound
# The streams' clock offsets against the stage's (s, positive: stamped late). Beyond
# +-DELAY_LIMIT a shifted sample could cross a phase boundary (0.05 s are left out at
# each): such an offset is reported as not determined. A 20 ms late tactile stream left unfitted moves c1 by -0.18 %
# (3 std) on `clean_short_keep`, with residuals still at the noise.
# A prior of DELAY_PRIOR_STD on each offset (clocks a robot's drivers keep within ~10 ms)
# holds an offset the data barely see (a shallow push: tactile std 7 ms) from trading
# against c1 out to the limit; where the data see it (1.8 ms) they decide.
DELAYS = ("tactile_delay", "marker_delay")
DELAY_LIMIT = 0.04
DELAY_PRIOR_STD = 0.01
# Force samples this close (s) to a phase boundary are left out: the measured force is
# mid-jump there, the quasi-static model has jumped.
BOUNDARY_GUARD = 0.05
MAX_PASSES = 4          # weighted fits, the weights from the previous pass's residuals
WEIGHT_CHANGE = 0.02    # weights that moved less than this (relative) are settled
# A mesh's error ~ h^p: each halving of h leaves DISCRETISATION_RATIO = 2^-p of the shift
# before it (p = 1.4, below Q4's 2: the bonded corners' singularity). Measured on noise-free
# data from a 257 x 257 mesh (`rheo bench mesh`), shift 65->129 over 33->65: E 0.354,
# c1 0.367, c2 0.515, gamma 0.418; on the simulator's default experiment, shift 129->257
# over 65->129: 0.35-0.38 for all four, while 65->129 over 33->65 was still 0.74 for gamma
# (not yet asymptotic): so the ratio is fixed, not read off the two shifts a fit computes.
DISCRETISATION_RATIO = 0.37
# Residual RMS over the noise the data show (second differences) above this: a misfit.
# A right model gives 1 within the two estimates' spread, ~1.3 / sqrt(samples) (RMS
# 0.7, the differences' median absolute deviation ~1.1), measured by `rheo bench
# calibration`: up to 1.06 on ~3000 live readings, 1.17 on a shallow push's few hundred.
MISFIT_RATIO = 1.25
MISFIT_SIGMAS = 5.0
# Readings under the live threshold averaged into one pair of bounds (``ReadingWindows``): as
# many as the live rule's window (``noise.LIVE_WINDOW``), half a second at 50 Hz.
READING_WINDOW = 25
# Readings of a segment under the band in a long window (five seconds at 50 Hz): a force
# steady there (a held adhesion) shows in their mean to a tenth of what a short window's
# margin lets through. Their margin is their own spread, never under this share of the
# live noise (a window all zero by chance says no more than a short one).
LONG_WINDOW = 250
LONG_MARGIN_FLOOR = 0.25
# The solves' relative tolerance on the cost and the step (MINPACK's ftol, xtol). At 1e-8
# the parameters stay within 1.2e-3 of their std of those at 1e-10, with 17 % less time
# over three reference bags' analyses (measured, stop 49): the last iterations moved nothing.
SOLVER_TOLERANCE = 1e-8
# The solve before the clock offsets join (``_solve``) only brings them near: the solve with
# them moves the cost on by far more (a misfitting base: 3 263 078 -> 3 219 332). At 1e-4
# instead of SOLVER_TOLERANCE, a discovery's evaluations fell 13-19 % with the final
# parameters within 8e-4 of their std (stop 73).
NEAR_TOLERANCE = 1e-4
OVERFLOW_RESIDUAL = 1e6   # noise stds: a residual of a model whose forces overflowed
# Above this many live force readings the solver takes their means over bins (``LiveBins``):
# its Jacobian's rows, and the memory and the factorisations that go with them, stay bounded
# whatever the record's length or rate. Every record (0): on a 170 s generator record the
# analysis 11.6 -> 9.3 s, its parameters within 0.015 of their std (stop 73); 50 000 before.
REDUCE_ABOVE = 0
# A bin spans BIN_GROWTH of the time since its phase began, and at least BIN_MIN s: the
# responses relax like exponentials, which move by at most BIN_GROWTH / e of their size
# over such a bin, so the means keep the shape.
BIN_GROWTH = 0.02
BIN_MIN = 0.02


def misfit_limit(samples: int) -> float:
    """The largest residual-to-noise ratio a right model shows on ``samples`` readings."""
    return max(MISFIT_RATIO, 1.0 + MISFIT_SIGMAS * 1.3 / np.sqrt(max(samples, 1)))


class LiveBins:
    """The live force readings grouped by segment and by bin of time (``BIN_GROWTH``,
    ``BIN_MIN``, the bins restarting at each phase boundary in ``edges``), and the map of
    their weighted residuals to one row per group: the sum over the group over the square
    root of its size, which is the group's mean residual weighted by its own noise (the
    exact likelihood of the mean). The rows are orthonormal combinations of the readings',
    so J^T J of the groups is the readings' wherever the model's slope is the same across a
    group, and ``expand`` spreads a group's row back over its readings.

    Args:
        t: (T,) the readings' times (s); node: (n,) each live reading's segment and
            row: (n,) its row in ``t``, in the fit's (row-major) order; edges: the phase
            boundaries (s).
    """

    def __init__(self, t: np.ndarray, row: np.ndarray, node: np.ndarray, edges: np.ndarray) -> None:
        edges = np.sort(np.asarray(edges, float))
        # Each temporary is dropped once used: an hour at 500 Hz is 9 million readings.
        tr = np.asarray(t, float)[row]
        phase = np.searchsorted(edges, tr, side="right")
        since = tr - np.concatenate([[tr.min() if tr.size else 0.0], edges])[phase]
        del tr
        step = np.floor(np.log1p(np.maximum(since, 0.0) / (BIN_MIN / BIN_GROWTH)) / np.log1p(BIN_GROWTH))
        del since
        step = step.astype(np.int64)
        # One code per (segment, phase, bin); a stable sort keeps each bin's readings in the
        # fit's order, which is in time: by segment, phase, bin, then time, on one key.
        code = (np.asarray(node, np.int64) * (edges.size + 1) + phase) * (int(step.max(initial=0)) + 1) + step
        del phase, step
        key = np.argsort(code, kind="stable")
        self.order = key
        code = code[key]
        first = np.ones(key.size, bool)
        first[1:] = code[1:] != code[:-1]
        del code
        self.starts = np.flatnonzero(first)
        sizes = np.diff(np.append(self.starts, key.size))
        self.scale = 1.0 / np.sqrt(sizes)
        self.group = np.empty(key.size, np.intp)            # each reading's group, in the fit's order
        self.group[key] = np.cumsum(first) - 1

    @property
    def groups(self) -> int:
        return int(self.starts.size)

    def reduce(self, r: np.ndarray) -> np.ndarray:
        """(groups,) rows of the readings' weighted residuals ``r`` (n,)."""
        return np.add.reduceat(r[self.order], self.starts) * self.scale

    def expand(self, rows: np.ndarray) -> np.ndarray:
        """(n, ...) the readings' rows of groups' rows (groups, ...): each group's row over
        the square root of its size, on each of its readings (the inverse on the span)."""
        scaled = rows * (self.scale if rows.ndim == 1 else self.scale[:, None])
        return scaled[self.group]


class BinTimes:
    """The times at which the solver asks the model's force when the live readings are
    binned (``LiveBins``), and the bins' rows from the force there. A bin's row holds the
    mean of the model over its readings' times; it is taken as the mean at the two points
    t_mean -+ t_std of those times (Gauss's two-point rule for their spread: exact for a
    force quadratic across the bin, which spans BIN_GROWTH of its phase's age), so each
    evaluation costs two model times a bin, not one a reading: the evaluations' time and
    memory no longer grow with the rate, nor with the length but as the bins' logarithm.
    The readings that bound the force (``ReadingBounds``) are asked at their own times.
    ``WholeRecordProblem.within_bins`` and the statistics still take every reading.

    Args:
        bins: the bins; t: (n,) each live reading's time, node: (n,) its segment,
            force: (n,) its reading (N), in the fit's order; nodes: segments a frame;
            frame_t: (T,) the fitted frames' times; bounded: flat (row-major) indices of
            the readings that bound the force, in (T, nodes) (None: none).
    """

    def __init__(self, bins: LiveBins, t: np.ndarray, node: np.ndarray, force: np.ndarray, nodes: int,
                 frame_t: np.ndarray, bounded: np.ndarray | None) -> None:
        size = np.diff(np.append(bins.starts, bins.order.size)).astype(float)
        ordered = t[bins.order]
        mean_t = np.add.reduceat(ordered, bins.starts) / size
        spread = np.sqrt(np.maximum(np.add.reduceat((ordered - np.repeat(mean_t, size.astype(int))) ** 2,
                                                    bins.starts) / size, 0.0))
        points = np.concatenate([mean_t - spread, mean_t + spread])
        bound_t = np.empty(0) if bounded is None else frame_t[bounded // nodes]
        self.times = np.unique(np.concatenate([points, bound_t]))
        self.node = node[bins.order[bins.starts]]   # each bin's segment
        self._at = np.searchsorted(self.times, points) * nodes + np.tile(self.node, 2)
        self._mean = np.add.reduceat(force[bins.order], bins.starts) / size
        self._root = np.sqrt(size)
        self.bounded = (np.empty(0, np.intp) if bounded is None else
                        np.searchsorted(self.times, bound_t) * nodes + bounded % nodes)

    def rows(self, force: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """(groups,) the bins' rows (``LiveBins.reduce`` of the weighted residuals) from the
        model's forces at ``times`` (flat, row-major: (times, nodes)) and each bin's noise
        (N, by ``node``)."""
        model = 0.5 * force[self._at].reshape(2, -1).sum(axis=0)
        return (model - self._mean) * self._root / noise


@dataclass
class WholeRecordProblem:
    """Weighted residuals of a record against the forward model.

    Args:
        record: the data.
        model: the model whose parameters are fitted (values are ignored).
        force_std: per-node force noise (N); marker_std: marker noise (m).
        profile: the stage profile (default: read off the record's stage).
        guard: force samples this close (s) to a phase boundary are left out
            (``BOUNDARY_GUARD``).
        forward: the forward model (default: the record's marker grid, nodal forces).
        live: (T, nodes) the force readings that count (default: all); readings in
            or near the tactile dead band are biased towards zero and left out.
        delays: also fit the tactile and marker streams' clock offsets against the
            stage's (``DELAYS``, s).
        ceiling: (nodes,) N: the highest force a reading that is not live can stand for
            (the live threshold); a model predicting more there is penalised by the
            excess over the noise (a censored reading: the sensor read nothing, so the
            force was below it). None: readings that are not live are left out.
        top: (nodes,) N: the lowest force a saturated reading (one above it) can stand
            for; a model predicting less there is penalised likewise. None: no saturation.
        window_std: (nodes,) N: the sensor noise by which windows of readings that are not
            live bound the mean force from both sides (``ReadingWindows``): a model outside
            is penalised by the excess. None: no such bound.
        excluded: (T, nodes) readings neither live nor a bound (isolated spikes,
            ``SensorNoise.force_spikes``); None: none.

    Each marker's starting position is a nuisance parameter (markers are not on the
    design grid to the micrometre): it is profiled out, residuals taken about each
    marker's mean over the frames, so only the motion informs the fit.
    """

    record: Record
    model: Model
    force_std: np.ndarray
    marker_std: float
    profile: StageProfile | None = None
    guard: float = BOUNDARY_GUARD
    forward: QuasiStaticFE | None = None
    live: np.ndarray | None = None
    delays: bool = False
    ceiling: np.ndarray | None = None
    top: np.ndarray | None = None
    window_std: np.ndarray | None = None
    excluded: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.profile = self.profile or self.record.profile()
        self._use = away_from_boundaries(self.record.force_t, self.profile, contact_time(self.record),
                                         self.guard)
        self._force = self.record.force[self._use]
        self._live = (np.ones(self._force.shape, bool) if self.live is None else self.live[self._use])
        # The readings that bound the model: neither live nor left out.
        self._bounded = ~self._live if self.excluded is None else ~self._live & ~self.excluded[self._use]
        band = self.record.dead_band
        windows = (None if self.window_std is None or band is None else
                   ReadingWindows(band, self._force, self._bounded, self.window_std))
        self._bounds = (None if self.ceiling is None else
                        ReadingBounds(self._force, self.ceiling, self.top, windows, np.flatnonzero(self._bounded)))
        # The live readings as flat (row-major) indices: a fit takes them at every evaluation.
        self._live_at = np.flatnonzero(self._live)
        self._live_node = self._live_at % self._force.shape[1]
        self._live_force = self._force.ravel()[self._live_at]
        edges = np.array([self.profile.t_pull_start, contact_time(self.record), self.profile.t_pull_end,
                          self.profile.t_keep_end])
        self._bins = (LiveBins(self.record.force_t[self._use], self._live_at // self._force.shape[1],
                               self._live_node, edges[np.isfinite(edges)])
                      if self._live_at.size > REDUCE_ABOVE else None)
        self._own = frozenset(self.model.parameters)   # the model's names: read at every evaluation
        self.forward = self.forward or QuasiStaticFE(self.record.mesh)
        self.names = tuple(self.model.parameters) + ("gamma",) + (DELAYS if self.delays else ())
        self._disp = self.record.markers - self.record.mesh.nodes[None]

    def on(self, forward: QuasiStaticFE) -> WholeRecordProblem:
        """This problem on another forward model (a finer mesh): the data's layout (live
        readings, bounds, bins) shared, not laid out again; what depends on the forward
        model found again on first use."""
        other = copy.copy(self)
        other.__dict__.pop("_markers_in_span", None)
        other.forward = forward
        return other

    @cached_property
    def _markers_in_span(self) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The solver's markers (None: every row): the span of the elastic shapes (the
        model reaches no other direction), the centred data in it, and the size of the
        rest. Found on first use: only the fitted problem needs it, not its finer meshes'."""
        span = None if self.model.moves_markers or not np.isfinite(self._disp).all() else self.forward.marker_span
        if span is None:
            return None
        centred = (self._disp - self._disp.mean(axis=0)).reshape(len(self._disp), -1)
        inside = centred @ span
        return span, inside, float(np.linalg.norm(centred - inside @ span.T))

    @property
    def live_mask(self) -> np.ndarray:
        """(T, nodes) the force readings fitted (away from the phase boundaries, live)."""
        return self._live

    @property
    def live_counts(self) -> np.ndarray:
        """(nodes,) force readings fitted per node."""
        return self._live.sum(axis=0)

    @property
    def marker_count(self) -> int:
        return int(self._disp.size)

    @property
    def samples(self) -> int:
        """Readings the fit rests on: live force readings and marker coordinates (the
        censored readings only bound the model, they add no count)."""
        return int(self.live_counts.sum()) + self.marker_count

    def _at(self, params: dict[str, float]) -> tuple[Model, bool, tuple[np.ndarray, np.ndarray]]:
        """The model at ``params``, whether it reads every sample, and the times to predict."""
        model = self.model.with_parameters({k: v for k, v in params.items() if k in self._own})
        # An effect with memory reads every sample's past: it gets every reading's time,
        # not only the fitted ones (a gap at a phase boundary would hold its input there).
        every = bool(model.memory)
        force_t = self.record.force_t if every else self.record.force_t[self._use]
        return model, every, (force_t - params.get("tactile_delay", 0.0),
                              self.record.marker_t - params.get("marker_delay", 0.0))

    def predict(self, params: dict[str, float]) -> Prediction:
        model, every, times = self._at(params)
        pred = self.forward.predict(model, params["gamma"], self.profile, *times)
        return replace(pred, force=pred.force[self._use]) if every else pred

    def dynamic_predict(self, params: dict[str, float]) -> Prediction | None:
        """``predict`` with inertia and the stage's compliance
        (``QuasiStaticFE.dynamic_predict``; None where the forward model has none)."""
        model, every, times = self._at(params)
        pred = self.forward.dynamic_predict(model, params["gamma"], self.profile, *times)
        return replace(pred, force=pred.force[self._use]) if every and pred is not None else pred

    def _noise_at(self, node: np.ndarray) -> np.ndarray:
        """The force weight of each reading of segment ``node`` (flat readings' segments)."""
        return np.broadcast_to(self.force_std, (self._force.shape[1],))[node]

    def _force_residuals(self, force: np.ndarray) -> np.ndarray:
        """The live readings' weighted residuals, row-major (in the order a boolean mask takes them)."""
        return (force.ravel()[self._live_at] - self._live_force) / self._noise_at(self._live_node)

    def residuals(self, params: dict[str, float], p: Prediction | None = None) -> np.ndarray:
        """The weighted residuals at ``params`` (of the prediction ``p`` when given)."""
        with np.errstate(over="ignore", invalid="ignore"):   # an overflowing trial: _assemble
            p = self.predict(params) if p is None else p
            rf = self._force_residuals(p.force)
            rm = p.displacement - self._disp
            rm = (rm - rm.mean(axis=0)) / self.marker_std
            excess = None if self._bounds is None else self._bounds.excess(p.force)
        return self._assemble(params, rf, rm, excess)

    def solver_residuals(self, params: dict[str, float]) -> np.ndarray:
        """``residuals`` in the form the solver works on: the markers' rows turned to the
        span of the elastic shapes (``QuasiStaticFE.marker_span``, k directions of 2 N)
        and one fixed row for the data outside it. An orthogonal change of basis that
        drops rows no parameter moves: the same sum of squares and the same J^T J, on
        (Tm k + 1) marker rows instead of Tm 2 N (on the 5 x 5 grid, 8 a frame of 50).
        Above REDUCE_ABOVE live force readings, those too as their bins' means
        (``LiveBins``: the sum of squares less the scatter within the bins, ``within_bins``).
        ``from_solver`` turns the solver's rows back."""
        reduced = self._markers_in_span
        if reduced is None and self._bins is None:
            return self.residuals(params)
        model, every, times = self._at(params)
        with np.errstate(over="ignore", invalid="ignore"):   # an overflowing trial: _assemble
            if self._bins is not None and not every:
                plan = self._bin_times
                p = self.forward.predict(model, params["gamma"], self.profile,
                                         plan.times - params.get("tactile_delay", 0.0), times[1])
                f = p.force.ravel()
                rf = plan.rows(f, self._noise_at(plan.node))
                excess = None if self._bounds is None else self._bounds.excess_at(f[plan.bounded])
            else:
                p = self.predict(params)
                rf = self._force_residuals(p.force)
                if self._bins is not None:
                    rf = self._bins.reduce(rf)
                excess = None if self._bounds is None else self._bounds.excess(p.force)
            if reduced is None:
                rm = p.displacement - self._disp
                rm = (rm - rm.mean(axis=0)) / self.marker_std
            else:
                span, inside, outside = reduced
                depth = p.depth - p.depth.mean()
                rm = np.append(((np.outer(depth, p.shape.ravel() @ span) - inside) / self.marker_std).ravel(),
                               outside / self.marker_std)
        return self._assemble(params, rf, rm, excess)

    @cached_property
    def _bin_times(self) -> BinTimes:
        """Where the solver asks the model's force when the readings are binned (``BinTimes``)."""
        t = self.record.force_t[self._use]
        ncols = self._force.shape[1]
        at = None if self._bounds is None else self._bounds.at
        return BinTimes(self._bins, t[self._live_at // ncols], self._live_node, self._live_force, ncols, t, at)

    def within_bins(self, r: np.ndarray) -> float:
        """What the solver's rows leave out of the sum of squares of ``r`` (``residuals``
        at some parameters): the live readings' scatter about their bins' means (0 without
        bins). The solver's cost plus this is the whole record's."""
        if self._bins is None:
            return 0.0
        rf = r[:self._live_at.size]
        return float(rf @ rf - np.sum(self._bins.reduce(rf) ** 2))

    @property
    def solver_samples(self) -> int:
        """The solver's rows for the readings (live force readings, markers), before the
        clocks' prior and the bounds."""
        nf = self._bins.groups if self._bins is not None else self._live_at.size
        reduced = self._markers_in_span
        return nf + (self.marker_count if reduced is None else len(self._disp) * reduced[0].shape[1] + 1)

    def to_solver(self, v: np.ndarray) -> np.ndarray:
        """A vector in the rows of ``residuals`` in those of ``solver_residuals``: the live
        readings' bins summed (``LiveBins.reduce``), each frame's markers turned to the span,
        what lies outside it as one row of its norm. Linear but for that row, which no
        parameter moves (a least-squares solve against the solver's Jacobian ignores it)."""
        reduced = self._markers_in_span
        if reduced is None and self._bins is None:
            return v
        nf = self._live_at.size
        force = v[:nf] if self._bins is None else self._bins.reduce(v[:nf])
        if reduced is None:
            return np.concatenate([force, v[nf:]])
        span = reduced[0]
        tm, nm = self._disp.shape[0], self._disp[0].size
        markers = v[nf:nf + tm * nm].reshape(tm, nm)
        inside = markers @ span
        outside = np.linalg.norm(markers - inside @ span.T)
        return np.concatenate([force, inside.ravel(), [outside], v[nf + tm * nm:]])

    def from_solver(self, rows: np.ndarray) -> np.ndarray:
        """Rows of ``solver_residuals`` (a vector, or a matrix such as its Jacobian) in the
        rows of ``residuals``: the bins' rows spread over their readings, the markers' turned
        back from the span, the row outside it dropped. Exact for every vector the model
        moves (each marker column lies in the span; a bin's readings share its slope)."""
        reduced = self._markers_in_span
        if reduced is None and self._bins is None:
            return rows
        matrix = rows.reshape(rows.shape[0], -1)
        nf = self._bins.groups if self._bins is not None else self._live_at.size
        force = matrix[:nf] if self._bins is None else self._bins.expand(matrix[:nf])
        if reduced is None:
            out = np.concatenate([force, matrix[nf:]])
        else:
            span = reduced[0]
            tm, k = len(self._disp), span.shape[1]
            markers = np.einsum("tkp,ck->tcp", matrix[nf:nf + tm * k].reshape(tm, k, -1), span)
            out = np.concatenate([force, markers.reshape(-1, matrix.shape[1]), matrix[nf + tm * k + 1:]])
        return out.reshape(-1, *rows.shape[1:])

    def _assemble(self, params: dict[str, float], rf: np.ndarray, rm: np.ndarray,
                  excess: np.ndarray | None) -> np.ndarray:
        """The residual vector: live force readings, markers, the clocks' prior, the bounds
        (``excess``: ``ReadingBounds.excess`` of the prediction, N)."""
        prior = [params[n] / DELAY_PRIOR_STD for n in DELAYS] if self.delays else []
        parts = [rf.ravel(), rm.ravel(), prior]
        if excess is not None:
            with np.errstate(over="ignore", invalid="ignore"):
                parts.append(excess / self._noise_at(self._bounds.node))
        r = np.concatenate(parts)
        # A trial step whose model overflows (a stiffening law at a huge coefficient) fits
        # nothing: a large residual, not a NaN the solver cannot compare, nor a zero.
        return r if np.all(np.isfinite(r)) else np.nan_to_num(r, nan=OVERFLOW_RESIDUAL, posinf=OVERFLOW_RESIDUAL,
                                                                neginf=-OVERFLOW_RESIDUAL)

    def group_rms(self, params: dict[str, float]) -> tuple[np.ndarray, float]:
        """Unweighted RMS residual per node's force over its live readings (N; NaN for
        a node with none) and of the markers (m)."""
        p = self.predict(params)
        sq = np.where(self._live, (p.force - self._force) ** 2, 0.0)
        with np.errstate(invalid="ignore"):
            rf = np.sqrt(sq.sum(axis=0) / self._live.sum(axis=0))
        rm = p.displacement - self._disp
        n = rm.shape[0]
        return rf, float(np.sqrt(np.sum((rm - rm.mean(axis=0)) ** 2) / (rm.size * (n - 1) / n)))


def away_from_boundaries(t: np.ndarray, profile: StageProfile, contact: float,
                         guard: float = BOUNDARY_GUARD) -> np.ndarray:
    """Mask of times ``t`` at least ``guard`` s from every phase boundary of ``profile``
    and from the ``contact`` (``record.contact_time``): a later push meets the earlier
    ones' set after its pull began, and the force jumps there (the dashpot in the Voigt
    element) at an instant the parameters move; a reading beside it would pin them
    through a jump, not a slope (seen: c2's std 16 x too small, 15 std off)."""
    edges = np.array([profile.t_pull_start, contact, profile.t_pull_end, profile.t_keep_end])
    return np.abs(np.asarray(t)[:, None] - edges[None]).min(axis=1) >= guard


def steady_readings(record: Record) -> np.ndarray:
    """(T,) the record's force readings away from its phase boundaries and its contact
    (``away_from_boundaries``): the ones a fit, a comparison or a plot of residuals counts."""
    return away_from_boundaries(record.force_t, record.profile(), contact_time(record))


def live_ceiling(record: Record, force_std: np.ndarray) -> np.ndarray | None:
    """(nodes,) N: the largest force a reading that is not live can stand for (the
    dead band's live threshold at noise ``force_std``); None without a dead band."""
    band = record.dead_band
    return None if band is None else band.threshold(np.nan_to_num(force_std))


def bounds(record: Record, force_std: np.ndarray) -> dict[str, np.ndarray | None]:
    """What the record's readings that are not live say of the force, at noise
    ``force_std``: ``ceiling``, ``top`` and ``window_std`` of a ``WholeRecordProblem``."""
    return {"ceiling": live_ceiling(record, force_std), "top": live_top(record, force_std),
            "window_std": None if record.dead_band is None else np.asarray(force_std, float)}


class ReadingWindows:
    """What readings under the live threshold say of the force: in windows of a segment's
    such readings in a row, the mean force lies within three stds of the window's mean
    reading, less the most a reading exceeds its force (``DeadBand.excess``) and plus the
    most it falls short of it (``DeadBand.deficit``), whatever the force's spread over the
    cells. Means, not each reading: a held adhesion of 100 Pa a cell under 600 Pa of live
    threshold is inside any one reading's bounds but not a window's. Two sizes:
    ``READING_WINDOW`` readings (a bound that moves with the model: the noise's std as
    margin, safe for windows of a few readings that are all zero) and ``LONG_WINDOW``
    (a force steady under the band for seconds: the readings' own std as margin, tens of
    times smaller than the live noise where most cells read nothing). A saturated reading
    has its own bound (the top) and is in no window.

    Args:
        band: the dead band; readings: (T, nodes) N; bounded: (T, nodes) the readings
            that bound the force (not live, not left out); force_std: (nodes,) N, the
            sensor noise (a segment whose noise is not known has no window).
    """

    def __init__(self, band: DeadBand, readings: np.ndarray, bounded: np.ndarray, force_std: np.ndarray) -> None:
        std = np.asarray(force_std, float)
        std0 = np.nan_to_num(std)
        use = bounded & (readings <= band.top(std0)) & np.isfinite(std)[None]
        seg, self._t = np.nonzero(use.T)   # by segment, then in time
        self._seg, self.shape = seg, readings.shape
        values = readings[self._t, seg]
        excess, deficit = band.excess(std0), band.deficit(std0)
        self._label, self._size, window_seg = self._windows(seg, readings.shape[1], READING_WINDOW)
        mean = np.bincount(self._label, weights=values) / self._size
        margin = 3.0 * std0[window_seg] / np.sqrt(self._size)
        self.floor = mean - excess[window_seg] - margin
        self.ceiling = mean + deficit[window_seg] + margin
        self._long_label, self._long_size, long_seg = self._windows(seg, readings.shape[1], LONG_WINDOW)
        mean = np.bincount(self._long_label, weights=values) / self._long_size
        spread = np.sqrt(np.bincount(self._long_label, weights=(values - mean[self._long_label]) ** 2)
                         / np.maximum(self._long_size - 1.0, 1.0))
        margin = 3.0 * np.maximum(spread, LONG_MARGIN_FLOOR * std0[long_seg]) / np.sqrt(self._long_size)
        self.long_floor = mean - excess[long_seg] - margin
        self.long_ceiling = mean + deficit[long_seg] + margin
        # Both sizes' windows as the rows of one 0/1 matrix: a fit sums the model's forces
        # over them at every evaluation, one sparse product instead of four bincounts (a
        # row adds its readings in order from zero, as bincount does: the same sums).
        n = self._size.size
        rows = np.concatenate([self._label, n + self._long_label])
        entries = np.tile(np.arange(seg.size), 2)
        order = np.argsort(rows, kind="stable")
        self._sums = csr_matrix((np.ones(rows.size), (rows[order], entries[order])),
                                shape=(n + self._long_size.size, seg.size))
        self._all_size = np.concatenate([self._size, self._long_size])
        self._all_floor = np.concatenate([self.floor, self.long_floor])
        self._all_ceiling = np.concatenate([self.ceiling, self.long_ceiling])

    @property
    def flat(self) -> np.ndarray:
        """The readings in a window: flat (row-major) indices into (T, nodes), in the windows' order."""
        return self._t * self.shape[1] + self._seg

    @staticmethod
    def _windows(seg: np.ndarray, nodes: int, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each reading's window (``size`` of a segment's readings in a row, the last one
        short), each window's size and segment."""
        first = np.searchsorted(seg, np.arange(nodes))
        windows = -(-np.bincount(seg, minlength=nodes) // size)
        label = (np.concatenate([[0], np.cumsum(windows)[:-1]])[seg] + (np.arange(seg.size) - first[seg]) // size)
        # Every window holds at least one reading (a segment's count is split by ceiling).
        count = np.bincount(label).astype(float)
        window_seg = np.zeros(count.size, int)
        window_seg[label] = seg
        return label, count, window_seg

    def entry_excess(self, f: np.ndarray) -> np.ndarray:
        """``excess`` at the readings in a window only, from the model's forces there
        (``f``, in the order of ``flat``)."""
        sums = self._sums @ np.column_stack([f, np.maximum(f, 0.0)])
        mean, pressing = sums[:, 0] / self._all_size, sums[:, 1] / self._all_size
        outside = np.maximum(mean - self._all_ceiling, 0.0) + np.minimum(pressing - self._all_floor, 0.0)
        short, long = outside[self._label], outside[self._size.size + self._long_label]
        return np.where(np.abs(long) > np.abs(short), long, short)

    def excess(self, force: np.ndarray) -> np.ndarray:
        """(T, nodes) N: at each reading in a window, how far the window's mean model force
        lies above its ceiling (positive) or below its floor (negative), of its two windows
        the farther; 0 within them and at the other readings. Against the floor a model's
        pull counts as zero force (tension reads nothing)."""
        out = np.zeros(self.shape)
        if self._t.size:
            out[self._t, self._seg] = self.entry_excess(force[self._t, self._seg])
        return out


class ReadingBounds:
    """What the readings that are not live say of the force, at the readings ``at`` (flat,
    row-major indices into (T, nodes)): :meth:`excess`. Laid out once for a record: a fit
    asks it at every evaluation, for those readings alone.

    Args:
        readings: (T, nodes) N; ceiling: (nodes,) N, the live threshold; top: (nodes,) N,
            the top of the live range (None: no saturation); windows: the windows of
            readings under the threshold (None: none), each of them among ``at``.
    """

    def __init__(self, readings: np.ndarray, ceiling: np.ndarray, top: np.ndarray | None,
                 windows: ReadingWindows | None, at: np.ndarray) -> None:
        self.at, self.nodes = at, readings.shape[1]
        self.node = node = at % self.nodes
        self._ceiling = np.asarray(ceiling, float)[node]
        self._windows = windows
        self._in_window = None if windows is None else np.searchsorted(at, windows.flat)
        self._saturated = None if top is None else readings.ravel()[at] > top[node]
        self._top = None if top is None else top[node]

    def excess(self, force: np.ndarray) -> np.ndarray:
        """(at,) N: how far model forces (T, nodes) lie outside what the readings stand for:
        above the ``ceiling`` (positive), below a saturated reading's ``top`` (negative),
        outside their window's range (``ReadingWindows.excess``); 0 within them."""
        return self.excess_at(force.ravel()[self.at])

    def excess_at(self, f: np.ndarray) -> np.ndarray:
        """``excess`` from the model's forces at the readings ``at`` alone (``f``, (at,) N)."""
        excess = np.maximum(f - self._ceiling, 0.0)
        if self._windows is not None and self._in_window.size:
            excess[self._in_window] += self._windows.entry_excess(f[self._in_window])
        if self._top is not None:   # a saturated reading: the force was at least the top
            excess = np.where(self._saturated, np.minimum(f - self._top, 0.0), excess)
        return excess


def live_top(record: Record, force_std: np.ndarray) -> np.ndarray | None:
    """(nodes,) N: the smallest force a saturated reading can stand for (the top of the
    live range at noise ``force_std``); None without saturation."""
    band = record.dead_band
    return None if band is None or not np.any(np.isfinite(band.saturation)) else band.top(np.nan_to_num(force_std))


@dataclass(frozen=True)
class FitStatistics:
    """What the whole-record fit measured besides the parameters (after lmfit's
    ``MinimizerResult``: named figures, no keys to parse).

    Attributes:
        signals: the signals, ``P1``..``Pn`` (tactile segments, N) and ``markers`` (m).
        noise: the sensor noise the data show per signal (NaN: not known, a noise-free record).
        floor: what no fit of this model can go below, per signal, whatever the sensor:
            the forward model's discretisation (its predictions' move to the continuum,
            from the meshes 2 and 4 times as fine; 0 when not computed) and the readings'
            float32 resolution.
        weights: the noise the fit weighted each signal by (the noise, or estimated).
        residual_rms: unweighted residual RMS per signal (NaN: no live reading).
        fit_to_noise: ``residual_rms / hypot(noise, floor)`` per signal (NaN where neither is known).
        samples: readings per signal.
        clock_offsets: stream (``tactile``, ``marker``) -> (offset, std) in s against the stage's stamps.
        discretisation: the mesh's systematic std per parameter (0 when not computed).
        cost: chi-square at the weights; deviance: -2 log-likelihood at the weights (constants
            dropped), comparable between fits that estimated their own weights.
        dof: residual degrees of freedom; free_parameters: parameters fitted (offsets included).
        passes: weighted solves; message: the solver's.
        ranges: parameter -> (low, high): the ones only readings under the dead band hold,
            within the range over which the cost stays within 1 of its least (no slope at
            the fit to take a std from: the middle is the value, half the range its std).
    """

    signals: tuple[str, ...]
    noise: dict[str, float]
    floor: dict[str, float]
    weights: dict[str, float]
    residual_rms: dict[str, float]
    fit_to_noise: dict[str, float]
    samples: dict[str, int]
    clock_offsets: dict[str, tuple[float, float]]
    discretisation: dict[str, float]
    cost: float
    deviance: float
    dof: int
    free_parameters: int
    passes: int
    message: str
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def readings(self) -> int:
        """Readings the fit rests on (live force readings and marker coordinates)."""
        return int(sum(self.samples.values()))

    @property
    def reduced_chi2(self) -> float:
        return self.cost / self.dof

    @property
    def bic(self) -> float:
        """Bayesian information criterion ``cost + k ln n`` (meaningful with the sensor noise as weights)."""
        return self.cost + self.free_parameters * float(np.log(max(self.readings, 2)))

    @property
    def force_weights(self) -> np.ndarray:
        return np.array([self.weights[s] for s in self.signals if s != "markers"])

    def delay(self, stream: str) -> float:
        """The clock offset of ``stream`` (``tactile`` or ``marker``) in s (0: not fitted)."""
        return self.clock_offsets.get(stream, (0.0, np.inf))[0]

    def misfits(self) -> dict[str, float]:
        """Signals whose residuals exceed what the sensor noise allows: ratio by signal."""
        return {k: v for k, v in self.fit_to_noise.items() if np.isfinite(v) and v > misfit_limit(self.samples[k])}


class ParameterMap:
    """The one map between the searched vector ``x`` and the physical parameters.

    Every parameter is searched unbounded (MINPACK's Levenberg-Marquardt) through a
    transform that keeps it physical: positive ones as log(p / p0) (scale-free), the
    Poisson ratio as a logistic map onto GAMMA_RANGE, a signed one linearly in units of
    its start, a clock offset in units of its prior's std (a saturating map would stall
    the search at its flat ends). Clipped at SEARCH_LIMIT: a step on data that do not
    determine a parameter may ask for e^1000; such a parameter is reported with an
    infinite std, never a number. A clock offset is clipped at +-DELAY_LIMIT, where it is
    reported as not determined: a model that misfits (a base model beside a missing
    effect) pulls it on towards a phase boundary's jump, and the search walked there over
    20-38 iterations of the fit, 7-17 once clipped (a settling-drift bag's analysis 20.0 ->
    16.4 s, stop 59).
    """

    def __init__(self, names: tuple[str, ...], start: dict[str, float], signed: frozenset[str]) -> None:
        self.names = names
        self.p0 = np.array([start[n] for n in names], dtype=float)
        self.delay = np.array([n in DELAYS for n in names])
        self.ratio = np.array([n == "gamma" for n in names])
        self.signed = np.array([n in signed for n in names])
        self.positive = ~self.delay & ~self.ratio & ~self.signed
        self.linear_scale = np.where(self.signed & (self.p0 != 0), np.abs(self.p0), 1.0)

    def values(self, x: np.ndarray) -> np.ndarray:
        lo, hi = GAMMA_RANGE
        x = np.where(self.signed, x, np.clip(x, -SEARCH_LIMIT, SEARCH_LIMIT))
        return np.select([self.positive, self.ratio, self.signed],
                         [self.p0 * np.exp(np.where(self.positive, x, 0.0)), lo + (hi - lo) * expit(x),
                          self.p0 + self.linear_scale * x],
                         np.clip(DELAY_PRIOR_STD * x, -DELAY_LIMIT, DELAY_LIMIT))

    def start(self) -> np.ndarray:
        lo, hi = GAMMA_RANGE
        g0 = np.clip((self.p0 - lo) / (hi - lo), 1e-6, 1 - 1e-6)
        return np.select([self.positive, self.ratio, self.signed], [0.0, logit(g0), 0.0], self.p0 / DELAY_PRIOR_STD)

    def slope(self, x: np.ndarray) -> np.ndarray:
        """dp / dx at ``x``."""
        lo, hi = GAMMA_RANGE
        sig = expit(np.clip(x, -SEARCH_LIMIT, SEARCH_LIMIT))
        return np.select([self.positive, self.ratio, self.signed],
                         [self.values(x), (hi - lo) * sig * (1 - sig), self.linear_scale], DELAY_PRIOR_STD)

    def at_edge(self, x: np.ndarray) -> np.ndarray:
        """Parameters run to the edge of their search (a signed one has none)."""
        return ((~self.signed & (np.abs(x) >= 0.99 * SEARCH_LIMIT))
                | (self.delay & (np.abs(self.values(x)) >= 0.95 * DELAY_LIMIT)))


def _least_squares(fun, x0: np.ndarray, tol: float, max_iterations: int | None):
    # least_squares hands MINPACK its finite-difference Jacobian as a callable (lmder), so
    # nfev counts the function's own evaluations: about one per iteration, more on rejected steps.
    return least_squares(fun, x0, method="lm", xtol=tol, ftol=tol,
                         max_nfev=None if max_iterations is None else 2 * max_iterations)


def _solve(residuals, pmap: ParameterMap, x0: np.ndarray, tol: float, max_iterations: int | None):
    """The least-squares solve, the clock offsets joining once the rest is near its
    optimum: from a closed form 10 % off, a step along an offset could jump it across a
    phase boundary, where the model is discontinuous, and strand it there (seen: -300
    ms, residuals 3.4 x the noise)."""
    keep = ~pmap.delay
    full = x0.copy()

    def without_offsets(xs: np.ndarray) -> np.ndarray:
        full[keep] = xs
        return residuals(full)

    full[keep] = _least_squares(without_offsets, x0[keep], max(tol, NEAR_TOLERANCE), max_iterations).x
    return _least_squares(residuals, full, tol, max_iterations)


def _covariance(sol, pmap: ParameterMap, chi2: float) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the searched ``x`` (``(J^T J)^-1`` scaled by the reduced chi-square)
    and which parameters the data leave loose: at the edge of their search, or with no
    effect on the residuals (infinite variance; their curvature would say ~0)."""
    column = np.linalg.norm(sol.jac, axis=0)
    loose = pmap.at_edge(sol.x) | (column <= 1e-12 * max(column.max(), 1e-300))
    bounded = ~loose
    cov_x = np.zeros((len(pmap.names), len(pmap.names)))
    inverse = np.linalg.pinv(sol.jac[:, bounded].T @ sol.jac[:, bounded])
    # J^T J numerically singular: pinv leaves a variance of zero or below zero (its rounding)
    # where a direction was cut, which is no measurement but an undetermined parameter.
    degenerate = np.zeros_like(loose)
    degenerate[bounded] = ~(np.diag(inverse) > 0.0)
    cov_x[np.ix_(bounded, bounded)] = inverse * chi2
    cov_x[degenerate, :] = cov_x[:, degenerate] = 0.0
    return cov_x, loose | degenerate


def _held_by_bounds(residuals, x: np.ndarray, i: int, cost: float) -> tuple[float, float] | None:
    """The middle and half width of the range of searched parameter ``i`` over which the
    cost stays within 1 of ``cost`` (one std), the others held at ``x``; None when it does
    not rise on both sides within the search (a parameter the data do not bound).

    A parameter only readings that are not live inform (a held adhesion under the dead
    band: windows of readings bound the force from above and below, ``ReadingWindows``) leaves
    the cost flat between the bounds and no slope at the fit: its least-squares std is
    infinite, while the data do hold it in a range. The range's middle is its value, as
    good as any inside it, and half its width its std."""
    def rise(v: float) -> float:
        trial = x.copy()
        trial[i] = v
        r = residuals(trial)
        return float(r @ r) - cost - 1.0

    ends = []
    for sign in (-1.0, 1.0):
        step = 0.01
        while step <= 2.0 * SEARCH_LIMIT and rise(x[i] + sign * step) <= 0.0:
            step *= 2.0
        if step > 2.0 * SEARCH_LIMIT:
            return None
        inner = x[i] + sign * step / 2.0 if step > 0.01 else x[i]
        ends.append(brentq(rise, inner, x[i] + sign * step, xtol=1e-3))
    return 0.5 * (ends[0] + ends[1]), 0.5 * (ends[1] - ends[0])


def _discretisation_std(problem: WholeRecordProblem, params: dict[str, float], at_fit: np.ndarray, sol,
                        loose: np.ndarray, slope: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The distance to the continuum as a systematic std per searched parameter: the
    parameters' shifts on meshes 2 and 4 times as fine (one Gauss-Newton step each from
    the fit, J dx = -(r_finer - r)), and the geometric tail beyond them at
    DISCRETISATION_RATIO per halving. Also the part of that distance in the predictions
    the parameters cannot take up, per signal: (nodes,) N and the markers' m, RMS over the
    readings (the model's floor: a misfit it leaves however the data were made)."""
    bounded = ~loose
    finer = problem.forward.finer()
    r = [at_fit, problem.on(finer).residuals(params), problem.on(finer.finer()).residuals(params)]
    dx = np.zeros((len(loose), 2))
    dx[bounded] = -np.linalg.lstsq(sol.jac[:, bounded], np.column_stack([problem.to_solver(r[1] - r[0]),
                                                                         problem.to_solver(r[2] - r[1])]),
                                   rcond=None)[0]
    std = np.abs((dx[:, 0] + dx[:, 1] / (1.0 - DISCRETISATION_RATIO)) * slope)
    # The residuals' move to the continuum (the rest is the parameters' shift above).
    move = (r[1] - r[0]) + (r[2] - r[1]) / (1.0 - DISCRETISATION_RATIO)
    force_floor, marker_floor = _floor_of(problem, move, sol, loose)
    return std, force_floor, marker_floor


def _floor_of(problem: WholeRecordProblem, move: np.ndarray, sol, loose: np.ndarray) -> tuple[np.ndarray, float]:
    """The part of a move of the weighted residuals (``move``: live force readings
    row-major, then the markers) that no parameter change takes up, unweighted, as a
    floor: (nodes,) N and the markers' m, RMS over the readings. One level for every
    segment: how the projection spreads the move over the segments follows the fit's
    weights, not the model (a segment weighted heavily takes its move into the parameters
    and would claim a floor of almost nothing)."""
    jac = sol.jac[:, ~loose]   # the solver's rows (``WholeRecordProblem.to_solver``)
    move = move - problem.from_solver(jac @ np.linalg.lstsq(jac, problem.to_solver(move), rcond=None)[0])
    node = np.nonzero(problem.live_mask)[1]
    nodes = problem.live_mask.shape[1]
    force_move = move[:node.size] * np.broadcast_to(problem.force_std, (nodes,))[node]
    force_floor = np.full(nodes, float(np.sqrt(np.mean(force_move**2))) if force_move.size else 0.0)
    marker_move = move[node.size:node.size + problem.marker_count] * problem.marker_std
    return force_floor, float(np.sqrt(np.mean(marker_move**2))) if marker_move.size else 0.0


def _quasi_static_floor(problem: WholeRecordProblem, params: dict[str, float], at_fit: np.ndarray, sol,
                        loose: np.ndarray) -> np.ndarray | None:
    """(nodes + 1,): what the quasi-static limit leaves that no parameter takes up
    (``_floor_of``): the dynamic FE's prediction at the fit
    (``WholeRecordProblem.dynamic_predict``) less the quasi-static one. None where the
    forward model has no dynamics. Asked only of a signal the data show noise-free: a
    simulation stepping the stage's constraint at 1000 rad/s leaves its markers 8e-8 m off
    the quasi-static shape (the paper's Table I bags), which against no noise read as a
    misfit of 4e8 x."""
    dynamic = problem.dynamic_predict(params)
    if dynamic is None:
        return None
    return np.append(*_floor_of(problem, problem.residuals(params, dynamic) - at_fit, sol, loose))


def _reweighted(problem: WholeRecordProblem, residuals, unpack, pmap: ParameterMap, max_iterations: int | None,
                scale_f: np.ndarray) -> tuple[object, int]:
    """Weights from the residuals: a first solve with a loose tolerance (it only sets the
    weights), then solves from there with the weights from the previous pass's residual
    RMS per group until they settle (WEIGHT_CHANGE; a first pass stopped early leaves
    them too large, and the std with them). Returns the last solution and the passes."""
    sol, passes = _solve(residuals, pmap, pmap.start(), 1e-6, max_iterations), 1
    while passes < MAX_PASSES:
        rf, rm = problem.group_rms(unpack(sol.x))
        old = np.append(problem.force_std, problem.marker_std)
        problem.force_std = np.maximum(np.nan_to_num(rf, nan=1.0), 1e-9 * scale_f)
        problem.marker_std = max(rm, 1e-12)
        change = np.abs(np.append(problem.force_std, problem.marker_std) / old - 1).max()
        if passes > 1 and change < WEIGHT_CHANGE:
            break
        sol = _least_squares(residuals, sol.x, SOLVER_TOLERANCE, max_iterations)
        passes += 1
    return sol, passes


def fit_record(
    record: Record, initial: Estimate, model: Model | None = None, weights: Weights | None = None,
    fixed: dict[str, float] | None = None, forward: QuasiStaticFE | None = None,
    discretisation: bool = True, max_iterations: int | None = None,
) -> Estimate:
    """Fit the whole record starting from ``initial`` (for example a closed form).

    Args:
        record: the data.
        initial: the start (its parameters; the model's own values for the rest).
        model: the model fitted (default: the three-element model).
        weights: the noise to weight by (the sensor's, for a chi-square); None: estimated
            from the residuals of a first fit, per node and for the markers, and the fit
            repeated with those weights (a two-step weighted least squares).
        fixed: parameters held at these values.
        forward: the forward model (default: the record's marker grid).
        discretisation: add the forward model's discretisation error to the covariance
            (``_discretisation_std``).
        max_iterations: cap on each least-squares solve (None: scipy's default); a fit it
            stops says so in its message.

    Returns:
        The estimate (``method`` ``whole_record``) with ``statistics`` (``FitStatistics``).
        The covariance is ``(J^T J)^-1`` of the weighted problem scaled by the reduced
        chi-square, plus the discretisation's systematic variance.
    """
    model = model or Model(three_element(1.0, 1.0, 1.0))
    scale_f = np.abs(record.force).max(axis=0) * 1e-2 + 1e-12
    noise = sensor_noise(record)
    problem = WholeRecordProblem(
        record, model, weights.force_std if weights else scale_f, weights.marker_std if weights else 1e-5,
        forward=forward, live=noise.force_live, delays=True, **bounds(record, noise.force_std),
        excluded=noise.force_spikes,
    )
    fixed = fixed or {}
    all_names = problem.names
    names = tuple(n for n in all_names if n not in fixed)
    defaults = {**model.parameters, "gamma": 0.3, **dict.fromkeys(DELAYS, 0.0)}
    pmap = ParameterMap(names, {n: initial.params.get(n, v) for n, v in defaults.items() if n in names},
                        frozenset(model.signed_parameters))

    def unpack(x: np.ndarray) -> dict[str, float]:
        free = dict(zip(names, pmap.values(x).tolist()))
        return {n: free[n] if n in free else float(fixed[n]) for n in all_names}

    def residuals(x: np.ndarray) -> np.ndarray:
        return problem.solver_residuals(unpack(x))

    if weights is None:
        sol, passes = _reweighted(problem, residuals, unpack, pmap, max_iterations, scale_f)
    else:
        sol, passes = _solve(residuals, pmap, pmap.start(), SOLVER_TOLERANCE, max_iterations), 1
    params = unpack(sol.x)
    dof = max(problem.samples + len(DELAYS) - len(names), 1)
    solved = float(sol.fun @ sol.fun)   # the solver's cost: what a bound's range is judged on
    at_fit = problem.residuals(params)   # every reading, with the weights after the last pass
    cost = solved + problem.within_bins(at_fit)
    chi2 = cost / dof
    cov_x, loose = _covariance(sol, pmap, chi2)
    held: dict[str, tuple[float, float]] = {}
    if problem.ceiling is not None and problem.window_std is not None:
        # A parameter no live reading and no marker moves is held by the bounds alone: a
        # hinge barely active at the fit gives it a slope, and a std, that say nothing.
        column = np.linalg.norm(sol.jac, axis=0)
        measured = np.linalg.norm(sol.jac[:problem.solver_samples], axis=0)
        only = np.flatnonzero(~pmap.at_edge(sol.x) & (measured <= 1e-9 * column))
        ranges = [_held_by_bounds(residuals, sol.x, i, solved) for i in only]
        for i in only:
            cov_x[i, :] = cov_x[:, i] = 0.0
        loose[only] = True
        # Each range holds the others where they are: one the bounds leave open (adhesion
        # on a clean record: no fraction too small) leaves the others' ranges meaningless.
        if ranges and all(r is not None for r in ranges):
            for i, (middle, half_width) in zip(only, ranges):   # the middle, half the width as std
                sol.x[i], cov_x[i, i], loose[i] = middle, half_width**2, False
                at_ends = np.repeat(sol.x[None], 2, axis=0)
                at_ends[:, i] += [-half_width, half_width]
                low, high = sorted(float(pmap.values(x)[i]) for x in at_ends)
                held[names[i]] = (low, high)
            params = unpack(sol.x)
            at_fit = problem.residuals(params)
    slope = pmap.slope(sol.x)
    cov = np.zeros((len(all_names), len(all_names)))
    free = np.array([all_names.index(n) for n in names])
    cov[np.ix_(free, free)] = cov_x * np.outer(slope, slope)
    cov[free[loose], free[loose]] = np.inf
    sys_std = np.zeros(len(names))
    # Float32 readings: half an ulp of the force per reading, a floor below any model's reach.
    floor = (np.append(np.sqrt(np.mean(record.force**2, axis=0)), 0.0) * np.finfo(np.float32).eps / 2)
    if discretisation and (~loose).any():
        sys_std, force_floor, marker_floor = _discretisation_std(problem, params, at_fit, sol, loose, slope)
        cov[free, free] += np.where(loose, 0.0, sys_std**2)
        floor = np.hypot(floor, np.append(force_floor, marker_floor))
        # A noise-free signal is judged against the model's floor alone: there the quasi-static
        # limit's own (under any real noise, not computed beside it) is part of that floor.
        if noise.marker_std == 0.0 or np.any(noise.force_std == 0.0):
            quasi_static = _quasi_static_floor(problem, params, at_fit, sol, loose)
            if quasi_static is not None:
                floor = np.hypot(floor, quasi_static)
    stats = replace(_statistics(problem, noise, params, cov, all_names, names, dict(zip(names, sys_std.tolist())),
                                at_fit, cost, dof, passes, sol.message, floor), ranges=held)
    physical = [i for i, n in enumerate(all_names) if n not in DELAYS]
    edge = [n for n, flag in zip(names, loose) if flag]
    return Estimate(
        params={all_names[i]: params[all_names[i]] for i in physical},
        method="whole_record",
        equations=("eq.1/18-21 FE model, quasi-static limit", "weighted least squares over all phases"),
        covariance=cov[np.ix_(physical, physical)],
        message=_message(stats, edge) + (f"; {note}" if (note := spikes_note(record, noise.force_spikes)) else ""),
        statistics=stats,
    )


def _statistics(problem: WholeRecordProblem, noise, params: dict[str, float], cov: np.ndarray,
                all_names: tuple[str, ...], names: tuple[str, ...], systematic: dict[str, float],
                at_fit: np.ndarray, cost: float, dof: int, passes: int, message: str,
                floor: np.ndarray) -> FitStatistics:
    cols = problem.record.mesh.cols
    signals = tuple(f"P{i + 1}" for i in range(cols)) + ("markers",)
    rf, rm = problem.group_rms(params)
    counts = np.append(problem.live_counts, problem.marker_count)
    sigma = np.append(np.broadcast_to(problem.force_std, (cols,)), problem.marker_std)
    # -2 log-likelihood (constants dropped) at the noise levels the fit converged on (the
    # weights after the last pass, which may have moved them after the last solve): fits that
    # each estimated their own weights compare on this, not on cost; it holds every term the
    # fit minimises (censored readings, the clocks' prior).
    deviance = float(np.sum(counts * 2.0 * np.log(sigma)) + at_fit @ at_fit)
    shown = np.append(noise.force_std, noise.marker_std)
    # Against the noise and the floor together: a noise-free record is judged against what
    # the model itself cannot resolve, not against zero (NaN where neither is known).
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.append(rf, rm) / np.hypot(np.nan_to_num(shown), floor)
    ratio = np.where(np.isfinite(ratio), ratio, np.nan)
    std = np.sqrt(np.diag(cov))
    offsets = {n.removesuffix("_delay"): (float(params[n]), float(std[all_names.index(n)]))
               for n in DELAYS if n in names}
    return FitStatistics(
        signals=signals, noise=dict(zip(signals, shown.tolist())), floor=dict(zip(signals, floor.tolist())),
        weights=dict(zip(signals, sigma.tolist())),
        residual_rms=dict(zip(signals, np.append(rf, rm).tolist())), fit_to_noise=dict(zip(signals, ratio.tolist())),
        samples=dict(zip(signals, counts.astype(int).tolist())), clock_offsets=offsets,
        discretisation={n: v for n, v in systematic.items() if n not in DELAYS}, cost=cost, deviance=deviance,
        dof=dof, free_parameters=len(names), passes=passes, message=message,
    )


def _message(stats: FitStatistics, edge: list[str]) -> str:
    note = f"; not bounded by the data: {', '.join(edge)}" if edge else ""
    worst = stats.misfits()
    if worst:
        note += ("; WARNING: the model misfits: its residuals are " + ", ".join(
            f"{v:.3g} x the sensor noise on {k}" for k, v in sorted(worst.items(), key=lambda kv: -kv[1]))
            + " (expected 1): an effect the model lacks or a wrong set-up (boundary, geometry); "
            "the std assume white residuals and understate the error")
    for stream, (offset, std) in stats.clock_offsets.items():
        if np.isfinite(std) and abs(offset) > max(3 * std, 1e-3):
            note += f"; the {stream} stamps are {1e3 * offset:+.3g} +- {1e3 * std:.2g} ms off the stage's (fitted)"
    return f"{stats.passes} pass(es); {stats.message}{note}"


def cramer_rao_std(problem: WholeRecordProblem, params: dict[str, float]) -> dict[str, float]:
    """Cramer-Rao lower bound on the standard deviation of each parameter.

    Fisher information ``J^T J`` of the weighted residuals (unit-variance noise, and the
    clock offsets' prior when the problem fits them) at ``params`` (offsets not given:
    0); the Jacobian by scipy's adaptive finite differences, in steps relative to each
    parameter and in units of the prior's std for the offsets.
    """
    names = problem.names
    p = np.array([params.get(n, 0.0) if n in DELAYS else params[n] for n in names], dtype=float)
    scale = np.array([DELAY_PRIOR_STD if n in DELAYS else abs(v) for n, v in zip(names, p)])

    def f(x: np.ndarray) -> np.ndarray:
        # scipy.differentiate evaluates many points at once along the trailing axes.
        flat = x.reshape(len(names), -1)
        cols = [problem.residuals(dict(zip(names, (p + scale * flat[:, j]).tolist())))
                for j in range(flat.shape[1])]
        return np.stack(cols, axis=-1).reshape(-1, *x.shape[1:])

    J = jacobian(f, np.zeros(len(names)), initial_step=1e-4, maxiter=4).df
    cov = np.linalg.inv(J.T @ J) * np.outer(scale, scale)
    return dict(zip(names, np.sqrt(np.diag(cov)).tolist()))
