"""The hardware stand-in: stage samples in, tactile images and marker frames out.

One streaming core for the simulator node (stage messages over DDS) and for
``rheo simulate`` (stage samples from the profile, written to a bag): both step the
same FE model with the same stage samples, so their outputs agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rheo_ros.experiment import sample_times
from rheo_ros.fe.dynamic import DynamicFE
from rheo_ros.models.effects import Release
from rheo_ros.params import Setup


@dataclass(frozen=True)
class Frame:
    """A sensor output: ``kind`` 'tactile' (pressure (rows, cols) Pa, float32) or
    'markers' (positions (N, 2) m), at time ``t`` (s)."""

    kind: str
    t: float
    data: np.ndarray


class Simulator:
    """The specimen on the sensor under the stage, with its hidden effects and noise.

    Args:
        setup: geometry, material, effects, sensors and rates.
        seed: noise seed; the same seed and stage samples give the same frames.
    """

    def __init__(self, setup: Setup, seed: int = 0) -> None:
        p = setup.params
        self.setup, self.mesh = setup, setup.mesh
        self.model = setup.model()
        self.tactile, self.camera = setup.tactile, setup.camera
        self.fe = DynamicFE(self.mesh, self.model.rheology(), setup.gamma,
                            density=p["material.density"], omega=p["simulator.omega"])
        tactile_seq, marker_seq = np.random.SeedSequence(seed).spawn(2)
        self.tactile_rng, self.marker_rng = np.random.default_rng(tactile_seq), np.random.default_rng(marker_seq)
        self.periods = {"tactile": 1.0 / p["rates.tactile"], "markers": 1.0 / p["rates.markers"]}
        self.due = {"tactile": 0.0, "markers": 0.0}
        self.started = False
        self.release: Release | None = None
        self._contact_force = np.zeros(self.mesh.cols)

    def specimen_force(self) -> np.ndarray:
        """Bottom nodal forces (N) the specimen's stress exerts now."""
        return self.fe.bottom_force() * float(self.model.stress_scale(np.array(self.fe.strain())))

    def step(self, t: float, depth: float) -> list[Frame]:
        """Advance to ``t`` (s) with the stage at ``depth`` (m); the frames due by then."""
        if not self.started:
            self.fe.reset(t)
            self.due = {k: t for k in self.due}
            self.started = True
        held = self.fe.contact == "held"
        self.fe.advance(t, depth)
        if held and self.fe.contact == "free" and self.release is None:
            self.release = Release(t, self._contact_force)  # force at the last sample in contact
        force = self.specimen_force()
        if self.fe.contact == "held":
            self._contact_force = force
        frames = []
        if t >= self.due["tactile"] - 1e-9:
            felt = self.model.measured_force(np.array([t]), force[None], self.release)
            image = self.tactile.read(self.tactile.pressure(felt), self.tactile_rng)[0]
            frames.append(Frame("tactile", t, image))
        if t >= self.due["markers"] - 1e-9:
            positions = self.mesh.nodes + self.fe.displacement()
            frames.append(Frame("markers", t, self.camera.observe(positions, self.marker_rng)))
        for kind in self.due:
            while self.due[kind] <= t + 1e-9:
                self.due[kind] += self.periods[kind]
        return frames


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


def simulate_run(setup: Setup, seed: int = 0) -> Run:
    """The whole run at once: the same FE model, effects and sensors as ``Simulator``,
    vectorised over the samples (what ``rheo simulate`` writes)."""
    p, profile, mesh = setup.params, setup.profile, setup.mesh
    model = setup.model()
    fe = DynamicFE(mesh, model.rheology(), setup.gamma, density=p["material.density"], omega=p["simulator.omega"])
    stage_t, depth, velocity = stage_samples(setup)
    tactile_t = sample_times(profile.t_end, p["rates.tactile"])
    marker_t = sample_times(profile.t_end, p["rates.markers"])
    t = np.union1d(tactile_t, marker_t)
    res = fe.simulate(profile, t)
    force = res.bottom_force * model.stress_scale(res.strain)[:, None]
    felt = model.measured_force(t, force, Release.find(t, force, res.contact))
    tactile_seq, marker_seq = np.random.SeedSequence(seed).spawn(2)
    ti, mi = np.searchsorted(t, tactile_t), np.searchsorted(t, marker_t)
    images = setup.tactile.read(setup.tactile.pressure(felt[ti]), np.random.default_rng(tactile_seq))
    markers = setup.camera.observe(mesh.nodes[None] + res.displacement[mi], np.random.default_rng(marker_seq))
    return Run(stage_t, depth, velocity, tactile_t, images, marker_t, markers)
