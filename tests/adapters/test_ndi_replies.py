"""The NDI replies spacecal parses itself (PHRQ, PHSR): ASCII hexadecimal of the lengths the
Combined API gives, or a DeviceError in one line. Needs no ndicapy."""

import pytest

from spacecal.adapters.ndi import port_handle, port_handle_statuses
from spacecal.core.errors import DeviceError


def test_a_phsr_reply_is_read():
    assert port_handle_statuses("00") == []
    assert port_handle_statuses("020A0310Bfff") == [(0x0A, 0x031), (0x0B, 0xFFF)]


@pytest.mark.parametrize(
    ("reply", "words"),
    [
        ("", "not hexadecimal"),
        ("0G", "not hexadecimal"),
        ("0x", "not hexadecimal"),
        ("010A0x1", "not hexadecimal"),
        ("010A_31", "not hexadecimal"),
        ("01 A031", "not hexadecimal"),
        ("01\u0660A031", "not hexadecimal"),
        ("01", "0 characters for 1 port handle(s) (expected 5)"),
        ("FF0A031", "5 characters for 255 port handle(s) (expected 1275)"),
        ("010A0311", "6 characters for 1 port handle(s)"),
        (None, "not hexadecimal"),
    ],
)
def test_a_phsr_reply_of_another_form_is_a_device_error(reply, words):
    with pytest.raises(DeviceError, match="PHSR reply") as caught:
        port_handle_statuses(reply)
    assert words in str(caught.value) and "\n" not in str(caught.value)


def test_a_phrq_reply_is_one_handle():
    assert port_handle("0A") == 0x0A and port_handle("ff") == 0xFF


@pytest.mark.parametrize("reply", ["", "A", "0AB", "0x", "G1", "\u0661\u0662", None, "ERROR01"])
def test_a_phrq_reply_of_another_form_is_a_device_error(reply):
    with pytest.raises(DeviceError, match="PHRQ reply"):
        port_handle(reply)
