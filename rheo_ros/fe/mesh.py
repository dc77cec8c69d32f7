"""FE meshes of the specimen and their stiffness per unit Young's modulus.

Two geometries (contract, parameter ``geometry``), both the 2D mesh of Section IV on
the marker grid (rows x cols nodes over the face, bilinear quadrilaterals, plane
stress, two degrees of freedom per node):

- ``uniaxial``: the homogeneous block of the paper's Sections II-III: both faces
  frictionless, so the block is in uniform uniaxial stress (which a Q4 mesh
  represents exactly) and the Poisson ratio shows only in the lateral motion;
- ``plane_fe``: the specimen's face with the boundary conditions of ``Boundary``.

Node order is the marker order of the contract: row-major, bottom row first, left
to right. The stiffness is split as in eq. 18-19, ``K = lambda^g K_lambda + mu^g K_mu``
(per unit E), so the Poisson ratio enters through two scalars only; it is assembled
sparse, so that a mesh refined far below the marker grid (``refined``) stays cheap.

Boundary conditions (``Boundary``) are stated choices: each face is ``bonded`` (no
slip against the sensor / the stage) or ``frictionless`` (free to slide). With both
faces frictionless the block could slide sideways as a whole; the bottom node at the
centre is then held in x (exact for the symmetric push).

What the sensors see of a mesh: marker displacements by bilinear interpolation at the
markers' positions (``interpolation``), and each tactile segment's force as the
bottom pressure integrated over the segment's extent (``segment_integrals``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sparse

GEOMETRIES = ("uniaxial", "plane_fe")
CONTACTS = ("bonded", "frictionless")
GAMMA_RANGE = (-1.0, 0.5)   # Poisson ratio of a stable isotropic plate in plane stress (open interval)
_UNPICKLED: dict[tuple, Mesh] = {}   # the meshes a process has received (``_mesh_of``)
_UNPICKLED_MAX = 16


@dataclass(frozen=True)
class Boundary:
    """How the bottom face meets the sensor and the top face the stage."""

    bottom: str = "bonded"
    top: str = "bonded"

    def __post_init__(self) -> None:
        for face in ("bottom", "top"):
            if getattr(self, face) not in CONTACTS:
                raise ValueError(f"boundary.{face}: {getattr(self, face)!r}, expected one of {', '.join(CONTACTS)}")


def lame_per_unit_modulus(gamma: float) -> tuple[float, float]:
    """Plane-stress ``(lambda^gamma, mu^gamma)`` for E = 1.

    The paper's eq. 19 writes the 3D value ``gamma / ((1 + gamma)(1 - 2 gamma))``;
    a thin plate loaded in its plane (12.5 mm thick, 80 mm wide) is in plane stress,
    where the effective first Lame constant is ``2 lambda mu / (lambda + 2 mu)``
    = ``gamma / (1 - gamma^2)``.
    """
    if not GAMMA_RANGE[0] < gamma < GAMMA_RANGE[1]:
        raise ValueError(f"Poisson ratio {gamma} outside (-1, 0.5)")
    return gamma / (1.0 - gamma**2), 1.0 / (2.0 * (1.0 + gamma))


def lame_slope_per_unit_modulus(gamma: float) -> tuple[float, float]:
    """d/dgamma of :func:`lame_per_unit_modulus`."""
    return lame_derivative_per_unit_modulus(gamma, 1)


def lame_derivative_per_unit_modulus(gamma: float, order: int) -> tuple[float, float]:
    """The ``order``-th derivative in gamma of :func:`lame_per_unit_modulus` (order 0: the
    values), from ``lambda = (1/(1 - gamma) - 1/(1 + gamma)) / 2``, ``mu = 1/(2 (1 + gamma))``."""
    if order == 0:
        return lame_per_unit_modulus(gamma)
    f = 0.5 * math.factorial(order)
    minus = (-1.0) ** order
    return f * (1.0 / (1.0 - gamma) ** (order + 1) - minus / (1.0 + gamma) ** (order + 1)), \
        f * minus / (1.0 + gamma) ** (order + 1)


FRICTIONLESS = Boundary("frictionless", "frictionless")


def geometry_boundary(geometry: str, boundary: Boundary | None) -> Boundary:
    """The boundary conditions of ``geometry``: ``None`` is its default (``uniaxial``:
    both faces frictionless; ``plane_fe``: both bonded). A bonded face would restrain
    the uniaxial block's lateral expansion, so it is refused there."""
    if geometry == "plane_fe":
        return boundary or Boundary()
    for face in ("bottom", "top"):
        if boundary is not None and getattr(boundary, face) != "frictionless":
            raise ValueError(f"boundary.{face}: {getattr(boundary, face)!r} with geometry uniaxial, the block in "
                             "uniaxial stress with both faces frictionless; use geometry plane_fe for a bonded face")
    return FRICTIONLESS


