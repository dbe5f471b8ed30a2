"""Figures in the style of the paper (PNG, matplotlib without a display)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spacecal.records.paper_reference import PAPER_VERIFICATION


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


def plot_verification_errors(
    position_error_mm,
    posture_error_deg,
    path: str | Path,
    paper_mean_mm: float = PAPER_VERIFICATION["position_mean_bound_mm"],
    paper_mean_deg: float = PAPER_VERIFICATION["posture_mean_deg"],
) -> Path:
    """The error curves of the paper's Fig. 7: (A) position deviation, (B) posture deviation.

    Parameters
    ----------
    position_error_mm, posture_error_deg : array_like, shape (N,)
        Per verification point.
    path : str or Path
        PNG file to write.
    """
    plt = _pyplot()
    position = np.asarray(position_error_mm)
    posture = np.asarray(posture_error_deg)
    points = np.arange(1, len(position) + 1)
    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    for ax, values, unit, paper, title in (
        (ax_a, position, "mm", paper_mean_mm, "(A) deviation of position"),
        (ax_b, posture, "deg", paper_mean_deg, "(B) deviation of posture"),
    ):
        ax.plot(points, values, "o-", color="tab:blue", label=f"spacecal (mean {values.mean():.2f} {unit})")
        ax.axhline(paper, color="tab:red", ls="--", label=f"paper mean {paper} {unit}")
        ax.set_xlabel("experimental point")
        ax.set_ylabel(f"error ({unit})")
        ax.set_title(title)
        ax.set_xticks(points)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return _save(fig, path)


def plot_phantom_errors(entry_error_mm, target_error_mm, direction_error_deg, path: str | Path) -> Path:
    """The paper's Fig. 9: (A) entry and target position errors, (B) puncture direction error."""
    plt = _pyplot()
    cases = np.arange(1, len(entry_error_mm) + 1)
    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    ax_a.plot(cases, entry_error_mm, "o-", label="entry")
    ax_a.plot(cases, target_error_mm, "s-", label="target (tumour)")
    ax_a.set_title("(A) position error of entry and target")
    ax_a.set_ylabel("error (mm)")
    ax_b.plot(cases, direction_error_deg, "o-", color="tab:green", label="direction")
    ax_b.set_title("(B) deviation of puncture direction")
    ax_b.set_ylabel("error (deg)")
    for ax in (ax_a, ax_b):
        ax.set_xlabel("case")
        ax.set_xticks(cases)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return _save(fig, path)


def plot_residuals(time_s, position_residual_mm, path: str | Path) -> Path:
    """Per-sample marker position residuals over time (PNG)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.2), constrained_layout=True)
    ax.plot(time_s, position_residual_mm, ".", ms=3)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("marker position residual (mm)")
    ax.grid(alpha=0.3)
    return _save(fig, path)
