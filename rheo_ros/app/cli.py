"""``rheo``: the command line (also ``python -m rheo_ros``)."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rheo_ros.config.setup import ParamsError
from rheo_ros.io.errors import BagError
from rheo_ros.io.files import write_json_atomic
from rheo_ros.nodes.errors import GraphError
from rheo_ros.online.worker import single_threaded_blas
from rheo_ros.record import RecordError


def writable(path: str | None, option: str, folder: bool = False) -> None:
    """Refuse an output path that cannot be written, before the work that fills it (an
    analysis took minutes, then failed on a missing folder): ``folder`` True for one
    created with its parents where missing (``--report DIR``), else a file or a bag
    directory made in an existing folder.

    Raises:
        OSError: names the option and the path."""
    if not path:
        return
    target = Path(path)
    if folder:
        if target.exists() and not target.is_dir():
            raise OSError(f"{option} {path}: exists and is not a folder")
        parent = next(p for p in (target, *target.parents) if p.exists())
    else:
        if target.is_dir():
            raise OSError(f"{option} {path}: is a folder")
        parent = target.parent
        if not parent.is_dir():
            raise OSError(f"{option} {path}: no folder {parent} to write it in")
    if not parent.is_dir():
        raise OSError(f"{option} {path}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OSError(f"{option} {path}: cannot write in {parent}")


# What a bad input raises: one line on stderr, exit 2 (``rheo analyze`` of many bags: the
# bag's row). Anything else is a bug in the package, with its traceback.
BAD_INPUT = (BagError, RecordError, GraphError, ParamsError, KeyError, OSError, ValueError)


def error_line(exc: BaseException) -> str:
    """The one line a bad input's error gives (a KeyError's own text, not its repr)."""
    text = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
    return " ".join(str(text).split())


def _write_json(path: str | None, data: dict[str, Any]) -> None:
    if path:
        write_json_atomic(path, data)


def _bench(args: argparse.Namespace) -> int:
    """Run ``rheo_ros.bench.<name>``: its ``run(**options)`` figures, printed and as JSON."""
    writable(args.json, "--json")
    module = importlib.import_module(f"rheo_ros.bench.{args.bench}")
    options = {k: getattr(args, k) for k in args.bench_options}
    result = module.run(**options)
    print(module.format_table(result))
    _write_json(args.json, result)
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from rheo_ros.app.simulate import simulate_to_bag
    from rheo_ros.config.setup import Setup, check_params, load_params
    from rheo_ros.models.effects import effect_class

    params = load_params(args.params_file)
    if args.effect is not None:
        for effect_id in args.effect:
            effect_class(effect_id)  # unknown ids fail here, with the catalogue
        params["simulator.effects"] = list(args.effect) or [""]
    if args.seed is not None:
        params["simulator.seed"] = args.seed
    params = check_params(params, "command line")
    if Path(args.out).exists():
        raise OSError(f"{args.out} exists already, not overwriting")
    writable(args.out, "--out")
    counts = simulate_to_bag(Setup(params), params["simulator.seed"], args.out)
    print(f"{args.out}: " + ", ".join(f"{n} on {topic}" for topic, n in counts.items()))
    return 0


def _record(args: argparse.Namespace) -> int:
    from rheo_ros.config.setup import load_params
    from rheo_ros.nodes.recorder import record

    if Path(args.out).exists():
        raise OSError(f"{args.out} exists already, not overwriting")
    writable(args.out, "--out")
    # Without a parameters file the bag carries the publishing nodes' own parameters
    # (from their parameter services), never defaults they may not have run with.
    params = load_params(args.params_file) if args.params_file else None
    counts = record(args.topics, args.out, params, args.duration, args.discovery_timeout)
    print(f"{args.out}: " + ", ".join(f"{n} on {topic}" for topic, n in counts.items()))
    return 0


def _play(args: argparse.Namespace) -> int:
    from rheo_ros.nodes.player import play

    counts = play(args.bag, args.rate, args.clock, args.loop, args.topics, args.wait_for_subscribers,
                  args.discovery_timeout, warn=lambda line: print(f"rheo play: warning: {line}", file=sys.stderr))
    print(f"{args.bag}: played " + ", ".join(f"{n} on {topic}" for topic, n in counts.items()))
    return 0


def _bag_repair(args: argparse.Namespace) -> int:
    from rheo_ros.config.setup import check_params, load_params
    from rheo_ros.io.bag import repair_bag

    params = check_params(load_params(args.params_file), args.params_file) if args.params_file else None
    repaired = repair_bag(args.bag, params)
    print(f"{args.bag}: rebuilt with " + ", ".join(f"{n} on {topic}" for topic, n in repaired.counts.items())
          + f" (the original kept as {' and '.join(p.name for p in repaired.kept)} beside it)")
    if repaired.spans:
        lost = ", ".join(f"{n} on {topic}" for topic, n in repaired.lost.items() if n) or "a count the file lacks"
        spans = ", ".join(f"{a:.3f}-{b:.3f} s" for a, b in repaired.spans)
        print(f"{args.bag}: lost {lost}: {len(repaired.spans)} chunk(s) that did not read, logged {spans}")
    return 0


NODES = ("stage", "simulator", "segmenter", "estimator")


def _run(args: argparse.Namespace) -> int:
    """``ros2 run rheo_ros NODE ...`` where there is no ros2 CLI: the same entry point,
    in this process, with the remaining arguments (``--ros-args ...``)."""
    module = importlib.import_module(f"rheo_ros.nodes.{args.node}")
    sys.argv = [args.node, *args.args]
    module.main()
    return 0


class ProgressBar:
    """rich's progress bar on stderr on a terminal (the diagnosis's candidates done, the
    elapsed time, the step); elsewhere (a log, CI) a line per step with the elapsed time."""

    def __init__(self, label: str = "rheo analyze") -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.label = label
        self.console = Console(stderr=True)
        self._progress = Progress(TextColumn(label), BarColumn(), TimeElapsedColumn(),
                                  TextColumn("{task.description}"), console=self.console)
        self._task = self._progress.add_task("", total=None)
        if self.console.is_terminal:
            self._progress.start()

    def __call__(self, step: str) -> None:
        import re

        done = re.search(r"\((\d+)/(\d+)\)", step)
        if done:   # "trying ... (k/n)": the k-th of n candidates under way; "tried ... (k/n)": k done
            self.count(int(done[1]) - (not step.startswith("tried")), int(done[2]), step)
        else:
            self._progress.update(self._task, description=step)
            self._log(step)

    def count(self, done: int, total: int, step: str) -> None:
        """``done`` of ``total`` finished, ``step`` the latest."""
        self._progress.update(self._task, description=step, completed=done, total=total)
        self._log(step)

    def _log(self, step: str) -> None:
        if not self.console.is_terminal:
            elapsed = self._progress.tasks[0].elapsed or 0.0
            print(f"{self.label}: {elapsed:5.1f} s  {step}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.console.is_terminal:
            self._progress.stop()


def _analyze(args: argparse.Namespace) -> int:
    from rheo_ros.app.analyze import analyze, write_outputs
    from rheo_ros.app.batch import bags_below, find_bags, is_bag

    if len(args.bag) > 1 or (not is_bag(Path(args.bag[0])) and bags_below(Path(args.bag[0]))):
        return _analyze_batch(args, find_bags(args.bag))
    if args.scheduler or args.workers or args.table:
        raise ValueError("--scheduler, --workers and --table are for several bags (a list or a directory of them)")
    writable(args.json, "--json")
    writable(args.report, "--report", folder=True)
    bar = None if args.quiet else ProgressBar()
    try:
        result = analyze(args.bag[0], effects=args.add or (), params_file=args.params_file,
                         discover_effects=not args.no_discover, progress=bar)
    finally:
        if bar:
            bar.close()
    report = result.to_json()
    for warning in report["warnings"]:
        print(f"rheo analyze: warning: {warning}", file=sys.stderr)
    path = write_outputs(result, args.json, args.report, report)
    print(format_analysis(report))
    if path:
        print(f"report: {path}")
    return 0


def _analyze_batch(args: argparse.Namespace, bags: list[Path]) -> int:
    """``rheo analyze`` over several bags on Dask (``app.batch``): a JSON per bag in the
    ``--json`` folder, a report per bag in the ``--report`` folder, the table at ``--table``;
    a line per bag. Exit 2 when a bag failed (its row says why), after writing the rest."""
    from rheo_ros.app.batch import batch_jobs, run_batch, write_table
    from rheo_ros.models.effects import effect_class

    for effect in args.add or ():
        effect_class(*effect.split(":", 1))  # an unknown id fails before any cluster starts
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers {args.workers}: at least 1")
    table = Path(args.table or "rheo-analysis.parquet")
    writable(args.json, "--json", folder=True)      # several bags: a folder, a JSON per bag
    writable(args.report, "--report", folder=True)
    writable(str(table.parent), "--table", folder=True)
    for folder in (args.json, args.report, table.parent):
        if folder:
            Path(folder).mkdir(parents=True, exist_ok=True)
    writable(str(table), "--table")
    jobs = list(batch_jobs(bags, args.params_file, args.add or (), not args.no_discover, args.json, args.report))
    bar = None if args.quiet else ProgressBar(f"rheo analyze ({len(jobs)} bags)")
    try:
        rows = run_batch(jobs, args.scheduler, args.workers,
                         progress=bar and (lambda done, total, bag: bar.count(done, total, f"{Path(bag).name} done")))
    finally:
        if bar:
            bar.close()
    table = write_table(rows, table)
    failed = 0
    for job in jobs:
        mine = [r for r in rows if r["bag"] == job.bag]
        if mine[0]["error"]:
            failed += 1
            print(f"{job.bag}: error: {mine[0]['error']}")
            continue
        final = next((r for r in mine if r["push"] == 0 and r["final"]), mine[-1])
        print(f"{job.bag}: {final['verdict']}; {final['model']}: E {final['E']:.4g} Pa, c1 {final['c1']:.4g} Pa s, "
              f"c2 {final['c2']:.4g} Pa s, gamma {final['gamma']:.3g}")
    print(f"{len(jobs)} bags: {len(jobs) - failed} analysed, {failed} failed; table: {table}"
          + (f"; JSON in {args.json}" if args.json else "") + (f"; reports in {args.report}" if args.report else ""))
    return 2 if failed else 0


def format_analysis(report: dict[str, Any]) -> str:
    """The analysis as a person reads it in a terminal: the models side by side, the verdict."""
    est = report["estimate"]
    lines = [f"{report['bag']}: " + ", ".join(f"{p['name']} {p['t_start']:.2f}-{p['t_end']:.2f} s"
                                             for p in report["phases"])]
    open_ = est.get("undetermined", {})
    lines.append("closed form (" + est["method"] + "): " + ", ".join(
        f"{k} not determined ({open_[k]})" if k in open_ else f"{k} {_number(est[k])}"
        for k in ("E", "c1", "c2", "gamma")))
    lines.append(f"{'model':<52} {'RMS force (N)':>13} {'pull':>9} {'keep':>9} {'release':>9} {'BIC':>12}")
    for m in report["models"]:
        ph = m["rmse_by_phase"]
        lines.append(f"{m['name']:<52} {m['rmse_force']:>13.4g} " + " ".join(
            f"{ph.get(p, float('nan')):>9.3g}" for p in ("pull", "keep", "release")) + f" {m['bic']:>12.6g}")
    final = report["models"][-1]
    bound = set(final.get("at_bound", ()))
    lines.append(f"{final['name']}: " + ", ".join(
        f"{k} {_number(v)}" + (" (at bound)" if k in bound else f" +- {final['std'][k]:.2g}"
                               if final["std"].get(k) is not None else " (not determined)")
        for k, v in final["params"].items()))
    lines.append(report["diagnosis"]["evidence"])
    rest = report["diagnosis"].get("remaining")
    if rest:
        from rheo_ros.diagnosis.remaining import describe

        lines.append(describe(rest))
    return "\n".join(lines)


def _number(value: float | None) -> str:
    """A value of the report (null: no data determine it)."""
    return "none" if value is None else f"{value:.4g}"


def _demo(args: argparse.Namespace) -> int:
    from rheo_ros.app.demo import run_demo

    effects = None if args.effect is None else [e for e in args.effect if e != "none"]
    return run_demo(args.params_file, args.timeout, effects, report=args.report)


def positive(text: str) -> float:
    """An argparse type: a finite number above zero."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number above 0")
    return value


