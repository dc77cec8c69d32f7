"""The sensor as the data show it (``sensors.read_sensor``), on readings the package did
not make: the independent generator's sensors (test/generator.py, seed 1, the Table IV
material, the default experiment), with only the contract's names in the parameters."""

from __future__ import annotations

import math
from dataclasses import replace

import generator as g
import numpy as np
import pytest
import yaml

from rheo_ros.config.setup import Setup, parse_params
from rheo_ros.identification.noise import force_noise
from rheo_ros.identification.pipeline import require_readings
from rheo_ros.record import RecordError
from rheo_ros.sensors import (
    LINEAR,
    TactileArray,
    TactileReadout,
    column_difference_noise,
    difference_noise,
    read_sensor,
)

CONTRACT_ONLY = yaml.safe_dump(g.params_document(g.Layout()))
CELL_NOISE = 100.0          # Pa, every noisy sensor of the generator
MARKER_NOISE = 2e-5         # m, all but the noisy camera


def record(sensor: str, params: str = CONTRACT_ONLY, **data_changes):
    data = replace(g.synthesize(sensor=sensor, seed=1), **data_changes)
    setup = Setup(parse_params(params, "<test>"))
    return setup.record(data.stage_t, data.depth, data.tactile_t, data.images, data.marker_t, data.markers)


@pytest.fixture(scope="module")
def records() -> dict:
    return {name: record(name) for name in g.SENSORS}


@pytest.fixture(scope="module")
def sensors(records) -> dict:
    return {name: r.sensor for name, r in records.items()}


@pytest.mark.parametrize("name, threshold, resolution, saturation", [
    ("default_like", 300.0, 10.0, math.inf),
    ("no_dead_band", 0.0, 0.0, math.inf),     # the noise clipped at zero, continuous
    ("clipped", 300.0, 10.0, 4000.0),
    ("quantised", 0.0, 50.0, math.inf),
    ("noisy_camera", 300.0, 10.0, math.inf),
])
def test_each_sensor_law_is_read_from_the_readings(sensors, name, threshold, resolution, saturation):
    """Dead band, clipping at zero, quantisation step and saturation exactly (a dead band
    within one 10 Pa step), the cell noise within 5 % of the generator's 100 Pa (measured
    100.4-103.8 Pa) and the camera's within 5 % (measured 2.010e-5 and 1.005e-4 m), all
    from the data: the parameters name none of them. No warning: nothing was stated."""
    s = sensors[name]
    assert s.tactile.threshold == pytest.approx(threshold, abs=10.0)
    assert s.tactile.resolution == pytest.approx(resolution, rel=1e-6)
    assert s.tactile.saturation == saturation
    assert s.tactile.noise == pytest.approx(CELL_NOISE, rel=0.05)
    camera = 1e-4 if name == "noisy_camera" else MARKER_NOISE
    assert s.marker_noise == pytest.approx(camera, rel=0.05)
    assert set(s.source.values()) == {"data"} and s.warnings == ()
    assert s.tactile.faults == () and s.unreadable == ""   # no cell taken for a faulty one


def test_noise_free_readings_are_read_as_noise_free(sensors):
    """Zero cell and camera noise (not the numerical 1e-8 of a smooth curve's second
    differences); no gap in noise-free readings is taken for a dead band: the default
    300 Pa band, below the first loaded reading, is kept."""
    s = sensors["noise_free"]
    assert s.tactile.noise == 0.0 and s.marker_noise == 0.0
    assert s.tactile.threshold == 300.0 and s.source["tactile.threshold"] == "parameters"
    assert s.tactile.faults == ()   # every cell of a column reads alike: none is faulty


