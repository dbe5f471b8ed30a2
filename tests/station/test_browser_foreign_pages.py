"""No page of another origin moves the robot: real pages in headless Chromium, served from
another loopback address (another site) and from another port of the station's own host (the
same site: the token's cookie goes there too), try what was once seen to work.

* frame the confirmation page invisibly over a decoy and click where "Yes, move" would be;
* create, plan and dry-run a calibration with forms, from the page and from a sandboxed frame
  (``Origin: null``), and with ``fetch``;
* open the live view's websocket of a run the operator started, to watch it and keep it going
  once the operator's page is closed;
* send the operator's browser to the confirmation page by a link, and post start requests;
* read the cookie the operator's browser sends to a web server on another port of the
  station's host (cookies are not bound to a port): it must not hold the token.

Nothing may be created, planned, confirmed or started, and the run must stop when the
operator's page closes. Each attack runs with the station on loopback without a token and with
one (the operator signed in, the cookie in the browser).
"""

from __future__ import annotations

import http.server
import re
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from tests.station.conftest import free_port, need, wait_js

TOKEN = "operator-token-0123456789abcdef"
#: The run stops within this of its last page closing (the station sees a closed socket at once;
#: the run's process then takes its stop path), s.
STOPPED_WITHIN_S = 60.0


@dataclass
class Station:
    url: str
    station: Any
    token: str | None


@pytest.fixture(params=["loopback", "token"])
def station(request, tmp_path) -> Iterator[Station]:
    """The station on 127.0.0.1, without a token and with one."""
    uvicorn = need("uvicorn")
    from spacecal.station.server import StationOptions, build, server_config

    port = free_port()
    token = TOKEN if request.param == "token" else None
    built, application = build(StationOptions(port=port, token=token, data=str(tmp_path / "station")))
    server = uvicorn.Server(server_config(application, "127.0.0.1", port))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "the station did not start"
        time.sleep(0.05)
    try:
        yield Station(f"http://127.0.0.1:{port}", built, token)
    finally:
        built.runs.stop_all("the test ended")
        server.should_exit = True
        thread.join(timeout=15)
        built.ledger.close()


class Attacker:
    """An HTTP server of another origin serving one page (``/``), set by the test."""

    def __init__(self, host: str):
        page = self
        self.html = "<p>nothing</p>"
        #: The ``Cookie`` header of every request it was sent ("" for none).
        self.cookies: list[str] = []

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                page.cookies.append(self.headers.get("Cookie") or "")
                body = page.html.encode()
                self.send_response(200)
                self.send_header("Content-Type", "text/html; charset=utf-8")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer((host, 0), Handler)
        self.url = f"http://{host}:{self.server.server_address[1]}/"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture(params=["another address", "another port"])
def attacker(request) -> Iterator[Attacker]:
    """The foreign page's server: on 127.0.0.2 (another site) or on 127.0.0.1 at another port
    (the same site as the station, another origin)."""
    served = Attacker("127.0.0.2" if request.param == "another address" else "127.0.0.1")
    try:
        yield served
    finally:
        served.close()


@pytest.fixture
def browser(browser_context) -> Any:
    """One browser: the operator's pages and the foreign page share its cookies."""
    return browser_context


def operator_prepares(context, station: Station) -> Any:
    """The operator, at the station's own page: signs in (token mode), adds a simulated robot
    and tracker, starts a calibration, plans and dry-runs it; the page, left on the
    calibration."""
    page = context.new_page()
    page.goto(station.url + (f"/?token={station.token}" if station.token else "/"))
    page.wait_for_selector("#add-robot")
    assert "token" not in page.url  # the address bar is clean once the cookie is set
    page.fill("#add-robot input[name=name]", "UR10 bay 1")
    page.click("#add-robot button")
    page.fill("#add-tracker input[name=name]", "Vicra")
    page.click("#add-tracker button")
    page.click("#start button")
    page.wait_for_selector("#robot-name")
    page.click("#plan")
    page.click("#dry-run")
    page.wait_for_selector("#acquire")
    return page


