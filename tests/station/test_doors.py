"""The station's doors without a browser: which requests may change anything, the token's ways
in, the files it serves, the answers it gives to bad addresses, and its bounds.

Each refusal is asserted on what it must prevent (nothing added, no ticket, no run), not only on
its status. The same attacks from real pages of other origins, in Chromium, are in
``test_browser_foreign_pages.py``.
"""

from __future__ import annotations

import re
import socket
import stat
import subprocess
import sys
import threading
import time

import pytest

from spacecal.core.errors import InvalidInputError, RecordError
from tests.idle_connections import closed_by_the_server
from tests.station.conftest import free_port, need

STATION = "http://127.0.0.1:8770"
#: The live view's socket of run 1, named in full: the test client's websockets otherwise go to
#: host "testserver", which the loopback door refuses (421) before the origin is looked at.
LIVE_VIEW = "ws://127.0.0.1:8770/runs/1/ws"
#: What a browser sends with a form of the station's own page.
OWN_PAGE = {"Origin": STATION, "Sec-Fetch-Site": "same-origin", "Sec-Fetch-Mode": "navigate"}


def client(tmp_path, token=None, host="127.0.0.1"):
    testclient = need("starlette.testclient")
    from spacecal.station.server import StationOptions, build

    station, application = build(StationOptions(host=host, token=token, data=str(tmp_path / "station")))
    return station, testclient.TestClient(application, base_url=f"http://{host}:8770")


@pytest.fixture
def station_client(tmp_path):
    station, web = client(tmp_path)
    try:
        yield station, web
    finally:
        station.runs.stop_all("the test ended")
        station.ledger.close()


def new_devices(web) -> None:
    """A simulated robot and tracker, added at the station's own page."""
    for kind, name in (("robot", "r"), ("tracker", "t")):
        web.post("/devices", data={"kind": kind, "name": name, "url": "sim"}, headers=OWN_PAGE)


def new_calibration(web) -> None:
    """The devices and a calibration of them (workspace 1), at the station's own page."""
    new_devices(web)
    web.post("/workspaces", data={"robot": "1", "tracker": "1"}, headers=OWN_PAGE)


def add_robot(web, headers, name="r"):
    return web.post(
        "/devices",
        data={"kind": "robot", "name": name, "url": "sim"},
        headers=headers,
        follow_redirects=False,
    )


FOREIGN_HEADERS = {
    "a sandboxed frame (Origin: null)": {"Origin": "null"},
    "another address": {"Origin": "http://127.0.0.2:8000", "Sec-Fetch-Site": "cross-site"},
    "another port of the same host": {"Origin": "http://127.0.0.1:8000", "Sec-Fetch-Site": "same-site"},
    "another site": {"Origin": "http://evil.example", "Sec-Fetch-Site": "cross-site"},
    "a browser that names no origin but another site": {"Sec-Fetch-Site": "cross-site"},
    "the station's origin on another scheme": {"Origin": "https://127.0.0.1:8770"},
}


@pytest.mark.parametrize("who", FOREIGN_HEADERS)
def test_no_form_of_another_origin_changes_anything(station_client, who):
    station, web = station_client
    headers = FOREIGN_HEADERS[who]
    refused = add_robot(web, headers)
    assert refused.status_code == 403 and station.ledger.robots() == []
    assert "refused" in refused.text and "<h1>Forbidden</h1>" in refused.text  # a page, styled
    # the station's own page: added
    assert add_robot(web, OWN_PAGE).status_code == 303 and len(station.ledger.robots()) == 1
    web.post("/devices", data={"kind": "tracker", "name": "t", "url": "sim"}, headers=OWN_PAGE)
    # nor a calibration, a plan, a dry run or a stop
    assert web.post("/workspaces", data={"robot": "1", "tracker": "1"}, headers=headers).status_code == 403
    assert station.workspaces == {}
    web.post("/workspaces", data={"robot": "1", "tracker": "1"}, headers=OWN_PAGE)
    work = station.workspaces[1]
    for step in ("plan", "dry-run"):
        assert web.post(f"/workspaces/1/step/{step}", headers=headers).status_code == 403
    assert work.plan_summary is None and not work.dry_run_ok


