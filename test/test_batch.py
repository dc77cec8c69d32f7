"""``rheo analyze`` over many bags on Dask (issue 22): ten bags on a local cluster of two
workers, a JSON per bag equal to the one-bag analysis, one Parquet table, a failing bag a
row with its error; and the same run on a cluster started elsewhere (``--scheduler``)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import BAGS, TRUTH

from rheo_ros.app.analyze import analyze
from rheo_ros.app.batch import BagJob, output_names, run_batch, table_rows, verdict

GOOD = ["clean_short_keep", "effect_relaxation_branch", "effect_strain_stiffening", "clean_short_keep",
        "effect_relaxation_branch", "effect_strain_stiffening", "clean_short_keep"]


def fleet(root: Path) -> dict[str, str]:
    """Ten bags as a lab would keep them, a folder per robot: seven good (copies of three
    reference bags) and three that fail (a killed recording, a truncated one, one with no
    parameters). Returns each bag's path and what it is."""
    kinds = {}
    for i, name in enumerate(GOOD):
        bag = root / f"robot{i % 3 + 1}" / f"{name}_{i}"
        shutil.copytree(BAGS / name, bag)
        kinds[str(bag)] = name
    killed = root / "robot1" / "killed"
    killed.mkdir()
    shutil.copy(next((BAGS / "clean_short_keep").glob("*.mcap")), killed / "killed.mcap")
    kinds[str(killed)] = "killed"
    truncated = root / "robot2" / "truncated"
    shutil.copytree(BAGS / "clean_short_keep", truncated)
    mcap = next(truncated.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 3])
    kinds[str(truncated)] = "truncated"
    bare = root / "robot3" / "no_params"
    shutil.copytree(BAGS / "clean_short_keep", bare)
    meta = bare / "metadata.yaml"
    meta.write_text(meta.read_text().replace("rheo_ros.params", "someone_else.params"))
    kinds[str(bare)] = "no params"
    return kinds


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    kinds = fleet(root / "lab")
    out = root / "out"
    run = subprocess.run([sys.executable, "-m", "rheo_ros", "analyze", str(root / "lab"), "--no-discover",
                          "--workers", "2", "--json", str(out / "json"), "--table", str(out / "table.parquet")],
                         capture_output=True, text=True, timeout=900, cwd=root)
    return kinds, out, run


def test_ten_bags_on_two_workers_give_a_json_each_and_one_table(batch):
    kinds, out, run = batch
    assert run.returncode == 2, run.stderr        # three bags failed, after the rest were written
    assert "Traceback" not in run.stderr
    lines = run.stdout.strip().splitlines()
    assert len(lines) == 11 and lines[-1].startswith("10 bags: 7 analysed, 3 failed; table: "), run.stdout
    table = pq.read_table(out / "table.parquet").to_pylist()
    by_bag = {}
    for row in table:
        by_bag.setdefault(row["bag"], []).append(row)
    assert set(by_bag) == {str(Path(b).resolve()) for b in kinds}
    for bag, kind in kinds.items():
        rows = by_bag[str(Path(bag).resolve())]
        if kind in GOOD:
            # --no-discover: the base model only, the one push.
            (row,) = rows
            assert row["error"] is None and row["model"] == "three_element" and row["push"] == 0
            assert row["final"] and row["verdict"] == "not diagnosed"
            written = json.loads((out / "json" / f"{Path(bag).name}.json").read_text())   # names unique: no prefix
            assert written["models"][0]["params"]["E"] == row["E"]
            if kind == "clean_short_keep":   # the simulator's truth within 3 of the fit's std
                for p in ("E", "c1", "c2", "gamma"):
                    assert abs(row[p] - TRUTH[p]) < 3 * row[f"std_{p}"] + 0.002 * TRUTH[p], (p, row)
        else:
            (row,) = rows
            assert row["model"] is None and row["E"] is None
    errors = {kinds[b]: by_bag[str(Path(b).resolve())][0]["error"] for b in kinds if kinds[b] not in GOOD}
    assert "not a rosbag2 directory" in errors["killed"] and "rheo bag repair" in errors["killed"]
    assert "cannot read bag" in errors["truncated"] or "truncated" in errors["truncated"], errors
    assert "no parameters in the bag's metadata" in errors["no params"]


