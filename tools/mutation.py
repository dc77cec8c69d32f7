"""Mutation testing as a benchmark (``./tasks mutation``): run mutmut 3 over the modules
``setup.cfg [mutmut] only_mutate`` names, with the fast unit tests it selects, then print
killed / survived / timeout / no tests / total and the score per module, and write it all,
with every surviving mutant (and why it is equivalent, where it is), to
docs/bench/mutation.txt.

    python tools/mutation.py [--max-children N] [--no-run] [--out FILE]

The score is (killed + timeout) / (total - not run): a mutant no test reaches ("no tests")
counts as surviving; "not run" are mutants an interrupted run did not reach. mutmut's results live in mutants/ (ignored by git); a rerun retests only the
mutants whose function changed (delete mutants/ for a clean run).
"""

from __future__ import annotations

import argparse
import configparser
import json
import os
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Surviving mutants judged equivalent (no test can tell them from the original), with why.
# Keys are mutmut's mutant names.
_MSGDEF = "rheo_ros.io.bag.x_message_definitions__mutmut_"
_FIT = "rheo_ros.identification.fit."
_PL = "rheo_ros.identification.pipeline."
_CF = "rheo_ros.identification.closed_form.x_"
EQUIVALENT: dict[str, str] = {
    # bag.message_definitions: rosbags names a used type "pkg/Name" on its "MSG: " line (no "/msg/",
    # one "/"), and generates the same text for any ros_version but 1.
    **{f"{_MSGDEF}{n}": "equivalent: rosbags' MSG: lines are 'pkg/Name' (one '/', no '/msg/'): the "
                        "'/msg/' test, the replace count and the split count change nothing" for n in
       (28, 31, 38, 40, 41, 48, 52)},
    **{f"{_MSGDEF}{n}": "equivalent: rosbags' generate_msgdef treats every ros_version but 1 as ROS 2"
       for n in (9, 12)},
    "rheo_ros.identification.pipeline.x_undetermined__mutmut_30":
        "equivalent: '2 / rate <= 1e5' differs from '< 1e5' only where 2 / rate is exactly 1e5 in floating "
        "point, which no E / (c1 + c2) of round numbers gives (2 / (1 / 5e4) = 99999.99999999999)",
    # identification.fit
    **{f"{_FIT}x_fit_record__mutmut_{n}": "equivalent: a loose parameter's variance is already inf; what is "
                                            "added to it (0, 1 or its zero shift) leaves it inf" for n in (198, 204)},
    f"{_FIT}x__discretisation_std__mutmut_19": "equivalent: both Gauss-Newton shifts change sign inside abs()",
    **{f"{_FIT}x__discretisation_std__mutmut_{n}": "equivalent: rcond=None is numpy's default (numpy >= 2)"
       for n in (24, 60)},
    f"{_FIT}x__discretisation_std__mutmut_26": "equivalent at a converged fit: the residuals there are orthogonal "
                                                 "to J's columns (normal equations), so lstsq(J, r1 + r0) = "
                                                 "lstsq(J, r1 - r0) to the solver's tolerance",
    **{f"{_FIT}x__discretisation_std__mutmut_{n}": "equivalent: a Record has >= 2 marker frames of >= 4 "
                                                    "markers, so the markers' move is never empty" for n in (91, 97)},
    f"{_FIT}x__reweighted__mutmut_53": "equivalent: '<=' and '<' differ only where a relative weight change is "
                                       "exactly 0.02 in floating point",
    f"{_FIT}x__covariance__mutmut_10": "equivalent: '<=' and '<' differ only where a column norm is exactly "
                                       "1e-12 of the largest in floating point",
    **{f"{_FIT}x__statistics__mutmut_{n}": "equivalent: np.errstate(invalid=...) only silences a 0/0 warning; "
                                            "the ratio is the same NaN" for n in (40, 42)},
    **{f"{_FIT}x_cramer_rao_std__mutmut_{n}": "equivalent: the parameters are floats; np.array infers float64"
       for n in (4, 6)},
    **{f"{_FIT}x_cramer_rao_std__mutmut_{n}": "equivalent: numpy reads any negative reshape size as the one "
                                               "inferred" for n in (31, 53)},
    f"{_FIT}x_cramer_rao_std__mutmut_39": "equivalent: stepping p - scale dx negates J; J^T J is unchanged",
    f"{_FIT}x_cramer_rao_std__mutmut_50": "equivalent: each column is 1-D, so stacking on axis 1 is stacking on -1",
    f"{_FIT}x_cramer_rao_std__mutmut_18": "equivalent: the scale cancels in inv(J^T J) * outer(scale, scale) (J "
                                          "is taken in units of it); only the difference steps change, and the "
                                          "adaptive differences agree to 1e-5",
    **{f"{_FIT}xǁParameterMapǁ__init____mutmut_{n}": "equivalent: p0 only enters float arithmetic (exp, logit, "
                                                      "division), so an int array gives the same values"
       for n in (4, 6)},
    f"{_FIT}xǁParameterMapǁvalues__mutmut_30": "equivalent: the where() only guards exp() for the entries "
                                               "np.select takes from the other branches",
    f"{_FIT}xǁWholeRecordProblemǁ__post_init____mutmut_31": "equivalent: each marker's start is profiled out "
                                                            "(residuals and group_rms subtract its mean over the "
                                                            "frames), so + nodes and - nodes cancel",
    # identification.pipeline
    **{f"{_PL}x_fit_from_starts__mutmut_{n}": "equivalent: fit_record reads only the start's params, never its "
                                              "method or equations" for n in (22, 23, 28, 29, 49, 50, 54, 55)},
    **{f"{_PL}x_fit_from_starts__mutmut_{n}": "equivalent: discretisation=True is fit_record's default"
       for n in (41, 99)},
    # identification.closed_form
    **{f"{_CF}{n}": "equivalent: rcond=None is numpy's default (numpy >= 2)"
       for n in ("_displacement_gradient__mutmut_13", "recovered_displacement__mutmut_22")},
    f"{_CF}recovered_displacement__mutmut_28": "equivalent: numpy reads any negative reshape size as the one inferred",
    f"{_CF}_line_fit__mutmut_5": "equivalent: dx sums to zero, so dx @ (y + y_mean) = dx @ (y - y_mean) up to "
                                 "rounding (2 y_mean dx.sum() ~ 1e-16 of it)",
    f"{_CF}_without_baseline__mutmut_4": "equivalent: zero_force_baseline's note is empty exactly when its "
                                         "baseline is zero: subtracting it leaves the force",
    f"{_CF}lateral_strain_ratio__mutmut_20": "equivalent: float('NAN') is the same NaN",
    f"{_CF}from_final_displacement__mutmut_40": "equivalent: '<=' and '<' differ only where the keep relaxed to "
                                                "exactly 0.01 of its start in floating point",
    f"{_CF}from_final_displacement__mutmut_155": "equivalent: '>=' and '>' differ only where the follow time is "
                                                 "exactly half a sample in floating point",
    f"{_CF}zero_force_baseline__mutmut_19": "equivalent: a zero-force sample at or after the pull's start lies after "
                                            "t_retracted + 0.5 s, so '>' and '>=' t_pull_start agree",
    f"{_CF}solve_node_equations__mutmut_110": "equivalent: on the block's uniform field g(gamma') is proportional to "
                                              "(1 - gamma gamma') / (1 - gamma'^2) > 0, so the sign test at 0.3 "
                                              "is the block gamma's; g0 otherwise only starts the (unique) search",
    **{f"{_CF}from_final_displacement__mutmut_{n}": "equivalent: solve_node_equations returns only c2 > eta > 0 "
                                                     "finite and r = exp() > 0, so c1/E = c1 / (r (c1 + c2)) is "
                                                     "finite and positive (short of eta c2 overflowing 1e308): the "
                                                     "branch is never taken" for n in (82, 84, 86)},
    "rheo_ros.online.segmenter.xǁPhaseSegmenterǁclose_release__mutmut_1":
        "equivalent: state 'release' and a pending release are set together (_stage_keep) and cleared "
        "together (_end_release), so 'or' and 'and' agree",
}

