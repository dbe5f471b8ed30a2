"""The calibration page's steps: each one done (with its result's grade), current (one of them
next) or locked (its button disabled, with the reason), derived from the workspace
(:func:`spacecal.station.workspace.step_states`); the motions as buttons of their own; and the
check's confirmation naming the moves its run then counts."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from spacecal import app as spacecal_app
from spacecal.planning.check_poses import check_plan
from spacecal.planning.motion import MotionLimits
from spacecal.sim.scenario import PRESETS
from spacecal.sim.world import build_world
from spacecal.station.workspace import (
    CURRENT,
    DONE,
    LOCKED,
    STEPS,
    Workspace,
    check_moves,
    step_states,
)
from tests.station.conftest import wait_js
from tests.station.test_browser import RUN_ENDED_JS, new_robot_and_tracker, wait_for_run_end

OWN_PAGE = {"Origin": "http://127.0.0.1:8770", "Sec-Fetch-Site": "same-origin"}


def states(work: Workspace, running: str | None = None) -> dict[str, tuple[str, str | None]]:
    """Each step's ``(state, grade)``."""
    return {s.key: (s.state, s.grade) for s in step_states(work, running)}


def next_step(work: Workspace) -> str | None:
    upcoming = [s.key for s in step_states(work) if s.next]
    assert len(upcoming) <= 1
    return upcoming[0] if upcoming else None


def workspace(tmp_path: Path) -> Workspace:
    robot = {"id": 1, "name": "UR10 bay 1", "url": "sim"}
    tracker = {"id": 1, "name": "Vicra", "url": "sim"}
    return Workspace(1, robot, tracker, tmp_path)


def acquire_at_once(work: Workspace) -> None:
    """The workspace's recording, acquired as fast as the simulated devices compute."""
    spacecal_app.acquire(
        spacecal_app.AcquireSettings(
            str(work.recording_path), devices=work.devices, confirm_robot_motion=True, plan=None
        )
    )


def test_a_new_calibration_asks_the_devices_first_and_locks_what_needs_a_recording(tmp_path):
    work = workspace(tmp_path)
    assert [s.key for s in step_states(work)] == [key for key, _ in STEPS]
    shown = states(work)
    assert shown["devices"] == (CURRENT, None) and next_step(work) == "devices"
    assert shown["plan"] == shown["dry-run"] == (CURRENT, None)
    for key in ("acquire", "calibrate", "check", "verify", "guide", "report", "export"):
        assert shown[key][0] == LOCKED, key
    why = {s.key: s.words for s in step_states(work)}
    assert why["acquire"] == "run the dry run first: the robot moves only after it passed"
    assert why["calibrate"].startswith("acquire first")
    assert all(why[key].startswith("calibrate first") for key in ("check", "verify", "guide", "report"))
    work.doctor()
    assert states(work)["devices"] == (DONE, "good") and next_step(work) == "plan"


@pytest.mark.parametrize(
    ("level", "state", "grade"),
    [
        ("fine", DONE, "good"),
        ("check this before you start", DONE, "acceptable"),
        ("must be fixed before the robot can move", CURRENT, "poor"),
    ],
)
def test_the_devices_step_takes_the_worst_finding(tmp_path, level, state, grade):
    work = workspace(tmp_path)
    work.findings = [("robot", "fine", "connected"), ("tracker", level, "its frames")]
    assert states(work)["devices"] == (state, grade)


def test_a_dry_run_that_did_not_pass_keeps_the_acquisition_locked(tmp_path):
    work = workspace(tmp_path)
    work.doctor()
    work.dry_run_lines = ["motion gate: refused (reach)", "dry run: nothing moved"]
    shown = {s.key: s for s in step_states(work)}
    assert (shown["dry-run"].state, shown["dry-run"].grade) == (CURRENT, "poor")
    assert shown["acquire"].state == LOCKED and shown["acquire"].words.startswith("the dry run did not pass")


