"""When the catalogue runs out (issue 24): an effect in no catalogue, from the generator
that shares no code with the package (test/generator.py), is not named; the closest
candidates and what remains are. Written as a plugin package of its own (the README's
effect with memory), the same effect runs in the simulator and is named, the model
adequate and its parameters right.

Three effects of different kinds, each from test/generator.py (8 mm at 1 mm/s): a tactile
array whose elastomer creeps (each cell reads 70 % of the pressure at once and 30 % through
a first-order lag of 3 s: a sensor with memory), a camera whose mount creeps (in the
markers alone) and a block that damages (a material law of another family: its stress
over 1 + d x the largest strain it has seen). The lag and the damage also from the
package's simulator with the plugin."""

import importlib
import json
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from conftest import readme_block
from scipy.signal import lsim, lti

from rheo_ros.app.analyze import analyze
from rheo_ros.app.cli import format_analysis
from rheo_ros.config.setup import Setup, check_params
from rheo_ros.models.effects import catalogue, unregister_effect
from rheo_ros.reports.html import render_report
from rheo_ros.rig.simulator import Simulator, simulate_clean, simulate_run


@pytest.fixture(scope="module")
def lagging(tmp_path_factory):
    from generator import Effects, Profile, generate

    assert "sensor_lag" not in catalogue()   # the plugin below is not installed yet
    root = tmp_path_factory.mktemp("lag")
    bag = generate(root / "bag", effects=Effects(sensor_lag=(3.0, 0.3)), profile=Profile(keep_time=15.0,
                                                                                           release_time=25.0, velocity=1e-3, depth=8e-3), seed=2)
    result = analyze(bag, workers=1)
    return result.to_json(), json.loads((root / "bag.truth.json").read_text()), bag, result


def test_an_effect_in_no_catalogue_is_not_named_and_the_closest_are_listed(lagging):
    """Measured (15 s keep, 25 s release): the loop added adhesion (force RMS 0.167 ->
    0.063 N) and the model still misfits (4.2-6.3 x the noise per segment): no missing
    effect, explained false, adhesion listed as the closest, the final word in the
    evidence. (Before issue 24 the JSON said adhesion is missing.)"""
    report, _, _, _ = lagging
    d = report["diagnosis"]
    assert (d["missing_effect"], d["missing_effects"], d["explained"], d["adequate"]) == (None, [], False, False)
    assert d["closest"] and [m["name"] for m in report["models"]][1:] == [
        "three_element+" + "+".join(d["closest"][: k + 1]) for k in range(len(d["closest"]))]
    assert "Final verdict: the catalogue does not explain these data" in d["evidence"]


def test_a_lag_read_as_an_arm_and_an_adhesion_of_its_time_is_not_named(tmp_path):
    """Generator out-of-catalogue bag 32:27 (quick; a clipped array, 20 % of each reading
    through a 0.976 s lag): the loop adds an adhesion fading over 0.979 s and a Maxwell arm
    of 0.972 s, and with both the force fits within the noise (1.06 x in the release at
    worst). At stop 58 both were named; they share one time (0.7 % apart), so the verdict
    is that the catalogue does not explain the data, both the closest, the shared time
    quoted (each within 10 % of the lag's) in the JSON and the evidence. (Since the clock
    offsets stay within their limit the markers' release also misfits with the arm,
    11.4 sd: the evidence gives both reasons.)"""
    from rheo_ros.bench.diagnosis import load_source

    _, source = load_source(Path(__file__).with_name("generator.py"))
    truth = source(np.random.default_rng((32, 27)), 27, tmp_path / "bag", 1.0, True, outside=True)
    tau = truth["outside"][0]["params"]["tau"]
    d = analyze(tmp_path / "bag", params_file=truth["params_file"], workers=1).to_json()["diagnosis"]
    assert (d["missing_effect"], d["explained"], sorted(d["closest"])) == (None, False, ["adhesion", "relaxation_branch"])
    assert len(d["shared_times"]) == 1
    times = [float(x) for x in re.findall(r"time ([0-9.]+) s", d["shared_times"][0])]
    assert len(times) == 2 and all(abs(t / tau - 1) < 0.1 for t in times), (times, tau)
    assert f"{d['shared_times'][0]} agree within 10%: one time spans the phases" in d["evidence"]


