"""A second data generator that shares no code with rheo_ros (issue 20, item 4).

It writes bags in the public format of the interface contract ("Topics",
"Recorded bags", "Parameters file") from its own physics and its own sensor models, so
that an accuracy figure can be checked against data the package did not make itself.
Every figure made from these bags should say "generator: test/generator.py".

Physics, written from the model's definition: a homogeneous block W x H x T between
frictionless faces, so stress and strain are uniform and uniaxial. Strain eps = s / H
with s the top's sinking. Three-element model: a Voigt element (spring E, dashpot c1 in
parallel) in series with a dashpot c2; eps = eps_v + eps_d and

    sigma = E eps_v + c1 d(eps_v)/dt = c2 d(eps_d)/dt.

While the stage touches the top, eps is prescribed and eps_d is integrated with
scipy's solve_ivp, one phase at a time (the strain rate jumps at the knots). Once the
specimen is free its total stress is zero and it recovers on its own.

Several pushes on the same specimen (issue 25): ``Profile(pushes=n, pause=p)`` repeats
the push n times, each to the same absolute stage depth (0 at the first contact), the
next push's stage leaving depth 0 ``pause`` s after the previous push's release_time.
The specimen's state carries over: after a push it keeps a permanent set (the c2
dashpot's strain) and may still be recovering, so the next push meets the top only when
the stage depth reaches the block's sinking eps H (a solve_ivp event during the free
phase); the contact phases then continue from the block's state at that moment.

Only numpy, scipy, yaml and rosbags are imported: nothing from rheo_ros, on purpose.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares
from scipy.signal import lsim, lti
from scipy.stats import norm

GENERATOR_ID = "test/generator.py (independent homogeneous block, scipy solve_ivp)"
PARAMS_KEY = "rheo_ros.params"
STAGE, TACTILE, MARKERS = "/stage/joint_states", "/tactile/pressure", "/markers/mesh"
TOPICS = {STAGE: "sensor_msgs/msg/JointState", TACTILE: "sensor_msgs/msg/Image",
          MARKERS: "geometry_msgs/msg/PoseArray"}


@dataclass(frozen=True)
class Material:
    """Three-element parameters (the paper's Table IV by default): Pa, Pa s, Pa s, -."""
    E: float = 3.33e4
    c1: float = 1.69e5
    c2: float = 3.11e7
    gamma: float = 0.332


@dataclass(frozen=True)
class Profile:
    """The stage's program (m, m/s, s). retract_speed None: the stage leaves at once.

    pushes: the program is run that many times on the same specimen, every push to the
    same absolute stage depth; push i + 1's stage leaves depth 0 ``pause`` s after the
    end of push i's release_time (start_delay only precedes the first push). The record
    ends at the end of the last push's release_time. fresh: the pushes (0-based) made on
    a new block of the same material and size, put in place at rest when the pause before
    them begins (at least 3 s: the block at rest in the camera before the stage moves)."""
    start_delay: float = 1.0
    velocity: float = 5e-4
    depth: float = 0.010
    keep_time: float = 48.0
    release_time: float = 100.0
    retract_speed: float | None = None
    pushes: int = 1
    pause: float = 0.0
    fresh: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if any(not 0 < i < self.pushes for i in self.fresh) or (self.fresh and self.pause < 3.0):
            raise ValueError(f"fresh: {self.fresh} must name later pushes (1..{self.pushes - 1}) with a pause "
                             f"of at least 3 s (pause {self.pause:g} s)")
        if not isinstance(self.pushes, (int, np.integer)) or self.pushes < 1:
            raise ValueError(f"pushes: {self.pushes} is not a whole number >= 1")
        if not self.pause >= 0.0:
            raise ValueError(f"pause: {self.pause} s is negative")
        if self.pushes > 1 and self.retract_speed is not None \
                and self.depth / self.retract_speed > self.release_time + self.pause:
            raise ValueError(f"retract_speed: the stage needs {self.depth / self.retract_speed:g} s to leave, "
                             f"more than release_time + pause = {self.release_time + self.pause:g} s")

    def push_knots(self, i: int) -> tuple[float, float, float, float]:
        """Push i's stage start (depth 0: the first push's contact), end of pull, release
        and end of its release_time (s)."""
        period = self.depth / self.velocity + self.keep_time + self.release_time + self.pause
        t0 = self.start_delay + i * period
        t1 = t0 + self.depth / self.velocity
        t2 = t1 + self.keep_time
        return t0, t1, t2, t2 + self.release_time

    @property
    def knots(self) -> tuple[float, float, float, float]:
        """Contact, end of pull, release (of the first push), end of record (s)."""
        return (*self.push_knots(0)[:3], self.push_knots(self.pushes - 1)[3])

    def stage(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stage depth and velocity at t; right-continuous at the knots (a sample on a
        knot belongs to the phase that starts there). Push i owns [its start, the next's)."""
        depth, vel = self._push_stage(t, 0)
        for i in range(1, self.pushes):
            d, v = self._push_stage(t, i)
            mine = t >= self.push_knots(i)[0]
            depth, vel = np.where(mine, d, depth), np.where(mine, v, vel)
        return depth, vel

    def depth_at(self, t: float) -> float:
        """The stage depth at one time t (s)."""
        return float(self.stage(np.array([t]))[0][0])

    def _push_stage(self, t: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray]:
        t0, t1, t2, _ = self.push_knots(i)
        depth = np.clip(self.velocity * (t - t0), 0.0, self.depth)
        vel = np.where((t >= t0) & (t < t1), self.velocity, 0.0)
        after = t >= t2
        if self.retract_speed is None:
            depth = np.where(after, 0.0, depth)
        else:
            back = np.maximum(self.depth - self.retract_speed * (t - t2), 0.0)
            depth = np.where(after, back, depth)
            vel = np.where(after & (back > 0.0), -self.retract_speed, vel)
        return depth, vel


@dataclass(frozen=True)
class Layout:
    """Specimen size (m), sensor layout and sampling rates (Hz), contract defaults."""
    width: float = 0.080
    height: float = 0.080
    thickness: float = 0.0125
    tactile_rows: int = 6
    tactile_cols: int = 32
    marker_rows: int = 5
    marker_cols: int = 5
    rate_stage: float = 100.0
    rate_tactile: float = 50.0
    rate_markers: float = 10.0


@dataclass(frozen=True)
class Effects:
    """Hidden effects, deliberately with other laws than the package's simulator.

    stiffening: k (1/strain); the Voigt spring alone gives E (exp(k eps_v) - 1) / k.
    maxwell: (E_i Pa, tau_i s) arms in parallel with the whole three-element model.
    adhesion: (p0 Pa, tau s): after release the bottom reads p0 exp(-t/tau), a positive
        pressure the free specimen does not carry (tau = inf: a constant stuck layer).
        Several pushes: each release starts its own p0 exp(-(t - t_release)/tau), which
        lasts until the stage meets the block again (in contact the bottom reads the
        mechanical stress only); a push the stage never meets releases nothing.
    drift: (a Pa, tau s, spread): each cell's baseline settles as a_j (1 - exp(-t/tau)),
        a_j = a (1 + spread N(0, 1)) drawn per cell from the seed.
    column_drift: (r Pa/s, spread): each column of cells drifts linearly from t = 0 at its
        own rate r_c = r (1 + spread N(0, 1)) (a gradient along the array).
    sensor_lag: (tau s, share): a sensor with memory, in no catalogue: each cell reads
        (1 - share) of the pressure at once and ``share`` through a first-order lag of time
        tau from rest (the elastomer over the cells creeps), before its noise.
    camera_drift: (vx m/s, vy m/s): in no catalogue and in the markers alone: the camera's
        mount creeps, every marker seen moving by (vx, vy) t from t = 0.
    damage: d: a material law in no catalogue (continuum damage, Mullins-like): the block's
        structure breaks down with the largest strain it has seen, its stress
        sigma / (1 + d eps_max); the kinematics are the undamaged block's (a stress-free
        recovery is one whatever the factor), so the markers do not see it.
    Laws of the same kinds that are not the package's rivals' (``models.rivals``), to
    measure what the rivals do on effects they were not written for:
    sensor_lag_second_order: (tau s, share): ``share`` of each reading through two equal
        first-order lags in series (a critically damped second-order sensor).
    damage_exponential: d: the stress times exp(-d eps_max).
    sensor_hysteresis: w Pa: each cell reads through a play of half-width w (it follows
        the pressure only once that has moved w past it: on loading w under, on unloading
        w over; after the release w stays read).
    """
    stiffening: float | None = None
    maxwell: tuple[tuple[float, float], ...] = ()
    adhesion: tuple[float, float] | None = None
    drift: tuple[float, float, float] | None = None
    column_drift: tuple[float, float] | None = None
    sensor_lag: tuple[float, float] | None = None
    camera_drift: tuple[float, float] | None = None
    damage: float | None = None
    sensor_lag_second_order: tuple[float, float] | None = None
    damage_exponential: float | None = None
    sensor_hysteresis: float | None = None


EFFECTS: dict[str, Effects] = {
    "none": Effects(),
    "strain_stiffening": Effects(stiffening=4.0),
    "relaxation_branch": Effects(maxwell=((1.5e4, 4.0), (8.0e3, 25.0))),
    "adhesion": Effects(adhesion=(1000.0, 200.0)),
    "sensor_drift": Effects(drift=(400.0, 60.0, 0.25)),
}


@dataclass(frozen=True)
class Sensor:
    """Tactile cells and camera. Order of the cell's chain: noise, floor at zero,
    dead band (readings under it read 0), quantisation, saturation; then one faulty cell
    (clipped alone, or dead) and the unit the array reports in."""
    name: str
    noise: float = 100.0            # Pa, Gaussian per cell and frame
    floor: bool = True              # a pressure cell reads no tension
    dead_band: float = 0.0          # Pa
    resolution: float = 0.0         # Pa per step; 0: continuous
    saturation: float = math.inf    # Pa
    marker_noise: float = 2e-5      # m, Gaussian per coordinate
    clipped_cell: tuple[int, int, float] | None = None   # (row, col, Pa): that cell alone saturates there
    dead_cell: tuple[int, int, float] | None = None      # (row, col, value): that cell reads value ...
    dead_from: float = -math.inf    # s: ... from this stamp on (throughout by default)
    unit: float = 1.0               # Pa per unit written: 1000 reports kPa (read as Pa: 1000 x too small)


SENSORS: dict[str, Sensor] = {
    "default_like": Sensor("default_like", dead_band=300.0, resolution=10.0),
    "no_dead_band": Sensor("no_dead_band"),
    "clipped": Sensor("clipped", dead_band=300.0, resolution=10.0, saturation=4000.0),
    "quantised": Sensor("quantised", resolution=50.0),
    "noisy_camera": Sensor("noisy_camera", dead_band=300.0, resolution=10.0, marker_noise=1e-4),
    "noise_free": Sensor("noise_free", noise=0.0, floor=False, marker_noise=0.0),
}


@dataclass(frozen=True)
class Truth:
    """What made a bag: written beside it as <bag>.truth.json."""
    generator: str
    seed: int
    material: Material
    effects: Effects
    sensor: Sensor
    profile: Profile
    layout: Layout
    knots: tuple[float, float, float, float]   # contact, end of pull, release, end (s)
    pushes: tuple[dict[str, Any], ...] = ()     # per push: Push.record() (contact, set, phases)
    fresh_material: Material | None = None      # the blocks put in place at profile.fresh (None: material)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, default=str)


@dataclass(frozen=True)
class Push:
    """One push as the integration met it (s, m). contact: the stage meets the top (None:
    never, the block sank deeper than the stage goes); contact_depth: the stage depth
    there, equal to the block's sinking eps H; set_at_start / sinking_at_start: the
    permanent set eps_d H and the sinking eps H when the push's stage leaves depth 0;
    leaves: the block loses the stage (None: never lost before the record ends);
    set_after: eps_d H there, the permanent set this push leaves."""
    index: int
    start: float
    contact: float | None
    contact_depth: float | None
    set_at_start: float
    sinking_at_start: float
    end_pull: float
    release: float
    end: float
    leaves: float | None
    set_after: float
    pause_end: float | None   # the next push's stage start (None: the last push)

    def record(self) -> dict[str, Any]:
        """The truth file's entry: these fields and the phase times (s, [start, end])."""
        phases = {"pull": [self.contact, self.end_pull] if self.contact is not None else None,
                  "keep": [max(self.contact, self.end_pull), self.release] if self.contact is not None else None,
                  "release": [self.release, self.end]}
        if self.pause_end is not None:
            phases["pause"] = [self.end, self.pause_end]
        return {**asdict(self), "phases": phases}


@dataclass(frozen=True)
class Trajectory:
    """Noise-free mechanics at times t: strain (s/H), total stress on the bottom
    (Pa, compression positive, 0 when free) and whether the stage touches the top;
    pushes: what each push met (independent of t)."""
    t: np.ndarray
    eps: np.ndarray
    sigma: np.ndarray
    contact: np.ndarray
    pushes: tuple[Push, ...] = ()


def simulate(material: Material, effects: Effects, profile: Profile, t: np.ndarray,
             height: float = Layout.height, fresh_material: Material | None = None) -> Trajectory:
    """Integrate the block phase by phase and evaluate it at the (sorted) times t.

    State y = [eps, eps_d, s_1..s_n] (s_i the Maxwell arms' stresses). In contact the
    strain rate is the stage's (constant within a phase, so eps is integrated exactly);
    free, the strain rate is whatever makes the total stress zero. Each sample takes
    the phase it falls in, half-open, so a sample on a knot belongs to the next phase.
    Pushes after the first: the free phase runs until the stage depth reaches the
    block's sinking (event gap = stage depth - eps H crossing zero upwards, searched up
    to the push's release); the contact phases start there from the block's state.
    The blocks put in place at ``profile.fresh`` are of ``fresh_material`` (default: the
    first block's; the Poisson ratio must be the same, the markers see one).
    """
    if fresh_material is not None and fresh_material.gamma != material.gamma:
        raise ValueError("fresh_material: the Poisson ratio must be the first block's")
    E, c1, c2, k = material.E, material.c1, material.c2, effects.stiffening
    arm_E = np.array([a[0] for a in effects.maxwell])
    arm_tau = np.array([a[1] for a in effects.maxwell])
    t = np.asarray(t, float)
    t_end = profile.knots[3]

    def spring(ev: float) -> float:
        return E * ev if not k else E * math.expm1(k * ev) / k

    def contact_stress(y: np.ndarray, rate: float) -> float:
        return (spring(y[0] - y[1]) + c1 * rate) / (1.0 + c1 / c2) + float(np.sum(y[2:]))

    def rhs_contact(_t: float, y: np.ndarray, rate: float) -> np.ndarray:
        sig3 = (spring(y[0] - y[1]) + c1 * rate) / (1.0 + c1 / c2)
        return np.concatenate(([rate, sig3 / c2], arm_E * rate - y[2:] / arm_tau))

    def rhs_free(_t: float, y: np.ndarray) -> np.ndarray:
        arms = float(np.sum(y[2:]))
        rate = -(spring(y[0] - y[1]) + (1.0 + c1 / c2) * arms) / c1
        # The three-element branch then carries -arms, so that the total stays zero.
        return np.concatenate(([rate, -arms / c2], arm_E * rate - y[2:] / arm_tau))

    # Tight tolerances: the tests hold the stress to closed forms at 1e-6 relative.
    # max_step well under the fastest time constant so dense output stays accurate.
    opts = {"method": "DOP853", "rtol": 1e-11, "dense_output": True,
            "max_step": min([c1 / E, *arm_tau.tolist()]) / 20,
            "atol": np.array([1e-15, 1e-15] + [1e-10] * len(arm_tau))}
    eps, sigma, contact = np.zeros_like(t), np.zeros_like(t), np.zeros(t.shape, bool)

    def fill(a: float, b: float, sol: Any, rate: float | None, last: bool = False) -> None:
        sel = (t >= a) & ((t <= b) if last else (t < b))
        if sel.any():
            ys = sol.sol(t[sel])
            eps[sel] = ys[0]
            if rate is not None:   # free: the bottom carries nothing
                contact[sel] = True
                sigma[sel] = [contact_stress(col, rate) for col in ys.T]

    def touch(tt: float, yy: np.ndarray) -> float:
        return profile.depth_at(tt) - yy[0] * height
    touch.terminal, touch.direction = True, 1  # type: ignore[attr-defined]

    def leaves(_t: float, yy: np.ndarray, r: float) -> float:
        return contact_stress(yy, r)
    leaves.terminal, leaves.direction = True, -1  # type: ignore[attr-defined]

    y = np.zeros(2 + len(arm_tau))   # before contact nothing moves: all zero
    a, pushes = t_end, []
    for i in range(profile.pushes):
        t0, t1, t2, t3 = profile.push_knots(i)
        at_start: np.ndarray = y
        c: float | None = t0
        if i in profile.fresh:   # the old block recovers until the pause, then a new one at rest
            swap = max(a, profile.push_knots(i - 1)[3])
            if swap > a:
                fill(a, swap, solve_ivp(rhs_free, (a, swap), y, **opts), None)
            y, a = np.zeros_like(y), swap
            if fresh_material is not None:   # the closures read these names: the new block's from here
                E, c1, c2 = fresh_material.E, fresh_material.c1, fresh_material.c2
            eps[(t >= swap) & (t < t0)] = 0.0
            at_start, c = y, t0
        elif i > 0:   # free since a: wait for the stage to meet the top
            sol = solve_ivp(rhs_free, (a, t2), y, events=touch, **opts)
            c = float(sol.t_events[0][0]) if sol.t_events[0].size else None
            fill(a, t2 if c is None else c, sol, None)
            at_start = sol.sol(t0) if t0 <= sol.t[-1] else sol.y[:, -1]
            y, a = sol.y[:, -1].copy(), float(sol.t[-1])
        if c is not None:
            if i > 0:
                y[0] = profile.depth_at(c) / height   # the top is where the stage is
            for pa, pb, rate in ((t0, t1, profile.velocity / height), (t1, t2, 0.0)):
                if pb <= c:
                    continue
                pa = max(pa, c)
                sol = solve_ivp(rhs_contact, (pa, pb), y, args=(rate,), **opts)
                fill(pa, pb, sol, rate)
                y = sol.y[:, -1]
            a = t2
            if profile.retract_speed is not None and contact_stress(y, -profile.retract_speed / height) > 0.0:
                # The stage retracts slower than the specimen recovers: the top follows the
                # stage, pushing on it, until its stress falls to zero. Then it is free; a free
                # recovery only slows down (linear model), so it never catches the stage again.
                rate = -profile.retract_speed / height
                end = min(t_end, t2 + profile.depth / profile.retract_speed)
                sol = solve_ivp(rhs_contact, (t2, end), y, args=(rate,), events=leaves, **opts)
                a = float(sol.t[-1])
                fill(t2, a, sol, rate)
                y = sol.y[:, -1]
        lost = a if c is not None and a < t_end else None
        pushes.append(Push(i, t0, c, profile.depth_at(c) if c is not None else None,
                           float(at_start[1]) * height, float(at_start[0]) * height, t1, t2, t3, lost,
                           float(y[1]) * height,
                           profile.push_knots(i + 1)[0] if i + 1 < profile.pushes else None))
    if a < t_end:
        sol = solve_ivp(rhs_free, (a, t_end), y, **opts)
        fill(a, t_end, sol, None, last=True)
    return Trajectory(t, eps, sigma, contact, tuple(pushes))


def sample_times(rate: float, t_end: float) -> np.ndarray:
    """k / rate from 0 to the end inclusive (k integer, no accumulated rounding)."""
    return np.arange(math.floor(t_end * rate + 1e-9) + 1) / rate


@dataclass(frozen=True)
class Data:
    """What the sensors report, noise included (the bag's content, before encoding)."""
    stage_t: np.ndarray
    depth: np.ndarray
    velocity: np.ndarray
    tactile_t: np.ndarray
    images: np.ndarray     # (T, rows, cols) float32 Pa
    marker_t: np.ndarray
    markers: np.ndarray    # (Tm, rows * cols, 2) m, row-major, bottom row first
    pushes: tuple[Push, ...] = ()   # what each push met (simulate's)


def cell_readings(pressure: np.ndarray, sensor: Sensor, rng: np.random.Generator) -> np.ndarray:
    """What cells at ``pressure`` (Pa) read: the chain up to saturation (noise, floor, dead
    band, quantisation, saturation); the faulty cell and the unit come after it."""
    p = np.array(pressure, dtype=float)
    if sensor.noise > 0:
        p += sensor.noise * rng.standard_normal(p.shape)
    if sensor.floor:
        p = np.maximum(p, 0.0)
    if sensor.dead_band > 0:
        p = np.where(p < sensor.dead_band, 0.0, p)
    if sensor.resolution > 0:
        p = np.round(p / sensor.resolution) * sensor.resolution
    return np.minimum(p, sensor.saturation)


def synthesize(material: Material = Material(), effects: Effects = Effects(), sensor: Sensor | str = "default_like",
               seed: int = 0, profile: Profile = Profile(), layout: Layout = Layout(),
               fresh_material: Material | None = None) -> Data:
    """Mechanics, then each sensor. One numpy Generator per stream (spawned from the
    seed), so the same seed gives the same bag and a new effect leaves the others' noise."""
    sensor = SENSORS[sensor] if isinstance(sensor, str) else sensor
    t_end = profile.knots[3]
    stage_t, tac_t, mk_t = (sample_times(r, t_end) for r in (layout.rate_stage, layout.rate_tactile,
                                                             layout.rate_markers))
    depth, velocity = profile.stage(stage_t)
    tac_rng, cam_rng, drift_rng = np.random.default_rng(seed).spawn(3)
    shape = (tac_t.size, layout.tactile_rows, layout.tactile_cols)

    # Tactile: every cell reads the uniform bottom stress (the block is homogeneous).
    mech = simulate(material, effects, profile, tac_t, layout.height, fresh_material)
    sigma = mech.sigma
    if effects.damage is not None:   # eps_max over the samples: the strain peaks on a stage knot
        sigma = sigma / (1.0 + effects.damage * np.maximum.accumulate(mech.eps))
    if effects.damage_exponential is not None:
        sigma = sigma * np.exp(-effects.damage_exponential * np.maximum.accumulate(mech.eps))
    p = np.broadcast_to(sigma[:, None, None], shape).copy()
    if effects.adhesion is not None:
        p0, tau = effects.adhesion
        touched = [push for push in mech.pushes if push.contact is not None]
        for j, push in enumerate(touched):   # each release sticks until the stage meets the block again
            t_rel = push.release
            on = tac_t >= t_rel
            if j + 1 < len(touched):
                on &= tac_t < touched[j + 1].contact
            p += np.where(on, p0 * np.exp(-(tac_t - t_rel) / tau), 0.0)[:, None, None]
    if effects.drift is not None:
        a, tau, spread = effects.drift
        amp = a * (1.0 + spread * drift_rng.standard_normal(shape[1:]))
        p += amp[None] * (1.0 - np.exp(-tac_t / tau))[:, None, None]
    if effects.column_drift is not None:
        r, spread = effects.column_drift
        rates = r * (1.0 + spread * drift_rng.standard_normal(layout.tactile_cols))
        p += tac_t[:, None, None] * rates[None, None, :]
    if effects.sensor_lag is not None:
        tau, share = effects.sensor_lag
        # The continuous lag tau dy/dt = p - y from rest, each cell's pressure linear between
        # its samples (scipy's lsim, linear interpolation: exact for that input).
        lag = lti([1.0], [tau, 1.0])
        cells = p.reshape(len(tac_t), -1)
        lagged = np.column_stack([lsim(lag, cells[:, j], tac_t)[1] for j in range(cells.shape[1])])
        p = (1.0 - share) * p + share * lagged.reshape(p.shape)
    if effects.sensor_lag_second_order is not None:
        tau, share = effects.sensor_lag_second_order
        lag2 = lti([1.0], [tau * tau, 2.0 * tau, 1.0])
        cells = p.reshape(len(tac_t), -1)
        lagged = np.column_stack([lsim(lag2, cells[:, j], tac_t)[1] for j in range(cells.shape[1])])
        p = (1.0 - share) * p + share * lagged.reshape(p.shape)
    if effects.sensor_hysteresis is not None:
        w = effects.sensor_hysteresis
        read = np.zeros(shape[1:])
        for i in range(len(tac_t)):   # the play operator: sequential by nature
            read = np.clip(read, p[i] - w, p[i] + w)
            p[i] = read
    p = cell_readings(p, sensor, tac_rng)
    if sensor.clipped_cell is not None:
        r, c, top = sensor.clipped_cell
        p[:, r, c] = np.minimum(p[:, r, c], top)
    if sensor.dead_cell is not None:
        r, c, value = sensor.dead_cell
        p[tac_t >= sensor.dead_from, r, c] = value
    p = p / sensor.unit

    # Markers: u_y = -eps y (bottom on the sensor), u_x = gamma eps (x - W/2) (free sides).
    eps = simulate(material, effects, profile, mk_t, layout.height, fresh_material).eps
    gx, gy = np.meshgrid(np.linspace(0, layout.width, layout.marker_cols),
                         np.linspace(0, layout.height, layout.marker_rows))
    x0, y0 = gx.ravel(), gy.ravel()   # row-major, bottom row first
    xy = np.stack([x0 + material.gamma * eps[:, None] * (x0 - layout.width / 2),
                   y0 - eps[:, None] * y0], axis=-1)
    if effects.camera_drift is not None:
        xy = xy + np.outer(mk_t, effects.camera_drift)[:, None, :]
    if sensor.marker_noise > 0:
        xy = xy + sensor.marker_noise * cam_rng.standard_normal(xy.shape)
    return Data(stage_t, depth, velocity, tac_t, p.astype(np.float32), mk_t, xy, mech.pushes)


def params_document(layout: Layout, profile: Profile | None = None) -> dict[str, Any]:
    """The contract's parameters file (its names only), ROS params-file shape. A profile
    of several pushes adds the stage: the per-push keys and ``stage.pushes``,
    ``stage.pause`` (one push: nothing, as before; retract_speed None is ``.inf``)."""
    params: dict[str, Any] = {
        "geometry": "uniaxial",
        "specimen": {"width": layout.width, "height": layout.height, "thickness": layout.thickness},
        "tactile": {"rows": layout.tactile_rows, "cols": layout.tactile_cols},
        "markers": {"rows": layout.marker_rows, "cols": layout.marker_cols}}
    if profile is not None and profile.pushes > 1:
        params["stage"] = {
            "depth": profile.depth, "velocity": profile.velocity, "keep_time": profile.keep_time,
            "start_delay": profile.start_delay, "release_time": profile.release_time,
            "retract_speed": math.inf if profile.retract_speed is None else profile.retract_speed,
            "pushes": int(profile.pushes), "pause": float(profile.pause)}
    return {"/**": {"ros__parameters": params}}


def write_bag(data: Data, out: Path, params_yaml: str | None = None, compress: bool = False) -> None:
    """One rosbag2 directory (metadata.yaml + one .mcap, CDR); log time = header stamp."""
    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Pose, Point, Quat = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]

    def header(ns: int, frame: str) -> Any:
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)

    def encode(kind: int, i: int, ns: int) -> Any:
        if kind == 0:
            return T[TOPICS[STAGE]](header=header(ns, ""), name=["stage"],
                                    position=np.array([data.depth[i]]), velocity=np.array([data.velocity[i]]),
                                    effort=np.array([], float))
        if kind == 1:
            img = data.images[i]
            raw = np.ascontiguousarray(img, dtype="<f4").view(np.uint8).ravel()
            return T[TOPICS[TACTILE]](header=header(ns, "tactile"), height=img.shape[0], width=img.shape[1],
                                      encoding="32FC1", is_bigendian=0, step=4 * img.shape[1], data=raw)
        poses = [Pose(position=Point(x=float(x), y=float(y), z=0.0), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0))
                 for x, y in data.markers[i]]
        return T[TOPICS[MARKERS]](header=header(ns, "specimen"), poses=poses)

    series = [data.stage_t, data.tactile_t, data.marker_t]
    stamps = np.concatenate([np.round(s * 1e9).astype(np.int64) for s in series])
    kinds = np.concatenate([np.full(s.size, k) for k, s in enumerate(series)])
    index = np.concatenate([np.arange(s.size) for s in series])
    order = np.lexsort((kinds, stamps))   # by stamp, ties stage < tactile < markers
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    if params_yaml is not None:
        writer.set_custom_data(PARAMS_KEY, params_yaml)
    with writer:
        conns = [writer.add_connection(topic, msgtype, typestore=store) for topic, msgtype in TOPICS.items()]
        for ns, k, i in zip(stamps[order].tolist(), kinds[order].tolist(), index[order].tolist()):
            writer.write(conns[k], ns, store.serialize_cdr(encode(k, i, ns), conns[k].msgtype))


