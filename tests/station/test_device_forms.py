"""The home page's robot and tracker forms, spoken to through the app's test client on both
records: each bad value is refused by the check the command line uses, its message beside its
field in an operator's words with the values entered kept; a taken name is refused beside the
name; devices are edited (a confirmation issued before the edit moves nothing), retired when a
calibration names them and deleted when none does; the new calibration's lists start on the
device added last."""

from __future__ import annotations

import html
import re

import pytest

from .conftest import need

STATION = "http://127.0.0.1:8770"


@pytest.fixture
def station_client(tmp_path, record_url):
    """A station (not served) on the record, and a test client of it."""
    testclient = need("starlette.testclient")
    from spacecal.station.server import StationOptions, build

    station, application = build(StationOptions(data=str(tmp_path / "station"), record=record_url))
    try:
        yield station, testclient.TestClient(application, base_url=STATION)
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()


def field_error(page: str, form_id: str, field: str) -> str | None:
    """The message shown beside ``field`` of the form ``form_id``, as text (None: no message)."""
    found = re.search(
        rf'<span class="field-error" id="{form_id}-{field}-error"[^>]*>(.*?)</span>', page, re.S
    )
    return None if found is None else html.unescape(found.group(1))


def field_value(page: str, form_id: str, field: str) -> str:
    """The value ``field`` of the form ``form_id`` shows."""
    found = re.search(rf'<input id="{form_id}-{field}" name="{field}" value="([^"]*)"', page)
    assert found is not None, f"no field {field} in {form_id}"
    return html.unescape(found.group(1))


def cli_words(exc_type, call) -> str:
    """The message the command line's own check raises for the same value."""
    with pytest.raises(exc_type) as refused:
        call()
    return str(refused.value)


def assert_operator_words(message: str) -> None:
    """One line for a person: no option name, no Python message."""
    assert "\n" not in message and 0 < len(message) < 300, message
    assert "--" not in message and "could not convert" not in message and "float" not in message, message


def test_each_bad_value_is_refused_beside_its_field_in_the_command_lines_words(station_client):
    from spacecal.app.devices import DeviceSettings, check_tracker_rate_hz, validate_device_url
    from spacecal.core.errors import InvalidInputError

    station, web = station_client
    # the rate: -20, 0, 1e9 and abc; refused with the words the command line puts after its option
    for typed, number in (("-20", -20.0), ("0", 0.0), ("1e9", 1e9), ("abc", None)):
        page = web.post(
            "/devices", data={"kind": "tracker", "name": "Vicra OR-2", "url": "sim", "rate_hz": typed}
        )
        message = field_error(page.text, "add-tracker", "rate_hz")
        assert message is not None and "frame rate must be" in message, (typed, message)
        assert_operator_words(message)
        assert "from 1 to 1000 frames per second" in message and repr(typed) in message
        if number is not None:  # the command line's check: its option's name, then the same words
            cli = cli_words(InvalidInputError, lambda n=number: check_tracker_rate_hz(n))
            assert cli.startswith(
                "--tracker-rate-hz: the frame rate must be from 1 to 1000 frames per second"
            )
        # the values entered are kept, the other fields without a message
        assert field_value(page.text, "add-tracker", "rate_hz") == typed
        assert field_value(page.text, "add-tracker", "name") == "Vicra OR-2"
        assert field_error(page.text, "add-tracker", "name") is None
        assert page.url.fragment == "add-tracker"
    # a cleared address never becomes the simulated device
    page = web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "", "model": "UR10"})
    message = field_error(page.text, "add-robot", "url")
    assert message is not None and "give the robot's address" in message
    assert_operator_words(message)
    assert (
        field_value(page.text, "add-robot", "url") == ""
        and field_value(page.text, "add-robot", "model") == "UR10"
    )
    # an address the device parser refuses: its own words, beside the address
    for url in ("ur//host", "ur://", "ndi://x"):
        page = web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": url})
        expected = cli_words(InvalidInputError, lambda u=url: validate_device_url("robot", u))
        assert field_error(page.text, "add-robot", "url") == expected
        assert field_value(page.text, "add-robot", "url") == url
    # a model spacecal has no kinematics of: the command line's --robot-model words
    page = web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "sim", "model": "UR99"})
    message = field_error(page.text, "add-robot", "model")
    cli = cli_words(InvalidInputError, lambda: DeviceSettings(robot_model="UR99"))
    assert message is not None and cli == f"--robot-model: {message}" and "UR10e" in message
    # control characters in a name
    for name in ("bay\x011", "bay\u202e1", "bay\x7f"):
        page = web.post("/devices", data={"kind": "robot", "name": name, "url": "sim"})
        message = field_error(page.text, "add-robot", "name")
        assert message is not None and "holds U+" in message, message
        assert_operator_words(message)
    # two bad fields: a message beside each
    page = web.post("/devices", data={"kind": "tracker", "name": "", "url": "", "rate_hz": "fast"})
    assert all(field_error(page.text, "add-tracker", f) for f in ("name", "url", "rate_hz"))
    assert station.ledger.robots() == [] and station.ledger.trackers() == []


