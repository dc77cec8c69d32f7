"""Data the package did not make: bags from ``test/generator.py`` (a homogeneous block
integrated by scipy's ODE solver, with its own sensor models; no code shared with
rheo_ros), analysed as a user would with ``rheo analyze``.

Every figure here was made by that generator, seed 1, the Table IV material, the
default experiment (push 10 mm at 0.5 mm/s, keep 48 s, release 100 s, instant let-go).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from generator import Material, generate

from rheo_ros.app.analyze import analyze

TRUTH = Material()
PARAMS = ("E", "c1", "c2", "gamma")
SENSORS = ("default_like", "no_dead_band", "quantised", "noise_free")


@pytest.fixture(scope="module")
def analyses(tmp_path_factory) -> dict[str, dict]:
    out = {}
    folder = tmp_path_factory.mktemp("generated")
    for sensor in SENSORS:
        bag = generate(folder / sensor, sensor=sensor, seed=1)
        out[sensor] = analyze(Path(bag), workers=1).to_json()
    return out


def relative(value: float, name: str) -> float:
    return value / getattr(TRUTH, name) - 1.0


@pytest.mark.parametrize("sensor", SENSORS)
def test_a_clean_block_is_adequate_whatever_the_sensor(analyses, sensor):
    """No effect is named and the three-element model is adequate: with a dead band, with
    the noise clipped at zero and no dead band, with 50 Pa quantisation, and noise-free
    (judged against the model's own floor, never against zero)."""
    diagnosis = analyses[sensor]["diagnosis"]
    assert diagnosis["adequate"] and diagnosis["missing_effects"] == [], diagnosis["evidence"]
    assert diagnosis["adequate_model"] == "three_element"


@pytest.mark.parametrize("sensor", SENSORS[:3])
def test_the_fit_holds_the_truth_within_its_std_on_noisy_sensors(analyses, sensor):
    """Measured (seed 1): within 0.71 std for every parameter on the three noisy sensors;
    tolerance 3 std."""
    fit = analyses[sensor]["models"][0]
    for name in PARAMS:
        error = fit["params"][name] - getattr(TRUTH, name)
        assert abs(error) < 3 * fit["std"][name], (name, error / fit["std"][name])


def test_noise_free_data_give_the_truth_to_float32_precision(analyses):
    """Noise-free float32 pressures: the fit within 1e-9 of the truth (measured), the
    closed form, which follows the recovery to its end (the release is cut by the
    segmenter 33 s after the let-go, 6.5 Voigt times), within 1e-7 (measured 1e-9;
    averaging the last frames instead left it 2.5 % low). Tolerance 1e-6 for both: above
    float32 rounding of the pressures (6e-8)."""
    report = analyses["noise_free"]
    for name in PARAMS:
        assert abs(relative(report["models"][0]["params"][name], name)) < 1e-6, name
        assert abs(relative(report["estimate"][name], name)) < 1e-6, name


@pytest.mark.parametrize("sensor", SENSORS[:3])
def test_the_closed_form_follows_the_recovery_on_noisy_sensors(analyses, sensor):
    """The paper's closed form from the same bags: measured within 0.11 % for E, c1, c2
    and 0.38 % for gamma (the release's markers, 20 um noise); tolerance 0.3 % and 1 %
    (it was 3.7 % low on every one of them before it followed the recovery)."""
    estimate = analyses[sensor]["estimate"]
    for name in ("E", "c1", "c2"):
        assert abs(relative(estimate[name], name)) < 3e-3, (name, estimate[name])
    assert abs(relative(estimate["gamma"], "gamma")) < 1e-2


def test_a_sensor_clipped_at_its_saturation_leaves_the_fit_within_its_std(tmp_path):
    """The generator's clipped sensor (cells saturating at 4000 Pa, reached at the end of
    the pull and early in the keep): a saturated reading bounds the force from below, the
    readings under the top are measures. Each reading's own value decides whether it is
    saturated (a window's median would leave readings under the top that are neither
    measure nor bound: E came out 24 std low here, 8 on a bench bag). Measured (seed 1):
    within 1.3 std for every parameter; tolerance 3 std."""
    bag = generate(tmp_path / "clipped", sensor="clipped", seed=1)
    report = analyze(Path(bag), discover_effects=False, workers=1).to_json()
    fit = report["models"][0]
    assert report["sensor"]["tactile"]["saturation"] == 4000.0
    for name in PARAMS:
        error = fit["params"][name] - getattr(TRUTH, name)
        assert abs(error) < 3 * fit["std"][name], (name, error / fit["std"][name])


def test_segments_saturated_most_of_the_time_take_the_cells_noise(tmp_path):
    """The diagnosis bench's bag 51 of seed 16 at twice the noise (a stiff block, E 39 kPa,
    on the clipped sensor: P1-P4 saturated from early in the pull to the release, too
    seldom live three frames in a row to show their own noise). Their cells' noise (193
    Pa, which P5 shows) sets their margins, so their cells clipping one by one near the
    top are not read as measures: measured E +0.05 %, c1 -0.25 %, c2 -4.5 %, gamma
    -0.05 % (before: E 51 % low, the misfit "1e7 x the noise"). Tolerance 1 % (c2: 10 %)."""
    import json

    import numpy as np
    from generator import bench_bag

    truth = bench_bag(np.random.default_rng((16, 51)), 51, tmp_path / "bag", 2.0, True)
    report = analyze(tmp_path / "bag", params_file=truth["params_file"], discover_effects=False, workers=1).to_json()
    material = json.loads((tmp_path / "bag.truth.json").read_text())["material"]
    fit = report["models"][0]["params"]
    for name, tolerance in {"E": 0.01, "c1": 0.01, "c2": 0.1, "gamma": 0.01}.items():
        assert fit[name] == pytest.approx(material[name], rel=tolerance), name
    assert report["sensor"]["tactile"]["saturation"] == 4000.0
