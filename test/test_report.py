"""The HTML report of ``rheo analyze``: one self-contained file that renders in a real
browser (headless Chromium, Debian's ``chromium``, which ``./tasks test`` installs)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from rheo_ros.app.analyze import analyze
from rheo_ros.diagnosis.analysis import Analysis
from rheo_ros.reports.html import write_report

CHROMIUM = Path("/usr/bin/chromium")
BAG = Path(__file__).resolve().parents[1] / "bags" / "effect_relaxation_branch"
# Chromium logs every console message (log, warn, error, uncaught exceptions alike) to
# stderr as ``[pid:tid:stamp:INFO:CONSOLE:line] "text", source: url (line)``.
CONSOLE_LINE = re.compile(r":CONSOLE[:\]]")
EXTERNAL_REFERENCE = re.compile(r"""\b(?:src|href)\s*=\s*["']?\s*(?:https?:)?//""", re.I)


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


def body_attributes(dom: str) -> dict[str, str]:
    body = re.search(r"<body\b([^>]*)>", dom)
    assert body, "no <body> in the dumped DOM"
    return dict(re.findall(r'([\w-]+)="([^"]*)"', body.group(1)))


@pytest.fixture(scope="module")
def analysis() -> Analysis:
    return analyze(BAG, candidates=("relaxation_branch", "adhesion"))


@pytest.fixture(scope="module")
def report(analysis: Analysis, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_report(analysis, tmp_path_factory.mktemp("report") / "made-by-write_report")


def test_report_is_one_self_contained_file(analysis: Analysis, report: Path) -> None:
    assert report.name == "report.html" and report.is_file()
    assert sorted(p.name for p in report.parent.iterdir()) == ["report.html"]
    text = report.read_text(encoding="utf-8")
    assert EXTERNAL_REFERENCE.findall(text) == []
    assert not re.search(r"<(?:link|img|iframe)\b|<script\b[^>]*\bsrc=|url\(\s*['\"]?(?:https?:)?//", text, re.I)
    assert "<?xml" not in text
    assert text.count("<svg") == expected_figures(analysis)
    assert analysis.bag in text
    # The verdict comes first, naming the effect the diagnosis found.
    verdict = re.search(r'<p class="verdict[^"]*">([^<]*)</p>', text)
    assert verdict and analysis.missing_effects == ("relaxation_branch",)
    assert "Missing effects found, in order: relaxation_branch" in verdict.group(1)
    assert text.index("verdict") < text.index("<h2>")
    for d in analysis.diagnoses:  # every step's evidence, in order
        assert d.model in text
    for unit in ("(s)", "(N)", "(mm)"):
        assert unit in text


def test_the_console_check_catches_a_console_error(tmp_path: Path) -> None:
    """What Chromium prints for a deliberate ``console.error``: the check below is real."""
    page = tmp_path / "broken.html"
    page.write_text('<!DOCTYPE html><html><body><script>console.error("deliberate");</script></body></html>')
    done = chromium(page, tmp_path / "profile", "--dump-dom")
    messages = console_messages(done.stderr)
    assert len(messages) == 1 and '"deliberate"' in messages[0], done.stderr[-3000:]


def test_report_renders_in_chromium(analysis: Analysis, report: Path, tmp_path: Path) -> None:
    done = chromium(report, tmp_path / "profile", "--dump-dom")
    assert console_messages(done.stderr) == []
    attributes = body_attributes(done.stdout)
    assert attributes.get("data-rendered") == "yes", attributes
    figures = expected_figures(analysis)
    assert figures >= 5
    assert attributes.get("data-figures") == str(figures), attributes


def test_report_screenshot_is_not_blank(report: Path, tmp_path: Path) -> None:
    shot = tmp_path / "report.png"
    done = chromium(report, tmp_path / "profile", f"--screenshot={shot}", "--window-size=1280,2400")
    assert console_messages(done.stderr) == []
    pixels = matplotlib.image.imread(shot)[..., :3]
    assert pixels.shape[:2] == (2400, 1280)
    colours = np.unique((pixels.reshape(-1, 3) * 255).round().astype(np.uint8), axis=0)
    assert len(colours) > 50, f"{len(colours)} colours: the page rendered (nearly) flat"
    # Ink on the page: a good share of pixels is far from the background.
    assert np.mean(np.abs(pixels - pixels[0, 0]).max(axis=-1) > 0.2) > 0.01
