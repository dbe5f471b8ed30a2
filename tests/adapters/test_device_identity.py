"""What a device says it is, recorded so a calibration names the one robot and tracker it
belongs to: the UR dashboard server's model, PolyScope version and serial number (from 5.6 on),
and the NDI ``VER 4`` text's model, serial number and freeze tag; through the real clients
against the protocol fakes, and hostile answers kept out."""

import pytest

pytest.importorskip("rtde_receive")
pytest.importorskip("ndicapy")

from spacecal.adapters.ndi import NDITracker, identity_from_version_text
from spacecal.adapters.ur import URRobot
from spacecal.core.ports import DeviceIdentity

from .ur_runs import ur_world


@pytest.mark.parametrize(
    "generation,expected",
    [
        # PolyScope 3 has no `get serial number`: spacecal does not ask, and records none
        ("cb3", DeviceIdentity("UR10", None, "PolyScope 3.15.7.106331")),
        ("eseries", DeviceIdentity("UR10e", "20195500000", "PolyScope 5.11.1.108318")),
    ],
)
@pytest.mark.realtime
def test_a_ur_controller_says_its_model_version_and_serial(generation, expected):
    world = ur_world(generation)
    robot = URRobot(world.info["host"])
    try:
        assert robot.identity() == expected
    finally:
        robot.close()
        world.stop()


@pytest.mark.parametrize("transport", ["tcp", "pty"])
@pytest.mark.realtime
def test_an_ndi_tracker_says_its_model_serial_and_firmware(world, rom_file, transport):
    if transport == "tcp":
        tracker = NDITracker(world.info["host"], world.info["ndi_port"], [rom_file])
    else:
        tracker = NDITracker(world.info["ndi_pty"], None, [rom_file])
    try:
        identity = tracker.identity()
    finally:
        tracker.close()
    assert identity.serial == "P6-00042"
    assert identity.model is not None and identity.model.startswith("Polaris")
    assert identity.firmware is not None and identity.firmware.endswith("Rev 007.000")


VER_TEXT = (
    "Polaris Vega Control Firmware\nNDI S/N: P9-01234\nCharacterization Date: 01/01/20\n"
    "Freeze Tag: Polaris Vega Rev 012.003\nFreeze Date: 01/01/20\n(C) Northern Digital Inc.\n"
)


@pytest.mark.parametrize(
    "text,expected",
    [
        (VER_TEXT, DeviceIdentity("Polaris Vega", "P9-01234", "Polaris Vega Rev 012.003")),
        (
            "Polaris Vicra Control Firmware\nSerial Number: 8700339\n",
            DeviceIdentity("Polaris Vicra", "8700339"),
        ),
        ("Polaris Control Firmware\n", DeviceIdentity("Polaris")),
        # hostile or broken replies: nothing that is not plain text is recorded
        ("x" * 500 + "\nS/N: " + "9" * 200, DeviceIdentity("x" * 64)),
        # control characters are dropped (the escape sequence no longer is one)
        ('Vega\x00\x1b[2J\nS/N: "; rm -rf /\nFreeze Tag: \x07\x08\n', DeviceIdentity("Vega[2J")),
        ("\n\n", DeviceIdentity()),
    ],
)
def test_an_ndi_version_text_is_read_for_what_it_says(text, expected):
    assert identity_from_version_text(text) == expected


@pytest.mark.parametrize(
    "serial,kept",
    [
        ("20195500000", "20195500000"),
        ("could not understand: 'get serial number'", None),  # a controller before PolyScope 5.6
        ("<script>", None),
        ("", None),
        ("A" * 41, None),
    ],
)
def test_only_a_serial_number_is_kept_as_one(serial, kept):
    identity = DeviceIdentity("UR10e", serial, "PolyScope 5.11")
    assert identity.serial == kept
    assert identity.as_metadata() == {
        "model": "UR10e",
        "firmware": "PolyScope 5.11",
        **({"serial": kept} if kept else {}),
    }
