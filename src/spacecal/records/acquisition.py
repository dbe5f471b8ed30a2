"""The progress file of an acquisition (``rec.progress.json``): how far a run got, so it can
be resumed with the same plan from the same home."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.records.fields import as_array, check_schema, get_str, plain


@dataclass(frozen=True)
class AcquisitionProgress:
    """How far an acquisition got.

    Attributes
    ----------
    plan_fingerprint : str
        Hash of the plan's moves (a resume must continue the same plan).
    moves_completed, moves_total : int
    stopped_because : str or None
        The one-line cause when the run stopped early.
    home_joints_rad : numpy.ndarray, shape (6,)
        The home the plan was made from (re-planned from it on resume).
    """

    plan_fingerprint: str
    moves_completed: int
    moves_total: int
    stopped_because: str | None
    home_joints_rad: np.ndarray

    def __post_init__(self) -> None:
        what = "acquisition progress"
        object.__setattr__(
            self, "home_joints_rad", as_array(self.home_joints_rad, (6,), "home_joints_rad", what)
        )
        if not (0 <= self.moves_completed <= self.moves_total):
            raise InvalidInputError(
                f"{what}: moves_completed {self.moves_completed} is not within 0..{self.moves_total}"
            )

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": "spacecal.acquisition_progress",
                "schema_version": 1,
                "plan": self.plan_fingerprint,
                "moves_completed": self.moves_completed,
                "moves_total": self.moves_total,
                "stopped_because": self.stopped_because,
                "home_joints_rad": self.home_joints_rad,
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "acquisition progress") -> AcquisitionProgress:
        check_schema(data, "spacecal.acquisition_progress", (1,), what)
        counts = []
        for key in ("moves_completed", "moves_total"):
            value = data.get(key)
            if isinstance(value, bool) or not isinstance(value, int):
                raise InvalidInputError(f"{what}: {key!r} must be a whole number")
            counts.append(value)
        stopped = data.get("stopped_because")
        if stopped is not None and not isinstance(stopped, str):
            raise InvalidInputError(f"{what}: 'stopped_because' must be text or null")
        return cls(
            plan_fingerprint=get_str(data, "plan", what),
            moves_completed=counts[0],
            moves_total=counts[1],
            stopped_because=stopped,
            home_joints_rad=as_array(data.get("home_joints_rad"), (6,), "home_joints_rad", what),
        )
