"""The station's verification on the robot (paper §5.2) at the door: a dry run first, its own
confirmation and ticket bound to the calibration file's sha256, and no other motion's ticket
starts it (nor its ticket another motion)."""

from __future__ import annotations

import re

from spacecal import app as spacecal_app
from tests.station.test_confirmation import assert_refused


def calibrated(station, web) -> None:
    """The workspace's recording, acquired as fast as the simulated devices compute, calibrated."""
    work = station.workspaces[1]
    spacecal_app.acquire(
        spacecal_app.AcquireSettings(
            str(work.recording_path), devices=work.devices, confirm_robot_motion=True, plan=None
        )
    )
    web.post("/workspaces/1/step/calibrate")
    assert work.calibration is not None


def ticket_of(page: str) -> str:
    return re.search(r'name="ticket" value="([^"]+)"', page).group(1)


def test_the_verification_starts_only_from_its_own_confirmation(simulated_workspace):
    station, web = simulated_workspace
    work = station.workspaces[1]
    assert "calibrate, then run the verification" in web.get("/workspaces/1/confirm/verify").text
    calibrated(station, web)
    # no confirmation before its dry run passed
    assert 'name="ticket"' not in web.get("/workspaces/1/confirm/verify").text
    refused = web.post("/workspaces/1/step/verify-dry-run", data={"poses": "0"})
    assert "the needle poses must be a whole number 1..100" in refused.text
    page = web.post("/workspaces/1/step/verify-dry-run", data={"poses": "3"}).text
    assert "motion gate: passed" in page and "3 needle poses planned" in page and 'id="verify"' in page
    # a check's ticket, an acquisition's, and a made-up one do not start it
    check_ticket = ticket_of(web.get("/workspaces/1/confirm/check").text)
    for data in ({}, {"ticket": "made-up"}, {"ticket": check_ticket}):
        assert_refused(web.post("/workspaces/1/motion/verify", data=data))
    # its own ticket does not start the check, and is used up so
    verify_ticket = ticket_of(web.get("/workspaces/1/confirm/verify").text)
    assert_refused(web.post("/workspaces/1/motion/check", data={"ticket": verify_ticket}))
    assert_refused(web.post("/workspaces/1/motion/verify", data={"ticket": verify_ticket}))
    # the confirmation names the calibration file and its digest
    page = web.get("/workspaces/1/confirm/verify").text
    sha = work.verification.calibration_sha256()
    text = re.search(r'id="confirm-text">(.*?)</p>', page, re.S).group(1)
    assert "UR10 bay 1" in text and "calibration.json" in text and sha[:12] in text
    assert "3 needle poses" in text
    ticket = ticket_of(page)
    # a calibration changed since the dry run leaves the ticket worthless
    work.calibration_path.write_bytes(work.calibration_path.read_bytes() + b"\n")
    assert_refused(web.post("/workspaces/1/motion/verify", data={"ticket": ticket}))
    assert 'id="verify"' not in web.get("/workspaces/1").text
    assert station.runs.get(1) is None and not list(work.folder.glob("verification-*"))
