"""The paper's identification (Sections III and IV.B).

1. Force curve fits: eq. 6 in the pull phase and eq. 7 in the keep phase, one
   relaxation rate ``r = E/(c1+c2)`` shared by both phases and every bottom node.
2. Long-time case (the force has relaxed, ``u_keep = u_final``): eq. 6 asymptote and
   eq. 10 force jump. Short-time case: eq. 6 with eq. 14 and eq. 17, from the final
   displacements only.
3. 2D: ``c2 J`` becomes ``c2 (lambda^g J_lambda + mu^g J_mu) = c2 K_gamma``; the
   equations of all bottom nodes are solved together by least squares for c2,
   ``c1 c2/(c1+c2)`` and the Poisson ratio (Section IV.B).
4. The uniaxial block (Sections II-III): every node's force is the uniform stress
   times its share of the face whatever the Poisson ratio, so the forces cannot
   give it; the markers can: the block deforms by a uniform strain field, whose
   lateral over axial strain is ``-gamma`` (``lateral_strain_ratio``). With gamma
   fixed, the least squares of 3. give c2 and ``c1 c2/(c1+c2)``, on the uniform
   field fitted to the markers (``uniform_strain_field``: every marker informs it).

Every bottom segment is used by default. The paper drops P1 and P5 because their
sensor segments cover half an element; here each segment sums to its node's
force (the tactile layout puts each nodal force on its own segment), so the edge
nodes carry the most Poisson information (their reaction depends most on gamma)
and drop nothing but noise. ``nodes=(1, 2, 3)`` gives the paper's P2-P4.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from scipy.optimize import least_squares
from scipy.special import expit, logit

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import GAMMA_RANGE, Mesh, lame_per_unit_modulus, lame_slope_per_unit_modulus
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.estimate import Estimate
from rheo_ros.identification.noise import force_noise
from rheo_ros.models.elements import three_element
from rheo_ros.models.response import respond, stage_program
from rheo_ros.record import Record, RecordError

Method = Literal["auto", "long_time", "short_time"]


@dataclass(frozen=True)
class ForceCurves:
    """Eq. 6 and 7 fitted to each node's force (N). ``rate`` = E/(c1+c2) in 1/s."""

    rate: float
    pull_asymptote: np.ndarray    # eq. 6: c2 J u_keep / t_P
    pull_end: np.ndarray          # F_P(t_P)
    keep_start: np.ndarray        # F_K(t_P)
    keep_end: np.ndarray          # F_K(t_P + t_K)
    residual_rms: float
    rate_rel_std: float = np.nan  # relative standard deviation of ``rate`` (Gauss-Newton)


@dataclass(frozen=True)
class PullCurve:
    """Eq. 6 fitted to each node's pull force alone (N): ``F = A + (F0 - A) exp(-r t)``."""

    rate: float
    rate_rel_std: float
    asymptote: np.ndarray         # A = c2 J u_keep / t_P
    start: np.ndarray             # F0 = F_P(0+) = c1c2/(c1+c2) J u_keep / t_P
    end: np.ndarray               # F_P(t_P)
    residual_rms: float


def _rate_search(residuals, rate0: float, n_linear: int) -> tuple[float, float]:
    """Variable projection over log(rate): the rate and its relative std.

    For the reduced problem (amplitudes projected out) the Gauss-Newton variance of
    log(rate) is ``s^2 / (J^T J)`` with ``s^2`` the residual variance after all the
    fitted parameters; it says how well the data pin the relaxation rate down.
    """
    # MINPACK (lm): one unbounded variable, its loop in compiled code. A relative step of
    # 1e-10 in log(rate) is far below any rate's std; tighter only spends iterations on rounding.
    # A trial step far out (data that hardly curve) overflows exp or flattens the decay
    # to a constant (0 / 0 in the line fit): the solver steps back, and the caller judges
    # the rate's std; no warning on stderr.
    # Searched as log(rate / rate0) from 0: MINPACK bounds its first step by 100 x the
    # start's norm (by 100 at exactly 0), and log(rate) from a start near 1 /s (a 1 s pull)
    # began it at ~1e-12, doubling: 47 evaluations where 10 do.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        fit = least_squares(lambda x: residuals(rate0 * np.exp(x[0])), [0.0], method="lm", xtol=1e-10,
                            ftol=1e-12, gtol=1e-12)
    dof = max(fit.fun.size - n_linear - 1, 1)
    s2 = float(fit.fun @ fit.fun) / dof
    jtj = float(fit.jac[:, 0] @ fit.jac[:, 0])
    rel_std = float(np.sqrt(s2 / jtj)) if jtj > 0 else np.inf
    return float(rate0 * np.exp(fit.x[0])), rel_std


