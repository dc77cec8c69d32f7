"""``write_report``: what ``analyze`` found, as one self-contained HTML page.

The page needs no server, fetches nothing and runs no script: the figures are
matplotlib SVG inlined in the HTML, the style sheet is inline too. It states the
verdict first, then the phases, the diagnosis step by step, what remains where no effect
explains the data, how the force error falls
from model to model, each model's force against the measurement with its residual, the
marker mesh measured against the final model, and every parameter with its std.

What it shows can be read back by a machine, as a browser has it, without changing
what a person sees:

- the verdict is ``<p id="verdict">``, each diagnosis step an ``<li>`` of ``ol.steps``;
- each parameter table is ``<table class="parameters" id="parameters-step-<k>">`` (one
  per model, ``data-model`` its name) or ``id="parameters-closed-form"``; a parameter's
  row is ``<tr data-param="<name>">`` with ``<td class="value">`` and ``<td class="std">``,
  each with ``data-value``, the float's ``repr`` (empty for no std or one at a bound,
  ``td.std.at-bound``, ``inf``/``nan`` for an undetermined one); the BIC and RMS rows are ``<tr data-stat="bic">`` and
  ``<tr data-stat="rmse_force">``;
- where the catalogue does not explain the data, the section "What remains": its
  sentence ``<p id="remaining-text">``, each phase's shape a row ``<tr data-phase=...
  data-shape=...>`` of ``table#remaining-shapes`` (``td.size``, ``td.tau`` with
  ``data-value``), the figure ``<figure id="remaining">`` with each fitted shape the
  SVG group ``remaining-shape-<phase>``;
- each model's force figure is ``<figure class="force" id="force-<k>" data-model=...>``
  (``k`` from 0, the order of ``Analysis.models``); its residual axes are the SVG group
  ``force<k>-residual-axes`` with ``data-xlim="<t0> <t1>"`` (s, the limits it was drawn
  with), its background rectangle ``force<k>-residual-frame``, and each shaded misfit
  window (``axvspan``) the group ``force<k>-misfit-window-<phase>-<i>``. A window's SVG
  x-extent maps to seconds through the frame's x-extent and ``data-xlim``.

The figures are ``matplotlib.figure.Figure`` objects on an Agg canvas, never
registered with pyplot: no window opens whatever the caller's backend, and each is
cleared once rendered.
"""

from __future__ import annotations

import html
import io
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from rheo_ros.diagnosis.analysis import Analysis
from rheo_ros.diagnosis.decision import Verdict, unexplained_text
from rheo_ros.diagnosis.fits import ModelFit
from rheo_ros.diagnosis.remaining import describe as describe_remaining
from rheo_ros.diagnosis.remaining import shape_curve
from rheo_ros.experiment import PUSH_PHASES, Phase
from rheo_ros.identification.fit import steady_readings
from rheo_ros.io.files import write_text_atomic
from rheo_ros.record import contact_depth

REPORT_NAME = "report.html"
MEASURED_COLOUR = "#333333"
MODEL_COLOUR = "#d9480f"
WINDOW_COLOUR = "#e03131"
PHASE_COLOURS = {"pull": "#e7f5ff", "keep": "#fff9db", "release": "#ebfbee"}
BAR_COLOURS = {"total": "#495057", "pull": "#1c7ed6", "keep": "#f59f00", "release": "#37b24d"}
# Units of the base model's parameters (``Estimate``); an effect's are in its description.
PARAMETER_UNITS = {"E": "Pa", "c1": "Pa s", "c2": "Pa s", "gamma": "-"}
# The mesh panels magnify displacements smaller than this share of the specimen's size.
VISIBLE_SHARE = 0.1