def generate(out_dir: str | Path, *, material: Material = Material(), effects: Effects | str = "none",
             sensor: Sensor | str = "default_like", seed: int = 0, profile: Profile = Profile(),
             layout: Layout = Layout(), params_in_metadata: bool = True, params_file: bool = True,
             compress: bool = False, fresh_material: Material | None = None) -> Path:
    """Write a bag at out_dir (must not exist) and, beside it, <name>.truth.json and
    (params_file) <name>.params.yaml for ``rheo analyze --params-file``. Returns out_dir."""
    out = Path(out_dir)
    effects = EFFECTS[effects] if isinstance(effects, str) else effects
    sensor = SENSORS[sensor] if isinstance(sensor, str) else sensor
    text = yaml.safe_dump(params_document(layout, profile), sort_keys=False)
    data = synthesize(material, effects, sensor, seed, profile, layout, fresh_material)
    write_bag(data, out, text if params_in_metadata else None, compress)
    if params_file:
        out.with_name(out.name + ".params.yaml").write_text(text)
    truth = Truth(GENERATOR_ID, seed, material, effects, sensor, profile, layout, profile.knots,
                  tuple(push.record() for push in data.pushes), fresh_material)
    out.with_name(out.name + ".truth.json").write_text(truth.to_json())
    return out