def test_readings_below_zero_are_a_linear_cell():
    """A cell that reports its noise unclipped: no dead band, every reading live."""
    rng = np.random.default_rng(3)
    array = TactileArray(rows=2, cols=5, width=0.05, depth=0.01, nodes=5)
    load = np.linspace(0.0, 5000.0, 400)[:, None, None] * np.ones((1, 2, 5))
    images = (load + 100.0 * rng.standard_normal(load.shape)).astype(np.float32)
    readout = TactileReadout()
    readout.add(images)
    s = read_sensor(array, readout, array.nodal_forces(images), float("nan"), 2e-5)
    assert s.tactile.threshold == LINEAR and s.tactile.dead_band is None
    assert s.tactile.noise == pytest.approx(100.0, rel=0.1)
    assert s.source["markers.noise"] == "parameters" and s.marker_noise == 2e-5


def test_a_coarse_lattice_under_a_small_load_is_read_from_few_values():
    """50 Pa counts of noise clipped at zero under a load of at most 1.5 kPa: 30-odd
    distinct readings, each met hundreds of times, are a lattice (under ``MIN_LATTICE``
    values they had been "not shown", the parameters' 10 Pa used, and the clipped noise's
    first count, 50 Pa, read as a dead band); a handful of frames is not."""
    rng = np.random.default_rng(4)
    array = TactileArray(rows=6, cols=32, nodes=5)
    load = np.linspace(0.0, 1500.0, 2000)[:, None, None] * np.ones((1, 6, 32))
    images = (50.0 * np.round(np.maximum(load + 100.0 * rng.standard_normal(load.shape), 0.0) / 50.0))
    readout = TactileReadout()
    readout.add(images.astype(np.float32))
    assert readout.distinct.size < 50 and readout.resolution == 50.0
    s = read_sensor(array, readout, array.nodal_forces(images), float("nan"), 2e-5)
    assert s.tactile.threshold == 0.0 and s.tactile.resolution == 50.0
    few = TactileReadout()
    few.add(images[-3:].astype(np.float32))
    assert few.resolution is None


def test_the_readout_is_the_same_frame_by_frame_as_whole(sensors):
    """The node adds a block of frames at a time, a bag all at once: the same facts,
    with a cell dying half way (its run and the load its column read meanwhile)."""
    data = g.synthesize(sensor="quantised", seed=1)
    images, t = data.images.copy(), data.tactile_t
    die = int(np.argmax(images[:, 3, 7]))   # under the highest load: it read non-zero until then
    images[die:, 2, 7] = 0.0
    whole, frames = TactileReadout(), TactileReadout()
    whole.add(images, t)
    for k in range(0, len(images), 37):
        frames.add(images[k:k + 37], t[k:k + 37])
    assert whole.readings == frames.readings and whole.zeros == frames.zeros
    assert whole.smallest_positive == frames.smallest_positive and whole.at_largest == frames.at_largest
    np.testing.assert_array_equal(whole.distinct, frames.distinct)
    for cells in ("cell_high", "cell_at_high", "cell_last", "cell_since", "cell_run", "cell_load"):
        np.testing.assert_array_equal(getattr(whole, cells), getattr(frames, cells))
    assert whole.resolution == frames.resolution == 50.0
    assert whole.cell_since[2, 7] == t[die] and whole.cell_run[2, 7] == len(t) - die


def stated(**tactile) -> str:
    doc = g.params_document(g.Layout())
    doc["/**"]["ros__parameters"]["tactile"].update(tactile)
    return yaml.safe_dump(doc)


def test_a_stated_value_the_data_contradict_is_a_warning_and_the_data_win():
    """A file stating a 500 Pa dead band, 40 Pa of noise and 1 Pa steps for the default-like
    sensor (300 Pa, 100 Pa, 10 Pa): one line per field naming it and both values; the
    analysis uses what the data show."""
    s = record("default_like", stated(threshold=500.0, noise=40.0, resolution=1.0)).sensor
    fields = [w.split(":")[0] for w in s.warnings]
    assert sorted(fields) == ["tactile.noise", "tactile.resolution", "tactile.threshold"], s.warnings
    threshold = next(w for w in s.warnings if w.startswith("tactile.threshold"))
    assert "500 Pa" in threshold and "300 Pa" in threshold
    assert s.tactile.threshold == 300.0 and s.tactile.resolution == 10.0
    assert s.tactile.noise == pytest.approx(CELL_NOISE, rel=0.05)


