"""``rheo analyze`` over many bags (a lab's or a fleet's recordings) on Dask.

Each bag is analysed in one task, on a worker of a ``dask.distributed`` cluster (a local
one by default, or the scheduler at ``--scheduler ADDRESS``): the bag's JSON and report
as ``rheo analyze`` writes them for one bag, and one Parquet table for the lot, a row per
bag, push and model. A bag that fails is a row with its error, never the end of the run.

The candidates' fits inside one analysis run in that task's process (``workers=1``): the
cluster's workers already fill the cores, one bag each.
"""

from __future__ import annotations

import json
import logging
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rheo_ros.io.errors import BagError
from rheo_ros.io.files import write_bytes_atomic

# The parameters every row carries as its own column (an effect's own go to ``params``).
BASE_PARAMETERS = ("E", "c1", "c2", "gamma")


def is_bag(path: Path) -> bool:
    """A rosbag2 directory (metadata.yaml), or a recording killed before writing it (an
    .mcap only: its analysis then says to repair it)."""
    return path.is_dir() and ((path / "metadata.yaml").is_file() or any(path.glob("*.mcap")))


def find_bags(paths: Sequence[str | Path]) -> list[Path]:
    """The bags ``paths`` name: each a bag itself, or a directory whose bags are found at
    any depth below it (in name order).

    Raises:
        BagError: a path that does not exist, or a directory with no bag in it.
    """
    found: list[Path] = []
    for path in map(Path, paths):
        if not path.exists():
            raise BagError(f"{path}: no such file or directory")
        if is_bag(path):
            found.append(path)
            continue
        below = bags_below(path)
        if not below:
            raise BagError(f"{path}: neither a rosbag2 directory nor a directory holding one")
        found += below
    return found


def bags_below(folder: Path) -> list[Path]:
    """The bags at any depth below ``folder`` (not inside another bag), in name order."""
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.rglob("*") if is_bag(p) and not any(is_bag(q) for q in p.parents))


@dataclass(frozen=True)
class BagJob:
    """One bag's analysis and where its outputs go (``json`` a file, ``report`` a folder;
    None: not written)."""

    bag: str
    params_file: str | None
    effects: tuple[str, ...]
    discover: bool
    json: str | None
    report: str | None


def output_names(bags: Sequence[Path]) -> list[str]:
    """A file name per bag: its folder's name, with as many parent folders as it takes to
    tell bags of the same name apart (``fleet/robot1/push`` and ``fleet/robot2/push``)."""
    depth = 1
    while True:
        names = ["__".join(b.resolve().parts[-depth:]) for b in bags]
        if len(set(names)) == len(names) or depth > max(len(b.resolve().parts) for b in bags):
            return names
        depth += 1


def analyze_bag(job: BagJob) -> list[dict[str, Any]]:
    """Analyse one bag (in a worker): write its JSON and report, return its table rows.
    Errors are rows: the bad input's one line (as ``rheo analyze`` prints it), or the
    exception's last line for a failure of the package (with its type)."""
    from rheo_ros.app.analyze import analyze, write_outputs
    from rheo_ros.app.cli import BAD_INPUT, error_line
    from rheo_ros.online.worker import single_threaded_blas

    # In the worker, whatever started it (a local cluster, or `dask worker` on another
    # machine): the same bits as `rheo analyze` of the bag, and no BLAS threads fighting
    # the other workers for the cores.
    single_threaded_blas()
    try:
        result = analyze(job.bag, effects=job.effects, params_file=job.params_file,
                         discover_effects=job.discover, workers=1)
        report = result.to_json()
        write_outputs(result, job.json, job.report, report)
        return table_rows(job.bag, report)
    except BAD_INPUT as exc:
        return [error_row(job.bag, error_line(exc))]
    except Exception as exc:   # a bug must not end the batch: the row says what failed, and where
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return [error_row(job.bag, f"{type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})")]


def verdict(diagnosis: dict[str, Any] | None) -> str:
    """The diagnosis in a few words: adequate, the effects added, or unexplained."""
    if not diagnosis or diagnosis.get("explained") is None:   # --no-discover
        return "not diagnosed"
    named = diagnosis.get("missing_effects") or ([diagnosis["missing_effect"]] if diagnosis.get("missing_effect")
                                                 else [])
    if not diagnosis["explained"]:
        return "unexplained" + (f" (after {'+'.join(named)})" if named else "")
    return "adequate" if not named else "explained by " + "+".join(named)