@pytest.mark.parametrize("bag, closest, rival, truth_key", [
    ((34, 2), ["relaxation_branch"], "lagging_reading", {"tau": "time", "share": "share"}),
    ((34, 23), ["sensor_drift"], "strain_softening", {"softening": "softening"}),
])
def test_a_catalogue_effect_that_fits_is_not_named_where_one_in_no_catalogue_fits_better(
        tmp_path, bag, closest, rival, truth_key):
    """Generator out-of-catalogue bags 34:2 (a clipped array, 8.4 % of each reading through
    a 0.60 s lag) and 34:23 (a default-like array; a block softening by 0.359 x its largest
    strain): at stop 68 a Maxwell arm and a settling drift were named, each fitting within
    the noise, E 0.5 % and 4.3 % off. The rivals fitted on the base alone (the lagging
    reading, the softening material) fit within the noise and lower the BIC below the named
    model by more than 10 (measured 89.9 and 119.8): nothing is named, the catalogue's
    effect is the closest, and the rival's parameters are within 10 % of the generator's
    (measured: 0.602 s and 8.35 % for 0.599 s and 8.40 %; a softening of 0.378 for 0.359)."""
    from rheo_ros.bench.diagnosis import load_source

    _, source = load_source(Path(__file__).with_name("generator.py"))
    truth = source(np.random.default_rng(bag), bag[1], tmp_path / "bag", 1.0, True, outside=True)
    d = analyze(tmp_path / "bag", params_file=truth["params_file"], workers=1).to_json()["diagnosis"]
    assert (d["missing_effect"], d["missing_effects"], d["explained"], d["closest"]) == (None, [], False, closest), \
        d["evidence"]
    found = {r["effect"]: r for r in d["remaining"]["rivals"]}[rival]
    assert found["beats"] and found["delta_bic"] < -10, found
    for generated, fitted in truth_key.items():
        assert found["params"][f"{rival}.{fitted}"] == pytest.approx(truth["outside"][0]["params"][generated], rel=0.1)


def test_a_sensors_play_is_not_read_as_a_drift_and_a_stiffening(tmp_path):
    """Generator bag 40:11 of the other laws (``BENCH_OUTSIDE_OTHER``; quick, an array with
    no dead band): each cell reads through a play of half-width 44.5 Pa (6.1 x the total
    force's noise). At stop 71 a settling drift and a stiffening were named, fitting within
    the noise. The play rival (``models.rivals.SensorPlay``: a play on each segment, its
    width in proportion to its cells) fits within the noise and lowers the BIC below them by
    more than 10 (measured 181.6): nothing is named, and its width is the generator's per
    cell summed over an average segment's cells within 10 % (measured 3.7 % over)."""
    from generator import BENCH_OUTSIDE_OTHER, Layout, bench_bag

    truth = bench_bag(np.random.default_rng((40, 11)), 11, tmp_path / "bag", 1.0, True, outside=True,
                      kinds=BENCH_OUTSIDE_OTHER)
    assert truth["outside"][0]["effect"] == "sensor_hysteresis"
    d = analyze(tmp_path / "bag", params_file=truth["params_file"], workers=1).to_json()["diagnosis"]
    assert (d["missing_effect"], d["missing_effects"], d["explained"]) == (None, [], False), d["evidence"]
    found = {r["effect"]: r for r in d["remaining"]["rivals"]}["sensor_play"]
    assert found["beats"] and found["delta_bic"] < -10, found
    layout = Layout()
    array = Setup(check_params({})).tactile
    cells = layout.tactile_rows * np.bincount(array.segment, minlength=array.nodes).mean()
    area = (layout.width / layout.tactile_cols) * (layout.thickness / layout.tactile_rows)
    width = truth["outside"][0]["params"]["w"] * cells * area   # N per average segment
    assert found["params"]["sensor_play.width"] == pytest.approx(width, rel=0.1), found


