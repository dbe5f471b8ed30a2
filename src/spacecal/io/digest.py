"""sha256 of files on disk: what a calibration records of the files it belongs to."""

from __future__ import annotations

import hashlib
import re
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


_SCHEMA = re.compile(rb'"schema"\s*:\s*"(spacecal\.[A-Za-z0-9_.]+)"')


def spacecal_schema_of(path: str | Path, head_bytes: int = 65536) -> str | None:
    """The ``schema`` name of an existing spacecal result file (``spacecal.calibration``, a
    check history's ``spacecal.check``, ...), read from the start of the file where spacecal
    writes it; None for any other file, or no file."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as handle:
            head = handle.read(head_bytes)
    except OSError:
        return None
    match = _SCHEMA.search(head)
    return match.group(1).decode("ascii") if match else None
