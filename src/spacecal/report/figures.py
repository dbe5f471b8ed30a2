"""PNG figures (matplotlib without a display): the paper's figures and every figure of the
HTML report, for papers, service records and pages that cannot run scripts.

Independent cases (verification targets, phantom cases, checks) are drawn as points, not
joined by lines: nothing lies between two targets. The paper reports its mean position error
as a bound ("< 1.05 mm"), so it is drawn as a bound, not as a measured mean.

Text that comes from files (segment labels, transform names of a covariance, check times) is
drawn as the characters it holds: every figure is made with matplotlib's mathtext parsing
off (a label ``$\\frac{x}$`` or ``$\\undefined$`` would otherwise be parsed as TeX, and an
unknown command raises), and a label starting with ``_`` is shown rather than dropped
from the legend.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import ParamSpec, TypeVar

import numpy as np

from spacecal.records import CalibrationResult, CheckResult, Recording
from spacecal.records.paper_reference import PAPER_PHANTOM, PAPER_VERIFICATION
from spacecal.report.evidence import check_series, fitted_sphere, sweeps, uncertainty

_P = ParamSpec("_P")
_R = TypeVar("_R")


def _text_as_text(plot: Callable[_P, _R]) -> Callable[_P, _R]:
    """Run ``plot`` with mathtext parsing off, so text from data never reaches the TeX parser.

    The setting is read when each Text is made, and tick labels are made when the figure is
    drawn, so the whole function, saving included, runs inside the context.
    """

    @functools.wraps(plot)
    def plain(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        import matplotlib

        with matplotlib.rc_context({"text.parse_math": False}):
            return plot(*args, **kwargs)

    return plain


def _label(text: object) -> str:
    """A legend label from data: matplotlib leaves out labels starting with ``_``."""
    text = str(text)
    return " " + text if text.startswith("_") else text


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    _pyplot().close(fig)
    return path


def _points_axis(ax, count: int, label: str) -> None:
    ax.set_xlabel(label)
    ax.set_xticks(np.arange(1, count + 1))
    ax.set_xlim(0.5, count + 0.5)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)


@_text_as_text
def plot_verification_errors(
    position_error_mm,
    posture_error_deg,
    path: str | Path,
    paper_mean_mm: float = PAPER_VERIFICATION["position_mean_bound_mm"],
    paper_mean_deg: float = PAPER_VERIFICATION["posture_mean_deg"],
) -> Path:
    """The verification errors of the paper's Fig. 7: (A) position, (B) posture, one point per
    target, with the paper's figures drawn as what they are.

    Parameters
    ----------
    position_error_mm, posture_error_deg : array_like, shape (N,)
        Per verification target.
    path : str or Path
        PNG file to write.
    paper_mean_mm : float
        The paper's bound on the mean position error ("< 1.05 mm").
    paper_mean_deg : float
        The paper's approximate mean posture error ("about 1.1 deg").
    """
    plt = _pyplot()
    position = np.asarray(position_error_mm, dtype=float)
    posture = np.asarray(posture_error_deg, dtype=float)
    targets = np.arange(1, len(position) + 1)
    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    panels = (
        (ax_a, position, "mm", "(A) deviation of position", f"paper: mean < {paper_mean_mm:g} mm (a bound)"),
        (ax_b, posture, "deg", "(B) deviation of posture", f"paper: mean about {paper_mean_deg:g} deg"),
    )
    for ax, values, unit, title, paper_label in panels:
        ax.plot(targets, values, "o", color="tab:blue", label="spacecal, per target")
        ax.axhline(values.mean(), color="tab:blue", lw=1, label=f"spacecal mean {values.mean():.2f} {unit}")
        paper = paper_mean_mm if unit == "mm" else paper_mean_deg
        ax.axhline(paper, color="tab:red", ls="--", label=paper_label)
        if unit == "mm":
            # a bound: the paper's mean lies somewhere below the line
            ax.axhspan(0, paper, color="tab:red", alpha=0.06)
        ax.set_ylabel(f"error ({unit})")
        ax.set_title(title)
        _points_axis(ax, len(values), "verification target")
        ax.set_ylim(0, max(values.max(), paper) * 1.25)
        ax.legend(fontsize=8, loc="upper right")
    return _save(fig, path)


@_text_as_text
def plot_phantom_errors(entry_error_mm, target_error_mm, direction_error_deg, path: str | Path) -> Path:
    """The paper's Fig. 9, one point per case: (A) entry and target position errors,
    (B) puncture direction error, with the paper's smallest errors (Table 2) for reference."""
    plt = _pyplot()
    entry = np.asarray(entry_error_mm, dtype=float)
    target = np.asarray(target_error_mm, dtype=float)
    direction = np.asarray(direction_error_deg, dtype=float)
    cases = np.arange(1, len(entry) + 1)
    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    ax_a.plot(cases - 0.08, entry, "o", label="entry")
    ax_a.plot(cases + 0.08, target, "s", label="target (tumour)")
    ax_a.axhline(
        PAPER_PHANTOM["entry_min_mm"], color="tab:blue", ls=":", lw=1, label="paper: smallest entry error"
    )
    ax_a.axhline(
        PAPER_PHANTOM["target_min_mm"], color="tab:orange", ls=":", lw=1, label="paper: smallest target error"
    )
    ax_a.set_title("(A) position error of entry and target")
    ax_a.set_ylabel("error (mm)")
    ax_b.plot(cases, direction, "o", color="tab:green", label="direction")
    ax_b.axhline(
        PAPER_PHANTOM["direction_min_deg"], color="tab:green", ls=":", lw=1, label="paper: smallest error"
    )
    ax_b.set_title("(B) deviation of puncture direction")
    ax_b.set_ylabel("error (deg)")
    for ax in (ax_a, ax_b):
        _points_axis(ax, len(cases), "case")
        ax.legend(fontsize=8)
    return _save(fig, path)


