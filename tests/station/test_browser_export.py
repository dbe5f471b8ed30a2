"""A partial export, in a real browser (headless Chromium from Debian's package, driven by
Playwright): of three targets one cannot be written; the two that were written are listed,
the third's reason stands beside its own tick in an operator's words, and the ticks are as the
operator left them. With ``SPACECAL_STATION_SHOTS=DIR`` the page is saved there
(``29-export-partial.png``)."""

from __future__ import annotations

from tests.station.test_browser import calibrated_from_a_simulation, shot
from tests.station.test_browser_device_forms import beside


def test_a_partial_export_lists_what_was_written_and_says_why_beside_the_rest(served, page):
    work = calibrated_from_a_simulation(page, served, "UR10 bay 12")
    (work.folder / "plus_config.xml").mkdir()  # where the PLUS file goes: it cannot be written
    for box in ("slicer", "plus", "ros2_launch"):
        page.check(f"#export-form input[name={box}]")
    page.click("#export")
    page.wait_for_selector("#export-outcome")

    assert page.inner_text("#export-written") == "wrote tracker_from_base.tfm, tracker.launch.py"
    assert page.inner_text("#export-failed") == "1 of 3 not written: see beside it"
    why = page.inner_text("#export-plus-error")
    assert why.startswith("PLUS configuration (plus_config.xml) was not written: "), why
    assert "Errno" not in why and "--" not in why and str(work.folder) not in why, why
    # beside the PLUS tick, on its line, and nowhere else
    beside(page, "#export-form input[name=plus]", "#export-plus-error")
    assert page.locator("#export-form .field-error").count() == 1
    ticked = {
        box for box in ("slicer", "plus", "ros2_launch") if page.is_checked(f"#export-form input[name={box}]")
    }
    assert ticked == {"slicer", "plus", "ros2_launch"}  # as the operator left them
    listed = page.inner_text("#exported")
    assert "tracker_from_base.tfm" in listed and "tracker.launch.py" in listed and "plus_config" not in listed
    assert (work.folder / "tracker_from_base.tfm").is_file() and (work.folder / "tracker.launch.py").is_file()
    assert page.locator("#error").count() == 0  # no message of the page's own, far from the form
    shot(page, "29-export-partial")

    # the cause removed, the same ticks written again: all three, nothing said against them
    (work.folder / "plus_config.xml").rmdir()
    page.click("#export")
    page.wait_for_selector("#export-written")
    assert (
        page.inner_text("#export-written")
        == "wrote tracker_from_base.tfm, plus_config.xml, tracker.launch.py"
    )
    assert (
        page.locator("#export-failed").count() == 0 and page.locator("#export-form .field-error").count() == 0
    )
