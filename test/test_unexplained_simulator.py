"""The effects in no catalogue of test_unexplained.py, made by the other generator: the
package's simulator (FE on its converged mesh, its own sensor path) runs each as a plugin
package (a sensor with memory, a material law of another family, an effect in the markers
alone). With the plugin found, the analysis names it, adequate, its parameters right;
with the plugin gone, the same bag names nothing, says the catalogue does not explain
it, and describes what remains where the effect sits (issue 24, item 5).

The simulator's own sensor (dead band, quantisation) is in these bags, so this is
self-consistency for the fit; the verdict without the plugin is the point."""

from pathlib import Path

import pytest
from conftest import readme_block
from test_unexplained import (
    CAMERA_DRIFT,
    DAMAGE,
    DAMAGE_PUSH,
    DRIFT,
    SOFTENING,
    assert_named_and_right,
    install_plugin,
    plugin_on_path,
    simulated_material,
)

from rheo_ros.app.analyze import analyze
from rheo_ros.app.simulate import simulate_to_bag
from rheo_ros.config.setup import Setup, check_params
from rheo_ros.models.effects import catalogue

LAG = {"sensor_lag.time": 1.5, "sensor_lag.share": 0.3}
LAG_PUSH = {"stage.keep_time": 10.0, "stage.release_time": 15.0}

# Each plugin: (its module, its source, its entry point, the push, its values, where the
# bag misfits without it: "force" or "markers").
PLUGINS = {
    "sensor_lag": ("rheo_sensor_lag", lambda: readme_block("python", "class SensorLag"), LAG_PUSH, LAG, "force"),
    "damage": ("rheo_damage", lambda: DAMAGE, DAMAGE_PUSH, {"damage.softening": SOFTENING}, "force"),
    "camera_drift": ("rheo_camera_drift", lambda: CAMERA_DRIFT, DAMAGE_PUSH,
                     {"camera_drift.vx": DRIFT[0], "camera_drift.vy": DRIFT[1]}, "markers"),
}


@pytest.fixture(scope="module", params=sorted(PLUGINS))
def simulated(request, tmp_path_factory) -> tuple[str, Path, Setup, dict, Path]:
    """A bag of the package's simulator running the plugin (found through the entry-point
    group), the analysis with it, and the plugin's site."""
    effect_id = request.param
    module, source, push, values, _ = PLUGINS[effect_id]
    assert effect_id not in catalogue()
    root = tmp_path_factory.mktemp(effect_id)
    site = install_plugin(root / "plugin", module, source(),
                          f'[project.entry-points."rheo_ros.effects"]\n{effect_id} = "{module}:'
                          f'{"".join(w.title() for w in effect_id.split("_"))}"\n')
    with plugin_on_path(site, effect_id, module):
        setup = Setup(check_params({**push, "simulator.effects": [effect_id],
                                    **{f"effects.{k}": v for k, v in values.items()}}))
        simulate_to_bag(setup, 7, root / "bag")
        report = analyze(str(root / "bag"), workers=1).to_json()
    return effect_id, root / "bag", setup, report, site


def test_with_the_plugin_the_simulators_effect_is_named_and_right(simulated):
    """Named alone, adequate and explained; the effect's parameters and E, c1, c2 within 3
    std of what the simulator was given (measured at stops 62-64: lag within 2.12 std, c2,
    the share 1.92; damage within 0.99 std, c2). With the lag held between samples
    instead of the README's exact law, a settling drift was named beside it; on a coarse
    simulator mesh (refine 4) its own discretisation is in the data and no model here has
    it (the force's 1-s means misfit at 19 sd: rightly unexplained). The damage push
    matters: with the default 20 s pull and a 10 s keep the softening trades against c2."""
    effect_id, _, setup, report, _ = simulated
    assert_named_and_right(report, effect_id, PLUGINS[effect_id][3], simulated_material(setup), stds=3)


def test_without_the_plugin_nothing_is_named_and_what_remains_sits_where_the_effect_does(simulated):
    """The plugin gone: no effect named, not explained; what remains misfits in the
    signal the effect changes: the force for the lag and the damage, the markers alone for
    the camera's drift. Measured (stop 71): the lag, adhesion the closest, every segment
    misfitting (the total force's release 129 x the noise), and the lagging-reading rival
    fitting better by 1.1e5 in BIC with 1.501 s and 0.299 of each reading (given 1.5 s,
    0.3); the damage, nothing added, the pull 13 x the noise, a ramp, and the softening
    rival at 1.502 (given 1.5); the camera's drift, a drift the closest, the markers
    before contact and in the pull 1.9 and 1.44 x their noise, no rival better."""
    effect_id, bag, _, _, _ = simulated
    assert effect_id not in catalogue()
    d = analyze(str(bag), workers=1).to_json()["diagnosis"]
    assert (d["missing_effect"], d["missing_effects"], d["explained"]) == (None, [], False), d["evidence"]
    rest = d["remaining"]
    signal = PLUGINS[effect_id][4]
    if signal == "markers":
        assert rest["markers_only"] and rest["segments"] == [], rest["misfits"]
    else:
        assert rest["segments"] and not rest["markers_only"], rest["misfits"]