def test_a_stated_dead_band_on_a_clipped_sensor_is_contradicted():
    s = record("no_dead_band", stated(threshold=500.0)).sensor
    assert [w.split(":")[0] for w in s.warnings] == ["tactile.threshold"]
    assert "exact zeros" in s.warnings[0] and s.tactile.threshold == 0.0


def test_a_stated_value_the_data_agree_with_is_silent():
    s = record("default_like", stated(noise=110.0)).sensor
    assert s.warnings == ()


def test_a_record_saturated_most_of_the_time_still_shows_its_noise():
    """A stiff specimen on the clipped sensor (4000 Pa): every cell saturated through most
    of the pull and the keep. A saturated reading has no noise; counted as live, it made
    the segments' noise 0 and the clean model 1e7 x "the noise" off (the bench's bag 6).
    Each segment's noise within 35 % of the generator's cell noise in segment units
    (measured 1-27 %: few readings are clear of saturation, and a segment with some of its
    cells saturated reads less noise than one with none)."""
    from rheo_ros.identification.noise import sensor_noise

    data = g.synthesize(material=g.Material(E=76775.0, c1=4.86e5, c2=1.06e8, gamma=0.43), sensor="clipped",
                        seed=3, profile=g.Profile(depth=0.008, keep_time=16.0, release_time=20.0))
    rec = Setup(parse_params(CONTRACT_ONLY, "<test>")).record(data.stage_t, data.depth, data.tactile_t,
                                                               data.images, data.marker_t, data.markers)
    array = rec.sensor.tactile
    assert np.mean(data.images >= 4000.0) > 0.4                  # most readings are saturated
    noise = sensor_noise(rec).force_std
    expected = CELL_NOISE * np.sqrt(array.cells_per_segment) * array.cell_area
    np.testing.assert_allclose(noise, expected, rtol=0.35)
    require_readings(rec)   # some readings clear of saturation: identified, not refused


@pytest.mark.parametrize("material, seed, profile", [
    (g.Material(E=87711.0, c1=7.585e5, c2=2.575e8, gamma=0.22), 3, g.Profile(depth=0.00925, keep_time=16.0,
                                                                              release_time=23.0)),
    # The diagnosis bench's bag 3 (generator, seed 8, quick): 1-2 readings of the whole
    # record between the dead band and saturation, in two segments of five. It was fitted:
    # E 4.02e4 against 9.13e4, "misfits at 4e6 x the noise" (a noise of 2e-12 N read off
    # the saturated readings themselves).
    (g.Material(E=91303.98, c1=683648.6, c2=1.7312e8, gamma=0.2829), 738757393,
     g.Profile(depth=0.0078136, keep_time=16.034, release_time=21.891)),
])
def test_a_push_read_only_at_saturation_is_refused_in_one_line(material, seed, profile):
    """A stiffer specimen on the clipped sensor: the first instant of the pull already
    presses every cell past 4000 Pa (c1 x the strain rate 4.7 kPa) and the keep never
    relaxes under it; every reading of the pull and the keep is at saturation. Refused,
    naming the stream and each segment's saturation (before, the closed forms failed on
    "the wrong sign for a push" and a fit from elsewhere called the flat line E +- 0.4 %).
    No segment shows its noise: none is read off the saturated readings; the sensor's
    cell noise is then the parameters' (it had been read as 0, a noise-free array)."""
    data = g.synthesize(material=material, sensor="clipped", seed=seed, profile=profile)
    rec = Setup(parse_params(CONTRACT_ONLY, "<test>")).record(data.stage_t, data.depth, data.tactile_t,
                                                               data.images, data.marker_t, data.markers)
    assert np.isnan(force_noise(rec)[0]).all()
    # Not shown is not zero: the cell noise is the parameters' (the default 100 Pa), said so.
    assert rec.sensor.tactile.noise == 100.0 and rec.sensor.source["tactile.noise"] == "parameters"
    with pytest.raises(RecordError, match=r"^<memory>: /tactile/pressure: through the pull and the keep every segment "
                                          r"reads at its saturation \(0\.5, 1, 1, 1, 0\.5 N, P1, P2, \.\.\.\) or under "
                                          r"its dead band \(too few readings between them to show a noise\): the "
                                          r"array did not measure the push's force"):
        require_readings(rec, "/tactile/pressure")


