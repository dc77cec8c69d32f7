"""Model against measurement: residual statistics per phase and per signal, judged
against the sensor noise the data show.

For each phase (before contact, pull, keep, release) and each signal (every tactile
segment P1..Pn, their total, the marker mesh) it gives the RMS and the bias of the
residuals, both over the signal's noise, a whiteness test (Ljung-Box: a right model
leaves white residuals, a missing effect leaves a slow structure) and the time
windows where the residuals' running mean stands out of the noise.

Live tactile readings away from the phase boundaries count (``identification.noise``): the dead band reads an
exact zero where the true force is small, and clipped noise leaves a small positive
reading where it is zero; either would look like adhesion or drift to a comparison
that took the readings at face value. A reading that is not live counts where the
model lies outside what it stands for (``fit.ReadingBounds``: above the live threshold,
or below the force its window of readings shows, ``fit.ReadingWindows``), by that excess: a right
model leaves such a reading about once in a thousand, a force the model misses under
the dead band leaves them all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc

from rheo_ros.experiment import PHASES, StageProfile, phase_of
from rheo_ros.fe.quasistatic import QuasiStaticFE
from rheo_ros.identification.fit import ReadingBounds, ReadingWindows, bounds, steady_readings
from rheo_ros.identification.noise import SensorNoise, sensor_noise
from rheo_ros.models.effects import Model
from rheo_ros.record import Record

WINDOW_S = 1.0        # running mean over this span (s) for systematic windows
# Residuals averaged over bins this long (s) for the binned chi-square: a smooth misfit
# keeps its whole chi-square in the bins' means while the noise's expectation falls from
# one per reading to one per bin (module docstring).
BIN_S = 1.0
WINDOW_SIGMAS = 4.0   # a window stands out when its mean exceeds this many of its own std
MAX_LAGS = 20         # Ljung-Box lags (fewer on short series: a fifth of the samples)


@dataclass(frozen=True)
class ResidualStats:
    """Residuals of one signal in one phase.

    Attributes:
        signal: ``P1``..``Pn``, ``total`` (N) or ``markers`` (m).
        phase: ``before``, ``pull``, ``keep`` or ``release``.
        samples: residuals counted.
        rms, bias: in the signal's unit.
        noise: the sensor noise std of one residual (same unit).
        whiteness_p: Ljung-Box p-value (small: the residuals are correlated in time).
        windows: (start, end) times (s) where the running mean stands out of the noise.
        binned_chi2, binned_expectation: the chi-square of the residuals' means over
            ``BIN_S`` bins (each over its own std, noise / sqrt(readings in it)) and what the
            noise alone would give it (``binned_chi_square``: each bin its share of live
            readings); a misfit smooth over a bin keeps its whole chi-square.
    """

    signal: str
    phase: str
    samples: int
    rms: float
    bias: float
    noise: float
    whiteness_p: float
    windows: tuple[tuple[float, float], ...]
    binned_chi2: float = 0.0
    binned_expectation: float = 0.0

    @property
    def rms_over_noise(self) -> float:
        return self.rms / self.noise if self.noise > 0 else float("nan")


def ljung_box_p(r: np.ndarray, lags: int = MAX_LAGS) -> float:
    """Ljung-Box p-value of a residual series ``r`` being white (NaN when too short)."""
    r = np.asarray(r, float)
    n = r.size
    h = min(lags, n // 5)
    if h < 1:
        return float("nan")
    r = r - r.mean()
    denom = r @ r
    if denom == 0:
        return float("nan")
    rho = np.array([r[:-k] @ r[k:] for k in range(1, h + 1)]) / denom
    q = n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, h + 1)))
    return float(chdtrc(h, q))   # chi-square(h) survival (scipy.stats' chi2.sf, without its import)


def systematic_windows(t: np.ndarray, r: np.ndarray, noise: float) -> tuple[tuple[float, float], ...]:
    """Spans of ``t`` where the running mean of ``r`` over ``WINDOW_S`` exceeds
    ``WINDOW_SIGMAS`` x ``noise`` / sqrt(samples in the window)."""
    if t.size < 3 or not noise > 0:
        return ()
    dt = float(np.median(np.diff(t)))
    w = max(int(round(WINDOW_S / dt)), 1)
    if t.size < w:
        return ()
    mean = np.convolve(r, np.ones(w) / w, mode="valid")
    out = np.abs(mean) > WINDOW_SIGMAS * noise / np.sqrt(w)
    # A running mean at index i covers samples i .. i + w - 1: a sample is in a window
    # when any mean covering it stands out; runs that touch merge into one span.
    covered = np.convolve(out.astype(int), np.ones(w, int), mode="full")[: t.size] > 0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], covered.astype(int), [0]])))
    return tuple((float(t[a]), float(t[b - 1])) for a, b in zip(edges[::2], edges[1::2]))


def residual_stats(signal: str, t: np.ndarray, r: np.ndarray, noise: float,
                   profile: StageProfile, floor: float = 0.0, noisy: np.ndarray | None = None) -> list[ResidualStats]:
    """Per-phase statistics of one signal's residuals ``r`` (T,) or (T, k) at times ``t``;
    a (T, k) signal (the markers' coordinates) is pooled over its columns. ``floor``: the
    part of ``noise`` that is the model's own systematic floor (``SensorNoise.floored``).
    ``noisy`` (T,): the residuals that carry the noise (None: all); the others are a
    bound's excess (``fit.ReadingBounds``), zero unless the model leaves the bound."""
    r2 = np.asarray(r, float).reshape(len(t), -1)
    noisy = np.ones(len(t), bool) if noisy is None else np.asarray(noisy, bool)
    which = phase_of(t, profile)
    out = []
    for i, name in enumerate(PHASES):
        sel = which == i
        if not sel.any():
            continue
        x = r2[sel]
        series = x.mean(axis=1)   # markers: the mean over coordinates keeps a shared drift visible
        per_sample = noise / np.sqrt(x.shape[1])
        binned_chi2, expectation = binned_chi_square(t[sel], x, noise, floor, noisy[sel])
        out.append(ResidualStats(
            signal=signal, phase=name, samples=int(x.size), rms=float(np.sqrt(np.mean(x**2))),
            bias=float(x.mean()), noise=float(noise), whiteness_p=ljung_box_p(series),
            windows=systematic_windows(t[sel], series, per_sample), binned_chi2=binned_chi2,
            binned_expectation=expectation,
        ))
    return out


def binned_chi_square(t: np.ndarray, x: np.ndarray, noise: float, floor: float = 0.0,
                      noisy: np.ndarray | None = None) -> tuple[float, float]:
    """Chi-square of the means of ``x`` (T, k) over ``BIN_S`` bins of ``t`` (T,), each
    column apart, each mean over its std; and its expectation under the noise alone (0, 0
    without a noise). Of ``noise`` per reading, the sensor's part averages down over a
    bin's readings and the model's ``floor`` does not (a systematic error, the same
    through the bin). A bin expects its share of ``noisy`` readings (T,; None: all): a
    bound's excess carries no noise, so a bin of them expects nothing, and a model that
    leaves the bounds misfits there by the whole of its chi-square (counted as noise, a
    held adhesion under the dead band was diluted to a 1.3-std excess by its own bins)."""
    if not noise > 0 or t.size == 0:
        return 0.0, 0.0
    label = np.floor((t - t[0]) / BIN_S).astype(np.int64)
    _, label, size = np.unique(label, return_inverse=True, return_counts=True)
    means = np.stack([np.bincount(label, weights=col) for col in x.T], axis=1) / size[:, None]
    variance = max(noise**2 - floor**2, 0.0) / size + floor**2
    share = np.ones(size.size) if noisy is None else np.bincount(label, weights=noisy) / size
    return float(np.sum(means**2 / variance[:, None])), float(share.sum() * x.shape[1])


@dataclass(frozen=True)
class Comparison:
    """A model's residuals against one record: ``stats`` per signal and phase."""

    model: str
    stats: tuple[ResidualStats, ...]

    def get(self, signal: str, phase: str) -> ResidualStats | None:
        return next((s for s in self.stats if s.signal == signal and s.phase == phase), None)

    def rmse_by_phase(self) -> dict[str, float]:
        """RMS error of the total force per phase (N), as the JSON report has it."""
        return {s.phase: s.rms for s in self.stats if s.signal == "total"}


def compare(record: Record, model: Model, gamma: float, forward: QuasiStaticFE,
            delays: tuple[float, float] = (0.0, 0.0), noise: SensorNoise | None = None) -> Comparison:
    """Residuals of ``model`` (with its parameter values) and ``gamma`` against ``record``.

    Args:
        forward: the forward model (``Setup.forward_model()``).
        delays: the tactile and marker streams' clock offsets (s) the fit found.
        noise: the record's sensor noise (default: estimated from it).
    """
    noise = noise or sensor_noise(record)
    profile = record.profile()
    p = forward.predict(model, gamma, profile, record.force_t - delays[0], record.marker_t - delays[1])
    # Readings at a phase boundary are mid-jump: left out, as the fit leaves them out.
    steady = steady_readings(record)[:, None]
    live = noise.force_live & steady
    rf = np.where(live, p.force - record.force, np.nan)
    limits = bounds(record, noise.force_std)
    if limits["ceiling"] is not None:
        bounded = ~noise.force_live & steady & (True if noise.force_spikes is None else ~noise.force_spikes)
        windows = ReadingWindows(record.dead_band, record.force, bounded, limits["window_std"])
        excess = np.zeros(bounded.shape)
        excess[bounded] = ReadingBounds(record.force, limits["ceiling"], limits["top"], windows,
                                        np.flatnonzero(bounded)).excess(p.force)
        rf = np.where(bounded & (excess != 0.0), excess, rf)
    counted = np.isfinite(rf)
    force_floor = np.broadcast_to(noise.force_floor, noise.force_std.shape)
    stats: list[ResidualStats] = []
    for j in range(rf.shape[1]):
        rows = counted[:, j]
        if rows.sum() >= 3 and np.isfinite(noise.force_std[j]):
            stats += residual_stats(f"P{j + 1}", record.force_t[rows], rf[rows, j], noise.force_std[j], profile,
                                    float(force_floor[j]), live[rows, j])
    # The total: readings every segment has live (a bound's excess is no reading to sum).
    every = live.all(axis=1) & np.all(np.isfinite(noise.force_std))
    if every.sum() >= 3:
        total_noise = float(np.sqrt(np.sum(noise.force_std**2)))
        # The segments' floors are one model's error: they add up, they do not average.
        stats += residual_stats("total", record.force_t[every], rf[every].sum(axis=1), total_noise, profile,
                                min(float(force_floor.sum()), total_noise))
    # Each marker's start is a nuisance (the fit profiles it out): residuals about its mean.
    rm = p.displacement - (record.markers - record.mesh.nodes[None])
    rm = rm - rm.mean(axis=0)
    stats += residual_stats("markers", record.marker_t, rm.reshape(len(record.marker_t), -1),
                            noise.marker_std, profile, noise.marker_floor)
    return Comparison(model.name, tuple(stats))