def test_a_lag_that_only_readings_under_the_dead_band_show_is_no_held_adhesion(tmp_path):
    """Generator out-of-catalogue bag 32:9 (quick; a dead-banded array, 2 % of each reading
    through a 1.19 s lag): after a Maxwell arm of the lag's time, a held adhesion of 0.4 %
    of the force lowered the BIC by 25.5, held only by the windows of readings under the
    dead band just after the release (stop 59: named). Those readings fall from 10.7 mN over
    the release's first second to 0.76 mN over the next four (above the unloaded array's
    level; 5 sd and a factor 2 are the rule) while a held force would read steady: the held
    form is contradicted (rule 5), nothing is named, and the evidence says why."""
    from rheo_ros.bench.diagnosis import load_source

    _, source = load_source(Path(__file__).with_name("generator.py"))
    truth = source(np.random.default_rng((32, 9)), 9, tmp_path / "bag", 1.0, True, outside=True)
    assert truth["outside"][0]["effect"] == "sensor_lag"
    d = analyze(tmp_path / "bag", params_file=truth["params_file"], workers=1).to_json()["diagnosis"]
    assert (d["missing_effect"], d["missing_effects"]) == (None, [])
    fades = re.search(r"adhesion \(held form\) lowers BIC by [0-9.e+]+, but the readings after the release fall "
                      r"from ([0-9.e-]+) N over its first second to ([0-9.e-]+) N over the next four", d["evidence"])
    assert fades, d["evidence"]
    first, later = map(float, fades.groups())
    assert first >= 2.0 * later and first == pytest.approx(0.0107, rel=0.1)


def test_what_remains_says_where_the_misfit_sits(lagging):
    """``remaining``: every phase of the push and every segment misfit with the closest
    model; each cell's ratio above 1 (the misfit limit)."""
    report, _, _, _ = lagging
    rest = report["diagnosis"]["remaining"]
    assert {"pull", "keep", "release"} <= set(rest["phases"])
    assert set(rest["segments"]) == {"P1", "P2", "P3", "P4", "P5"}
    assert all(c["ratio"] > 1.0 for c in rest["misfits"])
    assert not rest["markers_only"]


def test_what_remains_has_the_lags_time_in_its_shape(lagging):
    """A lagging reading of no catalogue fits better than the closest model (the effects
    found stood in for it), so what remains is the base model's misfit: in the pull, the
    keep and the release the total force's residual is a decay whose time is the sensor's
    lag (3 s; measured 2.85, 2.27 and 2.16 s), over 10 x the force noise (measured 38-155
    x; with the adhesion model's residual the release was a pulse): the hint for a user to
    write a sensor with memory."""
    report, truth, _, _ = lagging
    shapes = report["diagnosis"]["remaining"]["shapes"]
    lag = truth["effects"]["sensor_lag"][0]
    for phase in ("pull", "keep", "release"):
        assert shapes[phase]["shape"] == "decay", (phase, shapes[phase])
        assert 0.5 * lag < shapes[phase]["tau"] < 1.5 * lag, (phase, shapes[phase]["tau"])
        assert abs(shapes[phase]["size"]) > 10
    text = format_analysis(report)   # rheo analyze's text says it too
    assert "What remains (in " in text and "pull: decay of " in text


def test_an_effect_in_no_catalogue_that_fits_better_is_quoted_with_its_values(lagging):
    """The rivals (``models.rivals``) fitted on the base: the lagging reading fits within
    the noise and lowers the BIC below the closest model's by more than 10; its time and
    share within 10 % of the generator's 3 s and 30 % (measured 3.002 s and 0.29997, BIC lower
    by 4.4e5 than the adhesion model's, which misfits; the softening rival 1.2e6 higher); the verdict
    gives it as the reason, and the text of what remains names it."""
    report, truth, _, _ = lagging
    d = report["diagnosis"]
    rivals = {r["effect"]: r for r in d["remaining"]["rivals"]}
    lag = rivals["lagging_reading"]
    assert lag["beats"] and lag["sound"] and lag["delta_bic"] < -10, lag
    time, share = truth["effects"]["sensor_lag"]
    assert lag["params"]["lagging_reading.time"] == pytest.approx(time, rel=0.1), lag
    assert lag["params"]["lagging_reading.share"] == pytest.approx(share, rel=0.1), lag
    assert all(s is not None and s > 0 for s in lag["std"].values()), lag
    assert not rivals["strain_softening"]["beats"], rivals["strain_softening"]
    assert "an effect in no catalogue fits better than" in d["evidence"] and lag["description"] in d["evidence"]
    assert f"It looks like an effect in no catalogue: {lag['description']}" in format_analysis(report)