KILLED = {1, 3}          # mutmut: test failure, pytest internal error
TIMEOUT = {36, 24, -24, 152, 255}
SURVIVED = {0}
NO_TESTS = {5, 33}


def modules() -> list[str]:
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    return [m for m in cfg.get("mutmut", "only_mutate").split("\n") if m.strip()]


def tally(module: str) -> tuple[dict[str, int], list[str]]:
    meta = ROOT / "mutants" / (module + ".meta")
    counts = {"killed": 0, "survived": 0, "timeout": 0, "no tests": 0, "other": 0}
    alive: list[str] = []
    if not meta.exists():
        return counts, alive
    codes = json.loads(meta.read_text())["exit_code_by_key"]
    for name, code in sorted(codes.items()):
        if code in KILLED:
            counts["killed"] += 1
        elif code in TIMEOUT:
            counts["timeout"] += 1
        elif code in SURVIVED:
            counts["survived"] += 1
            alive.append(name)
        elif code in NO_TESTS:
            counts["no tests"] += 1
            alive.append(name)
        else:   # not checked, segfault, suspicious, skipped
            counts["other"] += 1
    return counts, alive


def show(name: str) -> str:
    """The mutant's diff, its changed lines only."""
    out = subprocess.run([str(ROOT / ".venv/bin/mutmut"), "show", name], cwd=ROOT, capture_output=True, text=True)
    lines = [ln for ln in out.stdout.splitlines() if ln[:1] in "+-" and not ln.startswith(("+++", "---"))]
    return " | ".join(ln.strip() for ln in lines)[:300]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-children", type=int, default=2)
    ap.add_argument("--no-run", action="store_true", help="report the results mutants/ holds")
    ap.add_argument("--out", default=str(ROOT / "docs/bench/mutation.txt"))
    args = ap.parse_args()
    wall = None
    if not args.no_run:
        start = time.monotonic()
        run = subprocess.run([str(ROOT / ".venv/bin/mutmut"), "run", "--max-children", str(args.max_children)],
                             cwd=ROOT, stdout=subprocess.DEVNULL)
        wall = time.monotonic() - start
        if run.returncode != 0:
            print(f"mutation: mutmut run failed (exit {run.returncode})", file=sys.stderr)
            return run.returncode
    rows, survivors = [], []
    totals = dict.fromkeys(("killed", "survived", "timeout", "no tests", "other"), 0)
    for module in modules():
        counts, alive = tally(module)
        total = sum(counts.values())
        for k in totals:
            totals[k] += counts[k]
        rows.append((module, counts, total))
        survivors += [(module, name) for name in alive]
    rows.append(("all", totals, sum(totals.values())))
    head = (f"{'module':42} {'killed':>7} {'survived':>8} {'timeout':>7} {'no tests':>8} {'not run':>7} "
            f"{'total':>6} {'score':>7}")
    table = [head, "-" * len(head)]
    for module, c, total in rows:
        run = total - c["other"]      # "not run": not checked yet (an interrupted run), or suspicious
        score = 100.0 * (c["killed"] + c["timeout"]) / run if run else float("nan")
        table.append(f"{module:42} {c['killed']:7d} {c['survived']:8d} {c['timeout']:7d} {c['no tests']:8d} "
                     f"{c['other']:7d} {total:6d} {score:6.1f}%")
    print("\n".join(table))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    lines = [
        "Mutation testing (./tasks mutation: mutmut 3.8.1, tools/mutation.py, config in setup.cfg [mutmut])",
        f"date {date.today().isoformat()}, commit {commit} (+ the working tree), "
        f"wall time {'%.0f s' % wall if wall is not None else 'not measured (--no-run)'}, "
        f"--max-children {args.max_children}, on a shared 2-core machine ({os.cpu_count()} CPUs seen)",
        "Tests: test/test_decision_rule.py, test_identification_units.py, test_fit_units.py, "
        "test_pipeline_units.py, test_segmenter_units.py, test_bag_reader_units.py (mutmut runs, per mutant, "
        "those of them that reach its function).",
        "Score = (killed + timeout) / (total - not run); a mutant no test reaches counts against it.",
        "",
        *table,
        "",
        "Surviving mutants judged equivalent (with why):",
    ]
    judged = [(m, n) for m, n in survivors if n in EQUIVALENT]
    for module, name in judged:
        lines.append(f"  {name}: {EQUIVALENT[name]}")
        lines.append(f"      {show(name)}")
    if not judged:
        lines.append("  none")
    # Open survivors by function (their diffs: `mutmut show NAME`, or `mutmut browse`): a
    # list per mutant would run to hundreds of lines while most are still to be judged.
    open_by_function: dict[str, int] = {}
    for _, name in survivors:
        if name not in EQUIVALENT:
            function = name.rsplit("__mutmut_", 1)[0]
            open_by_function[function] = open_by_function.get(function, 0) + 1
    lines += ["", f"Open survivors (not yet judged or killed), by function: {sum(open_by_function.values())}"]
    lines += [f"  {count:4d}  {function}" for function, count in
              sorted(open_by_function.items(), key=lambda kv: (-kv[1], kv[0]))]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"mutation: written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