def test_a_bag_of_the_batch_gets_the_same_json_as_alone(batch):
    """One computation: the worker's analysis of a bag is the one ``rheo analyze`` gives for
    it alone (the same code; BLAS kernels and threads may differ between the processes, so
    within 1e-3 of each parameter's std, and the BIC within 1e-3 of one unit)."""
    kinds, out, _ = batch
    bag = next(b for b, k in kinds.items() if k == "effect_relaxation_branch")
    alone = analyze(bag, discover_effects=False, workers=1).to_json()
    written = json.loads((out / "json" / f"{Path(bag).name}.json").read_text())
    for part in ("estimate", "model"):
        mine, theirs = ((d["estimate"], d["estimate"]["std"]) if part == "estimate" else
                        (d["models"][0]["params"], d["models"][0]["std"]) for d in (written, alone))
        for p in ("E", "c1", "c2", "gamma"):
            assert abs(mine[0][p] - theirs[0][p]) <= 1e-3 * theirs[1][p], (part, p, mine[0][p], theirs[0][p])
    assert abs(written["models"][0]["bic"] - alone["models"][0]["bic"]) <= 1e-3


def test_a_cluster_started_elsewhere_runs_the_batch(tmp_path):
    """``--scheduler ADDRESS``: the bags go to that cluster's workers (here one started by
    the test, as a lab's would be), rows in the jobs' order, a failing bag's row its error."""
    from dask.distributed import LocalCluster

    bags = [BAGS / "clean_short_keep", tmp_path / "missing"]
    jobs = [BagJob(str(b), None, (), False, None, None) for b in bags]
    done = []
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        rows = run_batch(jobs, scheduler=cluster.scheduler_address,
                         progress=lambda k, n, bag: done.append((k, n)))
    assert done == [(1, 2), (2, 2)]
    assert [r["bag"] for r in rows] == [str(b) for b in bags]
    assert rows[0]["error"] is None and rows[0]["E"] == pytest.approx(TRUTH["E"], rel=0.01)
    assert "not a rosbag2 directory" in rows[1]["error"] and str(tmp_path / "missing") in rows[1]["error"]


def test_names_verdicts_and_rows_of_several_pushes():
    assert output_names([Path("/a/r1/push"), Path("/a/r2/push"), Path("/a/r2/other")]) == \
        ["r1__push", "r2__push", "r2__other"]
    assert output_names([Path("/a/x"), Path("/b/y")]) == ["x", "y"]
    assert verdict({"explained": True, "missing_effects": [], "missing_effect": None}) == "adequate"
    assert verdict({"explained": True, "missing_effects": ["adhesion", "sensor_drift"]}) == \
        "explained by adhesion+sensor_drift"
    assert verdict({"explained": False, "missing_effects": ["adhesion"]}) == "unexplained (after adhesion)"
    assert verdict({"explained": None}) == "not diagnosed"
    model = {"name": "three_element", "effects": [], "params": {"E": 1.0, "c1": 2.0, "c2": 3.0, "gamma": 0.3},
             "std": {"E": 0.1}, "rmse_force": 0.01, "bic": 5.0}
    report = {"models": [model], "diagnosis": {"explained": True, "adequate_model": "three_element"},
              "experiments": [{"models": [model], "diagnosis": None}, {"models": [model, model], "diagnosis": None}]}
    rows = table_rows("b", report)
    assert [r["push"] for r in rows] == [0, 1, 2, 2]
    assert rows[0]["final"] and rows[0]["verdict"] == "adequate" and rows[0]["std_c1"] is None
