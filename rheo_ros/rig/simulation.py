"""Records made by the FE dynamic model, with optional measurement noise."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rheo_ros.experiment import StageProfile, sample_times
from rheo_ros.fe.dynamic import DynamicFE
from rheo_ros.fe.mesh import Mesh
from rheo_ros.models.effects import Model
from rheo_ros.record import Record


@dataclass(frozen=True)
class Rates:
    """Sample rates (Hz) of the contract's topics."""

    stage: float = 100.0
    force: float = 50.0
    markers: float = 10.0


def simulate_record(
    mesh: Mesh, model: Model, gamma: float, profile: StageProfile,
    rates: Rates = Rates(), density: float = 1.5e3, omega: float = 1.0e3, source: str = "simulation",
    refine: int = 1, segment_edges: np.ndarray | None = None,
) -> Record:
    """Run the dynamic FE model once (on ``mesh`` refined ``refine`` times, see
    ``DynamicFE``) and sample each topic at its own rate, noise-free."""
    fe = DynamicFE(mesh, model.rheology(), gamma, density=density, omega=omega, refine=refine,
                   segment_edges=segment_edges)
    grids = [sample_times(profile.t_end, rate) for rate in (rates.stage, rates.force, rates.markers)]
    t = np.unique(np.concatenate(grids))
    result = fe.simulate(profile, t)
    pick = [np.searchsorted(t, g) for g in grids]
    force_t, i = grids[1], pick[1]
    return Record(
        mesh=mesh,
        stage_t=grids[0], stage_depth=result.stage_depth[pick[0]],
        force_t=force_t, force=model.felt_force(force_t, result.bottom_force[i], result.strain[i], result.contact[i]),
        marker_t=grids[2], markers=mesh.nodes[None] + result.displacement[pick[2]],
        source=source,
    )


@dataclass(frozen=True)
class Noise:
    """Gaussian measurement noise: ``force`` as a fraction of each node's peak force,
    ``markers`` in m per coordinate."""

    force: float = 0.01
    markers: float = 20e-6

    def force_std(self, record: Record) -> np.ndarray:
        return self.force * np.abs(record.force).max(axis=0)

    def apply(self, record: Record, rng: np.random.Generator) -> Record:
        force = record.force + rng.standard_normal(record.force.shape) * self.force_std(record)
        markers = record.markers + rng.standard_normal(record.markers.shape) * self.markers
        return replace(record, force=force, markers=markers)