@pytest.mark.parametrize("who", FOREIGN_HEADERS)
def test_no_page_of_another_origin_confirms_starts_or_watches_a_motion(station_client, who):
    websockets = need("starlette.websockets")
    station, web = station_client
    headers = FOREIGN_HEADERS[who]
    new_calibration(web)
    web.post("/workspaces/1/step/dry-run", headers=OWN_PAGE)
    assert station.workspaces[1].dry_run_ok
    # a foreign page's frame or fetch of the confirmation gets no ticket
    frame = {**headers, "Sec-Fetch-Dest": "iframe", "Sec-Fetch-Mode": "navigate"}
    framed = web.get(
        "/workspaces/1/confirm/acquire", headers={k: v for k, v in frame.items() if k != "Origin"}
    )
    if "Sec-Fetch-Site" in headers:
        assert framed.status_code == 403 and 'name="ticket"' not in framed.text
    assert len(station.tickets) == (0 if "Sec-Fetch-Site" in headers else 1)
    # a ticket the station's own page got is of no use to a foreign page
    page = web.get("/workspaces/1/confirm/acquire", headers={"Sec-Fetch-Site": "same-origin"}).text
    ticket = re.search(r'name="ticket" value="([^"]+)"', page).group(1)
    started = web.post(
        "/workspaces/1/motion/acquire", data={"ticket": ticket}, headers=headers, follow_redirects=False
    )
    assert started.status_code == 403 and station.runs.get(1) is None
    # the station's own page starts it; a foreign socket can neither watch it nor keep it alive
    started = web.post(
        "/workspaces/1/motion/acquire", data={"ticket": ticket}, headers=OWN_PAGE, follow_redirects=False
    )
    assert started.status_code == 303
    run = station.runs.get(1)
    with pytest.raises(websockets.WebSocketDisconnect) as refused:
        with web.websocket_connect(LIVE_VIEW, headers=headers) as socket_:
            socket_.receive_text()
    assert refused.value.code == 1008 and "refused" in refused.value.reason  # by its origin
    assert run.watchers == 0 and run.first_frame_at is None
    run.request_stop("the test ended")
    run.thread.join(timeout=120)
    assert run.state == "stopped" and run.samples == 0


def test_a_websocket_must_name_the_stations_origin(station_client):
    websockets = need("starlette.websockets")
    station, web = station_client
    for headers in ({}, {"Origin": "null"}, {"Origin": "http://127.0.0.1:8000"}):
        with pytest.raises(websockets.WebSocketDisconnect) as refused:
            with web.websocket_connect(LIVE_VIEW, headers=headers) as socket_:
                socket_.receive_text()
        assert refused.value.code == 1008 and "refused" in refused.value.reason, headers


def test_a_link_from_another_site_opens_only_pages_that_start_nothing(station_client):
    station, web = station_client
    link = {"Sec-Fetch-Site": "cross-site", "Sec-Fetch-Mode": "navigate", "Sec-Fetch-Dest": "document"}
    assert web.get("/", headers=link).status_code == 200
    assert web.get("/trends", headers=link).status_code == 200
    assert web.get("/workspaces/1/confirm/acquire", headers=link).status_code == 403
    # a page of another site cannot put words on the station's pages either
    page = web.get("/?error=the+robot+is+safe:+call+555&note=made-up", headers=link).text
    assert "555" not in page and 'id="error"' not in page


def test_every_response_forbids_framing_and_foreign_scripts(station_client):
    station, web = station_client
    for path in ("/", "/trends", "/static/station.js", "/workspaces/99", "/nowhere"):
        response = web.get(path)
        policy = response.headers["content-security-policy"]
        assert "frame-ancestors 'none'" in policy and "script-src 'self'" in policy, path
        assert "unsafe-inline" not in policy.split("script-src")[1].split(";")[0], path
        assert response.headers["x-frame-options"] == "DENY", path
        assert response.headers["x-content-type-options"] == "nosniff", path
    refused = add_robot(web, {"Origin": "null"})
    assert refused.headers["x-frame-options"] == "DENY"
    # the trend figure is data, not a script (no inline script on any page)
    assert "var FIGURE" not in web.get("/trends").text