def test_the_report_shows_what_remains_with_the_fitted_shape_over_it(lagging):
    """The report's "What remains" section: the sentence of the text, a row per phase
    with the JSON's shape, size and time, and the figure with each shape drawn over the
    residual (its SVG group per phase)."""
    report, _, _, result = lagging
    page = render_report(result)
    shapes = report["diagnosis"]["remaining"]["shapes"]
    assert '<p id="remaining-text">What remains (in ' in page
    for phase, v in shapes.items():
        row = re.search(rf'<tr data-phase="{phase}" data-shape="{v["shape"]}">.*?</tr>', page)
        assert row, phase
        assert f'data-value="{v["size"]!r}"' in row.group(0)
        if v["tau"] is not None:
            assert f'data-value="{v["tau"]!r}"' in row.group(0)
        assert f'id="remaining-shape-{phase}"' in page
    assert '<figure class="remaining" id="remaining">' in page


def assert_named_and_right(report: dict, effect_id: str, own: dict[str, float], material: dict[str, float],
                           stds: float) -> None:
    """The diagnosis names ``effect_id`` alone, explained and adequate, and the final
    model's ``own`` parameters and E, c1, c2 (``material``'s) are each within ``stds`` of
    its std of the value given."""
    d = report["diagnosis"]
    assert (d["missing_effects"], d["explained"], d["adequate"]) == ([effect_id], True, True), d["evidence"]
    final = report["models"][-1]
    for name, value in {**own, **{k: material[k] for k in ("E", "c1", "c2")}}.items():
        assert abs(final["params"][name] - value) < stds * final["std"][name], (name, final["params"][name],
                                                                              final["std"][name])


def simulated_material(setup: Setup) -> dict[str, float]:
    """E, c1, c2 the package's simulator was given."""
    return {k: setup.params[f"material.{k}"] for k in ("E", "c1", "c2")}

def install_plugin(root: Path, module: str, source: str, entry_points: str) -> Path:
    """A plugin package of one module (``source``) whose ``entry_points`` (the TOML table's
    lines) register it, installed by pip into ``root``/site; returns that folder."""
    src = root / "src"
    src.mkdir(parents=True)
    (src / f"{module}.py").write_text(source)
    (src / "pyproject.toml").write_text(
        '[build-system]\nrequires = ["setuptools"]\nbuild-backend = "setuptools.build_meta"\n\n'
        f'[project]\nname = "{module.replace("_", "-")}"\nversion = "0.1.0"\n\n'
        + entry_points + f'\n[tool.setuptools]\npy-modules = ["{module}"]\n')
    site = root / "site"
    run = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                          "--no-index", "--target", str(site), str(src)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    return site


@contextmanager
def plugin_on_path(site: Path, effect_id: str, module: str) -> Iterator[None]:
    """The installed plugin found through the entry-point group while inside."""
    sys.path.insert(0, str(site))
    importlib.invalidate_caches()
    try:
        assert effect_id in catalogue()
        yield
    finally:
        sys.path.remove(str(site))
        unregister_effect(effect_id)
        sys.modules.pop(module, None)


@pytest.fixture(scope="module")
def lag_site(tmp_path_factory) -> Path:
    """The README's effect with memory as a package of its own (the README's code and
    entry point), installed by pip into a temporary folder."""
    return install_plugin(tmp_path_factory.mktemp("plugin"), "rheo_sensor_lag", readme_block("python", "class SensorLag"),
                          readme_block("toml", "rheo_ros.effects"))


@pytest.fixture
def lag_plugin(lag_site):
    """That package found through the ``rheo_ros.effects`` entry-point group (not imported
    by the test), for one test."""
    with plugin_on_path(lag_site, "sensor_lag", "rheo_sensor_lag"):
        yield


