"""sha256 of files on disk: what a calibration records of the files it belongs to."""

from __future__ import annotations

import hashlib
from pathlib import Path

#: Read in blocks of this many bytes (a raw robot stream can be a gigabyte).
_BLOCK_BYTES = 1 << 20


def file_sha256(path: str | Path) -> str:
    """The sha256 (lower-case hex) of the file's bytes.

    Raises
    ------
    OSError
        When the file cannot be read.
    """
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(_BLOCK_BYTES), b""):
            digest.update(block)
    return digest.hexdigest()
