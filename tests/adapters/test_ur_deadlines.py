"""The UR controller's dashboard server (29999), primary interface (30001) and RTDE port (30004)
as spacecal talks to them directly: every conversation ends by one deadline, against ports that
stay silent, send a byte at a time, announce a huge message or close in the middle of one.

The ports are fixed, so each peer gets a loopback address of its own. The bounds are the
deadlines plus a margin for a loaded 2-core machine, never tight times."""

import itertools
import struct
import time

import pytest

from spacecal.adapters import ur
from spacecal.core.errors import DeviceError
from spacecal.testing.fakes.peers import Peer, announce, drip, hang_up, silent

from .loopback import NETWORK as _NETWORK

#: Real client libraries against the protocol fakes, on real time: run apart (-m realtime).
pytestmark = pytest.mark.realtime

#: Time on top of a deadline for a loaded machine, s.
MARGIN_S = 5.0
_addresses = itertools.count(1)

GREETING = b"Connected: Universal Robots Dashboard Server\n"
#: A primary-interface message header announcing 2 GB.
HUGE_PRIMARY = struct.pack(">iB", 0x7FFFFFFF, 16)
#: An RTDE package header: the largest size there is, of another kind than the answer.
HUGE_RTDE = struct.pack(">HB", 0xFFFF, ord("U"))


def peer_on(port: int, behaviour, honest: bytes = b""):
    """A peer on ``port`` of a fresh loopback address, behaving so from the first byte."""
    return Peer(
        lambda connection, peer: behaviour(connection, peer, honest),
        f"127.{_NETWORK}.1.{next(_addresses)}",
        port,
    )


def flood(connection, peer, honest=b""):
    """Bytes as fast as the client takes them, never a line end."""
    while not peer.stop.is_set() and not peer.client_gone(connection):
        connection.sendall(b"x" * 4096)


def assert_ends_by(started: float, deadline_s: float) -> None:
    assert time.monotonic() - started < deadline_s + MARGIN_S


DASHBOARD_PEERS = {
    "silent": (silent, b""),
    "a byte at a time": (drip, GREETING),
    "an endless line": (flood, b""),
    "closed mid-line": (hang_up, GREETING),
}


@pytest.mark.parametrize("name", list(DASHBOARD_PEERS))
def test_a_dashboard_conversation_ends_by_its_deadline(name):
    behaviour, honest = DASHBOARD_PEERS[name]
    with peer_on(ur.DASHBOARD_PORT, behaviour, honest) as peer:
        started = time.monotonic()
        with pytest.raises(DeviceError, match=f"dashboard server on {peer.host}:29999") as caught:
            ur.dashboard(peer.host, ["PolyscopeVersion", "get robot model"])
        assert_ends_by(started, ur.DASHBOARD_DEADLINE_S)
        assert "\n" not in str(caught.value)


@pytest.mark.parametrize("name", list(DASHBOARD_PEERS))
def test_the_stop_ends_by_its_deadline_never_raises_and_is_not_waited_for_twice(name):
    behaviour, honest = DASHBOARD_PEERS[name]
    with peer_on(ur.DASHBOARD_PORT, behaviour, honest) as peer:
        started = time.monotonic()
        ur.stop_program(peer.host)  # run on every stop: returns, whatever the port does
        assert_ends_by(started, ur.STOP_DEADLINE_S)
        assert peer.host in ur._SILENT_HOSTS
        accepted = peer.accepted
        ur.stop_program(peer.host)
        assert peer.accepted == accepted  # the next stop of the process does not try again


@pytest.mark.parametrize(
    ("name", "behaviour", "honest"),
    [
        ("silent", silent, b""),
        ("a byte at a time", drip, struct.pack(">iB", 1000, 16) + bytes(995)),
        ("huge length", announce(HUGE_PRIMARY), b""),
        ("closed mid-message", hang_up, struct.pack(">iB", 1000, 16) + bytes(995)),
    ],
)
def test_reading_the_primary_interface_ends_by_its_deadline(name, behaviour, honest):
    with peer_on(ur.PRIMARY_PORT, behaviour, honest) as peer:
        started = time.monotonic()
        with pytest.raises(DeviceError, match=f"primary interface on {peer.host}:30001"):
            ur.read_primary_interface(peer.host)
        assert_ends_by(started, ur.PRIMARY_DEADLINE_S)


def test_a_huge_primary_message_is_refused_at_its_header():
    with peer_on(ur.PRIMARY_PORT, announce(HUGE_PRIMARY)) as peer:
        with pytest.raises(DeviceError, match=r"announced a 2147483647-byte message \(at most 65536"):
            ur.read_primary_interface(peer.host)