def test_an_effect_with_memory_runs_in_the_streaming_simulator_as_in_the_whole_run(lag_plugin):
    """The simulator node steps sample by sample; ``rheo simulate`` runs the whole
    profile. With the README's lag (memory: the whole history) both give the same images
    (measured: identical), and the lag is the one scipy's lsim gives of the lag-free run's
    forces through the pull and the keep (17 % of the peak force), to 1e-6 of the peak."""
    lag = {"effects.sensor_lag.time": 1.0, "effects.sensor_lag.share": 0.3}
    base = {"stage.depth": 0.004, "stage.velocity": 0.001, "stage.keep_time": 3.0, "stage.release_time": 3.0,
            "simulator.refine": 2}
    setup = Setup(check_params({**base, **lag, "simulator.effects": ["sensor_lag"]}))
    assert setup.model().memory == np.inf
    whole = simulate_run(setup, seed=4)
    node = Simulator(setup, seed=4)
    frames = [f for t, d in zip(whole.stage_t, whole.stage_depth) for f in node.step(float(t), float(d))]
    streamed = np.array([f.data for f in frames if f.kind == "tactile"])
    count = setup.params["tactile.resolution"]
    assert np.abs(streamed - whole.tactile).max() <= count and np.mean(streamed != whole.tactile) <= 1e-3

    # The lag is there, as scipy's lsim makes it of the lag-free run's forces (each node's,
    # linear between samples: the tactile array read at every step of the simulator here).
    every_step = {"rates.tactile": setup.params["rates.stage"]}
    lagged = simulate_clean(Setup(check_params({**base, **lag, **every_step, "simulator.effects": ["sensor_lag"]})))
    free = simulate_clean(Setup(check_params({**base, **every_step, "simulator.effects": [""]})))
    held = free.tactile_t < setup.profile.t_keep_end
    lsim_lag = np.column_stack([lsim(lti([1.0], [1.0, 1.0]), f, free.tactile_t)[1] for f in free.force.T])
    expected = 0.7 * free.force + 0.3 * lsim_lag
    peak = np.abs(free.force).max()
    assert np.abs(lagged.force - free.force)[held].max() > 0.05 * peak      # a visible lag
    assert np.abs(lagged.force - expected)[held].max() < 1e-6 * peak         # measured 1.7e-15


def test_with_the_effect_as_a_plugin_it_is_named_the_model_adequate_and_its_parameters_right(lagging, lag_plugin):
    """The same generator bag with the README's lag installed as a plugin: the diagnosis
    names sensor_lag, the model is adequate and explained, and the lag's time and share
    and E, c1, c2 come back within 3 std of the generator's truth (measured: within 0.52
    std, c2 the farthest, the time 0.07 % off; the generator's lag by scipy's lsim, the plugin's by the
    README's own formula; with every reading's time given to the lag - before, the fit
    gave it only the readings away from the phase boundaries and the share came out 1.6 %,
    15 std, high)."""
    _, truth, bag, _ = lagging
    report = analyze(bag, workers=1).to_json()
    lag = truth["effects"]["sensor_lag"]
    assert_named_and_right(report, "sensor_lag", {"sensor_lag.time": lag[0], "sensor_lag.share": lag[1]},
                           truth["material"], stds=3)


