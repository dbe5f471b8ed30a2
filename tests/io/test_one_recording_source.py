"""One recording source: every recording is named, opened and checked in ``spacecal.io``; a
calibration keeps its recording as a :class:`~spacecal.records.RecordingSource` and every kind
reopens through :func:`~spacecal.io.recording_source.open_source` into the samples it was made
from, refused in one line by ``report``, ``verify``, ``check`` and ``bound`` once a file changed."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from spacecal import app
from spacecal.cli.main import main
from spacecal.core.errors import InvalidInputError
from spacecal.io.recordings import open_path, open_source, recording_kind, stream_paths
from spacecal.io.results_json import read_calibration
from spacecal.records import CalibrationResult, Provenance, RecordingSource
from spacecal.records.recording_source import OFFSET_GIVEN, OFFSET_NOT_RECORDED, PAIRED_CSV, RAW_STREAMS

ROOT = Path(__file__).resolve().parents[2]
#: Simulated with the robot clock this far ahead; the raw streams are paired at it.
CLOCK_OFFSET_MS = 7.0


def test_only_io_names_the_recording_files():
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    found = subprocess.run(
        ["git", "grep", "-n", r"recording.csv\|meta.json", "src/spacecal"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert found.returncode in (0, 1), found.stderr
    outside = [line for line in found.stdout.splitlines() if not line.startswith("src/spacecal/io/")]
    assert not outside, "\n".join(outside)


@pytest.fixture(scope="module", params=[PAIRED_CSV, RAW_STREAMS])
def calibrated(request, tmp_path_factory):
    """A simulated recording of each kind and its calibration: (kind, folder, the files, cal)."""
    folder = tmp_path_factory.mktemp(request.param)
    calibration = folder / "cal.json"
    if request.param == PAIRED_CSV:
        recording = folder / "rec.csv"
        app.simulate(app.SimulateSettings(output=str(recording), scenario="paper-white"))
        app.calibrate(app.CalibrateSettings(str(recording), str(calibration), "paper"))
        files = (recording, folder / "rec.meta.json")
    else:
        stem = folder / "raw"
        app.simulate(
            app.SimulateSettings(
                output=str(stem), scenario="paper-white", raw=True, clock_offset_ms=CLOCK_OFFSET_MS
            )
        )
        robot, tracker, meta = stream_paths(stem)
        app.calibrate(
            app.CalibrateSettings(
                str(robot),
                str(calibration),
                "paper",
                tracker_stream=str(tracker),
                time_offset_ms=CLOCK_OFFSET_MS,
            )
        )
        files = (robot, tracker, meta)
    return request.param, folder, files, calibration


def test_each_kind_is_recorded_and_reopens_into_the_samples_it_was_made_from(calibrated):
    kind, _, files, calibration = calibrated
    assert recording_kind(files[0]) == kind
    source = read_calibration(calibration).provenance.source
    assert source is not None and source.kind == kind
    assert [Path(f.path) for f in source.files] == [f.resolve() for f in files]
    assert all(f.sha256 is not None and len(f.sha256) == 64 for f in source.files)
    assert source.origin == "spacecal simulator"
    if kind == RAW_STREAMS:
        assert source.pairing is not None and source.pairing.offset_origin == OFFSET_GIVEN
        assert source.time_offset_s == pytest.approx(CLOCK_OFFSET_MS / 1000.0)
    reopened = open_source(source)
    first = open_path(*files[: 2 if kind == RAW_STREAMS else 1], source.time_offset_s)
    assert reopened.source.kind == kind and len(reopened.recording) == len(first.recording) > 100
    assert np.array_equal(reopened.recording.time_s, first.recording.time_s)
    assert np.array_equal(reopened.recording.base_from_tcp_stack, first.recording.base_from_tcp_stack)
    # the offset is the source's, not written into the diagnostics after the estimate
    written = json.loads(calibration.read_text())
    assert "time_offset_s" not in written["diagnostics"] and "tracker_kind" not in written["diagnostics"]
    assert written["provenance"]["tracker_kind"] == "auto"
    assert written["provenance"]["recording_sha256"] == source.recording_sha256  # for older readers


def commands(folder: Path, files: tuple[Path, ...], calibration: Path) -> dict[str, list[str]]:
    return {
        "report": ["report", str(calibration), "-o", str(folder / "report.html"), "--force"],
        "verify": ["verify", str(calibration), "--points", "3"],
        "check": ["check", str(calibration), "--recording", str(files[0])],
        "bound": ["bound", str(files[0]), "--calibration", str(calibration), "--sigma-mm", "0.1"],
    }


def _edit_marker_cell(path: Path) -> None:
    """One sample's marker 0.01 mm aside: a file that still reads, with other numbers."""
    lines = path.read_text().split("\n")
    column = lines[0].split(",").index("marker_x_mm")
    for row in range(5, len(lines)):
        cells = lines[row].split(",")
        if cells[column]:
            cells[column] = repr(float(cells[column]) + 0.01)
            lines[row] = ",".join(cells)
            break
    path.write_text("\n".join(lines))