@pytest.mark.parametrize("spread", [0.0, 0.6])
def test_a_readings_floor_holds_however_the_force_spreads_over_the_cells(spread):
    """``fit.ReadingWindows``: the least and the most mean force a window of readings under
    the live threshold stands for (``DeadBand.excess``, ``DeadBand.deficit``). Cells (300 Pa
    dead band, 100 Pa noise, 10 Pa steps) whose pressures differ by ``spread`` (0.6: 60 %
    apart, as the generator's per-cell drift can be) from nothing to over the band: the
    floor lies above the segment's true force, or the ceiling below it, in at most 0.5 % of
    the windows, short or long (three stds of margin: ~0.13 % for a Gaussian mean; measured
    0 of 800 short and 80 long windows at each level); with nothing pressing no floor is
    above zero (no force where there is none); a force of 100 Pa a cell (a third of the band:
    a held adhesion whose readings are nearly all zero) has every long window's floor above
    zero, 150 Pa every short one's; and with no dead band (noise 200 Pa clipped at zero) a
    force of 50 Pa a cell, a quarter of the noise, has every long window's floor above zero."""
    from rheo_ros.identification.fit import LONG_WINDOW, READING_WINDOW, ReadingWindows

    rng = np.random.default_rng(3)
    frames = 800 * READING_WINDOW
    for array, level in [(TactileArray(), level) for level in (0.0, 50.0, 100.0, 150.0, 212.0, 300.0, 430.0, 550.0)] \
            + [(TactileArray(noise=200.0, threshold=0.0, resolution=0.0), level) for level in (0.0, 50.0)]:
        band = array.dead_band
        cells = int(band.cells[2])
        seg_std = np.sqrt(cells) * array.noise * array.cell_area   # N: the segment's noise
        pressure = level * (1.0 + spread * rng.standard_normal((1, cells))).clip(0.0)
        noisy = pressure + array.noise * rng.standard_normal((frames, cells))
        read = np.where(noisy < max(array.threshold, 0.0), 0.0, noisy)
        if array.resolution:
            read = np.round(read / array.resolution) * array.resolution
        reading = np.zeros((frames, array.nodes))
        reading[:, 2] = read.sum(axis=1) * array.cell_area
        bounded = np.zeros(reading.shape, bool)
        bounded[:, 2] = True
        truth = pressure.sum() * array.cell_area
        windows = ReadingWindows(band, reading, bounded, np.full(array.nodes, seg_std))
        assert windows.floor.size == 800 and windows.long_floor.size == frames // LONG_WINDOW
        for floor, ceiling in ((windows.floor, windows.ceiling), (windows.long_floor, windows.long_ceiling)):
            assert np.mean(floor > truth) <= 0.005, (level, np.mean(floor > truth))
            assert np.mean(ceiling < truth) <= 0.005, (level, np.mean(ceiling < truth))
            if level == 0.0:
                assert np.all(floor <= 0.0)
        if array.threshold == 300.0 and level == 100.0:
            assert np.all(windows.long_floor > 0.0)
        if array.threshold == 300.0 and level == 150.0:
            assert np.all(windows.floor > 0.0)
        if array.threshold == 0.0 and level == 50.0:
            assert np.all(windows.long_floor > 0.0)


