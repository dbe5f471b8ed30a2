"""The station's needle guidance (paper §5.3) at the door: uploads bounded and kept under the
station's names, the standoff and the insertion each behind a ticket of its own, none of which
starts another motion, and the insertion confirmed only while the robot stands at the standoff."""

from __future__ import annotations

import time
from pathlib import Path

from spacecal.station.guide_step import shown_name
from tests.station.test_browser_guide import phantom_files
from tests.station.test_confirmation import assert_refused
from tests.station.test_verify_step import calibrated, ticket_of


def upload(web, plan: Path, registration: Path, plan_name: str = "plan.mrk.json"):
    return web.post(
        "/workspaces/1/guide/upload",
        files={
            "plan": (plan_name, plan.read_bytes()),
            "registration": ("TrackerToRAS.tfm", registration.read_bytes()),
        },
        data={"registration_maps": ""},
    )


def test_uploads_are_bounded_and_kept_under_the_stations_names(simulated_workspace, tmp_path):
    station, web = simulated_workspace
    work = station.workspaces[1]
    calibrated(station, web)
    plan, registration = phantom_files(tmp_path, work)
    hostile = "<img src=x onerror=alert(1)>" + "x" * 300 + ".mrk.json"
    page = upload(web, plan, registration, plan_name="../../" + hostile).text
    assert "<img src=x" not in page and "&lt;img src=x onerror=alert(1)&gt;" in page
    assert work.guide.given_names["plan"] == shown_name(hostile) and len(shown_name(hostile)) == 100
    assert sorted(p.name for p in work.folder.glob("guide-*")) == [
        "guide-plan-located.json",
        "guide-plan.mrk.json",
        "guide-registration.tfm",
    ]
    # a wrong ending, a binary file and a body over the doors' bound: one line, nothing kept
    before = work.guide.path("plan").read_bytes()
    wrong = web.post("/workspaces/1/guide/upload", files={"plan": ("plan.exe", b"{}")}).text
    assert "the plan file must end in .mrk.json, not &#39;plan.exe&#39;" in wrong
    binary = web.post("/workspaces/1/guide/upload", files={"plan": ("p.mrk.json", b"\xff\xfe\x00")}).text
    assert "is not text (UTF-8)" in binary
    big = web.post("/workspaces/1/guide/upload", files={"plan": ("p.mrk.json", b" " * (65 * 1024))})
    assert big.status_code == 413
    assert work.guide.path("plan").read_bytes() == before


def test_each_guidance_stage_starts_only_from_its_own_confirmation(simulated_workspace, tmp_path):
    station, web = simulated_workspace
    work = station.workspaces[1]
    calibrated(station, web)
    plan, registration = phantom_files(tmp_path, work)
    # before the dry run: no standoff, no insertion
    assert 'name="ticket"' not in web.get("/workspaces/1/confirm/standoff").text
    upload(web, plan, registration)
    assert 'name="ticket"' not in web.get("/workspaces/1/confirm/standoff").text
    page = web.post("/workspaces/1/step/guide-dry-run", data={"standoff_mm": "20"}).text
    assert "motion gate: passed" in page and 'id="standoff"' in page
    for insertion in ("advance", "hold"):  # not before the robot stands at the standoff
        refused = web.get(f"/workspaces/1/confirm/insert?insertion={insertion}").text
        assert 'name="ticket"' not in refused and "only while the robot stands at the plan" in refused
    # a check's, a verification's and a made-up ticket do not start the standoff
    web.post("/workspaces/1/step/verify-dry-run", data={"poses": "3"})
    others = [ticket_of(web.get(f"/workspaces/1/confirm/{m}").text) for m in ("check", "verify")]
    for data in ({}, {"ticket": "made-up"}, *({"ticket": t} for t in others)):
        assert_refused(web.post("/workspaces/1/motion/standoff", data=data))
    # the standoff's ticket starts neither an insertion nor another motion (and is used up so)
    standoff = ticket_of(web.get("/workspaces/1/confirm/standoff").text)
    for motion in ("insert", "verify", "check", "acquire"):
        assert_refused(
            web.post(f"/workspaces/1/motion/{motion}", data={"ticket": standoff, "insertion": "advance"})
        )
    assert_refused(web.post("/workspaces/1/motion/standoff", data={"ticket": standoff}))
    assert station.runs.get(1) is None and not list(work.folder.glob("guidance-*"))
    # a new upload leaves the dry run's confirmation worthless
    standoff = ticket_of(web.get("/workspaces/1/confirm/standoff").text)
    upload(web, plan, registration)
    assert_refused(web.post("/workspaces/1/motion/standoff", data={"ticket": standoff}))
    web.post("/workspaces/1/step/guide-dry-run")
    standoff = ticket_of(web.get("/workspaces/1/confirm/standoff").text)
    started = web.post("/workspaces/1/motion/standoff", data={"ticket": standoff}, follow_redirects=False)
    assert started.status_code == 303 and started.headers["location"].endswith("/runs/1")
    run = station.runs.get(1)
    run.page_connected()  # the run's page, as a browser's would
    deadline = time.monotonic() + 120
    while run.awaiting != "insert" and run.active and time.monotonic() < deadline:
        time.sleep(0.05)
    assert run.awaiting == "insert", run.message
    # at the standoff: the insertion's ticket is bound to the insertion it names
    hold = ticket_of(web.get("/workspaces/1/confirm/insert?insertion=hold").text)
    assert_refused(web.post("/workspaces/1/motion/insert", data={"ticket": hold, "insertion": "advance"}))
    advance = ticket_of(web.get("/workspaces/1/confirm/insert?insertion=advance").text)
    assert_refused(web.post("/workspaces/1/motion/standoff", data={"ticket": advance}))
    assert_refused(web.post("/workspaces/1/motion/verify", data={"ticket": advance}))
    assert run.awaiting == "insert" and run.active  # still holding at the standoff
    run.request_stop("the test ended")
    run.thread.join(timeout=60)
    assert run.state == "stopped" and run.awaiting is None
    # stopped at the standoff: no insertion; the robot moves again only after a new dry run
    # (the last was planned from where the robot stood then) and a new confirmation
    assert 'name="ticket"' not in web.get("/workspaces/1/confirm/insert?insertion=advance").text
    assert 'name="ticket"' not in web.get("/workspaces/1/confirm/standoff").text
    web.post("/workspaces/1/step/guide-dry-run")
    assert 'name="ticket"' in web.get("/workspaces/1/confirm/standoff").text
    assert station.runs.get(2) is None
