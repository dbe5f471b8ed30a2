"""The trend page's figure: check errors over time, and their drift against each
calibration's expected error."""

from __future__ import annotations

from typing import Any

from spacecal.ledger import CalibrationRow, CheckRow


def trend_figure(calibrations: list[CalibrationRow], checks: list[CheckRow]) -> dict[str, Any]:
    """A plotly figure (as a dict): per calibration, its checks' largest TCP error (mm) over
    time and the calibration's expected error as a dashed line."""
    by_id = {c.id: c for c in calibrations}
    data: list[dict[str, Any]] = []
    for calibration_id in sorted({k.calibration_id for k in checks}):
        mine = [k for k in checks if k.calibration_id == calibration_id]
        cal = by_id.get(calibration_id)
        label = f"{cal.robot or 'robot ?'} {cal.created_utc[:16]} ({cal.content_sha256[:8]})" if cal else "?"
        data.append(
            {
                "type": "scatter",
                "mode": "lines+markers",
                "name": f"check error: {label}",
                "x": [k.checked_utc for k in mine],
                "y": [k.max_tcp_error_mm for k in mine],
                "text": ["PASS" if k.passed else "FAIL" for k in mine],
            }
        )
        if cal is not None and cal.expected_error_mm is not None:
            data.append(
                {
                    "type": "scatter",
                    "mode": "lines",
                    "line": {"dash": "dash"},
                    "name": f"expected error: {label}",
                    # from the calibration's making to its last check, so one check shows it too
                    "x": [min(cal.created_utc, mine[0].checked_utc), mine[-1].checked_utc],
                    "y": [cal.expected_error_mm, cal.expected_error_mm],
                }
            )
    layout = {
        "margin": {"l": 60, "r": 10, "t": 40, "b": 50},
        "xaxis": {"title": {"text": "checked (UTC)"}},
        "yaxis": {"title": {"text": "largest TCP error of the check (mm)"}, "rangemode": "tozero"},
        "legend": {"orientation": "h", "y": 1.15},
    }
    return {"data": data, "layout": layout}
