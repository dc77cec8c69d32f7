"""``rheo bench diagnosis``: how often the model-discovery loop names exactly the effects
hidden in a bag, against the effects' size, over bags from a pluggable source.

**Sources of bags.** A source is a function with the protocol of :data:`BagSource`::

    bench_bag(rng, index, out_dir, noise_scale, quick) -> dict

It draws the ``index``-th bag from ``rng`` (a ``numpy.random.Generator`` of its own,
seeded by the bench's seed and the index, so one bag can be made again alone), writes
it as a rosbag2 directory at ``out_dir`` (which does not exist; files beside it, in its
parent, are the bench's to delete), with every noise ``noise_scale`` times the
source's default and, with ``quick``, short records (for tests). It returns the truth:

- ``hidden``: a list of ``{"effect": family id, "form": form, "size": float,
  "size_live": float, "params": {...}}``, in the package's vocabulary
  (``rheo_ros.models.effects.catalogue`` and ``effect_forms``), empty for a clean bag;
  ``size`` and ``size_live`` are that effect's alone (below);
- ``size``, ``size_live``: the same for all the hidden effects together;
- ``params_file``: a parameters file to analyse with, or None (the bag's own);
- ``info``: anything else worth keeping in the JSON (material, sensor, ...).

A source may also take ``outside=True`` (``--outside``): the bag then hides one effect
in no catalogue (a sensor with memory, a camera's drift, ...) and none of the
catalogue's, and the truth lists it in ``outside`` (``{"effect": its name, "signal":
force or markers, "size": float, "params": {...}}``, ``size`` in that signal's noise).

A source may also take ``limit=(family, size)`` (``--limit``): the bag then hides exactly
one effect of that family, in a form drawn as usual, its amplitude scaled until its
readable size (``size_live``, below) is within ``LIMIT_TOLERANCE`` of ``size`` (where the
sensor lets it: an adhesion under a dead band reads nothing until its force crosses the
band, then much; the truth keeps the size reached). Random draws spread the sizes over
decades, so a threshold read off them is bounded by the largest miss and the next hit;
a limit run puts its bags between (``FAMILY:LO:HI``: targets log-uniform in that range).

The **effect size** is the RMS over the force readings of the change the hidden effects
make in the noise-free total bottom force, over the std of the total force's noise
(``sqrt(cells) x cell noise x cell area``); ``size_live`` is the same through the
sensor's dead band and floor (what a noise-free sensor would read): an adhesion of a
few percent, or a drift below zero, can be large by ``size`` and still unreadable.
A source may also give ``size_separable`` for each hidden effect (``hidden`` items; or
afterwards through a function ``bench_separable_sizes(rng, index, noise_scale, quick)``
for runs made without it, ``--merge ... --generator``): the part of its footprint the
rest of the truth cannot take up, its change of the expected readings (the noisy
sensor's mean reading: a small drift on idle floored cells shows by half) and markers
beside the other hidden effects, less the best compensation by the base's parameters
and theirs (the source's own model refitted without it), on the same scale. A settling
drift beside an adhesion can change the force by 1.9 x the noise and leave 0.27 x that
no other parameter could also make (generator seed 17 bag 26): a threshold read off
single-effect bags does not carry over to it by ``size_live``. Thresholds and accuracy
above them are then reported by it too.

Two sources exist: the package's simulator (:func:`simulator_bag`, the default) and any
file given by ``--generator PATH`` that defines ``bench_bag`` (:func:`load_source`;
``test/generator.py``, which shares no code with rheo_ros, is one). A bag ``i`` hides
``i mod 3`` effects (0, 1 or 2), of distinct families drawn at random, each in a form
drawn from those the source makes, with a magnitude from barely detectable to large.

**The package's simulator** (dynamic FE on its own finer mesh, the noisy sensor path)
draws: E log-uniform 1e4..1e5 Pa, c1 / E uniform 2..15 s, c2 / E uniform 300..3000 s,
gamma uniform 0.2..0.45; depth uniform 5..12 mm, keep 15..40 s, release 20..40 s (quick:
15..18 and 20..24 s); tactile noise uniform 60..150 Pa per cell and marker noise
1e-5..3e-5 m (around the defaults 100 Pa and 2e-5 m), each times ``noise_scale``;
geometry ``plane_fe`` (80 %) or ``uniaxial`` (20 %). Every form but ``voigt_exponential``
(the FE simulator's material is linear) and the per-segment drifts (a parameters file
sets one number per field). A drift's offset is log-uniform 1e-5..0.3 N a segment, its
settling amplitude +-1e-5..0.3 N and its rate +-3e-7..3e-3 N/s (``SIMULATOR_DRAWS``).
Its sizes come from the identification's
forward model (``QuasiStaticFE.predict``, 0.04 s) with the true parameters, with and
without the effects, within 0.1 % of the simulator's own noise-free run (checked on one
bag of each effect) at a fraction of its cost; its separable sizes likewise
(``separable_size``: the forward model refitted, the sensor's mean reading by
``expected_reading``), a fraction of a second a bag.

**Scoring** (:func:`score`). Each bag is analysed as ``rheo analyze`` does (``analyze``,
every candidate). Its outcome is ``failed`` (could not be made, or the analysis broke),
``refused`` (the analysis declined the bag with its one-line error: a sensor saturated
through the push, a phase too short), ``undecided`` (the loop ended unable to tell effects
apart), ``extra`` (an effect named that was not hidden), ``unexplained`` (nothing wrong
named, but the verdict that the catalogue does not explain the data: every bag here is
the catalogue's), ``exact`` (the set of effects named, ``missing_effects``, is the hidden
set) or ``missed`` (a hidden effect not named, nothing extra). Forms are scored apart: for
each hidden effect the loop named, the form the final model holds against the hidden one.

The **detection threshold** of a family (and of each form) is the smallest readable size
(``size_live``) such that at least ``target`` of the single-effect bags of that family
(form) with an effect that large or larger are ``exact`` (a bag hiding two effects
depends on both, so it does not set a family's threshold). ``target`` is 95 % at the
default noise and 90 % at twice it (issue 20); a limit run's bags pooled with the random
draws (``--merge``) join the single-effect bags here and nowhere else. A bag is **above**
the thresholds when each of its hidden effects is above its family's; exact-set accuracy
is reported above and below, by each size, and by both (``detectable_scores``: every
effect read by the sensor and not made by the rest of the truth). **Clean bags**: false claims (any effect named) and undecided; and how well
the final model fits: the RMS of its total-force residual over the readings where every
segment is live, pooled over the phases, over the total force's noise as the data show
it (``force_rms_to_noise``, from the analysis's comparison, signal ``total``). Readings
in the dead band are left out of it: there a model reads zero like the sensor and would
make the ratio look better than the fit is. A clean bag fits within the noise when the
ratio is at most ``FIT_LIMIT``, or, over readings too few for that, within
``FIT_SAMPLING_SIGMAS`` of its sampling std of 1 (``fit_limit``; the row keeps the count,
``force_rms_readings``).

**Out of the catalogue** (``--outside``, issue 24): a bag hiding an effect no catalogue
holds is ``unexplained`` when nothing is named and the verdict says the catalogue does
not explain the data (the right answer), ``wrong`` when an effect is named (the figure
to keep at 2 % or under), ``missed`` when nothing is named and the model is called
adequate (too small to see, or taken up by the base parameters).
"""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtr

from rheo_ros.app.analyze import analyze
from rheo_ros.config.setup import ParamsError, Setup, check_params
from rheo_ros.diagnosis.decision import Verdict
from rheo_ros.experiment import sample_times
from rheo_ros.io.bag import write_run
from rheo_ros.io.errors import BagError
from rheo_ros.models.effects import Effect, Model, PerSegmentEffect, effect_class, effect_forms
from rheo_ros.record import RecordError
from rheo_ros.rig.simulator import simulate_run
from rheo_ros.sensors import TactileArray