def forms_page(station_url: str) -> str:
    """Forms to the station, posted into hidden frames, from the page itself, from a sandboxed
    frame (``Origin: null``) and by ``fetch``: a robot, a calibration, a plan, a dry run."""
    posts = [
        ("/devices", {"kind": "robot", "name": "evil robot", "url": "sim"}),
        ("/devices", {"kind": "tracker", "name": "evil tracker", "url": "sim"}),
        ("/workspaces", {"robot": "1", "tracker": "1"}),
        ("/workspaces/1/step/plan", {}),
        ("/workspaces/1/step/dry-run", {}),
        ("/workspaces/1/motion/acquire", {"ticket": "made-up"}),
        ("/workspaces/1/motion/check", {"ticket": "made-up"}),
        ("/workspaces/1/step/verify-dry-run", {"poses": "3"}),
        ("/workspaces/1/motion/verify", {"ticket": "made-up"}),
        ("/workspaces/1/step/guide-dry-run", {}),
        ("/workspaces/1/motion/standoff", {"ticket": "made-up"}),
        ("/workspaces/1/motion/insert", {"ticket": "made-up", "insertion": "advance"}),
    ]
    forms = []
    for k, (path, fields) in enumerate(posts):
        inputs = "".join(f'<input name="{n}" value="{v}">' for n, v in fields.items())
        forms.append(
            f'<form id="f{k}" method="post" action="{station_url}{path}" target="sink">{inputs}</form>'
        )
    sandboxed = "".join(
        f'<iframe name="s{k}"></iframe><form method="post" action="{station_url}{path}" target="s{k}">'
        + "".join(f'<input name="{n}" value="{v}">' for n, v in fields.items())
        + "</form>"
        for k, (path, fields) in enumerate(posts)
    )
    sandboxed_doc = (sandboxed + "<script>for (const f of document.forms) { f.submit(); }</script>").replace(
        '"', "&quot;"
    )
    fetches = "".join(
        f"fetch('{station_url}{path}', {{method: 'POST', mode: 'no-cors', credentials: 'include', "
        f"body: new URLSearchParams({dict(fields)!r})}}).catch(() => null);"
        for path, fields in posts
    )
    return (
        '<iframe name="sink" style="display:none"></iframe>'
        + "".join(forms)
        + f'<iframe sandbox="allow-forms allow-scripts" srcdoc="{sandboxed_doc}"></iframe>'
        + "<script>"
        + "window.posted = 0;"
        + f"for (let k = 0; k < {len(posts)}; k++) {{ setTimeout(() => {{ "
        + "document.getElementById('f' + k).submit(); window.posted++; }, 300 * k); }"
        + fetches
        + "</script>"
    )


def test_forms_and_fetches_of_another_origin_change_nothing(station, attacker, browser):
    operator = operator_prepares(browser, station)
    work = station.station.workspaces[1]
    robots, trackers = len(station.station.ledger.robots()), len(station.station.ledger.trackers())
    plan_before = work.plan_path.read_bytes()
    basis_before = work.dry_run_basis
    attacker.html = forms_page(station.url)
    page = browser.new_page()
    page.goto(attacker.url)
    wait_js(page, "window.posted === 12", timeout=60_000)
    time.sleep(3.0)  # the sandboxed frame's and the fetches' requests have been answered
    assert len(station.station.ledger.robots()) == robots
    assert len(station.station.ledger.trackers()) == trackers
    assert list(station.station.workspaces) == [1]
    assert work.plan_path.read_bytes() == plan_before and work.dry_run_basis == basis_before
    assert work.verification.dry_run_lines == [] and work.guide.dry_run_lines == []
    assert station.station.runs.get(1) is None and station.station.runs.active() is None
    operator.close()


#: The confirmations of the verification and of the guidance's two stages.
NEEDLE_CONFIRMATIONS = ("verify", "standoff", "insert?insertion=advance")


def operator_prepares_needle_motions(context, station: Station, tmp_path) -> Any:
    """As :func:`operator_prepares`, then calibrated (its recording acquired at once), the
    verification dry-run and a Slicer plan uploaded and dry-run: the verification's and the
    standoff's confirmations are the operator's to open."""
    from spacecal import app as spacecal_app
    from tests.station.test_browser_guide import phantom_files

    page = operator_prepares(context, station)
    work = station.station.workspaces[1]
    spacecal_app.acquire(
        spacecal_app.AcquireSettings(
            str(work.recording_path), devices=work.devices, confirm_robot_motion=True, plan=None
        )
    )
    page.reload()  # the page shows the recording (calibrating is locked until there is one)
    page.click("#calibrate")
    page.fill("#verify-poses", "3")
    page.click("#verify-dry-run")
    plan, registration = phantom_files(tmp_path, work)
    page.set_input_files("#guide-upload input[name=plan]", str(plan))
    page.set_input_files("#guide-upload input[name=registration]", str(registration))
    page.click("#guide-upload-button")
    page.click("#guide-dry-run")
    page.wait_for_selector("#standoff")
    assert page.query_selector("#verify") is not None
    return page