# --- the diagnosis bench's protocol (rheo bench diagnosis --generator test/generator.py) ---
# Families in the package's vocabulary (names only: nothing is imported from rheo_ros).
BENCH_FAMILIES = ("relaxation_branch", "adhesion", "strain_stiffening", "sensor_drift")
BENCH_SENSORS = tuple(name for name in SENSORS if SENSORS[name].noise > 0)   # a size needs a noise
BENCH_KEEP, BENCH_RELEASE = (15.0, 40.0), (20.0, 40.0)
BENCH_QUICK_KEEP, BENCH_QUICK_RELEASE = (15.0, 18.0), (20.0, 24.0)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(math.log(lo), math.log(hi))))


def bench_effect(rng: np.random.Generator, family: str, material: Material, profile: Profile,
                 height: float) -> tuple[str, dict[str, Any], dict[str, float]]:
    """One hidden effect of ``family`` by this generator's laws, from barely detectable to
    large: the package's name of its form, the ``Effects`` fields it sets, its values.

    relaxation_branch: one Maxwell arm (form one_arm) or two (two_arms), each of
    stiffness 0.3 %..50 % of E, times within the keep; strain_stiffening: the Voigt
    spring's exponential law (voigt_exponential), k 0.05..10; adhesion: p0 0.2 %..40 %
    of the elastic stress at full depth, fading over 10..300 s (fading) or held (held);
    sensor_drift: every cell settling alike by a = +-3..600 Pa over 3 s..half the record
    (settling), or each cell by its own amount, spread 0.2..0.5 (settling_per_segment: the
    segments' sums differ), or each column drifting linearly at +-0.02..4 Pa/s, spread
    0.3..1 (per_segment)."""
    E, keep = material.E, profile.keep_time
    if family == "relaxation_branch":
        two = rng.random() < 0.5
        spans = ((1.0, keep / 6), (keep / 4, keep / 2)) if two else ((1.0, keep / 3),)
        arms = tuple((_log_uniform(rng, 0.003, 0.5) * E, float(rng.uniform(*span))) for span in spans)
        return ("two_arms" if two else "one_arm"), {"maxwell": arms}, \
            {f"{k}_{i + 1}": v for i, arm in enumerate(arms) for k, v in zip(("E", "tau"), arm)}
    if family == "strain_stiffening":
        k = _log_uniform(rng, 0.05, 10.0)
        return "voigt_exponential", {"stiffening": k}, {"k": k}
    if family == "adhesion":
        p0 = _log_uniform(rng, 0.002, 0.4) * E * profile.depth / height
        if rng.random() < 0.5:
            return "held", {"adhesion": (p0, math.inf)}, {"p0": p0}
        tau = _log_uniform(rng, 10.0, 300.0)
        return "fading", {"adhesion": (p0, tau)}, {"p0": p0, "tau": tau}
    if family == "sensor_drift":
        law = int(rng.integers(3))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        if law == 2:   # each column its own line
            r, spread = sign * _log_uniform(rng, 0.02, 4.0), float(rng.uniform(0.3, 1.0))
            return "per_segment", {"column_drift": (r, spread)}, {"r": r, "spread": spread}
        a = sign * _log_uniform(rng, 3.0, 600.0)
        tau = _log_uniform(rng, 3.0, profile.knots[3] / 2)
        spread = 0.0 if law == 0 else float(rng.uniform(0.2, 0.5))   # every cell alike, or each its own
        return ("settling" if law == 0 else "settling_per_segment"), {"drift": (a, tau, spread)}, \
            {"a": a, "tau": tau, "spread": spread}
    raise KeyError(family)


