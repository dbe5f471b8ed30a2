"""The NatNet reader on packets packed here by hand from the SDK's layout (little-endian; see
:mod:`spacecal.adapters.natnet`), and on the fake's packets cut and spoiled: units, the
quaternion's order, the tracking-valid flag, and every malformed packet one MalformedPacket line,
never another exception."""

import struct

import numpy as np
import pytest

from spacecal.adapters import DeviceOptions
from spacecal.adapters.natnet import (
    BodyPose,
    MalformedPacket,
    natnet_options,
    parse_frame,
    parse_model_definitions,
    parse_server_info,
    pose_of,
    split_packet,
)
from spacecal.core.errors import InvalidInputError
from spacecal.testing.fakes.natnet import FakeMotive

V3, V41 = (3, 1, 0, 0), (4, 1, 0, 0)


def frame_payload_3x(bodies, frame_number=7, timestamp=12.5):
    """A NatNet 3.x frame: no marker sets, no other markers, ``bodies`` as (id, x, y, z, qx, qy,
    qz, qw, error, params), nothing else, then the suffix."""
    payload = struct.pack("<i", frame_number) + struct.pack("<i", 0) + struct.pack("<i", 0)
    payload += struct.pack("<i", len(bodies)) + b"".join(struct.pack("<i3f4ffh", *b) for b in bodies)
    payload += struct.pack("<iiii", 0, 0, 0, 0)  # skeletons, labeled markers, force plates, devices
    return payload + struct.pack("<IId3Qhi", 0, 0, timestamp, 0, 0, 0, 0, 0)


