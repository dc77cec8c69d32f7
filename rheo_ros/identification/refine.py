"""Whole-record refinement: every phase, every node's force and every marker, fitted
with the FE model (its quasi-static limit, ``rheo_ros.fe.quasistatic``), with
standard deviations from the covariance; and the Cramer-Rao bound of the same
problem, the best any unbiased estimator can do on such data.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.differentiate import jacobian
from scipy.optimize import least_squares
from scipy.special import expit, logit

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import GAMMA_RANGE
from rheo_ros.fe.quasistatic import Prediction, QuasiStaticFE
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.noise import sensor_noise
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record


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


def misfit_limit(samples: int) -> float:
    """The largest residual-to-noise ratio a right model shows on ``samples`` readings."""
    return max(MISFIT_RATIO, 1.0 + MISFIT_SIGMAS * 1.3 / np.sqrt(max(samples, 1)))


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

    def __post_init__(self) -> None:
        self.profile = self.profile or self.record.profile()
        self._use = away_from_boundaries(self.record.force_t, self.profile, self.guard)
        self._force = self.record.force[self._use]
        self._live = (np.ones(self._force.shape, bool) if self.live is None else self.live[self._use])
        self.forward = self.forward or QuasiStaticFE(self.record.mesh)
        self.names = tuple(self.model.parameters) + ("gamma",) + (DELAYS if self.delays else ())
        self._disp = self.record.markers - self.record.mesh.nodes[None]

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

    def predict(self, params: dict[str, float]) -> Prediction:
        model = self.model.with_parameters({k: v for k, v in params.items() if k in self.model.parameters})
        return self.forward.predict(
            model, params["gamma"], self.profile, self.record.force_t[self._use] - params.get("tactile_delay", 0.0),
            self.record.marker_t - params.get("marker_delay", 0.0),
        )

    def residuals(self, params: dict[str, float]) -> np.ndarray:
        p = self.predict(params)
        rf = ((p.force - self._force) / self.force_std)[self._live]
        rm = p.displacement - self._disp
        rm = (rm - rm.mean(axis=0)) / self.marker_std
        prior = [params[n] / DELAY_PRIOR_STD for n in DELAYS] if self.delays else []
        parts = [rf.ravel(), rm.ravel(), prior]
        if self.ceiling is not None:
            over = np.maximum(p.force - self.ceiling, 0.0) / self.force_std
            parts.append(np.nan_to_num(over[~self._live]))
        return np.concatenate(parts)

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


def away_from_boundaries(t: np.ndarray, profile: StageProfile, guard: float = BOUNDARY_GUARD) -> np.ndarray:
    """Mask of times ``t`` at least ``guard`` s from every phase boundary of ``profile``."""
    edges = np.array([profile.t_pull_start, profile.t_pull_end, profile.t_keep_end])
    return np.abs(np.asarray(t)[:, None] - edges[None]).min(axis=1) >= guard


def live_ceiling(record: Record, force_std: np.ndarray) -> np.ndarray | None:
    """(nodes,) N: the largest force a reading that is not live can stand for (the
    dead band's live threshold at noise ``force_std``); None without a dead band."""
    band = record.dead_band
    return None if band is None else band.threshold(np.nan_to_num(force_std))


def _vector(names: tuple[str, ...], params: dict[str, float]) -> np.ndarray:
    return np.array([params[n] for n in names], dtype=float)


def refine(
    record: Record, initial: Estimate, model: Model | None = None,
    force_std: np.ndarray | None = None, marker_std: float | None = None,
    fixed: dict[str, float] | None = None, forward: QuasiStaticFE | None = None,
    discretisation: bool = True, max_iterations: int | None = None,
) -> Estimate:
    """Fit the whole record starting from ``initial`` (for example the paper's estimate).

    Noise levels not given are estimated from the residuals of a first fit, per node
    and for the markers, and the fit is repeated with those weights (a two-step
    weighted least squares). The covariance is ``(J^T J)^-1`` of the weighted
    problem scaled by the reduced chi-square, plus (``discretisation``) the forward
    model's discretisation error: the shift of the parameters that the same model on
    meshes 2 and 4 times as fine would cause (one Gauss-Newton step each) and the tail
    beyond them at the mesh's convergence order (``DISCRETISATION_RATIO``), as a
    systematic std in ``residual_rms['discretisation_<name>']`` added to the variance.
    ``max_iterations`` caps each least-squares solve (None: scipy's default); a fit it
    stops says so in its message.
    """
    model = model or Model(three_element(1.0, 1.0, 1.0))
    scale_f = np.abs(record.force).max(axis=0) * 1e-2 + 1e-12
    noise = sensor_noise(record)
    problem = WholeRecordProblem(
        record, model,
        force_std if force_std is not None else scale_f,
        marker_std if marker_std is not None else 1e-5,
        forward=forward, live=noise.force_live, delays=True, ceiling=live_ceiling(record, noise.force_std),
    )
    fixed = fixed or {}
    all_names = problem.names
    names = tuple(n for n in all_names if n not in fixed)
    defaults = {**model.parameters, "gamma": 0.3, **dict.fromkeys(DELAYS, 0.0)}
    start = {n: initial.params.get(n, v) for n, v in defaults.items() if n in names}
    p0 = _vector(names, start)
    delay = np.array([n in DELAYS for n in names])
    ratio = np.array([n == "gamma" for n in names])
    signed = np.array([n in model.signed_parameters for n in names])
    positive = ~delay & ~ratio & ~signed
    # A signed parameter moves on a linear scale, in units of its start (1 when it starts at 0).
    linear_scale = np.where(signed & (p0 != 0), np.abs(p0), 1.0)
    lo, hi = GAMMA_RANGE

    # Every parameter is searched unbounded (MINPACK's Levenberg-Marquardt) through a
    # transform that keeps it physical: positive ones as log(p / p0) (scale-free), the
    # Poisson ratio as a logistic map onto (-1, 0.5), a clock offset in units of its
    # prior's std (a saturating map would stall the search at its flat ends). Clipped: a step on data that do not determine a parameter may
    # ask for e^1000; such a parameter is reported with an infinite std below, never a number.
    def values_of(x: np.ndarray) -> np.ndarray:
        # A signed parameter is linear in x: no edge to its search.
        x = np.where(signed, x, np.clip(x, -SEARCH_LIMIT, SEARCH_LIMIT))
        return np.select([positive, ratio, signed],
                         [p0 * np.exp(np.where(positive, x, 0.0)), lo + (hi - lo) * expit(x), p0 + linear_scale * x],
                         DELAY_PRIOR_STD * x)

    def unpack(x: np.ndarray) -> dict[str, float]:
        free = dict(zip(names, values_of(x).tolist()))
        return {n: free[n] if n in free else float(fixed[n]) for n in all_names}

    g0 = np.clip((p0 - lo) / (hi - lo), 1e-6, 1 - 1e-6)
    x0 = np.select([positive, ratio, signed], [0.0, logit(g0), 0.0], p0 / DELAY_PRIOR_STD)

    def max_nfev(n: int) -> int | None:
        # least_squares hands MINPACK its finite-difference Jacobian as a callable (lmder), so
        # nfev counts the function's own evaluations: about one per iteration, more on rejected steps.
        return None if max_iterations is None else 2 * max_iterations

    def solve(x0: np.ndarray, tol: float):
        return least_squares(lambda x: problem.residuals(unpack(x)), x0, method="lm", xtol=tol, ftol=tol,
                             max_nfev=max_nfev(x0.size))

    # The clock offsets join once the rest is near its optimum: from a closed form 10 %
    # off, a step along an offset could jump it across a phase boundary, where the model
    # is discontinuous, and strand it there (seen: -300 ms, residuals 3.4 x the noise).
    def solve_without_offsets(x0: np.ndarray, tol: float):
        keep = ~delay
        full = x0.copy()

        def fun(xs: np.ndarray) -> np.ndarray:
            full[keep] = xs
            return problem.residuals(unpack(full))

        part = least_squares(fun, x0[keep], method="lm", xtol=tol, ftol=tol, max_nfev=max_nfev(int(keep.sum())))
        full[keep] = part.x
        return full

    estimate_noise = force_std is None or marker_std is None
    # A first pass only sets the weights: a loose tolerance is enough. The weights are the
    # residuals' RMS per group; a pass that moved them more than WEIGHT_CHANGE is repeated
    # (a first pass stopped early leaves them too large, and the std with them).
    sol = solve(solve_without_offsets(x0, 1e-6 if estimate_noise else 1e-10), 1e-6 if estimate_noise else 1e-10)
    passes = 1
    while estimate_noise and passes < MAX_PASSES:
        rf, rm = problem.group_rms(unpack(sol.x))
        old = np.append(problem.force_std, problem.marker_std)
        if force_std is None:
            problem.force_std = np.maximum(np.nan_to_num(rf, nan=1.0), 1e-9 * scale_f)
        if marker_std is None:
            problem.marker_std = max(rm, 1e-12)
        change = np.abs(np.append(problem.force_std, problem.marker_std) / old - 1).max()
        if passes > 1 and change < WEIGHT_CHANGE:
            break
        sol = solve(sol.x, 1e-10)
        passes += 1
    params = unpack(sol.x)
    dof = max(problem.samples + len(DELAYS) - len(names), 1)
    cost = float(sol.fun @ sol.fun)
    chi2 = cost / dof
    # A parameter at the edge of its search, or one the residuals do not depend on, is
    # not determined by these data: infinite variance (its curvature would say ~0).
    column = np.linalg.norm(sol.jac, axis=0)
    values = values_of(sol.x)
    loose = ((~signed & (np.abs(sol.x) >= 0.99 * SEARCH_LIMIT)) | (column <= 1e-12 * max(column.max(), 1e-300))
             | (delay & (np.abs(values) >= 0.95 * DELAY_LIMIT)))
    bounded = ~loose
    cov_x = np.zeros((len(names), len(names)))
    cov_x[np.ix_(bounded, bounded)] = np.linalg.pinv(sol.jac[:, bounded].T @ sol.jac[:, bounded]) * chi2
    xc = np.clip(sol.x, -SEARCH_LIMIT, SEARCH_LIMIT)
    sig = expit(xc)
    d = np.select([positive, ratio, signed], [values, (hi - lo) * sig * (1 - sig), linear_scale],
                  DELAY_PRIOR_STD)  # dp / dx
    cov = np.zeros((len(all_names), len(all_names)))
    free = np.array([all_names.index(n) for n in names])
    cov[np.ix_(free, free)] = cov_x * np.outer(d, d)
    cov[free[loose], free[loose]] = np.inf
    edge = [n for n, flag in zip(names, loose) if flag]
    note = f"; not bounded by the data: {', '.join(edge)}" if edge else ""
    systematic: dict[str, float] = {}
    at_fit = problem.residuals(params)   # with the weights after the last pass
    if discretisation and bounded.any():
        # The distance to the continuum: the parameters' shifts on meshes 2 and 4 times as
        # fine (one Gauss-Newton step each from the fit, J dx = -(r_finer - r)), and the
        # geometric tail beyond them at DISCRETISATION_RATIO per halving.
        finer = problem.forward.finer()
        r = [at_fit, replace(problem, forward=finer).residuals(params),
             replace(problem, forward=finer.finer()).residuals(params)]
        dx = np.zeros((len(names), 2))
        dx[bounded] = -np.linalg.lstsq(sol.jac[:, bounded], np.column_stack([r[1] - r[0], r[2] - r[1]]),
                                       rcond=None)[0]
        to_continuum = dx[:, 0] + dx[:, 1] / (1.0 - DISCRETISATION_RATIO)
        sys_std = np.abs(to_continuum * d)
        cov[free, free] += np.where(loose, 0.0, sys_std**2)
        systematic = {f"discretisation_{n}": float(v) for n, v in zip(names, sys_std)}
    rf, rm = problem.group_rms(params)
    # -2 log-likelihood (constants dropped) at the noise levels the fit converged on (the
    # weights after the last pass, which may have moved them after the last solve): fits that
    # each estimated their own weights compare on this, not on cost; it holds every term the
    # fit minimises (censored readings, the clocks' prior).
    counts = np.append(problem.live_counts, problem.marker_count)
    sigma = np.append(np.broadcast_to(problem.force_std, (record.mesh.cols,)), problem.marker_std)
    deviance = float(np.sum(counts * 2.0 * np.log(sigma)) + at_fit @ at_fit)
    # NaN where the data show no noise (a noise-free simulation): no misfit figure then.
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.append(rf, rm) / np.append(noise.force_std, noise.marker_std)
    ratio = np.where(np.isfinite(ratio), ratio, np.nan)
    fit_to_noise = dict(zip([f"P{i + 1}" for i in range(rf.size)] + ["markers"], ratio.tolist()))
    samples = {**{f"P{i + 1}": int(n) for i, n in enumerate(problem.live_counts)}, "markers": problem.marker_count}
    worst = {k: v for k, v in fit_to_noise.items() if v > misfit_limit(samples[k])}
    if worst:
        note += ("; WARNING: the model misfits: its residuals are " + ", ".join(
            f"{v:.3g} x the sensor noise on {k}" for k, v in sorted(worst.items(), key=lambda kv: -kv[1]))
            + " (expected 1): an effect the model lacks or a wrong set-up (boundary, geometry); "
            "the std assume white residuals and understate the error")
    std = np.sqrt(np.diag(cov))
    clocks: dict[str, float] = {}
    for n in DELAYS:
        if n in names:
            i = all_names.index(n)
            clocks |= {f"{n}_s": params[n], f"{n}_std_s": float(std[i])}
            if np.isfinite(std[i]) and abs(params[n]) > max(3 * std[i], 1e-3):
                stream = n.split("_")[0]
                note += (f"; the {stream} stamps are {1e3 * params[n]:+.3g} +- {1e3 * std[i]:.2g} ms off the "
                         "stage's (fitted)")
    physical = [i for i, n in enumerate(all_names) if n not in DELAYS]
    return Estimate(
        params={all_names[i]: params[all_names[i]] for i in physical},
        method="whole_record",
        equations=("eq.1/18-21 FE model, quasi-static limit", "weighted least squares over all phases"),
        covariance=cov[np.ix_(physical, physical)],
        residual_rms={"force": float(np.sqrt(np.nanmean(rf**2))), "markers": rm, "reduced_chi2": chi2,
                      "cost": cost, "deviance": deviance, "samples": float(problem.samples),
                      "marker_std": float(problem.marker_std),
                      **{f"force_std_P{i + 1}": float(v) for i, v in enumerate(np.broadcast_to(
                          problem.force_std, (record.mesh.cols,)))}, **systematic,
                      **{f"noise_P{i + 1}": float(v) for i, v in enumerate(noise.force_std)},
                      "noise_markers": noise.marker_std,
                      **{f"fit_to_noise_{k}": v for k, v in fit_to_noise.items()}, **clocks},
        message=f"{passes} pass(es); {sol.message}{note}",
    )


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
