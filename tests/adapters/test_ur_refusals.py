"""A controller that refuses us: ``spacecal acquire`` says in one line what to do on the teach
pendant, exits 1 without a traceback, uploads and moves nothing and closes every device; and
``--dry-run`` refuses the same way (a passing dry run means the real run can start)."""

import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from .ur_runs import acquire_argv, assert_everything_closed, last_line, run, stats, ur_world

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: name -> (generation, what the pendant / another client did, how it is undone, the line says)
REFUSALS = {
    "local control (e-Series)": (
        "eseries",
        "remote_control off",
        "remote_control on",
        "(remote control): the teach pendant is in Local control: switch it to Remote Control",
    ),
    "RTDE registers in use": (
        "cb3",
        "registers_taken on",
        "registers_taken off",
        "(RTDE registers): 26 RTDE input registers spacecal's control program needs",
    ),
    "arm powered off": (
        "cb3",
        "power_off",
        "mode RUNNING",
        "(robot mode): the arm is powered off: power it on",
    ),
    "brakes engaged": (
        "eseries",
        "mode IDLE",
        "mode RUNNING",
        "(robot mode): the arm is powered on with its brakes",
    ),
    "controller booting": (
        "cb3",
        "mode BOOTING",
        "mode RUNNING",
        "(robot mode): the controller is still booting",
    ),
    "protective stop": (
        "eseries",
        "protective_stop",
        "clear",
        "(safety): protective stop: find what the arm hit",
    ),
    "safeguard stop": (
        "cb3",
        "safeguard_stop",
        "safeguard_reset",
        "(safety): safeguard stop: close the safeguard",
    ),
}


@pytest.fixture(scope="module")
def worlds():
    made = {generation: ur_world(generation) for generation in ("cb3", "eseries")}
    yield made
    for world in made.values():
        world.stop()


@pytest.mark.parametrize("refusal", sorted(REFUSALS))
def test_a_controller_that_refuses_us_moves_nothing(worlds, rom_file, tmp_path, refusal):
    generation, condition, undo, says = REFUSALS[refusal]
    world = worlds[generation]
    before = stats(world)
    assert world.control(f"ur {condition}") == "OK"
    try:
        for dry_run in (False, True):
            recording = tmp_path / f"rec-{dry_run}.csv"
            argv = acquire_argv(world, generation, recording, rom_file, *(["--dry-run"] if dry_run else []))
            result = run(argv, timeout_s=60)
            assert result.returncode == 1, result.stdout + result.stderr
            line = last_line(result.stderr)
            assert line.startswith("spacecal: error: the robot is not ready ") and says in line, line
            assert line.endswith("nothing moved") and "Traceback" not in result.stderr
            assert not recording.exists()
            after = assert_everything_closed(world)
            assert after["scripts_uploaded"] == before["scripts_uploaded"] and after["commands"] == []
            assert after["still_for_s"] > 1.0
    finally:
        world.control(f"ur {undo}")


def test_a_tool_that_differs_from_the_pendant_is_refused_and_the_pendant_tool_is_used(rom_file, tmp_path):
    """A TCP rotated on the pendant never passes silently: a --tool without the rotation is
    refused with the pendant's values; --tool controller (the default) plans with them."""
    world = ur_world("cb3", "--pendant-tcp", "0,0,200,0,0.3,0")
    try:
        for tool in (
            ["--tool", "0,0,200,0,0,0"],
            ["--tool-offset-mm", "0,0,200"],
            ["--tool", "0,0,200,0,0.31,0"],
        ):
            result = run(acquire_argv(world, "cb3", tmp_path / "rec.csv", rom_file, "--dry-run", *tool))
            line = last_line(result.stderr)
            assert result.returncode == 1 and "(tool (TCP)): --tool is 0.0 mm and" in line, result.stderr
            assert "0.0000,0.3000,0.0000 rad" in line and "--tool controller" in line
        assert_everything_closed(world)
        for tool in ([], ["--tool", "0,0,200,0,0.3,0"]):
            result = run(acquire_argv(world, "cb3", tmp_path / "rec.csv", rom_file, "--dry-run", *tool))
            assert result.returncode == 0, result.stderr
            assert (
                "robot: tool (TCP): ok: set on the teach pendant: X 0.0 Y 0.0 Z 200.0 mm, RX 0.0000 RY 0.3000"
                in (result.stdout)
            )
        assert stats(world)["scripts_uploaded"] == 0
    finally:
        world.stop()


def test_the_robot_model_must_be_the_controllers(worlds, rom_file, tmp_path):
    argv = acquire_argv(worlds["eseries"], "eseries", tmp_path / "rec.csv", rom_file, "--dry-run")
    argv[argv.index("--robot-model") + 1] = "UR10"
    result = run(argv)
    assert result.returncode == 1
    assert "the controller says this is a UR10e, but --robot-model is UR10: pass --robot-model UR10e" in (
        last_line(result.stderr)
    )


def test_without_robot_model_acquire_takes_the_controllers(worlds, rom_file, tmp_path):
    # a UR10e (an e-Series controller whose dashboard says UR10) and no --robot-model: the
    # model is the one the controller names, and the dry run passes
    argv = acquire_argv(worlds["eseries"], "eseries", tmp_path / "rec.csv", rom_file, "--dry-run")
    at = argv.index("--robot-model")
    del argv[at : at + 2]
    result = run(argv)
    assert result.returncode == 0, result.stderr
    assert "note: robot: robot model: ok: UR10e, as the controller names it" in result.stdout.splitlines()
    assert "dry run: nothing moved" in result.stdout
    assert "but --robot-model is" not in result.stdout + result.stderr
    # an explicit model that is not the controller's is one line, exit 1
    wrong = run([*argv, "--robot-model", "UR10"])
    assert wrong.returncode == 1
    assert wrong.stderr.splitlines() == [
        "spacecal: error: the robot is not ready (robot model): the controller says this is a UR10e, "
        "but --robot-model is UR10: pass --robot-model UR10e; nothing moved"
    ]
    assert stats(worlds["eseries"])["scripts_uploaded"] == 0
