"""The last hostile inputs an independent probe of the command line found, each through
``spacecal.cli.main``: a segment label that is TeX, an NDI tracker whose PHSR reply is not
hexadecimal, easy_handeye samples with integers too large for a float or values that overflow
once converted, an unclosed IPv6 bracket for ``--igtl``, MCAP records declaring more bytes
than the file holds, result JSON holding integers beyond 64 bits, a tf tree with a loop, and
the live view beside hundreds of idle connections.

Each bad input must end in exit 1 with one line on stderr naming what is wrong (and no
traceback, no "internal error": :func:`spacecal.testing.fuzz.run_case` classifies that); a
valid one (a label that merely looks like TeX) must be handled.
"""

from __future__ import annotations

import json
import shutil
import socket
import struct
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from spacecal.testing.fuzz import Case, run_case
from tests.idle_connections import closed_by_the_server

from .bags import storage_file, write_small_bag

LIMIT_S = 60.0


def _run(folder: Path, argv: list[str], label: str):
    result = run_case(Case(argv[0], "hostile", label, argv, "any"), folder, LIMIT_S)
    assert result.outcome == "pass", f"{label}: {result.outcome}: {result.detail or result.stderr}"[:1500]
    return result


def _refused(folder: Path, argv: list[str], label: str, *words: str):
    """Exit 1, one line on stderr, holding every one of ``words``."""
    result = _run(folder, argv, label)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.code == 1 and len(lines) == 1, f"{label}: exit {result.code}: {result.stderr}"
    for word in words:
        assert word in lines[0], f"{label}: {word!r} not in {lines[0]!r}"
    return result


# -- 1. a segment label that is TeX ------------------------------------------------------------
TEX_LABELS = {
    "rot_x": r"$\undefinedcommand{x}$",
    "rot_y": r"\undefinedcommand{x}",
    "rot_z": "_hidden",
    "lin_y": "a$b$c$",
}


def test_segment_labels_that_are_tex_are_drawn_as_text(fuzz_base, tmp_path):
    text = (fuzz_base / "rec.csv").read_text()
    for name, label in TEX_LABELS.items():
        assert f",{name}," in text
        text = text.replace(f",{name},", f",{label},")
    (tmp_path / "rec.csv").write_text(text)
    result = _run(tmp_path, ["calibrate", "rec.csv", "-o", "cal.json", "--method", "ml"], "calibrate")
    assert result.code == 0, result.stderr
    result = _run(tmp_path, ["report", "cal.json", "--png-dir", "png", "-o", "report.html"], "report")
    assert result.code == 0, result.stderr
    for name in ("sweeps.png", "residuals.png"):
        assert (tmp_path / "png" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -- 2. an NDI tracker whose PHSR reply is not what the API says --------------------------------
@pytest.fixture
def lying_ndi(tmp_path):
    """An NDI tracker (the Combined API fake over TCP, in this process) whose PHSR reply is set by
    the test; yields (port, ROM file, a function setting the reply)."""
    pytest.importorskip("ndicapy")
    from spacecal.io.ndi_rom import rom_bytes
    from spacecal.models.marker import ndi_8700339_like
    from spacecal.testing.fakes.ndi import FakeNDI, ascii_reply, serve_tcp
    from spacecal.testing.fakes.net import listen

    reply = {"text": "010A031"}

    class Lying(FakeNDI):
        def cmd_PHSR(self, args):
            return ascii_reply(reply["text"])

    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, -1000.0]
    # frame numbers at the configured 20 Hz, from the clock, as a tracker counts camera frames
    device = Lying(lambda: (int(time.monotonic() * 20), pose, 0.1))
    server = listen("127.0.0.1", 0)
    stop, unplugged = threading.Event(), threading.Event()
    thread = threading.Thread(target=serve_tcp, args=(device, server, stop, unplugged), daemon=True)
    thread.start()
    rom = tmp_path / "marker.rom"
    rom.write_bytes(rom_bytes(ndi_8700339_like().spheres_in_marker))
    yield server.getsockname()[1], rom, lambda text: reply.__setitem__("text", text)
    stop.set()
    thread.join(5)


PHSR_REPLIES = {
    "a count of 10, one entry": ("0AZZ031", "PHSR reply of 5 characters for 10 port handle(s)"),
    "a count with a letter beyond F": ("0G", "PHSR reply that is not hexadecimal"),
    "a status with 0x": ("010A0x1", "PHSR reply that is not hexadecimal"),
    "an Arabic-Indic digit": ("01\u0660A031", "PHSR reply that is not hexadecimal"),
    "no entry after its count": ("01", "PHSR reply of 0 characters for 1 port handle(s)"),
}