def test_a_cells_reading_bias_is_its_noise_over_the_band_and_no_more():
    """``sensors.cell_reading_bias``: the most a cell's mean reading lies above or below its
    pressure. Without counts, the closed forms (phi(t) above; below, the minimum of
    phi(a) + (a - t) Phi(a), 1.448 stds for a band 3 stds up; clipped at zero, phi(0) and
    nothing); with 10 Pa counts under 100 Pa of noise within 0.1 Pa of a Monte Carlo of both
    band rules (the band on the value or on the count) over pressures from 0 to 600 Pa; a
    noise-free cell, half a count and the whole band."""
    from scipy.stats import norm

    from rheo_ros.sensors import cell_reading_bias

    above, below = cell_reading_bias(300.0, 100.0, 0.0)
    assert above == pytest.approx(100.0 * norm.pdf(3.0), rel=1e-3)
    assert below == pytest.approx(144.8, abs=0.1)
    assert cell_reading_bias(0.0, 100.0, 0.0) == pytest.approx((100.0 * norm.pdf(0.0), 0.0), abs=1e-3)
    assert cell_reading_bias(300.0, 0.0, 10.0) == (5.0, 305.0)
    above, below = cell_reading_bias(300.0, 100.0, 10.0)
    rng = np.random.default_rng(5)
    noise = 100.0 * rng.standard_normal(2_000_000)
    most_above = most_below = 0.0
    for p in np.arange(0.0, 600.0, 5.0):
        x = p + noise
        counted = 10.0 * np.round(x / 10.0)
        for read in (np.where(x >= 300.0, counted, 0.0), np.where(counted >= 300.0, counted, 0.0)):
            bias = read.mean() - p
            most_above, most_below = max(most_above, bias), max(most_below, -bias)
    # Monte Carlo's own std at the extremes: ~0.01 Pa at p = 0, ~0.1 Pa near the band.
    assert most_above <= above + 0.05 and above - most_above < 0.1, (above, most_above)
    assert most_below <= below + 0.3 and below - most_below < 0.5, (below, most_below)




def test_the_unloaded_array_measures_a_cells_excess_within_the_noises_doubt():
    """``DeadBand.unloaded``: a second of the unloaded array (50 frames of the 192 cells at
    zero pressure, 300 Pa band, 10 Pa counts) bounds the most a cell's mean reading exceeds
    its pressure (``cell_reading_bias`` at the cells' true noise: at zero pressure the
    noise's tail over the band). With the noise the live readings show (100 Pa) the bound
    is the measured one, under the truth (0.52 Pa) in none of 500 draws, its median 0.95 Pa a
    cell against the noise's doubt's 3.07 Pa (NOISE_DOUBT, 3.2 x looser); with cells 15 % noisier
    near zero than the live readings show (truth 1.70 Pa) it covers the truth in all but
    0.2 % of draws (a one-sided 3-std bound: 0.13 %; at most 0.5 % asserted); a baseline
    offset before contact (200 Pa a cell) is no noise: the doubt's bound stands."""
    from rheo_ros.sensors import NOISE_DOUBT, cell_reading_bias

    array = TactileArray()
    band, area = array.dead_band, array.cell_area
    cells = band.cells.astype(int)
    seg_std = np.sqrt(cells) * array.noise * area
    doubted = band.excess(seg_std) / (cells * area)
    assert doubted == pytest.approx(cell_reading_bias(300.0, NOISE_DOUBT * 100.0, 10.0)[0])
    starts = np.concatenate([[0], np.cumsum(cells)[:-1]])
    rng = np.random.default_rng(7)

    def measured(noise: float, offset: float = 0.0) -> np.ndarray:
        x = offset + noise * rng.standard_normal((50, cells.sum()))
        read = np.where(x >= 300.0, 10.0 * np.round(x / 10.0), 0.0)
        unloaded = band.unloaded(np.add.reduceat(read, starts, axis=1) * area, array.noise * area)
        return unloaded.excess(seg_std) / (cells * area)

    same = np.array([measured(100.0) for _ in range(500)])
    assert np.mean(same < cell_reading_bias(300.0, 100.0, 10.0)[0]) <= 0.005
    assert np.median(same) < doubted[0] / 3.0
    truth = cell_reading_bias(300.0, 115.0, 10.0)[0]
    noisier = np.array([measured(115.0)[0] for _ in range(500)])
    assert np.mean(noisier < truth) <= 0.005, np.mean(noisier < truth)
    np.testing.assert_allclose(measured(100.0, offset=200.0), doubted)
    assert band.unloaded(np.zeros((10, array.nodes)), array.noise * area) is band   # too few frames
    exact = TactileArray(noise=0.0, threshold=0.0, resolution=0.0).dead_band   # noise-free, clipped at zero
    assert exact.unloaded(np.zeros((50, array.nodes)), 0.0) is exact


