"""``spacecal doctor``: read-only checks of a robot and a tracker, one line per finding in an
operator's words, exit 1 on any problem; nothing uploaded, nothing moved, everything closed."""

import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("ndicapy")

from .ur_runs import SPACECAL, assert_everything_closed, last_line, run, stats, tracker_url, ur_world

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime


@pytest.fixture(scope="module")
def world():
    process = ur_world("eseries", "--calibrated-kinematics", "--pendant-tcp", "0,0,180,0,0,0.5")
    yield process
    process.stop()


def doctor(world, rom, *extra):
    return run(
        [
            *SPACECAL,
            "doctor",
            "--robot",
            f"ur://{world.info['host']}",
            "--tracker",
            tracker_url(world),
            "--rom",
            str(rom),
            "--robot-model",
            "UR10e",
            *extra,
        ],
        timeout_s=60,
    )


def test_a_ready_system_passes_and_nothing_is_uploaded(world, rom_file):
    result = doctor(world, rom_file)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    for expected in (
        "robot: controller version: ok: PolyScope 5.11.1.108318 (e-Series), robot state at 500 Hz",
        "robot: serial number: ok: 20195500000",
        "robot: remote control: ok: on",
        "robot: robot mode: ok: RUNNING",
        "robot: safety: ok: normal",
        "robot: RTDE registers: ok:",
        "robot: kinematics: ok: factory-calibrated (checksums",
        "robot: tool (TCP): ok: set on the teach pendant: X 0.0 Y 0.0 Z 180.0 mm, RX 0.0000 RY 0.0000 RZ 0.5",
    ):
        assert any(line.startswith(expected) for line in lines), (expected, result.stdout)
    assert lines[-1] == "every check passed: spacecal acquire can start"
    assert any(
        line.startswith("tracker: tracker: ok: Polaris") and ", serial number P6-00042, API revision" in line
        for line in lines
    ), result.stdout
    after = assert_everything_closed(world)
    assert after["scripts_uploaded"] == 0 and after["commands"] == []


def test_problems_are_each_named_and_fail_the_check(world, rom_file):
    world.control("ur remote_control off")
    world.control("ur registers_taken on")
    world.control("ur safeguard_stop")
    try:
        result = doctor(world, rom_file, "--tool", "0,0,180,0,0,0")
    finally:
        world.control("ur remote_control on")
        world.control("ur registers_taken off")
        world.control("ur safeguard_reset")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    problems = [line for line in result.stdout.splitlines() if ": PROBLEM: " in line]
    subjects = [line.split(":")[1].strip() for line in problems]
    assert subjects == ["remote control", "safety", "RTDE registers", "tool (TCP)"], result.stdout
    assert last_line(result.stderr) == (
        "spacecal: error: 4 problems found (marked PROBLEM above); fix them before running spacecal acquire"
    )
    assert stats(world)["scripts_uploaded"] == 0
    assert_everything_closed(world)


def test_kinematics_published_as_nan_are_a_problem_and_the_tracker_is_still_checked(world, rom_file):
    """A controller whose primary interface publishes a NaN DH length (a controller fault) is
    named as a kinematics problem; spacecal never computes with it, and checks the tracker too."""
    world.control("ur primary nan")
    try:
        result = doctor(world, rom_file)
    finally:
        world.control("ur primary on")
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stdout + result.stderr
    problems = [line for line in result.stdout.splitlines() if ": PROBLEM: " in line]
    assert problems == [
        "robot: kinematics: PROBLEM: the controller's primary interface published kinematics that are not "
        "finite numbers (DH a): a controller fault; spacecal cannot compute the TCP with its model"
    ], result.stdout
    assert any(line.startswith("tracker: ") for line in result.stdout.splitlines()), result.stdout
    assert_everything_closed(world)


def test_a_robot_that_does_not_answer_is_a_problem_not_a_crash(tmp_path):
    result = run([*SPACECAL, "doctor", "--robot", "ur://127.0.0.254"], timeout_s=60)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "robot: connection: PROBLEM: no UR controller answers RTDE on 127.0.0.254:30004" in result.stdout
    nothing = run([*SPACECAL, "doctor"])
    assert nothing.returncode == 1 and "name a device to check" in last_line(nothing.stderr)