STYLE = """
body { font-family: system-ui, sans-serif; max-width: 70rem; margin: 1.5rem auto; padding: 0 1rem;
       color: #212529; line-height: 1.45; }
h1 { font-size: 1.5rem; } h2 { font-size: 1.2rem; margin-top: 2rem; border-bottom: 1px solid #dee2e6; }
h3 { font-size: 1rem; }
code { background: #f1f3f5; padding: 0 .25rem; border-radius: 3px; }
.verdict { font-size: 1.15rem; padding: .75rem 1rem; border-left: .4rem solid #2f9e44; background: #ebfbee; }
.verdict.open { border-color: #e8590c; background: #fff4e6; }
table { border-collapse: collapse; margin: .5rem 0 1rem; }
th, td { border: 1px solid #dee2e6; padding: .2rem .6rem; text-align: right; }
th:first-child, td:first-child { text-align: left; }
th { background: #f8f9fa; }
td.undetermined { color: #c92a2a; }
figure { margin: 1rem 0; } figcaption { font-size: .9rem; color: #495057; }
svg { max-width: 100%; height: auto; }
ol.steps li { margin-bottom: .6rem; }
"""

def write_report(result: Analysis, directory: str | Path) -> Path:
    """Write ``result`` as ``report.html`` in ``directory`` (created if missing); returns its path."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    path = out / REPORT_NAME
    write_text_atomic(path, render_report(result))
    return path


def render_report(result: Analysis) -> str:
    """The whole page as a string (``write_report`` writes it)."""
    bag = html.escape(result.bag)
    verdict, settled = verdict_text(result)
    sections = [
        f"<h1>rheo analyze: <code>{bag}</code></h1>",
        f'<p class="verdict{"" if settled else " open"}" id="verdict">{html.escape(verdict)}</p>',
        _experiments_section(result),
        _phases_section(result),
        _sensor_section(result),
        _diagnosis_section(result),
        _remaining_section(result),
        _error_section(result),
        _force_section(result),
        _mesh_section(result),
        _parameters_section(result),
    ]
    body = "\n".join(sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        f"<title>rheo analyze: {bag}</title>\n<style>{STYLE}</style>\n</head>\n"
        f"<body>\n{body}\n</body>\n</html>\n"
    )


def verdict_text(result: Analysis) -> tuple[str, bool]:
    """The verdict in one or two sentences, and whether it is settled (adequate)."""
    final = result.final.name
    if not result.diagnoses:
        return f"Not diagnosed: {final} fitted as asked, no effect searched for.", False
    last = result.diagnoses[-1]
    verdict = Verdict.of(result.diagnoses)
    if verdict.closest:
        text = unexplained_text(verdict.reason, verdict.closest)
        return f"{text[0].upper()}{text[1:]} (see what remains).", False
    found = result.missing_effects
    head = ("Missing effects found, in order: " + ", ".join(found) + "." if found
            else "No missing effect found.")
    if last.adequate:
        return f"{head} Adequate: {final} fits these data.", True
    if len(last.undecided) > 1:
        return f"{head} Undecided: the data cannot tell {' and '.join(last.undecided)} apart.", False
    if last.undecided:
        return (f"{head} Undecided: the data ask for {last.undecided[0]} but do not pin its parameters "
                "down.", False)
    return f"{head} Not adequate: {final} still misfits and no effect in the catalogue explains it.", False


# -- sections -------------------------------------------------------------------------

def _experiments_section(result: Analysis) -> str:
    """With several pushes: each experiment's phases, closed form, final model and verdict,
    the pools of experiments judged one object and the changes flagged. The sections after
    it are experiment 1's."""
    if not result.experiments:
        return ""
    pools, changes = result.pools()
    pool_of = {k: i for i, p in enumerate(pools, 1) for k in p.experiments}
    rows = []
    for k, e in enumerate(result.experiments, 1):
        pull = e.record.profile().phases[0]
        fit = e.final.estimate
        values = "".join(_value_cell(fit.params[n], ".4g", extra=f' data-param="{n}"') +
                         _value_cell(fit.std.get(n, np.nan), ".2g", "std") for n in ("E", "c1", "c2"))
        rows.append(f'<tr data-experiment="{k}"><td>{k}</td><td>{pull.t_start:.2f}</td>'
                    f"<td>{contact_depth(e.record) * 1e3:.3f}</td>"
                    f"<td>{html.escape(e.final.name)}</td>{values}<td>{pool_of[k]}</td>"
                    f"<td>{html.escape(verdict_text(e)[0])}</td></tr>")
    head = ("<tr><th>experiment</th><th>pull from (s)</th><th>met at (mm)</th><th>final model</th><th>E (Pa)</th><th>std</th>"
            "<th>c1 (Pa s)</th><th>std</th><th>c2 (Pa s)</th><th>std</th><th>pool</th><th>verdict</th></tr>")
    pooled = "".join(
        f"<li>pool {i}: experiments {', '.join(map(str, p.experiments))}: "
        + ", ".join(f"{n} {p.params[n]:.4g} +- {p.std[n]:.2g}" for n in p.names)
        + f" (chi-square {p.chi2:.3g} on {p.dof} dof)</li>" for i, p in enumerate(pools, 1))
    flagged = "".join(f"<li>{html.escape(c.describe())}</li>" for c in changes)
    return (f'<section id="experiments"><h2>Experiments</h2><p>{len(result.experiments)} pushes on the '
            "specimen; each is modelled from where the earlier ones left it. The sections below are "
            f'experiment 1\'s.</p><table class="parameters">{head}{"".join(rows)}</table>'
            f'<ul id="pools">{pooled}</ul>' + (f'<ul id="changes">{flagged}</ul>' if flagged else "")
            + "</section>")


