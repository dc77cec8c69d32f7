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

The elastic shape is solved on a mesh refined below the marker grid (``refine``),
chosen for accuracy: the markers read it by interpolation at their positions, each
tactile segment as the bottom pressure integrated over its extent
(``Mesh.segment_integrals``). At ``refine`` 1 without segment edges the bottom
nodes' reactions are the segment forces, as in the paper's Section IV.

Release follows the contact: the specimen stays on a retracting stage while it
presses on it (the scalar stress stays positive), then recovers freely. At the
default 20 mm/s it lets go within a millisecond; at the paper's 0.5 mm/s it follows
the stage for seconds.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.polynomial import chebyshev

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.banded import BandedCholesky
from rheo_ros.fe.dynamic import DynamicFE
from rheo_ros.fe.mesh import GAMMA_RANGE, Mesh
from rheo_ros.models.effects import Model, Release
from rheo_ros.models.elements import Element
from rheo_ros.models.response import Response, respond, respond_voigt_spring, stage_program


@dataclass(frozen=True)
class ElasticShape:
    """Per unit stage depth (m) and unit Young's modulus (Pa): marker displacements
    (N, 2) in m/m, and tactile segment forces (segments,) in N/(Pa m)."""

    displacement: np.ndarray
    bottom_force: np.ndarray