# Effects in no catalogue (rheo bench diagnosis --outside): what the package must not name.
BENCH_OUTSIDE = ("sensor_lag", "camera_drift", "damage")
# Their kinds by laws the package's rivals were not written for, and a sensor's play.
BENCH_OUTSIDE_OTHER = ("sensor_lag_second_order", "damage_exponential", "sensor_hysteresis")


def bench_outside(rng: np.random.Generator, name: str) -> tuple[dict[str, Any], dict[str, float], str]:
    """One effect in no catalogue by this generator's law: its ``Effects`` fields, its
    values and the signal it shows in. sensor_lag: a share 2..50 % of each reading through
    a lag of 0.3..10 s; camera_drift: the camera seen moving at 0.1..5 um/s each way;
    damage: a softening d of 0.3..5 (the stress over 1 + d eps_max); the other laws
    (``BENCH_OUTSIDE_OTHER``): sensor_lag_second_order as sensor_lag, damage_exponential as
    damage (the stress times exp(-d eps_max)), sensor_hysteresis a play of 30..3000 Pa."""
    if name == "sensor_lag":
        tau, share = _log_uniform(rng, 0.3, 10.0), _log_uniform(rng, 0.02, 0.5)
        return {"sensor_lag": (tau, share)}, {"tau": tau, "share": share}, "force"
    if name == "camera_drift":
        v = tuple(float(rng.choice((-1.0, 1.0))) * _log_uniform(rng, 1e-7, 5e-6) for _ in range(2))
        return {"camera_drift": v}, {"vx": v[0], "vy": v[1]}, "markers"
    if name == "damage":
        d = _log_uniform(rng, 0.3, 5.0)
        return {"damage": d}, {"softening": d}, "force"
    if name == "sensor_lag_second_order":
        tau, share = _log_uniform(rng, 0.3, 10.0), _log_uniform(rng, 0.02, 0.5)
        return {"sensor_lag_second_order": (tau, share)}, {"tau": tau, "share": share}, "force"
    if name == "damage_exponential":
        d = _log_uniform(rng, 0.3, 5.0)
        return {"damage_exponential": d}, {"softening": d}, "force"
    if name == "sensor_hysteresis":
        w = _log_uniform(rng, 30.0, 3000.0)
        return {"sensor_hysteresis": w}, {"w": w}, "force"
    raise KeyError(name)