def _line_fit(x: np.ndarray, y: np.ndarray, y_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``y ~ a + b x`` per column of ``y`` (``y_mean`` its column means): ((2, columns)
    intercepts and slopes, residuals). About the means, as stable as a QR; a rate search
    calls it hundreds of times, where a LAPACK least squares each was its cost."""
    dx = x - x.mean()
    b = (dx @ (y - y_mean)) / (dx @ dx)
    a = y_mean - b * x.mean()
    return np.vstack([a, b]), a + np.outer(x, b) - y


def _decay_fit(rate: float, t: np.ndarray, y: np.ndarray, y_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``y ~ A + B exp(-rate t)`` per column of ``y``: ((2, columns) A and B, residuals).
    Fitted as a line in ``1 - exp(-rate t)`` (expm1): at a rate too slow for the data,
    ``exp(-rate t)`` is 1 to within rounding and a line in it cancels to rounding noise,
    which the rate search's finite differences read as a well-determined rate."""
    (a, b), res = _line_fit(-np.expm1(-rate * t), y, y_mean)
    return np.vstack([a + b, -b]), res


def fit_force_curves(
    t: np.ndarray, force: np.ndarray, profile: StageProfile, guard: float = 0.1, source: str = "<memory>"
) -> ForceCurves:
    """Fit eq. 6 (pull) and eq. 7 (keep) with one shared rate by variable projection.

    For a given rate both equations are linear in their amplitudes, so only the rate
    is searched (scipy ``least_squares``). ``guard`` (s) leaves out samples that
    close to a phase boundary, where the stage's stabilised constraint is settling.
    """
    t_ps, t_pe, t_ke = profile.t_pull_start, profile.t_pull_end, profile.t_keep_end
    pull = (t > t_ps + guard) & (t < t_pe - guard)
    keep = (t > t_pe + guard) & (t < t_ke - guard)
    for name, mask in (("pull", pull), ("keep", keep)):
        if mask.sum() < 4:
            raise RecordError(f"{source}: force: {mask.sum()} samples in the {name} phase, need 4 to fit")
    tp, tk = t[pull] - t_ps, t[keep] - t_pe
    Fp, Fk = force[pull], force[keep]
    Fp_mean = Fp.mean(axis=0)

    def amplitudes(rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ek = np.exp(-rate * tk)
        ab, res_p = _decay_fit(rate, tp, Fp, Fp_mean)
        k = (ek @ Fk) / (ek @ ek)                                  # (nodes,)
        return ab, k, np.concatenate([res_p.ravel(), (np.outer(ek, k) - Fk).ravel()])

    total = np.abs(Fk).sum(axis=1)
    head, tail = total[: max(1, total.size // 10)].mean(), total[-max(1, total.size // 10):].mean()
    span = tk[-1] - tk[0]
    rate0 = np.log(head / tail) / (0.9 * span) if head > tail > 0 else 1.0 / span
    rate, rate_rel_std = _rate_search(lambda r: amplitudes(r)[2], rate0, 3 * force.shape[1])
    (asym, amp), k, res = amplitudes(rate)
    pull_time, keep_time = t_pe - t_ps, t_ke - t_pe
    return ForceCurves(
        rate=rate,
        pull_asymptote=asym,
        pull_end=asym + amp * np.exp(-rate * pull_time),
        keep_start=k,
        keep_end=k * np.exp(-rate * keep_time),
        residual_rms=float(np.sqrt(np.mean(res**2))),
        rate_rel_std=rate_rel_std,
    )


def fit_pull_curve(
    t: np.ndarray, force: np.ndarray, profile: StageProfile, guard: float = 0.1, source: str = "<memory>"
) -> PullCurve:
    """Fit eq. 6 to the pull phase alone (one rate shared by every node).

    What the pull alone tells: the force's jump at the start (``c1c2/(c1+c2)``) and
    its asymptote (``c2``) and rate, the last two only as far as the force curves
    within the pull (``rate * t_P`` well above a few hundredths).
    """
    t_ps, t_pe = profile.t_pull_start, profile.t_pull_end
    pull = (t > t_ps + guard) & (t < t_pe - guard)
    if pull.sum() < 4:
        raise RecordError(f"{source}: force: {pull.sum()} samples in the pull phase, need 4 to fit")
    tp, Fp = t[pull] - t_ps, force[pull]
    Fp_mean = Fp.mean(axis=0)

    def amplitudes(rate: float) -> tuple[np.ndarray, np.ndarray]:
        ab, res = _decay_fit(rate, tp, Fp, Fp_mean)
        return ab, res.ravel()

    rate, rel_std = _rate_search(lambda r: amplitudes(r)[1], 1.0 / (t_pe - t_ps), 2 * force.shape[1])
    (asym, amp), res = amplitudes(rate)
    return PullCurve(rate, rel_std, asym, asym + amp, asym + amp * np.exp(-rate * (t_pe - t_ps)),
                     float(np.sqrt(np.mean(res**2))))


def displacement_during(record: Record, t_from: float, t_to: float) -> np.ndarray:
    """Marker displacements (N, 2) averaged over the frames in [t_from, t_to]; the
    bottom row held (zero), as the model has it."""
    frames = (record.marker_t >= t_from) & (record.marker_t <= t_to)
    if not frames.any():
        raise RecordError(f"{record.source}: markers: no frame between {t_from:.3f} s and {t_to:.3f} s")
    return held_by_the_sensor(record.mesh, record.marker_displacement[frames].mean(axis=0))


def displacement_at_depth(record: Record, depth: float) -> np.ndarray:
    """Marker displacements (N, 2) at stage ``depth`` (m), from the pull's frames.

    While the stage pushes, every marker moves in proportion to the depth (the body
    keeps one shape: the Lame parts share one operator, eq. 19-21), so a line through
    the origin fitted per coordinate against the stage depth gives the shape with
    the noise of every frame averaged out.
    """
    profile = record.profile()
    frames = (record.marker_t > profile.t_pull_start) & (record.marker_t <= profile.t_pull_end)
    if frames.sum() < 2:
        raise RecordError(f"{record.source}: markers: {frames.sum()} frames in the pull phase, need 2")
    d = np.interp(record.marker_t[frames], record.stage_t, record.stage_depth)
    u = record.marker_displacement[frames]
    shape = np.tensordot(d, u, axes=(0, 0)) / (d @ d)
    return held_by_the_sensor(record.mesh, shape) * depth


def settled_displacement(record: Record, since: float) -> np.ndarray:
    """Marker displacements (N, 2) averaged over the frames from ``since`` (s) to the end.

    The bottom row is held by the sensor: ``held_by_the_sensor``.
    """
    last = record.marker_t >= min(since, record.marker_t[-1])
    return held_by_the_sensor(record.mesh, record.marker_displacement[last].mean(axis=0))


def recovered_displacement(record: Record, t_free: float, voigt_time: float) -> np.ndarray:
    """Marker displacements (N, 2) the release tends to, from a recovery not yet over.

    Free of stress, the three-element model's strain recovers as ``u_inf + a e^(-t / tau)``
    with ``tau = c1 / E`` (the Voigt element; the dashpot's share stays): each coordinate's
    frames from ``t_free`` (s, the specimen off the stage) on are fitted so, at the given
    ``tau``, and ``u_inf`` returned (the bottom row held: ``held_by_the_sensor``). Averaging
    the last frames instead takes a recovery still under way for its end.

    Raises:
        RecordError: fewer than 3 frames after ``t_free``.
    """
    frames = record.marker_t >= t_free
    if frames.sum() < 3:
        raise RecordError(f"{record.source}: markers: {frames.sum()} frames after the release at {t_free:.3f} s, "
                          "need 3 to follow the recovery")
    t = record.marker_t[frames] - t_free
    design = np.column_stack([np.ones_like(t), np.exp(-t / voigt_time)])
    u = record.marker_displacement[frames]
    coef = np.linalg.lstsq(design, u.reshape(t.size, -1), rcond=None)[0]
    return held_by_the_sensor(record.mesh, coef[0].reshape(u.shape[1:]))


def held_by_the_sensor(mesh: Mesh, u: np.ndarray) -> np.ndarray:
    """Marker displacements (N, 2) with what the sensor holds set to zero, as the model
    has it (not the noise those markers show): the bottom row's y, and its x where the
    bottom is bonded (a frictionless bottom slides sideways with the block)."""
    u = u.copy()
    u[mesh.bottom, 1] = 0.0
    if mesh.boundary.bottom == "bonded":
        u[mesh.bottom, 0] = 0.0
    return u


def _displacement_gradient(points: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares affine field ``u(p) = t + G (p - mean p)`` through displacements
    ``u`` (N, 2) at ``points`` (N, 2): the translation ``t`` (2,) and the gradient ``G``
    (2, 2), ``G[i, j] = d u_i / d x_j``."""
    centred = points - points.mean(axis=0)
    X = np.column_stack([np.ones(len(points)), centred])
    coef, *_ = np.linalg.lstsq(X, u, rcond=None)     # (3, 2): rows 1, x, y; columns u_x, u_y
    return coef[0], coef[1:].T


def uniform_strain_field(points: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The displacements (N, 2) at ``points`` of the uniform strain field (plus rigid
    motion) nearest to ``u`` (N, 2) in least squares: the homogeneous block's shape
    with the markers' noise averaged over all of them."""
    translation, gradient = _displacement_gradient(points, u)
    return translation + (points - points.mean(axis=0)) @ gradient.T


def lateral_strain_ratio(points: np.ndarray, u: np.ndarray) -> float:
    """``-e_xx / e_yy`` of the uniform strain field fitted to displacements ``u`` (N, 2)
    at ``points`` (N, 2): the Poisson ratio of a block in uniaxial stress along y."""
    _, gradient = _displacement_gradient(points, u)
    axial = gradient[1, 1]
    return float(-gradient[0, 0] / axial) if axial != 0 else float("nan")


# The first pass of the final displacements: the last frames' average (s).
MIN_FINAL_WINDOW = 2.0  # s
# Passes of the recovery's extrapolation, each with the Voigt time of the one before
# (the first from the last frames' average): the values settle to ~1e-6 in three.
RECOVERY_PASSES = 3


BASELINE_GUARD = 0.5      # s between a zero-force window and the pull or the stage's return
BASELINE_SIGNIFICANT = 3.0  # a baseline this many of a node's noise stds from zero is corrected


def zero_force_baseline(record: Record) -> tuple[np.ndarray, str]:
    """The tactile reading when nothing presses the specimen, per node, over the record.

    Before the pull and after the stage is back at depth 0 the specimen's bottom force
    is zero; what the segments read there is the sensor's own baseline. A line through
    both windows (a constant with one) models an offset and a drift. Returns the
    baseline (T, nodes) in N to subtract, zero unless some node's lies more than
    ``BASELINE_SIGNIFICANT`` noise stds from zero during the push, and a warning.
    """
    profile, t, force = record.profile(), record.force_t, record.force
    zero = (t < profile.t_pull_start - BASELINE_GUARD) | (t > profile.t_retracted + BASELINE_GUARD)
    none = np.zeros_like(force)
    if zero.sum() < 5:
        return none, ""
    during = (t >= profile.t_pull_start) & (t <= profile.t_keep_end)
    after = zero & (t > profile.t_pull_start)
    if after.sum() >= 5 and (zero & ~after).sum() >= 5:
        slope, offset = np.polyfit(t[zero], force[zero], 1)
    else:
        slope, offset = np.zeros(force.shape[1]), force[zero].mean(axis=0)
    baseline = offset[None] + slope[None] * t[:, None]
    noise = np.nan_to_num(force_noise(record)[0], nan=np.inf)   # the markers' is not needed here
    size = np.abs(baseline[during]).max(axis=0) if during.any() else np.zeros(force.shape[1])
    if not np.any(size > BASELINE_SIGNIFICANT * noise):
        return none, ""
    return baseline, (f"; WARNING: the tactile baseline is not zero where nothing presses: up to "
                      f"{size.max():.3g} N per node during the push (drift {np.abs(slope).max():.3g} N/s); "
                      "subtracted a line through the readings before the pull and after the stage's "
                      "return (a drifting or offset sensor: rheo analyze diagnoses it)")


# A relaxation rate known no better than this (relative std) leaves every parameter of
# the equations undetermined: c2 = asymptote / (rate ...) and E = rate (c1 + c2).
RATE_REL_STD_LIMIT = 0.3


def rate_note(rate: float, rate_rel_std: float) -> str:
    """The warning for a relaxation rate the force curves do not pin down (empty if they do)."""
    if rate_rel_std <= RATE_REL_STD_LIMIT:
        return ""
    return (f"; WARNING: the force curves pin the relaxation rate only to +-{100 * rate_rel_std:.0f} %: "
            f"E, c1, c2 and gamma from these equations are not determined (a keep of at least "
            f"{2.0 / rate:.3g} s, 2 relaxation times, determines them; the whole-record fit may)")


def _without_baseline(record: Record) -> tuple[Record, str]:
    baseline, note = zero_force_baseline(record)
    return (replace(record, force=record.force - baseline), note) if note else (record, "")


def from_final_displacement(
    record: Record, method: Method = "auto", nodes: Sequence[int] | None = None,
    guard: float = 0.1, final_window: float | None = None, forward: QuasiStaticFE | None = None,
) -> Estimate:
    """E, c1, c2 and the Poisson ratio by the paper's equations.

    Args:
        record: the run; its phases are read off the stage.
        method: ``long_time`` (eq. 6, 7, 10), ``short_time`` (eq. 6+14, 7, 17), or
            ``auto``: long-time when the keep force has relaxed below 1 % of its
            start, short-time otherwise.
        nodes: bottom nodes to use (0-based; default all).
        guard: s left out of the fits at each phase boundary.
        final_window: s at the end of the record averaged for the final
            displacements. ``None``: a first pass on the last 2 s gives c1/E, then
            every frame after the specimen left the stage is fitted by the model's
            recovery and its end taken (``recovered_displacement``), and the equations
            solved again, RECOVERY_PASSES times (the paper reads one final frame after
            full recovery; following the recovery needs no full recovery and divides
            the marker noise by the root of all the release's frames), where the force
            curves pin the rate down (``RATE_REL_STD_LIMIT``: the Voigt time needs it).
        forward: the converged forward model (``Setup.forward_model()``) for the force
            the markers' displacement implies; ``None``: the paper's ``J u`` on the
            marker grid (its own mesh: Tables II-IV).

    Raises:
        RecordError: a phase too short to fit, or data the model cannot explain.
    """
    record, baseline = _without_baseline(record)
    profile = record.profile()
    mesh = record.mesh
    nodes = np.arange(mesh.cols) if nodes is None else np.asarray(nodes)
    curves = fit_force_curves(record.force_t, record.force[:, nodes], profile, guard, record.source)
    relaxed = float(np.sum(np.abs(curves.keep_end)) / np.sum(np.abs(curves.keep_start)))
    if method == "auto":
        method = "long_time" if relaxed < 0.01 else "short_time"
    t_last = record.marker_t[-1]
    since = t_last - (MIN_FINAL_WINDOW if final_window is None else final_window)
    params, rms, dropped = _solve_equations(record, curves, profile, nodes, method,
                                            settled_displacement(record, since), forward)
    final = f"final displacements averaged over {t_last - since:.3g} s"
    # Following the recovery needs the Voigt time c1/E = c1 / (rate (c1 + c2)): a rate the
    # force curves do not pin down (``rate_note``) leaves it undetermined too.
    if final_window is None and curves.rate_rel_std <= RATE_REL_STD_LIMIT:
        # Follow the recovery to its end rather than average frames still recovering
        # (exact for the model where the average leaves e^-(release / tau) of the Voigt
        # strain), the Voigt time from the pass before: a fixed point, reached in a few.
        for _ in range(RECOVERY_PASSES):
            voigt = params["c1"] / params["E"]
            if not (np.isfinite(voigt) and voigt > 0):
                break
            t_free = profile.t_keep_end + followed_stage_for(params, profile) + guard
            if np.count_nonzero(record.marker_t >= t_free) < 3:
                break   # a release too short to follow: the last frames' average stands
            params, rms, dropped = _solve_equations(record, curves, profile, nodes, method,
                                                    recovered_displacement(record, t_free, voigt), forward)
            final = (f"final displacements extrapolated from {t_last - t_free:.3g} s of recovery "
                     f"(Voigt time c1/E {params['c1'] / params['E']:.3g} s)")
    labels = [f"P{i + 1}" for i in nodes]
    eqs = ["eq.6", "eq.7", "eq.10"] if method == "long_time" else ["eq.6+14", "eq.7", "eq.15-17"]
    follow = followed_stage_for(params, profile)
    slow = ""
    if follow > 0.5 / _rate(record.force_t):
        slow = (f"; WARNING: slow release: the specimen follows the retracting stage for {follow:.3g} s "
                f"(at {1e3 * profile.retract_speed:.3g} mm/s, by these values) and keeps creeping; eq. 14-17 "
                "assume an instant release, so E, c1, c2 come out low (7 % at the paper's 0.5 mm/s): "
                "use the whole-record fit, which follows the contact")
    return Estimate(
        params=params,
        method=f"paper_{method}",
        equations=_node_labels(nodes, mesh.geometry, eqs),
        residual_rms={"force_fit": curves.residual_rms, "equations": rms, "rate_rel_std": curves.rate_rel_std,
                      "release_follow_s": follow},
        message=(f"keep force relaxed to {100 * relaxed:.3g} % of its start; nodes {','.join(labels)}; "
                 f"{final}{dropped_note(dropped)}{slow}{baseline}"
                 f"{rate_note(curves.rate, curves.rate_rel_std)}"),
    )


def followed_stage_for(params: dict[str, float], profile: StageProfile) -> float:
    """How long (s) a specimen with the three-element ``params`` stays on the stage
    as it retracts (0: it lets go at once)."""
    element = three_element(params["E"], params["c1"], params["c2"])
    t_release = respond(element, stage_program(profile), np.array([profile.t_keep_end])).t_release
    return float(t_release - profile.t_keep_end)


def _rate(t: np.ndarray) -> float:
    """Sample rate (1/s) of stamps ``t``."""
    return 1.0 / float(np.median(np.diff(t)))


def _solve_equations(
    record: Record, curves: ForceCurves, profile: StageProfile, nodes: np.ndarray, method: str,
    u_final: np.ndarray, forward: QuasiStaticFE | None = None,
) -> tuple[dict[str, float], float, tuple[int, ...]]:
    """Eq. 6 (+14), 10 or 17 over the nodes; -> params, RMS residual, nodes left out.

    Per node, with g = [K_gamma u_final] (J u_final of the paper) and eta = c1c2/(c1+c2):
      a = c2 g                                   (eq. 6; with eq. 14 short-time)
      b = eta g  (+ eta F_K(end) / (r c2))       (eq. 10 long-time / eq. 17 short-time)
    """
    t_P = profile.pull_time
    F_end = np.zeros_like(curves.keep_end) if method == "long_time" else curves.keep_end
    a = curves.pull_asymptote * t_P - F_end / curves.rate
    b = (curves.pull_end - curves.keep_start) * t_P
    return solve_node_equations(record, nodes, u_final, a, b, F_end, curves.rate, forward)


def solve_node_equations(
    record: Record, nodes: np.ndarray, u: np.ndarray, a: np.ndarray, b: np.ndarray, F_end: np.ndarray, r: float,
    forward: QuasiStaticFE | None = None,
) -> tuple[dict[str, float], float, tuple[int, ...]]:
    """Solve ``a = c2 g`` and ``b = eta g + eta F_end / (r c2)`` over the bottom nodes by
    least squares (Section IV.B), ``g = [K_gamma u]`` at each node; -> params, RMS
    residual, and the nodes left out (0-based).

    ``u`` (N, 2) is the displacement the equations refer to (u_keep or u_final). With
    a ``forward`` model, ``g`` is the force per unit modulus that ``u`` implies on its
    converged mesh (``QuasiStaticFE.implied_force``) instead of the marker grid's
    ``K_gamma u``, whose four elements across the face are too stiff. A node
    whose displacement term or force jumps have the wrong sign for a push (its signal
    is within the noise: an edge node on a shallow push) is left out; the rest solve
    the equations if they can (one node with the block's gamma from the markers, two
    where gamma is a third unknown).
    """
    mesh = record.mesh
    # The uniaxial block: gamma from the markers alone, the equations on the uniform field.
    block_gamma = None
    if mesh.geometry == "uniaxial":
        block_gamma = _block_poisson_ratio(record, u)
        u = uniform_strain_field(mesh.nodes, u)
    bottom_y = mesh.y_dofs(mesh.bottom[nodes])
    K_lambda, K_mu = mesh.stiffness_parts
    g_lambda, g_mu = (K_lambda @ u.ravel())[bottom_y], (K_mu @ u.ravel())[bottom_y]

    def g_of(gamma: float) -> tuple[np.ndarray, np.ndarray]:
        """``g`` at the usable nodes and its derivative in gamma."""
        if forward is not None:
            g, dg = forward.implied_force(u, gamma)
            return g[nodes][usable], dg[nodes][usable]
        (lam, mu), (dlam, dmu) = lame_per_unit_modulus(gamma), lame_slope_per_unit_modulus(gamma)
        return lam * g_lambda + mu * g_mu, dlam * g_lambda + dmu * g_mu

    def unpack(x: np.ndarray) -> tuple[float, float, float]:
        """c2, eta, gamma from the search vector: c2 and eta as logs relative to their
        starts, gamma (searched only on plane_fe) as a logistic of x[2] onto its range."""
        return (c2_start * np.exp(x[0]), eta_start * np.exp(x[1]),
                g_lo + (g_hi - g_lo) * expit(x[2]) if search else block_gamma)

    def residuals(x: np.ndarray) -> np.ndarray:
        nonlocal overflowed
        c2, eta, gamma = unpack(x)
        g, _ = g_of(gamma)
        out = np.concatenate([(c2 * g - a) / sa, (eta * g + eta * F_end / (r * c2) - b) / sb])
        overflowed |= not np.all(np.isfinite(out))
        return out

    def jacobian(x: np.ndarray) -> np.ndarray:
        # Analytic: a closed form runs online after each phase, within its latency budget.
        c2, eta, gamma = unpack(x)
        g, dg = g_of(gamma)
        lag = eta * F_end / (r * c2)
        columns = [np.concatenate([c2 * g / sa, -lag / sb]), np.concatenate([np.zeros_like(g), (eta * g + lag) / sb])]
        if search:
            s = expit(x[2])
            columns.append(np.concatenate([c2 * dg / sa, eta * dg / sb]) * ((g_hi - g_lo) * s * (1.0 - s)))
        return np.column_stack(columns)

    usable = np.ones(nodes.size, bool)
    g0, _ = g_of(0.3 if block_gamma is None else block_gamma)
    usable = (g0 > 0) & (a > 0) & (b > 0)
    if usable.sum() < (2 if block_gamma is None else 1):
        raise RecordError(
            f"{record.source}: markers/force: displacement or force jump has the wrong sign "
            f"for a push at {', '.join(f'P{i + 1}' for i in nodes[~usable])} (no residual deformation, "
            "or no force drop at the end of pull)"
        )
    dropped = tuple(int(i) for i in nodes[~usable])
    g_lambda, g_mu, a, b, F_end, g0 = (v[usable] for v in (g_lambda, g_mu, a, b, F_end, g0))
    sa, sb = np.sqrt(np.mean(a**2)), np.sqrt(np.mean(b**2))
    search = block_gamma is None
    g_lo, g_hi = (-0.99, 0.4999) if forward is None else forward.TABLE_GAMMA
    # The starts: c2 from eq. 6's a = c2 g, then eta from b = eta (g + F_end / (r c2)) with
    # that c2 (the F_end term dominates b where the rate is slow). The search moves in logs
    # relative to them: MINPACK's first step is bounded by 100 x the start's norm, and
    # absolute logs (~30 for c2) made it ~4000, out of floating-point range.
    c2_start = float(np.median(a / g0))
    with np.errstate(divide="ignore", invalid="ignore"):
        eta_start = float(np.median(b / (g0 + F_end / (r * c2_start))))
    if not (np.isfinite(eta_start) and eta_start > 0.0):
        # A keep-end force within the noise, negative at a node, can turn the sign: the
        # search keeps its start's sign, so b = eta g's start (positive: usable nodes).
        eta_start = float(np.median(b / g0))
    x0 = [0.0, 0.0] + ([logit((0.3 - g_lo) / (g_hi - g_lo))] if search else [])
    # MINPACK (lm) with gamma kept in its range by the logistic, instead of a bounded
    # trust-region search: the same optimum, the loop in compiled code (the release's
    # closed form runs after each push within its latency budget; trf's Python loop was
    # half of it). At a bound the logistic saturates and the search stops there.
    # Where lm's unbounded steps still leave the finite range: the trust-region search,
    # whose steps stay within its region.
    for method in ("lm", "trf"):
        overflowed = False
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            sol = least_squares(residuals, x0, jac=jacobian, method=method, xtol=1e-10, ftol=1e-10, gtol=1e-10)
        if not overflowed and np.all(np.isfinite(sol.x)):
            break
    c2, eta, gamma = (float(v) for v in unpack(sol.x))
    if not (np.isfinite([c2, eta, gamma]).all() and np.isfinite(sol.fun).all()):
        raise RecordError(f"{record.source}: markers: the node equations (14-17) have no finite solution "
                          f"(c2 {c2:.3g}, c1c2/(c1+c2) {eta:.3g})")
    if eta >= c2:
        raise RecordError(f"{record.source}: force: jump too large for the three-element model (c1c2/(c1+c2) >= c2)")
    c1 = eta * c2 / (c2 - eta)
    params = {"E": r * (c1 + c2), "c1": c1, "c2": c2, "gamma": gamma}
    return params, float(np.sqrt(np.mean(sol.fun**2))), dropped


def dropped_note(dropped: tuple[int, ...]) -> str:
    """The warning for nodes the equations left out (empty when none)."""
    if not dropped:
        return ""
    return (f"; WARNING: {', '.join(f'P{i + 1}' for i in dropped)} left out of the equations: the wrong sign "
            "for a push (its signal is within the noise; a deeper push determines it)")


def _block_poisson_ratio(record: Record, u: np.ndarray) -> float:
    """The uniaxial block's Poisson ratio from marker displacements ``u`` (N, 2)."""
    gamma = lateral_strain_ratio(record.mesh.nodes, u)
    if not GAMMA_RANGE[0] < gamma < GAMMA_RANGE[1]:   # also NaN: no axial strain at all
        raise RecordError(f"{record.source}: markers: lateral over axial strain {-gamma:.4g} gives a Poisson ratio "
                          f"outside ({GAMMA_RANGE[0]:g}, {GAMMA_RANGE[1]:g}): no uniaxial compression seen")
    return gamma


def _node_labels(nodes: np.ndarray, mesh_geometry: str, eqs: list[str]) -> tuple[str, ...]:
    if mesh_geometry == "uniaxial":   # every node's equation is the same up to its share of the face
        eqs.append("gamma from the markers' lateral strain")
    else:
        eqs.append("IV.B least squares over " + ",".join(f"P{i + 1}" for i in nodes))
    return tuple(eqs)


def from_pull(record: Record, nodes: Sequence[int] | None = None, guard: float = 0.1,
                  forward: QuasiStaticFE | None = None) -> Estimate:
    """What the pull phase alone gives (the run may still be going on).

    Eq. 6 per node: its jump at the start is ``eta J u_keep / t_P`` (eta = c1c2/(c1+c2))
    and its asymptote ``c2 J u_keep / t_P``, with ``u_keep`` the displacement the markers
    show at the end of the pull; the rate is ``E/(c1+c2)``. Solved over the nodes like
    eq. 6 and 10 (the jump at t = 0 plays the part of eq. 10's jump at t_P).
    ``Estimate.residual_rms['rate_rel_std']`` says how far the pull's curvature pins
    the rate (and with it E and c2) down.
    """
    record, baseline = _without_baseline(record)
    profile = record.profile()
    nodes = np.arange(record.mesh.cols) if nodes is None else np.asarray(nodes)
    curve = fit_pull_curve(record.force_t, record.force[:, nodes], profile, guard, record.source)
    u_keep = displacement_at_depth(record, profile.depth)
    t_P = profile.pull_time
    params, rms, dropped = solve_node_equations(record, nodes, u_keep, curve.asymptote * t_P, curve.start * t_P,
                                                np.zeros_like(curve.start), curve.rate, forward)
    return Estimate(
        params=params, method="paper_pull",
        equations=_node_labels(nodes, record.mesh.geometry, ["eq.6 (pull only)", "eq.10 at t = 0"]),
        residual_rms={"force_fit": curve.residual_rms, "equations": rms, "rate_rel_std": curve.rate_rel_std,
                      "rate_x_pull_time": curve.rate * t_P},
        message=f"relaxation rate {curve.rate:.4g} 1/s +- {100 * curve.rate_rel_std:.3g} % from the pull's curvature "
                f"(rate x t_P = {curve.rate * t_P:.3g}){dropped_note(dropped)}{baseline}"
                f"{rate_note(curve.rate, curve.rate_rel_std)}",
    )


def from_pull_and_keep(record: Record, nodes: Sequence[int] | None = None, guard: float = 0.1,
                  forward: QuasiStaticFE | None = None) -> Estimate:
    """Pull and keep, before release: eq. 6, 7 and 10 with ``u_keep`` as the markers show it.

    The paper needs ``u_final`` because it reads the displacement after release; the
    camera sees ``u_keep`` during the keep, and with it eq. 6 and 10 hold exactly in the
    long- and the short-time case alike (eq. 17 with eq. 14 is eq. 10 in ``u_keep``).
    """
    record, baseline = _without_baseline(record)
    profile = record.profile()
    nodes = np.arange(record.mesh.cols) if nodes is None else np.asarray(nodes)
    curves = fit_force_curves(record.force_t, record.force[:, nodes], profile, guard, record.source)
    u_keep = displacement_during(record, profile.t_pull_end + guard, profile.t_keep_end - guard)
    params, rms, dropped = _solve_equations(record, curves, profile, nodes, "long_time", u_keep, forward)
    relaxed = float(np.sum(np.abs(curves.keep_end)) / np.sum(np.abs(curves.keep_start)))
    return Estimate(
        params=params, method="paper_keep",
        equations=_node_labels(nodes, record.mesh.geometry, ["eq.6", "eq.7", "eq.10 with u_keep"]),
        residual_rms={"force_fit": curves.residual_rms, "equations": rms, "rate_rel_std": curves.rate_rel_std},
        message=(f"keep force relaxed to {100 * relaxed:.3g} % of its start; u_keep from the keep's marker frames"
                 f"{dropped_note(dropped)}{baseline}{rate_note(curves.rate, curves.rate_rel_std)}"),
    )


def deformation_error(simulated: np.ndarray, measured: np.ndarray, width: float, height: float) -> float:
    """The paper's deformation error (Section V.B), in %.

    ``sum_i [(x_sim - x_rel)^2 + (y_sim - y_rel)^2] / (W H) * 100`` over the markers;
    positions (N, 2) in m, W and H the undeformed width and height (m).
    """
    return float(np.sum((np.asarray(simulated) - np.asarray(measured)) ** 2) / (width * height) * 100.0)