def _phases_section(result: Analysis) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(p.name)}</td><td>{p.t_start:.3f}</td><td>{p.t_end:.3f}</td>"
        f"<td>{p.t_end - p.t_start:.3f}</td></tr>"
        for p in result.record.profile().phases)
    table = ("<table><tr><th>phase</th><th>start (s)</th><th>end (s)</th><th>duration (s)</th></tr>"
             f"{rows}</table>")
    figure = _figure(_stage_svg(result), "The stage depth the phases were read from.")
    return f"<section><h2>Phases</h2>{table}{figure}</section>"


def _sensor_section(result: Analysis) -> str:
    """The sensor the analysis used, as the data showed it, and where the parameters disagreed."""
    sensor = result.record.sensor
    if sensor is None:
        return "<section><h2>Sensor</h2><p>A model record: no sensor.</p></section>"
    rows = "".join(f'<tr data-field="{html.escape(k)}"><td>{html.escape(k)}</td>'
                   f"<td>{html.escape(v)}</td></tr>" for k, v in sensor.source.items())
    warnings = "".join(f"<li>{html.escape(w)}</li>" for w in sensor.warnings)
    excess = result.record.sensor_json()["tactile"].get("excess")
    under = "" if excess is None else (
        f" Under the dead band a cell's mean reading exceeds its pressure by at most {excess['used']:.3g} Pa ("
        + ("not measured: too few frames before contact" if excess["measured"] is None else
           f"{excess['measured']:.3g} Pa measured on the unloaded array before contact") + ").")
    return (f'<section><h2>Sensor</h2><p id="sensor-law">{html.escape(sensor.law)}; cell noise '
            f"{sensor.tactile.noise:.3g} Pa, marker noise {sensor.marker_noise:.3g} m.{under}</p>"
            f'<table id="sensor-source"><tr><th>field</th><th>from</th></tr>{rows}</table>'
            + (f'<ul id="sensor-warnings">{warnings}</ul>' if warnings else "") + "</section>")


def _diagnosis_section(result: Analysis) -> str:
    if not result.diagnoses:
        return "<section><h2>Diagnosis</h2><p>Not diagnosed (no effect searched for).</p></section>"
    added = ""
    if result.added:
        added = f"<p>Effects added on request before the diagnosis: {html.escape(', '.join(result.added))}.</p>"
    steps = "".join(f"<li>{html.escape(d.evidence)}</li>"
                    for d in result.diagnoses)
    return f'<section><h2>Diagnosis</h2>{added}<ol class="steps">{steps}</ol></section>'


