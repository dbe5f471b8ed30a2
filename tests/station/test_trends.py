"""The trend page's figure (:mod:`spacecal.station.trends`): text from the record is shown by
plotly.js as text, never as its markup (links, bold, line breaks, TeX)."""

from __future__ import annotations

import json
import re

import pytest

from tests.station.conftest import need

#: Names that plotly.js would read as markup or entities, and plain ones.
HOSTILE = [
    '<a href="https://example.invalid/x">bay 1</a>',
    "<b>UR10</b><br>second line",
    "<i>x</i><sup>2</sup><sub>3</sub><em>e</em><s>s</s><u>u</u>",
    '<span style="font-size:80px;fill:red">big</span>',
    "a &lt;b&gt; &amp;amp; &#60;b&#62; &#x3C;i&#x3E; &nbsp; &mu; &deg;",
    "$\\alpha$ and $x^2$",
    "<script>alert(1)</script>",
    "<<b>>",
    "bay <1> & 2",
    "UR10 bay 1",
    "é中 bay",
]


def _rows(robot: str):
    from spacecal.ledger import CalibrationRow, CheckRow

    calibration = CalibrationRow(
        1, "ab" * 32, "/x/cal.json", robot, "tracker", "ml", "good", 0.5, "2024-05-01T10:00:00+00:00", "cli"
    )
    check = CheckRow(7, 1, "ab" * 32, robot, "2024-05-02T10:00:00+00:00", True, 0.4, 0.1, 1.0, 0.5, "cli")
    return [calibration], [check]


def test_plotly_text_escapes_what_plotly_reads_as_markup():
    need("sqlalchemy")
    from spacecal.station.trends import plotly_text

    assert plotly_text("<b>bay 1</b>") == "&lt;b&gt;bay 1&lt;/b&gt;"
    assert plotly_text("a & b") == "a &amp; b"
    assert plotly_text("&lt;") == "&amp;lt;"  # an entity in a name stays those characters
    assert plotly_text("$x$") == "&#36;x&#36;"
    assert plotly_text("UR10 bay 1") == "UR10 bay 1"
    assert plotly_text("bay\u202e1\n") == "bay\\u202e1\\n"  # invisible characters shown, one line
    assert plotly_text("<" * 500) == "&lt;" * 197 + "..."  # cut before escaping: no entity cut in half
    for name in HOSTILE:
        assert not set("<>$") & set(plotly_text(name))


def test_every_record_text_in_the_figure_is_escaped():
    need("sqlalchemy")
    from spacecal.station.trends import plotly_text, trend_figure

    name = HOSTILE[0]
    figure = trend_figure(*_rows(name))
    names = [trace["name"] for trace in figure["data"]]
    assert names == [
        f"check error: {plotly_text(name)} 2024-05-01T10:00 (abababab)",
        f"expected error: {plotly_text(name)} 2024-05-01T10:00 (abababab)",
    ]
    text = json.dumps(figure)
    assert "<" not in text and ">" not in text


def _render(page, figure) -> dict:
    """Draw ``figure`` with the plotly.js the station serves; what the legend and the hover
    label show, and the markup elements plotly.js made."""
    from plotly.offline import get_plotlyjs

    page.set_content(
        '<!doctype html><html><body><div id="plot" style="width:900px;height:500px"></div></body></html>'
    )
    page.add_script_tag(content=get_plotlyjs())
    page.evaluate("figure => Plotly.newPlot('plot', figure.data, figure.layout)", figure)
    # the check's point hovered (plotly's own hover call: a mouse would hit the drag layer)
    page.evaluate("() => Plotly.Fx.hover('plot', [{curveNumber: 0, pointNumber: 0}])")
    page.wait_for_selector(".hoverlayer .hovertext", timeout=30_000)
    return page.evaluate(
        """() => {
            const plot = document.getElementById('plot');
            const texts = s => [...plot.querySelectorAll(s)].map(e => e.textContent);
            return {
                legend: texts('.legendtext'),
                hover: texts('.hoverlayer .hovertext .name'),
                links: plot.querySelectorAll('svg a').length,
                styled: [...plot.querySelectorAll('.legendtext tspan, .hovertext tspan')]
                    .filter(e => e.getAttribute('style')).length,
                lines: plot.querySelectorAll('.legendtext tspan.line').length,
            };
        }"""
    )


@pytest.mark.parametrize("name", HOSTILE)
def test_plotly_js_shows_a_hostile_robot_name_as_text(page, name):
    need("sqlalchemy")
    from spacecal.station.trends import trend_figure

    shown = _render(page, trend_figure(*_rows(name)))
    label = f"{name} 2024-05-01T10:00 (abababab)"
    assert shown["legend"] == [f"check error: {label}", f"expected error: {label}"]
    # plotly cuts a long hover name with "..."; what it shows is the start of the name, as text
    assert len(shown["hover"]) == 1 and f"check error: {label}".startswith(shown["hover"][0].rstrip("."))
    assert shown["links"] == 0 and shown["styled"] == 0 and shown["lines"] == 0


def test_plotly_js_would_draw_the_markup_of_an_unescaped_name(page):
    """The check above could fail: the same figure with the raw name makes a link, bold text
    and a second line."""
    need("sqlalchemy")
    from spacecal.station.trends import trend_figure

    figure = trend_figure(*_rows("x"))
    for trace in figure["data"]:
        trace["name"] = '<a href="https://example.invalid/x">bay</a> <b>1</b><br>2'
    shown = _render(page, figure)
    assert shown["links"] >= 2 and shown["styled"] >= 2 and shown["lines"] >= 2


def test_the_record_links_each_calibration_to_its_workspace_file_and_report(simulated_workspace):
    """The trend tables link a calibration still open at the station to its workspace, its file
    and its report, and the home list shows each workspace's verdict."""
    from tests.station.test_acquire_again import calibrated_at_the_station

    station, web = simulated_workspace
    work = calibrated_at_the_station(station, web)
    web.post("/workspaces/1/step/report")
    headline = work.calibration.record.verdict.headline
    trends = web.get("/trends").text
    calibrations = trends[trends.index('id="calibrations"') : trends.index('id="checks"')]
    assert re.search(r'class="calibration-link" href="[^"]*/workspaces/1"', calibrations)
    assert re.search(r'href="[^"]*/workspaces/1/files/calibration.json"', calibrations)
    assert re.search(r'class="report-link" href="[^"]*/workspaces/1/files/report.html"', calibrations)
    assert web.get("/workspaces/1/files/report.html").status_code == 200
    home = web.get("/").text
    assert f'data-grade="{work.calibration.record.verdict.grade}">{headline}</span>' in home