def test_the_token_by_file_or_environment_never_on_the_command_line(tmp_path):
    need("starlette")
    from spacecal.station.access import TOKEN_ENVIRONMENT, load_token

    made = tmp_path / "token"
    token = load_token(str(made))
    assert len(token) >= 32 and made.read_text().strip() == token
    assert stat.S_IMODE(made.stat().st_mode) == 0o600
    assert load_token(str(made)) == token  # read back
    made.chmod(0o640)
    with pytest.raises(InvalidInputError, match="may be read by other users"):
        load_token(str(made))
    short = tmp_path / "short"
    short.write_text("abc\n")
    short.chmod(0o600)
    with pytest.raises(InvalidInputError, match="16 to 256"):
        load_token(str(short))
    assert load_token(None, {TOKEN_ENVIRONMENT: "x" * 20}) == "x" * 20
    assert load_token(None, {}) is None
    with pytest.raises(InvalidInputError, match="printable ASCII"):
        load_token(None, {TOKEN_ENVIRONMENT: "a token with spaces in it"})


def test_a_served_station_shows_its_token_nowhere_in_the_process_list(tmp_path):
    need("uvicorn")
    token_file = tmp_path / "token"
    port = free_port()
    command = [
        sys.executable,
        "-m",
        "spacecal",
        "station",
        "--port",
        str(port),
        "--data",
        str(tmp_path / "d"),
    ]
    process = subprocess.Popen(
        [*command, "--token-file", str(token_file)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        printed = process.stdout.readline()
        token = token_file.read_text().strip()
        assert f"http://localhost:{port}/" in printed and token not in printed
        cmdline = open(f"/proc/{process.pid}/cmdline", "rb").read().decode()
        assert token not in cmdline and str(token_file) in cmdline
    finally:
        process.terminate()
        process.communicate(timeout=60)


def test_a_token_in_the_address_is_swapped_for_a_cookie_and_the_address_cleaned(tmp_path):
    token = "a-long-enough-token-1234"
    station, web = client(tmp_path, token=token)
    try:
        # without it, on loopback too: a sign-in page, and nothing changes
        first = web.get("/")
        assert first.status_code == 401 and 'id="sign-in"' in first.text
        assert add_robot(web, OWN_PAGE).status_code == 401 and station.ledger.robots() == []
        handed = web.get(f"/trends?token={token}")
        assert handed.status_code == 200 and token not in handed.text
        assert 'content="0; url=/trends"' in handed.text  # on to the address without the token
        cookie = handed.headers["set-cookie"]
        assert (
            "HttpOnly" in cookie and "SameSite=Strict" in cookie and "spacecal_station_token_8770=" in cookie
        )
        # the cookie goes to every port of this host: it holds a session key, not the token
        assert token not in cookie
        session = web.cookies["spacecal_station_token_8770"]
        assert len(session) >= 32
        assert handed.headers["cache-control"] == "no-store"
        assert web.get("/trends").status_code == 200
        assert add_robot(web, OWN_PAGE).status_code == 303
        # the token itself, or a made-up key, in the cookie opens nothing
        for value in (token, session[:-1] + ("A" if session[-1] != "A" else "B")):
            web.cookies.clear()
            web.cookies.set("spacecal_station_token_8770", value)
            assert web.get("/trends").status_code == 401
        web.cookies.clear()
        web.cookies.set("spacecal_station_token_8770", session)
        assert web.get("/trends").status_code == 200
        # a session lives as long as the station's process: a new one refuses its cookie
        restarted, again = client(tmp_path / "again", token=token)
        try:
            again.cookies.set("spacecal_station_token_8770", session)
            assert again.get("/trends").status_code == 401
        finally:
            restarted.ledger.close()
        # a wrong token in the address sets nothing
        web.cookies.clear()
        assert web.get("/?token=wrong-token-wrong-token").status_code == 401
        assert web.get("/").status_code == 401
        # the sign-in form: same-origin only, like every form
        assert web.post("/sign-in", data={"token": token}, headers={"Origin": "null"}).status_code == 403
        wrong = web.post("/sign-in", data={"token": "nope"}, headers=OWN_PAGE, follow_redirects=False)
        assert wrong.status_code == 401 and "set-cookie" not in wrong.headers
        signed = web.post("/sign-in", data={"token": token}, headers=OWN_PAGE, follow_redirects=False)
        assert signed.status_code == 303 and signed.headers["location"] == "/"
        assert web.get("/").status_code == 200
    finally:
        station.ledger.close()


def test_files_stay_inside_the_calibrations_folder(station_client, tmp_path):
    station, web = station_client
    new_calibration(web)
    folder = station.workspaces[1].folder
    (folder / "passwd").symlink_to("/etc/passwd")
    (folder / "record.db").symlink_to(station.data / "record.db")
    (folder / "sub").mkdir()
    (folder / "sub" / "x.txt").write_text("x")
    for name in ("passwd", "record.db", "sub", ".hidden", "a" * 300, "sub%2Fx.txt", "%2e%2e"):
        response = web.get(f"/workspaces/1/files/{name}")
        assert response.status_code == 404 and "root:" not in response.text, name
        assert "<h1>Not Found</h1>" in response.text
    (folder / "report.html").write_text("<script>fetch('/devices', {method: 'POST'})</script>")
    served = web.get("/workspaces/1/files/report.html")
    assert served.status_code == 200
    policy = served.headers["content-security-policy"]
    assert policy.startswith("sandbox allow-scripts") and "allow-same-origin" not in policy
    assert "frame-ancestors 'none'" in policy


@pytest.mark.parametrize(
    "method, path",
    [
        ("GET", "/workspaces/7"),
        ("POST", "/workspaces/7/step/plan"),
        ("POST", "/workspaces/7/export"),
        ("GET", "/workspaces/7/files/report.html"),
        ("GET", "/workspaces/7/confirm/acquire"),
        ("POST", "/workspaces/7/motion/acquire"),
        ("GET", "/runs/7"),
        ("POST", "/runs/7/stop"),
        ("GET", "/workspaces/" + "9" * 5000),
        ("GET", "/runs/" + "9" * 5000),
        ("POST", "/workspaces/1/step/unknown"),
        ("GET", "/static/" + "x" * 300),
        ("GET", "/workspaces/1/confirm/" + "x" * 300),
    ],
)
def test_an_unknown_address_is_a_page_saying_so_never_a_500(station_client, method, path):
    station, web = station_client
    new_calibration(web)
    response = web.request(method, path, headers=OWN_PAGE)
    assert response.status_code == 404, response.text[:300]
    assert "<h1>Not Found</h1>" in response.text and 'id="error"' in response.text
    assert "Traceback" not in response.text


def test_a_record_that_cannot_be_written_is_never_shown_as_done(station_client, monkeypatch):
    from spacecal.station import web as station_web

    station, web = station_client
    new_calibration(web)
    work = station.workspaces[1]
    from spacecal import app

    app.simulate(app.SimulateSettings(output=str(work.recording_path), force=True))

    def locked(*args, **kwargs):
        raise RecordError("the record could not be written: database is locked")

    monkeypatch.setattr(station_web.spacecal_app, "record_calibration", locked)
    page = web.post("/workspaces/1/step/calibrate", data={"method": "ml"}, headers=OWN_PAGE).text
    assert "calibration.json was written but not recorded" in page and "database is locked" in page
    assert 'id="calibrate-result"' not in page and 'id="verdict"' not in page and 'id="check"' not in page
    assert work.calibration is None and work.calibration_record_id is None

    def unreadable(*args, **kwargs):
        raise RecordError("the record could not be read: database is locked")

    monkeypatch.setattr(station.ledger, "robots", unreadable)
    home = web.get("/")
    assert home.status_code == 503 and "the record could not be read: database is locked" in home.text
    assert "<h1>Service Unavailable</h1>" in home.text


def test_confirmations_are_purged_and_capped(station_client):
    from spacecal.station.motions import MAX_OPEN_TICKETS, TICKET_LIFETIME_S

    station, web = station_client
    keys = [station.tickets.issue(1, "r", "acquire", "basis") for _ in range(10 * MAX_OPEN_TICKETS)]
    assert len(station.tickets) == MAX_OPEN_TICKETS
    assert station.tickets.redeem(keys[0], 1, "acquire", "basis") is None  # the oldest went first
    assert station.tickets.redeem(keys[-1], 1, "acquire", "basis") is not None
    # an expired one is dropped at the next issue
    station.tickets._open[keys[-2]] = station.tickets._open[keys[-2]].__class__(
        1, "r", "acquire", "basis", time.monotonic() - TICKET_LIFETIME_S - 1
    )
    station.tickets.issue(1, "r", "acquire", "basis")
    assert keys[-2] not in station.tickets._open


def test_new_calibrations_are_rate_limited(station_client):
    from spacecal.station.web import NEW_WORKSPACES_PER_WINDOW

    station, web = station_client
    new_devices(web)
    for _ in range(NEW_WORKSPACES_PER_WINDOW + 5):
        last = web.post("/workspaces", data={"robot": "1", "tracker": "1"}, headers=OWN_PAGE)
    assert len(station.workspaces) == NEW_WORKSPACES_PER_WINDOW
    assert "new calibrations a minute" in last.text
    assert len(list(station.data.iterdir())) == NEW_WORKSPACES_PER_WINDOW + 1  # and the record


def test_a_large_body_is_refused_before_it_is_read(station_client):
    station, web = station_client
    response = web.post(
        "/devices", data={"kind": "robot", "name": "r" * 100_000, "url": "sim"}, headers=OWN_PAGE
    )
    assert response.status_code == 413 and station.ledger.robots() == []


def test_a_failed_or_repeated_dry_run_leaves_no_confirmation_standing(station_client, monkeypatch):
    from spacecal.core.errors import DeviceError
    from spacecal.station import workspace as station_workspace

    station, web = station_client
    new_calibration(web)
    work = station.workspaces[1]
    web.post("/workspaces/1/step/plan", headers=OWN_PAGE)
    web.post("/workspaces/1/step/dry-run", headers=OWN_PAGE)
    assert work.dry_run_ok

    def ticket() -> str:
        page = web.get("/workspaces/1/confirm/acquire", headers={"Sec-Fetch-Site": "same-origin"}).text
        return re.search(r'name="ticket" value="([^"]+)"', page).group(1)

    def start(key: str):
        return web.post("/workspaces/1/motion/acquire", data={"ticket": key}, headers=OWN_PAGE)

    # a ticket of an earlier dry run is refused after a dry run that raised
    earlier = ticket()
    real_acquire = station_workspace.app.acquire

    def failing(settings):
        raise DeviceError("the tracker did not answer")

    monkeypatch.setattr(station_workspace.app, "acquire", failing)
    page = web.post("/workspaces/1/step/dry-run", headers=OWN_PAGE).text
    assert "the tracker did not answer" in page and 'id="acquire"' not in page and not work.dry_run_ok
    assert "the robot did not move" in start(earlier).text and station.runs.get(1) is None
    monkeypatch.setattr(station_workspace.app, "acquire", real_acquire)
    # and after a dry run run again (another dry run's confirmation), or a plan changed since
    web.post("/workspaces/1/step/dry-run", headers=OWN_PAGE)
    older = ticket()
    web.post("/workspaces/1/step/dry-run", headers=OWN_PAGE)
    assert "the robot did not move" in start(older).text
    changed = ticket()
    work.plan_path.write_bytes(work.plan_path.read_bytes() + b" ")
    assert "the robot did not move" in start(changed).text and station.runs.get(1) is None
    assert 'id="acquire"' not in web.get("/workspaces/1").text


def test_a_slow_or_idle_connection_is_closed_and_the_station_keeps_answering(tmp_path, monkeypatch):
    uvicorn = need("uvicorn")
    from spacecal.station import limits
    from spacecal.station.server import StationOptions, build, server_config

    monkeypatch.setattr(limits.HeaderDeadlineProtocol, "header_timeout_s", 2.0)
    port = free_port()
    station, application = build(StationOptions(port=port, data=str(tmp_path / "station")))
    server = uvicorn.Server(server_config(application, "127.0.0.1", port))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    idle: list[socket.socket] = []
    try:
        # 300 connections that send half a request and then nothing
        for _ in range(300):
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            s.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            idle.append(s)
        time.sleep(2.0 + 3.0)
        assert closed_by_the_server(idle) == len(idle)
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n".encode())
            assert s.recv(64).startswith(b"HTTP/1.1 200")
    finally:
        for s in idle:
            s.close()
        server.should_exit = True
        thread.join(timeout=15)
        station.ledger.close()


def test_a_locked_record_is_said_so_and_nothing_is_shown_as_recorded(station_client):
    """The record's SQLite file held by another writer (a second station, a backup tool): the
    calibration is written but not recorded, and pages that read the record say why."""
    import sqlite3

    from spacecal import app

    station, web = station_client
    new_calibration(web)
    work = station.workspaces[1]
    app.simulate(app.SimulateSettings(output=str(work.recording_path), force=True))
    holder = sqlite3.connect(station.data / "record.db", timeout=0)
    try:
        holder.execute("BEGIN EXCLUSIVE")
        page = web.post("/workspaces/1/step/calibrate", data={"method": "ml"}, headers=OWN_PAGE)
        assert page.status_code == 200 and "was written but not recorded" in page.text
        assert 'id="verdict"' not in page.text and 'id="calibrate-result"' not in page.text
        assert work.calibration is None and work.calibration_record_id is None
        trends = web.get("/trends")
        assert trends.status_code == 503 and "<h1>Service Unavailable</h1>" in trends.text
        assert "record" in trends.text and "Traceback" not in trends.text
    finally:
        holder.rollback()
        holder.close()
    # once the record can be written, calibrating again records it
    page = web.post("/workspaces/1/step/calibrate", data={"method": "ml"}, headers=OWN_PAGE)
    assert 'id="verdict"' in page.text and work.calibration_record_id is not None
    assert len(station.ledger.calibrations()) == 1


@pytest.mark.parametrize(
    "field, value",
    [
        ("name", "bay\u202e1"),  # a bidirectional override
        ("name", "bay\x851"),  # a C1 control
        ("name", "bay\x7f"),  # DEL
        ("name", "bay\n1"),
        ("url", "ur://" + "h" * 10_000),
        ("url", "ur://host\nX-Injected: 1"),
        ("url", ""),
        ("url", "ur//host"),
        ("url", "ndi:/dev/ttyUSB0"),
        ("model", "ur10e\n" + "x" * 5000),
        ("rate_hz", "abc"),
        ("rate_hz", "-20"),
        ("rate_hz", "1e9"),
    ],
)
def test_a_device_form_with_a_bad_value_adds_nothing_and_says_why(station_client, field, value):
    station, web = station_client
    kind = "tracker" if field == "rate_hz" else "robot"
    form = {"kind": kind, "name": "bay 1", "url": "sim", field: value}
    page = web.post("/devices", data=form, headers=OWN_PAGE)
    assert page.status_code == 200 and page.url.path == "/"
    # beside its field (tests/station/test_device_forms.py holds the words)
    error = re.search(rf'id="add-{kind}-{field}-error"[^>]*>(.*?)</span>', page.text, re.S)
    assert error is not None and "\n" not in error.group(1) and len(error.group(1)) < 500
    assert "could not convert" not in error.group(1)  # words for a person, not Python's
    assert station.ledger.robots() == [] and station.ledger.trackers() == []


#: A stopped run's process ends within this on a busy machine (it starts a Python interpreter), s.
LIVE_VIEW_CLOSED_WITHIN_S = 120.0


def test_the_live_view_is_closed_once_its_run_ended(station_client):
    """A socket of the station's own page is closed (1000) once the run ended and its last state
    was sent; one opened to an ended run gets that state and is closed too: no live socket
    outlives its run."""
    import json

    websockets = need("starlette.websockets")
    station, web = station_client
    new_calibration(web)
    web.post("/workspaces/1/step/dry-run", headers=OWN_PAGE)
    page = web.get("/workspaces/1/confirm/acquire", headers={"Sec-Fetch-Site": "same-origin"}).text
    ticket = re.search(r'name="ticket" value="([^"]+)"', page).group(1)
    web.post("/workspaces/1/motion/acquire", data={"ticket": ticket}, headers=OWN_PAGE)
    run = station.runs.get(1)
    states: list[str] = []
    deadline = time.monotonic() + LIVE_VIEW_CLOSED_WITHIN_S
    with pytest.raises(websockets.WebSocketDisconnect) as closed:
        with web.websocket_connect(LIVE_VIEW, headers=OWN_PAGE) as live:
            states.append(json.loads(live.receive_text())["run_state"])
            run.request_stop("the test ended")
            while time.monotonic() < deadline:
                states.append(json.loads(live.receive_text())["run_state"])
            pytest.fail(f"the socket was open {LIVE_VIEW_CLOSED_WITHIN_S:.0f} s after the STOP: {states[-1]}")
    assert closed.value.code == 1000 and not run.active and states[-1] == run.state == "stopped"
    assert run.watchers == 0
    with pytest.raises(websockets.WebSocketDisconnect) as closed:
        with web.websocket_connect(LIVE_VIEW, headers=OWN_PAGE) as late:
            assert json.loads(late.receive_text())["run_state"] == "stopped"
            late.receive_text()
    assert closed.value.code == 1000
