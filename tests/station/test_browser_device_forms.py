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


#: Every kind of bad value the forms refuse, typed into the page: (form, field, value, what
#: the message beside the field says). The command line's own words for each are checked
#: through the app's client (test_device_forms.py); here, that the operator sees them there.
BAD_VALUES = (
    ("add-tracker", "rate_hz", "-20", "the frame rate must be"),
    ("add-tracker", "rate_hz", "0", "the frame rate must be"),
    ("add-tracker", "rate_hz", "1e9", "the frame rate must be"),
    ("add-tracker", "rate_hz", "abc", "the frame rate must be a number from 1 to 1000"),
    ("add-tracker", "url", "", "give the tracker's address"),
    ("add-robot", "url", "", "give the robot's address"),
    ("add-robot", "url", "ur//host", "ur//host"),
    ("add-robot", "url", "ur://", "ur://"),
    ("add-robot", "url", "ndi://x", "ndi://x"),
    ("add-robot", "model", "UR99", "unknown robot model 'UR99'"),
    ("add-robot", "name", "bay\u202e1", "holds U+202E"),
    ("add-robot", "name", "", "give"),
)


def test_every_bad_value_is_said_beside_its_field_in_the_page(served, page):
    page.goto(served.url + "/")
    for form, field, typed, said in BAD_VALUES:
        kind = form.removeprefix("add-")
        good = {"name": f"{kind} OR-2", "url": "sim"} | (
            {"rate_hz": "20"} if kind == "tracker" else {"model": ""}
        )
        for name, value in (good | {field: typed}).items():
            page.fill(f"#{form} input[name={name}]", value)
        page.click(f"#{form} button")
        message = f"#{form}-{field}-error"
        page.wait_for_selector(message)
        assert said in page.inner_text(message), (field, typed, page.inner_text(message))
        beside(page, f"#{form}-{field}", message)
        assert page.input_value(f"#{form}-{field}") == typed  # the value entered is kept
        assert page.get_attribute(f"#{form}-{field}", "aria-invalid") == "true"
        assert page.locator(".field-error").count() == 1, (field, typed)  # beside that field only
    assert served.station.ledger.robots() == [] and served.station.ledger.trackers() == []
    # a taken name: refused beside the name, the first device kept
    for _ in range(2):
        for name, value in (("name", "UR10 bay 1"), ("url", "sim"), ("model", "")):
            page.fill(f"#add-robot input[name={name}]", value)
        page.click("#add-robot button")
    page.wait_for_selector("#add-robot-name-error")
    assert "UR10 bay 1" in page.inner_text("#add-robot-name-error")
    beside(page, "#add-robot-name", "#add-robot-name-error")
    assert [r["name"] for r in served.station.ledger.robots()] == ["UR10 bay 1"]
