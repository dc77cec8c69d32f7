"""``rheo``: the command line (also ``python -m rheo_ros``)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rheo_ros.record import RecordError


def _write_json(path: str | None, data: dict[str, Any]) -> None:
    if path:
        Path(path).write_text(json.dumps(data, indent=2, default=float) + "\n")


def _bench_paper(args: argparse.Namespace) -> int:
    from rheo_ros.bench import paper

    result = paper.run()
    print(paper.format_table(result))
    _write_json(args.json, result)
    return 0


def _bench_noise(args: argparse.Namespace) -> int:
    from rheo_ros.bench import noise

    result = noise.run(replicates=args.replicates, seed=args.seed)
    print(noise.format_table(result))
    _write_json(args.json, result)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rheo", description="Identify rheological parameters (E, c1, c2, Poisson ratio).")
    sub = parser.add_subparsers(dest="command", required=True)
    bench = sub.add_parser("bench", help="benchmarks").add_subparsers(dest="bench", required=True)
    p = bench.add_parser("paper", help="reproduce the paper's Tables II-IV with the project's FE model")
    p.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    p.set_defaults(func=_bench_paper)
    n = bench.add_parser("noise", help="bias, std and Cramer-Rao bound under measurement noise")
    n.add_argument("--replicates", type=int, default=200, help="noisy replicates (default 200)")
    n.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    n.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    n.set_defaults(func=_bench_noise)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (RecordError, OSError) as exc:
        print(f"rheo: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