def test_a_changed_file_of_each_kind_is_refused_in_one_line(calibrated, capsys):
    kind, folder, files, calibration = calibrated
    argvs = commands(folder, files, calibration)
    for name, argv in argvs.items():
        assert main(argv) == 0, (name, capsys.readouterr().err)
    # the file with the marker poses (the tracker stream of raw streams), then the metadata file
    edited = files[0] if kind == PAIRED_CSV else files[1]
    meta = files[-1]
    for changed, edit in (
        (edited, _edit_marker_cell),
        (meta, lambda p: p.write_text(json.dumps({**json.loads(p.read_text()), "note": "edited"}))),
    ):
        original = changed.read_bytes()
        edit(changed)
        capsys.readouterr()
        try:
            for name, argv in argvs.items():
                assert main(argv) == 1, (kind, name, changed.name)
                err = capsys.readouterr().err
                assert err.count("\n") == 1, (name, err)
                assert f"{changed.resolve()}: changed since the calibration was made from it" in err, (
                    name,
                    err,
                )
                assert "--accept-edited uses it anyway" in err
                assert main([*argv, "--accept-edited"]) == 0, (name, capsys.readouterr().err)
        finally:
            changed.write_bytes(original)
    assert main(argvs["report"]) == 0


def test_a_missing_tracker_stream_is_refused_in_one_line(calibrated, capsys):
    kind, folder, files, calibration = calibrated
    if kind != RAW_STREAMS:
        pytest.skip("a paired CSV has no tracker stream")
    moved = files[1].with_name("elsewhere.csv")
    files[1].rename(moved)
    try:
        capsys.readouterr()
        assert main(commands(folder, files, calibration)["report"]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "the calibration's tracker stream" in err and "is missing" in err
    finally:
        moved.rename(files[1])


def old_calibration_dict(recording: str, stream: str | None, offset_s: float | None) -> dict:
    """A calibration file as earlier versions wrote it: loose provenance fields, the offset
    and the tracker kind in the diagnostics."""
    new = CalibrationResult("paper", np.eye(4), np.eye(4), {"total": 1}, {}).to_dict()
    new.pop("integrity")
    provenance = {
        "recording": recording,
        "tracker_stream": stream,
        "simulated": True,
        "scenario": None,
        "devices": {},
        "recording_sha256": "a" * 64,
        "tracker_stream_sha256": None if stream is None else "b" * 64,
        "tool_definition": None,
        "tool_definition_sha256": None,
        "created_utc": "2025-01-01T00:00:00+00:00",
        "software": "spacecal 0.9",
    }
    diagnostics = {"tracker_kind": "pose"}
    if offset_s is not None:
        diagnostics["time_offset_s"] = offset_s
    return {**new, "schema_version": 2, "provenance": provenance, "diagnostics": diagnostics}


@pytest.mark.parametrize("stream, offset_s", [(None, None), ("/d/raw.tracker.csv", 0.0125)])
def test_an_old_calibration_file_reads_into_the_equivalent_source(stream, offset_s):
    robot = "/d/raw.robot.csv" if stream else "/d/rec.csv"
    calibration = CalibrationResult.from_dict(old_calibration_dict(robot, stream, offset_s))
    provenance = calibration.provenance
    source = provenance.source
    assert source is not None and source.kind == (RAW_STREAMS if stream else PAIRED_CSV)
    assert (provenance.recording, provenance.recording_sha256) == (robot, "a" * 64)
    assert (provenance.tracker_stream, provenance.tracker_stream_sha256) == (
        stream,
        "b" * 64 if stream else None,
    )
    assert provenance.tracker_kind == "pose"
    if stream:
        assert source.pairing is not None and source.pairing.offset_origin == OFFSET_NOT_RECORDED
        assert source.time_offset_s == offset_s
    else:
        assert source.pairing is None and source.time_offset_s is None
    # written again, it carries the source and the loose fields alike, and reads back the same
    again = CalibrationResult.from_dict(calibration.to_dict())
    assert again.provenance == provenance
    assert Provenance.from_dict(provenance.to_dict(), "again") == provenance


def test_a_raw_stream_source_without_its_offset_is_paired_at_an_estimate(calibrated):
    kind, _, files, calibration = calibrated
    if kind != RAW_STREAMS:
        pytest.skip("only raw streams are paired")
    source = read_calibration(calibration).provenance.source
    assert source is not None and source.pairing is not None
    data = source.to_dict()
    data["pairing"]["offset_s"] = None
    unknown = RecordingSource.from_dict(data)
    opened = open_source(unknown)
    assert "estimated clock offset" in opened.how
    estimated = float(opened.recording.metadata["paired_with_offset_s"])
    assert abs(estimated - CLOCK_OFFSET_MS / 1000.0) < 2e-3


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(kind="bag"), "'kind' must be one of"),
        (lambda d: d.update(files="rec.csv"), "'files' must be a list"),
        (lambda d: d["files"][0].update(sha256="xyz"), "sha256 must be 64 hex digits"),
        (lambda d: d["files"].append(dict(d["files"][0])), "each role at most once"),
        (lambda d: d.update(pairing={"offset_s": "soon"}), "'offset_s' must be a finite number"),
    ],
)
def test_a_bad_source_is_refused_in_one_line(change, message):
    data = RecordingSource.paired_csv("/d/rec.csv", "a" * 64).to_dict()
    change(data)
    with pytest.raises(InvalidInputError, match=message) as error:
        RecordingSource.from_dict(data, "cal.json: provenance source")
    assert "\n" not in str(error.value) and str(error.value).startswith("cal.json: provenance source")