def _remaining_section(result: Analysis) -> str:
    """Where the catalogue does not explain the data: what the final model leaves, its
    shape in each phase fitted over it, the hint for the effect to write."""
    rest = result.what_remains()
    if rest is None:
        return ""
    rows = "".join(
        f'<tr data-phase="{html.escape(phase)}" data-shape="{html.escape(v["shape"])}"><td>{html.escape(phase)}</td>'
        f'<td>{html.escape(v["shape"])}</td>{_value_cell(v["size"], "+.3g", "size")}'
        + ('<td class="tau" data-value="">-</td>' if v["tau"] is None else _value_cell(v["tau"], ".3g", "tau"))
        + "</tr>" for phase, v in rest["shapes"].items())
    misfits = ", ".join(f"{c['signal']} in the {c['phase']} ({c['ratio']:.3g} x the noise)" for c in rest["misfits"])
    caption = (f"The total bottom force measured minus {result.remaining_model.name}"
               + (", the final model" if result.remaining_model is result.final else
                  ", the base model (an effect in no catalogue fits better than the effects found)")
               + ": what a missing "
               "effect must add. Over each phase, the shape fitted to it (a step, a ramp or a decay with its "
               "own time, the lowest BIC); the band is two noise std wide.")
    return ('<section><h2>What remains</h2>'
            f'<p id="remaining-text">{html.escape(describe_remaining(rest))}</p>'
            f"<p>Misfitting: {html.escape(misfits) or 'none'}.</p>"
            '<table id="remaining-shapes"><tr><th>phase</th><th>shape</th><th>size (x noise)</th>'
            f"<th>time (s)</th></tr>{rows}</table>"
            + _figure(_remaining_svg(result, rest), caption, 'class="remaining" id="remaining"')
            + "</section>")


def _remaining_svg(result: Analysis, rest: dict) -> str:
    record = result.record
    t = record.force_t
    residual = record.force.sum(axis=1) - result.remaining_model.prediction_total
    steady = steady_readings(record)
    noise = rest["force_noise"]
    with _new_figure(9, 3.4) as fig:
        ax = fig.subplots()
        _shade_phases(ax, record.profile().phases, label=True)
        ax.axhspan(-2 * noise, 2 * noise, color="#adb5bd", alpha=0.35, lw=0, label="±2 σ noise")
        ax.plot(t, residual, color=MEASURED_COLOUR, lw=0.6, label="measured - model")
        for n, (phase, shape) in enumerate(rest["shapes"].items()):
            span = next(p for p in record.profile().phases if p.name == phase)
            inside = (t > span.t_start) & (t < span.t_end)
            label = "fitted shape" if n == 0 else None
            ax.plot(t[inside], shape_curve(shape, t[inside]), color=MODEL_COLOUR, lw=1.6, label=label,
                    gid=f"shape-{phase}")
        ax.axhline(0.0, color="#868e96", lw=0.6)
        if steady.any():
            ax.set_ylim(*(1.15 * np.array([min(residual[steady].min(), -3 * noise),
                                           max(residual[steady].max(), 3 * noise)])))
        ax.set_xlabel("time (s)")
        ax.set_ylabel("measured - model (N)")
        ax.legend(fontsize=8, loc="upper right")
        return _svg(fig, "remaining")


def _error_section(result: Analysis) -> str:
    caption = ("RMS error of the total bottom force over the record and in each phase, for each model "
               "in the order fitted (readings at a phase boundary, mid-jump, left out).")
    return f"<section><h2>The error falls</h2>{_figure(_error_svg(result.models), caption)}</section>"


