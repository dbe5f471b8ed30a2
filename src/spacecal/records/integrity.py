"""Content hashes of result files: has a file been edited since spacecal wrote it?

A file carries, in its ``integrity`` object, the sha256 of the canonical JSON of every other
top-level field: keys sorted, no whitespace, ASCII, numbers as Python writes them. The hash is
taken of the content *as read back* (the content is written to JSON text and parsed again
first), so a float that is printed and parsed gives the same bytes on both sides, and the
indentation and key order of the file itself do not matter.

The hash detects an edit or a corruption; it is not a signature (whoever edits a file can
recompute it).
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from spacecal.records.fields import plain

#: The top-level key of the hash (excluded from what it covers).
INTEGRITY_KEY = "integrity"
HASH_ALGORITHM = "sha256"
#: How the covered content is serialised before hashing (written into the file, for readers).
CANONICAL_FORM = "json: every other top-level field; keys sorted, no whitespace, ASCII"

_HEX_SHA256 = re.compile(r"[0-9a-f]{64}")


def is_sha256(value: Any) -> bool:
    """True for a lower-case hex sha256 digest."""
    return isinstance(value, str) and _HEX_SHA256.fullmatch(value) is not None


def canonical_json(data: Mapping[str, Any]) -> bytes:
    """``data`` as canonical JSON bytes, after a round trip through JSON text (what a reader
    of the file sees): sorted keys, no whitespace, ASCII."""
    text = json.dumps(plain(data), allow_nan=False)
    read_back = json.loads(text)
    return json.dumps(
        read_back, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False
    ).encode("ascii")


def content_sha256(data: Mapping[str, Any]) -> str:
    """The sha256 (hex) of every field of ``data`` but :data:`INTEGRITY_KEY`, canonical JSON."""
    covered = {key: value for key, value in data.items() if key != INTEGRITY_KEY}
    return hashlib.sha256(canonical_json(covered)).hexdigest()


def integrity_entry(data: Mapping[str, Any]) -> dict[str, str]:
    """The ``integrity`` object to write into a file of content ``data``."""
    return {"algorithm": HASH_ALGORITHM, "canonical": CANONICAL_FORM, "content_sha256": content_sha256(data)}


@dataclass(frozen=True)
class Integrity:
    """How a file read stands against the hash it carries.

    Attributes
    ----------
    content_sha256 : str
        The hash of the content as read (what a check history binds to).
    recorded_sha256 : str or None
        The hash the file carries; None when it carries none (a version written before files
        had one, or one whose hash was removed); ``''`` when its hash is not a sha256.
    required : bool
        The file's version carries a hash, so a missing one is an edit.
    """

    content_sha256: str
    recorded_sha256: str | None
    required: bool

    @property
    def verified(self) -> bool:
        """The file is as spacecal wrote it."""
        return self.recorded_sha256 is not None and self.recorded_sha256 == self.content_sha256

    @property
    def edited(self) -> bool:
        """The file was changed after it was written (the hash differs, or a version that
        carries one has none)."""
        if self.recorded_sha256 is None:
            return self.required
        return self.recorded_sha256 != self.content_sha256

    @property
    def unverifiable(self) -> bool:
        """A file of a version without a hash: nothing to verify it against."""
        return self.recorded_sha256 is None and not self.required

    @classmethod
    def of(cls, data: Mapping[str, Any], required: bool) -> Integrity:
        """Hash ``data``'s content and read the hash it carries in its ``integrity`` object.

        ``required``: the file's version carries a hash. A file that carries an ``integrity``
        object vouches for its content whatever its version, so a malformed object (not an
        object, another algorithm, no sha256) is an edit like any other.
        """
        entry = data.get(INTEGRITY_KEY)
        recorded: str | None = None
        if entry is not None:
            value = entry.get("content_sha256") if isinstance(entry, Mapping) else None
            algorithm = entry.get("algorithm", HASH_ALGORITHM) if isinstance(entry, Mapping) else None
            # '' never equals a digest: a mangled entry reads as an edit
            recorded = value if is_sha256(value) and algorithm == HASH_ALGORITHM else ""
            required = True
        return cls(content_sha256(data), recorded, required)
