"""One object, many pushes (issue 25): every push is an experiment, modelled from where
the earlier pushes left the specimen (its permanent set, a recovery under way).

Data: the package's own simulator (``rheo simulate``, dynamic FE with the stage meeting
the specimen again where it reaches it): self-consistency, not accuracy on data the
package did not make.
"""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import REPO, TRUTH

from rheo_ros.app.analyze import analyze, estimate_bag
from rheo_ros.identification.estimate import BASE_PARAMETERS
from rheo_ros.io.bag import read_params

PUSHES = 3
PARAMS = textwrap.dedent("""\
    /**:
      ros__parameters:
        simulator: {seed: 1, effects: [''], refine: 12}
        stage: {depth: 0.008, velocity: 0.001, keep_time: 15.0, release_time: 40.0, pushes: 3}
    """)
KEYS = {"phases", "estimate", "models", "diagnosis"}


@pytest.fixture(scope="module")
def three_pushes(tmp_path_factory):
    """A bag of three 8 mm pushes on one specimen, 40 s apart (the specimen keeps a set of
    ~0.37 mm after the first), analysed by ``rheo analyze --no-discover``."""
    root = tmp_path_factory.mktemp("pushes")
    (root / "params.yaml").write_text(PARAMS)
    bag, out = root / "three", root / "three.json"
    subprocess.run([sys.executable, "-m", "rheo_ros", "simulate", "--params-file", str(root / "params.yaml"),
                    "--out", str(bag)], check=True, capture_output=True)
    run = subprocess.run([sys.executable, "-m", "rheo_ros", "analyze", str(bag), "--no-discover", "--quiet",
                          "--json", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return {**json.loads(out.read_text()), "path": bag}


def test_every_push_is_an_experiment_with_the_keys_of_a_one_push_report(three_pushes):
    experiments = three_pushes["experiments"]
    assert [e["experiment"] for e in experiments] == list(range(1, PUSHES + 1))
    assert all(KEYS <= set(e) for e in experiments)
    pulls = [next(p for p in e["phases"] if p["name"] == "pull") for e in experiments]
    # 8 s pull + 15 s keep + 40 s release apart: each push starts 63 s after the last.
    assert [round(p["t_start"] - pulls[0]["t_start"], 1) for p in pulls] == [0.0, 63.0, 126.0]
    assert any("3 pushes in the bag" in w and "pooled fit of experiments 1, 2, 3" in w
               for w in three_pushes["warnings"])


def test_the_top_level_is_the_pooled_fit_of_the_pushes_judged_one_object(three_pushes):
    """The contract: with several pushes the top-level keys describe the pooled fit. Its base
    model is the pool's (to 1e-3 of its std: the model's pool holds gamma too, whose
    correlations move E by ~1e-5 std), the closed form the pushes' inverse-variance mean
    (so between the smallest and largest push, with a std below each push's), the phases
    every push's, the RMS force the members' root mean square (within the pushes' range)."""
    experiments, [pool] = three_pushes["experiments"], three_pushes["pools"]
    base = three_pushes["models"][0]
    assert base["name"] == "three_element" and "pooled" in base["message"]
    for name in ("E", "c1", "c2"):
        assert base["params"][name] == pytest.approx(pool["params"][name], abs=1e-3 * pool["std"][name])
        assert base["std"][name] == pytest.approx(pool["std"][name], rel=1e-3)
        pushes = [e["estimate"][name] for e in experiments]
        assert min(pushes) <= three_pushes["estimate"][name] <= max(pushes)
        assert three_pushes["estimate"]["std"][name] < min(e["estimate"]["std"][name] for e in experiments)
    assert [p["experiment"] for p in three_pushes["phases"]] == [k for k in (1, 2, 3) for _ in range(3)]
    rms = [e["models"][0]["rmse_force"] for e in experiments]
    assert min(rms) <= base["rmse_force"] <= max(rms)
    assert base["bic"] == pytest.approx(sum(e["models"][0]["bic"] for e in experiments), rel=1e-12)
    assert three_pushes["diagnosis"]["experiments"] == [1, 2, 3]


def test_each_push_is_fitted_within_three_std_of_the_truth(three_pushes):
    """From the earlier pushes' history (the stage meets the set the first push left, not
    depth 0), on the 49 x 49-node simulator mesh: measured -0.7 to +0.2 std (push 1),
    -0.8 to -0.2 (push 2), -2.4 to +0.2 (push 3); without the history push 2's c2 came out
    49 % low (the issue's run)."""
    for e in three_pushes["experiments"]:
        fit = e["models"][0]
        for name in ("E", "c1", "c2"):
            assert abs(fit["params"][name] - TRUTH[name]) < 3 * fit["std"][name], (e["experiment"], name)


def test_a_later_push_gets_a_closed_form_from_where_the_stage_met_the_specimen(three_pushes):
    """The closed form sees a later push as a fresh one from the contact the top markers
    show: within 4 % of the truth, as push 1's own (measured: push 1 1.8 %, pushes 2 and 3
    at most 2.7 %; from depth 0 they were 235-630 % off)."""
    for e in three_pushes["experiments"]:
        for name in ("E", "c1", "c2"):
            assert e["estimate"][name] == pytest.approx(TRUTH[name], rel=0.04), (e["experiment"], name)


def test_the_node_gives_each_push_the_estimate_rheo_analyze_gives_it(three_pushes):
    """One pipeline: the estimator node's final estimate of each push (its core over the
    bag, ``estimate_bag``) equals the analysis' experiment to rounding (1e-9)."""
    params = {**read_params(three_pushes["path"]), "estimator.release_interval": 0.0}
    _, updates, errors = estimate_bag(str(three_pushes["path"]), params=params)
    assert errors == []
    finals = [u for u in updates if u.final]
    assert [u.experiment for u in finals] == list(range(1, PUSHES + 1))
    for update, e in zip(finals, three_pushes["experiments"]):
        base = e["models"][0]
        for name in BASE_PARAMETERS:
            assert update.params[name] == pytest.approx(base["params"][name], rel=1e-9), (e["experiment"], name)
            assert update.std[name] == pytest.approx(base["std"][name], rel=1e-6), (e["experiment"], name)


def test_three_pushes_on_one_specimen_pool_into_one_object_with_a_smaller_std(three_pushes):
    """One pool of the three, no change flagged; the pooled std below every push's (measured
    E 9.5 against 16.2-16.9 Pa) and the pooled values within 3 pooled stds of the truth
    (measured E -0.4, c1 -0.6, c2 -2.3)."""
    assert three_pushes["changes"] == []
    [pool] = three_pushes["pools"]
    assert pool["experiments"] == [1, 2, 3]
    for name in ("E", "c1", "c2"):
        assert pool["std"][name] < min(e["models"][0]["std"][name] for e in three_pushes["experiments"])
        assert abs(pool["params"][name] - TRUTH[name]) < 3 * pool["std"][name], name


@pytest.mark.parametrize("pause", [0.0, 200.0])
def test_on_the_independent_generator_each_push_is_right_whether_or_not_the_specimen_rested(tmp_path, pause):
    """test/generator.py (no code shared with the package): three 8 mm pushes, the next one
    at once (the block still recovering: contact 0.21 and 0.40 mm deep) or after 200 s
    (40 Voigt times: only the permanent set left). Each push's fit within 3 std of the
    truth (measured at most 2.3 std), the contact the markers show within 0.01 mm of the
    generator's (measured at most 0.004 mm), one pool, no change; the node says the same."""
    from generator import Profile, generate

    profile = Profile(depth=8e-3, velocity=1e-3, keep_time=15.0, release_time=40.0, retract_speed=0.02,
                      pushes=PUSHES, pause=pause)
    bag = generate(tmp_path / "bag", profile=profile, seed=1)
    truth = json.loads((tmp_path / "bag.truth.json").read_text())
    report = analyze(bag, discover_effects=False, workers=1).to_json()
    assert len(report["experiments"]) == PUSHES and report["changes"] == [] and len(report["pools"]) == 1
    assert_each_push_right(report, truth)
    # One pipeline on data the package did not make: the node's final estimate of each push
    # is the analysis' (to rounding).
    assert_node_gives_each_push(bag, report)


def test_a_push_on_a_block_at_rest_is_modelled_from_rest_whatever_came_before(tmp_path):
    """test/generator.py: three 8 mm pushes 20 s apart, the second on a new block of the
    same clay put in place at rest (the first block left a 0.3 mm set). The data decide
    (``met_at_rest``): the stage met the second block at 0 mm, so it is modelled from rest
    and the third push from the second only. Each push's fit within 3 std of the truth
    (measured at most 2.0 std; with the first block's history kept, push 2's c2 came out
    105 % high, 74 std, and the three pushes fell in three pools), the JSON says which
    push started from rest, one pool (one material), the node agrees."""
    from generator import Profile, generate

    profile = Profile(depth=8e-3, velocity=1e-3, keep_time=15.0, release_time=40.0, retract_speed=0.02,
                      pushes=PUSHES, pause=20.0, fresh=(1,))
    bag = generate(tmp_path / "bag", profile=profile, seed=3)
    truth = json.loads((tmp_path / "bag.truth.json").read_text())
    assert [round(p["contact_depth"], 6) for p in truth["pushes"]][:2] == [0.0, 0.0]
    report = analyze(bag, discover_effects=False, workers=1).to_json()
    assert [e["from_rest"] for e in report["experiments"]] == [False, True, False]
    assert any("experiment 2: the stage met the specimen at" in w and "at rest" in w for w in report["warnings"])
    assert_each_push_right(report, truth)
    assert report["changes"] == [] and len(report["pools"]) == 1
    assert_node_gives_each_push(bag, report)


BLOCK_PROFILE = dict(depth=8e-3, velocity=1e-3, keep_time=15.0, release_time=40.0, retract_speed=0.02,
                     pushes=PUSHES, pause=20.0, fresh=(1,))


def test_a_block_of_another_clay_is_flagged_as_changed_and_pooled_apart(tmp_path):
    """test/generator.py: three pushes, the second and third on a new block of a stiffer,
    less viscous clay (E and c1 +35 %, c2 -35 %) put in place at rest; nothing tells the
    package. Each push's fit within 3 std of its own block's material, experiment 2
    flagged as another (or a changed) object with E, c1 and c2 among the parameters that
    moved, pools [1] and [2, 3]; the node's pools (its core over the bag) are the
    analysis' to rounding. Measured: each push within 2.3 std of its block; the change's
    distance 6.1e6 over a limit of 16.3, E +2012, c1 +566, c2 -96 stds."""
    from generator import Material, Profile, generate

    other = Material(E=3.33e4 * 1.35, c1=1.69e5 * 1.35, c2=3.11e7 * 0.65)
    bag = generate(tmp_path / "bag", profile=Profile(**BLOCK_PROFILE), seed=5, fresh_material=other)
    truth = json.loads((tmp_path / "bag.truth.json").read_text())
    report = analyze(bag, discover_effects=False, workers=1).to_json()
    assert_each_push_right(report, truth, [truth["material"], truth["fresh_material"], truth["fresh_material"]])
    [change] = report["changes"]
    assert change["experiment"] == 2 and not change["stated"] and {"E", "c1", "c2"} <= set(change["moved"])
    assert [p["experiments"] for p in report["pools"]] == [[1], [2, 3]]
    assert report["diagnosis"]["experiments"] == [2, 3]   # the top level: the object under the stage at the end
    assert_node_pools_as_analysis(bag, report)


def test_a_goal_that_says_new_object_starts_a_pool_and_models_the_push_from_rest(tmp_path):
    """The same clay's fresh block at push 2 (test/generator.py), with the ``/rheo/object``
    hint ``new`` an identify goal publishes, stamped 0.5 s before push 2's stage leaves
    depth 0: experiment 2 says object new and from rest, starts a pool that the change
    list says was stated (no parameter moved: the same clay), push 3 joins it; each push
    within 3 std of the truth; the node (its core over the bag, hint included) pools the
    same. Measured: each push within 2.0 std; the stated change's distance 3.9, under the
    limit of 16.3 that would have flagged it from the data."""
    from generator import Profile, generate

    bag = generate(tmp_path / "bag", profile=Profile(**BLOCK_PROFILE), seed=3)
    truth = json.loads((tmp_path / "bag.truth.json").read_text())
    hinted = with_object_hint(bag, tmp_path / "hinted", truth["pushes"][1]["start"] - 0.5, "new")
    report = analyze(hinted, discover_effects=False, workers=1).to_json()
    assert [e["object"] for e in report["experiments"]] == ["", "new", ""]
    assert [e["from_rest"] for e in report["experiments"]] == [False, True, False]
    assert any("experiment 2: the goal said 'new' object" in w for w in report["warnings"])
    [change] = report["changes"]
    assert change["experiment"] == 2 and change["stated"] and change["moved"] == {}
    assert [p["experiments"] for p in report["pools"]] == [[1], [2, 3]]
    assert_each_push_right(report, truth)
    assert_node_pools_as_analysis(hinted, report)


def with_object_hint(bag, out, t: float, kind: str):
    """A copy of ``bag`` with one ``/rheo/object`` message (stamp ``t`` s), as ``rheo
    record`` keeps an identify goal's hint."""
    from rosbags.highlevel import AnyReader

    from rheo_ros.io.bag import BagWriter, typestore
    from rheo_ros.io.messages import OBJECT_TOPIC, OBJECT_TYPE, object_hint_message

    definition = (REPO / "msg_schemas" / "rheo_ros_interfaces" / "msg" / "ObjectHint.msg").read_text()
    ns = round(t * 1e9)
    with AnyReader([bag], default_typestore=typestore()) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections} | {OBJECT_TOPIC: OBJECT_TYPE}
        with BagWriter(out, read_params(bag), topics=topics, definitions={OBJECT_TYPE: definition}) as writer:
            hint = [(ns, OBJECT_TOPIC, None)]
            for conn, stamp, raw in reader.messages():
                if hint and stamp >= hint[0][0]:
                    writer.write(OBJECT_TOPIC, ns, object_hint_message(writer.types, ns, kind))
                    hint = []
                writer.write_raw(conn.topic, stamp, raw)
    return out


def assert_node_pools_as_analysis(bag, report: dict) -> None:
    """One pipeline: the node's core over the bag pools the pushes as the analysis does."""
    pools = []
    _, _, errors = estimate_bag(str(bag), params={**read_params(bag), "estimator.release_interval": 0.0,
                                                  "estimator.diagnose": False}, pools=pools)
    assert errors == [] and [p.experiment for p in pools] == list(range(1, PUSHES + 1))
    assert [list(p.pool.experiments) for p in pools if p.experiment in report["pools"][-1]["experiments"]][-1] \
        == report["pools"][-1]["experiments"]
    assert [p.change.experiment for p in pools if p.change] == [c["experiment"] for c in report["changes"]]
    last = pools[-1].pool
    for name in ("E", "c1", "c2"):
        assert last.params[name] == pytest.approx(report["pools"][-1]["params"][name], rel=1e-9), name
        assert last.std[name] == pytest.approx(report["pools"][-1]["std"][name], rel=1e-6), name


def assert_each_push_right(report: dict, truth: dict, materials: list[dict] | None = None) -> None:
    """Each push's base fit within 3 std of the generator's material (``materials``: each
    push's block's), the contact the markers show within 0.01 mm of the generator's."""
    materials = materials or [truth["material"]] * len(truth["pushes"])
    for e, push, material in zip(report["experiments"], truth["pushes"], materials):
        fit = e["models"][0]
        for name in ("E", "c1", "c2"):
            assert abs(fit["params"][name] - material[name]) < 3 * fit["std"][name], (e["experiment"], name)
        assert e["contact_depth"] == pytest.approx(push["contact_depth"], abs=1e-5)


def assert_node_gives_each_push(bag, report: dict) -> None:
    """One pipeline: the node's core over the bag (same process, same operations) gives
    each push the analysis' base fit, to rounding."""
    _, updates, errors = estimate_bag(str(bag), params={**read_params(bag), "estimator.release_interval": 0.0})
    finals = [u for u in updates if u.final]
    assert errors == [] and len(finals) == PUSHES
    for update, e in zip(finals, report["experiments"]):
        for name in BASE_PARAMETERS:
            assert update.params[name] == pytest.approx(e["models"][0]["params"][name], rel=1e-9), name


def test_a_later_push_leaves_out_the_readings_beside_its_contact(tmp_path):
    """A later push meets the set the earlier one left after its pull began, and the force
    jumps there (the Voigt dashpot); a reading beside that instant pinned the parameters
    through the jump (seen in the action test: a tactile clock offset of 5 ms fitted, c2's
    std 16 x too small and c2 15 std off; with the guard 0.8 std). test/generator.py, two
    4 mm pushes 5 s apart: the contact the markers show within 15 ms of the generator's
    (measured 8.4 ms: the block still recovers before the second; the guard is 50 ms), and
    no fitted reading within the guard of it."""
    from generator import Profile, generate

    from rheo_ros.identification.fit import BOUNDARY_GUARD, WholeRecordProblem, away_from_boundaries
    from rheo_ros.models.effects import Model
    from rheo_ros.models.elements import three_element
    from rheo_ros.record import contact_time

    profile = Profile(depth=4e-3, velocity=1e-3, keep_time=6.0, release_time=20.0, pushes=2, pause=5.0)
    bag = generate(tmp_path / "bag", profile=profile, seed=1)
    truth = json.loads((tmp_path / "bag.truth.json").read_text())
    later = analyze(bag, discover_effects=False, workers=1).experiments[1].record
    met = truth["pushes"][1]["contact_depth"]
    assert met > 5e-5   # a set to meet (measured 0.084 mm): its contact beyond the pull start's guard
    t_contact = later.profile().t_pull_start + met / profile.velocity
    assert contact_time(later) == pytest.approx(t_contact, abs=0.015)   # measured 8.4 ms (the block still recovering)
    away = away_from_boundaries(later.force_t, later.profile(), contact_time(later))
    problem = WholeRecordProblem(later, Model(three_element(1.0, 1.0, 1.0)), 1.0, 1.0)
    assert problem.live_mask.shape[0] == away.sum()   # the fit's readings are these
    assert np.abs(later.force_t[away] - t_contact).min() >= BOUNDARY_GUARD - 0.015
    unguarded = away_from_boundaries(later.force_t, later.profile(), later.profile().t_pull_start)
    assert unguarded.sum() > away.sum()
