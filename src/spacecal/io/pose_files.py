"""Pose files of other tools: a folder of 4x4 matrices in text files (scikit-surgery style)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_floats
from spacecal.core.text import quoted
from spacecal.io.text import read_text_file

#: Larger than this (mm) is not a position a tracker reports.
MAX_ABS_POSITION_MM = 1e5


def read_matrix_folder(folder: str | Path, names=None) -> np.ndarray:
    """Read every ``*.txt`` 4x4 matrix in a folder, in sorted name order: shape (N, 4, 4).

    Parameters
    ----------
    folder : str or Path
    names : iterable of str, optional
        Only these file names (e.g. a published subset), still in sorted order.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidInputError(f"{folder}: not a folder of pose files")
    files = sorted(folder.glob("*.txt"))
    if names is not None:
        wanted = set(names)
        files = [f for f in files if f.name in wanted]
    if not files:
        raise InvalidInputError(f"{folder}: no .txt pose files found")
    matrices = []
    for path in files:
        text = read_text_file(path, "pose")
        if not text.strip():
            raise InvalidInputError(f"{path}: empty; expected a 4x4 matrix")
        rows = []
        for number, line in enumerate(text.split("\n"), start=1):
            content = line.split("#", 1)[0]  # numpy.loadtxt's comments, which these files may have
            if not content.strip():
                continue
            try:
                rows.append(parse_floats(content))
            except ValueError:
                raise InvalidInputError(
                    f"{path}: line {number}: {quoted(content.strip())} is not a row of plain decimal numbers"
                ) from None
        shape = (len(rows), len(rows[0])) if rows and all(len(r) == len(rows[0]) for r in rows) else None
        if shape != (4, 4):
            found = f"shape {shape}" if shape else "rows of different lengths" if rows else "no numbers"
            raise InvalidInputError(f"{path}: expected a finite 4x4 matrix, got {found}")
        matrix = np.array(rows)
        if not np.all(np.isfinite(matrix)):
            raise InvalidInputError(f"{path}: expected a finite 4x4 matrix, got a value that is not finite")
        if np.max(np.abs(matrix)) > MAX_ABS_POSITION_MM:
            raise InvalidInputError(
                f"{path}: a value {np.max(np.abs(matrix)):.3g} is not a pose in mm "
                f"(at most {MAX_ABS_POSITION_MM:g})"
            )
        matrices.append(matrix)
    return np.array(matrices)
