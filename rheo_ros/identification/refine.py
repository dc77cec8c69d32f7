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
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import three_element
from rheo_ros.record import Record


SEARCH_LIMIT = 30.0         # transformed parameters beyond +-30: e^30 times the start, or gamma at its bound
# A mesh's error ~ h^p: the error left after halving h is 2^-p of it; the error at h is the
# measured difference (h to h/2) times 1 / (1 - 2^-p). `rheo bench mesh` gives p ~ 1.3-1.4
# (E: 0.079 % at refine 4, 0.031 % at 8, ~0.012 % at 16): 1 / (1 - 2^-1.3) = 1.68.
DISCRETISATION_FACTOR = 1.7


@dataclass
class WholeRecordProblem:
    """Weighted residuals of a record against the forward model.

    Args:
        record: the data.
        model: the model whose parameters are fitted (values are ignored).
        force_std: per-node force noise (N); marker_std: marker noise (m).
        profile: the stage profile (default: read off the record's stage).
        guard: force samples this close (s) to a phase boundary are left out: the
            measured force is mid-jump there, the quasi-static model has jumped.
        forward: the forward model (default: the record's marker grid, nodal forces).

    Each marker's starting position is a nuisance parameter (markers are not on the
    design grid to the micrometre): it is profiled out, residuals taken about each
    marker's mean over the frames, so only the motion informs the fit.
    """

    record: Record
    model: Model
    force_std: np.ndarray
    marker_std: float
    profile: StageProfile | None = None
    guard: float = 0.05
    forward: QuasiStaticFE | None = None

    def __post_init__(self) -> None:
        self.profile = self.profile or self.record.profile()
        edges = np.array([self.profile.t_pull_start, self.profile.t_pull_end, self.profile.t_keep_end])
        t = self.record.force_t
        self._use = np.abs(t[:, None] - edges[None]).min(axis=1) >= self.guard
        self._force = self.record.force[self._use]
        self.forward = self.forward or QuasiStaticFE(self.record.mesh)
        self.names = tuple(self.model.parameters) + ("gamma",)
        self._disp = self.record.markers - self.record.mesh.nodes[None]

    def predict(self, params: dict[str, float]) -> Prediction:
        model = self.model.with_parameters({k: v for k, v in params.items() if k != "gamma"})
        return self.forward.predict(
            model, params["gamma"], self.profile, self.record.force_t[self._use], self.record.marker_t
        )

    def residuals(self, params: dict[str, float]) -> np.ndarray:
        p = self.predict(params)
        rf = (p.force - self._force) / self.force_std
        rm = p.displacement - self._disp
        rm = (rm - rm.mean(axis=0)) / self.marker_std
        return np.concatenate([rf.ravel(), rm.ravel()])

    def group_rms(self, params: dict[str, float]) -> tuple[np.ndarray, float]:
        """Unweighted RMS residual per node's force (N) and of the markers (m)."""
        p = self.predict(params)
        rf = np.sqrt(np.mean((p.force - self._force) ** 2, axis=0))
        rm = p.displacement - self._disp
        n = rm.shape[0]
        return rf, float(np.sqrt(np.sum((rm - rm.mean(axis=0)) ** 2) / (rm.size * (n - 1) / n)))


def _vector(names: tuple[str, ...], params: dict[str, float]) -> np.ndarray:
    return np.array([params[n] for n in names], dtype=float)