# A source of bags: (rng, index, out_dir, noise_scale, quick) -> truth (module docstring).
BagSource = Callable[[np.random.Generator, int, Path, float, bool], dict[str, Any]]
PROTOCOL = "bench_bag"          # the function a --generator file defines
SEPARABLE = "bench_separable_sizes"   # and may define: each hidden effect's separable size
SIMULATOR = "rheo_ros simulator"
# The simulator's draws (``draw_bag``), kept in each of its runs: a merge draws a bag
# again (its separable size) only where the run drew it the same way. 2: drifts from
# 1e-5 N a node (stop 56; 1: from 3e-3 N, no "draws" in the JSON).
SIMULATOR_DRAWS = 2
FAMILIES = ("relaxation_branch", "adhesion", "strain_stiffening", "sensor_drift")
# A limit run's bag (``--limit``): its effect's readable size within this share of the
# target, reached by scaling the amplitudes (``LIMIT_AMPLITUDES``) at most LIMIT_STEPS times.
LIMIT_TOLERANCE = 0.03
LIMIT_STEPS = 8
LIMIT_SCALES = (1e-3, 1e3)   # the amplitudes within these factors of the draw's
# The most a scaled amplitude may reach, where its domain ends (``check_params``): a held
# fraction of the force over 1 is no bag.
LIMIT_CAPS = {"fraction": 1.0}
# The simulator's fields scaled together to set an effect's size (its times kept).
LIMIT_AMPLITUDES = {"relaxation_branch": ("stiffness", "viscosity", "stiffness_2", "viscosity_2"),
                    "adhesion": ("fraction",), "strain_stiffening": ("coefficient",),
                    "sensor_drift": ("offset", "amplitude", "rate")}
OUTCOMES = ("exact", "missed", "extra", "unexplained", "undecided", "refused", "failed")
OUTSIDE_OUTCOMES = ("unexplained", "missed", "wrong", "undecided", "refused", "failed")
NO_ANSWER = ("refused", "failed")   # outcomes with no analysis to score
# The errors by which the analysis declines a bag in one line (``refused``).
REFUSALS = (BagError, RecordError, ParamsError, ValueError)
WRONG_LIMIT = 0.02              # wrong names on out-of-catalogue bags at most this share
# Exact-set accuracy wanted above the threshold: at the default noise, and at twice it.
TARGETS = {1.0: 0.95, 2.0: 0.90}
FIT_LIMIT = 1.1                 # a clean bag's final force RMS within this x the noise
# ... or within this many of its own sampling stds of 1 (the RMS of n white readings over
# their std: std 1/sqrt(2n)): a clipped sensor's clean bag (generator seed 17 bag 24) has
# 11 readings where every segment is live, and there the truth itself reads 1.19 one time in five.
FIT_SAMPLING_SIGMAS = 2.0
# Uniform ranges (s) of the keep and of the release: full runs, and quick ones for tests.
KEEP, RELEASE = (15.0, 40.0), (20.0, 40.0)
QUICK_KEEP, QUICK_RELEASE = (15.0, 18.0), (20.0, 24.0)
# How far (in log) the separable size's refit may move each compensating parameter: a
# trial sending an arm's time towards zero costs the generator's integrator minutes.
SEPARABLE_LOG_MOVE = 3.0
GAMMA_MAX = 0.4999   # the separable size's refit keeps the Poisson ratio under 1/2


def log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A draw uniform in log between ``lo`` and ``hi`` (magnitudes over decades)."""
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def default_target(noise_scale: float) -> float:
    """The issue's exact-set target at this noise: 95 % at the default, 90 % at twice it."""
    return TARGETS[1.0] if noise_scale <= 1.0 else TARGETS[2.0]


# --- the package's simulator as a source -------------------------------------------

def simulator_forms(family: str) -> tuple[str, ...]:
    """The forms of ``family`` the FE simulator can hide: its material is linear (no form
    that makes the Voigt spring nonlinear), and the parameters file sets one number per
    field (no per-segment form, whose fields follow the layout)."""
    return tuple(c.form for c in effect_forms(family)
                 if c.voigt_spring is Effect.voigt_spring and not issubclass(c, PerSegmentEffect))


def draw_families(rng: np.random.Generator, index: int) -> list[str]:
    """The families bag ``index`` hides: ``index mod 3`` of them, distinct, at random."""
    count = index % 3
    return [str(f) for f in rng.choice(FAMILIES, size=count, replace=False)]


def draw_effect(rng: np.random.Generator, family: str, form: str, E: float, keep_time: float) -> dict[str, float]:
    """The simulator's hidden effect's parameters (its fields, ``effects.<id>.<name>``),
    from barely detectable to large."""
    if family == "relaxation_branch":
        arms = [_arm(rng, E, 1.0, keep_time / 3)] if form == "one_arm" else \
            [_arm(rng, E, 1.0, keep_time / 6), _arm(rng, E, keep_time / 4, keep_time / 2)]
        names = (("stiffness", "viscosity"), ("stiffness_2", "viscosity_2"))
        return {n: v for (ns, arm) in zip(names, arms) for n, v in zip(ns, arm)}
    if family == "adhesion":
        fraction = log_uniform(rng, 0.002, 0.4)
        return {"fraction": fraction} if form == "held" else {"fraction": fraction,
                                                              "time": log_uniform(rng, 10.0, 300.0)}
    if family == "strain_stiffening":
        return {"coefficient": log_uniform(rng, 0.02, 1.5 if form == "power_law" else 6.0)}
    if family == "sensor_drift":
        # Down to a hundredth of the total force's noise (7.2 mN at the defaults) over the
        # nodes: drawn from 3 mN a node up (draws 1), every drift was 10 x the noise or more
        # and no threshold could be read off them.
        sign = 1.0 if rng.random() < 0.5 else -1.0
        offset = log_uniform(rng, 1e-5, 0.3)
        if form == "settling":
            return {"offset": offset, "amplitude": sign * log_uniform(rng, 1e-5, 0.3),
                    "time": log_uniform(rng, 3.0, 60.0)}
        return {"offset": offset, "rate": sign * log_uniform(rng, 3e-7, 3e-3)}
    raise KeyError(family)


def _arm(rng: np.random.Generator, E: float, t_lo: float, t_hi: float) -> tuple[float, float]:
    """A Maxwell arm: stiffness log-uniform 0.3 %..50 % of E, relaxation time uniform in range."""
    stiffness = log_uniform(rng, 0.003, 0.5) * E
    return stiffness, stiffness * float(rng.uniform(t_lo, t_hi))


def draw_params(rng: np.random.Generator, noise_scale: float, quick: bool) -> dict[str, Any]:
    """A simulator bag's parameters without effects (flat, unchecked; module docstring)."""
    E = log_uniform(rng, 1e4, 1e5)
    return {
        "geometry": "uniaxial" if rng.random() < 0.2 else "plane_fe",
        "material.E": E,
        "material.c1": E * float(rng.uniform(2.0, 15.0)),
        "material.c2": E * float(rng.uniform(300.0, 3000.0)),
        "material.gamma": float(rng.uniform(0.2, 0.45)),
        "stage.depth": float(rng.uniform(0.005, 0.012)),
        "stage.keep_time": float(rng.uniform(*(QUICK_KEEP if quick else KEEP))),
        "stage.release_time": float(rng.uniform(*(QUICK_RELEASE if quick else RELEASE))),
        "tactile.noise": noise_scale * float(rng.uniform(60.0, 150.0)),
        "markers.noise": noise_scale * float(rng.uniform(1e-5, 3e-5)),
    }


def draw_bag(rng: np.random.Generator, index: int, noise_scale: float = 1.0, quick: bool = False
             ) -> tuple[list[dict[str, Any]], dict[str, Any], int]:
    """The ``index``-th simulator bag: its hidden effects (family, form, parameters), its
    flat parameters (effects included, unchecked) and the simulator's seed."""
    params = draw_params(rng, noise_scale, quick)
    hidden = []
    for family in draw_families(rng, index):
        form = str(rng.choice(simulator_forms(family)))
        values = draw_effect(rng, family, form, params["material.E"], params["stage.keep_time"])
        hidden.append({"effect": family, "form": form, "params": values})
        params |= {f"effects.{family}.form": form} | {f"effects.{family}.{k}": v for k, v in values.items()}
    params["simulator.effects"] = [h["effect"] for h in hidden] or [""]
    return hidden, params, int(rng.integers(0, 2**31 - 1))