def test_a_taken_name_is_refused_beside_the_name(station_client):
    station, web = station_client
    added = web.post(
        "/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "sim"}, follow_redirects=False
    )
    assert added.status_code == 303
    page = web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "ur://10.0.0.2"})
    message = field_error(page.text, "add-robot", "name")
    assert message == "the record has a robot named 'UR10 bay 1' already: give this one another name"
    assert field_value(page.text, "add-robot", "url") == "ur://10.0.0.2"
    assert [(r["name"], r["url"]) for r in station.ledger.robots()] == [("UR10 bay 1", "sim")]


def test_an_edit_is_checked_and_a_confirmation_from_before_it_moves_nothing(station_client):
    station, web = station_client
    web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "sim"})
    web.post("/devices", data={"kind": "robot", "name": "UR10 bay 2", "url": "sim"})
    web.post("/devices", data={"kind": "tracker", "name": "Vicra", "url": "sim"})
    bay1 = station.ledger.robots()[0]["id"]
    web.post("/workspaces", data={"robot": str(bay1), "tracker": "1"})
    [work] = station.workspaces.values()
    web.post(f"/workspaces/{work.id}/step/dry-run")
    assert work.dry_run_ok
    page = web.get(f"/workspaces/{work.id}/confirm/acquire").text
    ticket = re.search(r'name="ticket" value="([^"]+)"', page).group(1)
    # a bad edit: refused beside its field, the values entered kept, nothing changed
    form_id = f"edit-robot-{bay1}"
    page = web.post(f"/devices/robot/{bay1}/edit", data={"name": "UR10 bay 2", "url": "ur://", "model": ""})
    assert "already" in field_error(page.text, form_id, "name")
    assert field_error(page.text, form_id, "url") == "device 'ur://' names no host"
    assert field_value(page.text, form_id, "url") == "ur://" and f'id="{form_id}"' in page.text
    assert station.ledger.robot(bay1)["name"] == "UR10 bay 1" and work.dry_run_ok
    # a good one: the record and the calibration in progress take it; its dry run is gone
    edited = web.post(
        f"/devices/robot/{bay1}/edit",
        data={"name": "UR10 OR-2", "url": "sim", "model": "UR10"},
        follow_redirects=False,
    )
    assert edited.status_code == 303
    assert (station.ledger.robot(bay1)["name"], station.ledger.robot(bay1)["model"]) == ("UR10 OR-2", "UR10")
    assert work.robot["name"] == "UR10 OR-2" and not work.dry_run_ok and work.findings is None
    assert field_value(web.get("/").text, form_id, "model") == "UR10"
    # the confirmation named the robot as it was: its ticket starts nothing
    refused = web.post(f"/workspaces/{work.id}/motion/acquire", data={"ticket": ticket})
    assert "the robot did not move" in refused.text and station.runs.get(1) is None
    # nor can an edit reach a device that is not in the record
    assert web.post("/devices/robot/99/edit", data={"name": "x", "url": "sim"}).status_code == 404
    assert web.post("/devices/arm/1/edit", data={"name": "x", "url": "sim"}).status_code == 404