def refine(
    record: Record, initial: Estimate, model: Model | None = None,
    force_std: np.ndarray | None = None, marker_std: float | None = None,
    fixed: dict[str, float] | None = None, forward: QuasiStaticFE | None = None,
    discretisation: bool = True,
) -> Estimate:
    """Fit the whole record starting from ``initial`` (for example the paper's estimate).

    Noise levels not given are estimated from the residuals of a first fit, per node
    and for the markers, and the fit is repeated with those weights (a two-step
    weighted least squares). The covariance is ``(J^T J)^-1`` of the weighted
    problem scaled by the reduced chi-square, plus (``discretisation``) the forward
    model's discretisation error: the shift of the parameters that the same model on
    a mesh twice as fine would cause (one Gauss-Newton step), times
    ``DISCRETISATION_FACTOR`` for what remains beyond it, as a systematic std in
    ``residual_rms['discretisation_<name>']`` and added to the variance.
    """
    model = model or Model(three_element(1.0, 1.0, 1.0))
    scale_f = np.abs(record.force).max(axis=0) * 1e-2 + 1e-12
    problem = WholeRecordProblem(
        record, model,
        force_std if force_std is not None else scale_f,
        marker_std if marker_std is not None else 1e-5,
        forward=forward,
    )
    fixed = fixed or {}
    all_names = problem.names
    names = tuple(n for n in all_names if n not in fixed)
    start = {n: initial.params.get(n, v) for n, v in {**model.parameters, "gamma": 0.3}.items() if n in names}
    p0 = _vector(names, start)
    positive = np.array([n != "gamma" for n in names])
    lo, hi = GAMMA_RANGE

    # Every parameter is searched unbounded (MINPACK's Levenberg-Marquardt) through a
    # transform that keeps it physical: positive ones as log(p / p0) (scale-free), the
    # Poisson ratio as a logistic map onto (-1, 0.5). Clipped: a step on data that do
    # not determine a parameter may ask for e^1000; such a parameter is reported with
    # an infinite std below, never a number.
    def unpack(x: np.ndarray) -> dict[str, float]:
        x = np.clip(x, -SEARCH_LIMIT, SEARCH_LIMIT)
        values = np.where(positive, p0 * np.exp(np.where(positive, x, 0.0)), lo + (hi - lo) * expit(x))
        free = dict(zip(names, values.tolist()))
        return {n: free[n] if n in free else float(fixed[n]) for n in all_names}

    g0 = np.clip((p0 - lo) / (hi - lo), 1e-6, 1 - 1e-6)
    x0 = np.where(positive, 0.0, logit(g0))

    def solve(x0: np.ndarray, tol: float):
        return least_squares(lambda x: problem.residuals(unpack(x)), x0, method="lm", xtol=tol, ftol=tol)

    estimate_noise = force_std is None or marker_std is None
    # A first pass only sets the weights: a loose tolerance is enough.
    sol = solve(x0, 1e-6 if estimate_noise else 1e-10)
    passes = 1
    if estimate_noise:
        rf, rm = problem.group_rms(unpack(sol.x))
        if force_std is None:
            problem.force_std = np.maximum(rf, 1e-9 * scale_f)
        if marker_std is None:
            problem.marker_std = max(rm, 1e-12)
        sol = solve(sol.x, 1e-10)
        passes = 2
    params = unpack(sol.x)
    dof = max(sol.fun.size - len(names), 1)
    cost = float(sol.fun @ sol.fun)
    chi2 = cost / dof
    # A parameter at the edge of its search, or one the residuals do not depend on, is
    # not determined by these data: infinite variance (its curvature would say ~0).
    column = np.linalg.norm(sol.jac, axis=0)
    loose = (np.abs(sol.x) >= 0.99 * SEARCH_LIMIT) | (column <= 1e-12 * max(column.max(), 1e-300))
    bounded = ~loose
    cov_x = np.zeros((len(names), len(names)))
    cov_x[np.ix_(bounded, bounded)] = np.linalg.pinv(sol.jac[:, bounded].T @ sol.jac[:, bounded]) * chi2
    sig = expit(np.clip(sol.x, -SEARCH_LIMIT, SEARCH_LIMIT))
    d = np.where(positive, _vector(names, params), (hi - lo) * sig * (1 - sig))  # d p / d x
    cov = np.zeros((len(all_names), len(all_names)))
    free = np.array([all_names.index(n) for n in names])
    cov[np.ix_(free, free)] = cov_x * np.outer(d, d)
    cov[free[loose], free[loose]] = np.inf
    edge = [n for n, flag in zip(names, loose) if flag]
    note = f"; not bounded by the data: {', '.join(edge)}" if edge else ""
    systematic: dict[str, float] = {}
    if discretisation and bounded.any():
        # Residuals of the finer mesh minus this one's, at the fit: the parameter shift
        # it implies is the least-squares solution of J dx = -(r_fine - r).
        finer = replace(problem, forward=problem.forward.finer())
        shift_r = finer.residuals(params) - problem.residuals(params)
        dx = np.zeros(len(names))
        dx[bounded] = -np.linalg.lstsq(sol.jac[:, bounded], shift_r, rcond=None)[0]
        sys_std = DISCRETISATION_FACTOR * np.abs(dx * d)
        cov[free, free] += np.where(loose, 0.0, sys_std**2)
        systematic = {f"discretisation_{n}": float(v) for n, v in zip(names, sys_std)}
    rf, rm = problem.group_rms(params)
    return Estimate(
        params=params,
        method="whole_record",
        equations=("eq.1/18-21 FE model, quasi-static limit", "weighted least squares over all phases"),
        covariance=cov,
        residual_rms={"force": float(np.sqrt(np.mean(rf**2))), "markers": rm, "reduced_chi2": chi2,
                      "cost": cost, "marker_std": float(problem.marker_std),
                      **{f"force_std_P{i + 1}": float(v) for i, v in enumerate(np.broadcast_to(
                          problem.force_std, (record.mesh.cols,)))}, **systematic},
        message=f"{passes} pass(es); {sol.message}{note}",
    )


def cramer_rao_std(problem: WholeRecordProblem, params: dict[str, float]) -> dict[str, float]:
    """Cramer-Rao lower bound on the standard deviation of each parameter.

    Fisher information ``J^T J`` of the weighted residuals (unit-variance noise) at
    ``params``; the Jacobian by scipy's adaptive finite differences.
    """
    names = problem.names
    p = _vector(names, params)

    def f(x: np.ndarray) -> np.ndarray:
        # scipy.differentiate evaluates many points at once along the trailing axes.
        flat = x.reshape(len(names), -1)
        cols = [problem.residuals(dict(zip(names, (p * (1 + flat[:, j])).tolist())))
                for j in range(flat.shape[1])]
        return np.stack(cols, axis=-1).reshape(-1, *x.shape[1:])

    J = jacobian(f, np.zeros(len(names)), initial_step=1e-4, maxiter=4).df
    cov = np.linalg.inv(J.T @ J) * np.outer(p, p)
    return dict(zip(names, np.sqrt(np.diag(cov)).tolist()))
