"""FE meshes of the specimen and their stiffness per unit Young's modulus.

Two geometries (contract, parameter ``geometry``):

- ``uniaxial``: the homogeneous 1D bar of the paper's Sections II-III, nodes P1..Pn
  along the pushing axis, one degree of freedom (y) per node;
- ``plane_fe``: the 2D mesh of Section IV on the marker grid (rows x cols nodes over
  the face, bilinear quadrilaterals, plane stress), two degrees of freedom per node.

Node order is the marker order of the contract: row-major, bottom row first, left
to right. The stiffness is split as in eq. 18-19, ``K = lambda^g K_lambda + mu^g K_mu``
(per unit E), so the Poisson ratio enters through two scalars only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

GEOMETRIES = ("uniaxial", "plane_fe")


def lame_per_unit_modulus(gamma: float) -> tuple[float, float]:
    """Plane-stress ``(lambda^gamma, mu^gamma)`` for E = 1.

    The paper's eq. 19 writes the 3D value ``gamma / ((1 + gamma)(1 - 2 gamma))``;
    a thin plate loaded in its plane (12.5 mm thick, 80 mm wide) is in plane stress,
    where the effective first Lame constant is ``2 lambda mu / (lambda + 2 mu)``
    = ``gamma / (1 - gamma^2)``.
    """
    if not -1.0 < gamma < 0.5:
        raise ValueError(f"Poisson ratio {gamma} outside (-1, 0.5)")
    return gamma / (1.0 - gamma**2), 1.0 / (2.0 * (1.0 + gamma))


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

    @classmethod
    def build(
        cls, geometry: str, width: float, height: float, thickness: float, rows: int = 5, cols: int = 5
    ) -> Mesh:
        """``rows`` x ``cols`` nodes over the face (``uniaxial``: ``rows`` nodes, one column)."""
        if geometry not in GEOMETRIES:
            raise ValueError(f"geometry {geometry!r}: expected one of {', '.join(GEOMETRIES)}")
        if min(width, height, thickness) <= 0:
            raise ValueError("specimen width, height and thickness must be positive")
        if geometry == "uniaxial":
            cols = 1
        if rows < 2 or (geometry == "plane_fe" and cols < 2):
            raise ValueError("a mesh needs at least two nodes along each axis")
        ys = np.linspace(0.0, height, rows)
        xs = np.array([width / 2]) if cols == 1 else np.linspace(0.0, width, cols)
        X, Y = np.meshgrid(xs, ys)
        return cls(geometry, width, height, thickness, rows, cols, np.column_stack([X.ravel(), Y.ravel()]))

    @property
    def dofs_per_node(self) -> int:
        return 1 if self.geometry == "uniaxial" else 2

    @property
    def n_dofs(self) -> int:
        return self.nodes.shape[0] * self.dofs_per_node

    @property
    def bottom(self) -> np.ndarray:
        """Bottom nodes P1..Pn, left to right."""
        return np.arange(self.cols)

    @property
    def top(self) -> np.ndarray:
        return np.arange((self.rows - 1) * self.cols, self.rows * self.cols)

    def y_dofs(self, nodes: np.ndarray) -> np.ndarray:
        return nodes * self.dofs_per_node + (self.dofs_per_node - 1)

    def node_dofs(self, nodes: np.ndarray) -> np.ndarray:
        d = self.dofs_per_node
        return (nodes[:, None] * d + np.arange(d)).ravel()

    def displacement_field(self, dofs: np.ndarray) -> np.ndarray:
        """Dof vector(s) (..., n_dofs) -> nodal displacements (..., N, 2)."""
        dofs = np.asarray(dofs)
        n = self.nodes.shape[0]
        if self.dofs_per_node == 2:
            return dofs.reshape(*dofs.shape[:-1], n, 2)
        out = np.zeros((*dofs.shape[:-1], n, 2))
        out[..., 1] = dofs
        return out

    @cached_property
    def stiffness_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """``(K_lambda, K_mu)``: stiffness per unit Lame constant (N/m per Pa)."""
        if self.geometry == "uniaxial":
            return np.zeros((self.n_dofs,) * 2), self._bar_stiffness()
        return self._plane_stiffness_parts()

    def stiffness(self, gamma: float | None) -> np.ndarray:
        """Stiffness per unit Young's modulus, ``lambda^g K_lambda + mu^g K_mu`` (eq. 18-19).

        The uniaxial bar has no Poisson effect (``gamma`` ignored).
        """
        K_lambda, K_mu = self.stiffness_parts
        if self.geometry == "uniaxial":
            return K_mu
        lam, mu = lame_per_unit_modulus(float(gamma))
        return lam * K_lambda + mu * K_mu

    def lumped_mass(self, density: float) -> np.ndarray:
        """Lumped nodal mass per dof (kg)."""
        if self.geometry == "uniaxial":
            seg = self.height / (self.rows - 1) * self.width * self.thickness * density
            m = np.full(self.rows, seg)
            m[[0, -1]] = seg / 2
            return m
        dx, dy = self.width / (self.cols - 1), self.height / (self.rows - 1)
        m = np.zeros(self.nodes.shape[0])
        for quad in self._quads():
            m[quad] += density * dx * dy * self.thickness / 4
        return np.repeat(m, 2)

    # -- assembly ---------------------------------------------------------------------

    def _bar_stiffness(self) -> np.ndarray:
        k = self.width * self.thickness / (self.height / (self.rows - 1))  # A / L_e
        K = np.zeros((self.rows, self.rows))
        for i in range(self.rows - 1):
            K[i : i + 2, i : i + 2] += k * np.array([[1.0, -1.0], [-1.0, 1.0]])
        return K

    def _quads(self) -> np.ndarray:
        c = self.cols
        return np.array(
            [[r * c + j, r * c + j + 1, (r + 1) * c + j + 1, (r + 1) * c + j]
             for r in range(self.rows - 1) for j in range(c - 1)]
        )

    def _plane_stiffness_parts(self) -> tuple[np.ndarray, np.ndarray]:
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
        K_l, K_m = np.zeros((self.n_dofs,) * 2), np.zeros((self.n_dofs,) * 2)
        for quad in self._quads():
            idx = self.node_dofs(quad)
            K_l[np.ix_(idx, idx)] += ke_l
            K_m[np.ix_(idx, idx)] += ke_m
        return K_l, K_m
