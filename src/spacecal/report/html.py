"""``spacecal report``: one self-contained HTML file (works offline: plotly.js is embedded)
for the person who decides whether a calibration may be used.

The page reads top to bottom as that person asks:

1. Summary (one screen): the verdict, coloured, with a red banner and its reasons when the
   errors are large (see :mod:`spacecal.report.summary`); the result ``tracker_from_base``
   with its units; the expected error at the target; what was calibrated with what, when,
   whether the data were simulated, and which software made it.
2. Evidence: the sweeps and fits in 3-D, the marker residuals by segment, the verification
   targets against the paper's figures, the check history over time, the uncertainty of
   both transforms (translations in mm and rotations in degrees on separate axes).
3. Raw numbers, collapsed.

A script error in the page is shown in a red banner (and is what the Chromium test looks
for). :func:`write_figures` writes every figure as a PNG too (matplotlib).
"""

from __future__ import annotations

import datetime
import html
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.geometry.transforms import matrix_to_rotvec
from spacecal.records import CalibrationResult, CheckResult, Recording, VerificationResult
from spacecal.records.paper_reference import PAPER_VERIFICATION
from spacecal.report.evidence import check_series, fitted_sphere, sweeps, tick_format, uncertainty
from spacecal.report.summary import Assessment, Residuals, assess, provenance_facts, residuals_of

ERROR_BANNER = """
<div id="script-errors" style="display:none;background:#fdd;border:1px solid #c00;padding:8px"></div>
<script>
window.addEventListener("error", function (event) {
  var banner = document.getElementById("script-errors");
  banner.style.display = "block";
  banner.textContent += "script error: " + event.message + "\\n";
});
</script>
"""

STYLE = """
<style>
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0 auto;
       max-width: 1240px; padding: 12px 20px; color: #1d1d1f; line-height: 1.35; }
h1 { font-size: 1.6em; margin: 0.2em 0 0.1em; }
h2 { font-size: 1.2em; margin: 0.4em 0; border-bottom: 1px solid #ddd; }
.subtitle { color: #555; margin: 0 0 0.6em; }
.tag { display: inline-block; padding: 1px 8px; border-radius: 10px; font-size: 0.85em;
       font-weight: 600; margin-left: 6px; }
.tag.simulated { background: #fff1d6; color: #8a5a00; border: 1px solid #e0b050; }
.tag.real { background: #e8f0fe; color: #1a4d9c; border: 1px solid #9db8e8; }
.verdict { border-radius: 6px; padding: 10px 16px; margin: 0 0 12px; border: 2px solid; }
.verdict .headline { font-size: 1.7em; font-weight: 700; }
.verdict p { margin: 0.3em 0; }
.verdict ul { margin: 0.2em 0 0.2em 1.2em; padding: 0; }
.verdict.ok { background: #e7f5ea; border-color: #2e8540; color: #174d22; }
.verdict.alarm { background: #fde7e7; border-color: #c8102e; color: #7a0a1b; }
.verdict.unknown { background: #f1f1f1; border-color: #888; color: #333; }
.columns { display: grid; grid-template-columns: 1fr 1fr; gap: 8px 28px; }
table.facts { border-collapse: collapse; width: 100%; font-size: 0.92em; }
table.facts th { text-align: left; font-weight: 600; padding: 2px 10px 2px 0; vertical-align: top;
                 white-space: nowrap; color: #444; }
table.facts td { padding: 2px 0; }
#key-figures th { white-space: normal; width: 42%; }
table.matrix { border-collapse: collapse; font-family: ui-monospace, "DejaVu Sans Mono", monospace;
               font-size: 0.9em; margin: 2px 0 4px; }
table.matrix td { padding: 1px 10px; text-align: right; }
table.matrix td.t { background: #f3f6fa; font-weight: 600; }
table.matrix th { font-weight: normal; color: #666; font-size: 0.85em; padding: 0 10px; }
.note { color: #555; font-size: 0.9em; }
.caption { color: #444; font-size: 0.92em; margin: 0 0 4px; }
nav { font-size: 0.92em; margin: 6px 0 0; }
nav a { margin-right: 14px; }
details pre { background: #f6f6f6; padding: 8px; overflow: auto; max-height: 40em; font-size: 0.8em; }
@media print { #evidence { break-before: page; } details { display: none; } }
</style>
"""


