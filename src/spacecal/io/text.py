"""Reading text files at the boundary: one place that refuses what is not UTF-8 text.

Binary, gzip, UTF-16 or Latin-1 bytes where a CSV, JSON or XML text file is expected give
one line naming the file and what it looks like, instead of a decoding traceback.
"""

from __future__ import annotations

import re
from pathlib import Path

from spacecal.core.errors import InvalidInputError

#: Larger than this is not a spacecal input text file (a day of 500 Hz robot states is ~1 GB).
MAX_TEXT_BYTES = 2 * 1024**3


def read_text_file(path: str | Path, what: str, max_bytes: int | None = None) -> str:
    """The file's text, decoded as UTF-8 (a byte-order mark is dropped).

    Raises
    ------
    InvalidInputError
        The file is missing, a folder, too large, compressed, binary or not UTF-8.
    """
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such {what} file")
    limit = MAX_TEXT_BYTES if max_bytes is None else min(max_bytes, MAX_TEXT_BYTES)
    if path.stat().st_size > limit:
        raise InvalidInputError(
            f"{path}: too large for a {what} file ({path.stat().st_size} bytes; at most {limit})"
        )
    raw = path.read_bytes()
    if raw[:2] == b"\x1f\x8b":
        raise InvalidInputError(f"{path}: gzip-compressed; decompress it first (a {what} file is text)")
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        raise InvalidInputError(f"{path}: UTF-16 text; save it as UTF-8")
    if b"\x00" in raw:
        raise InvalidInputError(f"{path}: binary data where a {what} text file was expected")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InvalidInputError(
            f"{path}: not UTF-8 text (byte {exc.start}); save the {what} file as UTF-8"
        ) from None


_DTD = re.compile(r"<!\s*(?:DOCTYPE|ENTITY)", re.IGNORECASE)


def refuse_dtd(text: str, where: str) -> str:
    """``text`` unless it declares a DTD or entities (``<!DOCTYPE``, ``<!ENTITY``), which no XML
    file spacecal reads (PLUS configurations, URDF) needs and which can expand a small file
    into gigabytes or pull in other files; one clear line then."""
    if _DTD.search(text):
        raise InvalidInputError(f"{where}: XML with a document type or entity declaration is not accepted")
    return text
