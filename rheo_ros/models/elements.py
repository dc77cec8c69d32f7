"""Linear rheological elements: springs and dashpots combined in series and in parallel.

Every element is a linear operator from strain to stress. In the Laplace domain
(zero initial state) ``stress(s) = Q(s) * strain(s)`` with ``Q`` a rational function,
the element's modulus: a spring ``E``, a dashpot ``c*s``; parallel elements add their
moduli, series elements add their compliances ``1/Q``. The differential equation of
a model (the paper's eq. 5 for the three-element model, eq. 23 for Fig. 8(b)) is the
modulus written as ``den(d/dt) stress = num(d/dt) strain``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np


def _add(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sum of two polynomials (highest power first). ``np.polyadd`` and ``np.polymul``
    give the same numbers but cost ~20 x more per call (poly1d checks): a fit builds a
    modulus per evaluation."""
    if a.size < b.size:
        a, b = b, a
    out = a.copy()
    out[a.size - b.size:] += b
    return out


def _trim(poly: np.ndarray) -> np.ndarray:
    """Drop leading zero coefficients (highest power first); keep at least one. (A loop
    over the few coefficients: a fit's Jacobian builds moduli by the thousand, and
    ``flatnonzero``'s calls were half the cost of one.)"""
    poly = np.asarray(poly, dtype=float).reshape(-1)
    for i, c in enumerate(poly.tolist()):
        if c != 0.0:
            return poly[i:]
    return np.zeros(1)


@dataclass(frozen=True, eq=False)
class Modulus:
    """``Q(s) = num(s) / den(s)``; coefficients highest power first, ``den`` monic.

    Common factors of ``s`` are cancelled (two dashpots in series would otherwise
    carry a spurious pole at zero).
    """

    num: np.ndarray
    den: np.ndarray

    @classmethod
    def from_polys(cls, num: Iterable[float], den: Iterable[float]) -> Modulus:
        num, den = _trim(num), _trim(den)
        if den[0] == 0.0:   # trimmed: all zero
            raise ValueError("modulus denominator is zero")
        while num.size > 1 and den.size > 1 and num[-1] == 0.0 and den[-1] == 0.0:
            num, den = num[:-1], den[:-1]
        return cls(num / den[0], den / den[0])

    def __call__(self, s: complex | np.ndarray) -> complex | np.ndarray:
        return np.polyval(self.num, s) / np.polyval(self.den, s)

    def __add__(self, other: Modulus) -> Modulus:  # parallel connection
        return Modulus.from_polys(
            _add(np.convolve(self.num, other.den), np.convolve(other.num, self.den)),
            np.convolve(self.den, other.den),
        )

    def in_series(self, other: Modulus) -> Modulus:
        return Modulus.from_polys(
            np.convolve(self.num, other.num),
            _add(np.convolve(self.num, other.den), np.convolve(other.num, self.den)),
        )


class Element(ABC):
    """A linear rheological element with named parameters."""

    @abstractmethod
    def modulus(self) -> Modulus:
        """The element's modulus ``Q(s)``."""

    @property
    @abstractmethod
    def parameters(self) -> dict[str, float]:
        """Parameter values by name, in a fixed order (depth first)."""

    @abstractmethod
    def with_parameters(self, values: Mapping[str, float]) -> Element:
        """A copy with the named parameters replaced (unknown names raise KeyError)."""

    def ode_coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """``(a, b)`` of ``sum_k a_k d^k(stress)/dt^k = sum_k b_k d^k(strain)/dt^k``.

        Lowest derivative first, ``a`` normalised so that its highest coefficient is 1.
        """
        q = self.modulus()
        return q.den[::-1].copy(), q.num[::-1].copy()


@dataclass(frozen=True)
class Spring(Element):
    """Linear spring: ``stress = E * strain`` (Pa)."""

    name: str
    stiffness: float

    def modulus(self) -> Modulus:
        return Modulus.from_polys([self.stiffness], [1.0])

    @property
    def parameters(self) -> dict[str, float]:
        return {self.name: float(self.stiffness)}

    def with_parameters(self, values: Mapping[str, float]) -> Spring:
        return Spring(self.name, float(values.get(self.name, self.stiffness)))