@pytest.mark.parametrize("name", sorted(PHSR_REPLIES))
def test_an_ndi_phsr_reply_that_is_not_hexadecimal_is_a_problem_in_one_line(lying_ndi, tmp_path, name):
    port, rom, set_reply = lying_ndi
    reply, words = PHSR_REPLIES[name]
    set_reply(reply)
    argv = ["doctor", "--tracker", f"ndi://127.0.0.1:{port}", "--rom", str(rom)]
    result = _refused(tmp_path, argv, f"PHSR {reply!r}", "1 problem found")
    (tools,) = [line for line in result.stdout.splitlines() if ": tools: " in line]
    assert "PROBLEM" in tools and words in tools, tools


def test_a_valid_phsr_reply_is_read(lying_ndi, tmp_path):
    port, rom, set_reply = lying_ndi
    set_reply("020A0310B001")
    result = _run(tmp_path, ["doctor", "--tracker", f"ndi://127.0.0.1:{port}", "--rom", str(rom)], "valid")
    assert "tools: ok: 2 port handle(s): 0A enabled, 0B not enabled" in result.stdout, result.stdout


# -- 3. easy_handeye samples with numbers no float holds -------------------------------------
def _samples_text() -> str:
    from scipy.spatial.transform import Rotation

    from spacecal.geometry.transforms import make_transform
    from spacecal.io.easy_handeye import easy_handeye2_samples_text

    rng = np.random.default_rng(3)
    robot = make_transform(Rotation.random(8, random_state=3).as_matrix(), rng.normal(0, 300, (8, 3)))
    marker = make_transform(
        Rotation.random(8, random_state=4).as_matrix(), rng.normal(0, 300, (8, 3)) + [0, 0, -1200]
    )
    return easy_handeye2_samples_text(
        robot,
        marker,
        name="probe",
        robot_base_frame="base_link",
        robot_effector_frame="tool0",
        tracking_base_frame="tracker",
        tracking_marker_frame="marker",
    )


HUGE_SAMPLE_VALUES = {
    "10e30 as a 32-digit integer": ("translation", "1" + "0" * 31, "field 'x' is 1" + "0" * 31),
    "a 400-digit integer": ("translation", "9" * 400, "field 'x' is an integer of 400 digits"),
    "1e308": ("translation", "1e308", "field 'x' is 1e+308"),
    "-1e308": ("translation", "-1e308", "field 'x' is -1e+308"),
    "150 m": ("translation", "150.0", "field 'x' is 150.0"),
    "a quaternion component of 1e300": ("rotation", "1.0e+300", "field 'x' is 1e+300"),
    "a 30-digit quaternion component": ("rotation", "9" * 30, "field 'x' is " + "9" * 30),
}


@pytest.mark.parametrize("name", sorted(HUGE_SAMPLE_VALUES))
def test_easy_handeye_numbers_no_float_holds_are_refused_naming_file_and_field(tmp_path, name):
    block, value, words = HUGE_SAMPLE_VALUES[name]
    lines = _samples_text().splitlines()
    # the robot transform's first x of the first sample, in its translation or rotation block
    start = lines.index(f"    {block}:", lines.index("- robot:"))
    assert lines[start + 1].startswith("      x: ")
    lines[start + 1] = f"      x: {value}"
    (tmp_path / "rec.samples").write_text("\n".join(lines) + "\n")
    argv = ["import-easy-handeye", "rec.samples", "-o", "out.csv"]
    _refused(
        tmp_path, argv, name, "rec.samples", f"sample 0.robot.{block}", words, "expected a finite number"
    )
    assert not (tmp_path / "out.csv").exists()


# -- 4. --igtl HOST:PORT that is not one ----------------------------------------------------
IGTL_ADDRESSES = {
    "[::1": "opened with '[' is not closed",
    "::1]": "write an IPv6 address in brackets",
    "[zz]:18944": "'zz' in brackets is not an IPv6 address",
    "[::1]18944": "expected ':PORT' after the IPv6 address",
    "ho/st": "'ho/st' is not a host name",
    "user@host": "'user@host' is not a host name",
    "host?x": "'host?x' is not a host name",
    "a b": "'a b' is not a host name",
    "host:": "the port must be a number from 1 to 65535, not ''",
    "host:0": "not '0'",
    "host:99999": "not '99999'",
    "host:+5": "not '+5'",
    "host:\u0665": "the port must be a number",
}