def _marker_size(material: Material, effects: Effects, sensor: Sensor, seed: int, profile: Profile,
                 layout: Layout) -> float:
    """RMS change ``effects`` make in the noise-free marker positions, over the camera noise
    (each marker coordinate's mean over the record taken off: a constant offset is no
    information, the analysis takes it off too)."""
    raw = replace(sensor, noise=0.0, marker_noise=0.0)
    a, b = (synthesize(material, e, raw, seed, profile, layout).markers for e in (effects, Effects()))
    change = (a - b) - (a - b).mean(axis=0)
    return float(np.sqrt(np.mean(change ** 2)) / sensor.marker_noise)


def _total_force(images: np.ndarray, layout: Layout) -> np.ndarray:
    """The bottom's total force (N) of tactile images (T, rows, cols) in Pa."""
    cell = layout.width / layout.tactile_cols * layout.thickness
    return images.astype(float).sum(axis=(1, 2)) * cell


def expected_reading(pressure: np.ndarray, sensor: Sensor) -> np.ndarray:
    """The mean reading (Pa) of cells at ``pressure`` (Pa) through ``sensor``'s noise,
    floor, dead band and saturation: E[min(x 1(x >= d), S)], x = p + noise, d the dead
    band (0 with the floor alone, none without either). Its quantisation, finer than the
    noise, averages out. Near zero a noisy floored cell moves by only part of a change of
    its pressure (half at p = 0): what the readings can show, not the noise-free chain."""
    p = np.asarray(pressure, dtype=float)
    low = sensor.dead_band if sensor.dead_band > 0 else (0.0 if sensor.floor else -math.inf)
    top = sensor.saturation
    if sensor.noise == 0:
        return np.minimum(np.where(p < low, 0.0, p), top)
    sd = sensor.noise
    a = (low - p) / sd
    out = p * norm.sf(a) + sd * norm.pdf(a)   # E[x 1(x >= d)], exact for d = -inf too
    if math.isfinite(top):
        b = (top - p) / sd
        out -= p * norm.sf(b) + sd * norm.pdf(b) - top * norm.sf(b)   # over S: S, not x
    return out


