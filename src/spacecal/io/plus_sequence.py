"""PLUS sequence files (``.igs.mha`` / ``.seq.mha``): MetaImage headers whose per-frame fields
carry tracked transforms.

Each frame has ``Seq_FrameNNNN_<From>To<To>Transform = 16 numbers`` (row-major 4x4 that maps
``<From>`` coordinates into ``<To>``, i.e. our ``to_from_from``), a ``...TransformStatus``
(``OK`` / ``INVALID`` / ``MISSING``) and ``Seq_FrameNNNN_Timestamp`` in seconds. Pixel data,
if any, follows ``ElementDataFile = LOCAL`` and is not read.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_float, parse_floats, parse_int

_FIELD = re.compile(r"^Seq_Frame([0-9]{1,9})_(\w+?)\s*=\s*(.*)$", re.ASCII)


@dataclass
class PlusSequence:
    """The tracking content of a PLUS sequence file.

    Attributes
    ----------
    timestamps_s : numpy.ndarray, shape (N,)
    transforms : dict
        ``{"StylusToTracker": (N, 4, 4) array, ...}``; NaN where the status is not OK.
    header : dict
        The file's header fields (strings).
    """

    timestamps_s: np.ndarray
    transforms: dict = field(default_factory=dict)
    header: dict = field(default_factory=dict)

    def transform(self, name: str) -> np.ndarray:
        """The (N, 4, 4) stack of ``name`` (PLUS naming, e.g. ``StylusToTracker``)."""
        if name not in self.transforms:
            raise InvalidInputError(
                f"the sequence has no {name}; it has {', '.join(sorted(self.transforms))}"
            )
        return self.transforms[name]


def read_plus_sequence(path: str | Path) -> PlusSequence:
    """Read the header and per-frame transforms of a PLUS ``.mha`` sequence file."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such sequence file")
    header: dict[str, str] = {}
    frames: dict[int, dict[str, str]] = {}
    with open(path, "rb") as handle:
        for raw in handle:
            if b"\x00" in raw:  # binary pixel data only follows ElementDataFile
                raise InvalidInputError(f"{path}: binary data in the header of a PLUS sequence file")
            line = raw.decode("latin-1").rstrip("\r\n")
            match = _FIELD.match(line)
            if match:
                index, key, value = parse_int(match.group(1)), match.group(2), match.group(3).strip()
                frames.setdefault(index, {})[key] = value
            elif "=" in line:
                key, _, value = line.partition("=")
                header[key.strip()] = value.strip()
            if line.startswith("ElementDataFile"):
                break  # pixel data follows
    if not frames:
        raise InvalidInputError(f"{path}: no Seq_Frame fields; not a PLUS sequence file")
    indices = sorted(frames)
    try:
        timestamps = np.array([parse_float(frames[i].get("Timestamp", "nan")) for i in indices])
    except ValueError:
        raise InvalidInputError(f"{path}: a frame timestamp is not a number") from None
    if not np.all(np.isfinite(timestamps)) or np.any(np.abs(timestamps) > 1e10):
        raise InvalidInputError(f"{path}: a frame timestamp is missing, not finite or absurd")
    names = sorted({k[: -len("Transform")] for f in frames.values() for k in f if k.endswith("Transform")})
    transforms = {}
    for name in names:
        stack = np.full((len(indices), 4, 4), np.nan)
        for row, i in enumerate(indices):
            values = frames[i].get(f"{name}Transform")
            status = frames[i].get(f"{name}TransformStatus", "OK").upper()
            if values is None or status != "OK":
                continue
            try:
                numbers = parse_floats(values)
            except ValueError:
                raise InvalidInputError(
                    f"{path}: frame {i} {name}Transform holds text that is not a number"
                ) from None
            if numbers.size != 16:
                raise InvalidInputError(
                    f"{path}: frame {i} {name}Transform has {numbers.size} numbers, not 16"
                )
            if not np.all(np.isfinite(numbers)) or np.max(np.abs(numbers)) > 1e5:
                raise InvalidInputError(
                    f"{path}: frame {i} {name}Transform holds a value that is not finite or not in mm"
                )
            stack[row] = numbers.reshape(4, 4)
        transforms[name] = stack
    return PlusSequence(timestamps, transforms, header)
