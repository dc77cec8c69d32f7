"""One experiment's measurements as the estimator sees them, and its phases."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rheo_ros.experiment import Phase, StageProfile
from rheo_ros.fe.mesh import Mesh


class RecordError(ValueError):
    """A record cannot be analysed; the message names the source and the field."""


@dataclass(frozen=True)
class Record:
    """Measurements of one push-keep-release run.

    Attributes:
        mesh: specimen mesh; its nodes are the markers' reference positions.
        stage_t, stage_depth: stage depth (m, positive into the specimen) at times (s).
        force_t, force: bottom nodal forces P1..Pn (N, positive pressing), (T, n).
        marker_t, markers: marker positions (m, specimen frame), (Tm, N, 2).
        source: where the data came from, for messages.
    """

    mesh: Mesh
    stage_t: np.ndarray
    stage_depth: np.ndarray
    force_t: np.ndarray
    force: np.ndarray
    marker_t: np.ndarray
    markers: np.ndarray
    source: str = "<memory>"

    def __post_init__(self) -> None:
        checks = [
            ("stage", self.stage_t, self.stage_depth.shape[:1]),
            ("force", self.force_t, self.force.shape[:1]),
            ("markers", self.marker_t, self.markers.shape[:1]),
        ]
        for name, t, n in checks:
            if t.shape[:1] != n:
                raise RecordError(f"{self.source}: {name}: {t.shape[0]} stamps for {n[0]} samples")
            if t.size < 2 or np.any(np.diff(t) <= 0):
                raise RecordError(f"{self.source}: {name}: stamps must be strictly increasing (>= 2 samples)")
        if self.force.shape[1:] != (self.mesh.cols,):
            raise RecordError(f"{self.source}: force: {self.force.shape[1:]} nodes, mesh has {self.mesh.cols}")
        if self.markers.shape[1:] != self.mesh.nodes.shape:
            raise RecordError(f"{self.source}: markers: shape {self.markers.shape[1:]}, mesh {self.mesh.nodes.shape}")
        for name, a in (("stage", self.stage_depth), ("force", self.force), ("markers", self.markers)):
            if not np.all(np.isfinite(a)):
                raise RecordError(f"{self.source}: {name}: non-finite values")

    @property
    def marker_displacement(self) -> np.ndarray:
        return self.markers - self.mesh.nodes[None]

    def profile(self) -> StageProfile:
        """The stage profile read off the stage samples (see ``segment_stage``)."""
        return segment_stage(self.stage_t, self.stage_depth, self.source)

    def phases(self) -> tuple[Phase, Phase, Phase]:
        return self.profile().phases


def segment_stage(t: np.ndarray, depth: np.ndarray, source: str = "<memory>") -> StageProfile:
    """Pull, keep and release from the stage depth alone.

    Pull is the constant-velocity ramp: a line fitted to the samples between 5 % and
    95 % of the maximum depth gives its velocity and, where it meets 0 and the
    maximum, its start and end to a fraction of a sample. Release starts where the
    stage leaves the maximum depth: extrapolated back along the retraction from the
    first two samples that have left it (an instant release: the first one).
    """
    d_max = float(np.max(depth))
    if d_max <= 0:
        raise RecordError(f"{source}: stage: depth never positive, no pull phase")
    tol = 1e-3 * d_max
    at_max = np.flatnonzero(depth >= d_max - tol)
    ramp = (depth > 0.05 * d_max) & (depth < 0.95 * d_max) & (np.arange(t.size) < at_max[0])
    if ramp.sum() < 2:
        raise RecordError(f"{source}: stage: fewer than 2 samples in the pull ramp")
    velocity, intercept = np.polyfit(t[ramp], depth[ramp], 1)
    t_start = -intercept / velocity
    t_pull_end = (d_max - intercept) / velocity
    left = np.flatnonzero((t > t[at_max[0]]) & (depth < d_max - tol))
    if left.size == 0:
        raise RecordError(f"{source}: stage: no release (depth held to the end)")
    i = left[0]
    t_keep_end, retract = float(t[i]), np.inf
    if i + 1 < t.size and 0 < depth[i + 1] < depth[i]:
        retract = float((depth[i] - depth[i + 1]) / (t[i + 1] - t[i]))
        t_keep_end = max(float(t[i] - (d_max - depth[i]) / retract), float(t[i - 1]))
    return StageProfile(
        depth=d_max, velocity=float(velocity), keep_time=t_keep_end - t_pull_end,
        start_delay=float(t_start), release_time=float(t[-1] - t_keep_end), retract_speed=retract,
    )