def test_without_a_tool_definition_the_robot_is_still_checked(world):
    # the missing --rom is the tracker's finding; the robot's findings are reported beside it
    result = run(
        [
            *SPACECAL,
            "doctor",
            "--robot",
            f"ur://{world.info['host']}",
            "--tracker",
            tracker_url(world),
            "--robot-model",
            "UR10e",
        ],
        timeout_s=60,
    )
    assert result.returncode == 1 and "Traceback" not in result.stderr
    lines = result.stdout.splitlines()
    assert any(line.startswith("robot: remote control: ok: on") for line in lines), result.stdout
    assert any(line.startswith("tracker: tool definition: PROBLEM:") and "--rom" in line for line in lines)
    assert_everything_closed(world)


def test_the_model_is_the_controllers_unless_a_wrong_one_is_named(world, rom_file):
    # an e-Series controller without --robot-model: the UR10e it names is used
    argv = [*SPACECAL, "doctor", "--robot", f"ur://{world.info['host']}", "--tracker", tracker_url(world)]
    taken = run([*argv, "--rom", str(rom_file)], timeout_s=60)
    assert taken.returncode == 0, taken.stdout + taken.stderr
    assert "robot: robot model: ok: UR10e, as the controller names it" in taken.stdout.splitlines()
    # an explicit model that is not the controller's is refused
    wrong = run([*argv, "--rom", str(rom_file), "--robot-model", "UR10"], timeout_s=60)
    assert (
        wrong.returncode == 1
        and "the controller says this is a UR10e, but --robot-model is UR10" in wrong.stdout
    )
    assert_everything_closed(world)


def _closed_loopback_host() -> str:
    """A loopback address on which nothing listens on the RTDE port (checked, not assumed)."""
    import socket

    for last in range(250, 200, -1):
        host = f"127.0.3.{last}"
        try:
            socket.create_connection((host, 30004), timeout=1.0).close()
        except ConnectionRefusedError:
            return host
    pytest.skip("every tried loopback address has something on port 30004")


def test_an_unreachable_robot_is_spacecals_one_line_only(tmp_path):
    # ur_rtde prints "connect: Connection refused" to the process's stderr before it raises;
    # the user reads spacecal's own line alone
    host = _closed_loopback_host()
    doctor = run([*SPACECAL, "doctor", "--robot", f"ur://{host}"], timeout_s=60)
    assert doctor.returncode == 1
    assert doctor.stdout.splitlines() == [
        f"robot: connection: PROBLEM: no UR controller answers RTDE on {host}:30004 (Connection refused)"
    ]
    assert doctor.stderr.splitlines() == [
        "spacecal: error: 1 problem found (marked PROBLEM above); fix it before running spacecal acquire"
    ]
    rom = tmp_path / "marker.rom"
    rom.write_bytes(b"")  # never read: the robot is opened first
    acquire = run(
        [
            *SPACECAL,
            "acquire",
            "--robot",
            f"ur://{host}",
            "--tracker",
            "ndi://127.0.0.1:1",
            "--rom",
            str(rom),
            "-o",
            str(tmp_path / "rec.csv"),
        ],
        timeout_s=60,
    )
    assert acquire.returncode == 1
    assert acquire.stderr.splitlines() == [
        f"spacecal: error: no UR controller answers RTDE on {host}:30004 (Connection refused)"
    ]


def test_native_output_while_connecting_is_held_and_dropped_on_failure(capfd):
    import os

    from spacecal.adapters.ur import _native_stderr_held

    with pytest.raises(RuntimeError), _native_stderr_held():
        os.write(2, b"connect: Connection refused\n")
        raise RuntimeError("Could not connect")
    assert capfd.readouterr().err == ""
    with _native_stderr_held():
        os.write(2, b"a library's note\n")
    assert capfd.readouterr().err == "a library's note\n"


def test_without_rom_or_robot_model_every_check_runs_and_the_rom_is_one_finding(world):
    # as a new user first runs it: only the two URLs
    result = run(
        [*SPACECAL, "doctor", "--robot", f"ur://{world.info['host']}", "--tracker", tracker_url(world)],
        timeout_s=60,
    )
    assert result.returncode == 1
    lines = result.stdout.splitlines()
    robot = [line for line in lines if line.startswith("robot: ")]
    assert "robot: robot model: ok: UR10e, as the controller names it" in robot
    assert any(line.startswith("robot: robot mode: ok: RUNNING") for line in robot)
    assert "robot: safety: ok: normal" in robot
    assert any(line.startswith("robot: controller version: ok: PolyScope 5") for line in robot)
    problems = [line for line in lines if ": PROBLEM: " in line]
    assert len(problems) == 1 and problems[0].startswith("tracker: tool definition: PROBLEM:")
    assert "--rom" in problems[0]
    assert result.stderr.splitlines() == [
        "spacecal: error: 1 problem found (marked PROBLEM above); fix it before running spacecal acquire"
    ]
    assert_everything_closed(world)