def elastic_shape(mesh: Mesh, gamma: float, order: int = 1) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Static elastic solution of ``mesh`` for a unit stage depth and unit E, under the
    mesh's boundary conditions, and its derivatives in gamma up to ``order``: the dof
    displacements (m/m) and the bottom nodes' y reactions (N/(Pa m), positive pressing
    the sensor), each a list (value, first derivative, ...). The derivatives come from
    the same factorisation (Leibniz on ``K u = 0`` at the free dofs:
    ``K u^(k) = -sum_j C(k, j) K^(j) u^(k-j)``; the held dofs do not move with gamma)."""
    K = [mesh.stiffness(gamma)] + [mesh.stiffness_derivative(gamma, k) for k in range(1, order + 1)]
    held, u0 = mesh.supports(stage_contact=True)
    free = ~held
    lu = BandedCholesky(K[0][free][:, free])
    u0[free] = lu.solve(-(K[0][free][:, held] @ u0[held]))
    u = [u0]
    for k in range(1, order + 1):
        rhs = sum(math.comb(k, j) * (K[j] @ u[k - j]) for j in range(1, k + 1))
        uk = np.zeros_like(u0)
        uk[free] = lu.solve(-rhs[free])
        u.append(uk)
    bottom = mesh.y_dofs(mesh.bottom)
    reactions = [sum(math.comb(k, j) * (K[j] @ u[k - j]) for j in range(k + 1))[bottom] for k in range(order + 1)]
    return u, reactions


@dataclass(frozen=True)
class Dynamics:
    """What the quasi-static limit leaves out, as the simulator's dynamic FE has it: the
    specimen's ``density`` (kg/m^3) and the stage contact's stabilisation frequency
    ``omega`` (rad/s): inertia, and a stage constraint met within about v / omega."""

    density: float
    omega: float


@dataclass(frozen=True)
class Prediction:
    """``force`` (T, n_bottom) in N at the force times; ``displacement`` (Tm, N, 2) in m
    at the marker times. Where no effect moves the markers, ``displacement`` is
    ``depth`` (Tm,) m times ``shape`` (N, 2) m/m, and both are given (else None), and
    ``markers`` is None: the product is formed on first look (a fit's solver works on
    depth and shape alone, and forming it was an eighth of an evaluation)."""

    force: np.ndarray
    markers: np.ndarray | None = None
    depth: np.ndarray | None = None
    shape: np.ndarray | None = None

    @cached_property
    def displacement(self) -> np.ndarray:
        return self.markers if self.markers is not None else self.depth[:, None, None] * self.shape[None]


class QuasiStaticFE:
    """Forward model: (model, Poisson ratio, stage profile) -> segment forces and markers.

    Args:
        mesh: the marker grid (markers at its nodes, one tactile segment per bottom node).
        refine: the FE mesh splits each of the grid's elements ``refine`` x ``refine``.
        segment_edges: x (m) of the tactile segments' edges (segments + 1); None: the
            grid's bottom nodes' reactions themselves (only at ``refine`` 1).
    """

    SHAPES_KEPT = 64   # elastic shapes cached (one per Taylor grid point a fit reaches)
    # The shape at a ratio is the Taylor polynomial of degree TAYLOR_ORDER about the nearest
    # point of this grid, where it is solved exactly with its derivatives (one
    # factorisation: a fit's steps in the ratio mostly stay near one point). The step's
    # error is ~(grid/2)^6 u^(6)/6!: measured 4e-14 relative at gamma 0.3, -0.5 and 0.45,
    # 1e-13 at -0.9 (first order on this grid errs by 4e-8). The shape stays a function
    # of the ratio alone, not of what was solved before (the node's fits and the offline
    # ones must agree to 1e-9).
    TAYLOR_GRID = 1e-3
    TAYLOR_ORDER = 5
    # A mesh made by ``finer()`` only measures its coarser one's discretisation error
    # (the difference of the two, ~1e-4 of the shape): its shape at a ratio is the
    # coarser's there plus their difference solved on this much coarser grid and stepped
    # to the ratio to first order. The step's error is (grid/2)^2/2 times the second
    # derivative's own discretisation error, ~1e-5 of the difference; the 129 x 129
    # solve is then one per grid point, shared by every fit near it, not one per fit.
    DIFFERENCE_GRID = 0.01

    def __init__(self, mesh: Mesh, refine: int = 1, segment_edges: np.ndarray | None = None,
                 coarser: QuasiStaticFE | None = None, dynamics: Dynamics | None = None) -> None:
        self.mesh, self.refine = mesh, refine
        self.segment_edges = segment_edges
        self.coarser = coarser
        self.dynamics = dynamics
        self.fe_mesh = mesh.refined(refine)
        if segment_edges is None and refine != 1:
            raise ValueError("a refined mesh needs the tactile segments' edges")
        self._finer: QuasiStaticFE | None = None
        self._segments = None if segment_edges is None else self.fe_mesh.segment_integrals(segment_edges)
        self._markers = self.fe_mesh.interpolation(mesh.nodes)
        self._shapes: dict[float, tuple[ElasticShape, ...]] = {}   # gamma: (shape, its derivatives in gamma)
        # The last material responses (see _response): a fit's finite-difference column in
        # gamma or in an effect's parameter leaves the rheology and the times alone.
        self._responses: dict[tuple, Response] = {}
        self._table: np.ndarray | None = None

    def finer(self) -> QuasiStaticFE:
        """The same model on a mesh twice as fine (its difference from this one measures
        this mesh's discretisation error); the marker grid's own mesh doubles to 2 with
        the segments integrated over their extent."""
        if self._finer is None:
            edges = self.segment_edges
            if edges is None:   # nodal forces: the segments are the bottom nodes' tributary halves
                x = self.mesh.nodes[self.mesh.bottom, 0]
                edges = np.concatenate([[x[0]], (x[1:] + x[:-1]) / 2, [x[-1]]])
            self._finer = QuasiStaticFE(self.mesh, 2 * self.refine, edges, coarser=self)
        return self._finer

    def shape(self, gamma: float) -> ElasticShape:
        gamma = float(gamma)
        if self.coarser is not None:
            return self._shape_from_coarser(gamma)
        anchor = self._anchor(gamma, self.TAYLOR_GRID)
        terms = self._exact(anchor)
        step = gamma - anchor
        if step == 0.0:
            return terms[0]
        weights = [step**k / math.factorial(k) for k in range(len(terms))]
        return ElasticShape(sum(w * s.displacement for w, s in zip(weights, terms)),
                            sum(w * s.bottom_force for w, s in zip(weights, terms)))

    @staticmethod
    def _anchor(gamma: float, grid: float) -> float:
        anchor = round(gamma / grid) * grid
        return anchor if GAMMA_RANGE[0] < anchor < GAMMA_RANGE[1] else gamma

    def _exact(self, gamma: float) -> tuple[ElasticShape, ...]:
        """The solved shape at ``gamma`` and its derivatives, cached."""
        if gamma not in self._shapes:
            if len(self._shapes) >= self.SHAPES_KEPT:
                del self._shapes[next(iter(self._shapes))]
            self._shapes[gamma] = self._solve_shape(gamma)
        return self._shapes[gamma]

    def _shape_from_coarser(self, gamma: float) -> ElasticShape:
        """The coarser mesh's shape at ``gamma`` plus this mesh's difference from it, solved
        at the nearest ``DIFFERENCE_GRID`` point and stepped to ``gamma`` (``finer()``)."""
        anchor = self._anchor(gamma, self.DIFFERENCE_GRID)
        (fine, fine_slope), (coarse, coarse_slope) = self._exact(anchor)[:2], self.coarser._exact(anchor)[:2]
        here, step = self.coarser.shape(gamma), gamma - anchor
        return ElasticShape(
            here.displacement + fine.displacement - coarse.displacement
            + step * (fine_slope.displacement - coarse_slope.displacement),
            here.bottom_force + fine.bottom_force - coarse.bottom_force
            + step * (fine_slope.bottom_force - coarse_slope.bottom_force))

    def _solve_shape(self, gamma: float) -> tuple[ElasticShape, ...]:
        """The shape at ``gamma`` and its derivatives in gamma: up to TAYLOR_ORDER on the
        grid's own mesh, the first on a finer one (``_shape_from_coarser``)."""
        u, bottom = elastic_shape(self.fe_mesh, gamma, 1 if self.coarser is not None else self.TAYLOR_ORDER)
        return tuple(self._observed(uk, rk) for uk, rk in zip(u, bottom))

    def _observed(self, u: np.ndarray, bottom: np.ndarray) -> ElasticShape:
        """What the markers and tactile segments see of dof displacements ``u`` and bottom reactions."""
        force = bottom if self._segments is None else self._segments @ bottom
        return ElasticShape((self._markers @ u).reshape(-1, 2), force)

    # Poisson ratios the implied-force table covers (plane stress: smooth up to 0.5),
    # and its Chebyshev nodes: 32 give the forces within 1e-5 relative (measured: 24 give 2e-4).
    TABLE_GAMMA = (-0.95, 0.4999)
    TABLE_NODES = 32

    def implied_force(self, u: np.ndarray, gamma: float) -> tuple[np.ndarray, np.ndarray]:
        """Segment forces (N/Pa) per unit Young's modulus that marker displacements ``u``
        (N, 2) in m imply, and their derivative in gamma: the elastic shape closest to
        ``u`` (least squares over the markers) and its bottom reaction. The paper's ``J u``
        (eq. 10, IV.B), computed on this converged mesh instead of the marker grid's own
        elements; the derivative lets a closed form's solver skip finite differences.

        For speed (a closed form tries many ratios) the shapes come from a Chebyshev
        table over ``TABLE_GAMMA``, built on first use (``TABLE_NODES`` solves).
        """
        (phi, force), (dphi, dforce) = self._shape_table(float(gamma))
        u = np.ravel(u)
        s, p = u @ phi, phi @ phi
        ds, dp = u @ dphi, 2.0 * (phi @ dphi)
        return force * s / p, dforce * s / p + force * (ds * p - s * dp) / p**2

    def tabulated_shape(self, gamma: float) -> ElasticShape:
        """The elastic shape from the implied-force table (within 1e-5 relative, no
        factorisation): for figures and live overlays at a new ratio each update, not for
        fits (an exact solve where the table does not reach)."""
        lo, hi = self.TABLE_GAMMA
        if not lo <= gamma <= hi:
            return self.shape(gamma)
        phi, force = self._shape_table(float(gamma))[0]
        return ElasticShape(phi.reshape(-1, 2), force)

    @cached_property
    def _node_shapes(self) -> tuple[np.ndarray, list[ElasticShape]]:
        """The table's Chebyshev nodes on [-1, 1] and the exact shapes solved there."""
        lo, hi = self.TABLE_GAMMA
        x = np.cos(np.pi * (np.arange(self.TABLE_NODES) + 0.5) / self.TABLE_NODES)
        return x, [self._observed(*(part[0] for part in elastic_shape(self.fe_mesh, lo + (xi + 1) / 2 * (hi - lo), 0)))
                   for xi in x]

    def _shape_table(self, gamma: float) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """(shape, bottom force) and their derivatives in gamma, from the table."""
        lo, hi = self.TABLE_GAMMA
        if not lo <= gamma <= hi:
            raise ValueError(f"Poisson ratio {gamma} outside the table's [{lo}, {hi}]")
        if self._table is None:
            x, shapes = self._node_shapes
            n = self.TABLE_NODES
            values = np.array([np.concatenate([s.displacement.ravel(), s.bottom_force]) for s in shapes])
            coef = chebyshev.chebfit(x, values, n - 1)
            slope = np.vstack([chebyshev.chebder(coef) * (2 / (hi - lo)), np.zeros((1, coef.shape[1]))])
            self._table = np.hstack([coef, slope])   # (n, 2 k): values and slopes side by side
        # One product with the Chebyshev basis at gamma (T_j = cos(j arccos x)) instead of
        # chebval's Clenshaw loop over arrays: a closed form evaluates it hundreds of times.
        x = np.clip(2 * (gamma - lo) / (hi - lo) - 1, -1.0, 1.0)
        row = np.cos(np.arange(self.TABLE_NODES) * np.arccos(x)) @ self._table
        k, m = self.mesh.nodes.size, self._table.shape[1] // 2
        return (row[:k], row[k:m]), (row[m:m + k], row[m + k:])

    # The relative singular value below which a direction is no marker shape's (``marker_span``).
    SPAN_TOLERANCE = 1e-12

    @cached_property
    def marker_span(self) -> np.ndarray | None:
        """(2 N, k) orthonormal basis of every marker shape a Poisson ratio gives (the
        markers' (N, 2) shapes raveled), or None when they span so many directions that
        working in the span would save nothing.

        The shapes of the whole ratio range lie in a few directions: on the 5 x 5 grid, 8
        of 50 (measured at refine 1 and 8: the 9th singular value of 200 shapes over the
        range is 1e-14 of the first, the 8th 4e-7); 7 x 7: 12 of 98, 9 x 9: 13 of 162. A
        fit's marker residuals then reduce to those directions
        (``WholeRecordProblem.solver_residuals``). The span is that of the implied-force
        table's solved shapes (``TABLE_NODES`` ratios over ``TABLE_GAMMA``, solved once
        for both): every shape of the open range lies within 7e-12 of it, -0.99999 and
        0.49999 included (measured on the three grids); a span of half as many directions
        as shapes or more is not trusted to be the whole."""
        shapes = np.array([s.displacement.ravel() for s in self._node_shapes[1]])
        _, sv, vt = np.linalg.svd(shapes, full_matrices=False)
        k = int(np.sum(sv > self.SPAN_TOLERANCE * sv[0]))
        return vt[:k].T.copy() if 2 * k < len(shapes) and 2 * k < shapes.shape[1] else None

    RESPONSES = 8   # kept: a Jacobian's columns, and the trial step beside them

    def _response(self, element: Element, profile: StageProfile, t: np.ndarray,
                  spring: Callable[[np.ndarray], np.ndarray] | None = None) -> Response:
        """``respond`` of ``element`` to ``profile``'s program at ``t`` (with a nonlinear
        Voigt ``spring``: ``respond_voigt_spring``, an ODE solve), kept for the next calls
        with the same element, spring, profile and times (compared whole: a key of the
        times' checksum only finds the candidate). A spring is an effect's method: keyed by
        the effect's value, which a fit rebuilds at every evaluation (a method compares its
        object by identity); an effect that cannot be hashed is solved every time."""
        def solve() -> Response:
            return (respond(element, stage_program(profile), t) if spring is None else
                    respond_voigt_spring(element, spring, self.mesh.height, stage_program(profile), t))

        law = None if spring is None else (getattr(spring, "__self__", spring), getattr(spring, "__func__", None))
        key = (element, law, profile, t.size, zlib.crc32(t.data))
        try:
            kept = self._responses.get(key)
        except TypeError:   # a user's effect or element that cannot be hashed
            return solve()
        if kept is not None and np.array_equal(kept.t, t):
            return kept
        r = solve()
        if len(self._responses) >= self.RESPONSES:
            self._responses.pop(next(iter(self._responses)), None)
        self._responses[key] = r
        return r

    def dynamic_predict(self, model: Model, gamma: float, profile: StageProfile,
                        force_t: np.ndarray, marker_t: np.ndarray) -> Prediction | None:
        """``predict`` with inertia and the stage's compliance (``dynamics``): the
        simulator's dynamic FE on this mesh, stepped at the samples' times as the simulator
        steps. None without ``dynamics``, or where the dynamic FE has no such model (a
        nonlinear Voigt spring). Its difference from ``predict`` is what the quasi-static
        limit leaves: far under any camera's noise at a real density, the whole misfit of
        a noise-free simulated record (``fit._quasi_static_floor``)."""
        if self.dynamics is None or model.voigt_spring is not None:
            return None
        fe = DynamicFE(self.mesh, model.rheology(), gamma, density=self.dynamics.density,
                       omega=self.dynamics.omega, refine=self.refine, segment_edges=self.segment_edges)
        return Prediction(*fe.clean_signals(model, profile, np.union1d(force_t, marker_t), force_t, marker_t))

    def predict(
        self, model: Model, gamma: float, profile: StageProfile,
        force_t: np.ndarray, marker_t: np.ndarray, tabulated: bool = False,
    ) -> Prediction:
        """Segment forces at ``force_t`` and marker displacements at ``marker_t``;
        ``tabulated``: the shape from the table (:meth:`tabulated_shape`)."""
        shape = self.tabulated_shape(gamma) if tabulated else self.shape(gamma)
        # The last time is the end of the hold: adhesion keeps a share of the force then.
        t_let_go = np.nextafter(profile.t_keep_end, -np.inf)
        t = np.concatenate([force_t, marker_t, [t_let_go]])
        order = np.argsort(t, kind="stable")
        spring = model.voigt_spring
        r = self._response(model.rheology(), profile, t[order], spring)
        scaled, depth = np.empty_like(t), np.empty_like(t)
        depth[order] = r.strain
        nf, nm = len(force_t), len(marker_t)
        # A fit's trial law may overflow (in the stress, or an effect's hook on it): the fit
        # handles the non-finite prediction; no warning for the user.
        with np.errstate(over="ignore", invalid="ignore"):
            # In time order: a stress effect with memory reads the strain's past.
            scaled[order] = r.stress * model.stress_scale(r.strain / self.mesh.height)
            release = None if r.t_release is None else Release(r.t_release, scaled[-1] * shape.bottom_force)
            force = model.measured_force(force_t, np.outer(scaled[:nf], shape.bottom_force), release)
            at_markers = depth[nf : nf + nm]
            if model.moves_markers:
                return Prediction(force, model.measured_markers(marker_t, at_markers[:, None, None]
                                                                * shape.displacement[None]))
        return Prediction(force, None, at_markers, shape.displacement)