@dataclass(frozen=True)
class Mesh:
    """Specimen mesh. Lengths in m; ``nodes`` (N, 2) reference positions."""

    geometry: str
    width: float
    height: float
    thickness: float
    rows: int
    cols: int
    nodes: np.ndarray = field(repr=False)
    boundary: Boundary = Boundary()

    @classmethod
    def build(
        cls, geometry: str, width: float, height: float, thickness: float, rows: int = 5, cols: int = 5,
        boundary: Boundary | None = None,
    ) -> Mesh:
        """``rows`` x ``cols`` nodes over the face; ``boundary`` None: the geometry's own
        (``geometry_boundary``)."""
        if geometry not in GEOMETRIES:
            raise ValueError(f"geometry {geometry!r}: expected one of {', '.join(GEOMETRIES)}")
        if min(width, height, thickness) <= 0:
            raise ValueError("specimen width, height and thickness must be positive")
        if rows < 2 or cols < 2:
            raise ValueError("a mesh needs at least two nodes along each axis")
        X, Y = np.meshgrid(np.linspace(0.0, width, cols), np.linspace(0.0, height, rows))
        return cls(geometry, width, height, thickness, rows, cols, np.column_stack([X.ravel(), Y.ravel()]),
                   geometry_boundary(geometry, boundary))

    def __reduce__(self) -> tuple:
        # A mesh crosses to a worker process inside every job's record: unpickled as the
        # process's one copy of it, its cached stiffness (~1.2 ms to assemble, in each
        # closed form's latency) is built once per process, not once per job.
        return _mesh_of, (self.geometry, self.width, self.height, self.thickness, self.rows, self.cols,
                          self.nodes, self.boundary)

    def refined(self, factor: int) -> Mesh:
        """The same specimen with every element split ``factor`` x ``factor``; ``factor`` 1
        is this mesh."""
        if factor < 1:
            raise ValueError(f"mesh refinement {factor}: must be a positive integer")
        if factor == 1:
            return self
        return Mesh.build(self.geometry, self.width, self.height, self.thickness,
                          (self.rows - 1) * factor + 1, (self.cols - 1) * factor + 1, self.boundary)

    @property
    def n_dofs(self) -> int:
        return 2 * self.nodes.shape[0]

    @property
    def bottom(self) -> np.ndarray:
        """Bottom nodes P1..Pn, left to right."""
        return np.arange(self.cols)

    @property
    def top(self) -> np.ndarray:
        return np.arange((self.rows - 1) * self.cols, self.rows * self.cols)

    @staticmethod
    def y_dofs(nodes: np.ndarray) -> np.ndarray:
        return 2 * nodes + 1

    @staticmethod
    def x_dofs(nodes: np.ndarray) -> np.ndarray:
        return 2 * nodes

    @staticmethod
    def node_dofs(nodes: np.ndarray) -> np.ndarray:
        return (nodes[:, None] * 2 + np.arange(2)).ravel()

    def supports(self, stage_contact: bool) -> tuple[np.ndarray, np.ndarray]:
        """Held dofs (bool, n_dofs) and each held dof's displacement per unit stage depth:
        the bottom on the sensor, the top pushed down by 1 m while the stage touches it."""
        held = np.zeros(self.n_dofs, bool)
        target = np.zeros(self.n_dofs)
        held[self.y_dofs(self.bottom)] = True
        if stage_contact:
            held[self.y_dofs(self.top)] = True
            target[self.y_dofs(self.top)] = -1.0
        if self.boundary.bottom == "bonded":
            held[self.x_dofs(self.bottom)] = True
        if stage_contact and self.boundary.top == "bonded":
            held[self.x_dofs(self.top)] = True
        if not held[0::2].any():   # nothing holds the block sideways: its centre stays put
            centre = self.bottom[np.argmin(np.abs(self.nodes[self.bottom, 0] - self.width / 2))]
            held[self.x_dofs(centre)] = True
        return held, target

    @cached_property
    def stiffness_parts(self) -> tuple[sparse.csr_matrix, sparse.csr_matrix]:
        """``(K_lambda, K_mu)``: stiffness per unit Lame constant (N/m per Pa), sparse."""
        # Bilinear quadrilateral, 2 x 2 Gauss points; strain in Voigt form (xx, yy, xy).
        I_lambda = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
        I_mu = np.diag([2.0, 2.0, 1.0])
        dx, dy = self.width / (self.cols - 1), self.height / (self.rows - 1)
        corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        ke_l, ke_m = np.zeros((8, 8)), np.zeros((8, 8))
        g = 1.0 / np.sqrt(3.0)
        for xi in (-g, g):
            for eta in (-g, g):
                dN_dxi = corners[:, 0] * (1 + eta * corners[:, 1]) / 4
                dN_deta = corners[:, 1] * (1 + xi * corners[:, 0]) / 4
                dN_dx, dN_dy = dN_dxi * 2 / dx, dN_deta * 2 / dy
                B = np.zeros((3, 8))
                B[0, 0::2], B[1, 1::2] = dN_dx, dN_dy
                B[2, 0::2], B[2, 1::2] = dN_dy, dN_dx
                w = self.thickness * dx * dy / 4  # Gauss weight 1 x Jacobian determinant
                ke_l += w * B.T @ I_lambda @ B
                ke_m += w * B.T @ I_mu @ B
        dofs = np.stack([2 * self._quads(), 2 * self._quads() + 1], axis=2).reshape(-1, 8)
        return _assemble(dofs, ke_l, self.n_dofs), _assemble(dofs, ke_m, self.n_dofs)

    def stiffness(self, gamma: float) -> sparse.csr_matrix:
        """Stiffness per unit Young's modulus, ``lambda^g K_lambda + mu^g K_mu`` (eq. 18-19),
        sparse."""
        K_lambda, K_mu = self.stiffness_parts
        lam, mu = lame_per_unit_modulus(float(gamma))
        return (lam * K_lambda + mu * K_mu).tocsr()

    def stiffness_derivative(self, gamma: float, order: int) -> sparse.csr_matrix:
        """The ``order``-th derivative in gamma of :meth:`stiffness`, sparse."""
        K_lambda, K_mu = self.stiffness_parts
        lam, mu = lame_derivative_per_unit_modulus(float(gamma), order)
        return (lam * K_lambda + mu * K_mu).tocsr()

    def lumped_mass(self, density: float) -> np.ndarray:
        """Lumped nodal mass per dof (kg)."""
        dx, dy = self.width / (self.cols - 1), self.height / (self.rows - 1)
        m = np.zeros(self.nodes.shape[0])
        for quad in self._quads():
            m[quad] += density * dx * dy * self.thickness / 4
        return np.repeat(m, 2)

    # -- assembly ---------------------------------------------------------------------

    def _quads(self) -> np.ndarray:
        """Node numbers of each element, counter-clockwise from its bottom left."""
        r, j = np.meshgrid(np.arange(self.rows - 1), np.arange(self.cols - 1), indexing="ij")
        first = (r * self.cols + j).ravel()
        return np.column_stack([first, first + 1, first + self.cols + 1, first + self.cols])

    # -- what the sensors see ---------------------------------------------------------

    def interpolation(self, points: np.ndarray) -> sparse.csr_matrix:
        """(2 P, n_dofs): displacements (x, y interleaved) at ``points`` (P, 2) in m, by the
        elements' bilinear shape functions."""
        points = np.asarray(points, float)
        ys = self.nodes[:: self.cols, 1]
        r = np.clip(np.searchsorted(ys, points[:, 1], side="right") - 1, 0, self.rows - 2)
        ty = (points[:, 1] - ys[r]) / (ys[r + 1] - ys[r])
        rows, cols, vals = [], [], []
        xs = self.nodes[: self.cols, 0]
        c = np.clip(np.searchsorted(xs, points[:, 0], side="right") - 1, 0, self.cols - 2)
        tx = (points[:, 0] - xs[c]) / (xs[c + 1] - xs[c])
        for k in range(len(points)):
            n0 = r[k] * self.cols + c[k]
            corners = (n0, n0 + 1, n0 + self.cols + 1, n0 + self.cols)
            weights = ((1 - tx[k]) * (1 - ty[k]), tx[k] * (1 - ty[k]), tx[k] * ty[k], (1 - tx[k]) * ty[k])
            for axis in (0, 1):
                rows += [2 * k + axis] * 4
                cols += [2 * n + axis for n in corners]
                vals += list(weights)
        return sparse.csr_matrix((vals, (rows, cols)), shape=(2 * len(points), self.n_dofs))

    def segment_integrals(self, edges: np.ndarray) -> np.ndarray:
        """(segments, n_bottom): each tactile segment's force from the bottom nodes'
        reactions, the segments spanning ``edges`` (segments + 1, m, along x).

        The reactions are the consistent nodal loads of a pressure linear between the
        nodes; that pressure is recovered (the edge's consistent mass matrix solved) and
        integrated exactly over each segment.
        """
        edges = np.asarray(edges, float)
        x = self.nodes[self.bottom, 0]
        h = np.diff(x)
        mass = np.zeros((x.size, x.size))
        for i, hi in enumerate(h):
            mass[i : i + 2, i : i + 2] += hi / 6 * np.array([[2.0, 1.0], [1.0, 2.0]])
        recover = np.linalg.inv(mass)            # reactions -> nodal pressures (N/m)
        # Integral over [a, b] of the hat function of each node (piecewise linear).
        def hat_integrals(a: float, b: float) -> np.ndarray:
            out = np.zeros(x.size)
            for i in range(x.size - 1):
                lo, hi_ = max(a, x[i]), min(b, x[i + 1])
                if hi_ <= lo:
                    continue
                t0, t1 = (lo - x[i]) / h[i], (hi_ - x[i]) / h[i]
                out[i] += h[i] * ((t1 - t1**2 / 2) - (t0 - t0**2 / 2))      # 1 - t
                out[i + 1] += h[i] * (t1**2 - t0**2) / 2                      # t
            return out
        return np.array([hat_integrals(a, b) for a, b in zip(edges[:-1], edges[1:])]) @ recover


