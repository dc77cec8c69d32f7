"""``rheo bench peers``: the package's whole-record fit against the generic tools a user
would reach for first, on the same bags (package simulator) from the same start.

Generic fit: the three-element model (a Voigt element, spring E parallel to dashpot c1,
in series with a dashpot c2) written here as an ODE for scipy's ``solve_ivp`` (none of
the package's model code), driven by the recorded stage depth, contact lost where the
stress would pull (the stage retracting faster than the specimen recovers) and made
again where the stage reaches the surface; its stress (Pa per m of depth) times the
total bottom force per unit modulus and depth that the package's FE implies at the
closed form's gamma (``QuasiStaticFE.shape(gamma).bottom_force`` summed: the one
geometry factor taken from the package) is fitted to the total bottom force (sum over
the segments) by ``scipy.optimize.least_squares`` and by ``lmfit.minimize`` (its
default Levenberg-Marquardt), over log E, log c1, log c2, from the paper's closed form.
The package: ``fit_record`` from the same start with the sensor's noise weights and the
discretisation error in its std, timed cold (a fresh process: forward model and its
tables built, first fit) and warm (the same process, a new forward model, fitted again).

Second relaxation: a long keep with the simulator's hidden ``relaxation_branch`` arm
(a Maxwell arm of time viscosity / stiffness, ~5 s) beside the base's own relaxation
((c1 + c2) / E, ~940 s): pyvisco's time-domain Prony fit (two terms, times optimised)
of the keep's force over the depth's strain against the package's fit of
three_element+relaxation_branch (one arm: the base gives the slow time).

The peers are not dependencies of the package: the bench installs them (``PEERS``,
pinned, ``pip install --target`` into ``PEER_DIR`` with ``--no-deps``: pyvisco's
declared dependencies pull Jupyter and voila, its ``prony`` module needs only numpy,
scipy, pandas and matplotlib) and appends that folder to ``sys.path``.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

# The peers and what their used modules import beyond this environment (one place).
PEERS = ("lmfit==1.3.4", "asteval==1.0.10", "uncertainties==3.2.3", "dill==0.4.1",
         "pyvisco==2.1.3", "pandas==2.3.3", "python-dateutil==2.9.0.post0", "six==1.17.0", "pytz==2025.2",
         "tzdata==2025.2")
PEER_DIR = Path(os.environ.get("RHEO_PEER_DIR", Path.home() / ".cache" / "rheo_ros" / "peers"))
RTOL = 1e-8        # solve_ivp's relative tolerance (the generic side's integration)
KINK = 1e-9        # m/s: a change of the stage's speed this large starts a new piece of the drive
RELAXATION_KEEP = 1000.0   # s, the second-relaxation record's keep


# ---------------------------------------------------------------- peers' installation

def install_peers(folder: Path = PEER_DIR) -> dict[str, str]:
    """Install ``PEERS`` into ``folder`` (once: a stamp names the pins installed) and
    return the versions importable from it (``peer_versions``)."""
    folder.mkdir(parents=True, exist_ok=True)
    stamp = folder / "rheo-peers.txt"
    wanted = "\n".join(PEERS) + "\n"
    if not stamp.exists() or stamp.read_text() != wanted:
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-deps",
                        "--upgrade", "--target", str(folder), *PEERS], check=True)
        stamp.write_text(wanted)
    return peer_versions(folder)


def peer_versions(folder: Path = PEER_DIR) -> dict[str, str]:
    """Put ``folder`` on ``sys.path`` (after the environment's own packages) and return
    the versions of the peers that import (a peer missing is left out)."""
    if str(folder) not in sys.path:
        sys.path.append(str(folder))
    versions = {}
    for name in ("lmfit", "pyvisco", "pandas"):
        try:
            versions[name] = __import__(name).__version__
        except ImportError:
            pass
    return versions


# ---------------------------------------------------------------- the generic model

def drive(stage_t: np.ndarray, stage_depth: np.ndarray) -> tuple[np.ndarray, Callable, Callable]:
    """The stage's depth as pieces of constant speed: the times where its speed changes
    (the pieces' ends), the depth d(t) and the speed v(t) (linear between samples)."""
    slope = np.diff(stage_depth) / np.diff(stage_t)
    change = np.flatnonzero(np.abs(np.diff(slope)) > KINK) + 1
    breaks = np.concatenate([[stage_t[0]], stage_t[change], [stage_t[-1]]])

    def depth(t: float) -> float:
        return float(np.interp(t, stage_t, stage_depth))

    def speed(t: float) -> float:
        i = int(np.clip(np.searchsorted(stage_t, t, side="right") - 1, 0, slope.size - 1))
        return float(slope[i])

    return breaks, depth, speed


def three_element_stress(t_out: np.ndarray, stage_t: np.ndarray, stage_depth: np.ndarray,
                         E: float, c1: float, c2: float, rtol: float = RTOL) -> np.ndarray:
    """Stress (Pa per m of depth: E times a depth) of the three-element model at
    ``t_out`` under the stage's depth, from rest: in contact the Voigt element's share x1
    obeys c1 x1' + E x1 = c2 (d' - x1') (the dashpot c2 carries the same stress, x2 = d -
    x1); contact is lost where that stress turns negative (the specimen then recovers
    freely: c1 x1' = -E x1, x2 held, zero stress) and made again where the stage reaches
    the surface x1 + x2. ``solve_ivp`` (RK45) over each piece of constant stage speed."""
    breaks, depth, speed = drive(stage_t, stage_depth)
    out = np.zeros(len(t_out))
    x1, x2, contact = 0.0, 0.0, True
    a = c1 + c2

    def pulling(t, y):        # in contact: c1 d' + E x1 (the stress's sign)
        return c1 * speed(t) + E * y[0]
    pulling.terminal, pulling.direction = True, -1

    def touching(t, y):       # free: the stage's depth over the surface
        return depth(t) - (y[0] + y[1])
    touching.terminal, touching.direction = True, 1

    for lo, hi in zip(breaks[:-1], breaks[1:]):
        v, t = speed(0.5 * (lo + hi)), lo
        # A new speed: contact lost where the stress would now pull, made where the stage is
        # past the surface; within the piece the events switch it.
        if contact and c1 * v + E * x1 < 0:
            contact = False
        elif not contact and depth(t) > x1 + x2:
            contact = True
        while t < hi:
            # A time at a piece's boundary takes the piece before (the left limit: the stage
            # had not yet changed its speed); the piece's end carries the state on.
            inside = np.flatnonzero(((t_out > t) | ((t_out == t) & (t == breaks[0]))) & (t_out <= hi))
            t_eval = t_out[inside] if inside.size and t_out[inside[-1]] == hi else np.append(t_out[inside], hi)
            if contact:
                sol = solve_ivp(lambda _t, y: [(c2 * v - E * y[0]) / a], (t, hi), [x1], t_eval=t_eval,
                                events=pulling if v < 0 else None, rtol=rtol, atol=1e-16)
                n = min(len(sol.t), inside.size)
                if n:
                    out[inside[:n]] = c2 * (c1 * v + E * np.asarray(sol.y)[0, :n]) / a
            else:
                sol = solve_ivp(lambda _t, y: [-E * y[0] / c1, 0.0], (t, hi), [x1, x2], t_eval=t_eval,
                                events=touching, rtol=rtol, atol=1e-16)
                out[inside[: min(len(sol.t), inside.size)]] = 0.0
            if sol.status == 1:                     # contact lost or made: switch at the event
                t_end, y_end = float(sol.t_events[0][0]), sol.y_events[0][0]
                contact = not contact
            else:
                t_end, y_end = hi, np.asarray(sol.y)[:, -1]
            if y_end.size == 1:
                x1 = float(y_end[0])
                x2 = depth(t_end) - x1
            else:
                x1, x2 = float(y_end[0]), float(y_end[1])
            t = max(t_end, np.nextafter(t, np.inf))
    return out


def force_scale(forward: Any, gamma: float) -> float:
    """Total bottom force (N) per unit modulus (Pa) and depth (m) that the package's FE
    implies at ``gamma``: the one piece of the package the generic model borrows."""
    return float(np.sum(forward.shape(gamma).bottom_force))


def generic_residual(record: Any, scale: float) -> Callable[[np.ndarray], np.ndarray]:
    """Residual (N) of the total bottom force against the generic model at log E, log c1, log c2."""
    measured = record.force.sum(axis=1)

    def residual(x: np.ndarray) -> np.ndarray:
        E, c1, c2 = np.exp(x)
        return scale * three_element_stress(record.force_t, record.stage_t, record.stage_depth, E, c1, c2) - measured

    return residual


def fit_least_squares(record: Any, scale: float, start: dict[str, float]) -> dict[str, Any]:
    residual = generic_residual(record, scale)
    t0 = time.perf_counter()
    sol = least_squares(residual, np.log([start["E"], start["c1"], start["c2"]]))
    wall = time.perf_counter() - t0
    return {"params": dict(zip(("E", "c1", "c2"), np.exp(sol.x).tolist())), "std": None, "s": wall,
            "evaluations": int(sol.nfev), "rms_N": float(np.sqrt(np.mean(sol.fun**2)))}


def fit_lmfit(record: Any, scale: float, start: dict[str, float]) -> dict[str, Any]:
    import lmfit

    residual = generic_residual(record, scale)
    params = lmfit.Parameters()
    for name in ("E", "c1", "c2"):
        params.add(f"log_{name}", value=float(np.log(start[name])))
    t0 = time.perf_counter()
    out = lmfit.minimize(lambda p: residual(np.array([p["log_E"].value, p["log_c1"].value, p["log_c2"].value])),
                         params)
    wall = time.perf_counter() - t0
    values = {n: float(np.exp(out.params[f"log_{n}"].value)) for n in ("E", "c1", "c2")}
    std = {n: (values[n] * out.params[f"log_{n}"].stderr if out.params[f"log_{n}"].stderr is not None else None)
           for n in ("E", "c1", "c2")}
    return {"params": values, "std": std, "s": wall, "evaluations": int(out.nfev),
            "rms_N": float(np.sqrt(np.mean(out.residual**2)))}


# ---------------------------------------------------------------- the package's side

def package_fit(bag: str, start: dict[str, float], relaxation: bool = False) -> dict[str, Any]:
    """The package's fit of ``bag`` from ``start``, timed cold (the forward model built
    and the first fit in this process) and warm (a new forward model, fitted again);
    ``relaxation``: three_element+relaxation_branch (one arm) from the effect's first start.
    Run in a fresh process (``python -m rheo_ros.bench.peers BAG``) for the cold time."""
    from rheo_ros.config.setup import Setup
    from rheo_ros.identification.estimate import Estimate
    from rheo_ros.identification.fit import fit_record
    from rheo_ros.identification.noise import sensor_noise
    from rheo_ros.identification.pipeline import fit_weights
    from rheo_ros.io.bag import read_bag
    from rheo_ros.models.effects import Model, RelaxationBranch
    from rheo_ros.models.elements import three_element

    contents = read_bag(bag)
    record, setup = contents.record, Setup(contents.params)
    model = Model(three_element(1.0, 1.0, 1.0))
    if relaxation:
        keep = record.profile().keep_time
        model = Model(three_element(1.0, 1.0, 1.0), (RelaxationBranch(1.0, keep * 0.05),))
    walls, fits = [], []
    for _ in range(2):
        t1 = time.perf_counter()
        forward = setup.forward_model()
        params = dict(start)
        if relaxation:   # the effect's first start: an arm of half E's stiffness, a twentieth of the keep
            params.update({"relaxation_branch.stiffness": 0.5 * start["E"],
                           "relaxation_branch.viscosity": 0.5 * start["E"] * keep * 0.05})
        est = fit_record(record, Estimate(params=params, method="start", equations=()), model=model,
                         forward=forward, weights=fit_weights(sensor_noise(record)), discretisation=True)
        walls.append(time.perf_counter() - t1)
        fits.append(est)
    est = fits[-1]
    out = {"params": est.params, "std": est.std, "cold_s": walls[0], "warm_s": walls[1]}
    if relaxation:
        pred = forward.predict(model.with_parameters(est.params), est.params["gamma"], record.profile(),
                               record.force_t - est.statistics.delay("tactile"), record.marker_t).force.sum(axis=1)
        out["predicted_total"] = pred.tolist()
    return out


def closed_form_start(bag: Path) -> tuple[Any, dict[str, float], float]:
    """The bag's record, the paper's closed form (the start of every fit) and the FE's
    force scale at its gamma (``force_scale``)."""
    from rheo_ros.config.setup import Setup
    from rheo_ros.identification.pipeline import closed_form
    from rheo_ros.io.bag import read_bag

    contents = read_bag(bag)
    forward = Setup(contents.params).forward_model()
    start = closed_form("release", contents.record, forward).starts[0]
    return contents.record, start, force_scale(forward, start["gamma"])


def _package_in_child(bag: Path, start: dict[str, float], relaxation: bool = False) -> dict[str, Any]:
    command = [sys.executable, "-m", "rheo_ros.bench.peers", str(bag), json.dumps(start)]
    command += ["--relaxation"] if relaxation else []
    done = subprocess.run(command, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------- the bench

def _errors(params: dict[str, float], truth: dict[str, float]) -> dict[str, float]:
    return {n: params[n] / truth[n] - 1.0 for n in ("E", "c1", "c2")}


def whole_record_row(length: float, rate: float, seed: int, lmfit_ok: bool) -> dict[str, Any]:
    from rheo_ros.app.simulate import simulate_to_bag
    from rheo_ros.bench.scaling import record_params
    from rheo_ros.config.setup import Setup

    params = record_params(length, rate)
    truth = {n: params[f"material.{n}"] for n in ("E", "c1", "c2")}
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        simulate_to_bag(Setup(params), seed, bag)
        record, start, scale = closed_form_start(bag)
        pkg = _package_in_child(bag, start)
    row = {"length_s": Setup(params).profile.t_end, "tactile_hz": rate, "samples": int(record.force_t.size),
           "start": start, "scale_N_per_Pa_m": scale, "truth": truth,
           "package": {**pkg, "errors": _errors(pkg["params"], truth)}}
    ls = fit_least_squares(record, scale, start)
    row["least_squares"] = {**ls, "errors": _errors(ls["params"], truth)}
    if lmfit_ok:
        lm = fit_lmfit(record, scale, start)
        row["lmfit"] = {**lm, "errors": _errors(lm["params"], truth)}
    return row


def relaxation_row(seed: int, rate: float, pyvisco_ok: bool) -> dict[str, Any]:
    """A keep of ``RELAXATION_KEEP`` s with the simulator's Maxwell arm: the times found."""
    from rheo_ros.app.simulate import simulate_to_bag
    from rheo_ros.config.setup import Setup, check_params, load_params

    params = load_params(None)
    params.update({"stage.keep_time": RELAXATION_KEEP, "simulator.effects": ["relaxation_branch"],
                   "rates.tactile": float(rate), "rates.stage": float(max(params["rates.stage"], rate))})
    params = check_params(params, "bench peers")
    k, c = params["effects.relaxation_branch.stiffness"], params["effects.relaxation_branch.viscosity"]
    truth = sorted([c / k, (params["material.c1"] + params["material.c2"]) / params["material.E"]])
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        simulate_to_bag(Setup(params), seed, bag)
        record, start, scale = closed_form_start(bag)
        pkg = _package_in_child(bag, start, relaxation=True)
    prof = record.profile()
    keep = (record.force_t > prof.t_pull_end) & (record.force_t < prof.t_keep_end)
    measured = record.force.sum(axis=1)
    p = pkg["params"]
    found = sorted([p["relaxation_branch.viscosity"] / p["relaxation_branch.stiffness"], (p["c1"] + p["c2"]) / p["E"]])
    resid = (np.asarray(pkg["predicted_total"]) - measured)[keep]
    row = {"keep_s": RELAXATION_KEEP, "tactile_hz": rate, "truth_times_s": truth,
           "package": {"times_s": found, "rms_N": float(np.sqrt(np.mean(resid**2))), "cold_s": pkg["cold_s"],
                       "warm_s": pkg["warm_s"], "std": pkg["std"]}}
    if pyvisco_ok:
        row["pyvisco"] = pyvisco_fit(record.force_t[keep] - prof.t_pull_end, measured[keep],
                                     np.interp(record.force_t[keep], record.stage_t, record.stage_depth),
                                     scale)
    return row


def pyvisco_fit(t: np.ndarray, force: np.ndarray, depth: np.ndarray, scale: float) -> dict[str, Any]:
    """pyvisco's time-domain Prony series (two terms, ``window='min'``, times optimised)
    of the keep's relaxation modulus force / (scale depth) from the keep's start, the
    way its documentation loads a master curve (a CSV of t, E_relax)."""
    from pyvisco import load, master, prony

    modulus = force / (scale * depth)
    csv = "t,E_relax\ns,Pa\n" + "\n".join(f"{a:.9g},{b:.9g}" for a, b in zip(t, modulus))
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):   # it prints its convergence
        df_master, _ = load.user_master(csv.encode(), "time", 20, "E")
        df_master = master.smooth(df_master, 1)
        df_dis = prony.discretize(df_master, window="min", nprony=2)
        fitted, _ = prony.fit(df_dis, df_master, opt=True)
    wall = time.perf_counter() - t0
    terms = fitted["df_terms"]
    taus, alphas = terms["tau_i"].to_numpy(float), terms["alpha_i"].to_numpy(float)
    model = fitted["E_0"] * (1 - alphas.sum() + np.exp(-t[:, None] / taus[None]) @ alphas)
    resid = model * scale * depth - force
    return {"times_s": sorted(taus.tolist()), "rms_N": float(np.sqrt(np.mean(resid**2))), "s": wall,
            "tau_bounds_s": [1 / (2 * np.pi * df_dis.f_max), 1 / (2 * np.pi * df_dis.f_min)]}


def run(lengths: str = "170,600", rates: str = "50", seed: int = 1, no_relaxation: bool = False,
        no_install: bool = False, out: str | None = None) -> dict[str, Any]:
    """Every length (s) x tactile rate (Hz), comma-separated: the whole-record fits (with
    both defaults also the 170 s record at 500 Hz); the second-relaxation record against
    pyvisco unless ``no_relaxation``; ``no_install``: the peers already in ``PEER_DIR``
    only; ``out``: also write the table there, under a line naming the command, commit,
    date and machine."""
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    versions = peer_versions() if no_install else install_peers()
    import scipy

    versions["scipy"] = scipy.__version__
    versions["numpy"] = np.__version__
    lmfit_ok, pyvisco_ok = "lmfit" in versions, "pyvisco" in versions
    cases = [(float(n), float(r)) for r in rates.split(",") for n in lengths.split(",")]
    if (lengths, rates) == ("170,600", "50"):
        cases.append((170.0, 500.0))
    rows = [whole_record_row(n, r, seed, lmfit_ok) for n, r in cases]
    result: dict[str, Any] = {"rows": rows, "seed": seed, "versions": versions}
    if not no_relaxation:
        result["relaxation"] = relaxation_row(seed, 50.0, pyvisco_ok)
    if out:
        Path(out).write_text(_header(lengths, rates, seed, no_relaxation, started) + "\n" + format_table(result) + "\n")
    return result


def _header(lengths: str, rates: str, seed: int, no_relaxation: bool, started: str) -> str:
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown commit"
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), "unknown CPU") if Path("/proc/cpuinfo").exists() else "unknown CPU"
    return (f"# rheo bench peers --lengths {lengths} --rates {rates} --seed {seed}"
            f"{' --no-relaxation' if no_relaxation else ''}"
            f"{' (and 170 s at 500 Hz)' if (lengths, rates) == ('170,600', '50') else ''} (data: the package's simulator), {commit} + working tree, "
            f"started {started}, {os.cpu_count()} cores ({cpu}), other work beside it")


