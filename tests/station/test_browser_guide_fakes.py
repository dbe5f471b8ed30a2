"""Guiding a needle at the station on the UR and NDI protocol fakes (a world in a process of its
own, spoken to by ur_rtde and ndicapi): there the robot stays where a motion left it, so the
standoff and the insertion run as two motions, each in its own process behind its own
confirmation, and the insertion's own check (the robot's reading puts the needle at this
plan's standoff) passes because the fake arm stood still between them.

The calibration's recording is acquired on the fakes through the app (a 30-s plan of the
paper's sweeps), then calibrated from the page.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from spacecal import app as spacecal_app
from tests.adapters.conftest import ahead_of_other_tests, hardware_lane, rom_file, watchdog  # noqa: F401
from tests.adapters.ur_runs import stats, ur_world
from tests.app.guide_files import write_markups, write_registration
from tests.station.test_browser import confirm_and_finish, shot
from tests.station.test_browser_fakes import ROBOT, new_robot_and_tracker_on_the_fakes

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")


def test_guide_a_needle_on_the_protocol_fakes_in_two_motions(served, page, rom_file, disk, tmp_path):  # noqa: F811
    world = ur_world("cb3")
    try:
        new_robot_and_tracker_on_the_fakes(page, served.url, world, rom_file)
        work = served.station.workspace(1)
        plan_file = tmp_path / "sweeps.json"
        spacecal_app.plan(
            spacecal_app.PlanSettings(scenario="paper-white", budget_s=30.0, output=str(plan_file))
        )
        spacecal_app.acquire(
            spacecal_app.AcquireSettings(
                str(work.recording_path), devices=work.devices, confirm_robot_motion=True, plan=str(plan_file)
            )
        )
        page.reload()
        page.click("#calibrate")
        assert page.inner_text("#verdict").split(":")[0] in ("Good", "Acceptable")
        phantom = json.loads(world.control("phantom"))
        path = phantom["paths"][0]
        plan = write_markups(
            tmp_path / "plan.mrk.json",
            {
                "entry": np.array(path["entry_in_image_lps_mm"]),
                "target": np.array(path["target_in_image_lps_mm"]),
            },
            "Line",
            "RAS",
        )
        registration = write_registration(
            tmp_path / "TrackerToRAS.tfm", np.array(phantom["tracker_from_image_lps"])
        )
        page.set_input_files("#guide-upload input[name=plan]", str(plan))
        page.set_input_files("#guide-upload input[name=registration]", str(registration))
        page.click("#guide-upload-button")
        page.click("#guide-dry-run")
        dry_run = page.inner_text("#guide-dry-run-result")
        assert "motion gate: passed" in dry_run, dry_run
        # the first motion: to the standoff, a process of its own that ends there
        page.click("#standoff")
        message = confirm_and_finish(page, served, disk, ROBOT, lambda: page.click("#standoff"))
        assert message.startswith("standoff: entry error"), message
        standoff_run = served.station.runs.latest()
        assert standoff_run.awaiting is None and not standoff_run.waits_for_confirmation
        page.click("#back")
        still = stats(world)
        # the second, its own confirmation: the insertion, in a new process, from where the arm stands
        page.click("#insert-advance")
        assert "advance to the target" in page.inner_text("#confirm-text")
        message = confirm_and_finish(page, served, disk, ROBOT, lambda: page.click("#insert-advance"))
        assert message.startswith("insert: entry error"), message
        insert_run = served.station.runs.latest()
        assert insert_run.id == standoff_run.id + 1 and insert_run.motion == "insert"
        assert stats(world)["commands"] > still["commands"]
        page.click("#back")
        rows = page.inner_text("#guide-results").splitlines()
        assert rows[1].startswith("standoff") and rows[2].startswith("insert"), rows
        inserted = json.loads((work.folder / "guidance-insert.json").read_text())
        assert inserted["stages_reached"] == ["insert"] and not inserted["interrupted"]
        assert inserted["devices"]["robot"].startswith("ur://")
        # what the page shows is the file's (the accuracy against the fake world's truth is
        # tests/app/test_guide_on_fakes.py's)
        cells = rows[2].split("\t")
        assert float(cells[2]) == round(inserted["target_error_mm"], 3)
        assert float(cells[3]) == round(inserted["direction_error_deg"], 3)
        shot(page, "17-fakes-guided")
        # the robot left the standoff: the insertion is not offered again
        assert page.query_selector("#insert-choices") is None
        assert page.query_selector("#insert-advance") is None
    finally:
        world.stop()