def table_rows(bag: str, report: dict[str, Any]) -> list[dict[str, Any]]:
    """A row per push and model of one bag's JSON: push 0 is the top level (the one push,
    or the pushes pooled), 1.. each push of a bag of several."""
    parts = [(0, report)] + list(enumerate(report.get("experiments", []), 1))
    sensor = report.get("sensor") or {}
    rows = []
    for push, part in parts:
        diagnosis = part.get("diagnosis")
        models = part.get("models", [])
        # The model the analysis ends with: the adequate one, else the last fitted.
        final = (diagnosis or {}).get("adequate_model") or (models[-1]["name"] if models else None)
        for model in models:
            params, std = model.get("params", {}), model.get("std") or {}
            rows.append({
                "bag": bag, "push": push, "model": model["name"], "effects": "+".join(model.get("effects", [])),
                "forms": json.dumps(model.get("forms", {}), sort_keys=True),
                **{p: params.get(p) for p in BASE_PARAMETERS},
                **{f"std_{p}": std.get(p) for p in BASE_PARAMETERS},
                "params": json.dumps(params, sort_keys=True), "std": json.dumps(std, sort_keys=True),
                "at_bound": "+".join(model.get("at_bound", [])),
                "rmse_force": model.get("rmse_force"), "bic": model.get("bic"),
                "final": model["name"] == final, "verdict": verdict(diagnosis),
                "sensor": sensor.get("law"), "tactile_noise": (sensor.get("tactile") or {}).get("noise"),
                "marker_noise": (sensor.get("markers") or {}).get("noise"), "error": None,
            })
    return rows or [error_row(bag, "the analysis fitted no model")]


def error_row(bag: str, error: str) -> dict[str, Any]:
    """The row of a bag that could not be analysed."""
    row = dict.fromkeys(ROW_SCHEMA)
    row.update(bag=bag, error=error, final=False)
    return row


# Column: Arrow type (fixed, so that a batch of failures alone still writes a typed table).
ROW_SCHEMA = {
    "bag": "string", "push": "int32", "model": "string", "effects": "string", "forms": "string",
    **dict.fromkeys(BASE_PARAMETERS, "float64"), **{f"std_{p}": "float64" for p in BASE_PARAMETERS},
    "params": "string", "std": "string", "at_bound": "string", "rmse_force": "float64", "bic": "float64",
    "final": "bool", "verdict": "string", "sensor": "string", "tactile_noise": "float64",
    "marker_noise": "float64", "error": "string",
}


def write_table(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """The rows as one Parquet file, written atomically (``io.files``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = pa.schema([(name, pa.type_for_alias(kind)) for name, kind in ROW_SCHEMA.items()])
    table = pa.Table.from_pylist([{k: r.get(k) for k in ROW_SCHEMA} for r in rows], schema=schema)
    buffer = pa.BufferOutputStream()
    pq.write_table(table, buffer)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_bytes_atomic(path, buffer.getvalue().to_pybytes())


def run_batch(jobs: Sequence[BagJob], scheduler: str | None = None, workers: int | None = None,
              progress: Callable[[int, int, str], None] | None = None) -> list[dict[str, Any]]:
    """Every job on a Dask cluster (``dask_client``). Returns the rows in the jobs' order;
    ``progress(done, total, bag)`` as each bag ends."""
    from dask.distributed import as_completed

    with dask_client(scheduler, workers) as client:
        futures = {client.submit(analyze_bag, job, pure=False, key=f"rheo-analyze-{i}"): i
                   for i, job in enumerate(jobs)}
        rows: dict[int, list[dict[str, Any]]] = {}
        for done, future in enumerate(as_completed(futures), 1):
            i = futures[future]
            try:
                rows[i] = future.result()
            except Exception as exc:   # the worker died (memory, a signal): the bag's row says so
                rows[i] = [error_row(jobs[i].bag, f"the worker analysing it failed: {type(exc).__name__}: {exc}")]
            if progress:
                progress(done, len(jobs), jobs[i].bag)
    return [row for i in range(len(jobs)) for row in rows[i]]


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A Dask client on the scheduler at ``scheduler``, or on a local cluster of its own of
    ``workers`` processes (default: one per core, at most four), a thread each; closed on
    exit, the local cluster with it."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    from rheo_ros.diagnosis.discover import default_workers

    levels = {name: logging.getLogger(name).level for name in DISTRIBUTED_LOGGERS}
    try:
        # A worker per core, one bag each (its BLAS on one thread: ``analyze_bag``).
        with LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            try:
                yield client
            finally:
                # A worker's heartbeat racing the shutdown logs a traceback ("Stream is
                # closed") after every result is in: the run is over, nothing to report.
                with suppress(Exception):
                    client.run(quiet_distributed_logs)
                quiet_distributed_logs()
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


# distributed's loggers a closing local cluster may write to.
DISTRIBUTED_LOGGERS = ("distributed", "distributed.worker", "distributed.nanny", "distributed.core",
                       "distributed.scheduler", "distributed.comm", "distributed.batched")


def quiet_distributed_logs() -> None:
    """Hold distributed's loggers to CRITICAL in this process (a closing cluster's)."""
    for name in DISTRIBUTED_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def batch_jobs(bags: Sequence[Path], params_file: str | None, effects: Sequence[str], discover: bool,
               json_dir: str | None, report_dir: str | None) -> Iterator[BagJob]:
    """A job per bag, its JSON at ``json_dir/<name>.json`` and its report in
    ``report_dir/<name>/`` (``output_names``)."""
    for bag, name in zip(bags, output_names(bags)):
        yield BagJob(str(bag.resolve()), params_file, tuple(effects), discover,
                     str(Path(json_dir) / f"{name}.json") if json_dir else None,
                     str(Path(report_dir) / name) if report_dir else None)
