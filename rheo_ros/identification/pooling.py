"""Successive experiments on one object, pooled; an object that changed, flagged.

Each push's fit gives the base parameters with their covariance. Pushes on one unchanged
object estimate the same parameters, so their information adds: the pool's estimate is
the information-weighted mean (``C = (sum C_k^-1)^-1``, ``theta = C sum C_k^-1 theta_k``)
and its std falls as pushes come in. A push whose parameters disagree with the pool so
far beyond what both covariances allow (the squared Mahalanobis distance over the
chi-square quantile at ``LEVEL``) is another object or a changed one (damage,
temperature): it is flagged, with the parameters that moved, and starts a new pool.
A push the robot says is on another object (the action goal's ``object: new``) starts a
new pool whatever its parameters; the flag then says so (``stated``).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri, ndtri

from rheo_ros.identification.estimate import BASE_PARAMETERS, Estimate

# A false "changed" once in a thousand pushes of an unchanged object, if the stds are right.
LEVEL = 1e-3


@dataclass(frozen=True)
class Pool:
    """Experiments (1-based numbers) judged one object, and their joint estimate.

    ``chi2`` is the members' squared distance from the pooled values, each by its own
    covariance, on ``dof`` degrees of freedom: about ``dof`` when the stds are right."""

    experiments: tuple[int, ...]
    names: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray
    chi2: float = 0.0
    dof: int = 0

    @property
    def params(self) -> dict[str, float]:
        return dict(zip(self.names, self.values.tolist()))

    @property
    def std(self) -> dict[str, float]:
        return dict(zip(self.names, np.sqrt(np.diag(self.covariance)).tolist()))

    def to_json(self) -> dict:
        return {"experiments": list(self.experiments), "params": self.params,
                "std": {k: (v if np.isfinite(v) else None) for k, v in self.std.items()},
                "chi2": self.chi2, "dof": self.dof}


@dataclass(frozen=True)
class Change:
    """Experiment ``experiment`` disagrees with the pool before it: squared Mahalanobis
    distance ``distance`` over ``limit`` (the chi-square quantile at ``LEVEL``); ``moved``:
    the parameters whose own difference exceeds the two-sided normal quantile at
    ``LEVEL`` shared over the parameters, with their shift in stds. ``stated``: the robot
    said it is another object (the distance then only describes the difference; NaN when
    no parameter is shared)."""

    experiment: int
    distance: float
    limit: float
    moved: dict[str, float]
    stated: bool = False

    def to_json(self) -> dict:
        return {"experiment": self.experiment, "distance": _finite(self.distance), "limit": _finite(self.limit),
                "moved": self.moved, "stated": self.stated}

    def describe(self) -> str:
        """One line: why experiment ``experiment`` starts a new pool."""
        moved = ", ".join(f"{n} {z:+.3g} std" for n, z in self.moved.items())
        if self.stated:
            return f"experiment {self.experiment}: another object (said by the goal)" + (
                f"; moved {moved}" if moved else "")
        return (f"experiment {self.experiment}: another or a changed object: its parameters are "
                f"{self.distance:.3g} from the pool's (limit {self.limit:.3g})" + (f"; moved {moved}" if moved else ""))


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _information(estimate: Estimate, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Values and information matrix (the inverse covariance) of ``names``; a parameter
    the data leave open (infinite or missing variance) carries no information."""
    order = list(estimate.params)
    values = np.array([estimate.params[n] for n in names], float)
    if estimate.covariance is None:
        return values, np.zeros((len(names), len(names)))
    idx = [order.index(n) for n in names]
    cov = np.asarray(estimate.covariance, float)[np.ix_(idx, idx)]
    known = np.isfinite(np.diag(cov)) & (np.diag(cov) > 0) & np.isfinite(values)
    info = np.zeros_like(cov)
    if known.any():
        sub = cov[np.ix_(known, known)]
        if np.all(np.isfinite(sub)):
            info[np.ix_(known, known)] = np.linalg.pinv(sub)
    return np.where(known, values, 0.0), info


def _merge(members: list[tuple[int, np.ndarray, np.ndarray]], names: tuple[str, ...]) -> Pool:
    info = sum(i for _, _, i in members)
    cov = np.linalg.pinv(info)
    open_ = np.diag(info) <= 0
    values = cov @ sum(i @ v for _, v, i in members)
    cov[open_, :], cov[:, open_] = np.nan, np.nan
    cov[open_, open_] = np.inf
    values[open_] = np.nan
    shown = ~open_
    distance = sum(float((v - values)[shown] @ i[np.ix_(shown, shown)] @ (v - values)[shown]) for _, v, i in members)
    dof = sum(int(np.count_nonzero(np.diag(i)[shown] > 0)) for _, _, i in members) - int(shown.sum())
    return Pool(tuple(k for k, _, _ in members), names, values, cov, distance, max(dof, 0))


def pooled(estimates: Sequence[Estimate], names: Sequence[str], numbers: Sequence[int] | None = None) -> Pool:
    """The joint estimate of ``names`` from experiments judged one object (no change test):
    each estimate's information added. ``numbers``: their experiment numbers (default 1..n)."""
    numbers = numbers or range(1, len(estimates) + 1)
    names = tuple(names)
    return _merge([(k, *_information(e, names)) for k, e in zip(numbers, estimates)], names)


def pool_experiments(estimates: Sequence[Estimate], names: tuple[str, ...] = BASE_PARAMETERS[:3],
                     level: float = LEVEL, numbers: Sequence[int] | None = None,
                     new_objects: Collection[int] = ()) -> tuple[list[Pool], list[Change]]:
    """Pool successive experiments' estimates (in order): each joins the current pool
    unless it disagrees with it or is said to be another object (then it is flagged and
    starts the next).

    Args:
        estimates: each experiment's fit (its ``params`` and ``covariance``).
        names: the parameters pooled (default E, c1, c2: the material; the Poisson ratio
            rests on the markers' view of one face).
        level: the false-alarm rate of the change test.
        numbers: the experiments' numbers (default 1..n).
        new_objects: numbers of experiments the robot said are on another object.
    """
    numbers = list(numbers or range(1, len(estimates) + 1))
    pools: list[Pool] = []
    changes: list[Change] = []
    members: list[tuple[int, np.ndarray, np.ndarray]] = []
    for number, estimate in zip(numbers, estimates):
        values, info = _information(estimate, names)
        if members:
            pool = _merge(members, names)
            stated = number in new_objects
            both = (np.diag(info) > 0) & np.isfinite(pool.values)
            distance, limit, moved = np.nan, np.nan, {}
            if both.any():
                cov_k = np.linalg.pinv(info[np.ix_(both, both)])
                gap = values[both] - pool.values[both]
                joint = cov_k + pool.covariance[np.ix_(both, both)]
                distance = float(gap @ np.linalg.solve(joint, gap))
                limit = float(chdtri(int(both.sum()), level))   # chi2.isf
                z = gap / np.sqrt(np.diag(joint))
                cut = float(-ndtri(level / (2 * both.sum())))   # norm.isf
                moved = {str(n): float(s) for n, s in zip(np.array(names)[both], z) if abs(s) > cut}
            if stated or distance > limit:
                changes.append(Change(number, distance, limit, moved, stated))
                pools.append(pool)
                members = []
        members.append((number, values, info))
    if members:
        pools.append(_merge(members, names))
    return pools, changes


def pool_of(pools: Sequence[Pool], experiment: int) -> Pool:
    """The pool ``experiment`` belongs to.

    Raises:
        KeyError: no pool holds it."""
    for pool in pools:
        if experiment in pool.experiments:
            return pool
    raise KeyError(experiment)
