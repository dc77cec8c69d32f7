"""The FE dynamic model of the paper: eq. 1 (1D) and its 2D extension, eq. 18-21.

Nodal masses ``M``, constraints held by Lagrange multipliers with the paper's
stabilisation (``C'' + 2 omega C' + omega^2 C = 0`` for each constraint ``C = 0``) and
the rheological nodal force ``F = J Omega`` (eq. 20: ``J_lambda Omega_lambda + J_mu
Omega_mu``). The Lame parts share E, c1, c2 up to the Poisson scaling of eq. 19, so
``F = Q(d/dt) [K_gamma u]`` with ``Q`` the rheology's modulus and ``K_gamma`` the
stiffness per unit E: any element of ``rheo_ros.models`` drives the mesh.

Eq. 1 keeps the instantaneous viscous term inside ``Omega``, which makes the system
implicit in the accelerations; we use the explicit state-space realisation of the
same operator (``Omega = C x + D d/dt(K u)``). Within a phase the model is linear
time-invariant with a linear drive, so it is propagated exactly by matrix
exponentials (stiffness from small masses costs nothing).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.linalg import expm

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import Mesh
from rheo_ros.models.elements import Element
from rheo_ros.models.response import StateSpace

Contact = Literal["held", "free"]


@dataclass(frozen=True)
class FEResult:
    """Sampled simulation: ``displacement`` (T, N, 2) in m, ``bottom_force`` (T, n_bottom)
    in N (y reaction of each bottom node, positive when pressing the sensor)."""

    t: np.ndarray
    stage_depth: np.ndarray
    displacement: np.ndarray
    bottom_force: np.ndarray


class DynamicFE:
    """Dynamic FE model of the specimen pushed by the stage.

    Args:
        mesh: specimen mesh (bottom nodes held; top nodes follow the stage in y and
            stick to it in x while in contact, free after release).
        rheology: the material's element (same operator on every dof).
        gamma: Poisson ratio (``plane_fe`` only).
        density: kg/m^3, lumped at the nodes.
        omega: constraint stabilisation frequency (rad/s).
    """

    def __init__(
        self, mesh: Mesh, rheology: Element, gamma: float | None = None,
        density: float = 1.5e3, omega: float = 1.0e3,
    ) -> None:
        self.mesh, self.gamma, self.omega = mesh, gamma, omega
        self.K = mesh.stiffness(gamma)
        self.mass = mesh.lumped_mass(density)
        self.ss = StateSpace.of(rheology)
        n, nq = mesh.n_dofs, self.ss.A.shape[0]
        self.n, self.nq = n, nq
        self.size = 2 * n + nq * n + 2
        # Index blocks of the state z = [u, v, x_1..x_nq, g, g'].
        self.iu, self.iv = slice(0, n), slice(n, 2 * n)
        self.ix = [slice(2 * n + k * n, 2 * n + (k + 1) * n) for k in range(nq)]
        self.ig, self.igd = 2 * n + nq * n, 2 * n + nq * n + 1
        self._modes: dict[Contact, tuple[np.ndarray, np.ndarray]] = {}
        self._phi: dict[tuple[Contact, float], np.ndarray] = {}

    def _force_rows(self) -> np.ndarray:
        """Rows mapping z to the rheological nodal force F (n x size)."""
        F = np.zeros((self.n, self.size))
        F[:, self.iv] = self.ss.D * self.K
        for k, sl in enumerate(self.ix):
            F[:, sl] = self.ss.C[k] * np.eye(self.n)
        return F

    def _mode(self, contact: Contact) -> tuple[np.ndarray, np.ndarray]:
        """System matrix and bottom-force output rows for a contact state."""
        if contact in self._modes:
            return self._modes[contact]
        mesh, n, w = self.mesh, self.n, self.omega
        held = np.zeros(n, bool)
        held[mesh.node_dofs(mesh.bottom)] = True
        target = np.zeros(n)  # multiplier of g(t) in each held dof's target
        if contact == "held":
            held[mesh.node_dofs(mesh.top)] = True
            target[mesh.y_dofs(mesh.top)] = 1.0
        F = self._force_rows()
        A = np.zeros((self.size, self.size))
        A[self.iu, self.iv] = np.eye(n)
        acc = np.zeros((n, self.size))
        acc[~held] = -F[~held] / self.mass[~held, None]
        hi = np.flatnonzero(held)
        acc[hi, n + hi] = -2 * w
        acc[hi, hi] = -(w**2)
        acc[hi, self.igd] = 2 * w * target[hi]
        acc[hi, self.ig] = w**2 * target[hi]
        A[self.iv] = acc
        Kv = np.zeros((n, self.size))
        Kv[:, self.iv] = self.K
        for k, sl in enumerate(self.ix):
            for j, sj in enumerate(self.ix):
                A[sl, sj] += self.ss.A[k, j] * np.eye(n)
            A[sl] += self.ss.B[k] * Kv
        A[self.ig, self.igd] = 1.0
        # Reaction of a held dof: lambda = M v' + F (what the support exerts on the node).
        reaction = self.mass[:, None] * acc + F
        out = reaction[mesh.y_dofs(mesh.bottom)]
        self._modes[contact] = (A, out)
        return A, out

    def _step(self, contact: Contact, dt: float) -> np.ndarray:
        key = (contact, round(dt, 12))
        if key not in self._phi:
            self._phi[key] = expm(self._mode(contact)[0] * dt)
        return self._phi[key]

    def simulate(self, profile: StageProfile, t: np.ndarray) -> FEResult:
        """Run the experiment and sample it at the sorted times ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        v, d = profile.velocity, profile.depth
        # (start, end, contact, g at start, g') with g the top target displacement (m, y up).
        segments = [
            (-np.inf, profile.t_pull_start, "held", 0.0, 0.0),
            (profile.t_pull_start, profile.t_pull_end, "held", 0.0, -v),
            (profile.t_pull_end, profile.t_keep_end, "held", -d, 0.0),
            (profile.t_keep_end, np.inf, "free", 0.0, 0.0),
        ]
        z = np.zeros(self.size)
        states = np.zeros((t.size, self.size))
        forces = np.zeros((t.size, self.mesh.cols))
        now = min(t[0], profile.t_pull_start) if t.size else 0.0
        for start, end, contact, g0, gdot in segments:
            if end <= now:
                continue
            z[self.ig], z[self.igd] = (g0, gdot) if contact == "held" else (0.0, 0.0)
            _, out = self._mode(contact)
            idx = np.flatnonzero((t >= max(start, now)) & (t < end))
            for i in idx:
                if t[i] > now:
                    z = self._step(contact, t[i] - now) @ z
                    now = t[i]
                states[i], forces[i] = z, out @ z
            if np.isfinite(end) and end > now:
                z = self._step(contact, end - now) @ z
                now = end
        disp = self.mesh.displacement_field(states[:, self.iu])
        return FEResult(t, profile.depth_at(t), disp, forces)
