"""The HTML report of ``rheo analyze``: one self-contained file that renders in a real
browser (headless Chromium, Debian's ``chromium``, which ``./tasks test`` installs), and
shows what the JSON says.

One analysis (a bag with a hidden relaxation branch, so that the base model misfits
and its force figure has shaded misfit windows) gives both the report and the JSON
(``Analysis.to_json``, serialised as ``rheo analyze --json`` writes it). Chromium loads
the report and dumps its DOM; the tests read from that DOM the verdict, every number of
the parameter tables and the SVG geometry of each shaded misfit window, and compare
them with the JSON (and, for the windows, which the JSON names only in its evidence
text, with the same ``Analysis`` object the JSON came from).
"""

from __future__ import annotations

import json
import math
import re
import subprocess
from collections.abc import Iterator
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rheo_ros.app.analyze import analyze
from rheo_ros.diagnosis.analysis import Analysis
from rheo_ros.identification.estimate import BASE_PARAMETERS
from rheo_ros.reports.html import write_report

CHROMIUM = Path("/usr/bin/chromium")
BAG = Path(__file__).resolve().parents[1] / "bags" / "effect_relaxation_branch"
# Chromium logs every console message (log, warn, error, uncaught exceptions alike) to
# stderr as ``[pid:tid:stamp:INFO:CONSOLE:line] "text", source: url (line)``.
CONSOLE_LINE = re.compile(r":CONSOLE[:\]]")
EXTERNAL_REFERENCE = re.compile(r"""\b(?:src|href)\s*=\s*["']?\s*(?:https?:)?//""", re.I)
# Significant digits the report prints: a model's values, their std, the closed form's
# std, the BIC, the RMS error. A printed number may differ from the JSON's by half a
# unit in its last digit (the rounding), no more.
VALUE_DIGITS, MODEL_STD_DIGITS, CLOSED_FORM_STD_DIGITS, BIC_DIGITS, RMSE_DIGITS = 4, 3, 2, 6, 3
# The evidence text prints window bounds to 0.1 s.
EVIDENCE_ROUNDING = 0.05


def expected_figures(result: Analysis) -> int:
    """The stage, the error bars, one force figure per model, the marker mesh."""
    return 3 + len(result.models)


