"""The device forms in a real browser (headless Chromium from Debian's package, driven by
Playwright): a refused value's message stands beside its field, on the field's line, with the
value entered still in it; a retired robot is shown as retired and offered for no new
calibration. With ``SPACECAL_STATION_SHOTS=DIR`` the page is saved there
(``20-device-forms.png``)."""

from __future__ import annotations

from tests.station.test_browser import shot


def beside(page, field: str, message: str) -> None:
    """The element ``message`` is to the right of ``field``, on its line (their boxes overlap
    in height), and both are shown."""
    box, said = page.locator(field).bounding_box(), page.locator(message).bounding_box()
    assert box is not None and said is not None, (field, message)
    assert said["x"] >= box["x"] + box["width"], (box, said)
    assert said["y"] < box["y"] + box["height"] and box["y"] < said["y"] + said["height"], (box, said)


def test_a_refused_value_is_said_beside_its_field(served, page):
    page.goto(served.url + "/")
    # two robots; the first one retired
    for name in ("UR10 bay 1", "UR5 spare"):
        page.fill("#add-robot input[name=name]", name)
        page.click("#add-robot button")
        page.wait_for_selector(f".device-name:text-is('{name}')")
    bay1 = next(r["id"] for r in served.station.ledger.robots() if r["name"] == "UR10 bay 1")
    page.click(f"#robot-{bay1} summary")
    page.click(f"#robot-{bay1} button.retire")
    page.wait_for_selector(f"#robot-{bay1}.retired")
    assert "retired" in page.inner_text(f"#robot-{bay1} .retired-tag")
    assert page.locator("select[name=robot] option").all_inner_texts() == ["UR5 spare"]
    # a tracker with a frame rate that is no number, and a cleared address
    page.fill("#add-tracker input[name=name]", "Vicra OR-2")
    page.fill("#add-tracker input[name=url]", "")
    page.fill("#add-tracker input[name=rate_hz]", "abc")
    page.click("#add-tracker button")
    page.wait_for_selector("#add-tracker-rate_hz-error")
    rate_said = page.inner_text("#add-tracker-rate_hz-error")
    assert rate_said == "the frame rate must be a number from 1 to 1000 frames per second, not 'abc'"
    assert page.inner_text("#add-tracker-url-error").startswith("give the tracker's address")
    beside(page, "#add-tracker-rate_hz", "#add-tracker-rate_hz-error")
    beside(page, "#add-tracker-url", "#add-tracker-url-error")
    # the values entered are kept; the page has no message of its own elsewhere
    assert page.input_value("#add-tracker-rate_hz") == "abc"
    assert page.input_value("#add-tracker-name") == "Vicra OR-2"
    assert page.locator("#error").count() == 0
    assert page.get_attribute("#add-tracker-rate_hz", "aria-invalid") == "true"
    assert served.station.ledger.trackers() == []
    # an edit refused the same way, beside the edit form's field
    spare = next(r["id"] for r in served.station.ledger.robots() if r["name"] == "UR5 spare")
    page.click(f"#robot-{spare} summary")
    page.fill(f"#edit-robot-{spare}-model", "UR99")
    page.click(f"#edit-robot-{spare} button[type=submit]")
    page.wait_for_selector(f"#edit-robot-{spare}-model-error")
    assert page.inner_text(f"#edit-robot-{spare}-model-error").startswith("unknown robot model 'UR99'")
    beside(page, f"#edit-robot-{spare}-model", f"#edit-robot-{spare}-model-error")
    assert page.input_value(f"#edit-robot-{spare}-model") == "UR99"
    page.fill("#add-tracker input[name=name]", "Vicra OR-2")
    page.fill("#add-tracker input[name=url]", "")
    page.fill("#add-tracker input[name=rate_hz]", "abc")
    page.click("#add-tracker button")
    page.wait_for_selector("#add-tracker-rate_hz-error")
    shot(page, "20-device-forms")
