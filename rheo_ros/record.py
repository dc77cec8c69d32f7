"""One experiment's measurements as the estimator sees them, and its phases."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rheo_ros.experiment import StageProfile
from rheo_ros.fe.mesh import Mesh
from rheo_ros.sensors import DeadBand, SensorReading

# s before the first contact that a frame counts as unloaded: the contact is read off the
# stage's ramp (to a fraction of a sample), and a viscous specimen's force jumps there.
UNLOADED_GUARD = 0.1


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
        stage_profile: the phases when already known (the online segmenter's, for a
            run still in progress); ``None``: read off the stage samples.
        sensor: the sensor as the data show it (``sensors.read_sensor``): its dead band
            says where the tactile segments' readings are live; ``None``: a noise-free
            model record, live everywhere.
    """

    mesh: Mesh
    stage_t: np.ndarray
    stage_depth: np.ndarray
    force_t: np.ndarray
    force: np.ndarray
    marker_t: np.ndarray
    markers: np.ndarray
    source: str = "<memory>"
    stage_profile: StageProfile | None = None
    sensor: SensorReading | None = None

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

    @cached_property
    def dead_band(self) -> DeadBand | None:
        """Where the tactile segments' readings are live (``None``: everywhere), with the
        most a reading exceeds its force as the frames before the first contact show it
        (``DeadBand.unloaded``)."""
        band = None if self.sensor is None else self.sensor.tactile.dead_band
        if band is None:
            return None
        profile = self.profile()
        contact = min([p.t_pull_start for p in profile.before] + [profile.t_pull_start])
        tactile = self.sensor.tactile
        return band.unloaded(self.force[self.force_t < contact - UNLOADED_GUARD], tactile.noise * tactile.cell_area)

    def sensor_json(self) -> dict | None:
        """The sensor model the analysis used (``SensorReading.to_json``), with the most a
        cell's mean reading exceeds its pressure under the dead band (``tactile.excess``,
        Pa a cell at the cells' noise: ``used``, and ``measured`` on the unloaded array
        before contact or null where too few frames show it); None: no sensor."""
        if self.sensor is None:
            return None
        sensor = self.sensor.to_json()
        band, tactile = self.dead_band, self.sensor.tactile
        if band is not None and np.isfinite(tactile.noise):
            cells = np.asarray(band.cells, float)
            per_cell = tactile.cell_area * cells   # a segment's N per Pa in each of its cells
            used = band.excess(tactile.segment_noise) / per_cell
            measured = None if band.measured_excess is None else float(np.max(band.measured_excess / per_cell))
            sensor["tactile"]["excess"] = {"used": float(np.max(used)), "measured": measured}
        return sensor

    def reading(self, force: np.ndarray) -> np.ndarray:
        """What the tactile segments read of model forces (T, n) in N: through the dead
        band where the record has one (``DeadBand.reading``), else the forces."""
        return force if self.dead_band is None else self.dead_band.reading(force)

    @cached_property
    def marker_reference(self) -> np.ndarray:
        """Where each marker starts (N, 2): the mean of the frames before the pull, or
        the mesh's nominal grid when there are none. Markers drawn by hand are never
        exactly on the design grid, and the paper measures displacements from the
        initial positions."""
        before = self.marker_t < self.profile().t_pull_start
        return self.markers[before].mean(axis=0) if before.any() else self.mesh.nodes

    @property
    def marker_displacement(self) -> np.ndarray:
        """Marker displacements (Tm, N, 2) from ``marker_reference``."""
        return self.markers - self.marker_reference[None]

    def profile(self) -> StageProfile:
        """The stage profile: given, or read off the stage samples (``segment_stage``)."""
        return self._profile

    @cached_property
    def _profile(self) -> StageProfile:
        if self.stage_profile is not None:
            return self.stage_profile
        return segment_stage(self.stage_t, self.stage_depth, self.source)