@pytest.mark.parametrize("address", sorted(IGTL_ADDRESSES))
def test_an_igtl_address_that_is_not_host_port_is_refused(fuzz_base, tmp_path, address):
    shutil.copy(fuzz_base / "cal.json", tmp_path / "cal.json")
    _refused(tmp_path, ["export", "cal.json", "--igtl", address], address, "--igtl", IGTL_ADDRESSES[address])


# -- 5. MCAP records that declare more than the file holds ---------------------------------
def _mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of each record of an MCAP file, to the footer."""
    records, position = [], 8
    while True:
        opcode, length = data[position], struct.unpack_from("<Q", data, position + 1)[0]
        records.append((position, opcode, length))
        if opcode == 0x02:
            return records
        position += 9 + length


def _chunk_index_sizes_at(data: bytes, position: int) -> int:
    """The offset of a chunk index entry's ``compressed_size`` (``uncompressed_size`` follows)."""
    body = position + 9 + 32  # start and end times, chunk start offset, chunk length
    body += 4 + struct.unpack_from("<I", data, body)[0] + 8  # message index offsets, their length
    return body + 4 + struct.unpack_from("<I", data, body)[0]  # compression


@pytest.fixture(scope="module")
def clean_mcap(tmp_path_factory):
    return write_small_bag(tmp_path_factory.mktemp("mcap") / "bag", "mcap")


def _lies(data: bytes) -> dict[str, tuple[int, int]]:
    records = _mcap_records(data)
    first = {opcode: position for position, opcode, _ in reversed(records)}
    sizes = _chunk_index_sizes_at(data, first[0x08])
    return {
        "the header record": (first[0x01] + 1, 2**62),
        "the chunk record": (first[0x06] + 1, 2**62),
        "the chunk's uncompressed size": (first[0x06] + 9 + 16, 2**62),
        "a message index record": (first[0x07] + 1, 2**62),
        "a schema record of the summary": (first[0x03] + 1, 2**62),
        "the chunk index's compressed size": (sizes, 2**62),
        "the chunk index's uncompressed size": (sizes + 8, 2**40),
    }


@pytest.mark.parametrize(
    "lie",
    [
        "the header record",
        "the chunk record",
        "the chunk's uncompressed size",
        "a message index record",
        "a schema record of the summary",
        "the chunk index's compressed size",
        "the chunk index's uncompressed size",
    ],
)
def test_mcap_sizes_beyond_the_file_are_refused_before_reading(clean_mcap, tmp_path, lie):
    data = storage_file(clean_mcap).read_bytes()
    at, value = _lies(data)[lie]
    damaged = bytearray(data)
    struct.pack_into("<Q", damaged, at, value)
    shutil.copytree(clean_mcap, tmp_path / "bag")
    storage_file(tmp_path / "bag").write_bytes(bytes(damaged))
    _refused(tmp_path, ["import-bag", "bag", "-o", "out"], lie, ".mcap", "declares", str(value))


def test_the_clean_mcap_bag_imports(clean_mcap, tmp_path):
    shutil.copytree(clean_mcap, tmp_path / "bag")
    assert _run(tmp_path, ["import-bag", "bag", "-o", "out"], "clean").code == 0


def test_an_mcap_chunk_that_expands_beyond_its_declared_size_is_refused(tmp_path):
    from tests.io.mcap_files import mcap_with_one_chunk

    # 40 MB of zeros in 1.3 kB of zstd, declared as 1000 bytes: rosbags would expand it whole
    (tmp_path / "bomb.mcap").write_bytes(mcap_with_one_chunk(b"\0" * (40 << 20), "zstd", declared=1000))
    _refused(tmp_path, ["import-bag", "bomb.mcap", "-o", "out"], "zstd bomb", "bomb.mcap", "expands to more")


# -- 6. result JSON with integers beyond 64 bits --------------------------------------------
def _calibration_with(fuzz_base: Path, folder: Path, path: tuple, value_text: str) -> None:
    data = json.loads((fuzz_base / "cal.json").read_text())
    target = data
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = "@VALUE@"
    (folder / "cal.json").write_text(json.dumps(data, indent=2).replace('"@VALUE@"', value_text))


BIG_INTEGERS = {
    "5000 digits in tracker_from_base": (("tracker_from_base", 0, 3), "9" * 5000, "5000 digits"),
    "4400 digits in a sample count": (("sample_counts", "total"), "1" + "0" * 4399, "4400 digits"),
    "100 digits in the expected error": (
        ("diagnostics", "expected_error", "position_mm"),
        "1" + "0" * 99,
        "100 digits",
    ),
    "2**64 as the schema version": (("schema_version",), str(2**64), "20 digits"),
}


