"""Nothing silently wrong (issue 21): tactile readings that do not read the load, and a
closed form pinned at a bound, each found and said instead of printed as a value.

Bags from ``test/generator.py`` (its own physics and sensors, nothing shared with the
package): seed 1, the Table IV material, the default-like sensor (300 Pa dead band,
10 Pa steps, 100 Pa noise), a short push (10 mm at 0.5 mm/s, keep 15 s, release 20 s),
one cell of the 6 x 32 array made faulty: row 2, col 13 (segment P3, 48 cells).
On the same bag without a fault the fit is within 0.81 std of the truth (E +0.25,
c1 -0.81, c2 -0.06, gamma -0.06 std) and the closed form within 0.92 % (E -0.79 %).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import generator as g
import pytest

from rheo_ros.app.analyze import analyze
from rheo_ros.config.setup import Setup, load_params
from rheo_ros.identification.estimate import BASE_PARAMETERS

TRUTH = g.Material()
SHORT = g.Profile(keep_time=15.0, release_time=20.0)
CELL = (2, 13)


def analysed(tmp_path: Path, sensor: g.Sensor) -> dict:
    bag = g.generate(tmp_path / "bag", sensor=sensor, seed=1, profile=SHORT)
    return analyze(bag, workers=1, discover_effects=False).to_json()


def faulty(**fault) -> g.Sensor:
    return replace(g.SENSORS["default_like"], name="faulty", **fault)


def assert_near_truth(report: dict, stds: float, closed: float) -> None:
    fit = report["models"][0]
    for name in BASE_PARAMETERS:
        error = fit["params"][name] - getattr(TRUTH, name)
        assert abs(error) < stds * fit["std"][name], (name, error / fit["std"][name])
        assert abs(report["estimate"][name] / getattr(TRUTH, name) - 1.0) < closed, (name, report["estimate"][name])


@pytest.mark.parametrize("value", [0.0, 500.0])
def test_a_dead_cell_is_found_left_out_and_named(tmp_path, value):
    """A cell reading 0 (or stuck at 500 Pa) through the whole record while its column
    reads up to 5320 Pa. Before: nothing said, the fit's E 34.0 std low (stuck: 32.5) and
    c1 11.1 std (10.4), the closed form's E -1.4 % (-3.6 %). After: named in a warning and
    in ``sensor.tactile.faults``, its segment read from its other 47 cells: measured as
    on the bag without the fault (fit within 0.82 std: E +0.29, c1 -0.82, c2 -0.09, gamma
    -0.05; closed form within 0.79 %). Tolerance 3 std, closed form 1.5 %."""
    report = analysed(tmp_path, faulty(dead_cell=(*CELL, value)))
    faults = report["sensor"]["tactile"]["faults"]
    # The load it missed: the highest per-frame median of its column's other cells (5160
    # measured; each cell's own highest is ~2.5 noise stds above the load: 5320).
    assert faults == [{"row": 2, "col": 13, "kind": "dead", "value": value, "peak": pytest.approx(5160.0, abs=100),
                       "since": None}]
    line = f"tactile cell (row 2, col 13) reads {value:g} throughout while the other cells of its column peak at"
    assert any(w.startswith(line) and w.endswith("left out, its segment read from its other cells")
               for w in report["warnings"]), report["warnings"]
    assert_near_truth(report, stds=3.0, closed=0.015)


def test_a_cell_that_dies_under_load_is_left_out_from_then(tmp_path):
    """A cell reading 0 from 8 s on, under load in the pull (its column
    rising to ~5160 Pa). Before (main at 0bc4393): nothing said (it was not dead
    throughout), the fit's E 37.1 std low and c1 10.6 std, the closed form's E -11.9 %,
    c1 -11.8 %, c2 -9.6 %. After: named with the stamp it died at, its segment read from its
    other 47 cells from then on, as on the bag without the fault (measured: fit within 0.82
    std, closed form within 0.78 %). Tolerance 3 std, closed form 1.5 %."""
    report = analysed(tmp_path, faulty(dead_cell=(*CELL, 0.0), dead_from=8.0))
    [fault] = report["sensor"]["tactile"]["faults"]
    assert (fault["row"], fault["col"], fault["kind"], fault["value"]) == (2, 13, "dead", 0.0)
    assert 8.0 <= fault["since"] < 8.0 + 0.02 + 1e-9   # the first frame at or after it (50 Hz)
    line = f"tactile cell (row 2, col 13) reads 0 from {fault['since']:.3f} s on while the other cells of its column"
    assert any(w.startswith(line) and w.endswith("left out from then, its segment read from its other cells")
               for w in report["warnings"]), report["warnings"]
    assert_near_truth(report, stds=3.0, closed=0.015)


def test_one_frame_glitches_are_left_out_and_named(tmp_path):
    """Five readings of single cells 20 000 Pa too high, each for one frame (an electrical
    glitch), spread over the pull, keep and release. Before: the fit right (within 0.8
    std) but the verdict "the model misfits (P4 at 1.34 x the noise, P5 at 1.33) but no
    effect in the catalogue explains it: an effect not yet written": a user sent to
    write an effect for five bad readings. After: each found (its segment and stamp), left
    out of the fit and the comparison (the closed forms read their neighbours' midpoint),
    the model adequate, the fit as without them (measured within 0.81 std), the closed
    form within 0.94 % (c2 +2.3 % with the spikes in). Tolerance 3 std, closed form 1.5 %."""
    import re

    import numpy as np
    import yaml

    data = g.synthesize(seed=1, profile=SHORT)
    rng = np.random.default_rng(0)
    frames = np.sort(rng.choice(len(data.tactile_t), 5, replace=False))
    images = data.images.copy()
    for f in frames:
        images[f, rng.integers(6), rng.integers(32)] += 20000.0
    g.write_bag(replace(data, images=images), tmp_path / "bag",
                yaml.safe_dump(g.params_document(g.Layout(), SHORT), sort_keys=False))
    report = analyze(tmp_path / "bag", workers=1).to_json()
    [line] = [w for w in report["warnings"] if "isolated spikes" in w]
    for t in data.tactile_t[frames]:
        assert f"{t:.3f}" in line, (t, line)
    assert sum(int(n) for n in re.findall(r"P\d: (\d+) at", line)) == 5   # nothing else
    assert report["diagnosis"]["adequate"] and report["diagnosis"]["missing_effects"] == [], report["diagnosis"]
    assert_near_truth(report, stds=3.0, closed=0.015)


def test_a_cell_saturating_alone_is_found_and_its_segment_bounded(tmp_path):
    """A cell clipped at 1500 Pa while its column peaks at 5320 Pa. Before: nothing said,
    the fit's E 27.9 std low and c1 8.4 std, the closed form's E -7.4 %, c2 -6.2 %.
    After: named; its segment's readings above where it clips are not live (the fit takes
    them as lower bounds) and the closed forms leave that segment out (P1, P2, P4, P5):
    fit within 0.82 std (E +0.35, c1 -0.82, c2 -0.13, gamma -0.05), closed form within
    0.96 %. Tolerance 3 std, closed form 1.5 %."""
    report = analysed(tmp_path, faulty(clipped_cell=(*CELL, 1500.0)))
    assert report["sensor"]["tactile"]["faults"] == [
        {"row": 2, "col": 13, "kind": "saturated", "value": 1500.0, "peak": pytest.approx(5320.0, abs=50),
         "since": None}]
    assert any(w.startswith("tactile cell (row 2, col 13) saturates alone at 1500 Pa") for w in report["warnings"])
    assert "nodes P1,P2,P4,P5" in report["estimate"]["message"]
    assert_near_truth(report, stds=3.0, closed=0.015)


def test_a_closed_form_at_its_bound_is_reported_not_determined(tmp_path):
    """A 0.4 s pull (10 mm at 25 mm/s) on the package's plane FE simulator (mesh refine 4
    for speed): the closed form's least squares pins gamma at its bound, 0.4999 (truth
    0.332), which was printed and reported as a value, and E, c1, c2 solved with it were
    biased (measured on a 0.4 s pull at 10 mm/s: E +24 %). Now all four NaN in the
    analysis, null in the JSON with their std, the reason in ``estimate.undetermined`` and
    in ``warnings``, as the estimator node reports it (``pipeline.undetermined``); the fit
    is unaffected (gamma 0.3314 +- 0.0012 measured)."""
    from rheo_ros.app.simulate import simulate_to_bag

    params = dict(load_params(None))
    params.update({"stage.velocity": 0.025, "stage.keep_time": 15.0, "stage.release_time": 20.0,
                   "simulator.refine": 4})
    simulate_to_bag(Setup(params), 0, tmp_path / "bag")
    result = analyze(tmp_path / "bag", workers=1, discover_effects=False)
    report = result.to_json()
    est = report["estimate"]
    assert est["gamma"] is None and est["std"]["gamma"] is None
    assert set(est["undetermined"]) == {"E", "c1", "c2", "gamma"}
    assert "at its bound (0.4999)" in est["undetermined"]["gamma"]
    assert all(est["undetermined"][k].startswith("solved with gamma at its bound (0.4999)") for k in ("E", "c1", "c2"))
    assert any(w.startswith("closed form: gamma not determined: the equations put it at its bound")
               for w in report["warnings"])
    assert all(est[k] is None and est["std"][k] is None for k in ("E", "c1", "c2"))
    assert abs(report["models"][0]["params"]["gamma"] - 0.332) < 0.01