@dataclass
class Report:
    """What goes into a report."""

    calibration: CalibrationResult
    recording: Recording | None = None
    verification: VerificationResult | None = None
    check_history: list[CheckResult] | None = None


# ---------------------------------------------------------------------------------------------
# interactive figures (plotly)


def _axis(title: str, values=None, **extra) -> dict:
    axis = {"title": {"text": title}, **extra}
    if values is not None:
        axis["tickformat"] = tick_format(values)
    return axis


def _sweep_figure(report: Report):
    import plotly.graph_objects as go

    assert report.recording is not None
    figure = go.Figure()
    for sweep in sweeps(report.recording, report.calibration):
        p = sweep.marker_in_tracker
        figure.add_trace(
            go.Scatter3d(
                x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", marker={"size": 2}, name=sweep.label
            )
        )
        if sweep.line_in_tracker is not None:
            line = sweep.line_in_tracker
            figure.add_trace(
                go.Scatter3d(
                    x=line[:, 0],
                    y=line[:, 1],
                    z=line[:, 2],
                    mode="lines",
                    line={"width": 5, "color": "black"},
                    name=f"{sweep.label} fitted line",
                )
            )
    sphere = fitted_sphere(report.calibration)
    if sphere is not None:
        centre, radius = sphere
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
        figure.add_trace(
            go.Surface(
                x=centre[0] + radius * np.cos(u) * np.sin(v),
                y=centre[1] + radius * np.sin(u) * np.sin(v),
                z=centre[2] + radius * np.cos(v),
                opacity=0.15,
                showscale=False,
                colorscale=[[0, "grey"], [1, "grey"]],
                name="fitted sphere",
                showlegend=True,
            )
        )
    figure.update_layout(
        height=620,
        margin={"l": 0, "r": 0, "t": 30, "b": 0},
        scene={
            "aspectmode": "data",
            "xaxis": {"title": {"text": "x (mm)"}},
            "yaxis": {"title": {"text": "y (mm)"}},
            "zaxis": {"title": {"text": "z (mm)"}},
        },
        title={"text": "Marker origin in the tracker frame (mm)"},
        legend={"itemsizing": "constant"},
    )
    return figure


def _residual_figure(residuals: Residuals):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    figure = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.08)
    for k, label in enumerate(dict.fromkeys(residuals.segment.tolist())):
        rows = residuals.segment == label
        colour = _COLOURS[k % len(_COLOURS)]
        for row, values in ((1, residuals.position_mm), (2, residuals.rotation_deg)):
            figure.add_trace(
                go.Scatter(
                    x=residuals.time_s[rows],
                    y=values[rows],
                    mode="markers",
                    marker={"size": 4, "color": colour},
                    name=label or "samples",
                    legendgroup=label,
                    showlegend=row == 1,
                ),
                row=row,
                col=1,
            )
    figure.update_yaxes(
        _axis("position residual (mm)", residuals.position_mm, rangemode="tozero"), row=1, col=1
    )
    figure.update_yaxes(
        _axis("rotation residual (deg)", residuals.rotation_deg, rangemode="tozero"), row=2, col=1
    )
    figure.update_xaxes(title_text="time (s)", row=2, col=1)
    figure.update_layout(height=520, margin={"t": 30}, legend={"title": {"text": "segment"}})
    return figure


_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]