def effect_size(setup: Setup, force_t: np.ndarray, marker_t: np.ndarray,
                effects: Sequence[Effect] | None = None) -> dict[str, float]:
    """The size of ``effects`` (default: all of ``setup``'s) at the force readings
    ``force_t``: the RMS of their change of the noise-free total bottom force (the
    forward model with the true parameters) over the total force's noise std;
    ``size_live``: the same with each segment's force through the dead band."""
    model = setup.model()
    effects = model.effects if effects is None else tuple(effects)
    if not effects:
        return {"size": 0.0, "size_live": 0.0}
    forward, profile, gamma = setup.forward_model(), setup.profile, setup.gamma
    with_effect = forward.predict(replace(model, effects=effects), gamma, profile, force_t, marker_t).force
    without = forward.predict(replace(model, effects=()), gamma, profile, force_t, marker_t).force
    tactile = setup.tactile
    noise_std = np.sqrt(tactile.rows * tactile.cols) * tactile.noise * tactile.cell_area
    out = {}
    for key, clip in (("size", False), ("size_live", True)):
        a, b = ((tactile.dead_band.reading(f) for f in (with_effect, without)) if clip
                else (with_effect, without))
        diff = a.sum(axis=1) - b.sum(axis=1)
        out[key] = float(np.sqrt(np.mean(diff**2)) / noise_std)
    return out


def expected_reading(tactile: TactileArray, force: np.ndarray) -> np.ndarray:
    """(T, nodes) N: the mean segment reading of the noisy sensor at segment forces
    ``force`` (T, nodes) N, spread evenly over each segment's cells as the simulator
    spreads them: per cell E[min(x 1(x >= threshold), saturation)] for x its pressure
    plus Gaussian noise (closed form), times its cells; 0 on a segment with no cells. A
    drift of a tenth of the noise on an idle cell under a 300 Pa band moves this mean
    where a noise-free reading stays at zero. The quantisation is left out: at a step of a
    tenth of the noise its mean bias is under 1e-3 of the step."""
    cells = tactile.cells_per_segment
    area = cells * tactile.cell_area
    p = np.divide(np.asarray(force, float), area, out=np.zeros(np.shape(force)), where=area > 0)
    s, low, high = tactile.noise, tactile.threshold, tactile.saturation
    if not s > 0.0:
        cell = np.where(p >= low, np.minimum(p, high), 0.0)
    else:
        z_low, z_high = (low - p) / s, (high - p) / s
        inside = ndtr(z_high) - ndtr(z_low)
        density = np.exp(-0.5 * z_low**2) - (np.exp(-0.5 * z_high**2) if np.isfinite(high) else 0.0)
        clipped = high * ndtr(-z_high) if np.isfinite(high) else 0.0
        cell = p * inside + s * density / np.sqrt(2.0 * np.pi) + clipped
    return cell * area


def separable_size(setup: Setup, force_t: np.ndarray, marker_t: np.ndarray, index: int) -> float:
    """The ``size_separable`` of ``setup``'s effect ``index`` (of ``setup.model().effects``)
    in a simulator bag (module docstring), as the generator's: its change of the expected
    total reading (``expected_reading``, over the total force's noise) and of the markers
    (means off, over the camera's noise) beside the other effects, less the best
    compensation by the base's parameters and the others' (the forward model refitted
    without it by ``least_squares``: each positive parameter times e^x, a signed one times
    1 + x, x within +-``SEPARABLE_LOG_MOVE``, the Poisson ratio under 1/2; a zero stays
    zero), the RMS over the force readings."""
    model, forward, profile, tactile = setup.model(), setup.forward_model(), setup.profile, setup.tactile
    force_std = np.sqrt(tactile.rows * tactile.cols) * tactile.noise * tactile.cell_area
    marker_std = setup.camera.noise

    def readings(m: Model, gamma: float) -> np.ndarray:
        p = forward.predict(m, gamma, profile, force_t, marker_t)
        markers = p.displacement - p.displacement.mean(axis=0)
        return np.concatenate([expected_reading(tactile, p.force).sum(axis=1) / force_std,
                               markers.ravel() / marker_std])

    target = readings(model, setup.gamma)
    without = replace(model, effects=model.effects[:index] + model.effects[index + 1:])
    truth = {**without.parameters, "gamma": setup.gamma}
    signed = set(without.signed_parameters)
    names = [k for k, v in truth.items() if np.isfinite(v) and v != 0.0]
    high = [min(SEPARABLE_LOG_MOVE, float(np.log(GAMMA_MAX / truth[k]))) if k == "gamma" else SEPARABLE_LOG_MOVE
            for k in names]

    def left(x: np.ndarray) -> np.ndarray:
        values = {**truth, **{k: truth[k] * (1.0 + float(v) if k in signed else float(np.exp(v)))
                              for k, v in zip(names, x)}}
        try:
            r = readings(without.with_parameters(values), values["gamma"]) - target
        except ValueError:   # a trial out of the model's range: no fit there
            return np.full(target.size, 1e6)
        return np.nan_to_num(r, nan=1e6, posinf=1e6, neginf=-1e6)

    fit = least_squares(left, np.zeros(len(names)), bounds=(-SEPARABLE_LOG_MOVE, high), diff_step=1e-4,
                        ftol=1e-4, xtol=1e-6, max_nfev=100)
    return float(np.sqrt(np.sum(fit.fun**2) / len(force_t)))


def simulator_bag(rng: np.random.Generator, index: int, out_dir: Path, noise_scale: float = 1.0,
                  quick: bool = False, limit: tuple[str, float] | None = None) -> dict[str, Any]:
    """The package's simulator as a bench source (:data:`BagSource`): draw, simulate and
    write bag ``index`` at ``out_dir``; its truth, each effect's size alone (only the
    catalogue's effects: no ``outside``). ``limit``: (family, readable size) of the one
    effect to hide (module docstring)."""
    if limit is None:
        hidden, params, seed = draw_bag(rng, index, noise_scale, quick)
        setup = Setup(check_params(params, f"bag {index}"))
        run = simulate_run(setup, seed)
    else:
        hidden, params, seed, setup, run = _limit_bag(rng, index, noise_scale, quick, *limit)
    write_run(run, {**setup.params, "simulator.seed": seed}, out_dir)
    for h, effect in zip(hidden, setup.model().effects):
        h |= effect_size(setup, run.tactile_t, run.marker_t, (effect,))
    info = {k: v for k, v in params.items() if not k.startswith(("effects.", "simulator."))}
    return {"hidden": hidden, **effect_size(setup, run.tactile_t, run.marker_t), "params_file": None,
            "info": info | {"seed": seed}}