@pytest.mark.parametrize("name", sorted(BIG_INTEGERS))
@pytest.mark.parametrize("command", ["report", "export"])
def test_integers_beyond_64_bits_in_a_calibration_are_refused(fuzz_base, tmp_path, name, command):
    path, value, words = BIG_INTEGERS[name]
    _calibration_with(fuzz_base, tmp_path, path, value)
    shutil.copy(fuzz_base / "rec.csv", tmp_path / "rec.csv")
    argv = {
        "report": ["report", "cal.json", "--accept-edited", "--recording", "rec.csv", "-o", "r.html"],
        "export": ["export", "cal.json", "--accept-edited", "--slicer", "out.tfm"],
    }[command]
    _refused(tmp_path, argv, f"{command}: {name}", "cal.json", words, "beyond the 64-bit integers")


# -- 7. a tf tree with a loop ------------------------------------------------------------------
TF_LOOPS = {
    "two frames": (("flange", "base"), "base -> flange -> base"),
    "three frames": (("tcp", "base"), "base -> flange -> tcp -> base"),
    "a frame its own parent": (("flange", "flange"), "flange -> flange"),
}


@pytest.mark.parametrize("name", sorted(TF_LOOPS))
def test_a_tf_loop_is_refused_naming_its_frames(tmp_path, name):
    (parent, child), loop = TF_LOOPS[name]

    def tweak(kind: str, k: int, values: dict) -> None:
        if kind == "robot" and k == 3:
            values["parent"], values["child"] = parent, child

    write_small_bag(tmp_path / "bag", tweak=tweak)
    for extra in ((), ("--base-frame", "base", "--tool-frame", "tcp")):
        _refused(tmp_path, ["import-bag", "bag", "-o", "out", *extra], f"{name} {extra}", f"loop ({loop})")
        assert not (tmp_path / "out.robot.csv").exists()
    listing = _run(tmp_path, ["import-bag", "bag", "--list"], f"{name} --list")
    assert listing.code == 0 and f"tf loop (no pose is composed through it): {loop}" in listing.stdout


# -- 8. the live view beside hundreds of idle connections -----------------------------------
IDLE_CONNECTIONS = 300


#: How long the handlers of pushed-out connections get to end (a fraction of the read timeout).
SETTLE_S = 0.5


def test_the_live_view_answers_beside_300_idle_connections_and_closes_them(monkeypatch):
    from spacecal.report import live

    monkeypatch.setattr(live, "READ_TIMEOUT_S", 2.0)
    # threads earlier tests of this worker left (they only end meanwhile): not the view's
    before = threading.active_count()
    view = live.LiveView(0)
    assert view.start()
    idle: list[socket.socket] = []
    try:
        for k in range(IDLE_CONNECTIONS):
            s = socket.create_connection(("127.0.0.1", view.port), timeout=5)
            if k % 2:  # half of them send half a request, the others nothing
                s.sendall(f"GET /data HTTP/1.1\r\nHost: 127.0.0.1:{view.port}\r\n".encode())
            idle.append(s)
        started = time.monotonic()
        with urllib.request.urlopen(view.url + "data", timeout=5) as reply:
            assert json.loads(reply.read())["status"] == "waiting for the first frame"
        assert time.monotonic() - started < 3.0
        # no more handler threads than connections served at once, whatever was opened (plus its
        # serving thread); the handler of a connection pushed out ends a moment after its socket
        # was shut down, so the count may run over for that moment: well under the read timeout,
        # after which an unbounded view would still hold a thread for each of the 300
        bound, settle_until = live.MAX_CONNECTIONS + 1, time.monotonic() + SETTLE_S
        while threading.active_count() - before > bound and time.monotonic() < settle_until:
            time.sleep(0.02)
        assert threading.active_count() - before <= bound
        time.sleep(live.READ_TIMEOUT_S + 2.0)
        assert closed_by_the_server(idle) == len(idle)
    finally:
        for s in idle:
            s.close()
        view.close()


@pytest.mark.parametrize("url", ["igtl://[::1", "ur://[zz", "ndi://[fe80::1:8765"])
def test_a_device_url_with_an_unclosed_bracket_is_one_line(url):
    """``--robot``/``--tracker`` are split by the device URL table's parser, which met the
    standard library's 'Invalid IPv6 URL' as an internal error."""
    from spacecal.adapters import parse_device_url
    from spacecal.core.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="Invalid IPv6 URL"):
        parse_device_url(url, ("igtl", "ur", "ndi"))