def _force_section(result: Analysis) -> str:
    parts = ["<section><h2>Total bottom force, measured and modelled</h2>"]
    for k, fit in enumerate(result.models):
        caption = (f"Step {k + 1}, {fit.name}: above, the total bottom force; below, the residual "
                   "(model - measured), the spans where it is systematic shaded, the band two sensor "
                   "noise std wide. The residual's axis fits the readings away from the phase boundaries; "
                   "the mid-jump readings there may fall outside it.")
        attributes = f'class="force" id="force-{k}" data-model="{html.escape(fit.name)}"'
        parts.append(f"<h3>{html.escape(fit.name)}</h3>{_figure(_force_svg(result, k), caption, attributes)}")
    parts.append("</section>")
    return "".join(parts)


def _mesh_section(result: Analysis) -> str:
    svg, note = _mesh_svg(result)
    caption = (f"The marker mesh of the final model, {result.final.name}, against the markers measured "
               f"(reference grid dashed). {note}")
    return f"<section><h2>Marker mesh</h2>{_figure(svg, caption)}</section>"


def _parameters_section(result: Analysis) -> str:
    parts = ["<section><h2>Parameters</h2>"]
    for step, fit in enumerate(result.models, start=1):
        parts.append(f"<h3>Step {step}: {html.escape(fit.name)}</h3>{_model_table(fit, step, result.at_bound(fit))}")
    cf, cf_std = result.closed_form, result.closed_form_std()
    rows = "".join(f'<tr data-param="{html.escape(k)}"><td>{html.escape(k)}</td>{_value_cell(v, ".4g")}'
                   + (f'<td class="std undetermined" data-value="" title="{html.escape(result.undetermined[k])}">'
                      "not determined</td>" if k in result.undetermined
                      else '<td class="std" data-value="">-</td>' if cf_std.get(k) is None
                      else _value_cell(cf_std[k], ".2g", "std"))
                   + f"<td>{PARAMETER_UNITS.get(k, '')}</td></tr>" for k, v in cf.params.items())
    parts.append(
        f"<h3>Closed form ({html.escape(cf.method)}, eq. {html.escape(', '.join(cf.equations))})</h3>"
        "<p>std: the whole-record fit's, combined with the closed form's distance from that fit.</p>"
        f'<table class="parameters" id="parameters-closed-form">'
        f"<tr><th>parameter</th><th>value</th><th>std</th><th>unit</th></tr>{rows}</table>"
        + (f"<p>{html.escape(cf.message)}</p>" if cf.message else ""))
    parts.append("</section>")
    return "".join(parts)


def _value_cell(value: float, spec: str, cls: str = "value", extra: str = "") -> str:
    """A table cell showing ``value`` as ``spec``, the float's ``repr`` in ``data-value``."""
    return f'<td class="{cls}" data-value="{float(value)!r}"{extra}>{value:{spec}}</td>'


def _model_table(fit: ModelFit, step: int, bound: Sequence[str] = ()) -> str:
    """``bound``: the parameters at a bound (``Analysis.at_bound``), shown with no std."""
    std = fit.estimate.std
    rows = []
    for name, value in fit.estimate.params.items():
        s = std.get(name)
        if name in bound:
            shown = '<td class="std undetermined at-bound" data-value="">at bound</td>'
        elif s is None:
            shown = '<td class="std" data-value="">-</td>'
        elif not np.isfinite(s):
            shown = f'<td class="std undetermined" data-value="{float(s)!r}">not determined</td>'
        else:
            shown = _value_cell(s, ".3g", "std")
        rows.append(f'<tr data-param="{html.escape(name)}"><td>{html.escape(name)}</td>{_value_cell(value, ".4g")}'
                    f"{shown}<td>{PARAMETER_UNITS.get(name, '')}</td></tr>")
    tactile, marker = fit.delays
    across = ' colspan="3"'
    rows.append(f'<tr data-stat="bic"><td>BIC</td>{_value_cell(fit.bic, ".6g", extra=across)}</tr>')
    rows.append(f'<tr data-stat="rmse_force"><td>RMS error, total force (N)</td>'
                f'{_value_cell(fit.rmse_force, ".3g", extra=across)}</tr>')
    rows.append(f'<tr><td>clock offsets, tactile / markers (ms)</td>'
                f'<td colspan="3">{1e3 * tactile:.1f} / {1e3 * marker:.1f}</td></tr>')
    return (f'<table class="parameters" id="parameters-step-{step}" data-model="{html.escape(fit.name)}">'
            "<tr><th>parameter</th><th>value</th><th>std</th><th>unit</th></tr>" + "".join(rows) + "</table>")


