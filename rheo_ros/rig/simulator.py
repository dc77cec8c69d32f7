"""The hardware stand-in: stage samples in, tactile images and marker frames out.

The one simulator of the package, built from a ``Setup`` (geometry, material, hidden
effects, sensors, rates): ``Simulator`` streams it for the simulator node (stage
messages over DDS); ``simulate_clean`` runs it over the whole profile at once, then
``observe`` adds the sensors (what ``rheo simulate`` writes) or ``CleanRun.record``
gives the noise-free record the benches and tests identify. The same FE model and
effects in each, so their outputs agree; the one noise model is the sensors'
(``rheo_ros.sensors``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from rheo_ros.config.setup import Setup
from rheo_ros.experiment import sample_times
from rheo_ros.models.effects import Release
from rheo_ros.record import Record


@dataclass(frozen=True)
class Frame:
    """A sensor output: ``kind`` 'tactile' (pressure (rows, cols) Pa, float32) or
    'markers' (positions (N, 2) m), at time ``t`` (s)."""

    kind: str
    t: float
    data: np.ndarray


class Simulator:
    """The specimen on the sensor under the stage, with its hidden effects and noise.

    Stage samples may come at any times (over DDS, with jitter); the model steps on
    its own grid of one stage period from the first sample, with the stage linear
    between samples, and stamps its frames with grid times.

    Args:
        setup: geometry, material, effects, sensors and rates.
        seed: noise seed; the same seed and stage samples give the same frames.
    """

    def __init__(self, setup: Setup, seed: int = 0) -> None:
        p = setup.params
        self.setup, self.mesh = setup, setup.mesh
        self.model = setup.model()
        self.tactile, self.camera = setup.tactile, setup.camera
        self.fe = setup.dynamic_fe(self.model.rheology())
        tactile_seq, marker_seq = np.random.SeedSequence(seed).spawn(2)
        self.tactile_rng, self.marker_rng = np.random.default_rng(tactile_seq), np.random.default_rng(marker_seq)
        self.step_s = 1.0 / p["rates.stage"]
        self.fe.prepare(self.step_s)   # a real-time run must not stall at its first step or at release
        self.every = {"tactile": round(p["rates.stage"] / p["rates.tactile"]),
                      "markers": round(p["rates.stage"] / p["rates.markers"])}
        self.k = -1                      # grid index of the model's time
        self.last: tuple[float, float] | None = None   # last stage sample (t, depth)
        self.release: Release | None = None
        self._contact_force = np.zeros(self.mesh.cols)
        # Effects with memory get the stretch of the run they depend on, step by step as
        # ``simulate_clean`` has it: (t, linear bottom forces, nominal strain, marker
        # displacements) per step.
        self.memory = self.model.memory
        self._history: deque[tuple[float, np.ndarray, float, np.ndarray]] = deque()

    @property
    def t(self) -> float:
        return self.k * self.step_s

    def specimen_force(self) -> np.ndarray:
        """Bottom nodal forces (N) the specimen's stress exerts now."""
        if not self.memory:
            return self.fe.bottom_force() * float(self.model.stress_scale(np.array(self.fe.strain())))
        _, force, strain, _ = self._past()
        return force[-1] * self.model.stress_scale(strain)[-1]

    def _past(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The steps the effects' memory reaches back to: times (s), linear bottom forces
        (T, nodes) N, nominal strains (T,) and marker displacements (T, N, 2) m."""
        t, force, strain, displacement = zip(*self._history)
        return np.array(t), np.array(force), np.array(strain), np.array(displacement)

    def _felt_force(self) -> np.ndarray:
        """The bottom nodal forces (N) the sensor feels now (the effects' hooks)."""
        if not self.memory:
            return self.model.measured_force(np.array([self.t]), self.specimen_force()[None], self.release)[0]
        t, force, strain, _ = self._past()
        return self.model.measured_force(t, force * self.model.stress_scale(strain)[:, None], self.release)[-1]

    def _seen_displacement(self) -> np.ndarray:
        """The marker displacements (N, 2) in m the camera sees now (the effects' hooks)."""
        if not self.memory:
            return self.model.measured_markers(np.array([self.t]), self.fe.displacement()[None])[0]
        t, _, _, displacement = self._past()
        return self.model.measured_markers(t, displacement)[-1]

    def _remember(self) -> None:
        if self.memory:
            self._history.append((self.t, self.fe.bottom_force(), float(self.fe.strain()), self.fe.displacement()))
            while self._history[0][0] < self.t - self.memory:
                self._history.popleft()

    def step(self, t: float, depth: float) -> list[Frame]:
        """Take a stage sample (``t`` s from the run's start, ``depth`` m); return the
        frames of every grid time reached."""
        frames: list[Frame] = []
        if self.last is None:
            self.last, self.k = (t, depth), 0
            self.fe.reset(0.0)
            self._remember()
            frames += self._frames()
            return frames
        t0, d0 = self.last
        if t <= t0:
            return frames  # late or repeated sample: the model has moved on
        while (self.k + 1) * self.step_s <= t + 1e-9:
            self.k += 1
            tk = self.k * self.step_s
            self._advance(tk, d0 + (depth - d0) * min(1.0, (tk - t0) / (t - t0)))
            frames += self._frames()
        self.last = (t, depth)
        return frames

    def new_block(self) -> None:
        """Another block of the same material put in place, at rest, the stage touching
        it at depth 0 (an identify goal's ``object: new``); the old one's set and recovery
        go with it. The stage should be at depth 0 (off the old block) when this is called."""
        if self.last is not None:
            self.fe.reset(self.t)
        self.release, self._contact_force = None, np.zeros(self.mesh.cols)
        self._history.clear()   # the old block's past is not the new one's
        if self.last is not None:
            self._remember()

    def _advance(self, t: float, depth: float) -> None:
        held = self.fe.contact == "held"
        self.fe.advance(t, depth)
        self._remember()
        if held and self.fe.contact == "free" and self.release is None:
            self.release = Release(t, self._contact_force)  # force at the last step in contact
        if self.fe.contact == "held":
            self._contact_force = self.specimen_force()

    def _frames(self) -> list[Frame]:
        out = []
        if self.k % self.every["tactile"] == 0:
            felt = self._felt_force()[None]
            out.append(Frame("tactile", self.t, self.tactile.read(self.tactile.pressure(felt), self.tactile_rng)[0]))
        if self.k % self.every["markers"] == 0:
            positions = self.mesh.nodes + self._seen_displacement()
            out.append(Frame("markers", self.t, self.camera.observe(positions, self.marker_rng)))
        return out


def stage_samples(setup: Setup) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The simulated stage's samples: times (s), depth (m), velocity (m/s)."""
    profile = setup.profile
    t = sample_times(profile.t_end, setup.params["rates.stage"])
    return t, profile.depth_at(t), profile.velocity_at(t)


@dataclass(frozen=True)
class Run:
    """A whole simulated run as the sensors report it (the contents of a bag)."""

    stage_t: np.ndarray
    stage_depth: np.ndarray
    stage_velocity: np.ndarray
    tactile_t: np.ndarray
    tactile: np.ndarray      # (T, rows, cols) float32 Pa
    marker_t: np.ndarray
    markers: np.ndarray      # (Tm, N, 2) m


@dataclass(frozen=True)
class CleanRun:
    """The FE model's run, once, before any sensor: what each bottom node's segment
    would feel (effects included) and where the markers are."""

    stage_t: np.ndarray
    stage_depth: np.ndarray
    stage_velocity: np.ndarray
    tactile_t: np.ndarray
    force: np.ndarray        # (T, nodes) N, felt by each tactile segment, noise-free
    marker_t: np.ndarray
    positions: np.ndarray    # (Tm, N, 2) m, noise-free

    def record(self, setup: Setup, source: str) -> Record:
        """The noise-free record of this run as the model has it (segment forces, no
        dead band): the benches' and tests' reference data."""
        return Record(mesh=setup.mesh, stage_t=self.stage_t, stage_depth=self.stage_depth, force_t=self.tactile_t,
                      force=self.force, marker_t=self.marker_t, markers=self.positions, source=source)


def simulate_clean(setup: Setup) -> CleanRun:
    """The FE model with its effects over the whole profile, vectorised over the samples."""
    p, profile, mesh = setup.params, setup.profile, setup.mesh
    model = setup.model()
    fe = setup.dynamic_fe(model.rheology())
    stage_t, depth, velocity = stage_samples(setup)
    tactile_t = sample_times(profile.t_end, p["rates.tactile"])
    marker_t = sample_times(profile.t_end, p["rates.markers"])
    # Steps on the stage's grid too, as the streaming ``Simulator`` does: the same steps,
    # the same numbers (the step size moves the FE's results by ~1e-8).
    t = np.union1d(stage_t, np.union1d(tactile_t, marker_t))
    felt, seen = fe.clean_signals(model, profile, t, tactile_t, marker_t)
    return CleanRun(stage_t, depth, velocity, tactile_t, felt, marker_t, mesh.nodes[None] + seen)


def observe(setup: Setup, clean: CleanRun, seed: int = 0) -> Run:
    """The sensors' reports of a clean run: the same noise as ``Simulator`` for ``seed``."""
    tactile_seq, marker_seq = np.random.SeedSequence(seed).spawn(2)
    images = setup.tactile.read(setup.tactile.pressure(clean.force), np.random.default_rng(tactile_seq))
    markers = setup.camera.observe(clean.positions, np.random.default_rng(marker_seq))
    return Run(clean.stage_t, clean.stage_depth, clean.stage_velocity, clean.tactile_t, images,
               clean.marker_t, markers)


def simulate_run(setup: Setup, seed: int = 0) -> Run:
    """The whole run at once: the same FE model, effects and sensors as ``Simulator``,
    vectorised over the samples (what ``rheo simulate`` writes)."""
    return observe(setup, simulate_clean(setup), seed)