def chromium(page: Path, profile: Path, *action: str) -> subprocess.CompletedProcess[str]:
    """Run headless Chromium on ``page`` with ``action`` (``--dump-dom``, ``--screenshot=...``)."""
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: install Debian's package chromium "
                    "(./tasks test does: apt-get install chromium)")
    command = [
        str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0", "--virtual-time-budget=5000",
        *action, page.resolve().as_uri(),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"chromium exited {done.returncode}:\n{done.stderr[-3000:]}"
    return done


def console_messages(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if CONSOLE_LINE.search(line)]


# -- the DOM Chromium dumps, as a tree ------------------------------------------------

class Comment(str):
    """A comment in the DOM (matplotlib writes each text it draws as paths in one)."""


class Node:
    """An element: tag, attributes, children (elements, text, comments)."""

    def __init__(self, tag: str, attrs: dict[str, str]) -> None:
        self.tag, self.attrs = tag, attrs
        self.children: list[Node | str] = []

    def iter(self) -> Iterator[Node]:
        """This element and every element under it, in document order."""
        yield self
        for child in self.children:
            if isinstance(child, Node):
                yield from child.iter()

    def find_all(self, tag: str | None = None, **attrs: str) -> list[Node]:
        """Elements under (or at) this one with ``tag`` and every attribute in ``attrs``
        (``data_value`` for ``data-value``, ``class_`` for a class among ``class``)."""
        out = []
        for node in self.iter():
            if tag is not None and node.tag != tag:
                continue
            if all(self._has(node, name, value) for name, value in attrs.items()):
                out.append(node)
        return out

    def find(self, tag: str | None = None, **attrs: str) -> Node:
        found = self.find_all(tag, **attrs)
        assert len(found) == 1, f"{len(found)} <{tag or '*'} {attrs}> where one was expected"
        return found[0]

    @staticmethod
    def _has(node: Node, name: str, value: str) -> bool:
        if name == "class_":
            return value in node.attrs.get("class", "").split()
        return node.attrs.get(name.replace("_", "-")) == value

    def text(self) -> str:
        """The text content (comments left out), whitespace runs as one space, stripped."""
        parts: list[str] = []

        def walk(node: Node) -> None:
            for child in node.children:
                if isinstance(child, Node):
                    walk(child)
                elif not isinstance(child, Comment):
                    parts.append(child)
        walk(self)
        return " ".join("".join(parts).split())

    def comments(self) -> list[str]:
        return [c.strip() for n in self.iter() for c in n.children if isinstance(c, Comment)]


class _TreeBuilder(HTMLParser):
    VOID = frozenset({"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source",
                      "track", "wbr"})

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.root = Node("#document", {})
        self.stack = [self.root]

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        node = Node(tag, {k: v or "" for k, v in attrs})
        self.stack[-1].children.append(node)
        if tag not in self.VOID:
            self.stack.append(node)

    def handle_startendtag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.stack[-1].children.append(Node(tag, {k: v or "" for k, v in attrs}))

    def handle_endtag(self, tag: str) -> None:
        if tag in self.VOID:
            return
        depth = next(i for i in range(len(self.stack) - 1, 0, -1) if self.stack[i].tag == tag)
        del self.stack[depth:]

    def handle_data(self, data: str) -> None:
        self.stack[-1].children.append(data)

    def handle_comment(self, data: str) -> None:
        self.stack[-1].children.append(Comment(data))


def parse_dom(markup: str) -> Node:
    builder = _TreeBuilder()
    builder.feed(markup)
    builder.close()
    return builder.root


def path_points(path: Node) -> np.ndarray:
    """An SVG ``<path>``'s vertices (its ``d`` is matplotlib's: ``M x y L x y ... z``)."""
    numbers = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", path.attrs["d"])]
    assert numbers and len(numbers) % 2 == 0, path.attrs["d"]
    return np.array(numbers).reshape(-1, 2)


def ids_matching(node: Node, pattern: str) -> list[tuple[Node, re.Match[str]]]:
    return [(n, m) for n in node.iter() if (m := re.fullmatch(pattern, n.attrs.get("id", "")))]


# -- fixtures -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def analysis() -> Analysis:
    return analyze(BAG, candidates=("relaxation_branch", "adhesion"))


@pytest.fixture(scope="module")
def report(analysis: Analysis, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_report(analysis, tmp_path_factory.mktemp("report") / "made-by-write_report")


@pytest.fixture(scope="module")
def report_json(analysis: Analysis) -> dict[str, Any]:
    """The JSON of the same analysis, as ``rheo analyze --json`` writes and a reader loads it."""
    return json.loads(json.dumps(analysis.to_json(), default=float))


@pytest.fixture(scope="module")
def rendered(report: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Node, list[str]]:
    """The report's DOM as Chromium has it once loaded, and the console's messages."""
    done = chromium(report, tmp_path_factory.mktemp("profile"), "--dump-dom")
    return parse_dom(done.stdout), console_messages(done.stderr)


@pytest.fixture(scope="module")
def dom(rendered: tuple[Node, list[str]]) -> Node:
    return rendered[0]


# -- the file -------------------------------------------------------------------------

def test_report_is_one_self_contained_file(analysis: Analysis, report: Path) -> None:
    assert report.name == "report.html" and report.is_file()
    assert sorted(p.name for p in report.parent.iterdir()) == ["report.html"]
    text = report.read_text(encoding="utf-8")
    assert EXTERNAL_REFERENCE.findall(text) == []
    assert not re.search(r"<(?:link|img|iframe|script)\b|url\(\s*['\"]?(?:https?:)?//", text, re.I)
    assert "<?xml" not in text
    assert text.count("<svg") == expected_figures(analysis)
    assert analysis.bag in text
    for unit in ("(s)", "(N)", "(mm)"):
        assert unit in text


def test_the_console_check_catches_a_console_error(tmp_path: Path) -> None:
    """What Chromium prints for a deliberate ``console.error``: the check below is real."""
    page = tmp_path / "broken.html"
    page.write_text('<!DOCTYPE html><html><body><script>console.error("deliberate");</script></body></html>')
    done = chromium(page, tmp_path / "profile", "--dump-dom")
    messages = console_messages(done.stderr)
    assert len(messages) == 1 and '"deliberate"' in messages[0], done.stderr[-3000:]


# -- the page as Chromium has it ------------------------------------------------------

def test_report_renders_in_chromium(analysis: Analysis, rendered: tuple[Node, list[str]]) -> None:
    dom, messages = rendered
    assert messages == []
    body = dom.find("body")
    # Every figure is an inline <svg> the HTML parser put in its <figure>.
    figures = body.find_all("figure")
    assert len(figures) == expected_figures(analysis) >= 5
    assert [len(f.find_all("svg")) for f in figures] == [1] * len(figures)
    assert len(body.find_all("svg")) == len(figures)


def test_verdict_and_diagnosis_are_the_jsons(dom: Node, report_json: dict[str, Any]) -> None:
    diagnosis = report_json["diagnosis"]
    # The bag's hidden effect, found: what makes this bag's report worth checking.
    assert diagnosis["missing_effect"] == "relaxation_branch" and diagnosis["adequate"] is True
    verdict = dom.find(id="verdict")
    found = diagnosis["missing_effects"]
    head = f"Missing effects found, in order: {', '.join(found)}." if found else "No missing effect found."
    assert verdict.text() == f"{head} Adequate: {diagnosis['adequate_model']} fits these data."
    assert "open" not in verdict.attrs["class"].split()
    # First on the page, before any section.
    order = list(dom.iter())
    assert order.index(verdict) < order.index(dom.find_all("h2")[0])
    steps = dom.find("ol", class_="steps").find_all("li")
    assert [li.text() for li in steps] == [" ".join(s["evidence"].split()) for s in diagnosis["steps"]]


def test_the_sensor_section_states_the_jsons_sensor_model(dom: Node, report_json: dict[str, Any]) -> None:
    sensor = report_json["sensor"]
    text = dom.find(id="sensor-law").text()
    assert text.startswith(sensor["law"] + "; cell noise"), text
    excess = sensor["tactile"]["excess"]
    assert excess["measured"] is not None and excess["used"] > 0.0, excess
    assert (f"exceeds its pressure by at most {excess['used']:.3g} Pa ({excess['measured']:.3g} Pa measured "
            "on the unloaded array before contact)") in " ".join(text.split()), text


def assert_printed(cell: Node, expected: float, digits: int, what: str) -> float:
    """``cell`` shows ``expected`` to ``digits`` significant digits (half a unit in the last
    one of rounding) and carries it exactly in ``data-value``; returns the error over that
    rounding."""
    shown = float(cell.text())
    assert float(cell.attrs["data-value"]) == expected, f"{what}: data-value {cell.attrs['data-value']} != {expected!r}"
    rounding = 0.5 * 10.0 ** (math.floor(math.log10(abs(expected))) - (digits - 1)) if expected else 0.0
    error = abs(shown - expected)
    assert error <= rounding * (1 + 1e-9), f"{what}: shows {cell.text()}, the JSON has {expected!r}"
    return error / rounding if rounding else 0.0


def parameter_rows(table: Node) -> dict[str, Node]:
    rows = {row.attrs["data-param"]: row for row in table.find_all("tr") if "data-param" in row.attrs}
    # A parameter's name, as printed, is its row's key.
    assert all(row.find_all("td")[0].text() == name for name, row in rows.items())
    return rows


def test_parameter_tables_are_the_jsons(dom: Node, report_json: dict[str, Any]) -> None:
    checked = 0
    for step, model in enumerate(report_json["models"], start=1):
        table = dom.find("table", id=f"parameters-step-{step}")
        assert table.attrs["data-model"] == model["name"]
        rows = parameter_rows(table)
        assert list(rows) == list(model["params"]), "every parameter of the JSON, none other, in its order"
        for name, row in rows.items():
            what = f"{model['name']} {name}"
            assert_printed(row.find("td", class_="value"), model["params"][name], VALUE_DIGITS, what)
            std = row.find("td", class_="std")
            if name not in model["std"]:
                assert std.text() == "-"
            elif model["std"][name] is None:
                assert std.text() == "not determined"
            else:
                assert_printed(std, model["std"][name], MODEL_STD_DIGITS, f"{model['name']} std {name}")
            checked += 1
        assert_printed(table.find("tr", data_stat="bic").find("td", class_="value"), model["bic"], BIC_DIGITS,
                       f"{model['name']} BIC")
        assert_printed(table.find("tr", data_stat="rmse_force").find("td", class_="value"), model["rmse_force"],
                       RMSE_DIGITS, f"{model['name']} RMS error")
    estimate = report_json["estimate"]
    rows = parameter_rows(dom.find("table", id="parameters-closed-form"))
    assert list(rows) == list(BASE_PARAMETERS)
    for name, row in rows.items():
        assert_printed(row.find("td", class_="value"), estimate[name], VALUE_DIGITS, f"closed form {name}")
        std = row.find("td", class_="std")
        if estimate["std"][name] is None:
            assert std.text() == "-"
        else:
            assert_printed(std, estimate["std"][name], CLOSED_FORM_STD_DIGITS, f"closed form std {name}")
        checked += 1
    assert checked == sum(len(m["params"]) for m in report_json["models"]) + len(BASE_PARAMETERS)


# -- the misfit windows, from the SVG geometry ----------------------------------------

def residual_axes(dom: Node, k: int) -> tuple[Node, tuple[float, float], tuple[float, float, float, float]]:
    """Force figure ``k``'s residual axes: the group, its x-limits (s) and its frame's
    extent in SVG units (x0, x1, y0, y1)."""
    axes = dom.find("figure", id=f"force-{k}").find("g", id=f"force{k}-residual-axes")
    low, high = map(float, axes.attrs["data-xlim"].split())
    frame = path_points(axes.find("g", id=f"force{k}-residual-frame").find("path"))
    return axes, (low, high), (frame[:, 0].min(), frame[:, 0].max(), frame[:, 1].min(), frame[:, 1].max())


def seconds(x: np.ndarray | float, xlim: tuple[float, float], frame: tuple[float, ...]) -> np.ndarray:
    """SVG x (user units) to seconds on the axes whose frame spans ``frame[:2]`` and shows ``xlim``."""
    return xlim[0] + (np.asarray(x) - frame[0]) / (frame[1] - frame[0]) * (xlim[1] - xlim[0])


def test_residual_axes_limits_are_what_the_axis_reads(dom: Node, report_json: dict[str, Any]) -> None:
    """The axes' ``data-xlim`` and frame put each x tick where its label (the text a person
    reads, kept by matplotlib as a comment beside its glyphs) says: the mapping the window
    test uses is the axis a person reads."""
    for k in range(len(report_json["models"])):
        axes, xlim, frame = residual_axes(dom, k)
        ticks = ids_matching(axes, rf"force{k}-xtick_\d+")
        assert len(ticks) >= 3
        for tick, _ in ticks:
            x = float(next(u for u in tick.find_all("use") if "x" in u.attrs).attrs["x"])  # the tick mark
            label = float(tick.comments()[0].replace("\u2212", "-"))
            assert abs(seconds(x, xlim, frame) - label) <= 1e-4 * (xlim[1] - xlim[0]), (k, label, x)


def test_misfit_windows_are_drawn_where_the_analysis_puts_them(
        analysis: Analysis, dom: Node, report_json: dict[str, Any]) -> None:
    """Each shaded window's x-extent, read from its SVG path and mapped to seconds through
    the axes' frame and limits, is the analysis's window within one plotted sample; the
    windows the JSON's evidence names are among them, in the phase it names."""
    sample = float(np.median(np.diff(analysis.record.force_t)))  # one plotted sample, 0.02 s here
    phases = {p["name"]: (p["t_start"], p["t_end"]) for p in report_json["phases"]}
    drawn_in_all = named_in_all = 0
    for k, model in enumerate(report_json["models"]):
        figure = dom.find("figure", id=f"force-{k}")
        assert figure.attrs["data-model"] == model["name"] == analysis.models[k].name
        axes, xlim, frame = residual_axes(dom, k)
        windows = ids_matching(figure, rf"force{k}-misfit-window-(\w+)-(\d+)")
        assert {id(n) for n, _ in windows} <= {id(n) for n in axes.iter()}, "a window outside the residual axes"
        drawn = []
        for group, match in windows:
            points = path_points(group.find("path"))
            # An axvspan: the frame's full height.
            assert np.allclose(sorted({points[:, 1].min(), points[:, 1].max()}), frame[2:], atol=1e-3)
            start, end = seconds([points[:, 0].min(), points[:, 0].max()], xlim, frame)
            drawn.append((match.group(1), float(start), float(end)))
        drawn.sort(key=lambda w: w[1])
        # The windows of the very analysis the JSON was made from (the JSON names them only
        # in its evidence text, below).
        expected = sorted(((s.phase, a, b) for s in analysis.models[k].comparison.stats if s.signal == "total"
                           for a, b in s.windows), key=lambda w: w[1])
        assert [w[0] for w in drawn] == [w[0] for w in expected], (model["name"], drawn, expected)
        for (phase, start, end), (_, a, b) in zip(drawn, expected):
            assert abs(start - a) <= sample and abs(end - b) <= sample, (model["name"], phase, (start, end), (a, b))
            lo, hi = phases[phase]
            assert lo - sample <= start <= end <= hi + sample, f"{phase} window {start}-{end} s outside the phase"
        drawn_in_all += len(drawn)
        # What the JSON says of them: the evidence on this model, "worst in the <phase>
        # phase ..., systematic over a-b s, c-d s" (0.1 s).
        for step in (s for s in report_json["diagnosis"]["steps"] if s["model"] == model["name"]):
            said = re.match(rf"{re.escape(model['name'])}: total force RMS \S+ N over the record; worst in the (\w+) "
                            r"phase at \S+ x the noise, systematic over ((?:\d+\.\d-\d+\.\d s(?:, )?)+)",
                            step["evidence"])
            if not said:
                continue
            for a, b in re.findall(r"(\d+\.\d)-(\d+\.\d) s", said.group(2)):
                assert any(phase == said.group(1) and abs(start - float(a)) <= EVIDENCE_ROUNDING + sample
                           and abs(end - float(b)) <= EVIDENCE_ROUNDING + sample
                           for phase, start, end in drawn), (model["name"], said.group(1), a, b, drawn)
                named_in_all += 1
    assert drawn_in_all >= 1 and named_in_all >= 1, "no misfit window to check: the test would prove nothing"
