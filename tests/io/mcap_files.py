"""Small MCAP files built byte by byte from the MCAP specification, for chunks that lie.

A file is the magic, a Header record (profile ``ros2``), one Chunk record of the records given
(compressed as asked, its uncompressed size declared as asked), a DataEnd record, a Footer
without a summary, and the magic again. Each record is an opcode (1 byte), a length (u64 LE)
and that many bytes; strings are a u32 LE length and UTF-8 bytes.
"""

from __future__ import annotations

import struct

MAGIC = b"\x89MCAP0\r\n"
HEADER, FOOTER, CHUNK, DATA_END = 0x01, 0x02, 0x06, 0x0F


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _record(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


def _compress(records: bytes, compression: str) -> bytes:
    if compression == "zstd":
        try:
            from compression import zstd  # type: ignore[import-not-found]
        except ImportError:
            from backports import zstd  # type: ignore[no-redef]
        return zstd.compress(records)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.compress(records)
    return records


def mcap_with_one_chunk(records: bytes, compression: str = "", declared: int | None = None) -> bytes:
    """An MCAP file of one chunk holding ``records`` (bytes of records, or any bytes), whose
    Chunk record declares ``declared`` uncompressed bytes (default: the true length)."""
    compressed = _compress(records, compression)
    chunk = (
        struct.pack("<QQQI", 0, 0, len(records) if declared is None else declared, 0)
        + _string(compression)
        + struct.pack("<Q", len(compressed))
        + compressed
    )
    return (
        MAGIC
        + _record(HEADER, _string("ros2") + _string("spacecal tests"))
        + _record(CHUNK, chunk)
        + _record(DATA_END, struct.pack("<I", 0))
        + _record(FOOTER, struct.pack("<QQI", 0, 0, 0))
        + MAGIC
    )
