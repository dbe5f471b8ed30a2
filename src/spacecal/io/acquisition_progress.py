"""The progress file of an acquisition: ``rec.csv`` -> ``rec.progress.json``, written after
every completed move and when a run stops, so ``acquire --resume`` continues the same plan
(its fingerprint) from the move after the last completed one, from the same home.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spacecal.io.results_json import read_json_object, write_json
from spacecal.records import AcquisitionProgress


def progress_path(recording_path: str | Path) -> Path:
    """``rec.csv`` -> ``rec.progress.json``."""
    path = Path(recording_path)
    return path.with_name(path.stem + ".progress.json")


def write_progress(progress: AcquisitionProgress, path: str | Path) -> None:
    """Write the progress record (atomically: a stop mid-write leaves the previous one)."""
    write_json(progress.to_dict(), path)


def read_progress(recording_path: str | Path) -> AcquisitionProgress | None:
    """The progress of a stopped acquisition, or None when there is none."""
    path = progress_path(recording_path)
    if not path.is_file():
        return None
    return AcquisitionProgress.from_dict(read_json_object(path, "acquisition progress"), what=str(path))


def resume_home_joints(recording_path: str | Path) -> np.ndarray | None:
    """The home configuration a stopped acquisition was planned from (to re-plan it on resume)."""
    progress = read_progress(recording_path)
    return None if progress is None else progress.home_joints_rad
