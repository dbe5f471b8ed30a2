"""The Slicer link's messages, without a connection: plan points read from POINT and TRANSFORM
bodies packed by pyigtl (an independent packer) or by hand from the protocol's layout
(igtl_point.h: name char[64], group char[32], RGBA u8[4], XYZ float32[3], radius float32,
owner char[20]; TRANSFORM: 12 float32, the rotation column by column, then the translation),
and our TRANSFORM read back by pyigtl."""

import struct

import numpy as np
import pytest

pyigtl = pytest.importorskip("pyigtl")

from spacecal.adapters.slicer_link import (  # noqa: E402
    SlicerLink,
    plan_points_from_point_message,
    point_from_transform_message,
    transform_message,
)
from spacecal.core.errors import DeviceError, InvalidInputError  # noqa: E402
from spacecal.records.needle_plan import ImageRegistration  # noqa: E402

HEADER_SIZE = 58


def point_body(names, positions_ras):
    """A POINT body as pyigtl packs it (header version 1: the body is the content)."""
    packed = pyigtl.PointMessage(positions=positions_ras, names=names, device_name="Plan").pack()
    return packed[HEADER_SIZE:]


def raw_element(name: bytes, xyz) -> bytes:
    """One POINT element by hand, from the layout in igtl_point.h."""
    return struct.pack(">64s32s4B3ff20s", name, b"Selected", 255, 0, 0, 255, *xyz, 0.0, b"")


def transform_body(matrix) -> bytes:
    m = np.asarray(matrix, dtype=float)
    return struct.pack(">12f", *m[:3, :3].T.reshape(-1), *m[:3, 3])


def test_the_entry_and_target_of_a_point_list_come_in_lps():
    # asymmetric numbers: every sign and every axis tells; x and y negated, z kept
    body = point_body(["F-1", "Entry", "target"], [[1, 2, 3], [12.5, -40.25, 7.0], [-31.75, 18.5, -102.0]])
    entry, target, labels = plan_points_from_point_message(body)
    assert np.array_equal(entry, [-12.5, 40.25, 7.0])
    assert np.array_equal(target, [31.75, -18.5, -102.0])
    assert labels == ("Entry", "target")


def test_start_and_end_are_the_entry_and_target_as_in_a_markups_file():
    entry, target, _ = plan_points_from_point_message(point_body(["end", "start"], [[1, 1, 1], [2, 3, 4]]))
    assert np.array_equal(entry, [-2, -3, 4]) and np.array_equal(target, [-1, -1, 1])


@pytest.mark.parametrize(
    "body, message",
    [
        (raw_element(b"entry", (0, 0, 0)) + raw_element(b"target", (np.nan, 0, 0)), "non-finite"),
        (raw_element(b"entry", (0, 0, 0)) + raw_element(b"target", (np.inf, 0, 0)), "non-finite"),
        (raw_element(b"entry", (0, 0, 0)) + raw_element(b"target", (1e30, 0, 0)), "mm from the origin"),
        (raw_element(b"entry", (0, 0, 0)) + raw_element(b"F-2", (np.nan, 0, 0)), "non-finite"),
        (raw_element(b"entry", (0, 0, 0)) + raw_element(b"F-2", (5, 0, 0)), "no point labelled 'target'"),
        (
            raw_element(b"entry", (0, 0, 0)) * 2 + raw_element(b"target", (9, 0, 0)),
            "2 points are labelled 'entry'",
        ),
        (raw_element(b"entry", (0, 0, 0)) + raw_element(b"tar\x1b[2Jget", (9, 0, 0)), "U\\+001B"),
        (raw_element(b"entry", (0, 0, 0)) + raw_element(b"\xff\xfe", (9, 0, 0)), "not UTF-8"),
        (raw_element(b"entry", (0, 0, 0))[:-1], "not n x 136"),
        (b"", "not n x 136"),
    ],
    ids=[
        "nan",
        "inf",
        "absurd",
        "nan-elsewhere",
        "no-target",
        "two-entries",
        "escape",
        "not-utf8",
        "cut",
        "empty",
    ],
)
def test_a_bad_point_list_is_refused_in_one_line(body, message):
    with pytest.raises(InvalidInputError, match=message) as refused:
        plan_points_from_point_message(body)
    assert "\n" not in str(refused.value) and "\x1b" not in str(refused.value)


def test_a_transforms_translation_is_its_point_in_lps():
    matrix = np.array([[0, -1, 0, -30.5], [1, 0, 0, 22.25], [0, 0, 1, -98.0], [0, 0, 0, 1]])
    assert np.array_equal(
        point_from_transform_message(transform_body(matrix), "TargetToRAS"), [30.5, -22.25, -98.0]
    )


@pytest.mark.parametrize("where", [0, 4, 9, 11])
def test_a_transform_with_a_non_finite_number_is_refused(where):
    values = list(np.eye(4)[:3, :3].T.reshape(-1)) + [1.0, 2.0, 3.0]
    values[where] = float("nan")
    with pytest.raises(InvalidInputError, match="non-finite"):
        point_from_transform_message(struct.pack(">12f", *values), "TargetToRAS")
    with pytest.raises(InvalidInputError, match="expected 48"):
        point_from_transform_message(struct.pack(">12f", *values)[:44], "TargetToRAS")


def test_our_transform_reads_back_in_pyigtl():
    c, s = np.cos(0.4), np.sin(0.4)
    matrix = np.array([[c, 0, s, 101.5], [0, 1, 0, -7.25], [-s, 0, c, 1333.0], [0, 0, 0, 1]])
    packed = transform_message("NeedleToTracker", matrix, 1_700_000_000.25)
    fields = pyigtl.MessageBase.parse_header(packed[:HEADER_SIZE])
    message = pyigtl.MessageBase.create_message(fields["message_type"])
    message.unpack(fields, packed[HEADER_SIZE:])
    assert fields["device_name"] == "NeedleToTracker" and fields["body_size"] == 48
    assert fields["timestamp"] == pytest.approx(1_700_000_000.25, abs=1e-6)
    assert np.allclose(message.matrix, matrix, atol=1e-4)


def test_refusals_of_the_link_itself():
    with pytest.raises(InvalidInputError, match="rate 200 Hz"):
        SlicerLink.serve(port=0, rate_hz=200)
    with SlicerLink.serve(port=0) as link:
        with pytest.raises(DeviceError, match="cannot listen"):
            SlicerLink.serve(port=link.port)
        with pytest.raises(InvalidInputError, match="non-finite"):
            link.update_needle(np.full((4, 4), np.nan))
        with pytest.raises(InvalidInputError, match="det"):
            link.update_needle(np.diag([1.0, 1.0, -1.0, 1.0]))
        unstated = ImageRegistration(np.eye(4), image_frame="image")
        with pytest.raises(InvalidInputError, match="LPS or RAS"):
            link.set_registration(unstated)
        assert link.latest_plan() is None
