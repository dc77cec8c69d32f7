"""The result object of every identification step (after scipy's OptimizeResult)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:   # the fit's module imports this one
    from rheo_ros.identification.fit import FitStatistics

# The three-element model's parameters and the Poisson ratio, in the order every result lists them.
BASE_PARAMETERS = ("E", "c1", "c2", "gamma")


@dataclass(frozen=True)
class Estimate:
    """Identified parameters.

    Attributes:
        params: values by name (``E``, ``c1``, ``c2`` in Pa / Pa s; ``gamma`` the Poisson ratio).
        method: the procedure (``paper_long_time``, ``paper_short_time``, ``whole_record``).
        equations: the paper's equations that produced the values.
        covariance: in the order of ``params``, or None where the method gives none.
        residual_rms: a closed form's own figures (force-curve RMS, the relaxation rate's
            relative std, ...), by name.
        message: what a person should know (how the data were used, warnings).
        statistics: the whole-record fit's figures (noise, fit to noise, clock offsets,
            deviance, BIC; ``FitStatistics``); None for a closed form.
    """

    params: dict[str, float]
    method: str
    equations: tuple[str, ...]
    covariance: np.ndarray | None = None
    residual_rms: dict[str, float] = field(default_factory=dict)
    message: str = ""
    statistics: FitStatistics | None = None

    @property
    def std(self) -> dict[str, float]:
        """Standard deviations from the covariance (empty without one)."""
        if self.covariance is None:
            return {}
        return dict(zip(self.params, np.sqrt(np.diag(self.covariance)).tolist()))

    def relative_errors(self, truth: dict[str, float]) -> dict[str, float]:
        """Relative error of each parameter against ``truth``, in %."""
        return {k: 100.0 * (self.params[k] - v) / v for k, v in truth.items() if k in self.params}
