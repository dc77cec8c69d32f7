"""Exact response of a linear rheological element to a loading program.

A program is a sequence of segments, each either strain-controlled at a constant
strain rate (pull, keep, a stage retracting) or stress-free (release: free
recovery). Within a segment the element is a linear time-invariant system with
constant input, so the response is exact: a matrix exponential and its integral, no
time stepping. A one-sided segment (the stage only pushes) ends where the stress
reaches zero: the specimen follows a slowly retracting stage while it still presses
on it, then recovers freely; that instant is found to machine precision by a root
finder on the exact stress.

The element is realised in state space from ``G(s) = Q(s)/s``: input the strain
rate, output the stress. ``G`` is proper for every spring-dashpot network (at high
frequency ``Q`` grows at most like a dashpot, ``c*s``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import brentq

from rheo_ros.experiment import StageProfile
from rheo_ros.models.elements import Dashpot, Element, Parallel, Series, Spring


@dataclass(frozen=True)
class Segment:
    """``duration`` in s (``inf`` for an open end); ``strain_rate`` in 1/s, or
    ``None`` for a stress-free segment (the specimen recovers freely).
    ``one_sided``: the drive only pushes; the segment ends early where the stress
    reaches zero, and the segments after it start there (the next must be stress-free)."""

    duration: float
    strain_rate: float | None
    one_sided: bool = False


@dataclass(frozen=True)
class Program:
    """Loading program starting at ``t0`` from the unloaded state."""

    t0: float
    segments: tuple[Segment, ...]

    @classmethod
    def push_hold_release(
        cls, depth: float, pull_time: float, keep_time: float, t0: float = 0.0, retract_speed: float = np.inf,
    ) -> Program:
        """The paper's Fig. 2(b): pull at ``depth/pull_time``, keep, then release: at
        once, or by a stage retracting at ``retract_speed`` that the specimen follows
        while it presses on it."""
        release: tuple[Segment, ...] = (Segment(np.inf, None),)
        if np.isfinite(retract_speed):
            release = (Segment(depth / retract_speed, -retract_speed, one_sided=True),) + release
        return cls(t0, (Segment(pull_time, depth / pull_time), Segment(keep_time, 0.0)) + release)


def stage_program(profile: StageProfile) -> Program:
    """The top-face displacement program (m) of a stage profile, for the exact model
    response; the specimen follows a retracting stage while it presses on it."""
    return Program.push_hold_release(profile.depth, profile.pull_time, profile.keep_time, profile.t_pull_start,
                                     profile.retract_speed)


@dataclass(frozen=True)
class Response:
    """Stress and strain at times ``t``; ``t_release``: when the first stress-free
    segment began (None: not in the program)."""

    t: np.ndarray
    stress: np.ndarray
    strain: np.ndarray
    t_release: float | None = None


@dataclass(frozen=True)
class StateSpace:
    """Realisation of ``G(s) = Q(s)/s``: ``x' = A x + B rate``, ``stress = C x + D rate``."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: float

    @classmethod
    def of(cls, element: Element) -> StateSpace:
        q = element.modulus()
        num, den = q.num, np.append(q.den, 0.0)   # times s
        while num.size > 1 and num[-1] == 0.0 and den[-1] == 0.0:
            num, den = num[:-1], den[:-1]
        if num.size > den.size:
            raise ValueError("modulus grows faster than a dashpot: not a spring-dashpot network")
        A, B, C, D = signal.tf2ss(num, den)
        return cls(A, B[:, 0], C[0], float(D[0, 0]))