def test_the_sensor_model_states_the_excess_it_allows_and_what_the_unloaded_array_showed(records):
    """``Record.sensor_json`` (the JSON's ``sensor``): the most a cell's mean reading
    exceeds its pressure, as used and as measured before contact. Dead band 300 Pa at
    100 Pa of noise, 10 Pa counts: measured, within the noise's own tail (0.44 Pa a cell)
    and its doubt's bound (3.1 Pa); the noise clipped at zero: at zero pressure a cell reads
    the noise's positive half, 100 / sqrt(2 pi) = 39.9 Pa, the doubt's 49.9 (the count's
    bound over a second of frames: 20 % over it, where every cell crosses); noise-free
    cells exceed nothing: what reads before contact is load, not noise."""
    from rheo_ros.sensors import NOISE_DOUBT, cell_reading_bias

    band = records["default_like"].sensor_json()["tactile"]["excess"]
    assert band["used"] == pytest.approx(band["measured"], rel=1e-12)
    assert 0.44 <= band["used"] <= cell_reading_bias(300.0, NOISE_DOUBT * 100.0, 10.0)[0] / 2, band
    clipped = records["no_dead_band"].sensor_json()["tactile"]["excess"]
    assert CELL_NOISE / math.sqrt(2 * math.pi) * 0.97 <= clipped["used"] <= NOISE_DOUBT * CELL_NOISE / math.sqrt(2 * math.pi)
    assert clipped["measured"] >= CELL_NOISE / math.sqrt(2 * math.pi) * 0.97, clipped   # a bound over it
    assert records["noise_free"].sensor_json()["tactile"]["excess"]["used"] == 0.0



def test_each_columns_noise_at_once_is_its_median_absolute_deviation():
    """``column_difference_noise`` (every segment at once) gives each column the median
    absolute deviation of its own second differences in use (``np.median`` over them
    alone), scaled to a std, within 1e-9 of it, however many are in use, with ties (a
    lattice of readings) and with too few (NaN); ``difference_noise`` pools the columns."""
    rng = np.random.default_rng(7)
    for trial in range(300):
        T, k = int(rng.integers(3, 300)), int(rng.integers(1, 33))
        y = rng.normal(0.0, 3.0, (T, k)) + np.linspace(0.0, 40.0, T)[:, None]
        if trial % 2:
            y = np.round(y)   # ties
        use = rng.random((T, k)) < rng.uniform(0.0, 1.0)
        d2 = y[:-2] - 2.0 * y[1:-1] + y[2:]
        ok = use[:-2] & use[1:-1] & use[2:]
        std, counts = column_difference_noise(y, use)
        for j in range(k):
            mine = d2[ok[:, j], j]
            assert counts[j] == mine.size
            if mine.size < 10:
                assert np.isnan(std[j])
                continue
            expected = 1.4826 * np.median(np.abs(mine - np.median(mine))) / np.sqrt(6.0)
            assert std[j] == pytest.approx(expected, rel=1e-9, abs=1e-12)
        pooled, count = difference_noise(y, use)
        assert count == ok.sum()
        if count >= 10:
            every = d2[ok]
            assert pooled == pytest.approx(1.4826 * np.median(np.abs(every - np.median(every))) / np.sqrt(6.0),
                                           rel=1e-9, abs=1e-12)
