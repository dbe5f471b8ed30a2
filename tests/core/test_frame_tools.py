"""TrackerFrame.tools: further tools checked at the device boundary as the marker's pose is."""

import numpy as np
import pytest

from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FRAME_INVALID, FRAME_MISSING, FRAME_OK, TrackerFrame


def pose(z=-1000.0):
    matrix = np.eye(4)
    matrix[:3, 3] = [10.0, 20.0, z]
    return matrix


def test_a_frame_without_tools_has_none():
    frame = TrackerFrame(1.0, 1, FRAME_OK, pose())
    assert frame.tools == {} and frame.tool_statuses == {} and frame.refused_tools == ()


def test_tools_are_kept_checked_and_read_only():
    scaled = pose() * 2.0
    scaled[3] = [0, 0, 0, 1]
    frame = TrackerFrame(
        1.0,
        1,
        FRAME_OK,
        pose(),
        tools={"pointer": pose(-900.0), "reference": None, "bad": scaled, "far": pose(-1e9), "doubt": pose()},
        tool_statuses={"doubt": "partially_out_of_volume"},
    )
    assert np.array_equal(frame.tool("pointer"), pose(-900.0))
    assert frame.tool_statuses["pointer"] == FRAME_OK
    assert frame.tool("reference") is None and frame.tool_statuses["reference"] == FRAME_MISSING
    assert frame.tools["bad"] is None and frame.tools["far"] is None
    assert frame.tool_statuses["bad"] == FRAME_INVALID and frame.refused_tools == ("bad", "far")
    assert frame.tools["doubt"] is None and frame.tool_statuses["doubt"] == "partially_out_of_volume"
    assert frame.status == FRAME_OK and frame.tracker_from_marker is not None  # the marker as it was
    with pytest.raises(ValueError):
        frame.tools["pointer"][0, 0] = 5.0
    with pytest.raises(InvalidInputError, match="no tool 'stylus'.*bad, doubt, far, pointer, reference"):
        frame.tool("stylus")


def test_a_nameless_tool_or_an_unknown_status_is_a_device_error():
    with pytest.raises(DeviceError, match="name"):
        TrackerFrame(1.0, 1, FRAME_OK, pose(), tools={"": pose()})
    with pytest.raises(DeviceError, match="status"):
        TrackerFrame(1.0, 1, FRAME_OK, pose(), tools={"p": pose()}, tool_statuses={"p": "great"})