def test_parameters_at_a_bound_have_no_std_and_are_named(tmp_path):
    """Adhesion added by the user to a clean bag (bags/clean_short_keep, the package's
    simulator): the data bound them on one side only (the release's readings under the
    live threshold allow no more adhesion than they show: measured, the fit stopped at
    fraction 0.068 and time 316 s from 0.1 and 30.8 s; nothing holds them from below),
    with an infinite std. They are at a bound: null std and listed in ``at_bound`` in the
    JSON, a warning naming them, "(at bound)" in the text and "at bound" in the report -
    never a value +- a std; the base parameters keep theirs."""
    result = analyze(str(Path(__file__).parents[1] / "bags" / "clean_short_keep"), effects=["adhesion"],
                     discover_effects=False)
    report = result.to_json()
    added = report["models"][-1]
    bound = ["adhesion.fraction", "adhesion.time"]
    assert added["at_bound"] == bound and report["models"][0]["at_bound"] == []
    assert all(added["std"][k] is None for k in bound)
    assert all(added["std"][k] is not None for k in ("E", "c1", "c2", "gamma"))
    assert any(w.startswith("three_element+adhesion: adhesion.fraction, adhesion.time at a bound")
               for w in report["warnings"])
    text = format_analysis(report)
    assert re.search(r"adhesion\.fraction [0-9.e+-]+ \(at bound\)", text), text
    assert re.search(r"adhesion\.time [0-9.e+-]+ \(at bound\)", text), text
    page = render_report(result)
    table = re.search(r'<table class="parameters" id="parameters-step-2".*?</table>', page, re.S).group(0)
    for k in bound:
        assert re.search(rf'<tr data-param="{k}">.*?<td class="std undetermined at-bound" data-value="">at bound</td>',
                         table), k


# A camera whose mount creeps: in no catalogue, and in the markers alone (the force
# never sees it). The user's plugin for it, as a package of its own.
CAMERA_DRIFT = """
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rheo_ros.models.effects import Effect


@dataclass(frozen=True)
class CameraDrift(Effect):
    \"\"\"The camera's mount creeps: every marker seen moving by (vx, vy) t.\"\"\"

    id: ClassVar[str] = "camera_drift"
    signals: ClassVar[tuple[str, ...]] = ("markers",)
    shows_in: ClassVar[tuple[str, ...]] = ("pull", "keep", "release")
    signed: ClassVar[tuple[str, ...]] = ("vx", "vy")
    vx: float = 0.0    # m/s
    vy: float = 0.0    # m/s

    def measured_markers(self, t, displacement):
        return displacement + np.stack([self.vx * t, self.vy * t], axis=-1)[:, None, :]
"""
DRIFT = (1.0e-6, -2.0e-6)   # m/s: 50 s move the markers 2.5 and 5 camera noise stds


@pytest.fixture(scope="module")
def drifting(tmp_path_factory):
    """A generator bag whose camera drifts, analysed without the plugin, and the plugin."""
    from generator import Effects, Profile, generate

    assert "camera_drift" not in catalogue() and "sensor_lag" not in catalogue()
    root = tmp_path_factory.mktemp("drift")
    bag = generate(root / "bag", effects=Effects(camera_drift=DRIFT), seed=3,
                   profile=Profile(keep_time=15.0, release_time=25.0, velocity=1e-3, depth=8e-3))
    site = install_plugin(root / "plugin", "rheo_camera_drift", CAMERA_DRIFT,
                          '[project.entry-points."rheo_ros.effects"]\ncamera_drift = "rheo_camera_drift:CameraDrift"\n')
    return bag, analyze(bag, workers=1).to_json(), json.loads((root / "bag.truth.json").read_text()), site


def test_an_effect_in_the_markers_alone_is_not_named_and_what_remains_says_markers_only(drifting):
    """Without the plugin: no catalogue effect touches the markers, none is named; what
    remains sits in the markers, in every phase (measured 1.3-1.8 x the noise), and in
    no tactile segment (the base fit's compromise leaves the total force of the keep at
    1.26 x its noise, which ``remaining`` reports too)."""
    _, report, _, _ = drifting
    d = report["diagnosis"]
    assert (d["missing_effects"], d["adequate"], d["explained"]) == ([], False, False), d["evidence"]
    rest = d["remaining"]
    assert rest["segments"] == [] and not rest["force_only"]
    assert {c["phase"] for c in rest["misfits"] if c["signal"] == "markers"} >= {"pull", "release"}, rest["misfits"]


def test_with_the_markers_effect_as_a_plugin_it_is_named_and_its_drift_measured(drifting):
    """With the plugin installed: camera_drift named, the model adequate, the drift and
    E, c1, c2 within 3 std of the generator's truth (measured: within 1.9 std, the fit to
    the noise 0.96-1.02 per signal)."""
    bag, _, truth, site = drifting
    with plugin_on_path(site, "camera_drift", "rheo_camera_drift"):
        report = analyze(bag, workers=1).to_json()
    assert_named_and_right(report, "camera_drift", {"camera_drift.vx": DRIFT[0], "camera_drift.vy": DRIFT[1]},
                           truth["material"], stds=3)