@dataclass(frozen=True)
class Dashpot(Element):
    """Linear dashpot: ``stress = c * d(strain)/dt`` (Pa s)."""

    name: str
    viscosity: float

    def modulus(self) -> Modulus:
        return Modulus.from_polys([self.viscosity, 0.0], [1.0])

    @property
    def parameters(self) -> dict[str, float]:
        return {self.name: float(self.viscosity)}

    def with_parameters(self, values: Mapping[str, float]) -> Dashpot:
        return Dashpot(self.name, float(values.get(self.name, self.viscosity)))


@dataclass(frozen=True)
class _Composite(Element):
    parts: tuple[Element, ...]

    def __post_init__(self) -> None:
        if len(self.parts) < 2:
            raise ValueError(f"{type(self).__name__} needs at least two parts")
        names = [n for p in self.parts for n in p.parameters]
        duplicated = sorted({n for n in names if names.count(n) > 1})
        if duplicated:
            raise ValueError(f"parameter names used twice: {', '.join(duplicated)}")

    @property
    def parameters(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for part in self.parts:
            out.update(part.parameters)
        return out

    def with_parameters(self, values: Mapping[str, float]) -> Element:
        unknown = set(values) - set(self.parameters)
        if unknown:
            raise KeyError(f"unknown parameters: {', '.join(sorted(unknown))}")
        return type(self)(
            tuple(p.with_parameters({k: v for k, v in values.items() if k in p.parameters}) for p in self.parts)
        )


class Parallel(_Composite):
    """Parts side by side: one strain, the stresses add."""

    def modulus(self) -> Modulus:
        total = self.parts[0].modulus()
        for part in self.parts[1:]:
            total = total + part.modulus()
        return total


class Series(_Composite):
    """Parts one after the other: one stress, the strains add."""

    def modulus(self) -> Modulus:
        total = self.parts[0].modulus()
        for part in self.parts[1:]:
            total = total.in_series(part.modulus())
        return total


# -- the named models ---------------------------------------------------------------

def voigt(E: float, c: float, names: tuple[str, str] = ("E", "c")) -> Parallel:
    """Voigt (Kelvin-Voigt) element: spring E parallel to dashpot c."""
    return Parallel((Spring(names[0], E), Dashpot(names[1], c)))


def maxwell(E: float, c: float, names: tuple[str, str] = ("E", "c")) -> Series:
    """Maxwell element: spring E in series with dashpot c."""
    return Series((Spring(names[0], E), Dashpot(names[1], c)))


def three_element(E: float, c1: float, c2: float) -> Series:
    """The paper's three-element model (Fig. 2(a)): Voigt (E, c1) in series with dashpot c2."""
    return Series((voigt(E, c1, ("E", "c1")), Dashpot("c2", c2)))


def generalized_maxwell(E_inf: float, arms: Iterable[tuple[float, float]]) -> Element:
    """Equilibrium spring ``E_inf`` parallel to Maxwell arms ``(E_k, c_k)``, k = 1, 2, ...

    Parameters are named ``E_inf``, ``E_1``, ``c_1``, ``E_2``, ``c_2``, ...
    """
    parts: list[Element] = [Spring("E_inf", E_inf)]
    for k, (E, c) in enumerate(arms, start=1):
        parts.append(maxwell(E, c, (f"E_{k}", f"c_{k}")))
    return parts[0] if len(parts) == 1 else Parallel(tuple(parts))


def fig8b_model(E1: float, c1: float, E2: float, c2: float) -> Series:
    """The paper's Fig. 8(b) model: spring E2 in series with [dashpot c2 | Maxwell(E1, c1)].

    Its differential equation is eq. 23, its relaxation eq. 24 (two exponentials).
    """
    return Series((Spring("E2", E2), Parallel((Dashpot("c2", c2), maxwell(E1, c1, ("E1", "c1"))))))