def bench_sizes(material: Material, effects: Effects, sensor: Sensor, seed: int, profile: Profile,
                layout: Layout) -> dict[str, float]:
    """The size of ``effects``: the RMS of their change of the noise-free total force over
    the std of the total force's noise; ``size_live`` through the sensor's floor, dead
    band and saturation (the same chain, noise-free and unquantised)."""
    noise_std = math.sqrt(layout.tactile_rows * layout.tactile_cols) * sensor.noise \
        * layout.width / layout.tactile_cols * layout.thickness
    raw = Sensor("raw", noise=0.0, floor=False, marker_noise=0.0)
    readable = replace(sensor, noise=0.0, resolution=0.0, marker_noise=0.0)
    out = {}
    for key, chain in (("size", raw), ("size_live", readable)):
        a, b = (_total_force(synthesize(material, e, chain, seed, profile, layout).images, layout)
                for e in (effects, Effects()))
        out[key] = float(np.sqrt(np.mean((a - b) ** 2)) / noise_std)
    return out


# How far (in log) the separable size's refit may move each compensating parameter.
LOG_MOVE = 3.0


def bench_separable(material: Material, effect: Effects, others: Effects, sensor: Sensor, seed: int,
                    profile: Profile, layout: Layout, step: float = 1e-3) -> float:
    """The part of ``effect``'s footprint the rest of the truth cannot take up: its change
    of the expected readings beside ``others`` (``expected_reading``: a drift of a tenth
    of the noise on an idle floored cell moves its mean by half as much; the total force
    over its noise, each marker coordinate over the camera's, less its mean: a constant
    offset is no information), less its best compensation by the base's four parameters and
    ``others``' (a zero or infinite value stays), as ``bench_sizes`` measures it: the RMS
    over the force readings, in total-force noise. ``bench_sizes`` asks what an effect
    changes; this what no other parameter could also have changed: a baseline settling
    within the pull reads much like a stiffer block.

    The compensation is this generator's own model refitted without the effect (scipy's
    ``least_squares`` on each parameter's log, from the linear compensation by finite
    differences of relative ``step``): a linear one overstates what is left where the
    others move far (generator seed 10 bag 53: a Voigt-spring stiffening of k 0.40 keeps
    0.92 x the noise linearly, 0.29 once c2 moves by 14 %)."""
    raw = Sensor("raw", noise=0.0, floor=False, marker_noise=0.0)
    force_std = math.sqrt(layout.tactile_rows * layout.tactile_cols) * sensor.noise \
        * layout.width / layout.tactile_cols * layout.thickness
    n_force = sample_times(layout.rate_tactile, profile.knots[3]).size

    def readings(m: Material, e: Effects) -> np.ndarray:
        data = synthesize(m, e, raw, seed, profile, layout)
        markers = data.markers - data.markers.mean(axis=0)
        return np.concatenate([_total_force(expected_reading(data.images, sensor), layout) / force_std,
                               markers.ravel() / sensor.marker_noise])

    bases = ("E", "c1", "c2", "gamma")
    moving = [(name, i) for name, value in ((f.name, getattr(others, f.name)) for f in fields(Effects))
              for i, x in enumerate(_flattened(value)) if math.isfinite(x) and x != 0.0]

    def moved(scales: np.ndarray) -> tuple[Material, Effects]:
        """The material and ``others`` with each compensating parameter times its scale."""
        m = replace(material, **{name: getattr(material, name) * float(f) for name, f in zip(bases, scales)})
        flat = {name: _flattened(getattr(others, name)) for name in {n for n, _ in moving}}
        for (name, i), f in zip(moving, scales[len(bases):]):
            flat[name][i] *= float(f)
        return m, replace(others, **{name: _shaped(getattr(others, name), iter(v)) for name, v in flat.items()})

    combined = Effects(**{f.name: getattr(effect, f.name) or getattr(others, f.name) for f in fields(Effects)})
    target = readings(material, combined)
    at = readings(material, others)
    ones = np.ones(len(bases) + len(moving))
    jac = np.column_stack([readings(*moved(np.where(np.arange(ones.size) == j, 1.0 + step, 1.0))) - at
                           for j in range(ones.size)])
    linear = np.linalg.lstsq(jac, target - at, rcond=None)[0] * step

    def left(logs: np.ndarray) -> np.ndarray:
        try:
            return readings(*moved(np.exp(logs))) - target
        except ValueError:   # a trial out of the model's range (a Poisson ratio over 1/2)
            return np.full(target.size, 1e6)

    # Each factor within e^-3..e^3: a trial sending an arm's time towards zero made the
    # integrator's steps follow it down (several GB, minutes). least_squares accepts only
    # steps that lower the cost, so its answer is never worse than the linear start.
    start = np.log1p(np.clip(linear, -0.9, 10.0))
    fit = least_squares(left, start, bounds=(-LOG_MOVE, LOG_MOVE), diff_step=1e-4, ftol=1e-4, xtol=1e-6,
                        max_nfev=100)
    return float(np.sqrt(np.sum(fit.fun ** 2) / n_force))