def test_the_steps_follow_a_calibration_from_its_plan_to_its_export(tmp_path):
    work = workspace(tmp_path)
    work.doctor()
    work.plan()
    work.dry_run()
    shown = states(work)
    assert shown["plan"] == (DONE, None) and shown["dry-run"] == (DONE, "good")
    assert next_step(work) == "acquire"
    assert shown["acquire"] == (CURRENT, None) and next_step(work) == "acquire"
    assert states(work, running="acquire")["calibrate"][0] == LOCKED  # not while it records
    # an edited plan: the dry run no longer holds, so neither does the acquisition's confirmation
    work.plan_path.write_text(work.plan_path.read_text() + " ")
    shown = {s.key: s for s in step_states(work)}
    assert (shown["dry-run"].state, shown["dry-run"].grade) == (CURRENT, None)
    assert shown["acquire"].state == LOCKED and "the plan changed" in shown["acquire"].words
    work.dry_run()
    assert states(work)["acquire"] == (CURRENT, None)
    assert states(work, running="acquire")["acquire"] == (CURRENT, None)
    # while the robot moves nothing is next: the operator watches it, or presses STOP
    assert not any(s.next for s in step_states(work, "acquire"))

    acquire_at_once(work)
    shown = states(work)
    assert shown["acquire"] == (DONE, None) and shown["calibrate"] == (CURRENT, None)
    assert next_step(work) == "calibrate" and shown["check"][0] == LOCKED

    work.calibrate("ml")
    grade = work.calibration.record.verdict.grade
    shown = states(work)
    assert shown["calibrate"] == (DONE, grade)
    for key in ("check", "verify", "guide", "report", "export"):
        assert shown[key] == (CURRENT, None), key
    assert next_step(work) == "check"

    # a check's result colours its step: PASS as good, FAIL as poor
    work.checks.append(SimpleNamespace(result=SimpleNamespace(passed=False)))
    assert states(work)["check"] == (DONE, "poor") and next_step(work) == "report"
    work.checks.append(SimpleNamespace(result=SimpleNamespace(passed=True)))
    assert states(work)["check"] == (DONE, "good")

    work.make_report()
    work.export(["slicer"])
    shown = {s.key: s for s in step_states(work)}
    assert shown["report"].state == shown["export"].state == DONE
    assert shown["export"].words == "1 file"
    assert next_step(work) == "verify"  # the needle steps come once the rest is done


def test_the_next_step_passes_over_what_is_not_needed_yet(tmp_path):
    work = workspace(tmp_path)
    work.doctor()
    work.dry_run()  # without a plan: the dry run plans the paper's sweeps itself
    assert states(work)["plan"] == (CURRENT, None) and next_step(work) == "acquire"
    acquire_at_once(work)
    work.calibrate("ml")
    work.make_report()
    assert next_step(work) == "check"  # a report written first does not pass the check over


def test_a_new_acquisition_forgets_the_steps_that_followed(tmp_path):
    work = workspace(tmp_path)
    work.doctor()
    acquire_at_once(work)
    work.calibrate("ml")
    work.make_report()
    work.set_aside_earlier_recording(2)
    shown = states(work)
    assert shown["acquire"][0] == LOCKED and shown["calibrate"][0] == LOCKED
    assert shown["report"][0] == LOCKED


@pytest.mark.parametrize("poses", [1, 2, 3])
def test_the_check_moves_named_are_the_moves_its_plan_has(poses):
    world = build_world(PRESETS["paper-realistic"])
    plan = check_plan(world.controller_model, world.home_joints_rad, poses, MotionLimits(), 0.05)
    assert check_moves(poses) == len(plan.moves)


def test_the_page_disables_a_locked_step_and_says_why(simulated_workspace):
    station, web = simulated_workspace
    page = web.get("/workspaces/1").text
    for button, why in (
        ("acquire", "run the dry run first"),
        ("calibrate", "acquire first"),
        ("check", "calibrate first"),
        ("report", "calibrate first"),
        ("export", "calibrate first"),
    ):
        tag = re.search(rf'<button[^>]*id="{button}-locked"[^>]*>', page)
        assert tag is not None and " disabled" in tag.group(0), button
        assert f'aria-describedby="{button}-why"' in tag.group(0)
        assert re.search(rf'id="{button}-why"[^>]*>{why}', page), button
        assert f'id="{button}"' not in page  # nothing to press
    assert 'id="stepper-acquire" class="step step-locked"' in page
    web.post("/workspaces/1/step/dry-run", headers=OWN_PAGE)
    page = web.get("/workspaces/1").text
    acquire = re.search(
        r'<form method="get" action="([^"]+)" class="motion-form"><button type="submit" '
        r'class="motion" id="acquire">',
        page,
    )
    assert acquire is not None and acquire.group(1).endswith("/workspaces/1/confirm/acquire")
    assert 'id="acquire-locked"' not in page and 'aria-current="step"' in page