def test_a_used_device_is_retired_never_deleted_and_an_unused_one_deleted(station_client):
    station, web = station_client
    for kind, name in (("robot", "UR10 bay 1"), ("robot", "spare"), ("tracker", "Vicra")):
        web.post("/devices", data={"kind": kind, "name": name, "url": "sim"})
    bay1, spare = (r["id"] for r in sorted(station.ledger.robots(), key=lambda r: r["id"]))
    web.post("/workspaces", data={"robot": str(bay1), "tracker": "1"})
    home = web.get("/").text
    assert f'action="{STATION}/devices/robot/{spare}/delete"' in home  # unused: offered
    assert f'action="{STATION}/devices/robot/{bay1}/delete"' not in home  # used: not offered
    # deleting the used one anyway: refused beside it, kept
    page = web.post(f"/devices/robot/{bay1}/delete")
    said = re.search(
        rf'id="robot-{bay1}".*?<p class="field-error device-error"[^>]*>(.*?)</p>', page.text, re.S
    )
    assert said is not None and "retire it instead" in html.unescape(said.group(1))
    assert page.url.fragment == f"edit-robot-{bay1}"
    assert bay1 in [r["id"] for r in station.ledger.robots()]
    # retired: kept in the record, shown as retired, offered for no new calibration
    web.post(f"/devices/robot/{bay1}/retire", data={"retired": "1"})
    home = web.get("/").text
    assert station.ledger.robot(bay1)["retired_utc"] is not None
    listed = re.search(rf'<li id="robot-{bay1}" class="device retired">.*?</li>', home, re.S)
    assert listed is not None and "retired " in listed.group(0)
    robots_offered = re.search(r'<select name="robot">(.*?)</select>', home, re.S).group(1)
    assert "UR10 bay 1" not in robots_offered and "spare" in robots_offered
    refused = web.post("/workspaces", data={"robot": str(bay1), "tracker": "1"})
    assert "is retired" in refused.text and len(station.workspaces) == 1
    # the calibration in progress keeps it; back in service, it is offered again
    web.post(f"/devices/robot/{bay1}/retire", data={"retired": "0"})
    assert "UR10 bay 1" in re.search(r'<select name="robot">(.*?)</select>', web.get("/").text, re.S).group(1)
    # the unused one is deleted
    deleted = web.post(f"/devices/robot/{spare}/delete", follow_redirects=False)
    assert deleted.status_code == 303 and [r["id"] for r in station.ledger.robots()] == [bay1]


def test_the_lists_start_on_the_device_added_last_whatever_its_name(station_client):
    station, web = station_client

    def selected() -> str:
        robots = re.search(r'<select name="robot">(.*?)</select>', web.get("/").text, re.S).group(1)
        return re.search(r'<option value="\d+" selected>([^<]*)</option>', robots).group(1)

    web.post("/devices", data={"kind": "robot", "name": "Mercury", "url": "sim"})
    assert selected() == "Mercury"
    web.post("/devices", data={"kind": "robot", "name": "Zeta", "url": "sim"})
    assert selected() == "Zeta"
    # a name that sorts first does not take the default from the one added after it
    web.post("/devices", data={"kind": "robot", "name": "Alpha", "url": "sim"})
    web.post("/devices", data={"kind": "robot", "name": "Beta", "url": "sim"})
    assert selected() == "Beta"
    # a refused one changes nothing; retiring another leaves it where it is
    web.post("/devices", data={"kind": "robot", "name": "Aaa", "url": ""})
    zeta = next(r["id"] for r in station.ledger.robots() if r["name"] == "Zeta")
    web.post(f"/devices/robot/{zeta}/retire")
    assert selected() == "Beta"


def test_no_page_of_another_origin_edits_retires_or_deletes_a_device(station_client):
    station, web = station_client
    web.post("/devices", data={"kind": "robot", "name": "UR10 bay 1", "url": "sim"})
    elsewhere = {"Origin": "http://evil.example", "Sec-Fetch-Site": "cross-site"}
    for action, data in (("edit", {"name": "x", "url": "ur://10.6.6.6"}), ("retire", {}), ("delete", {})):
        refused = web.post(f"/devices/robot/1/{action}", data=data, headers=elsewhere)
        assert refused.status_code == 403, action
    assert [(r["name"], r["url"], r["retired_utc"]) for r in station.ledger.robots()] == [
        ("UR10 bay 1", "sim", None)
    ]