def _flattened(value: Any) -> list[float]:
    """The numbers of an ``Effects`` field (a number, nested tuples of them, or None)."""
    if value is None:
        return []
    return [x for v in value for x in _flattened(v)] if isinstance(value, tuple) else [float(value)]


def _shaped(like: Any, numbers: Any) -> Any:
    """``numbers`` (an iterator) in the shape of ``like`` (``_flattened``'s inverse)."""
    return tuple(_shaped(v, numbers) for v in like) if isinstance(like, tuple) else next(numbers)


def bench_bag(rng: np.random.Generator, index: int, out_dir: Path, noise_scale: float = 1.0,
              quick: bool = False, outside: bool = False, limit: tuple[str, float] | None = None,
              kinds: tuple[str, ...] = BENCH_OUTSIDE) -> dict[str, Any]:
    """The diagnosis bench's protocol (``rheo bench diagnosis --generator test/generator.py``):
    draw bag ``index`` from ``rng``, write it at ``out_dir`` (its .truth.json and
    .params.yaml beside it) and return its truth in the package's vocabulary.

    Draws: E log-uniform 1e4..1e5 Pa, c1 / E 2..15 s, c2 / E 300..3000 s, gamma
    0.2..0.45; depth 5..12 mm, keep 15..40 s, release 20..40 s (quick: 15..18, 20..24 s);
    a sensor of ``SENSORS`` but the noise-free one, its noises times ``noise_scale``;
    ``index mod 3`` hidden effects of distinct families (``bench_effect``); with
    ``outside``, none of them but one effect in no catalogue of ``kinds`` (``bench_outside``); with
    ``limit`` (family, readable size), one effect of that family scaled to that size
    (``_at_size``)."""
    material, profile, base, sensor, layout, seed = _bench_draw(rng, noise_scale, quick)
    if limit is not None:
        family, size = limit
        form, fields, values = bench_effect(rng, family, material, profile, layout.height)
        fields, values, sizes = _at_size(family, fields, values, size, material, sensor, seed, profile, layout)
        generate(out_dir, material=material, effects=Effects(**fields), sensor=sensor, seed=seed, profile=profile,
                 layout=layout)
        return {"hidden": [{"effect": family, "form": form, "params": values, **sizes}], **sizes,
                "params_file": str(out_dir.with_name(out_dir.name + ".params.yaml")),
                "info": {"generator": GENERATOR_ID, "seed": seed, "sensor": base.name, "noise": sensor.noise,
                         "material": asdict(material)}}
    if outside:
        name = str(rng.choice(kinds))
        fields, values, signal = bench_outside(rng, name)
        effects = Effects(**fields)
        sizes = bench_sizes(material, effects, sensor, seed, profile, layout)
        size = sizes["size"] if signal == "force" else _marker_size(material, effects, sensor, seed, profile, layout)
        generate(out_dir, material=material, effects=effects, sensor=sensor, seed=seed, profile=profile, layout=layout)
        return {"hidden": [], "outside": [{"effect": name, "signal": signal, "size": size, "params": values}],
                **sizes, "params_file": str(out_dir.with_name(out_dir.name + ".params.yaml")),
                "info": {"generator": GENERATOR_ID, "seed": seed, "sensor": base.name}}
    drawn = _bench_hidden(rng, index, material, profile, layout)
    # No separable size here (tens of seconds a bag): the bench asks bench_separable_sizes.
    hidden = [{"effect": str(family), "form": form, "params": values,
               **bench_sizes(material, Effects(**fields), sensor, seed, profile, layout)}
              for family, form, fields, values in drawn]
    effects = Effects(**{k: v for _, _, fields, _ in drawn for k, v in fields.items()})
    generate(out_dir, material=material, effects=effects, sensor=sensor, seed=seed, profile=profile, layout=layout)
    return {"hidden": hidden, **bench_sizes(material, effects, sensor, seed, profile, layout),
            "params_file": str(out_dir.with_name(out_dir.name + ".params.yaml")),
            "info": {"generator": GENERATOR_ID, "seed": seed, "sensor": base.name, "noise": sensor.noise,
                     "marker_noise": sensor.marker_noise, "material": asdict(material),
                     "depth": profile.depth, "keep_time": profile.keep_time, "release_time": profile.release_time}}