def test_the_stepper_and_the_check_counters_in_the_browser(served, page, disk):
    """Locked steps' buttons are disabled in the page, the motions are buttons, and the check
    says the moves its run then counts, with its samples shown as they come."""
    new_robot_and_tracker(page, served.url, "UR10 bay 11")
    assert page.get_attribute("#stepper-devices", "data-state") == "done"
    assert page.get_attribute("#stepper-acquire", "data-state") == "locked"
    assert page.is_disabled("#acquire-locked") and page.is_disabled("#calibrate-locked")
    assert "run the dry run first" in page.inner_text("#acquire-why")
    page.click("#plan")
    page.click("#dry-run")
    assert page.get_attribute("#stepper-dry-run", "data-grade") == "good"
    assert page.get_attribute("#stepper-acquire", "aria-current") == "step"
    assert page.evaluate("document.getElementById('acquire').tagName") == "BUTTON"
    assert page.evaluate("getComputedStyle(document.getElementById('acquire')).backgroundColor") != (
        page.evaluate("getComputedStyle(document.getElementById('dry-run')).backgroundColor")
    )
    acquire_at_once(served.station.workspace(1))
    page.reload()
    page.click("#calibrate")
    grade = page.get_attribute("#verdict", "data-grade")
    assert page.get_attribute("#stepper-calibrate", "data-grade") == grade
    assert page.get_attribute("#stepper-check", "aria-current") == "step"

    page.click("#check")
    poses = served.station.workspace(1).check_settings().poses
    confirmation = page.inner_text("#confirm-text")
    named = int(re.search(r"the check: (\d+) moves", confirmation).group(1))
    assert f"at {poses} poses" in confirmation
    assert page.evaluate("document.getElementById('confirm').className") == "confirm-motion"
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    run = served.station.runs.get(int(page.url.rsplit("/", 1)[1]))
    wait_js(page, f"Number(document.getElementById('samples').textContent) > 0 || {RUN_ENDED_JS}")
    wait_for_run_end(page, disk, RUN_ENDED_JS)
    assert page.inner_text("#run-state") == "finished", page.inner_text("#message")
    assert run.moves_total == named
    assert int(page.inner_text("#moves")) == named and int(page.inner_text("#move")) == named
    assert int(page.inner_text("#samples")) == run.samples > 0
    assert int(page.inner_text("#visible")) == run.visible
    page.click("#back")
    passed = page.inner_text("#checks").startswith("PASS")
    assert page.get_attribute("#stepper-check", "data-grade") == ("good" if passed else "poor")


def test_a_run_counts_the_move_of_its_last_sample_and_every_move_once_finished():
    from spacecal.station.motions import Run

    run = Run(1, 1, "UR10 bay 1", settings=None, motion="check")
    run.moves_total = 6
    assert run.snapshot(0)["move"] == 0  # nothing sampled yet
    run.samples, run.visible, run.move_index = 30, 28, 4  # sampling the last hold
    shown = run.snapshot(0)
    assert (shown["move"], shown["samples"], shown["visible"]) == (5, 30, 28)
    run.state = "stopped"
    assert run.snapshot(0)["move"] == 5  # stopped there
    run.state = "finished"  # the last move, back home, took no samples
    assert run.snapshot(0)["move"] == 6
    from pathlib import Path

    from spacecal import app
    from spacecal.workflows.acquisition import AcquisitionResult

    result = AcquisitionResult(Path("rec.csv"), 500, 480, moves_completed=19, moves_total=19)
    run.output = SimpleNamespace(record=app.AcquireOutput(moves=19, motion_time_s=60.0, result=result))
    assert run.snapshot(0)["move"] == 19  # an acquisition says how many it completed