def test_no_page_of_another_origin_starts_a_verification_or_a_guidance(station, attacker, browser, tmp_path):
    """Links to the new confirmations, the confirmations framed and clicked over a decoy, a
    plan uploaded and the start requests posted: nothing confirmed, uploaded or started."""
    operator = operator_prepares_needle_motions(browser, station, tmp_path)
    work = station.station.workspaces[1]
    guide_files = {p.name: p.read_bytes() for p in work.folder.glob("guide-*")}
    verify_basis, standoff_basis = work.verification.basis, work.guide.basis
    tickets_before = len(station.station.tickets)
    links = "".join(
        f'<a id="go{k}" href="{station.url}/workspaces/1/confirm/{c}">results {k}</a>'
        for k, c in enumerate(NEEDLE_CONFIRMATIONS)
    )
    upload = (
        f'<form id="up" method="post" enctype="multipart/form-data" target="sink" '
        f'action="{station.url}/workspaces/1/guide/upload"><input name="registration_maps" '
        'value="tracker-to-image"></form><iframe name="sink"></iframe>'
    )
    frames = "".join(
        f'<iframe src="{station.url}/workspaces/1/confirm/{c}" style="position:absolute; top:0; '
        f'left:{k * 400}px; width:400px; height:800px; opacity:0.01; z-index:2; border:0"></iframe>'
        for k, c in enumerate(NEEDLE_CONFIRMATIONS)
    )
    attacker.html = links + upload + "<script>document.getElementById('up').submit();</script>"
    page = browser.new_page()
    page.goto(attacker.url)
    page.wait_for_timeout(1000)
    for k in range(len(NEEDLE_CONFIRMATIONS)):
        page.goto(attacker.url)
        page.click(f"#go{k}")
        page.wait_for_load_state()
        assert "Move the robot?" not in page.content() and "<h1>Forbidden</h1>" in page.content()
    attacker.html = frames
    page.goto(attacker.url)
    page.wait_for_timeout(2000)
    for frame in [f for f in page.frames if f != page.main_frame]:
        try:
            shown = frame.content()
        except Exception:  # a frame the browser blocked may have no readable document
            shown = ""
        assert "Move the robot?" not in shown and 'name="ticket"' not in shown
    for x in range(40, 1200, 80):
        for y in range(20, 800, 40):
            page.mouse.click(x, y)
    page.wait_for_timeout(1000)
    attacker.html = forms_page(station.url)
    page.goto(attacker.url)
    wait_js(page, "window.posted === 12", timeout=60_000)
    time.sleep(3.0)  # the sandboxed frame's and the fetches' requests have been answered
    assert len(station.station.tickets) == tickets_before
    assert station.station.runs.get(1) is None and station.station.runs.active() is None
    assert {p.name: p.read_bytes() for p in work.folder.glob("guide-*")} == guide_files
    assert work.guide.registration_maps is None
    assert work.verification.basis == verify_basis and work.guide.basis == standoff_basis
    assert not list(work.folder.glob("verification-*")) and not list(work.folder.glob("guidance-*"))
    # the same confirmations at the station's own page are what move it
    operator.click("#verify")
    assert "Move the robot?" in operator.content()
    operator.go_back()
    operator.click("#standoff")
    assert "Move the robot?" in operator.content()
    operator.close()


def test_a_link_to_the_confirmation_from_another_origin_is_refused(station, attacker, browser):
    operator = operator_prepares(browser, station)
    tickets_before = len(station.station.tickets)
    attacker.html = f'<a id="go" href="{station.url}/workspaces/1/confirm/acquire">your results</a>'
    page = browser.new_page()
    page.goto(attacker.url)
    page.click("#go")
    page.wait_for_load_state()
    assert "Move the robot?" not in page.content() and "<h1>Forbidden</h1>" in page.content()
    assert len(station.station.tickets) == tickets_before
    assert station.station.runs.active() is None
    operator.close()