def _amplified(fields: dict[str, Any], values: dict[str, float], c: float
               ) -> tuple[dict[str, Any], dict[str, float]]:
    """A drawn effect (``bench_effect``'s fields and values) with its amplitude times ``c``:
    the stiffening's k, the adhesion's p0, each arm's stiffness, the drift's size or each
    column's rate (times and spreads kept)."""
    key, v = next(iter(fields.items()))
    if key == "stiffening":
        return {key: v * c}, {"k": v * c}
    if key == "maxwell":
        arms = tuple((E * c, tau) for E, tau in v)
        return {key: arms}, {f"{k}_{i + 1}": x for i, arm in enumerate(arms) for k, x in zip(("E", "tau"), arm)}
    name = {"adhesion": "p0", "drift": "a", "column_drift": "r"}[key]
    return {key: (v[0] * c, *v[1:])}, {**values, name: values[name] * c}


# A limit bag's readable size within this share of its target (``_at_size``), in this many
# steps, its amplitude within these factors of the draw's.
LIMIT_TOLERANCE, LIMIT_STEPS, LIMIT_SCALES = 0.03, 8, (1e-3, 1e3)


def _at_size(family: str, fields: dict[str, Any], values: dict[str, float], size: float, material: Material,
             sensor: Sensor, seed: int, profile: Profile, layout: Layout
             ) -> tuple[dict[str, Any], dict[str, float], dict[str, float]]:
    """``bench_effect``'s draw of ``family`` scaled (``_amplified``, the secant on log size)
    until its readable size (``size_live``) is within ``LIMIT_TOLERANCE`` of ``size``; where
    the sensor does not let it (an adhesion under a dead band reads nothing until its force
    crosses the band) the last try. Returns its fields, values and sizes."""
    scale = 1.0
    for _ in range(LIMIT_STEPS):
        scaled, named = _amplified(fields, values, scale)
        sizes = bench_sizes(material, Effects(**scaled), sensor, seed, profile, layout)
        if abs(sizes["size_live"] / size - 1.0) <= LIMIT_TOLERANCE:
            break
        step = size / sizes["size_live"] if sizes["size_live"] > 0.0 else 10.0
        if not LIMIT_SCALES[0] <= scale * step <= LIMIT_SCALES[1]:
            break   # a saturated array reads no more of a larger effect: stop at the last try
        scale *= step
    return scaled, named, sizes


def bench_separable_sizes(rng: np.random.Generator, index: int, noise_scale: float = 1.0,
                          quick: bool = False) -> list[float]:
    """Each hidden effect's ``size_separable`` of bench bag ``index`` drawn from ``rng``
    (``bench_bag``'s draws, nothing written): the bench asks it of each bag it made, and of
    the bags of runs merged that lack it (``rheo bench diagnosis --merge ... --generator``)."""
    material, profile, _, sensor, layout, seed = _bench_draw(rng, noise_scale, quick)
    return _separable_sizes(material, _bench_hidden(rng, index, material, profile, layout),
                            sensor, seed, profile, layout)


def _bench_draw(rng: np.random.Generator, noise_scale: float, quick: bool
                ) -> tuple[Material, Profile, Sensor, Sensor, Layout, int]:
    """``bench_bag``'s material, profile, sensor (as drawn, and with its noises scaled),
    layout and noise seed."""
    E = _log_uniform(rng, 1e4, 1e5)
    material = Material(E=E, c1=E * float(rng.uniform(2.0, 15.0)), c2=E * float(rng.uniform(300.0, 3000.0)),
                        gamma=float(rng.uniform(0.2, 0.45)))
    keep, release = (BENCH_QUICK_KEEP, BENCH_QUICK_RELEASE) if quick else (BENCH_KEEP, BENCH_RELEASE)
    profile = Profile(depth=float(rng.uniform(0.005, 0.012)), keep_time=float(rng.uniform(*keep)),
                      release_time=float(rng.uniform(*release)))
    base = SENSORS[str(rng.choice(BENCH_SENSORS))]
    sensor = replace(base, noise=base.noise * noise_scale, marker_noise=base.marker_noise * noise_scale)
    return material, profile, base, sensor, Layout(), int(rng.integers(0, 2**31 - 1))


def _bench_hidden(rng: np.random.Generator, index: int, material: Material, profile: Profile,
                  layout: Layout) -> list[tuple[str, str, dict[str, Any], dict[str, float]]]:
    """``bench_bag``'s hidden effects: ``index mod 3`` of distinct families (family, form,
    ``Effects`` fields, values)."""
    return [(str(family), *bench_effect(rng, family, material, profile, layout.height))
            for family in rng.choice(BENCH_FAMILIES, size=index % 3, replace=False)]


def _separable_sizes(material: Material, drawn: list[tuple[str, str, dict[str, Any], dict[str, float]]],
                     sensor: Sensor, seed: int, profile: Profile, layout: Layout) -> list[float]:
    """``bench_separable`` of each drawn effect beside the others."""
    return [bench_separable(material, Effects(**fields),
                            Effects(**{k: v for j, (_, _, f, _) in enumerate(drawn) if j != i for k, v in f.items()}),
                            sensor, seed, profile, layout)
            for i, (_, _, fields, _) in enumerate(drawn)]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Independent bag generator (homogeneous block).")
    ap.add_argument("out", type=Path)
    ap.add_argument("--effect", default="none", choices=sorted(EFFECTS))
    ap.add_argument("--sensor", default="default_like", choices=sorted(SENSORS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--retract-speed", type=float, default=None)
    ap.add_argument("--pushes", type=int, default=1, help="pushes on the same specimen")
    ap.add_argument("--pause", type=float, default=0.0, help="s at depth 0 between pushes")
    ap.add_argument("--no-params-in-metadata", action="store_true")
    args = ap.parse_args(argv)
    generate(args.out, effects=args.effect, sensor=args.sensor, seed=args.seed,
             profile=Profile(retract_speed=args.retract_speed, pushes=args.pushes, pause=args.pause),
             params_in_metadata=not args.no_params_in_metadata)


if __name__ == "__main__":
    main()
