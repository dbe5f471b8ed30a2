"""MCAP declared sizes are checked against the file before rosbags reads by them
(:func:`spacecal.io.ros_bag.check_mcap_sizes`), and a tf loop is found and named."""

import struct

import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.io import ros_bag
from spacecal.io.ros_bag import _tf_cycle, check_mcap_sizes

from .mcap_files import mcap_with_one_chunk

#: A few records' worth of bytes (any bytes do: only sizes are checked here).
RECORDS = bytes(range(256)) * 8


@pytest.mark.parametrize("compression", ["", "zstd", "lz4"])
def test_a_chunk_as_declared_passes(tmp_path, compression):
    path = tmp_path / "ok.mcap"
    path.write_bytes(mcap_with_one_chunk(RECORDS, compression))
    check_mcap_sizes(path)


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_a_chunk_expanding_beyond_its_declared_size_is_refused(tmp_path, compression):
    path = tmp_path / "bomb.mcap"
    path.write_bytes(mcap_with_one_chunk(b"\0" * (8 << 20), compression, declared=len(RECORDS)))
    assert path.stat().st_size < 100_000
    with pytest.raises(InvalidInputError, match=f"declares a chunk of {len(RECORDS)} bytes"):
        check_mcap_sizes(path)


def test_a_chunk_beyond_the_largest_read_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(ros_bag, "MAX_MCAP_CHUNK_BYTES", 1000)
    path = tmp_path / "big.mcap"
    path.write_bytes(mcap_with_one_chunk(RECORDS, "zstd"))
    with pytest.raises(
        InvalidInputError, match=r"declares a chunk of 2048 bytes .* more than spacecal reads"
    ):
        check_mcap_sizes(path)


@pytest.mark.parametrize(("keep", "opcode"), [(100, "0x06"), (-10, "0x02"), (-20, "0x02")])
def test_a_file_cut_short_is_refused_at_the_record_it_cuts(tmp_path, keep, opcode):
    data = mcap_with_one_chunk(RECORDS)
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[:keep])
    with pytest.raises(InvalidInputError, match=rf"the record at byte \d+ \(opcode {opcode}\) declares"):
        check_mcap_sizes(path)


def test_a_record_longer_than_the_file_is_refused(tmp_path):
    data = bytearray(mcap_with_one_chunk(RECORDS))
    struct.pack_into("<Q", data, 9, 2**62)  # the header record's length
    path = tmp_path / "lie.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(InvalidInputError, match=f"record at byte 8 \\(opcode 0x01\\) declares {2**62} bytes"):
        check_mcap_sizes(path)


def test_a_file_that_is_no_mcap_is_left_to_the_reader(tmp_path):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"not an mcap file at all")
    check_mcap_sizes(path)


@pytest.mark.parametrize(
    ("edges", "loop"),
    [
        ([("a", "b"), ("b", "c")], None),
        ([("a", "b"), ("a", "c"), ("c", "d")], None),
        ([("a", "b"), ("b", "a")], ["a", "b", "a"]),
        ([("x", "x")], ["x", "x"]),
        ([("r", "a"), ("a", "b"), ("b", "c"), ("c", "a")], ["a", "b", "c", "a"]),
    ],
)
def test_tf_loops_are_found(edges, loop):
    assert _tf_cycle(edges) == loop


def test_a_long_tf_loop_is_found_without_recursion():
    edges = [(f"f{k}", f"f{k + 1}") for k in range(50_000)] + [("f50000", "f0")]
    loop = _tf_cycle(edges)
    assert loop is not None and len(loop) == 50_002 and loop[0] == loop[-1]