def test_position_is_converted_from_m_to_mm_and_the_quaternion_is_read_scalar_last():
    half = np.sqrt(0.5)
    # 90 deg about z, as Motive sends it: qx qy qz qw = 0 0 sin45 cos45
    frame = parse_frame(frame_payload_3x([(3, 0.1, -0.25, 1.5, 0.0, 0.0, half, half, 0.0004, 1)]), V3)
    assert frame.frame_number == 7 and frame.timestamp_s == 12.5
    body = frame.bodies[3]
    assert body.valid and body.error_m == pytest.approx(0.0004)
    pose = pose_of(body)
    assert pose is not None
    # float32 metres: 1.5 m holds to 1.2e-7 m, i.e. 1e-4 mm
    np.testing.assert_allclose(pose[:3, 3], [100.0, -250.0, 1500.0], atol=1e-3)
    # the body's x axis is the tracker's y axis (a scalar-first reading would give another rotation)
    np.testing.assert_allclose(pose[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(pose[:3, :3] @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-6)


def test_the_tracking_valid_flag_is_bit_0_of_the_body_parameters():
    frame = parse_frame(
        frame_payload_3x([(1, 0.1, 0.2, 1.0, 0, 0, 0, 1, 0, 0), (2, 0.1, 0.2, 1.0, 0, 0, 0, 1, 0, 0b10)]), V3
    )
    assert not frame.bodies[1].valid and not frame.bodies[2].valid
    assert parse_frame(frame_payload_3x([(1, 0.1, 0.2, 1.0, 0, 0, 0, 1, 0, 0b11)]), V3).bodies[1].valid


@pytest.mark.parametrize(
    "position,quaternion",
    [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        ((0.1, 0.2, 1.0), (0.0, 0.0, 0.0, 0.0)),
    ],
)
def test_zeros_are_no_pose(position, quaternion):
    assert pose_of(BodyPose(position, quaternion, 0.0, True)) is None


def test_server_info_names_the_application_and_both_versions():
    payload = b"Motive".ljust(256, b"\0") + bytes((3, 1, 2, 0)) + bytes((4, 1, 0, 0)) + b"\x00" * 7
    info = parse_server_info(payload)
    assert (info.application, info.application_text, info.natnet_text) == ("Motive", "3.1.2.0", "4.1.0.0")
    with pytest.raises(MalformedPacket, match="NAT_SERVERINFO ends"):
        parse_server_info(payload[:200])


@pytest.mark.parametrize("version", [(3, 0), (3, 1), (4, 0), (4, 1), (4, 2)])
def test_the_fakes_packets_of_each_version_read_back(version):
    pose = np.eye(4)
    pose[:3, 3] = [10.0, 20.0, 1300.0]
    fake = FakeMotive(lambda t: {"B": pose}, bodies=("A", "B"), version=version, rate_hz=1.0)
    try:
        full = (*version, 0, 0)
        message, payload = split_packet(fake.model_definitions())
        assert message == 5 and parse_model_definitions(payload, full) == {"A": 1, "B": 2}
        message, payload = split_packet(fake.frame(42, 3.25))
        frame = parse_frame(payload, full)
    finally:
        fake.close()
    assert message == 7 and (frame.frame_number, frame.timestamp_s) == (42, 3.25)
    assert set(frame.bodies) == {1, 2} and frame.bodies[2].valid and not frame.bodies[1].valid
    np.testing.assert_allclose(pose_of(frame.bodies[2]), pose, atol=1e-3)


@pytest.fixture(scope="module")
def good_packets():
    pose = np.eye(4)
    pose[:3, 3] = [10.0, 20.0, 1300.0]
    packets = {}
    for version in [(3, 1), (4, 1)]:
        fake = FakeMotive(lambda t: {"B": pose}, bodies=("A", "B"), version=version, rate_hz=1.0)
        packets[version] = (fake.frame(1, 1.0), fake.model_definitions())
        fake.close()
    return packets


@pytest.mark.parametrize("version", [(3, 1), (4, 1)])
def test_every_truncation_of_a_packet_is_one_malformed_packet_line(good_packets, version):
    full = (*version, 0, 0)
    # what the reader does not need after the timestamp: three u64 stamps, (4.0 on) the
    # precision timestamp, params and the end-of-data tag
    unread = 24 + (8 if version >= (4, 0) else 0) + 6
    for packet, parse, needed in zip(
        good_packets[version], (parse_frame, parse_model_definitions), (unread, 0), strict=True
    ):
        _, payload = split_packet(packet)
        for cut in range(len(payload) - needed):
            with pytest.raises(MalformedPacket) as caught:
                parse(payload[:cut], full)
            assert "\n" not in str(caught.value)
        parse(payload[: len(payload) - needed], full)


@pytest.mark.parametrize("version", [(3, 1), (4, 1)])
def test_random_bytes_in_place_of_a_packet_are_malformed_or_read_never_an_error(good_packets, version):
    rng = np.random.default_rng(7)
    full = (*version, 0, 0)
    _, payload = split_packet(good_packets[version][0])
    for _ in range(2000):
        spoiled = bytearray(payload)
        for position in rng.integers(0, len(spoiled), size=rng.integers(1, 6)):
            spoiled[position] = int(rng.integers(0, 256))
        try:
            parse_frame(bytes(spoiled), full)
        except MalformedPacket:
            pass


@pytest.mark.parametrize(
    "payload,message",
    [
        # a rigid-body count of 2**30: refused before any loop, by the bytes left
        (struct.pack("<iiii", 7, 0, 0, 2**30), "1073741824 rigid bodies cannot fit"),
        (struct.pack("<iiii", 7, 0, 0, -1), "-1 rigid bodies cannot fit"),
        (struct.pack("<ii", 7, 1) + b"name without its end", "a name without its end"),
        (struct.pack("<i", 7), "ends 4 byte"),
    ],
)
def test_absurd_counts_and_missing_ends_are_one_line(payload, message):
    with pytest.raises(MalformedPacket, match=message):
        parse_frame(payload, V3)


def test_a_41_byte_count_that_does_not_match_its_rigid_bodies_is_refused():
    body = struct.pack("<i3f4ffh", 1, 0.1, 0.2, 1.0, 0, 0, 0, 1, 0, 1)
    payload = struct.pack("<i", 7) + struct.pack("<ii", 0, 0) * 2
    payload += struct.pack("<ii", 1, len(body) + 4) + body + b"\0" * 4
    payload += struct.pack("<ii", 0, 0) * 5 + struct.pack("<IId", 0, 0, 1.0)
    with pytest.raises(MalformedPacket, match="4 bytes after its 1 rigid bodies"):
        parse_frame(payload, V41)


@pytest.mark.parametrize(
    "packet,message",
    [
        (b"\x07\x00", "2-byte datagram"),
        (struct.pack("<HH", 7, 100) + b"\0" * 50, "announces 100 payload bytes, 50"),
    ],
)
def test_a_datagram_shorter_than_it_says_is_truncated(packet, message):
    with pytest.raises(MalformedPacket, match=message):
        split_packet(packet)


def test_the_url_query_names_the_marker_and_the_tools():
    guide = DeviceOptions(tools=(("guide", "Guide"),))
    chosen = natnet_options("body=Tool%20A&tools=Pointer,Reference", guide)
    assert chosen.body == "Tool A"
    assert chosen.tools == (("Pointer", "Pointer"), ("Reference", "Reference"), ("guide", "Guide"))
    assert chosen.multicast is None
    assert natnet_options("body=M&multicast=239.255.42.99&data_port=1600", DeviceOptions()).data_port == 1600


@pytest.mark.parametrize(
    "query,message",
    [
        ("", "needs the marker's rigid-body name: natnet://HOST\\?body=NAME"),
        ("bdy=Marker", "takes body=, tools=, multicast=, data_port=; not bdy="),
        ("body=M&tools=M", "named twice"),
        ("body=M&data_port=99999", "data_port must be a port number"),
        ("body", "is not key=value"),
    ],
)
def test_a_bad_query_is_one_line(query, message):
    with pytest.raises(InvalidInputError, match=message) as caught:
        natnet_options(query, DeviceOptions())
    assert "\n" not in str(caught.value)