def passes(text: str) -> int:
    """An argparse type: a whole number of passes, at least one."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} must be at least 1")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rheo", description="Identify rheological parameters (E, c1, c2, Poisson ratio).")
    sub = parser.add_subparsers(dest="command", required=True)
    bench = sub.add_parser("bench", help="benchmarks").add_subparsers(dest="bench", required=True)

    def bench_command(name: str, text: str, **options: tuple) -> None:
        """``rheo bench NAME``: its options (type, default, help and, for an option given or
        not, its metavar (default PATH); ``bool``: a flag, ``str`` with default None: a path
        given or not), ``--json``, run by ``_bench``, which
        passes each option to the bench's ``run`` under its name (``-`` as ``_``)."""
        b = bench.add_parser(name, help=text)
        for option, (kind, default, what, *shape) in options.items():
            flag = f"--{option.replace('_', '-')}"
            if kind is bool:
                b.add_argument(flag, dest=option, action="store_true", help=what)
            elif default is None:
                b.add_argument(flag, dest=option, type=kind, metavar=shape[0] if shape else "PATH" if kind is str else None,
                               help=what)
            else:
                shown = default if isinstance(default, str) else f"{default:g}"
                b.add_argument(flag, dest=option, type=kind, default=default, help=f"{what} (default {shown})")
        b.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
        b.set_defaults(func=_bench, bench_options=tuple(options))

    seed = (int, 0, "random seed")
    bench_command("paper", "reproduce the paper's Tables II-IV with the project's FE model")
    bench_command("noise", "bias, std and Cramer-Rao bound under measurement noise",
                  replicates=(int, 200, "noisy replicates"), seed=seed)
    bench_command("online", "estimator node over DDS: latency per phase, idle CPU, memory over many experiments",
                  experiments=(int, 100, "experiments replayed"), rate=(float, 10.0, "replay speed, x real time"),
                  closed_form_priority=(int, 0, "the estimator's estimator.closed_form_priority (SCHED_FIFO 1-99 of "
                                                "its closed-form worker; 0: normal scheduling)"))
    bench_command("calibration", "reported std against the error over noise seeds through the sensor path",
                  replicates=(int, 100, "noise seeds per case"), seed=(int, 0, "first seed"))
    bench_command("diagnosis", "exact-set accuracy of the model-discovery loop over generated bags hiding 0, 1 or 2 "
                               "effects, detection thresholds per effect and form, false claims on clean bags",
                  replicates=(int, 100, "bags generated"), seed=seed,
                  quick=(bool, False, "short records (keep 15-18 s, release 20-24 s)"),
                  noise_scale=(float, 1.0, "every noise times this (1: the source's default, 2: twice it)"),
                  generator=(str, None, "a Python file defining bench_bag(rng, index, out_dir, noise_scale, quick) "
                                        "(e.g. test/generator.py; default: the package's simulator)"),
                  plot=(str, None, "also plot exact-set accuracy against effect size into this PNG or SVG file"),
                  outside=(bool, False, "each bag hides an effect in no catalogue instead (needs --generator): "
                                        "how often a wrong effect is named"),
                  merge=(str, None, "comma-separated --json files of earlier runs of one bench (each its own "
                                    "seed) to score as one instead: a long bench made in parts"),
                  limit=(str, None, "FAMILY:LO:HI: every bag hides one effect of FAMILY scaled to a readable size "
                                    "log-uniform in [LO, HI] x the total-force noise (the threshold measured "
                                    "where random draws leave a gap)", "FAMILY:LO:HI"))
    bench_command("mesh", "identification error against the FE mesh's refinement (data from a finer mesh)")
    bench_command("simulator", "simulator speed as a multiple of real time (bag written directly)")
    bench_command("scaling", "rheo analyze's time and peak memory (all processes) against the record's length and "
                             "the tactile rate",
                  lengths=(str, "170,600", "record lengths in s, comma-separated (the issue's: 170,600,3000)"),
                  rates=(str, "50", "tactile rates in Hz, comma-separated (50,500)"), seed=(int, 1, "noise seed"))
    bench_command("peers", "the whole-record fit against scipy least_squares and lmfit over solve_ivp, and the second "
                           "relaxation against pyvisco (the peers installed by the bench, pinned, into "
                           "~/.cache/rheo_ros/peers)",
                  lengths=(str, "170,600", "record lengths in s, comma-separated (with the default rates also 170 s "
                                           "at 500 Hz; the issue's: 170,600,3000, longer)"),
                  rates=(str, "50", "tactile rates in Hz, comma-separated (50,500)"), seed=(int, 1, "noise seed"),
                  no_relaxation=(bool, False, "leave out the second-relaxation record (pyvisco)"),
                  no_install=(bool, False, "install nothing: the peers already in the cache folder only"),
                  out=(str, None, "also write the table into this file"))
    s = sub.add_parser("simulate", help="simulate a run and write it as a rosbag2 MCAP bag (no DDS)")
    s.add_argument("--effect", action="append", metavar="ID",
                   help="hidden effect to add (repeatable): relaxation_branch, adhesion, strain_stiffening, "
                        "sensor_drift; overrides simulator.effects")
    s.add_argument("--seed", type=int, help="noise seed (default: simulator.seed)")
    s.add_argument("--params-file", metavar="FILE", help="ROS 2 parameters file (default: config/rheo_ros.yaml values)")
    s.add_argument("--out", required=True, metavar="DIR", help="bag directory to create")
    s.set_defaults(func=_simulate)
    r = sub.add_parser("record", help="record live topics from DDS into a rosbag2 MCAP bag (Ctrl-C to stop)")
    r.add_argument("topics", nargs="+", metavar="TOPIC")
    r.add_argument("--out", required=True, metavar="DIR", help="bag directory to create")
    r.add_argument("--params-file", metavar="FILE",
                   help="parameters file stored in the bag's metadata (default: the publishing nodes' parameters)")
    r.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    r.add_argument("--discovery-timeout", type=float, default=10.0, metavar="S",
                   help="give up if a topic has no publisher after S seconds (default 10)")
    r.set_defaults(func=_record)
    bag = sub.add_parser("bag", help="bag tools").add_subparsers(dest="bag_command", required=True)
    rp = bag.add_parser("repair", help="rebuild a recording whose writer was killed (no metadata.yaml), or a bag "
                                       "with a corrupt chunk, from what of its MCAP reads (the original kept "
                                       "beside it); says what was lost")
    rp.add_argument("bag", metavar="DIR")
    rp.add_argument("--params-file", metavar="FILE",
                    help="parameters to store (default: the recorder's recording.params.yaml, if any)")
    rp.set_defaults(func=_bag_repair)
    pl = sub.add_parser("play", help="publish a bag's topics over DDS (recorded timing, or as fast as taken with --clock)")
    pl.add_argument("bag", metavar="BAG", help="rosbag2 directory")
    pl.add_argument("--rate", type=positive, default=1.0, help="speed factor on the recorded timing (default 1)")
    pl.add_argument("--clock", action="store_true",
                    help="drive /clock and go as fast as the subscribers take the messages")
    pl.add_argument("--loop", type=passes, default=1, metavar="N", help="play N times (N >= 1), stamps shifted each pass")
    pl.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics")
    pl.add_argument("--wait-for-subscribers", type=int, default=0, metavar="N",
                    help="start once every topic has N subscribers (default 0: at once)")
    pl.add_argument("--discovery-timeout", type=float, default=10.0, metavar="S",
                    help="give up waiting for subscribers after S seconds (default 10)")
    pl.set_defaults(func=_play)
    rn = sub.add_parser("run", help="start a node (as 'ros2 run rheo_ros NODE' does), e.g. rheo run estimator "
                                    "--ros-args --params-file config/rheo_ros.yaml")
    rn.add_argument("node", choices=NODES)
    rn.add_argument("args", nargs=argparse.REMAINDER, help="node arguments (--ros-args ...)")
    rn.set_defaults(func=_run)
    an = sub.add_parser("analyze", help="identify, compare model and measurement, diagnose the missing effect, "
                                        "add it and refit: the models side by side, JSON and an HTML report")
    an.add_argument("bag", metavar="BAG", nargs="+",
                    help="rosbag2 directory; several, or a directory of them, run as a batch on Dask")
    an.add_argument("--params-file", metavar="FILE", help="parameters file overriding the bag's own")
    an.add_argument("--json", metavar="FILE",
                    help="write the contract's JSON report (several bags: a folder, a JSON per bag)")
    an.add_argument("--report", metavar="DIR", help="write an HTML report (one self-contained file) into DIR "
                                                   "(several bags: a folder per bag in DIR)")
    an.add_argument("--table", metavar="FILE", help="several bags: the Parquet table, a row per bag, push and "
                                                   "model (default: rheo-analysis.parquet)")
    an.add_argument("--scheduler", metavar="ADDRESS",
                    help="several bags: the Dask scheduler to run them on (default: a local cluster)")
    an.add_argument("--workers", type=int, metavar="N",
                    help="several bags: the local cluster's worker processes (default: one per core, at most 4)")
    an.add_argument("--add", action="append", metavar="EFFECT",
                    help="effect to add to the base model (repeatable, in order): relaxation_branch, adhesion, "
                         "strain_stiffening, sensor_drift, or one you registered")
    an.add_argument("--no-discover", action="store_true", help="fit the base and --add models only, no diagnosis")
    an.add_argument("--quiet", action="store_true", help="no progress bar")
    an.set_defaults(func=_analyze)
    dm = sub.add_parser("demo", help="stage, simulator, segmenter and estimator as separate processes over DDS: "
                                     "each estimate as it arrives, the final one beside the true parameters")
    dm.add_argument("--params-file", metavar="FILE", help="parameters file (default: config/rheo_ros.yaml values)")
    dm.add_argument("--timeout", type=float, default=600.0, metavar="S", help="give up after S seconds (default 600)")
    dm.add_argument("--effect", action="append", metavar="ID",
                    help="effect hidden in the simulator, not told to the estimator (repeatable; default: the "
                         "parameters file's, else relaxation_branch; 'none': a clean run)")
    dm.add_argument("--report", action=argparse.BooleanOptionalAction, default=True,
                    help="record the run and write the HTML report of rheo analyze on it (default: on)")
    dm.set_defaults(func=_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    single_threaded_blas()
    try:
        return args.func(args)
    except BAD_INPUT as exc:
        print(f"rheo: error: {error_line(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
