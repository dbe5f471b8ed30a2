"""Small helpers the app functions share: outputs that must not overwrite inputs, provenance."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.records import Provenance, Recording


def refuse_overwriting_inputs(output: str | Path | None, *inputs: str | Path | None) -> None:
    """Raise if ``output`` names one of the command's own input files."""
    if output is None:
        return
    target = Path(output).resolve()
    for item in inputs:
        if item is not None and Path(item).resolve() == target:
            raise InvalidInputError(
                f"{output}: the output would overwrite an input of this command; choose another file"
            )


def provenance_of(
    recording: Recording, recording_path: str | Path | None, tracker_stream: str | Path | None = None
) -> Provenance:
    """Where a recording came from, as far as its metadata says."""
    metadata: dict[str, Any] = recording.metadata or {}
    scenario = metadata.get("scenario")
    simulated: bool | None = metadata.get("simulated")
    if simulated is None and metadata.get("source") == "spacecal simulator":
        simulated = True
    if simulated is None and metadata.get("source") == "spacecal acquire":
        simulated = False
    devices = {}
    for role in ("robot", "tracker"):
        entry = metadata.get(role)
        if isinstance(entry, dict):
            devices[role] = {k: v for k, v in entry.items() if k in ("model", "url", "name", "rate_hz")}
    return Provenance(
        recording=None if recording_path is None else str(Path(recording_path).resolve()),
        tracker_stream=None if tracker_stream is None else str(Path(tracker_stream).resolve()),
        simulated=simulated if isinstance(simulated, bool) else None,
        scenario=scenario if isinstance(scenario, dict) else None,
        devices=devices,
    )
