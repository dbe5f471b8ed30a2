"""Pose files of other tools: a folder of 4x4 matrices in text files (scikit-surgery style)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
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
        try:
            matrix = np.loadtxt(io.StringIO(text), dtype=float, ndmin=2)
        except ValueError as exc:
            raise InvalidInputError(f"{path}: not a matrix of numbers ({str(exc).splitlines()[0]})") from None
        if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
            raise InvalidInputError(f"{path}: expected a finite 4x4 matrix, got shape {matrix.shape}")
        if np.max(np.abs(matrix)) > MAX_ABS_POSITION_MM:
            raise InvalidInputError(
                f"{path}: a value {np.max(np.abs(matrix)):.3g} is not a pose in mm "
                f"(at most {MAX_ABS_POSITION_MM:g})"
            )
        matrices.append(matrix)
    return np.array(matrices)