def test_another_port_of_the_host_never_receives_the_token(station, browser):
    """Cookies are not bound to a port: once signed in, the browser sends the station's cookie
    to every web server of 127.0.0.1 whose page it opens, also when a page of another address
    sends it there. The cookie must hold no token (a session key of this station's process)."""
    operator = operator_prepares(browser, station)
    other_port, lure = Attacker("127.0.0.1"), Attacker("127.0.0.2")
    try:
        other_port.html = "<script>fetch('/again');</script>"
        lure.html = f"<script>location = '{other_port.url}';</script>"
        for start in (other_port.url, lure.url):  # typed by the operator; a link elsewhere
            page = browser.new_page()
            page.goto(start)
            page.wait_for_load_state()
            page.wait_for_timeout(1000)
            page.close()
        sent = [c for c in other_port.cookies if "spacecal_station_token" in c]
        if station.token is None:
            assert sent == []  # no token, no cookie
        else:
            assert sent, "the browser sent no cookie: the test did not do what it says"
            assert all(station.token not in c for c in sent)
    finally:
        other_port.close()
        lure.close()
    operator.close()


def test_a_framed_confirmation_cannot_be_clicked(station, attacker, browser):
    operator = operator_prepares(browser, station)
    # the confirmation, invisibly over a decoy, where the operator's click lands
    attacker.html = (
        '<button style="position:absolute; top:40px; left:20px; width:600px; height:400px">'
        "Win a prize</button>"
        f'<iframe id="frame" src="{station.url}/workspaces/1/confirm/acquire" style="position:absolute; '
        'top:0; left:0; width:1200px; height:800px; opacity:0.01; z-index:2; border:0">'
        "</iframe>"
    )
    page = browser.new_page()
    page.goto(attacker.url)
    page.wait_for_timeout(2000)
    framed = [f for f in page.frames if f != page.main_frame]
    assert len(framed) == 1
    shown = ""
    try:
        shown = framed[0].content()
    except Exception:  # a frame the browser blocked may have no readable document
        pass
    assert "Move the robot?" not in shown and 'name="ticket"' not in shown
    tickets_before = len(station.station.tickets)
    for x in range(40, 1200, 80):
        for y in range(20, 800, 40):
            page.mouse.click(x, y)
    page.wait_for_timeout(2000)
    assert station.station.runs.get(1) is None and station.station.runs.active() is None
    assert len(station.station.tickets) == tickets_before  # the frame got no ticket either
    # the same confirmation at the station's own page is what moves it
    operator.click("#acquire")
    assert "Move the robot?" in operator.content()
    operator.close()


def test_a_foreign_socket_neither_watches_nor_keeps_a_run_alive(station, attacker, browser):
    operator = operator_prepares(browser, station)
    operator.click("#acquire")
    operator.click("#confirm")
    operator.wait_for_url(re.compile(r"/runs/\d+$"))
    run = station.station.runs.get(1)
    deadline = time.monotonic() + 240
    while run.first_frame_at is None:  # the robot moves: the operator's page watches it
        assert time.monotonic() < deadline and run.active, run.message
        time.sleep(0.2)
    ws_url = station.url.replace("http://", "ws://") + "/runs/1/ws"
    # from the page itself, and from a sandboxed frame (Origin: null), again and again
    watch = (
        "function watch() { const s = new WebSocket('" + ws_url + "');"
        " s.onmessage = () => { parent.postMessage('message', '*'); };"
        " s.onclose = () => { parent.postMessage('closed', '*'); setTimeout(watch, 500); }; }"
        "watch();"
    )
    attacker.html = (
        "<script>window.messages = 0; window.ended = 0;"
        "window.addEventListener('message', (e) => { if (e.data === 'message') { window.messages++; }"
        " else { window.ended++; } });"
        + watch
        + "</script>"
        + f'<iframe sandbox="allow-scripts" srcdoc="<script>{watch}</script>"></iframe>'
    )
    page = browser.new_page()
    page.goto(attacker.url)
    wait_js(page, "window.ended >= 4", timeout=60_000)  # both refused, twice
    assert run.watchers == 1  # the operator's page only
    operator.close()  # the operator's page goes: the run must stop, whoever else tries to watch
    deadline = time.monotonic() + STOPPED_WITHIN_S
    while run.active:
        assert time.monotonic() < deadline, f"the run went on without the operator's page: {run.message}"
        time.sleep(0.2)
    from spacecal.station.motions import PAGE_LOST

    assert run.state == "stopped" and PAGE_LOST in run.stop_reason
    assert page.evaluate("window.messages") == 0  # it never saw a frame
