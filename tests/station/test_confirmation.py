"""No motion starts without its confirmation: a start request must hand back the ticket the
confirmation page issued (naming the robot and the motion), once."""

from __future__ import annotations

import re


def test_no_motion_without_its_confirmation(simulated_workspace):
    station, web = simulated_workspace
    work = station.workspaces[1]
    # no confirmation before the dry run passed
    early = web.get("/workspaces/1/confirm/acquire")
    assert "run the dry run first" in early.text and 'name="ticket"' not in early.text
    web.post("/workspaces/1/step/dry-run")
    assert work.dry_run_ok
    # no ticket, a made-up one, and one issued for the other motion: refused, nothing moves
    for data in ({}, {"ticket": "made-up"}):
        assert_refused(web.post("/workspaces/1/motion/acquire", data=data))
    check_ticket = station.tickets.issue(1, "UR10 bay 1", "check", work.motion_basis("acquire"))
    assert_refused(web.post("/workspaces/1/motion/acquire", data={"ticket": check_ticket}))
    assert station.runs.active() is None and station.runs.get(1) is None
    assert not work.recording_path.exists()
    # the confirmation names the robot and the motion
    page = web.get("/workspaces/1/confirm/acquire").text
    text = re.search(r'id="confirm-text">(.*?)</p>', page, re.S).group(1)
    assert "UR10 bay 1" in text and "calibration motion" in text
    ticket = re.search(r'name="ticket" value="([^"]+)"', page).group(1)
    started = web.post("/workspaces/1/motion/acquire", data={"ticket": ticket}, follow_redirects=False)
    assert started.status_code == 303 and started.headers["location"].endswith("/runs/1")
    run = station.runs.get(1)
    run.request_stop("the test ended")
    run.thread.join(timeout=60)
    # a ticket is used once
    assert_refused(web.post("/workspaces/1/motion/acquire", data={"ticket": ticket}))
    assert station.runs.get(2) is None


def assert_refused(response) -> None:
    """A refused start: back on the calibration's page, which says the robot did not move."""
    assert response.status_code == 200 and response.url.path == "/workspaces/1", response.url
    assert "the robot did not move: a motion starts only from its confirmation page" in response.text
