"""The FE dynamic model of the paper: eq. 1 in its 2D extension, eq. 18-21 (on the
uniaxial block, whose stress is uniform, every column of nodes is eq. 1's bar).

Nodal masses ``M``, constraints held by Lagrange multipliers with the paper's
stabilisation (``C'' + 2 omega C' + omega^2 C = 0`` for each constraint ``C = 0``) and
the rheological nodal force ``F = J Omega`` (eq. 20: ``J_lambda Omega_lambda + J_mu
Omega_mu``). The Lame parts share E, c1, c2 up to the Poisson scaling of eq. 19, so
``F = Q(d/dt) [K_gamma u]`` with ``Q`` the rheology's modulus and ``K_gamma`` the
stiffness per unit E: any element of ``rheo_ros.models`` drives the mesh.

Eq. 1 keeps the instantaneous viscous term inside ``Omega``, which makes the system
implicit in the accelerations; we use the explicit state-space realisation of the
same operator (``Omega = C x + D d/dt(K u)``). Between two stage samples the stage
moves linearly and the contact does not change, so the model is linear
time-invariant with a linear drive and is propagated exactly by matrix exponentials
(stiffness from small masses costs nothing). Not of the whole system's (~900 states on
the 65 x 65 mesh: seconds a specimen, and scaling and squaring over its stiff modes cost
2e-8 of the force over 15 s of pull against a 30-digit reference): the held dofs follow
their targets alone, and the rheology being one scalar operator on ``K u``, the free dofs
part into the modes of ``M^-1 K``, each a system of a few states driven by the held dofs
(``_Split``; 1e-9 against that reference).

Contact with the stage is one-sided: the top nodes follow the stage (bonded: stick to
it in x) while it presses; when the stage retracts faster than the specimen
recovers, the pressing force reaches zero, the specimen lets go at that instant
(found by bisection inside the step) and recovers freely.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.linalg import expm

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.banded import BandedCholesky
from rheo_ros.fe.mesh import Mesh
from rheo_ros.models.effects import Model
from rheo_ros.models.elements import Element
from rheo_ros.models.response import StateSpace

Contact = Literal["held", "free"]


@dataclass(frozen=True)
class Condensed:
    """The specimen's FE mesh seen at the nodes the dynamics need.

    A mesh refined below the marker grid is statically condensed onto its master
    nodes (the markers, the bottom row on the sensor, the top row under the stage):
    ``K_c = K_mm - K_ms K_ss^-1 K_sm``. The rheology is one scalar operator on ``K u``
    and the other nodes carry no load, so their equations ``Q[K_sm u_m + K_ss u_s] = 0``
    give ``u_s = -K_ss^-1 K_sm u_m`` at all times: the condensation is exact for the
    quasi-static response, and only inertia is approximated (each other node's mass
    goes to its nearest master; the lowest mode is ~60 Hz, the experiment ~0.1 Hz).
    Unrefined, every node is a master and nothing is approximated.

    Attributes:
        fine: the refined mesh; ``masters`` its master nodes (sorted).
        K: condensed stiffness per unit E (dense: its modes are taken).
        mass: lumped mass per condensed dof (kg).
        bottom_y, top_y: condensed dofs of the bottom and top rows' y.
        segments: (segments, bottom nodes) each tactile segment's force from the
            bottom reactions (identity without segment edges).
        marker_dofs: condensed dofs of each marker's x and y.
    """

    fine: Mesh
    masters: np.ndarray
    K: np.ndarray
    mass: np.ndarray
    bottom_y: np.ndarray
    top_y: np.ndarray
    segments: np.ndarray
    marker_dofs: np.ndarray

    @classmethod
    def of(cls, mesh: Mesh, gamma: float, density: float, refine: int = 1,
           segment_edges: np.ndarray | None = None) -> Condensed:
        fine = mesh.refined(refine)
        if segment_edges is None and refine != 1:
            raise ValueError("a refined mesh needs the tactile segments' edges")
        # Marker nodes in the fine mesh: the marker grid sits on every refine-th node.
        marker_nodes = np.array([(i // mesh.cols) * refine * fine.cols + (i % mesh.cols) * refine
                                 for i in range(mesh.nodes.shape[0])])
        masters = np.unique(np.concatenate([marker_nodes, fine.bottom, fine.top]))
        dofs = fine.node_dofs(masters)
        K = fine.stiffness(gamma).tocsr()
        if dofs.size == fine.n_dofs:
            K_c = K.toarray()
        else:
            slave = np.setdiff1d(np.arange(fine.n_dofs), dofs)
            # K_ms K_ss^-1 K_sm = Y^T Y, Y = U^-T K_sm: one triangular solve (a sparse LU's
            # solve takes two, and its factor more fill than the grid's band).
            Y = BandedCholesky(K[slave][:, slave]).half_solve(K[slave][:, dofs].toarray())
            K_c = K[dofs][:, dofs].toarray() - Y.T @ Y
        # Lumped masses: each node's to its nearest master.
        node_mass = fine.lumped_mass(density)[::2]
        nearest = np.argmin(np.linalg.norm(fine.nodes[:, None] - fine.nodes[masters][None], axis=2), axis=1)
        mass = np.repeat(np.bincount(nearest, weights=node_mass, minlength=masters.size), 2)
        local = lambda nodes: np.searchsorted(masters, nodes)  # noqa: E731  (masters are sorted)
        segments = (np.eye(fine.cols) if segment_edges is None else fine.segment_integrals(segment_edges))
        marker_dofs = fine.node_dofs(local(marker_nodes)).reshape(-1, 2)
        return cls(fine, masters, K_c, mass, fine.y_dofs(local(fine.bottom)), fine.y_dofs(local(fine.top)),
                   segments, marker_dofs)

    def supports(self, stage_contact: bool) -> tuple[np.ndarray, np.ndarray]:
        """``Mesh.supports`` of the fine mesh on the condensed dofs."""
        held, target = self.fine.supports(stage_contact)
        dofs = self.fine.node_dofs(self.masters)
        return held[dofs], target[dofs]

    def marker_displacement(self, u: np.ndarray) -> np.ndarray:
        """Condensed dof vector(s) (..., n) -> marker displacements (..., N, 2)."""
        return np.asarray(u)[..., self.marker_dofs]


@dataclass(frozen=True)
class FEResult:
    """Sampled simulation: ``displacement`` (T, N, 2) in m, ``bottom_force`` (T, n_bottom)
    in N (y reaction of each bottom node, positive when pressing the sensor), stage
    ``contact`` (T,) and nominal compressive ``strain`` (T,) = top sinking / height."""

    t: np.ndarray
    stage_depth: np.ndarray
    displacement: np.ndarray
    bottom_force: np.ndarray
    contact: np.ndarray
    strain: np.ndarray


@dataclass(frozen=True)
class _Split:
    """One contact's system split as the propagation needs it: the held dofs (each
    tracking its target by the stabilisation alone, the same 2 x 2 system for every one)
    and the free dofs in the modes of ``M^-1 K`` (the rheology is one scalar operator on
    ``K u``, so each mode is a small system of its own, driven by the held dofs).

    With ``S = M_f^-1/2 K_ff M_f^-1/2 = Q diag(lam) Q^T``, ``u_f = M_f^-1/2 Q q`` and each
    internal variable ``x_f = M_f^1/2 Q xi``, mode ``i`` obeys ``q'' = -(D (lam q' + h) +
    C xi)``, ``xi' = A xi + B (lam q' + h)``, ``h = (W v_h)_i``, ``W = Q^T M_f^-1/2 K_fh``;
    the held dofs' internal variables are driven by ``(K v)_h = W^T q' + K_hh v_h``.

    Attributes:
        held, free: dof indices; ``target`` each held dof's displacement per unit g.
        lam: the free modes' eigenvalues (per unit of the rheology's modulus).
        to_modes, from_modes: ``Q^T M_f^1/2`` (u_f -> q) and ``M_f^-1/2 Q`` (q -> u_f).
        x_to_modes, x_from_modes: ``Q^T M_f^-1/2`` and ``M_f^1/2 Q`` (internal variables).
        W: (free, held) coupling; ``K_hh``: (held, held) stiffness.
    """

    held: np.ndarray
    free: np.ndarray
    target: np.ndarray
    lam: np.ndarray
    to_modes: np.ndarray
    from_modes: np.ndarray
    x_to_modes: np.ndarray
    x_from_modes: np.ndarray
    W: np.ndarray
    K_hh: np.ndarray

    @classmethod
    def of(cls, structure: Condensed, contact: Contact) -> _Split:
        held_mask, target = structure.supports(contact == "held")
        held, free = np.flatnonzero(held_mask), np.flatnonzero(~held_mask)
        K, root = structure.K, np.sqrt(structure.mass[free])
        lam, Q = np.linalg.eigh(K[np.ix_(free, free)] / root[:, None] / root[None])
        to_x = Q.T / root[None]
        return cls(held, free, -target[held], lam, Q.T * root[None], Q / root[:, None], to_x, Q * root[:, None],
                   to_x @ K[np.ix_(free, held)], K[np.ix_(held, held)])


def _mode_matrices(ss: StateSpace, omega: float, lam: np.ndarray) -> np.ndarray:
    """Each free mode's system (modes, m, m) on ``[q, q', xi (nq), a, b, c, eta (nq)]``:
    ``a, b`` the held dofs' lag behind their targets and its rate, seen through ``W``, ``c``
    their targets' velocity seen so (the held velocity is ``c + b``), ``eta`` the
    internal variables' filter of ``q'`` (what drives the held dofs' internal variables)."""
    nq, w = ss.A.shape[0], omega
    xi, a, b, c = slice(2, 2 + nq), 2 + nq, 3 + nq, 4 + nq
    eta = slice(5 + nq, 5 + 2 * nq)
    m = 5 + 2 * nq
    M = np.zeros((lam.size, m, m))
    M[:, 0, 1] = 1.0
    M[:, 1, 1] = -ss.D * lam
    M[:, 1, xi] = -ss.C
    M[:, 1, b] = M[:, 1, c] = -ss.D
    M[:, xi, xi] = ss.A
    M[:, xi, 1] = ss.B[None] * lam[:, None]
    M[:, xi, b] = M[:, xi, c] = ss.B
    M[:, a, b] = 1.0
    M[:, b, a], M[:, b, b] = -w**2, -2 * w
    M[:, eta, eta] = ss.A
    M[:, eta, 1] = ss.B
    return M


def _held_matrix(ss: StateSpace, omega: float) -> np.ndarray:
    """Every held dof's system on ``[e, e', c, zeta (nq), chi (nq)]``: its lag behind its
    target ``e`` (the stabilisation ``e'' + 2 omega e' + omega^2 e = 0``: the lag, not the
    displacement, so that no step takes the difference of two nearly equal numbers), its
    target's velocity ``c``, ``zeta`` the internal variables' filter of its velocity
    ``c + e'``, ``chi`` its own internal variables left alone."""
    nq, w = ss.A.shape[0], omega
    zeta, chi = slice(3, 3 + nq), slice(3 + nq, 3 + 2 * nq)
    H = np.zeros((3 + 2 * nq, 3 + 2 * nq))
    H[0, 1] = 1.0
    H[1, 0], H[1, 1] = -w**2, -2 * w
    H[zeta, zeta] = ss.A
    H[zeta, 1] = H[zeta, 2] = ss.B
    H[chi, chi] = ss.A
    return H


@dataclass(frozen=True)
class _Flow:
    """The exact propagation of one contact's system over a step ``dt``: every free
    mode's matrix exponential (modes, m, m), and the held dofs' (h, h)."""

    dt: float
    modes: np.ndarray
    held: np.ndarray

    @classmethod
    def of(cls, split: _Split, ss: StateSpace, omega: float, dt: float) -> _Flow:
        return cls(dt, expm(_mode_matrices(ss, omega, split.lam) * dt), expm(_held_matrix(ss, omega) * dt))

    def squared(self) -> _Flow:
        """The flow over twice the step."""
        return _Flow(2 * self.dt, self.modes @ self.modes, self.held @ self.held)

    def powers(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The flows over 1..``count`` steps: the modes' (modes, count * m, m), each mode's
        powers stacked for one product per mode, and the held dofs' (count, h, h)."""
        modes, held = [self.modes], [self.held]
        for _ in range(count - 1):
            modes.append(modes[-1] @ self.modes)
            held.append(held[-1] @ self.held)
        m = self.modes.shape[-1]
        return np.stack(modes, axis=1).reshape(-1, count * m, m), np.stack(held)


@dataclass
class _Shared:
    """What the runs of one specimen, rheology and step share: the condensed mesh, and
    each contact's system, split and flows as they are made (never changed once made)."""

    structure: Condensed
    modes: dict[Contact, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    splits: dict[Contact, _Split] = field(default_factory=dict)
    flows: dict[tuple[Contact, float], _Flow] = field(default_factory=dict)
    ladders: dict[tuple[Contact, float], list[_Flow]] = field(default_factory=dict)
    blocks: dict[tuple[Contact, float], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    readouts: dict[Contact, np.ndarray] = field(default_factory=dict)


# Specimens whose matrices a process keeps (~15 MB each for the 65 x 65 mesh).
SHARED_RUNS = 2
_SHARED: dict[bytes, _Shared] = {}


class DynamicFE:
    """Dynamic FE model of the specimen pushed by the stage, stepped by stage samples.

    Args:
        mesh: specimen mesh (bottom nodes on the sensor, top nodes following the stage
            in y while in contact; in x as the mesh's boundary conditions say).
        rheology: the material's element (same operator on every dof).
        gamma: Poisson ratio.
        density: kg/m^3, lumped at the nodes.
        omega: constraint stabilisation frequency (rad/s).
    """

    def __init__(
        self, mesh: Mesh, rheology: Element, gamma: float,
        density: float = 1.5e3, omega: float = 1.0e3, refine: int = 1, segment_edges: np.ndarray | None = None,
    ) -> None:
        self.mesh, self.gamma, self.omega = mesh, gamma, omega
        self.ss = StateSpace.of(rheology)
        # The condensation and the flows are the same for every run of the same specimen,
        # rheology and step: a process making several runs (the simulator node, a bench,
        # the tests) builds them once (~0.2 s of a 65 x 65 mesh's construction).
        key = pickle.dumps((mesh, gamma, density, omega, refine, segment_edges, self.ss))
        shared = _SHARED.pop(key, None)
        if shared is None:
            shared = _Shared(Condensed.of(mesh, gamma, density, refine, segment_edges))
        _SHARED[key] = shared   # the latest last: the oldest goes first
        while len(_SHARED) > SHARED_RUNS:
            _SHARED.pop(next(iter(_SHARED)))
        self.structure = shared.structure
        self.K, self.mass = self.structure.K, self.structure.mass
        n, nq = self.K.shape[0], self.ss.A.shape[0]
        self.n, self.nq = n, nq
        self.size = 2 * n + nq * n + 2
        # Index blocks of the state z = [u, v, x_1..x_nq, g, g'], g = top target (m, y up).
        self.iu, self.iv = slice(0, n), slice(n, 2 * n)
        self.ix = [slice(2 * n + k * n, 2 * n + (k + 1) * n) for k in range(nq)]
        self.ig, self.igd = 2 * n + nq * n, 2 * n + nq * n + 1
        self._bottom_y, self._top_y = self.structure.bottom_y, self.structure.top_y
        self._modes, self._splits, self._flows = shared.modes, shared.splits, shared.flows
        self._ladders, self._blocks, self._readouts = shared.ladders, shared.blocks, shared.readouts
        self.reset()

    def reset(self, t: float = 0.0) -> None:
        """Unloaded specimen, stage touching it at depth 0, at time ``t``."""
        self.z = np.zeros(self.size)
        self.t, self.depth, self.contact = t, 0.0, "held"

    # -- the linear system of each contact state ----------------------------------------

    def _mode(self, contact: Contact) -> tuple[np.ndarray, np.ndarray]:
        """System matrix and reaction rows (n x size: support force on each held dof)."""
        if contact in self._modes:
            return self._modes[contact]
        n, w = self.n, self.omega
        held, down = self.structure.supports(contact == "held")
        target = -down  # multiplier of g(t) (the top's target, m, y up) in each held dof's target
        F = np.zeros((n, self.size))  # rheological nodal force
        F[:, self.iv] = self.ss.D * self.K
        for k, sl in enumerate(self.ix):
            F[:, sl] = self.ss.C[k] * np.eye(n)
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
        reaction = self.mass[:, None] * acc + F  # lambda = M v' + F
        self._modes[contact] = (A, reaction)
        return A, reaction

    @staticmethod
    def _cached(cache: dict, contact: Contact, dt: float, make):
        """``cache[(contact, dt)]``, made once: steps of one sample period differ in the
        last bits of their end times (2.8e-14 s at 128 s), so a step within 1e-9 of a
        cached one (10 fs at 10 ms) shares its matrices."""
        key = (contact, dt)
        if key not in cache:
            near = next((k for k in cache if k[0] == contact and abs(k[1] - dt) <= 1e-9 * dt), None)
            cache[key] = cache[near] if near else make()
        return cache[key]

    def _split(self, contact: Contact) -> _Split:
        if contact not in self._splits:
            self._splits[contact] = _Split.of(self.structure, contact)
        return self._splits[contact]

    def _flow(self, contact: Contact, dt: float) -> _Flow:
        return self._cached(self._flows, contact, dt,
                            lambda: _Flow.of(self._split(contact), self.ss, self.omega, dt))

    def _propagate(self, contact: Contact, z: np.ndarray, flow: _Flow, steps: int = 1) -> np.ndarray:
        """The states (steps, size) after each of ``steps`` (up to ``BLOCK``) steps of
        ``flow`` from ``z`` in ``contact``: the free modes and the held dofs stepped apart,
        in their own coordinates; several steps at once by each mode's powers, one product
        a mode (within 1e-11 of the peak force of those steps one by one)."""
        split, n, nq = self._split(contact), self.n, self.nq
        held, free = split.held, split.free
        x = z[2 * n:self.ig].reshape(nq, n)
        g, gd = z[self.ig], z[self.igd]
        # Each held dof's state, and the same seen through K_hh (its velocity's filter is
        # what drives the held dofs' internal variables; the dynamics are one for all).
        g_k = g + gd * flow.dt * np.arange(1, steps + 1)
        s = np.zeros((2 * held.size, 3 + 2 * nq))
        s[:held.size, 0] = z[held] - split.target * g
        s[:held.size, 2] = split.target * gd
        s[:held.size, 1] = z[n + held] - s[:held.size, 2]
        s[:held.size, 3 + nq:] = x[:, held].T
        s[held.size:, :3] = split.K_hh @ s[:held.size, :3]
        y = np.zeros((free.size, 5 + 2 * nq, 1))
        y[:, 0, 0], y[:, 1, 0] = split.to_modes @ z[free], split.to_modes @ z[n + free]
        y[:, 2:2 + nq, 0] = split.x_to_modes @ x[:, free].T
        y[:, 2 + nq:5 + nq, 0] = split.W @ s[:held.size, :3]
        if steps == 1:
            Y, S = (flow.modes @ y)[None, ..., 0], (s @ flow.held.T)[None]
        else:
            modes, held_powers = self._cached(self._blocks, contact, flow.dt, lambda: flow.powers(self.BLOCK))
            m = y.shape[1]
            Y = (modes[:, :steps * m] @ y).reshape(free.size, steps, m).swapaxes(0, 1)
            S = np.swapaxes(held_powers[:steps] @ s.T, 1, 2)
        # The velocities' filters (zeta, eta) start from 0 with the first step: after k
        # steps they are the filters over k dt, as the held dofs' own internal variables
        # (chi) are theirs left alone over k dt.
        own, seen = S[:, :held.size], S[:, held.size:]
        out = np.empty((steps, self.size))
        out[:, free], out[:, n + free] = Y[..., 0] @ split.from_modes.T, Y[..., 1] @ split.from_modes.T
        out[:, held], out[:, n + held] = g_k[:, None] * split.target + own[..., 0], own[..., 2] + own[..., 1]
        for k in range(nq):
            at = 2 * n + k * n
            out[:, at + free] = Y[..., 2 + k] @ split.x_from_modes.T
            out[:, at + held] = own[..., 3 + nq + k] + seen[..., 3 + k] + Y[..., 5 + nq + k] @ split.W
        out[:, self.ig], out[:, self.igd] = g_k, gd
        return out

    def _step(self, contact: Contact, z: np.ndarray, flow: _Flow) -> np.ndarray:
        """The state after a one-step ``flow`` from ``z``."""
        return self._propagate(contact, z, flow)[0]

    BLOCK = 64   # steps ``simulate`` propagates at once along a stretch of equal steps

    def _readout(self, contact: Contact) -> tuple[np.ndarray, np.ndarray]:
        """Rows that read off a state what a sample keeps and a step checks: (each tactile
        segment's force, then the top's sinking (m), then the force (N) the stage presses
        with; the markers' x and y). Every output of a state is one of these rows."""
        if contact not in self._readouts:
            marker_dofs = self.structure.marker_dofs.ravel()
            markers = np.zeros((marker_dofs.size, self.size))
            markers[np.arange(marker_dofs.size), marker_dofs] = 1.0   # iu starts at 0
            sinking = np.zeros((1, self.size))
            sinking[0, self._top_y] = -1.0 / self._top_y.size
            pressing = -self._mode("held")[1][self._top_y].sum(axis=0, keepdims=True)
            force = self.structure.segments @ self._mode(contact)[1][self._bottom_y]
            self._readouts[contact] = (np.vstack([force, sinking, pressing]), markers)
        return self._readouts[contact]

    # -- outputs of the current state -----------------------------------------------------

    def bottom_force(self) -> np.ndarray:
        """Force on each tactile segment (N, positive pressing)."""
        return self._readout(self.contact)[0][:-2] @ self.z

    def displacement(self) -> np.ndarray:
        """Marker displacements (N, 2) in m."""
        return self.structure.marker_displacement(self.z[self.iu])

    def strain(self) -> float:
        """Nominal compressive strain: mean sinking of the top nodes / height."""
        return self._sinking(self.z) / self.mesh.height

    def _pressing(self, z: np.ndarray) -> float:
        """Force (N) the stage exerts down on the specimen in contact; < 0 means pulling."""
        return float(self._readout("held")[0][-1] @ z)

    # -- stepping ----------------------------------------------------------------------

    def advance(self, t: float, depth: float) -> None:
        """Move on to time ``t`` (s) while the stage goes linearly to ``depth`` (m).

        A zero-length step with a smaller depth is an instant retraction: the
        specimen cannot follow, contact ends there.
        """
        dt = t - self.t
        if dt < 0:
            raise ValueError(f"time went back: {self.t} -> {t}")
        d0, self.t, self.depth = self.depth, t, depth
        if dt == 0.0:
            if depth < d0 and self.contact == "held":
                self.contact = "free"
            return
        if self.contact == "held":
            self.z[self.ig], self.z[self.igd] = -d0, -(depth - d0) / dt
            z_end = self._step("held", self.z, self._flow("held", dt))
            if depth < d0 and self._pressing(z_end) < 0.0:
                held_units, self.z = self._release(dt)
                self.contact = "free"
                self.z = self._run_for("free", 2**self.RELEASE_DEPTH - held_units, dt, self.z)
            else:
                self.z = z_end
        else:
            z_end = self._step("free", self.z, self._flow("free", dt))
            if self._sinking(z_end) < depth:   # the stage reaches the specimen again within the step
                units, z = self._contact(dt, d0, depth)
                at = d0 + (depth - d0) * units / 2**self.RELEASE_DEPTH
                z = z.copy()
                z[self.ig], z[self.igd] = -at, -(depth - d0) / dt
                self.z = self._run_for("held", 2**self.RELEASE_DEPTH - units, dt, z)
                self.contact = "held"
            else:
                self.z = z_end

    RELEASE_DEPTH = 24   # the release instant to dt / 2^24 (under a nanosecond at 100 Hz)

    def _ladder(self, contact: Contact, dt: float) -> list[_Flow]:
        """Flows of dt/2, dt/4, ... dt/2^RELEASE_DEPTH: the smallest's exponentials squared
        up; kept per contact and step length (one step length per run)."""
        def make() -> list[_Flow]:
            steps = [_Flow.of(self._split(contact), self.ss, self.omega, dt / 2**self.RELEASE_DEPTH)]
            for _ in range(self.RELEASE_DEPTH - 1):
                steps.append(steps[-1].squared())
            return steps[::-1]
        return self._cached(self._ladders, contact, dt, make)

    def prepare(self, dt: float) -> None:
        """Compute now what stepping by ``dt`` needs (a real-time simulator must not stall
        at the first step or at release)."""
        for contact in ("held", "free"):
            self._flow(contact, dt)
            self._ladder(contact, dt)

    def _release(self, dt: float) -> tuple[int, np.ndarray]:
        """Instant within the step at which the stage stops pressing (in units of
        dt / 2^RELEASE_DEPTH) and the state then, by bisection on the held ladder."""
        if self._pressing(self.z) <= 0.0:
            return 0, self.z
        return self._last_before("held", dt, lambda z, _: self._pressing(z) > 0.0)

    def _sinking(self, z: np.ndarray) -> float:
        """How far (m) the top has sunk in state ``z`` (its nodes' mean)."""
        return float(self._readout("held")[0][-2] @ z)

    def _contact(self, dt: float, d0: float, depth: float) -> tuple[int, np.ndarray]:
        """Instant within a free step at which the stage, going linearly from ``d0`` to
        ``depth``, reaches the recovering top (in units of dt / 2^RELEASE_DEPTH) and the
        state then, by bisection on the free ladder (a step's jump onto the specimen would
        push it by up to the step's travel at once)."""
        whole = 2**self.RELEASE_DEPTH
        return self._last_before("free", dt, lambda z, units: self._sinking(z) > d0 + (depth - d0) * units / whole)

    def _last_before(self, contact: Contact, dt: float, still) -> tuple[int, np.ndarray]:
        """The last instant of the step (units of dt / 2^RELEASE_DEPTH) at which
        ``still(state, units)`` holds, stepping ``contact``'s ladder from the state now
        (``still`` holds now and changes once within the step), and the state then."""
        units, z = 0, self.z
        for j, flow in enumerate(self._ladder(contact, dt), start=1):
            trial = self._step(contact, z, flow)
            later = units + 2 ** (self.RELEASE_DEPTH - j)
            if still(trial, later):
                units, z = later, trial
        return units, z

    def _run_for(self, contact: Contact, units: int, dt: float, z: np.ndarray) -> np.ndarray:
        """``z`` propagated in ``contact`` for ``units`` x dt / 2^RELEASE_DEPTH (up to dt),
        one ladder step per binary digit: no new matrix exponential inside a run (in contact
        the stage's position and speed are in the state)."""
        if units >= 2**self.RELEASE_DEPTH:
            return self._step(contact, z, self._flow(contact, dt))
        for j, flow in enumerate(self._ladder(contact, dt), start=1):
            if units & (1 << (self.RELEASE_DEPTH - j)):
                z = self._step(contact, z, flow)
        return z

    def simulate(self, profile: StageProfile, t: np.ndarray, markers_at: np.ndarray | None = None) -> FEResult:
        """Run the stage ``profile`` from rest and sample at the sorted times ``t`` (s);
        the markers only where ``markers_at`` (a mask over ``t``; default all), NaN at
        the other samples.

        Steps go from sample to sample with the profile's breakpoints added, so the
        stage is linear within each step and the result is exact at any sample rate.
        Along a stretch of equal steps (one step length, one stage speed, one contact)
        ``BLOCK`` steps go at once (``_block``); a block in which the stage lets go of the
        specimen, or reaches it again, is stepped one by one instead.
        """
        t = np.asarray(t, dtype=float)
        knots = [k[0] for k in profile.knots() if np.isfinite(k[0])]
        grid = np.union1d(t, knots)
        depths = profile.depth_at(grid)
        self.reset(min(grid[0], 0.0))
        slot = np.full(grid.size, -1)
        slot[np.searchsorted(grid, t)] = np.arange(t.size)
        wanted = np.zeros(grid.size, bool)
        wanted[slot >= 0] = True if markers_at is None else np.asarray(markers_at, bool)
        scalars = np.zeros((t.size, self.structure.segments.shape[0] + 2))   # as ``_readout``'s rows
        markers = np.full((t.size, self.structure.marker_dofs.size), np.nan)
        held = np.zeros(t.size, bool)
        # An instant release: the step onto its time arrives at the push's depth, then leaves.
        jumps = {p.t_keep_end: p.depth for p in profile.pushes if not np.isfinite(p.retract_speed)}
        steady = self._steady_steps(grid, depths, np.isin(grid, list(jumps)))
        B, i = self.BLOCK, 0
        while i < grid.size:
            block = np.s_[i:i + B]
            if steady[i] >= B and self._advance_block(grid[block], depths[block], slot[block], wanted[block],
                                                      scalars, markers, held):
                i += B
                continue
            if grid[i] in jumps:
                self.advance(grid[i], jumps[grid[i]])
            self.advance(grid[i], float(depths[i]))
            if slot[i] >= 0:
                scalar_rows, marker_rows = self._readout(self.contact)
                scalars[slot[i]], held[slot[i]] = scalar_rows @ self.z, self.contact == "held"
                if wanted[i]:
                    markers[slot[i]] = marker_rows @ self.z
            i += 1
        strain = scalars[:, -2] / self.mesh.height
        return FEResult(t, profile.depth_at(t), markers.reshape(t.size, -1, 2), scalars[:, :-2], held, strain)

    def clean_signals(self, model: Model, profile: StageProfile, t: np.ndarray, force_t: np.ndarray,
                      marker_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the sensors are fed, before their noise (``rig.simulator.observe`` and the
        camera's ``observe`` add it), of ``profile`` run with ``model``'s effects, stepped at the
        sorted times ``t`` (holding ``force_t`` and ``marker_t``): the felt segment forces at
        ``force_t`` and the markers' displacements seen at ``marker_t``. An effect with
        memory sees the markers at every step (as a streaming simulator does); otherwise
        the FE reads them only where the camera does (most of its readouts)."""
        fi, mi = np.searchsorted(t, force_t), np.searchsorted(t, marker_t)
        markers_at = None if model.memory else np.isin(np.arange(t.size), mi)
        res = self.simulate(profile, t, markers_at)
        felt = model.felt_force(t, res.bottom_force, res.strain, res.contact)[fi]
        seen = (model.measured_markers(t, res.displacement)[mi] if model.memory
                else model.measured_markers(t[mi], res.displacement[mi]))
        return felt, seen

    def _steady_steps(self, grid: np.ndarray, depths: np.ndarray, jump: np.ndarray) -> np.ndarray:
        """For each step (onto ``grid[i]``), how many steps from it on share its length and
        the stage's speed, none of them an instant release (0 for a zero-length step)."""
        dt = np.diff(grid, prepend=self.t)
        with np.errstate(divide="ignore", invalid="ignore"):
            speed = np.diff(depths, prepend=self.depth) / dt
        scale = np.nanmax(np.abs(speed[dt > 0]), initial=0.0)
        ok = (dt > 0) & ~jump
        like = np.zeros(grid.size, bool)   # step i continues step i - 1's stretch
        like[1:] = (ok[1:] & ok[:-1] & (np.abs(dt[1:] - dt[:-1]) <= 1e-9 * dt[1:])
                    & (np.abs(speed[1:] - speed[:-1]) <= 1e-9 * scale))
        steady = np.zeros(grid.size, int)
        run = 0
        for i in range(grid.size - 1, -1, -1):
            run = (run + 1 if i + 1 < grid.size and like[i + 1] else 1) if ok[i] else 0
            steady[i] = run
        return steady

    def _advance_block(self, times: np.ndarray, depths: np.ndarray, slots: np.ndarray, wanted: np.ndarray,
                       scalars: np.ndarray, markers: np.ndarray, held: np.ndarray) -> bool:
        """Steps onto ``times`` (``BLOCK`` equal steps, the stage linear to ``depths``) at
        once, their samples into ``scalars`` and, where ``wanted``, ``markers``; False, with
        nothing changed, when within them the stage lets go of the specimen or reaches it
        again (``advance`` finds the instant)."""
        dt, d0 = times[0] - self.t, self.depth
        z = self.z.copy()
        if self.contact == "held":
            z[self.ig], z[self.igd] = -d0, -(depths[0] - d0) / dt
        states = self._propagate(self.contact, z, self._flow(self.contact, dt), times.size)
        rows, marker_rows = self._readout(self.contact)
        read = states @ rows.T
        if self.contact == "held":
            if depths[0] < d0 and (read[:, -1] < 0.0).any():
                return False
        elif (read[:, -2] < depths).any():
            return False
        sampled = slots >= 0
        scalars[slots[sampled]], held[slots[sampled]] = read[sampled], self.contact == "held"
        seen = np.flatnonzero(sampled & wanted)
        if seen.size:
            markers[slots[seen]] = states[seen] @ marker_rows.T
        self.z, self.t, self.depth = states[-1], float(times[-1]), float(depths[-1])
        return True