# -- figures --------------------------------------------------------------------------

@contextmanager
def _new_figure(width: float, height: float) -> Iterator[Figure]:
    """A figure on an Agg canvas (no pyplot, no window), cleared after use."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    try:
        yield fig
    finally:
        fig.clear()


def _svg(fig: Figure, figure_id: str) -> str:
    """``fig`` as an inline ``<svg>`` element: no XML prolog, no metadata, its ids
    prefixed with ``figure_id`` so that figures on one page cannot collide. The group
    of each axes given a gid carries the limits it was drawn with, ``data-xlim`` and
    ``data-ylim`` (``"<low> <high>"``, the floats' ``repr``)."""
    buf = io.StringIO()
    # Text as paths: the page looks the same whatever fonts the reader's browser has.
    with matplotlib.rc_context({"svg.fonttype": "path", "svg.hashsalt": figure_id}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    svg = buf.getvalue()
    svg = svg[svg.index("<svg"):]
    svg = re.sub(r"<metadata>.*?</metadata>\s*", "", svg, flags=re.S)
    for ax in fig.axes:
        if ax.get_gid():
            tag = f'<g id="{ax.get_gid()}">'
            if svg.count(tag) != 1:
                raise ValueError(f"figure {figure_id}: axes gid {ax.get_gid()!r} not found once in the SVG")
            x0, x1 = map(float, ax.get_xlim())
            y0, y1 = map(float, ax.get_ylim())
            svg = svg.replace(tag, f'<g id="{ax.get_gid()}" data-xlim="{x0!r} {x1!r}" data-ylim="{y0!r} {y1!r}">')
    svg = re.sub(r'\bid="([^"]+)"', rf'id="{figure_id}-\1"', svg)
    svg = re.sub(r'href="#([^"]+)"', rf'href="#{figure_id}-\1"', svg)
    return re.sub(r"url\(#([^)]+)\)", rf"url(#{figure_id}-\1)", svg)


def _figure(svg: str, caption: str, attributes: str = "") -> str:
    """``svg`` with its caption; ``attributes``: the ``<figure>`` element's, as HTML."""
    opening = f"<figure {attributes}>" if attributes else "<figure>"
    return f"{opening}{svg}<figcaption>{html.escape(caption)}</figcaption></figure>"


def _shade_phases(ax: Axes, phases: Sequence[Phase], label: bool = False, shade: bool = True) -> None:
    """Phase boundaries drawn, spans shaded (``shade``); ``label``: their names along the top."""
    for p in phases:
        if shade:
            ax.axvspan(p.t_start, p.t_end, color=PHASE_COLOURS.get(p.name, "#f1f3f5"), zorder=0, lw=0)
        ax.axvline(p.t_start, color="#868e96", lw=0.7, ls=":")
        if label:
            ax.text((p.t_start + p.t_end) / 2, 1.01, p.name, transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=9, color="#495057")
    if phases:
        ax.axvline(phases[-1].t_end, color="#868e96", lw=0.7, ls=":")


def _stage_svg(result: Analysis) -> str:
    record = result.record
    with _new_figure(9, 2.6) as fig:
        ax = fig.subplots()
        _shade_phases(ax, record.profile().phases, label=True)
        ax.plot(record.stage_t, 1e3 * record.stage_depth, color=MEASURED_COLOUR, lw=1)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("stage depth (mm)")
        return _svg(fig, "stage")


def _error_svg(models: Sequence[ModelFit]) -> str:
    groups = ("total", *PUSH_PHASES)
    values = np.array([[m.rmse_force, *(m.rmse_by_phase.get(p, np.nan) for p in PUSH_PHASES)]
                       for m in models], dtype=float)
    positive = values[np.isfinite(values) & (values > 0)]
    log_scale = positive.size > 0 and positive.max() / positive.min() > 20
    width = 0.8 / len(groups)
    x = np.arange(len(models))
    with _new_figure(max(6.0, 2.2 * len(models) + 3), 3.6) as fig:
        ax = fig.subplots()
        for k, group in enumerate(groups):
            bars = ax.bar(x + (k - (len(groups) - 1) / 2) * width, np.nan_to_num(values[:, k]), width,
                          label="whole record" if group == "total" else group, color=BAR_COLOURS[group])
            if group == "total":
                ax.bar_label(bars, labels=[f"{v:.3g} N" for v in values[:, k]], fontsize=8, padding=2)
        if log_scale:
            ax.set_yscale("log")
        ax.set_xticks(x, [m.name.replace("+", "\n+ ") for m in models], fontsize=9)
        ax.set_ylabel("RMS error, total force (N)")
        ax.legend(fontsize=8, ncols=len(groups), loc="upper right")
        ax.margins(y=0.25)
        return _svg(fig, "error")


def _merged(windows: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Overlapping or touching (start, end) spans joined."""
    out: list[tuple[float, float]] = []
    for a, b in sorted(windows):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _force_svg(result: Analysis, k: int) -> str:
    """Model ``k``'s total force against the measured, and its residual with the misfit
    windows shaded (their ids and the axes' limits as the module's docstring says)."""
    fit = result.models[k]
    record = result.record
    profile = record.profile()
    t = record.force_t
    measured = record.force.sum(axis=1)
    residual = fit.prediction_total - measured
    totals = [s for s in fit.comparison.stats if s.signal == "total"]
    # Each phase's windows, merged where they overlap (a phase's runs never do).
    windows = [(s.phase, i, a, b) for s in totals for i, (a, b) in enumerate(_merged(s.windows))]
    noise = totals[0].noise if totals else np.nan
    steady = steady_readings(record)
    with _new_figure(9, 5.0) as fig:
        top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(2, 1.2))
        _shade_phases(top, profile.phases, label=True)
        _shade_phases(bottom, profile.phases, shade=False)  # the systematic windows are shaded there
        top.plot(t, measured, color=MEASURED_COLOUR, lw=0.8, label="measured")
        top.plot(t, fit.prediction_total, color=MODEL_COLOUR, lw=1.2, label=fit.name)
        top.set_ylabel("total bottom force (N)")
        top.legend(fontsize=8, loc="upper right")
        bottom.set_gid("residual-axes")
        bottom.patch.set_gid("residual-frame")
        for n, (phase, i, a, b) in enumerate(windows):
            bottom.axvspan(a, b, color=WINDOW_COLOUR, alpha=0.18, lw=0, gid=f"misfit-window-{phase}-{i}",
                           label="systematic residual" if n == 0 else None)
        if np.isfinite(noise):
            bottom.axhspan(-2 * noise, 2 * noise, color="#adb5bd", alpha=0.35, lw=0, label="±2 σ sensor noise")
        bottom.plot(t, residual, color=MODEL_COLOUR, lw=0.6)
        bottom.axhline(0.0, color="#868e96", lw=0.6)
        if steady.any():
            span = float(np.max(np.abs(residual[steady])))
            span = max(span, 3 * noise if np.isfinite(noise) else 0.0) * 1.15 or 1.0
            bottom.set_ylim(-span, span)
        bottom.set_ylabel("model - measured (N)")
        bottom.set_xlabel("time (s)")
        if windows or np.isfinite(noise):
            bottom.legend(fontsize=8, loc="lower right")
        return _svg(fig, f"force{k}")


def _magnification(displacements: Sequence[np.ndarray], size: float) -> float:
    """1, or a round factor (1, 2, 5 x 10^k) that makes the largest displacement about
    ``VISIBLE_SHARE`` of ``size``."""
    largest = max(float(np.max(np.linalg.norm(d, axis=-1))) for d in displacements)
    if largest <= 0 or largest >= 0.5 * VISIBLE_SHARE * size:
        return 1.0
    wanted = VISIBLE_SHARE * size / largest
    exponent = np.floor(np.log10(wanted))
    step = max(s for s in (1, 2, 5) if s * 10**exponent <= wanted)
    return float(step * 10**exponent)


def _draw_grid(ax: Axes, nodes_mm: np.ndarray, rows: int, cols: int, **style: object) -> None:
    """The grid lines through ``nodes_mm`` (rows x cols, row-major, bottom row first)."""
    grid = nodes_mm.reshape(rows, cols, 2)
    for r in range(rows):
        ax.plot(grid[r, :, 0], grid[r, :, 1], **style)
    for c in range(cols):
        ax.plot(grid[:, c, 0], grid[:, c, 1], **style)


def _mesh_svg(result: Analysis) -> tuple[str, str]:
    """The final model's marker mesh against the measured one at the end of the keep
    (the last marker frame within it) and at the record's end; returns the SVG and a
    sentence on the magnification."""
    record, final, mesh = result.record, result.final, result.setup.mesh
    profile = record.profile()
    tactile_delay, marker_delay = final.delays
    p = result.forward.predict(final.model, final.estimate.params["gamma"], profile,
                               record.force_t - tactile_delay, record.marker_t - marker_delay)
    in_keep = np.flatnonzero(record.marker_t <= profile.t_keep_end)
    keep_end = int(in_keep[-1]) if in_keep.size else int(np.argmin(np.abs(record.marker_t - profile.t_keep_end)))
    frames = (("end of keep", keep_end), ("end of record", len(record.marker_t) - 1))
    reference = record.marker_reference
    size = max(mesh.width, mesh.height)
    panels = []
    for title, i in frames:
        measured = record.markers[i] - reference
        modelled = p.displacement[i]
        panels.append((title, i, measured, modelled, _magnification((measured, modelled), size)))
    notes = []
    with _new_figure(9, 4.6) as fig:
        axes = fig.subplots(1, len(panels), sharey=True)
        for ax, (title, i, measured, modelled, k) in zip(axes, panels):
            _draw_grid(ax, 1e3 * reference, mesh.rows, mesh.cols, color="#adb5bd", lw=0.7, ls="--")
            _draw_grid(ax, 1e3 * (reference + k * modelled), mesh.rows, mesh.cols, color=MODEL_COLOUR, lw=1.6)
            _draw_grid(ax, 1e3 * (reference + k * measured), mesh.rows, mesh.cols,
                       color=MEASURED_COLOUR, lw=0.7, marker="o", ms=3)
            shown = "" if k == 1 else f", displacements x {k:g}"
            ax.set_title(f"{title}, t = {record.marker_t[i]:.2f} s{shown}", fontsize=10)
            ax.set_xlabel("x (mm)")
            ax.set_aspect("equal")
            notes.append(f"{title} (t = {record.marker_t[i]:.2f} s): "
                         + ("displacements to scale" if k == 1 else f"displacements magnified {k:g} times"))
        axes[0].set_ylabel("y (mm)")
        axes[0].plot([], [], color="#adb5bd", lw=0.7, ls="--", label="reference (before the pull)")
        axes[0].plot([], [], color=MEASURED_COLOUR, lw=0.7, marker="o", ms=3, label="measured")
        axes[0].plot([], [], color=MODEL_COLOUR, lw=1.6, label=final.name)
        fig.legend(fontsize=8, loc="outside lower center", ncols=3)
        svg = _svg(fig, "mesh")
    note = "; ".join(notes)
    return svg, note[:1].upper() + note[1:] + "."