@_text_as_text
def plot_residuals(
    time_s, position_residual_mm, path: str | Path, rotation_residual_deg=None, segment=None
) -> Path:
    """Per-sample marker residuals over time, coloured by segment: position (mm) above and,
    when given, rotation (deg) below, each with its own axis."""
    plt = _pyplot()
    time_s = np.asarray(time_s, dtype=float)
    position = np.asarray(position_residual_mm, dtype=float)
    segment = np.full(len(time_s), "samples") if segment is None else np.asarray(segment).astype(str)
    panels = 1 if rotation_residual_deg is None else 2
    fig, axes = plt.subplots(
        panels, 1, figsize=(9, 2.6 * panels + 0.6), sharex=True, constrained_layout=True, squeeze=False
    )
    columns = [(position, "position residual (mm)")]
    if rotation_residual_deg is not None:
        columns.append((np.asarray(rotation_residual_deg, dtype=float), "rotation residual (deg)"))
    for ax, (values, label) in zip(axes[:, 0], columns):
        for name in dict.fromkeys(segment.tolist()):
            rows = segment == name
            ax.plot(time_s[rows], values[rows], ".", ms=3, label=_label(name))
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    axes[0, 0].set_title("Marker residuals: measured vs predicted marker pose")
    if len(set(segment.tolist())) > 1:
        axes[0, 0].legend(fontsize=7, ncol=6, markerscale=3, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    return _save(fig, path)


@_text_as_text
def plot_sweeps(recording: Recording, calibration: CalibrationResult, path: str | Path) -> Path:
    """The marker origin over the sweeps in the tracker frame (mm), with the fitted lines and
    sphere of the paper's method where it made them."""
    plt = _pyplot()
    fig = plt.figure(figsize=(7.5, 6.5), constrained_layout=True)
    ax = fig.add_subplot(projection="3d")
    everything = []
    for sweep in sweeps(recording, calibration):
        p = sweep.marker_in_tracker
        everything.append(p)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], ".", ms=2, label=_label(sweep.label))
        if sweep.line_in_tracker is not None:
            line = sweep.line_in_tracker
            ax.plot(line[:, 0], line[:, 1], line[:, 2], "-", color="k", lw=1)
    sphere = fitted_sphere(calibration)
    if sphere is not None:
        centre, radius = sphere
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
        ax.plot_wireframe(
            centre[0] + radius * np.cos(u) * np.sin(v),
            centre[1] + radius * np.sin(u) * np.sin(v),
            centre[2] + radius * np.cos(v),
            color="grey",
            lw=0.3,
            alpha=0.4,
        )
    if everything:
        points = np.concatenate(everything)
        ax.set_box_aspect(np.ptp(points, axis=0) + 1e-9)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title("Marker origin over the sweeps, tracker frame (lines: fits)")
    ax.legend(fontsize=7, markerscale=4, loc="upper left")
    return _save(fig, path)


@_text_as_text
def plot_uncertainty(calibration: CalibrationResult, path: str | Path) -> Path | None:
    """Standard deviations of both transforms: translations (mm) and rotations (deg) on their
    own axes. None when the calibration has no covariance."""
    split = uncertainty(calibration)
    if split is None:
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    x = np.arange(3)
    for ax, values, unit, title in (
        (axes[0], split.translation_sd_mm, "mm", "translation"),
        (axes[1], split.rotation_sd_deg, "deg", "rotation"),
    ):
        width = 0.8 / max(len(values), 1)
        for k, (name, sd) in enumerate(values.items()):
            ax.bar(x + (k - (len(values) - 1) / 2) * width, sd, width, label=_label(name))
        ax.set_xticks(x, [f"{title} {a}" for a in split.axes])
        ax.set_ylabel(f"standard deviation ({unit})")
        ax.set_title(f"{title.capitalize()}s ({unit})")
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=8)
    return _save(fig, path)


@_text_as_text
def plot_check_history(history: list[CheckResult], path: str | Path) -> Path | None:
    """Worst TCP and rotation error of each check over time, with the thresholds."""
    if not history:
        return None
    series = check_series(history)
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    x = series.when if series.dated else np.arange(1, len(series.when) + 1)
    colours = np.where(series.passed, "tab:green", "tab:red")
    for ax, values, threshold, unit, title in (
        (axes[0], series.worst_tcp_mm, series.threshold_mm, "mm", "worst TCP error"),
        (axes[1], series.worst_rotation_deg, series.threshold_deg, "deg", "worst rotation error"),
    ):
        ax.scatter(x, values, c=colours, zorder=3)
        ax.axhline(threshold, color="tab:red", ls="--", label=f"threshold {threshold:.2f} {unit}")
        ax.set_ylim(0, max(float(values.max()), threshold) * 1.25)
        ax.set_ylabel(f"{title} ({unit})")
        ax.set_title(f"Checks: {title}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        if series.dated:
            import datetime

            from matplotlib.dates import AutoDateLocator, DateFormatter

            # at least half a day either side: checks minutes apart read as one occasion
            first, last = min(series.when), max(series.when)
            pad = max(0.1 * (last - first), datetime.timedelta(hours=12))
            ax.set_xlim(first - pad, last + pad)
            ax.xaxis.set_major_locator(AutoDateLocator(maxticks=6))
            ax.xaxis.set_major_formatter(DateFormatter("%Y-%m-%d\n%H:%M"))
            ax.set_xlabel("check time (UTC)")
        else:
            ax.set_xticks(x, [str(t) for t in series.when], rotation=30, ha="right")
    return _save(fig, path)