def _verification_figure(verification: VerificationResult):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    targets = np.arange(1, len(verification.position_error_mm) + 1)
    stats = verification.statistics()
    figure = make_subplots(
        rows=1,
        cols=2,
        subplot_titles=(
            f"(A) deviation of position: mean {stats['position_mm']['mean']:.2f} mm, "
            f"max {stats['position_mm']['max']:.2f} mm",
            f"(B) deviation of posture: mean {stats['posture_deg']['mean']:.2f} deg, "
            f"max {stats['posture_deg']['max']:.2f} deg",
        ),
    )
    paper = PAPER_VERIFICATION
    panels = (
        (
            1,
            verification.position_error_mm,
            "mm",
            paper["position_mean_bound_mm"],
            "paper: mean < {:g} mm (a bound)",
        ),
        (2, verification.posture_error_deg, "deg", paper["posture_mean_deg"], "paper: mean about {:g} deg"),
    )
    for col, values, unit, reference, label in panels:
        figure.add_trace(
            go.Scatter(
                x=targets,
                y=values,
                mode="markers",
                marker={"size": 8, "color": "#1f77b4"},
                name=f"spacecal, per target ({unit})",
                hovertemplate=f"target %{{x}}: %{{y:.3f}} {unit}<extra></extra>",
            ),
            row=1,
            col=col,
        )
        figure.add_hline(
            y=float(values.mean()),
            line={"color": "#1f77b4", "width": 1},
            row=1,
            col=col,
        )
        if unit == "mm":
            # the paper gives a bound on the mean, not a mean: shade what it allows
            figure.add_hrect(y0=0, y1=reference, fillcolor="red", opacity=0.06, line_width=0, row=1, col=col)
        figure.add_hline(
            y=reference,
            line={"color": "#c8102e", "dash": "dash"},
            annotation_text=label.format(reference),
            annotation_position="top left",
            row=1,
            col=col,
        )
        top = max(float(values.max()), reference) * 1.25
        figure.update_yaxes(
            _axis(f"error ({unit})", [top], range=[0, top]),
            row=1,
            col=col,
        )
        figure.update_xaxes(title_text="verification target", dtick=1, row=1, col=col)
    figure.update_layout(height=420, showlegend=False, margin={"t": 40})
    return figure


def _uncertainty_figure(calibration: CalibrationResult):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    split = uncertainty(calibration)
    assert split is not None
    figure = make_subplots(rows=1, cols=2, subplot_titles=("Translations (mm)", "Rotations (deg)"))
    for col, values, unit, kind in (
        (1, split.translation_sd_mm, "mm", "translation"),
        (2, split.rotation_sd_deg, "deg", "rotation"),
    ):
        for k, (name, sd) in enumerate(values.items()):
            figure.add_trace(
                go.Bar(
                    x=[f"{kind} {a}" for a in split.axes],
                    y=sd,
                    name=name,
                    marker_color=_COLOURS[k],
                    legendgroup=name,
                    showlegend=col == 1,
                    hovertemplate=f"{name} %{{x}}: %{{y:.4f}} {unit}<extra></extra>",
                ),
                row=1,
                col=col,
            )
        every = np.concatenate([v for v in values.values()]) if values else np.zeros(1)
        figure.update_yaxes(_axis(f"standard deviation ({unit})", every, rangemode="tozero"), row=1, col=col)
    figure.update_layout(barmode="group", height=400, margin={"t": 40})
    return figure


