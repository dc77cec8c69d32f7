"""``rheo``: the command line (also ``python -m rheo_ros``)."""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rheo_ros.params import ParamsError
from rheo_ros.record import RecordError


def _write_json(path: str | None, data: dict[str, Any]) -> None:
    if path:
        Path(path).write_text(json.dumps(data, indent=2, default=float) + "\n")


def _bench(args: argparse.Namespace) -> int:
    """Run ``rheo_ros.bench.<name>``: its ``run(**options)`` figures, printed and as JSON."""
    module = importlib.import_module(f"rheo_ros.bench.{args.bench}")
    options = {k: getattr(args, k) for k in ("replicates", "seed") if hasattr(args, k)}
    result = module.run(**options)
    print(module.format_table(result))
    _write_json(args.json, result)
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from rheo_ros.io.bag import simulate_to_bag
    from rheo_ros.models.effects import effect_class
    from rheo_ros.params import Setup, check_params, load_params

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
    counts = simulate_to_bag(Setup(params), params["simulator.seed"], args.out)
    print(f"{args.out}: " + ", ".join(f"{n} on {topic}" for topic, n in counts.items()))
    return 0


def _record(args: argparse.Namespace) -> int:
    from rheo_ros.nodes.recorder import record
    from rheo_ros.params import load_params

    if Path(args.out).exists():
        raise OSError(f"{args.out} exists already, not overwriting")
    # Without a parameters file the bag carries none: reading it then asks for one,
    # rather than trusting defaults the nodes may not have run with.
    params = load_params(args.params_file) if args.params_file else None
    counts = record(args.topics, args.out, params, args.duration, args.discovery_timeout)
    print(f"{args.out}: " + ", ".join(f"{n} on {topic}" for topic, n in counts.items()))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rheo", description="Identify rheological parameters (E, c1, c2, Poisson ratio).")
    sub = parser.add_subparsers(dest="command", required=True)
    bench = sub.add_parser("bench", help="benchmarks").add_subparsers(dest="bench", required=True)
    p = bench.add_parser("paper", help="reproduce the paper's Tables II-IV with the project's FE model")
    p.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    p.set_defaults(func=_bench)
    n = bench.add_parser("noise", help="bias, std and Cramer-Rao bound under measurement noise")
    n.add_argument("--replicates", type=int, default=200, help="noisy replicates (default 200)")
    n.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    n.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    n.set_defaults(func=_bench)
    b = bench.add_parser("simulator", help="simulator speed as a multiple of real time (bag written directly)")
    b.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    b.set_defaults(func=_bench)
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
    r.add_argument("--params-file", metavar="FILE", help="parameters file stored in the bag's metadata")
    r.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    r.add_argument("--discovery-timeout", type=float, default=10.0, metavar="S",
                   help="give up if a topic has no publisher after S seconds (default 10)")
    r.set_defaults(func=_record)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (RecordError, ParamsError, KeyError, OSError) as exc:
        text = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        print(f"rheo: error: {' '.join(str(text).split())}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