def segment_stage(t: np.ndarray, depth: np.ndarray, source: str = "<memory>") -> StageProfile:
    """Pull, keep and release from the stage depth alone, robust to encoder noise.

    The hold is the plateau near the deepest samples: its median is the depth and
    its spread (median absolute deviation) the encoder noise, which sets the
    tolerance. Pull is the constant-velocity ramp before the plateau: a line fitted
    to the samples between 5 % and 95 % of the depth gives its velocity and, where
    it meets 0 and the depth, its start and end to a fraction of a sample. Release
    starts where the stage leaves the plateau for good (three samples in a row):
    extrapolated back along a line through the retraction, or at that sample when
    the stage left at once.
    """
    t, depth = np.asarray(t, float), np.asarray(depth, float)
    peak = float(np.max(depth))
    if peak <= 0:
        raise RecordError(f"{source}: stage: depth never positive, no pull phase")
    near = depth >= 0.98 * peak
    level = float(np.median(depth[near]))
    noise = 1.4826 * float(np.median(np.abs(depth[near] - level)))
    tol = max(1e-3 * level, 6.0 * noise)
    held = np.flatnonzero(np.abs(depth - level) <= tol)
    first = held[0]
    ramp = (depth > 0.05 * level) & (depth < 0.95 * level) & (np.arange(t.size) < first)
    if ramp.sum() < 2:
        raise RecordError(f"{source}: stage: fewer than 2 samples in the pull ramp")
    velocity, intercept = np.polyfit(t[ramp], depth[ramp], 1)
    if velocity <= 0:
        raise RecordError(f"{source}: stage: the pull ramp does not go deeper")
    t_start, t_pull_end = -intercept / velocity, (level - intercept) / velocity
    below = depth < level - tol
    run = np.convolve(below.astype(int), np.ones(3, int), mode="full")[2:]  # below at i, i+1, i+2
    left = np.flatnonzero((np.arange(t.size) > first) & below & ((run >= 3) | (np.arange(t.size) >= t.size - 2)))
    if left.size == 0:
        raise RecordError(f"{source}: stage: no release (depth held to the end)")
    i = left[0]
    t_keep_end, retract = float(t[i]), np.inf
    j = i
    while j < t.size and 0.05 * level < depth[j] < level - tol:  # the retraction ramp
        j += 1
    seg = np.arange(i, j)
    if seg.size >= 2:
        slope, icept = np.polyfit(t[seg], depth[seg], 1)
        if slope < 0:
            retract = float(-slope)
            # A slow retraction takes several samples to leave the tolerance band: the
            # line meets the plateau anywhere after the hold's first sample.
            t_keep_end = float(np.clip((level - icept) / slope, t[first], t[i]))
    try:
        return StageProfile(
            depth=level, velocity=float(velocity), keep_time=max(t_keep_end - t_pull_end, 0.0),
            start_delay=float(t_start), release_time=float(t[-1] - t_keep_end), retract_speed=retract,
        )
    except ValueError as exc:
        raise RecordError(f"{source}: stage: {exc}") from None


def contact_depth(record: Record) -> float:
    """Where the stage met the specimen in this push (m of stage depth): the push's depth
    less how far the top markers sank between before the push and the hold (they follow
    the stage while it presses). 0 for a first push; a later one meets the permanent set
    the earlier ones left (and whatever recovery is still under way)."""
    profile, mesh = record.profile(), record.mesh
    top = mesh.nodes[:, 1] >= mesh.nodes[:, 1].max() - 1e-12
    before, hold = frames_before(record), frames_held(record)
    if not before.any() or not hold.any():
        return 0.0
    sank = float(np.mean(record.markers[before][:, top, 1]) - np.mean(record.markers[hold][:, top, 1]))
    return float(np.clip(profile.depth - sank, 0.0, profile.depth))


def contact_time(record: Record) -> float:
    """When the stage met the specimen in this push (s): its pull's start, later by the
    ``contact_depth`` at the pull's speed for a push meeting an earlier one's set."""
    profile = record.profile()
    if not profile.before:
        return profile.t_pull_start
    return profile.t_pull_start + contact_depth(record) * profile.pull_time / profile.depth


def frames_before(record: Record) -> np.ndarray:
    """Marker frames before the push's pull."""
    return record.marker_t < record.profile().t_pull_start


def frames_held(record: Record) -> np.ndarray:
    """Marker frames of the hold (between the pull and the let-go)."""
    profile = record.profile()
    return (record.marker_t > profile.t_pull_end) & (record.marker_t < profile.t_keep_end)
