"""The FE model in its quasi-static limit: the forward model of the fits.

With the Lame parts sharing one operator ``Q`` (eq. 19-21), the nodal forces are
``Q(d/dt) [K_gamma u]``. When inertia is negligible (clay: lowest mode ~60 Hz, the
experiment ~0.1 Hz) every free node carries no force at any time, so by the
correspondence principle the displacement field is the elastic shape for a unit
stage depth scaled by one scalar history ``s(t)``, and each bottom node's force is
its elastic reaction times ``Q[s](t)``. ``s`` follows the stage while in contact
and the element's free recovery after release (the body is then stress-free).
One exact scalar response thus gives every node's force and every marker: the
whole-record fit costs milliseconds per evaluation.

Release is taken as instant: a stage retracting at the default 20 mm/s leaves the
specimen within one stage sample (its viscous stress drops at once). A slow
retraction, which the specimen follows for a while, is not modelled here yet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import Mesh
from rheo_ros.models.effects import Model, Release
from rheo_ros.models.response import respond


@dataclass(frozen=True)
class ElasticShape:
    """Per unit stage depth (m) and unit Young's modulus (Pa): nodal displacement
    (N, 2) in m/m, and bottom reactions (n_bottom,) in N/(Pa m)."""

    displacement: np.ndarray
    bottom_force: np.ndarray


def elastic_shape(mesh: Mesh, gamma: float | None) -> ElasticShape:
    """Static elastic solution: bottom held, top pushed down by 1 m (no x slip)."""
    K = mesh.stiffness(gamma)
    held = np.zeros(mesh.n_dofs, bool)
    held[mesh.node_dofs(mesh.bottom)] = True
    held[mesh.node_dofs(mesh.top)] = True
    u = np.zeros(mesh.n_dofs)
    u[mesh.y_dofs(mesh.top)] = -1.0
    free = ~held
    u[free] = np.linalg.solve(K[np.ix_(free, free)], -K[np.ix_(free, held)] @ u[held])
    return ElasticShape(mesh.displacement_field(u), (K @ u)[mesh.y_dofs(mesh.bottom)])


@dataclass(frozen=True)
class Prediction:
    """``force`` (T, n_bottom) in N at the force times; ``displacement`` (Tm, N, 2) in m
    at the marker times."""

    force: np.ndarray
    displacement: np.ndarray


class QuasiStaticFE:
    """Forward model: (model, Poisson ratio, stage profile) -> bottom forces and markers."""

    def __init__(self, mesh: Mesh) -> None:
        self.mesh = mesh
        self._shapes: dict[float | None, ElasticShape] = {}

    def shape(self, gamma: float | None) -> ElasticShape:
        key = None if self.mesh.geometry == "uniaxial" else float(gamma)
        if key not in self._shapes:
            self._shapes[key] = elastic_shape(self.mesh, key)
        return self._shapes[key]

    def predict(
        self, model: Model, gamma: float | None, profile: StageProfile,
        force_t: np.ndarray, marker_t: np.ndarray,
    ) -> Prediction:
        shape = self.shape(gamma)
        # The stage lets go at the end of keep: the force just before it feeds adhesion.
        t_release = profile.t_keep_end
        t = np.concatenate([force_t, marker_t, [np.nextafter(t_release, -np.inf)]])
        order = np.argsort(t, kind="stable")
        r = respond(model.rheology(), profile.program(), t[order])
        stress, depth = np.empty_like(t), np.empty_like(t)
        stress[order], depth[order] = r.stress, r.strain
        nf, nm = len(force_t), len(marker_t)
        scaled = stress * model.stress_scale(depth / self.mesh.height)
        release = Release(t_release, scaled[-1] * shape.bottom_force)
        force = model.measured_force(force_t, np.outer(scaled[:nf], shape.bottom_force), release)
        disp = depth[nf : nf + nm, None, None] * shape.displacement[None]
        return Prediction(force, disp)
