"""NDI tool definitions: the geometry a recording states is the one the tracker was given."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from spacecal.app.devices import marker_in_use
from spacecal.core.errors import InvalidInputError
from spacecal.io.ndi_rom import (
    MARKER_COUNT_OFFSET,
    POSITIONS_OFFSET,
    read_rom_marker,
    rom_bytes,
    rom_checksum,
)

#: NDI's 8700340 passive probe layout differs from the 8700339 reference: another marker.
OTHER_MARKER = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 50.0], [0.0, 25.0, 100.0], [0.0, -25.0, 135.0]])


def test_a_tool_definition_reads_back_its_geometry(tmp_path):
    path = tmp_path / "probe.rom"
    path.write_bytes(rom_bytes(OTHER_MARKER, face_normal=[1.0, 0.0, 0.0]))
    marker = read_rom_marker(path)
    assert marker.name == "probe"
    assert np.allclose(marker.spheres_in_marker, OTHER_MARKER, atol=1e-5)
    assert np.allclose(marker.face_normal_in_marker, [1.0, 0.0, 0.0])
    # the recording's metadata states this geometry, not an assumed one
    entry = marker_in_use([str(path)])
    assert entry["geometry_known"] and np.allclose(entry["spheres_in_marker_mm"], OTHER_MARKER, atol=1e-5)
    assert marker_in_use([])["geometry_known"] is False


def _spoil(data: bytes, offset: int, packed: bytes) -> bytes:
    spoilt = bytearray(data)
    spoilt[offset : offset + len(packed)] = packed
    struct.pack_into("<H", spoilt, 4, rom_checksum(bytes(spoilt)))
    return bytes(spoilt)


@pytest.mark.parametrize(
    "case",
    ["text", "empty", "short", "checksum", "two markers", "21 markers", "nan", "far", "coincident"],
)
def test_a_damaged_or_foreign_file_is_one_clear_line(tmp_path, case):
    good = rom_bytes(OTHER_MARKER)
    data = {
        "text": b"passive marker definition\n" + bytes(200),
        "empty": b"",
        "short": good[:300],
        "checksum": good[:100] + b"\x01" + good[101:],
        "two markers": _spoil(good, MARKER_COUNT_OFFSET, bytes([2])),
        "21 markers": _spoil(good, MARKER_COUNT_OFFSET, bytes([21])),
        "nan": _spoil(good, POSITIONS_OFFSET, struct.pack("<f", float("nan"))),
        "far": _spoil(good, POSITIONS_OFFSET, struct.pack("<f", 1e6)),
        "coincident": _spoil(good, POSITIONS_OFFSET + 12, struct.pack("<3f", 0.0, 0.0, 1.0)),
    }[case]
    path = tmp_path / "tool.rom"
    path.write_bytes(data)
    with pytest.raises(InvalidInputError) as error:
        read_rom_marker(path)
    assert str(tmp_path) in str(error.value) and "\n" not in str(error.value)
