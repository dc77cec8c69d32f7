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
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy.integrate import ODEintWarning, odeint, solve_ivp
from scipy.linalg import expm
from scipy.optimize import brentq

from rheo_ros.experiment import StageProfile
from rheo_ros.models.elements import Dashpot, Element, Parallel, Series, Spring


@dataclass(frozen=True)
class Segment:
    """``duration`` in s (``inf`` for an open end); ``strain_rate`` in 1/s, or
    ``None`` for a stress-free segment (the specimen recovers freely).
    ``one_sided``: the drive only pushes; the segment ends early where the stress
    reaches zero, and the next segment starts there (the drive has let go; the segments
    keep their planned ends). ``drive_from``: where the drive is at the segment's start
    (strain): after the drive let go, a driven segment meets a specimen that may still be
    recovering only where the drive reaches its strain (the contact of a later push); it
    is free until then, or all along if the drive never gets there."""

    duration: float
    strain_rate: float | None
    one_sided: bool = False
    drive_from: float | None = None


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
    response; the specimen follows a retracting stage while it presses on it. Earlier
    pushes (``profile.before``) come first: each later push meets the specimen where
    the stage reaches it (a permanent set, a recovery under way), not at depth 0."""
    pushes = profile.pushes
    first = pushes[0]
    if len(pushes) == 1:
        return Program.push_hold_release(first.depth, first.pull_time, first.keep_time, first.t_pull_start,
                                         first.retract_speed)
    segments: list[Segment] = []
    for k, push in enumerate(pushes):
        driven = list(Program.push_hold_release(push.depth, push.pull_time, push.keep_time,
                                                retract_speed=push.retract_speed).segments[:-1])
        if k:   # the drive starts at depth 0 and meets the specimen where it reaches it
            driven = [replace(seg, drive_from=at) for seg, at in zip(driven, (0.0, push.depth, push.depth))]
        until = pushes[k + 1].t_pull_start if k + 1 < len(pushes) else np.inf
        segments += driven + [Segment(until - push.t_pull_start - sum(seg.duration for seg in driven), None)]
    return Program(first.t_pull_start, tuple(segments))


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
        """The realisation of ``element``'s modulus (``tf2ss``), kept for the next calls
        with an equal element: a fit's Jacobian asks it again for every column that moves
        no element parameter (the Poisson ratio, the clock offsets, an effect's), and
        building the modulus and its realisation costs ~0.1 ms, half a one-state response."""
        return _realised(element)


@lru_cache(maxsize=64)
def _realised(element: Element) -> StateSpace:
    """``StateSpace.of`` (read-only arrays, shared by every caller)."""
    q = element.modulus()
    num, den = q.num, np.append(q.den, 0.0)   # times s
    while num.size > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    if num.size > den.size:
        raise ValueError("modulus grows faster than a dashpot: not a spring-dashpot network")
    if den.size > 1 and den[0] == 1.0 and abs(num[0]) > 1e-14:
        # scipy.signal.tf2ss's controller canonical form, term for term, for the monic,
        # trimmed polynomials a modulus has (tf2ss's normalisation leaves them as they are):
        # its checks cost as much as the rest of a new model's response, which a fit's
        # Jacobian asks for every column that moves an element (``test_models``).
        k = den.size
        num = np.concatenate([np.zeros(k - num.size), num])
        A = np.vstack([-den[1:], np.eye(k - 2, k - 1)])
        out = StateSpace(A, np.eye(k - 1, 1)[:, 0], num[1:] - np.outer(num[:1], den[1:])[0], float(num[0]))
    else:
        # scipy.signal costs ~1 s to import (its array-API wrappers): only where a model is
        # solved, not in every process that imports the package (the stage, the recorder).
        from scipy.signal import tf2ss

        A, B, C, D = tf2ss(num, den)
        out = StateSpace(A, B[:, 0], C[0], float(D[0, 0]))
    for a in (out.A, out.B, out.C):
        a.setflags(write=False)
    return out


def _flows(A: np.ndarray, taus: np.ndarray, x: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``exp(A tau) x`` and ``int_0^tau exp(A s) ds b`` for each tau: arrays (T, n).

    Spring-dashpot networks have real, simple poles, so the eigen-decomposition is
    exact and vectorises over tau (applied to the vectors, never forming a matrix per
    tau); a defective or ill-conditioned matrix (repeated arms) falls back to the
    augmented matrix exponential.
    """
    n = A.shape[0]
    if n == 1:
        # One state (the three-element model): its own mode, without the eigen-decomposition,
        # its cache and the products with its eigenvector (1: what LAPACK's eig gives it),
        # the same numbers at half the cost of a response.
        lam = float(A[0, 0])
        lt = taus * lam
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = np.where(np.abs(lt) < 1e-8, taus * (1 + lt / 2), np.expm1(lt) / lam)
        return (np.exp(lt) * x[0])[:, None], (phi * b[0])[:, None]
    modes = _modes(A.tobytes(), A.shape, A.dtype.str)
    if modes is not None:
        lam, V, Vinv = modes
        lt = np.outer(taus, lam)
        small = np.abs(lt) < 1e-8
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = np.where(small, taus[:, None] * (1 + lt / 2), np.expm1(lt) / lam)
        return (np.exp(lt) * (Vinv @ x)) @ V.T, (phi * (Vinv @ b)) @ V.T
    aug = np.zeros((n * 2, n * 2))
    aug[:n, :n], aug[:n, n:] = A, np.eye(n)
    # A fit's trial arms may be wild enough to overflow here: the non-finite response is
    # the fit's to handle (a large residual), not a warning for the user.
    with np.errstate(over="ignore", invalid="ignore"):
        big = expm(aug[None] * taus[:, None, None])
        return big[:, :n, :n] @ x, big[:, :n, n:] @ b


@lru_cache(maxsize=256)
def _modes(data: bytes, shape: tuple[int, ...], dtype: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The real eigen-decomposition of the matrix ``data`` (its bytes, ``shape``, ``dtype``) for
    ``_flows``: eigenvalues, eigenvectors and their inverse, or None where it is complex
    or ill-conditioned. Cached: a response flows through every segment of a program with
    the same matrix (five times a release), and a fit's residual calls many responses of
    one model. Read-only arrays, shared by every caller."""
    A = np.frombuffer(data, dtype=dtype).reshape(shape)
    lam, V = np.linalg.eig(A)
    if not (np.all(np.abs(lam.imag) < 1e-12 * (1 + np.abs(lam.real))) and np.linalg.cond(V) < 1e8):
        return None
    lam, V = lam.real, V.real
    out = (lam, V, np.linalg.inv(V))
    for a in out:
        a.setflags(write=False)
    return out


def respond(element: Element, program: Program, t: np.ndarray) -> Response:
    """Stress and strain of ``element`` at times ``t`` (sorted) under ``program``.

    Before ``program.t0`` the element is unloaded. At a segment boundary the value
    is the one just after it (a strain-rate step makes the stress jump). After the
    drive let go, a driven segment with ``drive_from`` finds the contact where the
    drive reaches the freely recovering specimen (a root of the exact gap), then drives.
    ``t_release`` is when the drive last let go.

    Raises:
        ValueError: ``t`` not sorted, a stress-free segment for an element that
            cannot recover (a pure spring has no internal state to relax), or a
            strain-controlled segment without ``drive_from`` after the drive let go.
    """
    t = np.asarray(t, dtype=float)
    if np.any(np.diff(t) < 0):
        raise ValueError("times must be sorted")
    ss = StateSpace.of(element)
    stress, strain = np.zeros_like(t), np.zeros_like(t)
    x, eps = np.zeros(ss.A.shape[0]), 0.0
    start = planned = program.t0
    let_go, t_release = False, None
    for k, seg in enumerate(program.segments):
        last = k == len(program.segments) - 1
        planned_start, planned = planned, planned + seg.duration
        end, rate = planned, seg.strain_rate
        if rate is not None and let_go:
            if seg.drive_from is None:
                raise ValueError("a strain-controlled segment after the drive let go")
            drive = seg.drive_from + rate * (start - planned_start)
            touch = _contact(ss, x, eps, drive, rate, end - start)
            if touch > 0.0:   # free until the drive reaches the specimen
                x, eps = _piece(ss, x, eps, None, start, min(start + touch, end), last and touch >= end - start,
                                t, stress, strain)
            if touch >= end - start:
                start = end
                continue
            start, let_go = start + touch, False
            eps = seg.drive_from + rate * (start - planned_start)
        if seg.one_sided and rate is not None:
            tau = _first_zero_stress(ss, x, rate, end - start)
            if tau < end - start:
                let_go, end = True, start + tau
                t_release = end
        if rate is None and not let_go:
            let_go, t_release = True, start
        x, eps = _piece(ss, x, eps, rate, start, end, last, t, stress, strain)
        start = end
    return Response(t, stress, strain, t_release)


def _piece(ss: StateSpace, x: np.ndarray, eps: float, rate: float | None, start: float, end: float, last: bool,
           t: np.ndarray, stress: np.ndarray, strain: np.ndarray) -> tuple[np.ndarray, float]:
    """Fill ``stress`` and ``strain`` at the times of ``t`` in [start, end) (and after
    ``end`` when ``last``) driven at ``rate`` from state ``(x, eps)``, or free (``rate``
    None); return the state at ``end`` (the same state for an open end)."""
    # ``t`` is sorted: the piece's times are one run of it.
    mask = slice(np.searchsorted(t, start), t.size if last else np.searchsorted(t, end))
    taus = t[mask] - start
    tau_end = np.array([end - start]) if np.isfinite(end) else np.zeros(0)
    every = np.concatenate([taus, tau_end])
    if rate is not None:
        free, driven = _flows(ss.A, every, x, ss.B)
        xs = free + driven * rate
        eps_s = eps + rate * every
        stress[mask] = xs[: taus.size] @ ss.C + ss.D * rate
    else:
        xs, eps_s = _free_flow(ss, x, eps, every)
        stress[mask] = 0.0
    strain[mask] = eps_s[: taus.size]
    return (xs[-1], float(eps_s[-1])) if tau_end.size else (x, eps)


def _free_flow(ss: StateSpace, x: np.ndarray, eps: float, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States (T, n) and strains (T,) of the specimen recovering freely from ``(x, eps)``."""
    Af, gain, jump = _free_dynamics(ss, x)
    x0, eps0 = x + ss.B * jump, eps + jump
    xs, integral = _flows(Af, taus, x0, x0)
    return xs, eps0 + integral @ gain


def _contact(ss: StateSpace, x: np.ndarray, eps: float, drive: float, rate: float, duration: float) -> float:
    """Time into a segment at which a drive at ``drive`` moving at ``rate`` meets a
    specimen recovering freely from ``(x, eps)`` (the drive at or past its strain);
    ``inf`` if it does not within ``duration`` (a recovery slows down; a drive that moves
    on meets it once)."""
    def short(taus: np.ndarray) -> np.ndarray:   # how far the drive still is from the top
        return _free_flow(ss, x, eps, taus)[1] - drive - rate * taus

    touch = _first_crossing(short, duration, 257)
    return np.inf if touch is None else touch


def _first_crossing(f: Callable[[np.ndarray], np.ndarray], duration: float, points: int) -> float | None:
    """The first time in [0, duration] at which ``f`` (exact, vectorised over times) is at
    or below zero; None if it stays above. Bracketed on a grid of ``points``, polished by
    Brent's method on ``f`` itself."""
    grid = np.linspace(0.0, duration, points)
    values = f(grid)
    if values[0] <= 0.0:
        return 0.0
    below = np.flatnonzero(values <= 0.0)
    if below.size == 0:
        return None
    i = below[0]
    return float(brentq(lambda tau: float(f(np.array([tau]))[0]), grid[i - 1], grid[i],
                        xtol=1e-12 * duration, rtol=8.9e-16))


def _first_zero_stress(ss: StateSpace, x: np.ndarray, rate: float, duration: float) -> float:
    """Time into a segment driven at ``rate`` from state ``x`` at which the stress first
    reaches zero; ``duration`` if it stays positive throughout.

    The stress is bracketed on a grid, then the root is polished by Brent's method
    on the exact expression (a retracting drive lowers the stress monotonically for
    spring-dashpot networks; the grid guards against a shallow start)."""
    def stress(taus: np.ndarray) -> np.ndarray:
        free, driven = _flows(ss.A, taus, x, ss.B)
        return (free + driven * rate) @ ss.C + ss.D * rate

    zero = _first_crossing(stress, duration, 65)
    return duration if zero is None else zero


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
# Evaluations of the law a segment may ask: a fit's wild trial can ask for millions at
# ODE_RTOL (seen with solve_ivp, which keeps each step's interpolant: 22 GB before the
# machine ran out); the trial is then a failure (NaN stress: a large residual) like a
# diverging one. LSODA takes about two a step: some 100 000 steps.
ODE_MAX_EVALUATIONS = 200_000


class _OutOfBudget(Exception):
    """A segment's integration asked its law more than ``ODE_MAX_EVALUATIONS`` times."""


def _budgeted(rhs: Callable) -> Callable:
    """``rhs`` that raises ``_OutOfBudget`` at its ``ODE_MAX_EVALUATIONS``-th call: one cap
    on steps, time and memory for either solver (neither has its own on the whole call)."""
    calls = 0

    def counted(t: float, y: np.ndarray, rate: float | None) -> list[float]:
        nonlocal calls
        calls += 1
        if calls > ODE_MAX_EVALUATIONS:
            raise _OutOfBudget
        return rhs(t, y, rate)
    return counted


def _lsoda_at(rhs: Callable, y0: np.ndarray, start: float, stop: float, at: np.ndarray, rate: float | None,
              atol: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The states at the sorted times ``at`` (within [start, stop]) and at ``stop``, from
    ``y0`` at ``start``, by LSODA through ``odeint``: its Fortran loop steps and
    interpolates to each time without a Python call per step (``solve_ivp`` keeps every
    step's interpolant: 60 % of a stiffening's solve). None where it fails or runs out of
    its budget (a fit's wild trial)."""
    # LSODA refuses to start towards a time within rounding of the start ("illegal input":
    # a sample on the segment's first instant): there the state is the start's.
    rounding = 100.0 * np.finfo(float).eps * max(abs(start), abs(stop), 1.0)
    near = at - start <= rounding
    if stop - start <= rounding:
        return np.repeat(np.asarray(y0, dtype=float)[:, None], at.size, axis=1), np.asarray(y0, dtype=float)
    times = np.concatenate([[start], at[~near], [stop]])
    with warnings.catch_warnings(record=True) as said:
        # LSODA's failures are warnings of its own; the law's (a trial's overflow) are not
        # the user's, as on solve_ivp's path, and a non-finite state says the rest.
        warnings.simplefilter("ignore")
        warnings.simplefilter("always", ODEintWarning)
        try:   # no cap per output interval (a gap in the samples may need many steps): the budget's
            ys = odeint(_budgeted(rhs), y0, times, args=(rate,), tfirst=True, rtol=ODE_RTOL, atol=atol,
                        mxstep=ODE_MAX_EVALUATIONS, tcrit=[stop])
        except _OutOfBudget:
            return None
    if said or not np.all(np.isfinite(ys[-1])):
        return None
    states = np.empty((ys.shape[1], at.size))
    states[:, near], states[:, ~near] = ys[:1].T, ys[1:-1].T
    return states, ys[-1]


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
    so LSODA (``ODE_RTOL``) integrates the states (Voigt displacement, displacement, each
    arm's stress) segment by segment: ``odeint`` at the samples, ``solve_ivp`` where an
    event ends the segment (the stage reached, the stress gone).

    Driven: ``sigma3 = (c1 c2 rate + c2 f) / (c1 + c2)``, ``u_v' = (sigma3 - f) / c1``;
    stress-free: the arms' stress balances the base's, ``sigma3 = -sum(arms)`` and
    ``u' = ((c1 + c2) sigma3 - c2 f) / (c1 c2)``; each arm ``s_i' = k_i u' - s_i k_i / c_i``.
    """
    t = np.asarray(t, dtype=float)
    if np.any(np.diff(t) < 0):
        raise ValueError("times must be sorted")
    (E, c1, c2), arms = three_element_and_arms(element)

    # LSODA calls this a million times in a stiffening's fit: Python floats and lists
    # (odeint takes any sequence), no array built per call but the spring's own.
    c1_, c2_, eh = float(c1), float(c2), float(E * height)
    arm_k = [(float(a), float(a / b)) for a, b in arms]

    def rhs(_t: float, y: np.ndarray, rate: float | None) -> list[float]:
        f = eh * float(spring(y[:1] / height)[0])
        if rate is None:
            s3 = -sum(y[2:].tolist()) if arm_k else 0.0
            du = ((c1_ + c2_) * s3 - c2_ * f) / (c1_ * c2_)
        else:
            s3 = (c1_ * c2_ * rate + c2_ * f) / (c1_ + c2_)
            du = rate
        out = [(s3 - f) / c1_, du]
        if arm_k:
            out += [ki * du - ri * si for (ki, ri), si in zip(arm_k, y[2:].tolist())]
        return out

    def total_stress(y: np.ndarray, rate: float | None) -> np.ndarray:
        if rate is None:
            return np.zeros(y.shape[1])
        f = E * height * spring(y[0] / height)
        return (c1 * c2 * rate + c2 * f) / (c1 + c2) + y[2:].sum(axis=0)

    stress, strain = np.zeros_like(t), np.zeros_like(t)
    y = np.zeros(2 + len(arms))
    typical = 1e-2 * height * np.array([1.0, 1.0] + [ki for ki, _ in arm_k])   # a 1 % strain, its arm stresses
    start = planned = program.t0
    let_go, t_release = False, None

    def integrate(rate: float | None, span: tuple[float, float], y0: np.ndarray, events=None):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # LSODA's own complaints: a failure is reported below
            try:
                sol = solve_ivp(_budgeted(rhs), span, y0, method="LSODA", rtol=ODE_RTOL, atol=ODE_RTOL * typical,
                                args=(rate,), dense_output=True, events=events)
            except ValueError:   # steps of zero length (a stiff trial): no dense output, a failed trial
                return None
            except _OutOfBudget:
                return None
        if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
            return None   # failed, or out of steps: a trial the fit rejects, never the machine's memory
        return sol

    for i, seg in enumerate(program.segments):
        rate = seg.strain_rate
        last = i == len(program.segments) - 1
        planned_start, planned = planned, planned + seg.duration
        end = planned
        if let_go and rate is not None:
            if seg.drive_from is None:
                raise ValueError("a strain-controlled segment after the drive let go")
            drive_from = seg.drive_from

            def reached(tt: float, yy: np.ndarray, _r: float | None) -> float:
                return drive_from + rate * (tt - planned_start) - yy[1]
            reached.terminal, reached.direction = True, 1   # type: ignore[attr-defined]
            if reached(start, y, None) < 0.0:   # free until the drive reaches the specimen
                sol = integrate(None, (start, end), y, reached) if end > start else None
                if sol is None:
                    stress[t >= start], strain[t >= start] = np.nan, np.nan
                    return Response(t, stress, strain, t_release)
                touch = float(sol.t_events[0][0]) if sol.t_events[0].size else end
                free = (t >= start) & ((t < touch) | (last & (t >= touch) & (touch >= end)))
                stress[free], strain[free] = 0.0, sol.sol(t[free])[1] if free.any() else strain[free]
                y = sol.sol(touch) if touch < end else sol.y[:, -1]
                start = touch
                if touch >= end:
                    continue
            let_go = False
            y = y.copy()
            y[1] = drive_from + rate * (start - planned_start)
        if rate is None and not let_go:
            let_go, t_release = True, start
        inside = (t >= start) & ((t < end) | (last & (t >= end)))
        stop = max(end if np.isfinite(end) else (t[inside].max() if inside.any() else start), start)
        events = None
        if seg.one_sided and rate is not None:
            if total_stress(y[:, None], rate)[0] <= 0.0:
                stop, let_go, t_release = start, True, start
            else:
                def unloaded(_t: float, yy: np.ndarray, r: float | None) -> float:
                    return float(total_stress(yy[:, None], r)[0])
                unloaded.terminal, unloaded.direction = True, -1   # type: ignore[attr-defined]
                events = unloaded
        if stop > start:
            if events is None:   # no event to find: LSODA at the samples themselves
                at_samples = _lsoda_at(rhs, y, start, stop, t[inside], rate, ODE_RTOL * typical)
                failed = at_samples is None
            else:
                sol = integrate(rate, (start, stop), y, events)
                failed = sol is None
            if failed:
                # A law the solver cannot follow (a fit's trial of an absurd coefficient):
                # no response, which the fit reads as the worst of fits.
                stress[t >= start] = np.nan
                strain[t >= start] = np.nan
                return Response(t, stress, strain, t_release)
            if events is None:
                ys, y = at_samples
            else:
                if sol.t_events[0].size:
                    stop, let_go = float(sol.t_events[0][0]), True
                    t_release = stop
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