def _check_figure(history: list[CheckResult]):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    series = check_series(history)
    x = [t.isoformat() for t in series.when] if series.dated else series.when
    colours = ["#2e8540" if ok else "#c8102e" for ok in series.passed]
    text = ["PASS" if ok else "FAIL" for ok in series.passed]
    figure = make_subplots(
        rows=1, cols=2, subplot_titles=("Worst TCP error (mm)", "Worst rotation error (deg)")
    )
    for col, values, threshold, unit in (
        (1, series.worst_tcp_mm, series.threshold_mm, "mm"),
        (2, series.worst_rotation_deg, series.threshold_deg, "deg"),
    ):
        figure.add_trace(
            go.Scatter(
                x=x,
                y=values,
                mode="markers",
                marker={"size": 10, "color": colours},
                text=text,
                hovertemplate=f"%{{x}}: %{{y:.3f}} {unit} (%{{text}})<extra></extra>",
                showlegend=False,
            ),
            row=1,
            col=col,
        )
        figure.add_hline(
            y=threshold,
            line={"color": "#c8102e", "dash": "dash"},
            annotation_text=f"threshold {threshold:.2f} {unit}",
            annotation_position="top left",
            row=1,
            col=col,
        )
        top = max(float(values.max()), threshold) * 1.25
        figure.update_yaxes(_axis(f"error ({unit})", [top], range=[0, top]), row=1, col=col)
        figure.update_xaxes(title_text="check time (UTC)" if series.dated else "check", row=1, col=col)
        if series.dated:
            # at least half a day either side: one check is a point, not a bar across the page,
            # and checks minutes apart read as one occasion
            first, last = min(series.when), max(series.when)
            pad = max(0.1 * (last - first), datetime.timedelta(hours=12))
            figure.update_xaxes(range=[(first - pad).isoformat(), (last + pad).isoformat()], row=1, col=col)
    figure.update_layout(height=380, margin={"t": 40})
    return figure


# ---------------------------------------------------------------------------------------------
# the page


def _facts_table(rows: list[tuple[str, str]], table_id: str) -> str:
    body = "".join(
        f"<tr><th>{html.escape(label)}</th><td>{html.escape(value)}</td></tr>" for label, value in rows
    )
    return f"<table class='facts' id='{table_id}'>{body}</table>"


