"""The paper's identification (Sections III and IV.B).

1. Force curve fits: eq. 6 in the pull phase and eq. 7 in the keep phase, one
   relaxation rate ``r = E/(c1+c2)`` shared by both phases and every bottom node.
2. Long-time case (the force has relaxed, ``u_keep = u_final``): eq. 6 asymptote and
   eq. 10 force jump. Short-time case: eq. 6 with eq. 14 and eq. 17, from the final
   displacements only.
3. 2D: ``c2 J`` becomes ``c2 (lambda^g J_lambda + mu^g J_mu) = c2 K_gamma``; the
   equations of all bottom nodes are solved together by least squares for c2,
   ``c1 c2/(c1+c2)`` and the Poisson ratio (Section IV.B).

Every bottom segment is used by default. The paper drops P1 and P5 because their
sensor segments cover half an element; here each segment sums to its node's
force (the tactile layout puts each nodal force on its own segment), so the edge
nodes carry the most Poisson information (their reaction depends most on gamma)
and drop nothing but noise. ``nodes=(1, 2, 3)`` gives the paper's P2-P4.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.optimize import least_squares

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import lame_per_unit_modulus
from rheo_ros.identification.estimate import Estimate
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

    def amplitudes(rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ep, ek = np.exp(-rate * tp), np.exp(-rate * tk)
        X = np.column_stack([np.ones_like(ep), ep])
        ab, *_ = np.linalg.lstsq(X, Fp, rcond=None)  # (2, nodes): asymptote, amplitude
        k = (ek @ Fk) / (ek @ ek)                    # (nodes,)
        res = np.concatenate([(X @ ab - Fp).ravel(), (np.outer(ek, k) - Fk).ravel()])
        return ab, k, res

    total = np.abs(Fk).sum(axis=1)
    head, tail = total[: max(1, total.size // 10)].mean(), total[-max(1, total.size // 10):].mean()
    span = tk[-1] - tk[0]
    rate0 = np.log(head / tail) / (0.9 * span) if head > tail > 0 else 1.0 / span
    fit = least_squares(lambda x: amplitudes(np.exp(x[0]))[2], [np.log(rate0)], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    rate = float(np.exp(fit.x[0]))
    (asym, amp), k, res = amplitudes(rate)
    pull_time, keep_time = t_pe - t_ps, t_ke - t_pe
    return ForceCurves(
        rate=rate,
        pull_asymptote=asym,
        pull_end=asym + amp * np.exp(-rate * pull_time),
        keep_start=k,
        keep_end=k * np.exp(-rate * keep_time),
        residual_rms=float(np.sqrt(np.mean(res**2))),
    )


def final_displacement(record: Record, since: float) -> np.ndarray:
    """Marker displacements (N, 2) averaged over the frames from ``since`` (s) to the end.

    The bottom row is held by the sensor (the model's boundary condition): its
    displacement is zero, not the noise its markers show.
    """
    last = record.marker_t >= min(since, record.marker_t[-1])
    u = record.marker_displacement[last].mean(axis=0)
    u[record.mesh.bottom] = 0.0
    return u


# Final displacements: the specimen has recovered (to e^-15 of its Voigt strain) 15
# Voigt times c1/E after release; every frame from then on shows the same shape.
SETTLED_VOIGT_TIMES = 15.0
MIN_FINAL_WINDOW = 2.0  # s


def identify_paper(
    record: Record, method: Method = "auto", nodes: Sequence[int] | None = None,
    guard: float = 0.1, final_window: float | None = None,
) -> Estimate:
    """E, c1, c2 (and the Poisson ratio in 2D) by the paper's equations.

    Args:
        record: the run; its phases are read off the stage.
        method: ``long_time`` (eq. 6, 7, 10), ``short_time`` (eq. 6+14, 7, 17), or
            ``auto``: long-time when the keep force has relaxed below 1 % of its
            start, short-time otherwise.
        nodes: bottom nodes to use (0-based; default all).
        guard: s left out of the fits at each phase boundary.
        final_window: s at the end of the record averaged for the final
            displacements. ``None``: a first pass on the last 2 s gives c1/E, then
            every frame from 15 Voigt times after release on is averaged and the
            equations are solved again (the paper reads one final frame; averaging
            the recovered plateau divides the marker noise by the root of its frames).

    Raises:
        RecordError: a phase too short to fit, or data the model cannot explain.
    """
    profile = record.profile()
    mesh = record.mesh
    nodes = np.arange(mesh.cols) if nodes is None else np.asarray(nodes)
    curves = fit_force_curves(record.force_t, record.force[:, nodes], profile, guard, record.source)
    relaxed = float(np.sum(np.abs(curves.keep_end)) / np.sum(np.abs(curves.keep_start)))
    if method == "auto":
        method = "long_time" if relaxed < 0.01 else "short_time"
    t_last = record.marker_t[-1]
    since = t_last - (MIN_FINAL_WINDOW if final_window is None else final_window)
    params, rms = _solve_equations(record, curves, profile, nodes, method, final_displacement(record, since))
    if final_window is None:
        settled = profile.t_keep_end + SETTLED_VOIGT_TIMES * params["c1"] / params["E"]
        if settled < since:
            since = settled
            params, rms = _solve_equations(record, curves, profile, nodes, method, final_displacement(record, since))
    labels = [f"P{i + 1}" for i in nodes]
    eqs = ["eq.6", "eq.7", "eq.10"] if method == "long_time" else ["eq.6+14", "eq.7", "eq.15-17"]
    if mesh.geometry == "plane_fe":
        eqs.append("IV.B least squares over " + ",".join(labels))
    return Estimate(
        params=params,
        method=f"paper_{method}",
        equations=tuple(eqs),
        residual_rms={"force_fit": curves.residual_rms, "equations": rms},
        message=(f"keep force relaxed to {100 * relaxed:.3g} % of its start; nodes {','.join(labels)}; "
                 f"final displacements averaged over {t_last - since:.3g} s"),
    )


def _solve_equations(
    record: Record, curves: ForceCurves, profile: StageProfile, nodes: np.ndarray, method: str,
    u_final: np.ndarray,
) -> tuple[dict[str, float], float]:
    """Solve eq. 6 (+14), 10 or 17 over the nodes by least squares; -> params, RMS residual."""
    mesh = record.mesh
    r, t_P = curves.rate, profile.pull_time
    u_dofs = u_final.ravel() if mesh.dofs_per_node == 2 else u_final[:, 1]
    bottom_y = mesh.y_dofs(mesh.bottom[nodes])
    K_lambda, K_mu = mesh.stiffness_parts
    g_lambda, g_mu = (K_lambda @ u_dofs)[bottom_y], (K_mu @ u_dofs)[bottom_y]
    plane = mesh.geometry == "plane_fe"

    # Per node, with g = [K_gamma u_final] (J u_final of the paper) and eta = c1c2/(c1+c2):
    #   a = c2 g                                   (eq. 6; with eq. 14 short-time)
    #   b = eta g  (+ eta F_K(end) / (r c2))       (eq. 10 long-time / eq. 17 short-time)
    F_end = np.zeros_like(curves.keep_end) if method == "long_time" else curves.keep_end
    a = curves.pull_asymptote * t_P - F_end / r
    b = (curves.pull_end - curves.keep_start) * t_P
    sa, sb = np.sqrt(np.mean(a**2)), np.sqrt(np.mean(b**2))

    def g_of(gamma: float) -> np.ndarray:
        if not plane:
            return g_mu
        lam, mu = lame_per_unit_modulus(gamma)
        return lam * g_lambda + mu * g_mu

    def residuals(x: np.ndarray) -> np.ndarray:
        c2, eta = np.exp(x[0]), np.exp(x[1])
        g = g_of(x[2]) if plane else g_mu
        return np.concatenate([(c2 * g - a) / sa, (eta * g + eta * F_end / (r * c2) - b) / sb])

    g0 = g_of(0.3)
    if np.any(g0 <= 0) or np.any(a <= 0) or np.any(b <= 0):
        raise RecordError(
            f"{record.source}: markers/force: final displacement or force jump has the wrong sign "
            "for a push (no residual deformation, or no force drop at the end of pull)"
        )
    x0 = [np.log(np.median(a / g0)), np.log(np.median(b / g0))] + ([0.3] if plane else [])
    lo = [-np.inf, -np.inf] + ([-0.99] if plane else [])
    hi = [np.inf, np.inf] + ([0.4999] if plane else [])
    sol = least_squares(residuals, x0, bounds=(lo, hi), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    c2, eta = float(np.exp(sol.x[0])), float(np.exp(sol.x[1]))
    if eta >= c2:
        raise RecordError(f"{record.source}: force: jump too large for the three-element model (c1c2/(c1+c2) >= c2)")
    c1 = eta * c2 / (c2 - eta)
    params = {"E": r * (c1 + c2), "c1": c1, "c2": c2}
    if plane:
        params["gamma"] = float(sol.x[2])
    return params, float(np.sqrt(np.mean(sol.fun**2)))


def deformation_error(simulated: np.ndarray, measured: np.ndarray, width: float, height: float) -> float:
    """The paper's deformation error (Section V.B), in %.

    ``sum_i [(x_sim - x_rel)^2 + (y_sim - y_rel)^2] / (W H) * 100`` over the markers;
    positions (N, 2) in m, W and H the undeformed width and height (m).
    """
    return float(np.sum((np.asarray(simulated) - np.asarray(measured)) ** 2) / (width * height) * 100.0)