# A material law of another family, in no catalogue: continuum damage (Mullins-like).
# The specimen's structure breaks down with the largest strain it has seen, so its whole
# stress is divided by (1 + softening x that strain): a softening with memory, which no
# stiffening form (each grows with the strain now) and no relaxation arm can follow. The
# user's plugin for it, as a package of its own.
DAMAGE = """
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rheo_ros.models.effects import Effect


@dataclass(frozen=True)
class Damage(Effect):
    \"\"\"Continuum damage: stress / (1 + softening x the largest nominal strain so far).\"\"\"

    id: ClassVar[str] = "damage"
    shows_in: ClassVar[tuple[str, ...]] = ("pull", "keep")
    resolving_experiment: ClassVar[str] = "a second push to the same depth"
    softening: float = 1.0

    @property
    def memory(self) -> float:
        return math.inf   # the largest strain since the start

    def stress_scale(self, strain):
        return 1.0 / (1.0 + self.softening * np.maximum.accumulate(np.maximum(strain, 0.0)))
"""
SOFTENING = 1.5   # at the 10 % strain of an 8 mm push: the stress 13 % under the undamaged block's
DAMAGE_PUSH = {"stage.depth": 8e-3, "stage.velocity": 1e-3, "stage.keep_time": 15.0, "stage.release_time": 25.0}


@pytest.fixture(scope="module")
def damaged(tmp_path_factory):
    """A generator bag of a damaging block (its own law: the undamaged block's stress over
    1 + d eps_max), analysed without the plugin, and the plugin installed."""
    from generator import Effects, Profile, generate

    assert "damage" not in catalogue()
    root = tmp_path_factory.mktemp("damage")
    push = Profile(**{k.split(".")[1]: v for k, v in DAMAGE_PUSH.items()})
    bag = generate(root / "bag", effects=Effects(damage=SOFTENING), seed=2, profile=push)
    site = install_plugin(root / "plugin", "rheo_damage", DAMAGE,
                          '[project.entry-points."rheo_ros.effects"]\ndamage = "rheo_damage:Damage"\n')
    return bag, analyze(bag, workers=1).to_json(), json.loads((root / "bag.truth.json").read_text()), site


def test_a_material_law_of_another_family_is_not_named_and_what_remains_is_a_ramp_in_the_pull(damaged):
    """Without the plugin: no effect named (measured: sensor_drift removes 72 % of the
    misfit where it shows but makes the keep worse, relaxation_branch -9 %, the stiffening
    forms change BIC by less than 3); what remains sits in the force, worst in the pull
    (measured: the total force 12.8 x the noise there, a ramp), in every segment."""
    _, report, _, _ = damaged
    d = report["diagnosis"]
    assert (d["missing_effect"], d["missing_effects"], d["explained"], d["adequate"]) == (None, [], False, False), \
        d["evidence"]
    rest = d["remaining"]
    assert set(rest["segments"]) == {"P1", "P2", "P3", "P4", "P5"} and not rest["markers_only"]
    worst = max(rest["misfits"], key=lambda c: c["ratio"])
    assert (worst["signal"], worst["phase"]) == ("total", "pull") and worst["ratio"] > 5, worst
    pull = rest["shapes"]["pull"]
    assert pull["shape"] == "ramp" and abs(pull["size"]) > 10, pull   # measured: a ramp of 89 x the noise


def test_with_the_material_law_as_a_plugin_it_is_named_and_its_softening_measured(damaged):
    """With the plugin installed: damage named, the model adequate, the softening and E,
    c1, c2 within 3 std of the generator's truth (measured: within 1.4 std; the final
    model's worst phase at 1.05 x the noise)."""
    bag, _, truth, site = damaged
    with plugin_on_path(site, "damage", "rheo_damage"):
        report = analyze(bag, workers=1).to_json()
    assert_named_and_right(report, "damage", {"damage.softening": SOFTENING}, truth["material"], stds=3)