def _assemble(element_dofs: np.ndarray, element: np.ndarray, n_dofs: int) -> sparse.csr_matrix:
    """Sum one element matrix over every element's dofs (E, k) into a sparse (n, n)."""
    k = element_dofs.shape[1]
    rows = np.repeat(element_dofs, k, axis=1).ravel()
    cols = np.tile(element_dofs, (1, k)).ravel()
    vals = np.tile(element.ravel(), element_dofs.shape[0])
    return sparse.csr_matrix((vals, (rows, cols)), shape=(n_dofs, n_dofs))


def _mesh_of(geometry: str, width: float, height: float, thickness: float, rows: int, cols: int,
             nodes: np.ndarray, boundary: Boundary) -> Mesh:
    """The mesh of these fields: the one this process already received where it has (its
    caches with it), else a new one, kept for the next (the last ``_UNPICKLED_MAX``)."""
    key = (geometry, width, height, thickness, rows, cols, boundary, nodes.shape, nodes.tobytes())
    mesh = _UNPICKLED.get(key)
    if mesh is None:
        if len(_UNPICKLED) >= _UNPICKLED_MAX:
            del _UNPICKLED[next(iter(_UNPICKLED))]
        mesh = _UNPICKLED[key] = Mesh(geometry, width, height, thickness, rows, cols, nodes, boundary)
    return mesh