def _flows(A: np.ndarray, taus: np.ndarray, x: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``exp(A tau) x`` and ``int_0^tau exp(A s) ds b`` for each tau: arrays (T, n).

    Spring-dashpot networks have real, simple poles, so the eigen-decomposition is
    exact and vectorises over tau (applied to the vectors, never forming a matrix per
    tau); a defective or ill-conditioned matrix (repeated arms) falls back to the
    augmented matrix exponential.
    """
    n = A.shape[0]
    lam, V = np.linalg.eig(A)
    if np.all(np.abs(lam.imag) < 1e-12 * (1 + np.abs(lam.real))) and np.linalg.cond(V) < 1e8:
        lam, V = lam.real, V.real
        Vinv = np.linalg.inv(V)
        lt = np.outer(taus, lam)
        small = np.abs(lt) < 1e-8
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = np.where(small, taus[:, None] * (1 + lt / 2), np.expm1(lt) / lam)
        return (np.exp(lt) * (Vinv @ x)) @ V.T, (phi * (Vinv @ b)) @ V.T
    aug = np.zeros((n * 2, n * 2))
    aug[:n, :n], aug[:n, n:] = A, np.eye(n)
    big = expm(aug[None] * taus[:, None, None])
    return big[:, :n, :n] @ x, big[:, :n, n:] @ b


def respond(element: Element, program: Program, t: np.ndarray) -> Response:
    """Stress and strain of ``element`` at times ``t`` (sorted) under ``program``.

    Before ``program.t0`` the element is unloaded. At a segment boundary the value
    is the one just after it (a strain-rate step makes the stress jump).

    Raises:
        ValueError: ``t`` not sorted, a stress-free segment for an element that
            cannot recover (a pure spring has no internal state to relax), or a
            strain-controlled segment after a one-sided one let go.
    """
    t = np.asarray(t, dtype=float)
    if np.any(np.diff(t) < 0):
        raise ValueError("times must be sorted")
    ss = StateSpace.of(element)
    n = ss.A.shape[0]
    stress, strain = np.zeros_like(t), np.zeros_like(t)
    x, eps = np.zeros(n), 0.0
    start, let_go = program.t0, False
    t_release = None
    for k, seg in enumerate(program.segments):
        end = start + seg.duration
        if seg.one_sided and seg.strain_rate is not None:
            tau = _first_zero_stress(ss, x, seg.strain_rate, seg.duration)
            let_go, end = tau < seg.duration, start + tau
        elif let_go and seg.strain_rate is not None:
            raise ValueError("a strain-controlled segment after the drive let go")
        if seg.strain_rate is None and t_release is None:
            t_release = start
        last = k == len(program.segments) - 1
        mask = (t >= start) & ((t < end) | (last & (t >= end)))
        taus = t[mask] - start
        tau_end = np.array([end - start]) if np.isfinite(end) else np.zeros(0)
        every = np.concatenate([taus, tau_end])
        if seg.strain_rate is not None:
            rate = seg.strain_rate
            free, driven = _flows(ss.A, every, x, ss.B)
            xs = free + driven * rate
            eps_s = eps + rate * every
            stress[mask] = xs[: taus.size] @ ss.C + ss.D * rate
        else:
            Af, gain, jump = _free_dynamics(ss, x)
            x0, eps0 = x + ss.B * jump, eps + jump
            xs, integral = _flows(Af, every, x0, x0)
            eps_s = eps0 + integral @ gain
            stress[mask] = 0.0
        strain[mask] = eps_s[: taus.size]
        if tau_end.size:
            x, eps = xs[-1], float(eps_s[-1])
        start = end
    return Response(t, stress, strain, t_release)


def _first_zero_stress(ss: StateSpace, x: np.ndarray, rate: float, duration: float) -> float:
    """Time into a segment driven at ``rate`` from state ``x`` at which the stress first
    reaches zero; ``duration`` if it stays positive throughout.

    The stress is bracketed on a grid, then the root is polished by Brent's method
    on the exact expression (a retracting drive lowers the stress monotonically for
    spring-dashpot networks; the grid guards against a shallow start)."""
    def stress(taus: np.ndarray) -> np.ndarray:
        free, driven = _flows(ss.A, taus, x, ss.B)
        return (free + driven * rate) @ ss.C + ss.D * rate

    grid = np.linspace(0.0, duration, 65)
    values = stress(grid)
    if values[0] <= 0.0:
        return 0.0
    below = np.flatnonzero(values <= 0.0)
    if below.size == 0:
        return duration
    i = below[0]
    return float(brentq(lambda tau: float(stress(np.array([tau]))[0]), grid[i - 1], grid[i],
                        xtol=1e-12 * duration, rtol=8.9e-16))


def _free_dynamics(ss: StateSpace, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Stress-free motion from state ``x``: ``(Af, gain, jump)`` with ``x' = Af x``,
    ``strain' = gain . x`` after an instantaneous strain ``jump``.

    With an instantaneous viscous path (``D != 0``) the strain rate adjusts at once
    to keep the stress at zero: ``rate = -C x / D``, no jump. Without one (a spring
    at the front, ``D = 0``) the strain jumps back elastically until ``C x = 0``,
    then the rate keeps ``d(stress)/dt = C A x + C B rate = 0``.
    """
    if ss.D != 0.0:
        gain = -ss.C / ss.D
        return ss.A + np.outer(ss.B, gain), gain, 0.0
    cb = float(ss.C @ ss.B)
    if cb == 0.0:
        raise ValueError("element cannot recover freely (no internal state)")
    gain = -(ss.C @ ss.A) / cb
    return ss.A + np.outer(ss.B, gain), gain, -float(ss.C @ x) / cb


# The nonlinear response feeds finite-difference Jacobians (steps ~1.5e-8 relative): its
# integration error must sit far below that, so its parameter dependence is smooth.
ODE_RTOL = 1e-12
ODE_METHOD = "LSODA"   # switches to BDF where the spring grows stiff (a fit's trial of a huge k)


def three_element_and_arms(element: Element) -> tuple[tuple[float, float, float], list[tuple[float, float]]]:
    """``(E, c1, c2)`` of the three-element base and ``(stiffness, viscosity)`` of each
    Maxwell arm in parallel with it, from ``element`` built as ``three_element(...)``
    with arms added by ``Parallel``.

    Raises:
        ValueError: any other network (the nonlinear Voigt spring has no general solver).
    """
    parts: list[Element] = []
    stack = [element]
    while stack:
        e = stack.pop()
        if isinstance(e, Parallel) and not any(isinstance(p, Spring) for p in e.parts):
            stack.extend(e.parts)
        else:
            parts.append(e)
    base, arms = None, []
    for e in parts:
        kinds = [type(p) for p in getattr(e, "parts", ())]
        if isinstance(e, Series) and kinds == [Spring, Dashpot]:
            arms.append((e.parts[0].stiffness, e.parts[1].viscosity))
        elif (isinstance(e, Series) and kinds == [Parallel, Dashpot]
              and [type(p) for p in e.parts[0].parts] == [Spring, Dashpot] and base is None):
            voigt_part, dashpot = e.parts
            base = (voigt_part.parts[0].stiffness, voigt_part.parts[1].viscosity, dashpot.viscosity)
        else:
            raise ValueError("a nonlinear Voigt spring needs the three-element base with Maxwell arms in parallel")
    if base is None:
        raise ValueError("a nonlinear Voigt spring needs the three-element base")
    return base, arms


def respond_voigt_spring(element: Element, spring: Callable[[np.ndarray], np.ndarray], height: float,
                         program: Program, t: np.ndarray) -> Response:
    """As :func:`respond`, with the base's Voigt spring nonlinear: its stress is
    ``E height spring(u_v / height)`` at Voigt displacement ``u_v`` (``spring(eps)``:
    stress per unit E at nominal strain, ``eps`` to first order). No closed form exists,
    so scipy's ``solve_ivp`` (DOP853, ``ODE_RTOL``) integrates the states (Voigt
    displacement, displacement, each arm's stress) segment by segment.

    Driven: ``sigma3 = (c1 c2 rate + c2 f) / (c1 + c2)``, ``u_v' = (sigma3 - f) / c1``;
    stress-free: the arms' stress balances the base's, ``sigma3 = -sum(arms)`` and
    ``u' = ((c1 + c2) sigma3 - c2 f) / (c1 c2)``; each arm ``s_i' = k_i u' - s_i k_i / c_i``.
    """
    t = np.asarray(t, dtype=float)
    if np.any(np.diff(t) < 0):
        raise ValueError("times must be sorted")
    (E, c1, c2), arms = three_element_and_arms(element)
    k = np.array([a[0] for a in arms])
    rate_k = np.array([a[0] / a[1] for a in arms])

    def voigt_force(uv: float) -> float:
        return E * height * float(spring(np.array([uv / height]))[0])

    def rhs(_t: float, y: np.ndarray, rate: float | None) -> np.ndarray:
        uv, arm = y[0], y[2:]
        f = voigt_force(uv)
        if rate is None:
            s3 = -float(arm.sum())
            du = ((c1 + c2) * s3 - c2 * f) / (c1 * c2)
        else:
            s3 = (c1 * c2 * rate + c2 * f) / (c1 + c2)
            du = rate
        return np.concatenate([[(s3 - f) / c1, du], k * du - rate_k * arm])

    def total_stress(y: np.ndarray, rate: float | None) -> np.ndarray:
        if rate is None:
            return np.zeros(y.shape[1])
        f = np.array([voigt_force(u) for u in y[0]])
        return (c1 * c2 * rate + c2 * f) / (c1 + c2) + y[2:].sum(axis=0)

    stress, strain = np.zeros_like(t), np.zeros_like(t)
    y = np.zeros(2 + len(arms))
    typical = np.concatenate([[1e-2 * height] * 2, 1e-2 * height * k])   # a 1 % strain, its arm stresses
    start, let_go, t_release = program.t0, False, None
    for i, seg in enumerate(program.segments):
        rate = seg.strain_rate
        if let_go and rate is not None:
            raise ValueError("a strain-controlled segment after the drive let go")
        if rate is None and t_release is None:
            t_release = start
        last = i == len(program.segments) - 1
        end = start + seg.duration
        inside = (t >= start) & ((t < end) | (last & (t >= end)))
        stop = max(end if np.isfinite(end) else (t[inside].max() if inside.any() else start), start)
        events = None
        if seg.one_sided and rate is not None:
            if total_stress(y[:, None], rate)[0] <= 0.0:
                stop, let_go = start, True
            else:
                def unloaded(_t: float, yy: np.ndarray, r: float | None) -> float:
                    return float(total_stress(yy[:, None], r)[0])
                unloaded.terminal, unloaded.direction = True, -1   # type: ignore[attr-defined]
                events = unloaded
        if stop > start:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")   # LSODA's own complaints: a failure is reported below
                sol = solve_ivp(rhs, (start, stop), y, method=ODE_METHOD, rtol=ODE_RTOL, atol=ODE_RTOL * typical,
                                args=(rate,), dense_output=True, events=events)
            if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
                # A law the solver cannot follow (a fit's trial of an absurd coefficient):
                # no response, which the fit reads as the worst of fits.
                stress[t >= start] = np.nan
                strain[t >= start] = np.nan
                return Response(t, stress, strain, t_release)
            if events is not None and sol.t_events[0].size:
                stop, let_go = float(sol.t_events[0][0]), True
                inside &= t < stop
            ys = sol.sol(t[inside]) if inside.any() else np.zeros((y.size, 0))
            y = sol.y[:, -1]
        else:
            inside &= False
            ys = np.zeros((y.size, 0))
        stress[inside] = total_stress(ys, rate) if ys.shape[1] else stress[inside]
        strain[inside] = ys[1]
        start = stop if let_go and rate is not None else end
    return Response(t, stress, strain, t_release)
