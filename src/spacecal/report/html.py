"""``spacecal report``: one self-contained HTML file (works offline: plotly.js is embedded)
with interactive plots of a calibration, plus PNG figures for papers.

Plots: the sweeps in 3-D with the fitted sphere and lines; per-sample residuals; target
errors of a verification experiment (paper Fig. 7 style); uncertainty (predicted TRE and
parameter standard deviations); the calibration-check history. A script error in the page is
shown in a red banner (and is what the Chromium test looks for).
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.estimators.diagnostics import sample_residuals
from spacecal.records import CalibrationResult, CheckResult, Recording, VerificationResult
from spacecal.records.paper_reference import PAPER_VERIFICATION

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


@dataclass
class Report:
    """What goes into a report."""

    calibration: CalibrationResult
    recording: Recording | None = None
    verification: VerificationResult | None = None
    check_history: list[CheckResult] | None = None


def _sweep_figure(report: Report):
    import plotly.graph_objects as go

    recording, calibration = report.recording, report.calibration
    figure = go.Figure()
    visible = recording.visible
    for label in dict.fromkeys(recording.segment.tolist()):
        rows = (recording.segment == label) & visible
        points = recording.tracker_from_marker_stack[rows, :3, 3]
        figure.add_trace(
            go.Scatter3d(
                x=points[:, 0],
                y=points[:, 1],
                z=points[:, 2],
                mode="markers",
                marker={"size": 2},
                name=str(label),
            )
        )
        if str(label).startswith("lin_") and len(points) > 1:
            direction = np.asarray(
                calibration.diagnostics.get("lines", {})
                .get(label, {})
                .get("direction_in_tracker", np.linalg.svd(points - points.mean(0))[2][0])
            )
            along = (points - points.mean(0)) @ direction
            ends = points.mean(0) + np.outer([along.min(), along.max()], direction)
            figure.add_trace(
                go.Scatter3d(
                    x=ends[:, 0],
                    y=ends[:, 1],
                    z=ends[:, 2],
                    mode="lines",
                    line={"width": 5},
                    name=f"{label} fit",
                )
            )
    sphere = calibration.diagnostics.get("sphere")
    if sphere:
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
        c, r = np.asarray(sphere["centre_in_tracker_mm"]), sphere["radius_mm"]
        figure.add_trace(
            go.Surface(
                x=c[0] + r * np.cos(u) * np.sin(v),
                y=c[1] + r * np.sin(u) * np.sin(v),
                z=c[2] + r * np.cos(v),
                opacity=0.15,
                showscale=False,
                name="fitted sphere",
            )
        )
    figure.update_layout(
        title="Calibration sweeps: marker origin in the tracker frame (mm)",
        height=600,
        scene={"aspectmode": "data"},
    )
    return figure


def _residual_figure(report: Report):
    import plotly.graph_objects as go

    residuals = sample_residuals(
        report.recording, report.calibration.tracker_from_base, report.calibration.tcp_from_marker
    )
    times = report.recording.time_s[residuals["rows"]]
    figure = go.Figure()
    figure.add_trace(go.Scatter(x=times, y=residuals["position_mm"], mode="markers", name="position (mm)"))
    figure.add_trace(
        go.Scatter(x=times, y=residuals["rotation_deg"], mode="markers", name="rotation (deg)", yaxis="y2")
    )
    figure.update_layout(
        title="Per-sample residuals: measured vs predicted marker pose",
        xaxis_title="time (s)",
        yaxis_title="position residual (mm)",
        yaxis2={"title": "rotation residual (deg)", "overlaying": "y", "side": "right"},
    )
    return figure


def _verification_figure(verification: VerificationResult):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    index = list(range(1, len(verification.position_error_mm) + 1))
    figure = make_subplots(
        rows=1, cols=2, subplot_titles=("(A) deviation of position (mm)", "(B) deviation of posture (deg)")
    )
    figure.add_trace(
        go.Scatter(x=index, y=verification.position_error_mm, mode="markers", name="position"),
        row=1,
        col=1,
    )
    figure.add_trace(
        go.Scatter(x=index, y=verification.posture_error_deg, mode="markers", name="posture"),
        row=1,
        col=2,
    )
    paper = PAPER_VERIFICATION
    figure.add_hline(
        y=paper["position_mean_bound_mm"], line_dash="dash", row=1, col=1, annotation_text="paper: mean below"
    )
    figure.add_hline(
        y=paper["posture_mean_deg"], line_dash="dash", row=1, col=2, annotation_text="paper: about"
    )
    figure.update_layout(title="Verification experiment (paper Fig. 7)")
    return figure


def _uncertainty_figure(calibration: CalibrationResult):
    import plotly.graph_objects as go

    covariance = np.asarray(calibration.covariance["matrix"])
    names = calibration.covariance["parameters"]
    sd = np.sqrt(np.diag(covariance))
    shown = [s * (180.0 / np.pi if "_rad" in n else 1.0) for n, s in zip(names, sd)]
    labels = [n.replace("_rad", " (deg)").replace("_mm", " (mm)") for n in names]
    figure = go.Figure(go.Bar(x=labels, y=shown))
    tre = calibration.predicted_tre_mm or {}
    figure.update_layout(
        title=f"Uncertainty: parameter s.d.; predicted TRE {tre.get('site', float('nan')):.3f} mm "
        f"at the site, {tre.get('cube_rms', float('nan')):.3f} mm over the cube"
    )
    return figure


def _check_figure(history: list[CheckResult]):
    import plotly.graph_objects as go

    labels = [entry.checked_utc for entry in history]
    worst = [float(np.max(entry.tcp_error_mm)) for entry in history]
    colours = ["green" if entry.passed else "red" for entry in history]
    figure = go.Figure(go.Bar(x=labels, y=worst, marker_color=colours))
    if history:
        figure.add_hline(y=history[-1].threshold_mm, line_dash="dash", annotation_text="threshold")
    figure.update_layout(title="Calibration checks: worst TCP error per check (mm)")
    return figure


def build_report_html(report: Report) -> tuple[str, list[str]]:
    """The report page and the titles of the plots in it."""
    import plotly.io as pio

    sections, titles = [], []

    def add(title, figure):
        titles.append(title)
        div = pio.to_html(figure, full_html=False, include_plotlyjs=False, div_id=f"plot-{len(titles)}")
        sections.append(f"<h2>{html.escape(title)}</h2>\n{div}")

    calibration = report.calibration
    if report.recording is not None:
        add("Sweeps and fits", _sweep_figure(report))
        add("Residuals", _residual_figure(report))
    if report.verification is not None:
        add("Target errors", _verification_figure(report.verification))
    if calibration.covariance:
        add("Uncertainty", _uncertainty_figure(calibration))
    if report.check_history:
        add("Check history", _check_figure(report.check_history))
    summary = {
        "method": calibration.method,
        "sample_counts": calibration.sample_counts,
        "predicted_tre_mm": calibration.predicted_tre_mm,
        "verdict": calibration.diagnostics.get("verdict"),
        "tracker_from_base": np.round(calibration.tracker_from_base, 6).tolist(),
    }
    from plotly.offline import get_plotlyjs

    plotly_js = f'<script type="text/javascript">{get_plotlyjs()}</script>'  # embedded: works offline
    page = (
        f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>spacecal report</title></head>\n<body>\n"
        f"{ERROR_BANNER}\n{plotly_js}\n<h1>spacecal calibration report</h1>\n"
        f"<pre id='summary' style='white-space:pre-wrap'>{html.escape(json.dumps(summary, indent=2))}</pre>\n"
        + "\n".join(sections)
        + "\n</body></html>\n"
    )
    return page, titles


def write_report(
    report: Report, path: str | Path, png_dir: str | Path | None = None
) -> tuple[Path, list[str]]:
    """Write the HTML report (and, with ``png_dir``, PNG figures); returns the path and plot titles."""
    page, titles = build_report_html(report)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    if png_dir is not None and report.verification is not None:
        from spacecal.report.figures import plot_verification_errors

        plot_verification_errors(
            report.verification.position_error_mm,
            report.verification.posture_error_deg,
            Path(png_dir) / "verification_errors.png",
        )
    if png_dir is not None and report.recording is not None:
        from spacecal.report.figures import plot_residuals

        residuals = sample_residuals(
            report.recording, report.calibration.tracker_from_base, report.calibration.tcp_from_marker
        )
        plot_residuals(
            report.recording.time_s[residuals["rows"]],
            residuals["position_mm"],
            Path(png_dir) / "residuals.png",
        )
    return path, titles
