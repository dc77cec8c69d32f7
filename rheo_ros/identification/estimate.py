"""The result object of every identification step (after scipy's OptimizeResult)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Estimate:
    """Identified parameters.

    Attributes:
        params: values by name (``E``, ``c1``, ``c2`` in Pa / Pa s; ``gamma`` the Poisson ratio).
        method: the procedure (``paper_long_time``, ``paper_short_time``, ``whole_record``).
        equations: the paper's equations that produced the values.
        covariance: in the order of ``params``, or None where the method gives none.
        residual_rms: RMS of the residuals the method minimised, by group.
        message: what a person should know (how the data were used, warnings).
    """

    params: dict[str, float]
    method: str
    equations: tuple[str, ...]
    covariance: np.ndarray | None = None
    residual_rms: dict[str, float] = field(default_factory=dict)
    message: str = ""

    @property
    def std(self) -> dict[str, float]:
        """Standard deviations from the covariance (empty without one)."""
        if self.covariance is None:
            return {}
        return dict(zip(self.params, np.sqrt(np.diag(self.covariance)).tolist()))

    def relative_errors(self, truth: dict[str, float]) -> dict[str, float]:
        """Relative error of each parameter against ``truth``, in %."""
        return {k: 100.0 * (self.params[k] - v) / v for k, v in truth.items() if k in self.params}