@pytest.mark.parametrize(
    ("name", "behaviour", "honest"),
    [
        ("silent", silent, b""),
        ("a byte at a time", drip, struct.pack(">HB", 4, ord("V")) + b"\x01"),
        ("huge length", announce(HUGE_RTDE + b"\0" * 100), b""),
        ("closed mid-message", hang_up, struct.pack(">HB", 40, ord("V")) + bytes(37)),
    ],
)
def test_the_rtde_register_check_ends_by_its_deadline(name, behaviour, honest):
    with peer_on(ur.RTDE_PORT, behaviour, honest) as peer:
        started = time.monotonic()
        with pytest.raises(DeviceError, match=f"RTDE interface on {peer.host}:30004"):
            ur.registers_in_use(peer.host)
        assert_ends_by(started, ur.REGISTER_CHECK_DEADLINE_S)


#: An RTDE controller's answers to the handshake's requests, by request type.
RTDE_ANSWERS = {
    "V": struct.pack(">B", 1),
    "v": struct.pack(">4I", 5, 11, 0, 0),
    "O": struct.pack(">B", 1) + b"DOUBLE",
    "S": struct.pack(">B", 1),
}


def answers_then_nothing(kinds: str):
    """An RTDE port that answers the handshake's requests of ``kinds`` (in any order) and then
    never sends anything again: no other answer and no data package."""

    def behave(connection, peer, honest=b""):
        connection.settimeout(0.1)
        received = b""
        while not peer.stop.is_set():
            try:
                chunk = connection.recv(256)
            except TimeoutError:
                continue
            if not chunk:
                return
            received += chunk
            while len(received) >= 3 and len(received) >= struct.unpack(">H", received[:2])[0]:
                size, kind = struct.unpack(">HB", received[:3])
                received = received[size:]
                if chr(kind) in kinds:
                    answer = RTDE_ANSWERS[chr(kind)]
                    connection.sendall(struct.pack(">HB", len(answer) + 3, kind) + answer)

    return behave


@pytest.mark.parametrize(
    ("name", "behaviour", "honest"),
    [
        ("silent", silent, b""),
        ("huge length", announce(HUGE_RTDE + b"\0" * 100), b""),
        ("closed mid-message", hang_up, struct.pack(">HB", 40, ord("V")) + bytes(37)),
        ("silent after the protocol version", answers_then_nothing("V"), b""),
        ("silent on the output recipe", answers_then_nothing("Vv"), b""),
        ("started but never sending data", answers_then_nothing("VvOS"), b""),
    ],
)
def test_opening_a_robot_whose_rtde_port_does_not_answer_ends_by_its_deadline(name, behaviour, honest):
    """ur_rtde's constructors wait for a silent RTDE server for ever, holding the interpreter;
    spacecal asks the port for its protocol version first, with a deadline of its own."""
    with peer_on(ur.RTDE_PORT, behaviour, honest) as peer:
        started = time.monotonic()
        with pytest.raises(DeviceError, match=f"no UR controller answers RTDE on {peer.host}:30004: "):
            ur.URRobot(peer.host, control=False, robot_model="UR10")
        assert_ends_by(started, 2 * ur.REACH_DEADLINE_S)


def test_nothing_listening_is_one_device_error():
    host = f"127.{_NETWORK}.1.{next(_addresses)}"
    with pytest.raises(DeviceError, match="dashboard server on .* is not reachable"):
        ur.dashboard(host, ["PolyscopeVersion"])


# -- motion commands through ur_rtde ----------------------------------------------------------


@pytest.mark.parametrize("generation", ["cb3", "eseries"])
def test_a_move_sent_to_a_controller_that_just_vanished_is_given_up(generation):
    """A controller switched off between the last state seen and the next command: ur_rtde's
    ``moveL`` would wait for ever (over 60 s measured), so the command is sent from a worker and
    given up once the controller's state stands still; the stop and the close that follow end
    by their deadlines, and nothing more is sent on that connection."""
    pytest.importorskip("rtde_control")
    from spacecal.adapters.ur import URRobot

    from .ur_runs import ur_world

    world = ur_world(generation)
    robot = URRobot(world.info["host"], control=True)
    try:
        target = robot.state().base_from_tcp.copy()
        target[2, 3] += 5.0
        assert world.control("ur vanish") == "OK"
        started = time.monotonic()
        with pytest.raises(DeviceError, match="did not answer moveL"):
            robot.move_linear(target, 20.0, 200.0, asynchronous=True)
        given_up_after = time.monotonic() - started
        with pytest.raises(DeviceError, match="did not answer moveL"):  # nothing more is sent
            robot.move_linear(target, 20.0, 200.0, asynchronous=True)
        started = time.monotonic()
        robot.stop()
        robot.close()
        closed_after = time.monotonic() - started
    finally:
        world.stop()
    print(f"{generation}: moveL given up after {given_up_after:.2f} s, stop and close {closed_after:.2f} s")
    assert given_up_after < ur.COMMAND_SILENCE_S + MARGIN_S
    # the dashboard's stop (its deadline) and ur_rtde's disconnect (0.5 s per interface)
    assert closed_after < ur.STOP_DEADLINE_S + ur.DASHBOARD_DEADLINE_S + MARGIN_S