def _matrix_table(matrix: np.ndarray, table_id: str) -> str:
    head = "<tr><th colspan='3'>rotation (unitless)</th><th>translation (mm)</th></tr>"
    rows = []
    for r in range(4):
        cells = [f"<td>{matrix[r, c]:.5f}</td>" for c in range(3)]
        cells.append(f"<td class='t'>{matrix[r, 3]:.2f}</td>" if r < 3 else "<td>1</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table class='matrix' id='{table_id}'>{head}{''.join(rows)}</table>"


def _rotation_text(matrix: np.ndarray) -> str:
    rotvec = matrix_to_rotvec(matrix[:3, :3])
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return "no rotation"
    axis = rotvec / angle
    return f"{np.degrees(angle):.3f} deg about ({axis[0]:.4f}, {axis[1]:.4f}, {axis[2]:.4f})"


def _summary_section(report: Report, assessment: Assessment) -> str:
    calibration = report.calibration
    facts = provenance_facts(calibration, report.recording)
    lookup = dict(facts)
    simulated = calibration.provenance.simulated
    tag = (
        "<span class='tag simulated'>SIMULATED DATA</span>"
        if simulated
        else "<span class='tag real'>real devices</span>"
        if simulated is False
        else ""
    )
    subtitle = (
        f"{html.escape(lookup.get('robot', '?'))} to {html.escape(lookup.get('tracker', '?'))}; "
        f"method <b>{html.escape(calibration.method)}</b>; {html.escape(lookup.get('calibrated', ''))}{tag}"
    )
    reasons = "".join(f"<li>{html.escape(r)}</li>" for r in assessment.reasons)
    verdict_text = (
        f"<p class='verdict-text'><b>estimator's verdict:</b> {html.escape(assessment.verdict)}</p>"
        if assessment.verdict
        else "<p class='verdict-text'>This method gives no verdict; judge by the residuals and a check.</p>"
    )
    banner = (
        f"<div id='verdict' class='verdict {assessment.level}' data-level='{assessment.level}'>"
        f"<div class='headline'>{html.escape(assessment.headline)}</div>{verdict_text}"
        + (f"<ul class='reasons'>{reasons}</ul>" if reasons else "")
        + "</div>"
    )
    matrix = calibration.tracker_from_base
    result = (
        "<h2>Result: <code>tracker_from_base</code></h2>"
        "<p class='note'>Maps points in the robot base frame to the tracker frame: "
        "p_tracker = tracker_from_base &middot; p_base. Lengths in mm.</p>"
        + _matrix_table(matrix, "tracker-from-base")
        + f"<p class='note'>translation {matrix[0, 3]:.2f}, {matrix[1, 3]:.2f}, {matrix[2, 3]:.2f} mm; "
        f"rotation {_rotation_text(matrix)}</p>"
    )
    marker = calibration.tcp_from_marker
    result += (
        f"<p class='note'><code>tcp_from_marker</code>: translation {marker[0, 3]:.2f}, {marker[1, 3]:.2f}, "
        f"{marker[2, 3]:.2f} mm; rotation {_rotation_text(marker)}</p>"
    )
    numbers = "<h2>Expected error and evidence in numbers</h2>" + _facts_table(
        assessment.numbers, "key-figures"
    )
    provenance = "<h2>What, with what, when</h2>" + _facts_table(facts, "provenance")
    return (
        "<section id='summary'>"
        "<h1>Robot-to-tracker calibration report</h1>"
        f"<p class='subtitle'>{subtitle}</p>"
        f"{banner}"
        f"<div class='columns'><div>{numbers}</div><div>{result}</div></div>"
        f"{provenance}"
        "</section>"
    )


_CAPTIONS = {
    "Sweeps and fits": "Each dot is the marker origin of one recorded sample, in the tracker frame (mm), "
    "coloured by sweep; black lines are fitted translation axes, the grey sphere the fitted rotation sphere "
    "(the paper's method). Drag to rotate.",
    "Residuals": "Distance and angle between the marker pose the tracker measured and the pose the "
    "calibration predicts from the robot's pose, per sample. Noise-like scatter well below 1 mm is "
    "expected; a trend or a jump within one sweep points to a systematic error.",
    "Target errors": "The verification experiment (paper Fig. 7): one point per target. The dashed red "
    "line is the paper's figure: an upper bound on its mean position error (shaded: below the bound), "
    "and its approximate mean posture error.",
    "Check history": "Each point is one check of this calibration (green: passed, red: failed), with the "
    "threshold it was checked against.",
    "Uncertainty": "Standard deviation of each parameter of both transforms, from the calibration's "
    "covariance: translations in mm (left), rotations in degrees (right).",
}


def _raw_numbers(report: Report) -> dict[str, Any]:
    calibration = report.calibration.to_dict()
    # the file's diagnostics object as written, its per-sample rows counted rather than listed
    stored = dict(calibration.get("diagnostics") or {})
    per_sample = stored.pop("per_sample_residuals", None)
    if per_sample is not None:
        stored["per_sample_residuals"] = f"{len(per_sample)} rows (in the calibration file)"
    calibration["diagnostics"] = stored
    raw: dict[str, Any] = {"calibration": calibration}
    if report.verification is not None:
        raw["verification"] = {
            "statistics": report.verification.statistics(),
            "position_error_mm": report.verification.position_error_mm.tolist(),
            "posture_error_deg": report.verification.posture_error_deg.tolist(),
            "simulated": report.verification.simulated,
        }
    if report.check_history:
        raw["check_history"] = [entry.to_dict() for entry in report.check_history]
    return raw


def build_report_html(report: Report) -> tuple[str, list[str]]:
    """The report page and the titles of the plots in it (in page order)."""
    import plotly.io as pio
    from plotly.offline import get_plotlyjs

    residuals = residuals_of(report.calibration, report.recording)
    assessment = assess(report.calibration, residuals, report.verification, report.check_history)
    sections, titles = [], []

    def add(title, figure):
        titles.append(title)
        div = pio.to_html(
            figure,
            full_html=False,
            include_plotlyjs=False,
            div_id=f"plot-{len(titles)}",
            config={"displaylogo": False, "responsive": True},
        )
        anchor = title.lower().replace(" ", "-")
        sections.append(
            f"<section id='{anchor}'><h2>{html.escape(title)}</h2>"
            f"<p class='caption'>{html.escape(_CAPTIONS.get(title, ''))}</p>\n{div}</section>"
        )

    calibration = report.calibration
    if report.recording is not None:
        add("Sweeps and fits", _sweep_figure(report))
    if residuals is not None:
        add("Residuals", _residual_figure(residuals))
    if report.verification is not None:
        add("Target errors", _verification_figure(report.verification))
    if uncertainty(calibration) is not None:
        add("Uncertainty", _uncertainty_figure(calibration))
    if report.check_history:
        add("Check history", _check_figure(report.check_history))
    missing = []
    if report.recording is None:
        missing.append("no recording: the sweeps are not shown")
    if report.verification is None:
        missing.append("no verification (spacecal verify -o, then --verification)")
    if not report.check_history:
        missing.append("no check history (spacecal check)")
    nav = "".join(f"<a href='#{t.lower().replace(' ', '-')}'>{html.escape(t)}</a>" for t in titles)
    raw = html.escape(json.dumps(_raw_numbers(report), indent=2))
    plotly_js = f'<script type="text/javascript">{get_plotlyjs()}</script>'  # embedded: works offline
    page = (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<title>Calibration report: {html.escape(assessment.headline)}</title>{STYLE}</head>\n<body>\n"
        f"{ERROR_BANNER}\n"
        + _summary_section(report, assessment)
        + "\n<section id='evidence'><h2 style='font-size:1.4em'>Evidence</h2>"
        + f"<nav>{nav}</nav>"
        + ("".join(f"<p class='note'>{html.escape(m)}</p>" for m in missing))
        + "</section>\n"
        + f"{plotly_js}\n"
        + "\n".join(sections)
        + "\n<section id='raw'><h2>Raw numbers</h2><details><summary>all figures of the calibration, "
        "verification and checks (JSON; mm, rad unless named)</summary>"
        f"<pre id='raw-numbers'>{raw}</pre></details></section>\n"
        "</body></html>\n"
    )
    # plotly.js (several MB) comes after the summary, so the summary is drawn before it is
    # parsed, and before the plots, whose scripts call it at once.
    return page, titles


def write_report(
    report: Report, path: str | Path, png_dir: str | Path | None = None
) -> tuple[Path, list[str]]:
    """Write the HTML report (and, with ``png_dir``, every figure as PNG: see
    :func:`write_figures`); returns the path and plot titles."""
    page, titles = build_report_html(report)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    if png_dir is not None:
        write_figures(report, png_dir)
    return path, titles


def write_figures(report: Report, png_dir: str | Path) -> list[Path]:
    """Every figure of the report as a PNG in ``png_dir`` (matplotlib): ``sweeps.png``,
    ``residuals.png``, ``verification_errors.png``, ``uncertainty.png``,
    ``check_history.png``, as far as the report has the data for them."""
    from spacecal.report import figures

    folder = Path(png_dir)
    written = []
    if report.recording is not None:
        written.append(figures.plot_sweeps(report.recording, report.calibration, folder / "sweeps.png"))
    residuals = residuals_of(report.calibration, report.recording)
    if residuals is not None:
        written.append(
            figures.plot_residuals(
                residuals.time_s,
                residuals.position_mm,
                folder / "residuals.png",
                rotation_residual_deg=residuals.rotation_deg,
                segment=residuals.segment,
            )
        )
    if report.verification is not None:
        written.append(
            figures.plot_verification_errors(
                report.verification.position_error_mm,
                report.verification.posture_error_deg,
                folder / "verification_errors.png",
            )
        )
    for made in (
        figures.plot_uncertainty(report.calibration, folder / "uncertainty.png"),
        figures.plot_check_history(report.check_history or [], folder / "check_history.png"),
    ):
        if made is not None:
            written.append(made)
    return written