def _limit_bag(rng: np.random.Generator, index: int, noise_scale: float, quick: bool, family: str, size: float
               ) -> tuple[list[dict[str, Any]], dict[str, Any], int, Setup, Any]:
    """``simulator_bag``'s bag for ``limit``: one effect of ``family`` (its form and values
    drawn as ``draw_bag`` draws them, the power law left out) with its ``LIMIT_AMPLITUDES``
    scaled by the secant on log size (within ``LIMIT_SCALES`` and ``LIMIT_CAPS``) until its
    readable size is within ``LIMIT_TOLERANCE`` of ``size``: the forward model at the bag's sample times at each step (as
    ``simulator_separable_sizes``), the simulator run once, on the last."""
    if family not in FAMILIES:
        raise ValueError(f"--limit: {family!r} is not one of the simulator's families ({', '.join(FAMILIES)})")
    params = draw_params(rng, noise_scale, quick)
    # Not the power law: its coefficient is an exponent, and as it falls to zero the stress
    # at zero strain stays zero, so its size does not fall with it (at 5e-7: 11.5 x).
    form = str(rng.choice([f for f in simulator_forms(family) if f != "power_law"]))
    values = draw_effect(rng, family, form, params["material.E"], params["stage.keep_time"])
    seed = int(rng.integers(0, 2**31 - 1))
    scale = 1.0
    top = min([LIMIT_CAPS[k] / abs(v) for k, v in values.items()
               if k in LIMIT_AMPLITUDES[family] and k in LIMIT_CAPS and v], default=np.inf)
    for _ in range(LIMIT_STEPS):
        scaled = {k: float(np.clip(v * scale, -LIMIT_CAPS.get(k, np.inf), LIMIT_CAPS.get(k, np.inf)))
                  if k in LIMIT_AMPLITUDES[family] else v for k, v in values.items()}   # the cap: not 1 + 2e-16
        flat = params | {f"effects.{family}.form": form} | {f"effects.{family}.{k}": v for k, v in scaled.items()} \
            | {"simulator.effects": [family]}
        setup = Setup(check_params(flat, f"bag {index}"))
        reached = effect_size(setup, sample_times(setup.profile.t_end, setup.params["rates.tactile"]),
                              sample_times(setup.profile.t_end, setup.params["rates.markers"]))["size_live"]
        if abs(reached / size - 1.0) <= LIMIT_TOLERANCE:
            break
        step = size / reached if reached > 0.0 else 10.0
        if not LIMIT_SCALES[0] <= scale * step <= LIMIT_SCALES[1]:
            break   # a saturated array reads no more of a larger effect: stop at the last try
        if scale * step > top:
            if scale >= top:
                break   # at its domain's edge (a fraction of 1) it reads no more
            step = top / scale
        scale *= step
    return [{"effect": family, "form": form, "params": scaled}], flat, seed, setup, simulate_run(setup, seed)


# --- any source: loading, checking, running one bag ---------------------------------

def load_source(path: str | Path | None) -> tuple[str, BagSource]:
    """The bench's source of bags: the package's simulator (``path`` None), or the
    :data:`PROTOCOL` function of the Python file at ``path`` (loaded by importlib, so the
    file need not be importable as a package). Its name: the module's ``GENERATOR_ID``,
    else the path.

    Raises:
        ValueError: the file cannot be loaded or defines no such function.
    """
    if path is None:
        return SIMULATOR, simulator_bag
    file = Path(path)
    module = _source_module(file)
    source = getattr(module, PROTOCOL, None)
    if not callable(source):
        raise ValueError(f"{file}: defines no function {PROTOCOL}(rng, index, out_dir, noise_scale, quick)")
    return str(getattr(module, "GENERATOR_ID", file)), source


def simulator_separable_sizes(rng: np.random.Generator, index: int, noise_scale: float = 1.0,
                              quick: bool = False) -> list[float]:
    """The simulator's :data:`SEPARABLE` function: each hidden effect's
    ``separable_size`` in bag ``index`` drawn from ``rng`` (``draw_bag``; nothing
    simulated: the forward model at the bag's sample times)."""
    _, params, _ = draw_bag(rng, index, noise_scale, quick)
    setup = Setup(check_params(params, f"bag {index}"))
    force_t = sample_times(setup.profile.t_end, setup.params["rates.tactile"])
    marker_t = sample_times(setup.profile.t_end, setup.params["rates.markers"])
    return [separable_size(setup, force_t, marker_t, i) for i in range(len(setup.model().effects))]


def separable_source(path: str | Path | None) -> Callable[..., list[float]] | None:
    """The :data:`SEPARABLE` function of the generator file at ``path`` (None: the
    package's simulator's), or None where it defines none."""
    if path is None:
        return simulator_separable_sizes
    found = getattr(_source_module(Path(path)), SEPARABLE, None)
    return found if callable(found) else None


def _source_module(file: Path) -> Any:
    """The Python file ``file``, loaded by importlib (it need not be importable as a package).

    Raises:
        ValueError: it is not a Python file that can be loaded.
    """
    name = f"rheo_bench_source_{file.stem}"
    spec = importlib.util.spec_from_file_location(name, file)
    if spec is None or spec.loader is None or not file.is_file():
        raise ValueError(f"{file}: not a Python file to load a bag source from")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module   # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


def check_truth(truth: dict[str, Any], index: int) -> dict[str, Any]:
    """A source's truth, checked: every hidden family and form is the package's, no
    family twice, sizes finite and non-negative. Raises ValueError naming the bag."""
    seen = set()
    for h in truth["hidden"]:
        try:
            effect_class(h["effect"], h["form"])
        except KeyError as exc:
            raise ValueError(f"bag {index}: hidden effect {h}: {exc}") from None
        if h["effect"] in seen:
            raise ValueError(f"bag {index}: family {h['effect']} hidden twice")
        seen.add(h["effect"])
    for item in (truth, *truth["hidden"]):
        if not all(np.isfinite(item[k]) and item[k] >= 0 for k in ("size", "size_live")):
            raise ValueError(f"bag {index}: sizes not finite and non-negative: {item}")
    return truth


def force_rms_to_noise(fit: Any) -> tuple[float, int]:
    """The fit's total-force residual RMS over the total force's noise, pooled over the
    phases (the comparison's ``total`` signal: readings where every segment is live), and
    the readings it is taken over."""
    stats = [s for s in fit.comparison.stats if s.signal == "total" and s.samples and s.noise > 0]
    if not stats:
        return float("nan"), 0
    n = np.array([s.samples for s in stats], float)
    return float(np.sqrt(np.sum(n * np.array([s.rms for s in stats]) ** 2) / n.sum()) / stats[0].noise), int(n.sum())


def fit_limit(readings: int | None) -> float:
    """The largest clean-bag ``force_rms_to_noise`` over ``readings`` that counts as a fit
    within the noise: ``FIT_LIMIT``, or ``FIT_SAMPLING_SIGMAS`` sampling stds above 1 where
    the readings are too few for that (None: a row that did not count them)."""
    if not readings:
        return FIT_LIMIT
    return max(FIT_LIMIT, 1.0 + FIT_SAMPLING_SIGMAS / np.sqrt(2.0 * readings))


def outside_outcome(named: Iterable[str], explained: bool | None, undecided: bool = False,
                    failed: bool = False) -> str:
    """One of :data:`OUTSIDE_OUTCOMES` for a bag hiding an effect in no catalogue."""
    if failed:
        return "failed"
    if list(named):
        return "wrong"
    if undecided:
        return "undecided"
    return "unexplained" if explained is False else "missed"


def outcome(hidden: Iterable[str], named: Iterable[str], undecided: bool = False, failed: bool = False,
            explained: bool | None = None) -> str:
    """One of :data:`OUTCOMES` for a bag hiding the families ``hidden`` where the loop
    named ``named`` (``undecided``: it ended unable to decide; ``failed``: no analysis;
    ``explained`` False: it said the catalogue does not explain the data, which for a
    catalogue's bag is not the answer even when nothing wrong was named)."""
    hidden, named = set(hidden), set(named)
    if failed:
        return "failed"
    if undecided:
        return "undecided"
    if named - hidden:
        return "extra"
    if explained is False:
        return "unexplained"
    return "exact" if named == hidden else "missed"