def _pct(x: float) -> str:
    return f"{100 * x:+.3f}%"


def format_table(result: dict[str, Any]) -> str:
    v = result["versions"]
    lines = [f"peers: scipy {v.get('scipy')}, numpy {v.get('numpy')}, lmfit {v.get('lmfit', 'not installed')}, "
             f"pyvisco {v.get('pyvisco', 'not installed')} (pandas {v.get('pandas', '-')}); data: the package's "
             f"simulator, seed {result['seed']}",
             "whole-record fit of E, c1, c2 from the closed form (the same start for all). Generic: solve_ivp "
             "(RK45, rtol 1e-8) of the three-element ODE driven by the stage depth, contact lost where the stress "
             "would pull; force = stress x the FE's total bottom force per unit modulus and depth at the closed "
             "form's gamma; fitted to the total bottom force, unweighted, over log E, log c1, log c2.",
             "package: fit_record (E, c1, c2, gamma, clock offsets; every segment and marker), cold = forward model "
             "built + first fit in a fresh process (the start given), warm = a new forward model, "
             "fitted again in that process. Error = fit / truth - 1; std: the fit's own (- : none given); "
             "ratio = generic time / package time (target >= 10 x).",
             f"{'record':>8} {'rate':>6} {'fit':>13} {'time':>8} {'ratio':>13} | {'E err':>9} {'c1 err':>9} "
             f"{'c2 err':>9} | {'E std':>7} {'c1 std':>7} {'c2 std':>7} {'err/std':>8} | {'rms N':>7}"]
    for r in result["rows"]:
        pkg = r["package"]
        for label, f in (("package cold", pkg), ("package warm", pkg), ("least_squares", r.get("least_squares")),
                         ("lmfit", r.get("lmfit"))):
            if f is None:
                lines.append(f"{r['length_s']:>6.0f} s {r['tactile_hz']:>3.0f} Hz {label:>13} not installed")
                continue
            wall = f["cold_s"] if label == "package cold" else f["warm_s"] if label == "package warm" else f["s"]
            if label.startswith("package"):
                ratio = ""
            else:
                ratio = f"{wall / pkg['cold_s']:>5.1f}x/{wall / pkg['warm_s']:>5.1f}x"
            std = f.get("std") or {}
            stds = " ".join(f"{100 * std[n] / f['params'][n]:>6.3f}%" if std.get(n) is not None else f"{'-':>7}"
                            for n in ("E", "c1", "c2"))
            e = f["errors"]
            sig = max((abs(e[n]) * f["params"][n] / std[n] for n in e if std.get(n)), default=None)
            stds += f" {sig:>8.1f}" if sig is not None else f" {'-':>8}"
            rms = f"{f['rms_N']:>7.4f}" if "rms_N" in f else f"{'':>7}"
            lines.append(f"{r['length_s']:>6.0f} s {r['tactile_hz']:>3.0f} Hz {label:>13} {wall:>6.2f} s {ratio:>13} | "
                         f"{_pct(e['E']):>9} {_pct(e['c1']):>9} {_pct(e['c2']):>9} | {stds} | {rms}")
    lines.append("ratio: the generic fit's time over the package's, cold / warm (above 1: the package is faster); "
                 "err/std: the largest |error| over the fit's own std; rms N: the total force's residual")
    rel = result.get("relaxation")
    if rel:
        t = rel["truth_times_s"]
        lines.append(f"second relaxation: keep {rel['keep_s']:.0f} s, {rel['tactile_hz']:.0f} Hz, simulator's "
                     f"relaxation_branch arm (true times {t[0]:.3g} s and (c1 + c2) / E = {t[1]:.4g} s); "
                     "the keep's total force")
        p = rel["package"]
        lines.append(f"  package three_element+relaxation_branch: times {p['times_s'][0]:.4g} s, {p['times_s'][1]:.4g} s "
                     f"(errors {_pct(p['times_s'][0] / t[0] - 1)}, {_pct(p['times_s'][1] / t[1] - 1)}), keep force "
                     f"rms {p['rms_N']:.4f} N, {p['cold_s']:.2f} s cold / {p['warm_s']:.2f} s warm")
        q = rel.get("pyvisco")
        if q is None:
            lines.append("  pyvisco: not installed")
        else:
            lines.append(f"  pyvisco Prony (2 terms, window 'min', opt): times {q['times_s'][0]:.4g} s, "
                         f"{q['times_s'][1]:.4g} s (errors {_pct(q['times_s'][0] / t[0] - 1)}, "
                         f"{_pct(q['times_s'][1] / t[1] - 1)}), keep force rms {q['rms_N']:.4f} N, {q['s']:.2f} s; "
                         f"its times bounded to [{q['tau_bounds_s'][0]:.3g}, {q['tau_bounds_s'][1]:.4g}] s "
                         "(1 / 2 pi f over the data's window); package time / pyvisco's "
                         f"{p['cold_s'] / q['s']:.1f}x cold, {p['warm_s'] / q['s']:.1f}x warm")
    return "\n".join(lines)


if __name__ == "__main__":   # the package's side of one bag, in a fresh process (cold)
    print(json.dumps(package_fit(sys.argv[1], json.loads(sys.argv[2]), relaxation="--relaxation" in sys.argv[3:]),
                     default=float))
