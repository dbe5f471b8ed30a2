"""The trend page's figure: check errors over time, and their drift against each
calibration's expected error.

Every string of the figure that comes from the record (robot names, dates, hashes) goes
through :func:`plotly_text`: plotly.js reads its text as a small markup language, so a robot
named ``<a href="https://x">bay 1</a>`` would otherwise be drawn as a link.
"""

from __future__ import annotations

from typing import Any

from spacecal.core.text import sanitize_for_terminal
from spacecal.ledger import CalibrationRow, CheckRow

#: Longest piece of record text shown in the figure (a name is at most 200 characters).
FIGURE_TEXT_CHARS = 200
#: What plotly.js reads as markup in text, and the entity it shows as the character itself.
_PLOTLY_ENTITIES = {"&": "&amp;", "<": "&lt;", ">": "&gt;", "$": "&#36;"}


def plotly_text(text: object, limit: int = FIGURE_TEXT_CHARS) -> str:
    """``text`` as plotly.js shows it literally in a trace name, hover text or axis title.

    plotly.js (``src/lib/svg_text_utils.js``, ``convertToTspans``) splits text at every
    ``<...>``: ``<br>`` breaks the line, ``<b> <i> <em> <sup> <sub> <s> <u> <span style>``
    format it and ``<a href>`` makes a link; then it decodes the entities ``&lt; &gt; &amp;``
    (and ``&nbsp; &mu; &times; &plusmn; &deg;``, ``&#N;``, ``&#xH;``) once, and writes each
    piece as a text node. Text between two ``$`` is typeset as TeX where MathJax is loaded.
    So ``&`` (first), ``<`` and ``>`` become entities, which make no tag and decode to
    themselves, and ``$`` becomes ``&#36;``, which the TeX match does not see. Invisible and
    control characters are shown escaped and the text is cut to ``limit``
    (:func:`~spacecal.core.text.sanitize_for_terminal`), before escaping, so an entity is
    never cut in half.

    Parameters
    ----------
    text : object
        Anything (``str`` of it is shown).
    limit : int
        Most characters of ``text`` shown.

    Returns
    -------
    str
        ``"&lt;b&gt;bay 1&lt;/b&gt;"`` for ``"<b>bay 1</b>"``.
    """
    shown = sanitize_for_terminal(text, limit)
    return "".join(_PLOTLY_ENTITIES.get(character, character) for character in shown)


def trend_figure(calibrations: list[CalibrationRow], checks: list[CheckRow]) -> dict[str, Any]:
    """A plotly figure (as a dict): per calibration, its checks' largest TCP error (mm) over
    time and the calibration's expected error as a dashed line. Every text from the record is
    escaped (:func:`plotly_text`)."""
    by_id = {c.id: c for c in calibrations}
    data: list[dict[str, Any]] = []
    for calibration_id in sorted({k.calibration_id for k in checks}):
        mine = [k for k in checks if k.calibration_id == calibration_id]
        cal = by_id.get(calibration_id)
        label = (
            f"{plotly_text(cal.robot or 'robot ?')} {plotly_text(cal.created_utc[:16])} "
            f"({plotly_text(cal.content_sha256[:8])})"
            if cal
            else "?"
        )
        data.append(
            {
                "type": "scatter",
                "mode": "lines+markers",
                "name": f"check error: {label}",
                "x": [plotly_text(k.checked_utc) for k in mine],
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
                    "x": [
                        plotly_text(min(cal.created_utc, mine[0].checked_utc)),
                        plotly_text(mine[-1].checked_utc),
                    ],
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