def run_bag(source: BagSource, index: int, rng: np.random.Generator, directory: Path,
            noise_scale: float = 1.0, quick: bool = False, outside: bool = False,
            limit: tuple[str, float] | None = None) -> dict[str, Any]:
    """Make, analyse and delete one bag; its row of the result (module docstring).
    ``hidden`` stays None when the source fails: what it hid is not known. ``outside``:
    the source hides an effect in no catalogue (``outside`` in the row, scored by
    :func:`outside_outcome`). ``limit``: (family, readable size) of the one effect the
    source hides (``--limit``; the row keeps the target as ``limit_size``)."""
    row: dict[str, Any] = {
        "index": index, "hidden": None, "outside": [], "size": 0.0, "size_live": 0.0, "info": {}, "named": [],
        "forms": {}, "undecided": [], "explained": None, "outcome": "failed", "force_rms_to_noise": None,
        "force_rms_readings": 0,
        "evidence": "", "make_seconds": 0.0, "seconds": 0.0, "message": "",
    }
    scratch = directory / f"bag{index:04d}"
    scratch.mkdir()
    try:
        t0 = time.perf_counter()
        if outside:
            made = source(rng, index, scratch / "bag", noise_scale, quick, outside=True)
        elif limit is not None:
            made = source(rng, index, scratch / "bag", noise_scale, quick, limit=limit)
            row["limit_size"] = limit[1]
        else:
            made = source(rng, index, scratch / "bag", noise_scale, quick)
        truth = check_truth(made, index)
        row |= {k: truth[k] for k in ("hidden", "size", "size_live")} | {"info": truth.get("info", {}),
                                                                          "outside": truth.get("outside", [])}
        row["make_seconds"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            analysis = analyze(scratch / "bag", params_file=truth.get("params_file"))
        finally:
            row["seconds"] = time.perf_counter() - t0
        undecided = list(analysis.diagnoses[-1].undecided) if analysis.diagnoses else []
        verdict = Verdict.of(analysis.diagnoses) if analysis.diagnoses else None
        explained = verdict.explained if verdict else None
        ratio, readings = force_rms_to_noise(analysis.final)
        row |= {"named": list(analysis.missing_effects), "forms": dict(analysis.final.forms),
                "undecided": undecided, "explained": explained, "force_rms_to_noise": ratio,
                "force_rms_readings": readings,
                "evidence": verdict.evidence if verdict else "",   # with the final verdict's why, when unexplained
                "outcome": outside_outcome(analysis.missing_effects, explained, bool(undecided)) if row["outside"]
                else outcome((h["effect"] for h in row["hidden"]), analysis.missing_effects, bool(undecided),
                             explained=explained)}
    except REFUSALS as exc:
        row["message"] = f"{type(exc).__name__}: {exc}"
        if row["hidden"] is not None:   # a bag made right that the package declined: its answer
            row["outcome"] = "refused"
    except Exception as exc:  # noqa: BLE001 - one bag must not end a long bench
        row["message"] = f"unexpected {type(exc).__name__}: {exc}"
        traceback.print_exc(file=sys.stderr)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return row


# --- scoring ----------------------------------------------------------------------

def detection_threshold(items: Iterable[tuple[float, bool]], target: float) -> dict[str, Any]:
    """The smallest size ``s`` among ``items`` (size, correct) such that at least
    ``target`` of the items of size ``s`` or more are correct; None when even the
    largest alone is wrong. With the counts above and below it, and the largest wrong
    size below it (``missed_below``; None: none): the threshold lies between the two, the
    bags drawn say no closer. Bags of one size fall on one side together: nine held
    adhesions wholly under the dead band (readable size 0) are all above a threshold of 0,
    the six named and the three missed alike."""
    ordered = sorted(items, key=lambda x: x[0])
    correct = np.array([c for _, c in ordered], dtype=float)
    for k in range(len(ordered)):
        if k and ordered[k][0] == ordered[k - 1][0]:
            continue
        above = correct[k:]
        if above.mean() >= target:
            wrong = [size for size, c in ordered[:k] if not c]
            return {"threshold": ordered[k][0], "bags_above": int(above.size), "correct_above": int(above.sum()),
                    "bags_below": k, "correct_below": int(correct[:k].sum()),
                    "missed_below": wrong[-1] if wrong else None}
    return {"threshold": None, "bags_above": 0, "correct_above": 0,
            "bags_below": len(ordered), "correct_below": int(correct.sum()), "missed_below": None}


def thresholds(rows: list[dict[str, Any]], target: float, size: str = "size_live",
               forms: bool = True) -> dict[str, dict[str, Any]]:
    """:func:`detection_threshold` of exact-set correctness against the readable size (or
    ``size``: ``size``, the whole, with what the dead band hides), over the single-effect
    bags of each family, and of each form (``family:form``) with ``forms``."""
    single = [r for r in rows if r["hidden"] and len(r["hidden"]) == 1]
    groups: dict[str, list[tuple[float, bool]]] = {}
    for r in single:
        h = r["hidden"][0]
        item = (h[size], r["outcome"] == "exact")
        for key in (h["effect"], f"{h['effect']}:{h['form']}") if forms else (h["effect"],):
            groups.setdefault(key, []).append(item)
    return {key: detection_threshold(items, target) for key, items in sorted(groups.items())}


def above_thresholds(row: dict[str, Any], family_thresholds: dict[str, dict[str, Any]],
                     size: str = "size_live") -> bool:
    """Whether each of the bag's hidden effects is at or above its family's threshold by its
    readable size (or ``size``; a family with no threshold: not above)."""
    def above(h: dict[str, Any]) -> bool:
        th = family_thresholds.get(h["effect"], {}).get("threshold")
        return th is not None and h[size] >= th
    return all(above(h) for h in row["hidden"])


def separable_scores(rows: list[dict[str, Any]], target: float) -> dict[str, Any]:
    """The thresholds and the accuracy above and below them by ``size_separable`` (module
    docstring), where every hidden effect has one; else empty."""
    effect_rows = [r for r in rows if r["hidden"]]
    if not effect_rows or not all("size_separable" in h for r in effect_rows for h in r["hidden"]):
        return {}
    per, above, below = _split_by_thresholds(rows, target, "size_separable")
    return {"thresholds_separable": per, "above_separable": _accuracy(above), "below_separable": _accuracy(below)}


def detectable_scores(rows: list[dict[str, Any]], readable: dict[str, dict[str, Any]],
                      separable: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The accuracy over the bags each of whose hidden effects is above its family's
    threshold by both sizes: the sensor reads it (``size_live``) and the rest of the truth
    cannot make it (``size_separable``). Either alone lets a pair count as above that
    the data cannot tell: an effect the sensor reads well can be one the others take up
    whole (a settling drift's curve in the pull beside a stiffening), and a separable one
    can sit under the dead band. Empty where the rows lack separable sizes."""
    if not separable:
        return {}
    families = {k: v for k, v in separable.items() if ":" not in k}
    effect_rows = [r for r in rows if r["hidden"]]
    both = [r for r in effect_rows if above_thresholds(r, readable) and above_thresholds(r, families, "size_separable")]
    return {"above_detectable": _accuracy(both), "below_detectable": _accuracy([r for r in effect_rows if r not in both])}


def _split_by_thresholds(rows: list[dict[str, Any]], target: float, size: str,
                         threshold_rows: list[dict[str, Any]] | None = None
                         ) -> tuple[dict[str, dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    """The thresholds by ``size`` (:func:`thresholds`, over ``threshold_rows``; None:
    ``rows``) and the rows with hidden effects above every family's and the rest."""
    per = thresholds(rows if threshold_rows is None else threshold_rows, target, size)
    families = {k: v for k, v in per.items() if ":" not in k}
    effect_rows = [r for r in rows if r["hidden"]]
    above = [r for r in effect_rows if above_thresholds(r, families, size)]
    return per, above, [r for r in effect_rows if r not in above]


def _accuracy(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Bags, exact among them, and each outcome's count."""
    counts = {o: sum(r["outcome"] == o for r in rows) for o in OUTCOMES}
    return {"bags": len(rows), "exact": counts["exact"],
            "accuracy": counts["exact"] / len(rows) if rows else None, "outcomes": counts}


def form_scores(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, int]]]:
    """For each hidden effect the loop named: family -> hidden form -> named form -> bags."""
    out: dict[str, dict[str, dict[str, int]]] = {}
    for r in rows:
        for h in r["hidden"] or ():
            if h["effect"] in r["named"]:
                named = r["forms"].get(h["effect"], "?")
                counts = out.setdefault(h["effect"], {}).setdefault(h["form"], {})
                counts[named] = counts.get(named, 0) + 1
    return out


def score(rows: list[dict[str, Any]], target: float) -> dict[str, Any]:
    """Every figure of the bench from its rows (module docstring); a bag whose source
    failed (``hidden`` None) counts in ``failed`` alone; a bag the analysis declined counts in
    ``refused``, and among its kind's bags as not exact (a clean one is no false claim).
    Bags of a limit run (``limit_size``) pooled with random draws join the single-effect
    bags that set the thresholds and nothing else: the accuracies, the clean bags and the
    forms are the random draws' (a limit run alone: its own)."""
    failed = sum(r["outcome"] == "failed" for r in rows)
    refused = sum(r["outcome"] == "refused" for r in rows)
    outside = [r for r in rows if r["outside"]]
    rows = [r for r in rows if r["hidden"] is not None and not r["outside"]]
    singles = rows
    rows = [r for r in rows if "limit_size" not in r] or rows
    effect_rows = [r for r in rows if r["hidden"]]
    clean = [r for r in rows if not r["hidden"] and r["outcome"] not in NO_ANSWER]
    per, above, below = _split_by_thresholds(rows, target, "size_live", singles)
    whole = thresholds(singles, target, "size", forms=False)
    separable = separable_scores(rows, target)
    weakest = [(min(h["size_live"] for h in r["hidden"]), r["outcome"] == "exact") for r in effect_rows]
    forms = form_scores(rows)
    fitted = [r for r in clean if r["force_rms_to_noise"] is not None and np.isfinite(r["force_rms_to_noise"])]
    fits = [r["force_rms_to_noise"] for r in fitted]
    return {
        "target": target,
        "by_hidden": {n: _accuracy([r for r in rows if len(r["hidden"]) == n]) for n in (0, 1, 2)},
        "thresholds": per,
        # An effect wholly under the dead band has a readable size of 0: the whole size says
        # how far below the band it is still found.
        "thresholds_whole": whole,
        "threshold_weakest": detection_threshold(weakest, target),
        "above": _accuracy(above), "below": _accuracy(below),
        **separable,
        **detectable_scores(rows, {k: v for k, v in per.items() if ":" not in k},
                            separable.get("thresholds_separable", {})),
        "limit_bags": len(singles) - len(rows),
        "forms": forms,
        "forms_right": sum(c.get(f, 0) for fam in forms.values() for f, c in fam.items()),
        "forms_named": sum(sum(c.values()) for fam in forms.values() for c in fam.values()),
        "clean_bags": len(clean),
        "false_claims_on_clean": sum(bool(r["named"]) for r in clean),
        "undecided_on_clean": sum(r["outcome"] == "undecided" for r in clean),
        "unexplained_on_clean": sum(r["outcome"] == "unexplained" for r in clean),
        "clean_fit_median": float(np.median(fits)) if fits else None,
        "clean_fit_max": float(np.max(fits)) if fits else None,
        "clean_fit_within": sum(r["force_rms_to_noise"] <= fit_limit(r.get("force_rms_readings")) for r in fitted),
        "clean_fit_max_readings": (max(fitted, key=lambda r: r["force_rms_to_noise"]).get("force_rms_readings")
                                   if fitted else None),
        "failed": failed,
        "refused": refused,
        "outside": {"bags": len(outside),
                    "outcomes": {o: sum(r["outcome"] == o for r in outside) for o in OUTSIDE_OUTCOMES},
                    "by_effect": {e: {o: sum(r["outcome"] == o for r in outside if r["outside"][0]["effect"] == e)
                                      for o in OUTSIDE_OUTCOMES}
                                  for e in sorted({r["outside"][0]["effect"] for r in outside})}},
    }


def run(replicates: int = 100, seed: int = 0, quick: bool = False, noise_scale: float = 1.0,
        generator: str | None = None, target: float | None = None, plot: str | None = None,
        outside: bool = False, merge: str | None = None, limit: str | None = None) -> dict[str, Any]:
    """Make, analyse and score ``replicates`` bags from the source ``generator`` (a file
    defining :data:`PROTOCOL`; None: the package's simulator). Bag ``i`` draws from
    ``default_rng((seed, i))``. ``target``: default by the noise (:func:`default_target`);
    ``plot``: also write :func:`plot_accuracy` there; ``outside``: every bag hides an
    effect in no catalogue instead. ``merge``: comma-separated JSON files of earlier runs
    (``--json``) to score together instead (:func:`merged`): no bag is made; with
    ``generator``, its :data:`SEPARABLE` function gives the bags' separable sizes the runs
    lack. ``limit``: ``FAMILY:LO:HI``, every bag hides one effect of that family at a
    readable size drawn log-uniform in [LO, HI] from ``default_rng((seed, i, 1))`` (module
    docstring; no separable sizes)."""
    if merge:
        result = merged([Path(f) for f in merge.split(",") if f], target,
                        separable_source(generator) if generator else None)
        if plot:
            plot_accuracy(result, plot)
            result["plot"] = str(plot)
        return result
    if outside and generator is None:
        raise ValueError("--outside: the package's simulator has only the catalogue's effects; give --generator")
    if outside and limit:
        raise ValueError("--limit: the bags hide one effect of the catalogue; --outside hides none of them")
    sizes = parse_limit(limit) if limit else None
    name, source = load_source(generator)
    separable = None if sizes else separable_source(generator)
    target = default_target(noise_scale) if target is None else target
    rows = []
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rheo-bench-diagnosis-") as tmp:
        for i in range(replicates):
            at = None if sizes is None else \
                (sizes[0], log_uniform(np.random.default_rng((seed, i, 1)), sizes[1], sizes[2]))
            row = run_bag(source, i, np.random.default_rng((seed, i)), Path(tmp), noise_scale, quick, outside, at)
            if separable is not None:
                row = _with_separable(row, separable, noise_scale, quick, seed)
            rows.append(row)
            print(f"bag {i} ({i + 1}/{replicates}): hidden {_hidden_text(row)}, size {row['size']:.3g} "
                  f"(readable {row['size_live']:.3g}), named {'+'.join(row['named']) or 'none'}: {row['outcome']}, "
                  f"{row['make_seconds']:.1f} + {row['seconds']:.1f} s"
                  + (f" ({row['message']})" if row["message"] else ""), file=sys.stderr, flush=True)
    result = {
        "source": name, "generator": generator, "replicates": replicates, "seed": seed, "quick": quick,
        "outside_catalogue": outside, **({"draws": SIMULATOR_DRAWS} if generator is None else {}),
        **({"limit": limit} if limit else {}),
        "noise_scale": noise_scale, **score(rows, target), **_times(rows, time.perf_counter() - t_start),
        "bags": rows,
    }
    if plot:
        plot_accuracy(result, plot)
        result["plot"] = str(plot)
    return result


# What runs pooled must share. A limit run (``--limit``) pools with random draws of its
# source and noise: its bags join the single-effect bags that set the thresholds (``score``).
MERGED_AS_ONE = ("source", "noise_scale", "quick", "outside_catalogue")


def parse_limit(text: str) -> tuple[str, float, float]:
    """``FAMILY:LO:HI`` (``--limit``) as (family, lo, hi).

    Raises:
        ValueError: names what is wrong with it."""
    parts = text.split(":")
    try:
        family, lo, hi = parts[0], float(parts[1]), float(parts[2])
    except (IndexError, ValueError):
        raise ValueError(f"--limit {text!r}: give FAMILY:LO:HI, e.g. strain_stiffening:1.5:6") from None
    if len(parts) != 3 or family not in FAMILIES or not 0.0 < lo <= hi < np.inf:
        raise ValueError(f"--limit {text!r}: FAMILY one of {', '.join(FAMILIES)}, 0 < LO <= HI (readable sizes "
                         "x the total-force noise)")
    return family, lo, hi


def merged(paths: list[Path], target: float | None = None,
           separable: Callable[..., list[float]] | None = None) -> dict[str, Any]:
    """The runs' bags (their ``--json`` files) scored as one bench: a long bench made in
    parts (sessions, machines), each part its own seed. The runs must share the source,
    the noise, the records' length and the kind of bags (``MERGED_AS_ONE``), and no two
    may hold the same bags (one seed twice); limit runs among random draws set thresholds
    only (``score``). ``separable``: the source's
    :data:`SEPARABLE` function, which gives each bag's hidden effects the separable size
    a run made before it existed lacks (the bag drawn again, nothing analysed); the
    simulator's runs get the simulator's without asking.

    Raises:
        ValueError: names the file and what differs, or the seed met twice."""
    runs = [json.loads(path.read_text()) for path in paths]
    if not runs:
        raise ValueError("--merge: no file given")
    first, seeds = runs[0], {}
    for path, r in zip(paths, runs):
        for key in MERGED_AS_ONE:
            if r.get(key) != first.get(key):
                raise ValueError(f"--merge: {path}: {key} is {r.get(key)!r}, {paths[0]} has {first.get(key)!r}: "
                                 "only runs of one bench pool")
        for seed in np.atleast_1d(r["seed"]).tolist():
            if seed in seeds:
                raise ValueError(f"--merge: {path} and {seeds[seed]} both hold seed {seed}'s bags")
            seeds[seed] = path
    # A bag is named by its run's seed and its index (``_bag_name``); a merged run's keep theirs.
    rows = [_rescored({"seed": r["seed"], **row}) for r in runs for row in r["bags"]]
    redrawn = set(seeds)
    if first.get("source") == SIMULATOR:
        if separable not in (None, simulator_separable_sizes):
            raise ValueError(f"--merge: {paths[0]}: the package's simulator's runs; their separable sizes are the "
                             "simulator's (leave out --generator)")
        separable = simulator_separable_sizes
        redrawn = {s for r in runs if r.get("draws", 1) == SIMULATOR_DRAWS for s in np.atleast_1d(r["seed"]).tolist()}
        if len(redrawn) < len(seeds):
            print(f"--merge: the simulator drew the bags of seed(s) {', '.join(str(s) for s in seeds if s not in redrawn)} "
                  f"before its draws {SIMULATOR_DRAWS}: they cannot be drawn again for their separable sizes; where "
                  "a bag lacks them, the scores by the separable size are left out", file=sys.stderr)
    if separable is not None:
        filled = []
        for k, row in enumerate(rows):   # tens of seconds a bag with effects: said as it goes
            if row["seed"] not in redrawn or "limit_size" in row:   # a limit bag is scaled: not its draw
                filled.append(row)
                continue
            filled.append(_with_separable(row, separable, first["noise_scale"], bool(first.get("quick")), row["seed"]))
            if filled[-1] is not row:
                print(f"{_bag_name(row)} ({k + 1}/{len(rows)}): separable sizes "
                      + ", ".join(f"{h['effect']} {h['size_separable']:.3g}" for h in filled[-1]["hidden"]),
                      file=sys.stderr, flush=True)
        rows = filled
    target = default_target(first["noise_scale"]) if target is None else target
    return {
        **{key: first.get(key) for key in MERGED_AS_ONE}, "generator": first.get("generator"),
        **({"draws": first["draws"]} if "draws" in first and all(r.get("draws") == first["draws"] for r in runs)
           else {}),
        "replicates": len(rows), "seed": list(seeds), "runs": [str(p) for p in paths],
        **({"limits": limits} if (limits := sorted({r["limit"] for r in runs if r.get("limit")})) else {}),
        **score(rows, target), **_times(rows, float(sum(r["total_seconds"] for r in runs))),
        "bags": rows,
    }


def _with_separable(row: dict[str, Any], separable: Callable[..., list[float]], noise_scale: float,
                    quick: bool, seed: int) -> dict[str, Any]:
    """``row`` with each hidden effect's ``size_separable`` (from ``separable``, its bag
    drawn again from ``default_rng((seed, index))``) where it lacks one."""
    if not row["hidden"] or all("size_separable" in h for h in row["hidden"]):
        return row
    sizes = separable(np.random.default_rng((seed, row["index"])), row["index"], noise_scale, quick)
    if len(sizes) != len(row["hidden"]):
        raise ValueError(f"{_bag_name(row)}: {SEPARABLE} gave {len(sizes)} sizes for {len(row['hidden'])} hidden effects")
    return {**row, "hidden": [{**h, "size_separable": float(size)} for h, size in zip(row["hidden"], sizes)]}


def _rescored(row: dict[str, Any]) -> dict[str, Any]:
    """A row of a run made before ``refused`` and ``unexplained`` existed, scored as
    ``run_bag`` now does."""
    if row["hidden"] is None or row.get("outside") or row["outcome"] == "refused":
        return row   # a refusal has no analysis to score again
    if row["outcome"] == "failed":
        refused = row["message"].split(":")[0] in {e.__name__ for e in REFUSALS}
        return {**row, "outcome": "refused"} if refused else row
    return {**row, "outcome": outcome((h["effect"] for h in row["hidden"]), row["named"], bool(row["undecided"]),
                                      explained=row.get("explained"))}


def _times(rows: list[dict[str, Any]], total: float) -> dict[str, float | None]:
    """The bench's times: analysis median and max over the bags analysed, making median."""
    analysed = [r["seconds"] for r in rows if r["outcome"] not in NO_ANSWER]
    return {"seconds_median": float(np.median(analysed)) if analysed else None,
            "seconds_max": float(np.max(analysed)) if analysed else None,
            "make_seconds_median": float(np.median([r["make_seconds"] for r in rows])) if rows else None,
            "total_seconds": total}


# --- output -----------------------------------------------------------------------

def _hidden_text(row: dict[str, Any]) -> str:
    if row["outside"]:
        return "+".join(f"{h['effect']} (no catalogue)" for h in row["outside"])
    if row["hidden"] is None:
        return "unknown"
    return "+".join(f"{h['effect']}:{h['form']}" for h in row["hidden"]) or "none"


def _seeds(seed: int | list[int]) -> str:
    seeds = [seed] if isinstance(seed, int) else list(seed)
    return ("seed " if len(seeds) == 1 else "seeds ") + ", ".join(map(str, seeds))


def _bag_name(row: dict[str, Any]) -> str:
    """``bag INDEX``, or ``bag SEED:INDEX`` in runs merged (``merged``)."""
    return f"bag {row['seed']}:{row['index']}" if "seed" in row else f"bag {row['index']}"


def _fraction(k: int, n: int) -> str:
    return f"{k}/{n}" + (f" ({100 * k / n:.1f} %)" if n else "")


def _threshold_line(key: str, th: dict[str, Any]) -> str:
    at = "none" if th["threshold"] is None else f"{th['threshold']:.3g}"
    missed = th.get("missed_below")
    since = f" (largest miss below: {missed:.3g})" if missed is not None else ""
    return (f"  {key:<36} threshold {at:>6}: {th['correct_above']}/{th['bags_above']} exact above, "
            f"{th['correct_below']}/{th['bags_below']} below{since}")


def format_outside(result: dict[str, Any]) -> str:
    """The out-of-catalogue bench's figures as text (``--outside``)."""
    out = result["outside"]
    n = out["bags"]
    lines = [f"diagnosis over {result['replicates']} bags from {result['source']}, each hiding one effect in no "
             f"catalogue ({_seeds(result['seed'])}, noise x {result['noise_scale']:g}"
             + (", quick records" if result.get("quick") else "") + ")",
             f"  {'effect':<16}{'bags':>6}" + "".join(f"{o:>13}" for o in OUTSIDE_OUTCOMES)]
    for effect, counts in {**out["by_effect"], "all": out["outcomes"]}.items():
        lines.append(f"  {effect:<16}{sum(counts.values()):>6}" + "".join(f"{counts[o]:>13}" for o in OUTSIDE_OUTCOMES))
    wrong = out["outcomes"]["wrong"]
    lines.append(f"a wrong effect named: {_fraction(wrong, n)} (at most {100 * WRONG_LIMIT:.0f} % wanted); "
                 f"said the catalogue does not explain them: {_fraction(out['outcomes']['unexplained'], n)}; "
                 f"called adequate (nothing seen): {_fraction(out['outcomes']['missed'], n)}")
    if result["seconds_median"] is not None:
        lines.append(f"time per bag: analysis median {result['seconds_median']:.1f} s, max {result['seconds_max']:.1f} s; "
                     f"total {result['total_seconds'] / 60:.1f} min")
    for r in sorted(result["bags"], key=lambda r: -max((h["size"] for h in r["outside"]), default=0.0)):
        if r["outcome"] != "unexplained":
            h = r["outside"][0] if r["outside"] else {"effect": "?", "size": float("nan"), "signal": "?"}
            lines.append(f"  {_bag_name(r)}: {h['effect']} (size {h['size']:.3g} x the {h['signal']} noise) -> "
                         f"{'+'.join(r['named']) or 'none'}: {r['outcome']}" + (f": {r['message']}" if r["message"] else ""))
    return "\n".join(lines)


def format_table(result: dict[str, Any]) -> str:
    """The bench's figures as text (what docs/bench keeps)."""
    if result.get("outside_catalogue"):
        return format_outside(result)
    target = 100 * result["target"]
    lines = [f"diagnosis over {result['replicates']} bags from {result['source']} ({_seeds(result['seed'])}, noise x "
             f"{result['noise_scale']:g}" + (", quick records" if result.get("quick") else "") + ")",
             "exact-set accuracy (the effects named are the hidden ones, nothing extra) by effects hidden:",
             f"  {'hidden':<10}{'bags':>6}" + "".join(f"{o:>12}" for o in OUTCOMES) + f"{'accuracy':>11}"]
    for n, acc in result["by_hidden"].items():
        share = "-" if acc["accuracy"] is None else f"{100 * acc['accuracy']:.1f} %"
        lines.append(f"  {n:<10}{acc['bags']:>6}" + "".join(f"{acc['outcomes'][o]:>12}" for o in OUTCOMES)
                     + f"{share:>11}")
    lines.append(f"detection threshold (readable size x the total-force noise; {target:.0f} % exact above it; "
                 "single-effect bags):")
    lines += [_threshold_line(key, th) for key, th in result["thresholds"].items()]
    lines.append(_threshold_line("any bag, by its weakest effect", result["threshold_weakest"]))
    if "thresholds_whole" in result:
        lines.append("by the whole size (with what the dead band hides): " + "; ".join(
            f"{key} {'none' if th['threshold'] is None else format(th['threshold'], '.3g')} "
            f"({th['correct_above']}/{th['bags_above']} exact above)" for key, th in result["thresholds_whole"].items()))
    lines.append(f"bags with every effect above its family's threshold: {_fraction(result['above']['exact'], result['above']['bags'])} "
                 f"exact; below: {_fraction(result['below']['exact'], result['below']['bags'])}")
    if result.get("limit_bags"):
        lines.append(f"  (the thresholds with {result['limit_bags']} single-effect bags of limit runs: "
                     f"{', '.join(result.get('limits', []))}; every other figure from the random draws)")
    if "thresholds_separable" in result:
        lines.append("by the separable size (what the rest of the truth cannot take up): thresholds " + "; ".join(
            f"{key} {'none' if th['threshold'] is None else format(th['threshold'], '.3g')} "
            f"({th['correct_above']}/{th['bags_above']} exact above)"
            for key, th in result["thresholds_separable"].items() if ":" not in key)
            + f"; bags with every effect above: {_fraction(result['above_separable']['exact'], result['above_separable']['bags'])} "
            f"exact; below: {_fraction(result['below_separable']['exact'], result['below_separable']['bags'])}")
    if "above_detectable" in result:
        lines.append("bags with every effect above both its family's thresholds (the sensor reads it and the rest of "
                     f"the truth cannot make it): {_fraction(result['above_detectable']['exact'], result['above_detectable']['bags'])} "
                     f"exact; below: {_fraction(result['below_detectable']['exact'], result['below_detectable']['bags'])}")
    lines.append(f"forms, where the family was named: {_fraction(result['forms_right'], result['forms_named'])} right "
                 "(" + "; ".join(f"{fam}:{hid} -> " + ", ".join(f"{f} {n}" for f, n in named.items())
                                 for fam, by in result["forms"].items() for hid, named in by.items()) + ")")
    lines.append(f"clean bags: false claims {result['false_claims_on_clean']}/{result['clean_bags']}, undecided "
                 f"{result['undecided_on_clean']}, unexplained {result.get('unexplained_on_clean', 0)}; final force RMS / noise (live readings) "
                 + ("-" if result["clean_fit_median"] is None else
                    f"median {result['clean_fit_median']:.3f}, max {result['clean_fit_max']:.3f} (over "
                    f"{result.get('clean_fit_max_readings') or '?'} readings), {result['clean_fit_within']} within "
                    f"{FIT_LIMIT} or {FIT_SAMPLING_SIGMAS:g} sampling std of 1"))
    lines.append(f"bags refused with a one-line error: {result.get('refused', 0)}; failed bags: {result['failed']}")
    if result["seconds_median"] is not None:
        lines.append(f"time per bag: analysis median {result['seconds_median']:.1f} s, max {result['seconds_max']:.1f} s; "
                     f"making median {result['make_seconds_median']:.1f} s; total {result['total_seconds'] / 60:.1f} min")
    wrong = [r for r in result["bags"] if r["outcome"] != "exact"]
    if wrong:
        lines.append("not exact:")
        for r in sorted(wrong, key=lambda r: -r["size_live"]):
            sizes = ", ".join(f"{h['effect']} {h['size_live']:.3g}"
                              + (f" [{h['size_separable']:.3g}]" if "size_separable" in h else "")
                              for h in r["hidden"] or ())
            lines.append(f"  {_bag_name(r)}: {_hidden_text(r)} (readable {sizes or '0'}) -> "
                         f"{'+'.join(r['named']) or 'none'}: {r['outcome']}"
                         + (f" [{', '.join(r['undecided'])}]" if r["undecided"] else "")
                         + (f": {r['message']}" if r["message"] else ""))
    return "\n".join(lines)


def accuracy_curves(rows: list[dict[str, Any]], bins: int = 8) -> dict[str, list[tuple[float, float, int]]]:
    """Exact-set accuracy against readable size, binned in log: per family over its
    single-effect bags (that effect's size), and over the two-effect bags (their weakest
    effect's). Each curve: (geometric mean size of the bin's bags, accuracy, bags) for
    the bins with bags. Unreadable effects (size 0) have no place on a log axis: left
    out (``format_table`` lists them)."""
    groups: dict[str, list[tuple[float, bool]]] = {}
    for r in rows:
        if r["outcome"] in NO_ANSWER or not r["hidden"]:   # no answer, unknown or clean
            continue
        size = min(h["size_live"] for h in r["hidden"])
        if size > 0:
            key = r["hidden"][0]["effect"] if len(r["hidden"]) == 1 else "two effects (weakest)"
            groups.setdefault(key, []).append((size, r["outcome"] == "exact"))
    if not groups:
        return {}
    sizes = [s for items in groups.values() for s, _ in items]
    edges = np.geomspace(min(sizes) * 0.999, max(sizes) * 1.001, bins + 1)
    curves = {}
    for key, items in sorted(groups.items()):
        s = np.array([x for x, _ in items])
        ok = np.array([c for _, c in items], float)
        which = np.digitize(s, edges) - 1
        curves[key] = [(float(np.exp(np.mean(np.log(s[which == b])))), float(ok[which == b].mean()),
                        int((which == b).sum())) for b in range(bins) if (which == b).any()]
    return curves


def plot_accuracy(result: dict[str, Any], path: str | Path) -> None:
    """Exact-set accuracy against readable effect size, per family (``accuracy_curves``),
    with the issue's 3 x noise and the target; PNG or SVG by ``path``'s suffix (Agg)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

    fig = Figure(figsize=(7.0, 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for key, curve in accuracy_curves(result["bags"]).items():
        x, y, n = zip(*curve)
        ax.plot(x, y, marker="o", alpha=0.8, label=f"{key} ({sum(n)} bags)")
    ax.axvline(3.0, color="grey", linestyle=":", label="3 x noise (target threshold)")
    ax.axhline(result["target"], color="grey", linestyle="--", label=f"{100 * result['target']:.0f} % target")
    ax.set_xscale("log")
    # Labels at 1 and 3 of each decade: every minor tick labelled ran into each other.
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 3.0)))
    ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel("readable effect size (x total-force noise std)")
    ax.set_ylabel("exact-set accuracy")
    ax.set_title(f"{result['source']}: {result['replicates']} bags, noise x {result['noise_scale']:g}", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(str(path))
